"""Whole-frame render cost of the tabulated-BRDF closure vs the SVM anisotropic Glossy (issue 16 item 7).

Protocol (the one of ``bench/scratch_cost`` and ``bench/iridescence_cost``): an orthographic view filled by
a UV sphere carrying the material (no background pixel), studio world + an area lamp (NEE on), adaptive
sampling off, equal spp; per-sample cost = (t(N) - t(1)) / (N - 1) in CPU seconds of this (the render)
process (user + system, all render threads: robust to other processes sharing the cores); materials
interleaved A/B/C... in each round, medians over the rounds.

Rows: SVM anisotropic Glossy (the baseline), the same Glossy node on Cycles' OSL backend (the tables need
OSL: the backend's own overhead), an anisotropic 10² x 10² table (a bi-scale bake's size), an isotropic
32² x 32 table (an analytic BRDF), a MERL import (``merl_ops.material_from_merl`` of a MERL-format file
written from an analytic BRDF: iso 32² x 32; with its default floors, Diffuse + glossy, and with the Diffuse floor alone: the glossy floor's cost)
and a Dong NDF table (``make_ndf_material`` of the filtered
NDF of a brushed height field: the half-vector table of ``ndf_brdf``).  "SVM table" rows: the same materials on
Cycles' default shading system (SVM), which renders the table as nodes (``node_groups/tabulated_svm``: alias-table
bin pick, one narrow Glossy node).

    .venv/bin/python -m bench tabulated_cost [--quick] [--spp 33] [--rounds 5] [--res 96] [--only SVM]
    .venv/bin/python -m bench tabulated_cost --callgrind [--only "view grid"]   (load-free instruction counts)
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile


def cpu_seconds() -> float:
    """User + system CPU time of this process (all render threads)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def glossy(wi, wo):
    """The cost scenes' analytic BRDF (1/sr): GGX α 0.2 x 0.8 + Lambert (0.1, 0.15, 0.2); ``wi``, ``wo`` (N, 3)."""
    import numpy as np

    from scratch_materials.precompute.tables import tabulated_brdf as tb

    return 0.8 * tb._ggx_unit(wi, wo, 0.2)[:, None] * np.ones(3) + np.array([0.1, 0.15, 0.2]) / np.pi


def baseline_material():
    """Every cost ratio's baseline: Cycles' SVM anisotropic Glossy (GGX, roughness 0.45, anisotropy 0.8, UV tangent)."""
    from scratch_materials.scratch_addon import materials

    m = materials.new_material("SVM aniso glossy")
    g = m.node_tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Roughness"].default_value = 0.45
    g.inputs["Anisotropy"].default_value = 0.8
    tan = m.node_tree.nodes.new("ShaderNodeTangent")
    tan.direction_type = "UV_MAP"
    m.node_tree.links.new(tan.outputs["Tangent"], g.inputs["Tangent"])
    m.node_tree.links.new(g.outputs["BSDF"], m.node_tree.nodes["Material Output"].inputs["Surface"])
    return m


def cost_scene(make=None):
    """The whole-frame scene: studio world + an area lamp, a UV sphere (radius 1) filling an orthographic view
    (every pixel hits it), carrying ``make()`` (called after the scene reset, which removes every material);
    returns (scene, sphere)."""
    from scratch_materials.scratch_addon import render

    scene = render.reset_scene()
    render.studio_world(scene, 1.0)
    render.add_light(scene, "AREA", location=(2.0, -2.0, 3.0), energy=300.0, size=1.0)
    sphere = render.add_sphere(scene, radius=1.0, material=None if make is None else make())
    render.add_camera(scene, location=(0.0, -3.0, 3.0), target=(0, 0, 0), ortho_scale=1.3)
    return scene, sphere


def main(argv: list[str]) -> int:
    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="bench tabulated_cost")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--spp", type=int, default=33, help="N of (t(N) - t(1)) / (N - 1)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--res", type=int, default=96)
    ap.add_argument("--only", default=None, help="rows whose name contains this (and the baseline)")
    ap.add_argument("--callgrind", action="store_true", help="instructions per sample under valgrind (load-free)")
    args = ap.parse_args(argv)
    if args.callgrind:
        return callgrind_main(only=args.only or "")
    if args.quick:
        args.spp, args.rounds, args.res = 5, 1, 48
    blender()
    import bpy

    from scratch_materials.precompute.microgeometry.heightfield import gaussian_surface
    from scratch_materials.precompute.microgeometry.ndf import filtered_ndf
    from scratch_materials.precompute.tables import merl
    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.scratch_addon import merl_ops, render, tabulated_material

    scene, sphere = cost_scene()
    svm = baseline_material()
    tmp = tempfile.mkdtemp()
    merl_path = os.path.join(tmp, "ggx.binary")
    merl.write_merl(merl_path, merl.tabulate(glossy))
    hf = gaussian_surface((256, 256), 0.5, 0.3, (20.0, 1.5), seed=2)          # brushed, as the operator test
    ndf = filtered_ndf(hf, sigma_um=1.0, resolution=513)
    ndf_mat = tabulated_material.make_ndf_material(ndf, "NDF table", F=(0.9, 0.9, 0.9))
    aniso_mat = tabulated_material.make_tabulated_material(tb.TabulatedBRDF.from_function(glossy, 10), "aniso table")
    iso_mat = tabulated_material.make_tabulated_material(
        tb.TabulatedBRDF.from_function(glossy, 32, iso=True, n_theta=32), "iso table")
    merl_mat = merl_ops.material_from_merl(merl_path, "MERL ggx")          # floor "auto": the glossy floor here
    merl_diffuse = merl_ops.material_from_merl(merl_path, "MERL ggx diffuse floor", floor="diffuse")
    cases = [("SVM aniso Glossy", svm, False), ("OSL backend, same Glossy", svm, True),
             ("table aniso 10²x10² (OSL)", aniso_mat, True),
             ("table iso 32²x32 (OSL)", iso_mat, True),
             ("MERL import iso 32²x32 (OSL)", merl_mat, True),
             ("MERL, Diffuse floor only (OSL)", merl_diffuse, True),
             (f"Dong NDF table {ndf_mat['tabulated_res']}² (OSL)", ndf_mat, True),
             # the same materials on Cycles' default shading system: the table as SVM nodes (node_groups/tabulated_svm)
             ("SVM table aniso 10²x10²", aniso_mat, False),
             ("SVM table iso 32²x32", iso_mat, False),
             ("SVM table MERL iso 32²x32", merl_mat, False),
             ("SVM table MERL, Diffuse floor only", merl_diffuse, False),
             (f"SVM table Dong NDF {ndf_mat['tabulated_res']}² (half)", ndf_mat, False)]
    cases = [c for c in cases if args.only is None or c[0] in ("SVM aniso Glossy",) or args.only in c[0]]
    times = {name: [] for name, _, _ in cases}
    load0 = os.getloadavg()
    for r in range(args.rounds):
        for name, mat, osl in cases:                   # interleaved
            sphere.data.materials.clear()
            sphere.data.materials.append(mat)
            t = {}
            for spp in (0, 1, args.spp):     # 0: a 1-spp warm-up (shader compile, scene sync), discarded
                render.configure_cycles(scene, samples=max(spp, 1), res=(args.res, args.res), seed=0, osl=osl)
                c0 = cpu_seconds()
                render.render_to_file(scene, os.path.join(tmp, f"cost_{spp}.exr"))
                t[spp] = cpu_seconds() - c0
            times[name].append((t[args.spp] - t[1]) / (args.spp - 1))
            print(f"round {r}: {name:32s} {1e3 * times[name][-1]:8.2f} ms CPU / sample", flush=True)
    load1 = os.getloadavg()
    base = statistics.median(times["SVM aniso Glossy"])
    osl_base = statistics.median(times.get("OSL backend, same Glossy", times["SVM aniso Glossy"]))
    rows = [[name, f"{1e3 * statistics.median(v):.1f}", f"{statistics.median(v) / base:.2f}x",
             f"{statistics.median(v) / osl_base:.2f}x", " ".join(f"{x / b:.2f}" for x, b in
                                                                  zip(v, times['SVM aniso Glossy']))]
            for name, v in times.items()]
    report("tabulated_cost", ["material", f"CPU ms / sample ({args.res}² frame)", "vs SVM aniso Glossy",
                              "vs OSL Glossy", "per-round ratio vs SVM"], rows,
           notes=f"whole frame: orthographic view filled by a UV sphere (radius 1, ortho scale 1.3), studio world + "
                 f"area lamp, adaptive sampling off; per sample = (t({args.spp}) - t(1)) / {args.spp - 1} after a discarded "
                 f"1-spp warm-up render, CPU time (user + sys) of the render process; {args.rounds} interleaved rounds, medians; load average "
                 f"{load0[0]:.1f} at start, {load1[0]:.1f} at end, 2 cores")
    return 0


# ----------------------------------------------------------------------------- load-free: callgrind
def _callgrind_setups():
    """(name, factory() -> material) of the callgrind set-ups: the baseline and the SVM table graphs."""
    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.scratch_addon import tabulated_material

    def table(**kw):
        return lambda: tabulated_material.make_tabulated_material(tb.TabulatedBRDF.from_function(glossy, **kw), "t")
    vg = tb.view_grid_nodes(19, events=(-0.6458, 0.6458))
    return [("SVM aniso Glossy", baseline_material), ("SVM table aniso 10²x10²", table(res=10)),
            ("SVM table iso 32²x32", table(res=32, iso=True, n_theta=32)),
            ("SVM table view grid 19² x 19x19 (bi-scale size)", table(res=19, view_a=vg, view_b=tb.view_grid_nodes(19)))]


def callgrind_main(res: int = 32, spp: int = 4, jobs: int = 2, only: str = "") -> int:
    """Instructions per pixel-sample of each set-up (``_callgrind_setups``) under callgrind (``bench/scratch_svm_profile``:
    only Cycles' path-tracing loop counted), the ``tabulated_cost`` scene at ``res``² x ``spp``, one render thread."""
    from concurrent.futures import ThreadPoolExecutor

    from bench import scratch_svm_profile as prof
    from bench._util import blender, report

    blender()
    import bpy

    from scratch_materials.scratch_addon import render

    folder = tempfile.mkdtemp(prefix="bench_tab_cg_")
    built = []
    for i, (name, make) in enumerate(_callgrind_setups()):
        if only and i and only not in name:
            continue
        bpy.ops.wm.read_homefile(use_empty=True)
        scene, _ = cost_scene(make)
        render.configure_cycles(scene, samples=spp, res=(res, res), seed=0, threads=1)
        path = os.path.join(folder, f"setup{i}.blend")
        bpy.ops.wm.save_as_mainfile(filepath=path, compress=False)
        built.append((name, path))
    with ThreadPoolExecutor(jobs) as pool:
        futures = {name: pool.submit(prof.callgrind, path, 8) for name, path in built}
    results = {name: f.result() for name, f in futures.items()}
    n = res * res * spp
    base = results[built[0][0]][0]
    rows = [[name, f"{total / n:.0f}", f"{total / base:.3f}x",
             "; ".join(f"{f} {100 * ir / total:.0f} %" for ir, f in funcs[:6] if ir > 0.02 * total)]
            for name, (total, funcs) in results.items()]
    report("tabulated_callgrind", ["setup", "Ir / pixel-sample", "vs SVM aniso Glossy", "top self cost"], rows,
           notes=f"callgrind (valgrind), the tabulated_cost scene (UV sphere filling an orthographic view, studio world + "
                 f"area lamp) at {res}x{res} px, {spp} spp, one render thread; Ir counted inside {prof.TOGGLE.rstrip('*')} "
                 "only; deterministic, independent of the machine's load")
    return 0
