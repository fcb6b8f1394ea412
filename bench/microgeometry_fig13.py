"""Fig. 13 of Dong et al. 2015 in Cycles: average-NDF vs synthesised-texture material, side by side.

    python -m bench microgeometry_fig13 [--quick] [--res 480 320] [--spp 64]

A synthetic brushed height field (numpy generators of precompute.microgeometry.heightfield: a Gaussian surface
with long correlation along x, its scratch depth modulated by a second, slow Gaussian field) is
saved as .npy and turned into two materials through the add-on's own path
(``scratch_addon.microgeometry_ops.material_from_heightfield``): (a) the ellipsoid fit to the
average filtered NDF (§5.1, §8; Fig. 13 middle) and (b) the §9 texture synthesised from one texel
strip along and one across the scratches (Fig. 13 right).  The same torus (UV u around the ring =
brushing direction), studio world and small area light are rendered with each.  Writes
``docs/img/microgeometry_fig13.png`` and ``bench/out/microgeometry_fig13.{md,png}`` and prints the
render times and the per-stage precompute times.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DOCS_IMG = ROOT / "docs" / "img"


def brushed_heightfield(shape, pixel_um: float = 1.0, seed: int = 5):
    """Brushed surface (µm): scratches along x whose depth varies slowly across the sample."""
    from scratch_materials.precompute.microgeometry.heightfield import HeightField, gaussian_surface

    scratches = gaussian_surface(shape, pixel_um, 0.12, (150.0, 3.0), seed=seed)
    depth = gaussian_surface(shape, pixel_um, 1.0, (600.0, 60.0), seed=seed + 1)
    h = scratches.heights * np.clip(1.0 + 0.45 * depth.heights, 0.2, None)
    return HeightField(h, pixel_um, source="brushed_heightfield")


def _scene(render, scene, material, res, spp):
    render.studio_world(scene, 0.6)
    render.add_torus(scene, material=material)
    render.add_light(scene, "AREA", location=(2.2, -2.6, 3.2), energy=180.0, size=0.2)
    render.add_camera(scene, location=(0.0, -3.6, 3.0), target=(0.0, 0.0, -0.15), lens=42.0)
    render.configure_cycles(scene, samples=spp, res=res, seed=0)


def _to_srgb(img):
    x = np.clip(img, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def main(argv: list[str]) -> int:
    from bench._util import out_path, pyplot, report

    ap = argparse.ArgumentParser(prog="python -m bench microgeometry_fig13")
    ap.add_argument("--quick", action="store_true", help="small field, 160x106 px, 16 spp (smoke run)")
    ap.add_argument("--res", type=int, nargs=2, default=(480, 320))
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--texture-size", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=2, help="renders per material (median time reported)")
    a = ap.parse_args(argv)
    field = (512, 512) if a.quick else (1024, 1024)
    if a.quick:
        a.res, a.spp, a.texture_size, a.repeats = (160, 106), 16, 128, 1
    from bench._util import blender

    blender()
    from scratch_materials.scratch_addon import microgeometry_ops as mg
    from scratch_materials.scratch_addon import render

    tmp = tempfile.mkdtemp(prefix="bench_fig13_")
    hf = brushed_heightfield(field)
    path = os.path.join(tmp, "brushed.npy")
    np.save(path, hf.heights)
    texel_um = 16.0
    common = dict(pixel_um=hf.pixel_um, sigma_um=1.0, ndf_kind="FILTERED")
    variants = (("(a) average NDF (ellipsoid fit)", {}),
                ("(b) synthesised texture (§9)", dict(synthesize=True, texture_size=a.texture_size,
                                                      texel_um=texel_um, seed=3)))
    pre = {}
    for label, extra in variants:  # precompute (or load from the cache), timed
        t0 = time.perf_counter()
        tables = mg.compute_tables(path, **common, **extra)
        pre[label] = (time.perf_counter() - t0, tables)
    # texels roughly square on the torus: u runs 2 pi R = 6.3 units, v 2 pi r = 2.5 units
    reps_u = 1.0 * 512 / a.texture_size
    rows, imgs, times = [], {}, {label: [] for label, _ in variants}
    for _ in range(a.repeats):  # interleaved; the first render of a process also pays kernel set-up
        for label, extra in variants:
            scene = render.reset_scene()  # a fresh file per image (drops the previous material)
            mat, info = mg.material_from_heightfield(path, color=(0.78, 0.77, 0.75), **common, **extra)
            if extra:
                mapping = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeMapping")
                mapping.inputs["Scale"].default_value = (reps_u, reps_u * 2.5 / 6.3, 1.0)
            _scene(render, scene, mat, a.res, a.spp)
            imgs[label], seconds = render.render_array(scene, tmp, "tex" if extra else "avg")
            times[label].append(seconds)
            if not extra:
                info_avg = info
            else:
                info_tex = info
    for (label, _), info in zip(variants, (info_avg, info_tex)):
        rows.append((label, f"{pre[label][0]:.2f}" + (" (cached)" if pre[label][1]["cached"] else ""),
                     statistics.median(times[label]), str(info["loss"])))
    ell = info_avg["ellipsoid"]
    notes = (f"height field {field[1]}x{field[0]} px of {hf.pixel_um} µm (synthetic brushed), filtered NDF "
             f"sigma = 1 µm; average ellipsoid (alpha_x, alpha_y, theta_x, theta_y, theta_z) = "
             f"{tuple(round(float(v), 4) for v in ell)}; texture {a.texture_size}^2 texels of {texel_um} µm; "
             f"render {a.res[0]}x{a.res[1]} px, {a.spp} spp, CPU, median of {a.repeats}.  Precompute time includes the cache "
             "(second runs are cache hits).")
    report("microgeometry_fig13", ["material", "precompute s", "render s", "Cycles conversion"], rows, notes)
    plt = pyplot()
    w, h = a.res
    fig, axs = plt.subplots(1, 2, figsize=(2 * w / 100, h / 100 + 0.45), dpi=100)
    for ax, (label, img) in zip(axs, imgs.items()):
        ax.imshow(_to_srgb(img))
        ax.set_title(label, fontsize=10)
        ax.axis("off")
    fig.suptitle("Dong et al. 2015 Fig. 13 analogue: same brushed microgeometry, Cycles SVM Glossy (GGX)",
                 fontsize=9, y=0.02, va="bottom")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    DOCS_IMG.mkdir(parents=True, exist_ok=True)
    target = DOCS_IMG / "microgeometry_fig13.png" if not a.quick else out_path("microgeometry_fig13_quick.png")
    fig.savefig(target)
    fig.savefig(out_path("microgeometry_fig13.png"))
    print(f"wrote {target}")
    return 0
