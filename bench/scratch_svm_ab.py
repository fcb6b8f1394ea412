"""Interleaved timing A/B of two versions of the SVM scratch twin (node_groups/scratch_svm.py) in one process.

    git show fb1403d:node_groups/scratch_svm.py > /tmp/scratch_svm_old.py
    python -m bench scratch_svm_ab --old /tmp/scratch_svm_old.py [--res 96 96 --spp 65 --repeats 5]

The old file is loaded as a sibling module of ``node_groups.scratch_svm`` (same relative imports) and the material
builder uses it for the "old" rows.  Scene and per-sample cost as ``bench/scratch_cost`` (whole frame: a sphere
filling an orthographic view, white world, CPU time, (t(spp) - t(1)) / (spp - 1)); rows baseline, old / new at 4
and 16 layers (fig1c), interleaved in every round; ratios against the baseline of the same run.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import tempfile
import time


def main(argv: list[str]) -> int:
    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="python -m bench scratch_svm_ab")
    ap.add_argument("--old", required=True, help="an older node_groups/scratch_svm.py")
    ap.add_argument("--res", type=int, nargs=2, default=(96, 96))
    ap.add_argument("--spp", type=int, default=65)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="scratch_svm_ab_timing")
    a = ap.parse_args(argv)
    blender()
    from scratch_materials.node_groups import scratch_svm as new_svm
    from scratch_materials.scratch_addon import materials, presets, render
    from scratch_materials.scratch_addon import scratch_material as sm

    spec = importlib.util.spec_from_file_location("scratch_materials.node_groups.scratch_svm_old", a.old)
    old_svm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(old_svm)
    fig1c = dict(presets.get("fig1c_scratched").params)

    def scratch(n, module, tag):
        def make():
            sm.scratch_svm = module
            try:
                mat = materials.new_material(f"{tag} {n}")
                return sm.build(mat, sm.validate(**dict(fig1c, layers=dict(fig1c["layers"], n_layers=n))))
            finally:
                sm.scratch_svm = new_svm
        return make

    setups = [("baseline: SVM aniso Glossy (MS GGX)", lambda: materials.make_brushed_material(roughness=0.2,
                                                                                            anisotropy=0.8))]
    for n in (4, 16):
        setups += [(f"old svm {n} layers", scratch(n, old_svm, "old")), (f"new svm {n} layers", scratch(n, new_svm, "new"))]
    tmp = tempfile.mkdtemp(prefix="bench_svm_ab_")

    def scene_for(make, spp):
        scene = render.reset_scene()
        mat = make()
        render.uniform_world(scene, 1.0)
        render.add_sphere(scene, material=mat)
        render.add_camera(scene, location=(0.0, -4.0, 0.0), target=(0.0, 0.0, 0.0), ortho_scale=1.3)
        render.configure_cycles(scene, samples=spp, res=a.res, seed=0)
        return scene

    for _name, make in setups:   # warm the table cache: timings are render-only
        render.render_array(scene_for(make, 1), tmp, "warm")
    t_n = {n: [] for n, _m in setups}
    t_1 = {n: [] for n, _m in setups}
    load = []
    for _ in range(a.repeats):
        for name, make in setups:
            scene = scene_for(make, a.spp)
            for spp, store in ((a.spp, t_n), (1, t_1)):
                scene.cycles.samples = spp
                c0 = time.process_time()
                render.render_array(scene, tmp, "ab")
                store[name].append(time.process_time() - c0)
        load.append(os.getloadavg()[0])
    scenes = t_n
    per = {n: (statistics.median(t_n[n]) - statistics.median(t_1[n])) / (a.spp - 1) for n in scenes}
    base = per[setups[0][0]]
    rows = [(n, 1e3 * per[n], per[n] / base) for n in scenes]
    report(a.out, ["setup", "per-sample CPU ms", "ratio"], rows,
           f"Old: {a.old}.  Whole frame {a.res[0]}x{a.res[1]}, {a.spp} spp, CPU time, medians of {a.repeats} rounds, "
           f"every set-up in every round (interleaved).  Load average (1 min) after each round: "
           f"{', '.join(f'{x:.1f}' for x in load)} on {os.cpu_count()} cores shared with other jobs.")
    return 0
