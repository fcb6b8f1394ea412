"""Render cost of the scratch SV-BRDF vs the SVM anisotropic GGX baseline (Raymond et al. 2016, Table 2 shape).

All set-ups render the demo scene (torus, studio world, small area light) at equal samples, interleaved
in one process, median of --repeats; ratios are against the SVM anisotropic GGX in the same run.

  baseline          node_groups/brushed.py (SVM Glossy, GGX, anisotropic)
  osl N layers      the generated OSL shader with the default table lobes, N = 1, 4, 16, 32 layers
                    (hash-picked layer, one sampled table lobe); "fitted lobes": K = 8 fitted lobes
  fitted, all       4 layers, K = 8 fitted lobes all summed (lobe_mode="all"): the cost of K without picking
  svm N layers      the node-group path (table lobes: log2 M lookups, one Glossy), N = 1, 4; and 4 layers
                    with K = 8 fitted lobes (every lobe of a slice summed)
  fitted K = 1..4   4 layers, OSL, varying the fitted-lobe budget (render cost vs fit error, bench.lobe_fit)
  skip              the baseline scene rendered with the add-on registered vs not: ratio must be ~1

    python -m bench scratch_cost [--quick] [--res 192 128] [--spp 32] [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _modules():
    from bench._util import blender

    scratch_addon = blender()
    from scratch_materials.scratch_addon import materials, render, scratch_material

    return scratch_addon, materials, render, scratch_material


def _scene(material, render, osl: bool, spp: int, res):
    scene = render.reset_scene()
    mat = material()
    render.studio_world(scene)
    render.add_torus(scene, material=mat)
    render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
    render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
    render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=osl)
    return scene


def main(argv: list[str]) -> int:
    from bench._util import out_path, pyplot, report

    ap = argparse.ArgumentParser(prog="python -m bench scratch_cost")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--res", type=int, nargs=2, default=(192, 128))
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-repeats", type=int, default=9,
                    help="interleaved pairs for the add-on-registered vs not ratio (a small effect needs many)")
    ap.add_argument("--only-skip", action="store_true", help="measure only the skip ratio")
    a = ap.parse_args(argv)
    if a.quick:
        a.res, a.spp, a.repeats = (64, 48), 8, 1
    addon, materials, render, sm = _modules()
    tmp = tempfile.mkdtemp(prefix="bench_scratch_cost_")

    def scratch(n_layers, backend="osl", lobes=8, shape="table", **spec):
        layers = None if n_layers == 0 else dict(n_layers=n_layers, theta_deg=360, length=0.3, width=0.005, density=0.2)

        def make():
            mat = materials.new_material(f"S{n_layers}{backend}{lobes}{shape}")
            params = sm.validate(profile=("quartic", 0.3), fresnel="aluminium", layers=layers, lobes=lobes,
                                 base="mirror", resolution=128, slices=64, backend=backend, lobe_shape=shape)
            return sm.build(mat, params, **spec)
        return make

    baseline = lambda: materials.make_brushed_material(roughness=0.35, anisotropy=0.85)  # noqa: E731
    setups = [("baseline (SVM aniso GGX)", baseline, False)]
    layer_counts = (1, 4) if a.quick else (1, 4, 16, 32)
    setups += [(f"osl {n} layers", scratch(n), True) for n in layer_counts]
    setups += [("osl 4 layers, fitted lobes", scratch(4, shape="fit"), True)]
    setups += [("osl 4 layers, fitted, all lobes", scratch(4, shape="fit", lobe_mode="all"), True)]
    setups += [(f"svm {n} layers", scratch(n, backend="svm"), False) for n in (1, 4)]
    setups += [("svm 4 layers, fitted lobes", scratch(4, backend="svm", shape="fit"), False)]
    if not a.quick:
        setups += [(f"osl 4 layers, fitted K={k}", scratch(4, lobes=k, shape="fit"), True) for k in (1, 2, 4)]
    # skip: the baseline scene with the add-on registered (nothing of ours in the scene)
    setups += [("baseline, add-on registered", baseline, False)]

    if a.only_skip:
        return _skip_ratio(a, addon, render, baseline, tmp)
    for _name, make, osl in setups:  # warm the table cache so timings are render-only
        _scene(make, render, osl, 1, (8, 8))
    times = {name: [] for name, _m, _o in setups}
    times1 = {name: [] for name, _m, _o in setups}
    for _ in range(a.repeats):
        for name, make, osl in setups:
            registered = name.endswith("registered")
            if registered:
                addon.register()
            try:
                for spp, store in ((a.spp, times), (1, times1)):
                    scene = _scene(make, render, osl, spp, a.res)
                    _img, seconds = render.render_array(scene, tmp, "cost")
                    store[name].append(seconds)
            finally:
                if registered:
                    addon.unregister()
    med = {n: statistics.median(t) for n, t in times.items()}
    # marginal cost per sample: (t(spp) - t(1)) / (spp - 1), free of the fixed scene-sync/OSL-JIT time
    marg = {n: max(med[n] - statistics.median(times1[n]), 1e-9) / (a.spp - 1) for n in times}
    b = "baseline (SVM aniso GGX)"
    rows = [(n, med[n], med[n] / med[b], 1e3 * marg[n], marg[n] / marg[b], med[n] - (a.spp - 1) * marg[n])
            for n in times]
    notes = (f"{a.res[0]}x{a.res[1]} px, {a.spp} spp, CPU, median of {a.repeats} interleaved runs in one process. "
             "'per-sample' = (t(spp) - t(1)) / (spp - 1): the cost that scales with samples, without the fixed "
             "scene-sync / OSL-JIT time ('fixed s'). "
             "Paper Table 2 (GPU, ms, brushed): 1/6/16/32 layers = 166/749/1850/3540 (sub-linear with culling).")
    report("scratch_cost", ["setup", "median s", "ratio", "per-sample ms", "per-sample ratio", "fixed s"], rows, notes)
    rows = [(n, t, r4) for n, t, r, _pm, r4, _f in rows]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    osl_rows = [(int(n.split()[1]), r) for n, _t, r in rows if n.startswith("osl") and n.endswith("layers")]
    ax.plot([n for n, _ in osl_rows], [r for _, r in osl_rows], "o-", label="OSL (picked layer, table lobe)")
    svm_rows = [(int(n.split()[1]), r) for n, _t, r in rows if n.startswith("svm") and n.endswith("layers")]
    ax.plot([n for n, _ in svm_rows], [r for _, r in svm_rows], "s-", label="SVM node group (table lobe)")
    ax.axhline(1.0, color="grey", lw=0.8)
    ax.axhline(1.3, color="red", lw=0.8, ls="--", label="target at 4 layers")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("layers")
    ax.set_ylabel("render time / SVM aniso GGX")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_path("scratch_cost.png"), dpi=120)
    print(f"wrote {out_path('scratch_cost.png')}")
    return 0


def _skip_ratio(a, addon, render, baseline, tmp) -> int:
    """A scene without scratch materials, rendered with the add-on registered vs not, in interleaved
    pairs (median of ``--skip-repeats``): the add-on installs no render hooks, so the ratio is ~1."""
    from bench._util import report

    times = {"not registered": [], "registered": []}
    for _ in range(a.skip_repeats):
        for key in times:
            if key == "registered":
                addon.register()
            try:
                scene = _scene(baseline, render, False, a.spp, a.res)
                times[key].append(render.render_array(scene, tmp, "skip")[1])
            finally:
                if key == "registered":
                    addon.unregister()
    med = {k: statistics.median(v) for k, v in times.items()}
    rows = [(k, med[k], med[k] / med["not registered"], min(v), max(v)) for k, v in times.items()]
    report("scratch_cost_skip", ["add-on", "median s", "ratio", "min s", "max s"], rows,
           f"{a.res[0]}x{a.res[1]} px, {a.spp} spp, SVM anisotropic GGX only; {a.skip_repeats} interleaved pairs.")
    return 0
