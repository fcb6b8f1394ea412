"""README figure in the spirit of Wu et al. 2011, Fig. 5 ("editing anisotropic metallic appearance by
altering a small-scale geometry"): isotropic -> anisotropic -> 4-way -> 5-way reflection.

Four small-scale tiles with the same isotropic Cook-Torrance metal (α = 0.2, as in the paper):
a random bumpy height field (isotropic), grooves along y (anisotropic), a raised 4-sided pyramid
(4-way) and a 5-sided pyramid (5-way, "no existing BRDF model can represent this").  Each tile is
baked to its effective BRDF (10K facets, dir_res 10) and fitted with Cycles closures
(``precompute.biscale.fit``, diffuse + 4 GGX lobes); the same UV-mapped torus (tangent around the
ring) is rendered under the studio world + a small area light.  ``--reference`` adds a second row
rendered with the exact reference mode (``osl.biscale_reference``; OSL, no light sampling: the area
light is reached only by sampled rays, made camera-visible for them, so its highlight is noisier).

Writes docs/img/biscale_fig5.png (full run) and bench/out/biscale_fig5.{png,md}; prints render times
and fit errors.  Run: ``.venv/bin/python -m bench biscale_fig5 [--quick] [--reference]``.
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = str(Path(__file__).resolve().parent.parent)
DOCS = Path(ROOT) / "docs" / "img"
METAL = {"model": "cook_torrance", "alpha": 0.2, "F0": (0.95, 0.78, 0.45), "distribution": "ggx"}


def tiles(quick: bool):
    """(label, numpy Tile) of the four panels."""
    from scipy.ndimage import gaussian_filter

    from scratch_materials.precompute.biscale.geometry import groove_tile, heightfield_tile, pyramid_tile
    res = 24 if quick else 48
    h = gaussian_filter(np.random.default_rng(5).random((res, res)), res / 12, mode="wrap")
    bumps = heightfield_tile((h - h.min()) / np.ptp(h) * 0.25)
    return [("isotropic: random bumps", bumps),
            ("anisotropic: grooves along v", groove_tile(depth=0.45, floor=0.2, top=0.2)),
            ("4-way: raised pyramid", pyramid_tile(n_sides=4, height=0.5)),
            ("5-way: pentagonal pyramid", pyramid_tile(n_sides=5, height=0.5))]


def _setup():
    from bench._util import blender

    blender(register=True)
    from scratch_materials.scratch_addon import biscale_material, render

    return render, biscale_material


def _scene(render, res, spp, osl):

    scene = render.reset_scene()
    render.studio_world(scene, strength=0.3)
    torus = render.add_torus(scene, major=1.0, minor=0.42)
    light = render.add_light(scene, kind="AREA", location=(1.5, -1.8, 2.6), energy=250.0, size=0.5)
    # the reference's ray_portal_bsdf rays keep camera-ray visibility: only a camera-visible light is
    # ever hit by them (no light sampling); the light is outside the frame
    light.visible_camera = bool(osl)
    render.add_camera(scene, location=(0.0, -3.4, 2.9), target=(0.0, 0.0, -0.05), lens=42.0)
    render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=osl, max_bounces=4)
    scene.view_settings.view_transform = "AgX"
    return scene, torus


def _render(render, scene, torus, mat, path):
    torus.data.materials.clear()
    torus.data.materials.append(mat)
    return render.render_to_file(scene, path)


def _inset(ax, tile):
    """Small shaded top view of the tile (lower-right corner), as in the paper's figures."""
    from scratch_materials.precompute.biscale.geometry import face_geometry
    V, F = np.asarray(tile.vertices), np.asarray(tile.faces)
    _, n = face_geometry(V, F)
    shade = np.clip(n @ np.array([-0.4, 0.5, 0.77]), 0.05, 1.0)
    ins = ax.inset_axes([0.74, 0.02, 0.25, 0.25])
    ins.tripcolor(V[:, 0], V[:, 1], F, facecolors=shade, cmap="gray", vmin=0, vmax=1)
    ins.set_aspect("equal")
    ins.set_xticks([])
    ins.set_yticks([])


def main(argv) -> int:
    from bench._util import out_path, pyplot, report
    from scratch_materials.precompute.tables import cache
    from scratch_materials.precompute.biscale.effective import BiscaleTile
    from scratch_materials.precompute.biscale.fit import fit_closures

    quick = "--quick" in argv
    with_ref = "--reference" in argv
    render, bmat = _setup()
    cache.set_cache_dir(os.environ.get("SCRATCH_ADDON_CACHE") or tempfile.mkdtemp(prefix="biscale_fig5_"))
    opts = dict(n_facets=2000, dir_res=6, normal_res=41, l_M=120) if quick else dict(n_facets=10000, dir_res=10)
    res = (160, 120) if quick else (480, 320)
    spp = 16 if quick else 128
    tmp = Path(tempfile.mkdtemp(prefix="biscale_fig5_"))
    rows, panels = [], []
    for k, (label, g) in enumerate(tiles(quick)):
        t0 = time.perf_counter()
        brdf = BiscaleTile(g.vertices, g.faces, g.face_material, **opts).effective_brdf([METAL] * 3)
        t_brdf = time.perf_counter() - t0
        t0 = time.perf_counter()
        fit = fit_closures(brdf, n_lobes=2 if quick else 4, max_nfev=15 if quick else 60)
        t_fit = time.perf_counter() - t0
        scene, torus = _scene(render, res, spp, osl=False)
        mat = bmat.make_biscale_material(fit, name=f"fit {k}")
        p_fit = str(tmp / f"fit_{k}.png")
        t_r = _render(render, scene, torus, mat, p_fit)
        row = [label, f"{len(g.faces)}", f"{t_brdf:.2f} s", f"{t_fit:.1f} s", f"{fit.rel_l1:.3f}", f"{fit.psnr:.1f} dB",
               f"{t_r:.1f} s"]
        p_ref = None
        if with_ref:
            scene, torus = _scene(render, res, spp * 2, osl=True)
            ref = bmat.make_biscale_material(name=f"ref {k}", mode="reference", brdf=brdf)
            p_ref = str(tmp / f"ref_{k}.png")
            row.append(f"{_render(render, scene, torus, ref, p_ref):.1f} s ({spp * 2} spp)")
        rows.append(row)
        panels.append((label, g, p_fit, p_ref))
        print(" | ".join(row), flush=True)
    plt = pyplot()
    import matplotlib.image as mpimg
    n_rows = 2 if with_ref else 1
    w_in = 4 * res[0] / 100
    fig, axes = plt.subplots(n_rows, 4, figsize=(w_in, n_rows * res[1] / 100 + 0.35 * n_rows), squeeze=False)
    for c, (label, g, p_fit, p_ref) in enumerate(panels):
        for r_, (p, tag) in enumerate([(p_fit, "fitted closures")] + ([(p_ref, "exact reference (OSL)")] if with_ref else [])):
            ax = axes[r_, c]
            ax.imshow(mpimg.imread(p))
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{label}" + (f"\n{tag}" if with_ref else ""), fontsize=8)
            _inset(ax, g)
    fig.tight_layout(pad=0.3)
    dst = out_path("biscale_fig5.png")
    fig.savefig(dst, dpi=100)
    plt.close(fig)
    if not quick:
        DOCS.mkdir(parents=True, exist_ok=True)
        shutil.copy(dst, DOCS / "biscale_fig5.png")
    headers = ["tile", "triangles", "f̄r (eq. 12)", "fit", "fit rel. L1", "fit PSNR", f"render fit ({spp} spp)"]
    if with_ref:
        headers.append("render reference")
    report("biscale_fig5", headers, rows,
           notes=f"Torus, studio world + area light, {res[0]}x{res[1]} px per panel, Cycles CPU (2 cores), "
                 f"SVM for the fitted closures.  Small-scale material: Cook-Torrance GGX α = 0.2, F0 = "
                 f"{METAL['F0']} (the paper's Fig. 5 metal).  Fit errors are on the D x D table (rel. L1 of "
                 f"f̄r, PSNR with peak = max f̄r).  Figure: {'bench/out only (--quick)' if quick else 'docs/img/biscale_fig5.png'}.")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
