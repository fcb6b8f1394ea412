"""Benchmark: fitted vs box vs tabulated-tilt lobes in a render: error vs samples vs time (issue #4).

The demo-like scene (torus, studio world, small area light; quartic 0.3 with iron Fresnel, 4 layers,
mirror base) rendered with each lobe shape at 4..256 spp.  Error = relative RMSE of the image
against a 4096-spp render with tabulated-tilt lobes (exact in expectation to < 0.1 % rel. L1 per
slice, ``precompute.scratch.lobe_table``, and matched to the ``reference`` mode in the tests), plus the
relative difference of the image mean.  ``--scene world`` (dense scratches, studio world only, M = 128) uses the
exact-table ``reference`` mode as the truth instead: independent of every lobe shape (it cannot
see lamps, hence no lamp in that scene).  Fitted lobes converge to their fit error (a bias); table
lobes to zero, with somewhat more noise per sample under the small light (a narrow lobe: NEE seldom
helps).  Time = wall time of the render (median of --repeats), table precompute time reported apart.

    python -m bench lobe_shapes [--quick] [--scene demo|spot] [--res 96 64] [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import numpy as np


def _blocks(img, b=8):
    """Mean over b x b pixel blocks (RGB summed): a low-noise view of the image for bias comparisons."""
    h, w = (img.shape[0] // b) * b, (img.shape[1] // b) * b
    return img[:h, :w].sum(-1).reshape(h // b, b, w // b, b).mean(axis=(1, 3))


def main(argv) -> int:
    from bench._util import blender, out_path, pyplot, report

    ap = argparse.ArgumentParser(prog="python -m bench lobe_shapes")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--res", type=int, nargs=2, default=(96, 64))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--truth-spp", type=int, default=4096)
    ap.add_argument("--scene", choices=["demo", "spot", "world"], default="demo",
                    help="demo: studio world + area light, 4 layers; spot: dense scratches, black world, "
                         "one small area light (the worst case for narrow lobes: only NEE/MIS light the image); "
                         "world: studio world only, M = 128, truth = the exact-table reference mode "
                         "(ray_portal_bsdf: independent of every lobe shape, but blind to lamps)")
    a = ap.parse_args(argv)
    spps = (4, 16) if a.quick else (4, 16, 64, 256)
    truth_spp = 256 if a.quick else a.truth_spp
    blender()
    from scratch_materials.precompute.scratch import brdf as scratch_brdf, lobes as scratch_lobes
    from scratch_materials.scratch_addon import materials, render, scratch_material as sm

    tmp = tempfile.mkdtemp(prefix="bench_lobe_shapes_")
    layers = dict(n_layers=4, theta_deg=360, length=0.3, width=0.005, density=0.2) if a.scene == "demo" else None
    M = 128 if a.scene == "world" else 256
    base = dict(profile=("quartic", 0.3), fresnel="iron", layers=layers, base="mirror", resolution=M, slices=64)
    shapes = ("fit", "box", "table")
    pre = {}
    brdf = scratch_brdf.simulate(sm.validate(**base).profile, resolution=M, fresnel=sm.validate(**base).fresnel)
    for shape in shapes:  # precompute time of the lobe tables (no cache)
        t0 = time.perf_counter()
        d = (scratch_lobes.table_lobes(sm.validate(**base).profile, sm.validate(**base).fresnel,
                                            resolution=M, slices=64, use_cache=False) if shape == "table" else
             scratch_lobes.lobe_tables(brdf, K=8, slices=64, jitter=shape == "box", use_cache=False))
        pre[shape] = (time.perf_counter() - t0, sm.fit_error(d))

    def scene_for(shape, spp, seed=0):
        scene = render.reset_scene()
        kw = dict(mode="reference") if shape == "reference" else dict(lobe_shape=shape)
        mat = sm.build(materials.new_material(f"L_{shape}"), sm.validate(**base, **kw))
        if a.scene == "world":
            render.studio_world(scene)
        elif a.scene == "demo":
            render.studio_world(scene)
            render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
        else:
            render.uniform_world(scene, 0.0)
            render.add_light(scene, "AREA", location=(1.5, -1.0, 2.0), energy=60.0, size=0.1)
        render.add_torus(scene, material=mat)
        render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
        render.configure_cycles(scene, samples=spp, res=a.res, seed=seed, osl=True)
        return scene

    truth_shape = "reference" if a.scene == "world" else "table"
    truth, _ = render.render_array(scene_for(truth_shape, truth_spp, seed=99), tmp, "truth")
    truth = truth[..., :3]
    norm = float(np.sqrt(np.mean(truth ** 2)))
    rows, curves = [], {s: [] for s in shapes}
    for spp in spps:
        for shape in shapes:
            ts, errs, mdiff, blocks = [], [], [], []
            for r in range(a.repeats):
                img, sec = render.render_array(scene_for(shape, spp, seed=r), tmp, f"{shape}{spp}")
                img = img[..., :3]
                ts.append(sec)
                errs.append(float(np.sqrt(np.mean((img - truth) ** 2))) / norm)
                mdiff.append(float(abs(img.mean() - truth.mean()) / truth.mean()))
                blocks.append(float(np.abs(_blocks(img) - _blocks(truth)).sum() / _blocks(truth).sum()))
            t, e = statistics.median(ts), statistics.median(errs)
            rows.append([shape, spp, t, e, statistics.median(blocks), statistics.median(mdiff), pre[shape][0],
                         pre[shape][1]])
            curves[shape].append((t, e))
            print(" ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in rows[-1]), flush=True)
    notes = (f"{a.res[0]}x{a.res[1]} px, CPU, median of {a.repeats} seeds; truth = {truth_shape} "
             f"{'mode' if truth_shape == 'reference' else 'lobes'} at {truth_spp} spp. "
             "rel. RMSE = RMS(image - truth) / RMS(truth); 'fit s' = lobe-table precompute without cache "
             f"(M = {M}, 64 slices, K = 8); 'fit err' = worst per-slice rel. L1 of the lobes vs rho cos; "
             "'8x8-block rel. L1': images averaged over 8x8 pixel blocks first (noise / 8: shows the bias).")
    report(f"lobe_shapes_{a.scene}", ["lobe shape", "spp", "render s", "rel. RMSE", "8x8-block rel. L1",
                                      "mean rel. diff", "fit s", "fit err"], rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for shape, pts in curves.items():
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=shape)
    ax.set_xlabel("render time (s)")
    ax.set_ylabel("rel. RMSE vs truth")
    ax.legend(title="lobe shape")
    ax.set_title(f"scene: {a.scene}")
    fig.tight_layout()
    fig.savefig(out_path(f"lobe_shapes_{a.scene}.png"), dpi=120)
    print(f"wrote {out_path(f'lobe_shapes_{a.scene}.png')}")
    return 0
