"""Whole-frame render cost of the tabulated-BRDF closure vs the SVM anisotropic Glossy (issue 16).

A plane fills a 96x96 frame (camera at 45°), studio world + an area lamp, adaptive sampling off,
per-sample cost = (t(1 + S) - t(1)) / S, materials interleaved A/B/C... in one run, median of the
repeats.  Tables: an anisotropic 10² x 10² table (a bi-scale bake's size) and an isotropic 32² x 32
table (a MERL import's size); baselines: SVM Glossy (GGX, anisotropy 0.8) and the same Glossy node on
the OSL backend (the table needs OSL; its own cost is the difference).

    .venv/bin/python -m bench tabulated_cost [--quick]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile


def main(argv: list[str]) -> int:
    import numpy as np

    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="bench tabulated_cost")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    if args.quick:
        args.spp, args.repeats = 8, 1
    blender()
    import bpy

    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.scratch_addon import materials, render, tabulated_material

    scene = render.reset_scene()
    render.studio_world(scene, 1.0)
    render.add_light(scene, "AREA", location=(2.0, -2.0, 3.0), energy=300.0, size=1.0)
    plane = render.add_plane(scene, size=40.0)
    render.add_camera(scene, location=(0.0, -3.0, 3.0), target=(0, 0, 0), lens=50.0)

    def glossy(wi, wo):
        return 0.8 * tb._ggx_unit(wi, wo, 0.2)[:, None] * np.ones(3) + np.array([0.1, 0.15, 0.2]) / np.pi

    svm = materials.new_material("SVM aniso glossy")
    g = svm.node_tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Roughness"].default_value = 0.45
    g.inputs["Anisotropy"].default_value = 0.8
    tan = svm.node_tree.nodes.new("ShaderNodeTangent")
    tan.direction_type = "UV_MAP"
    svm.node_tree.links.new(tan.outputs["Tangent"], g.inputs["Tangent"])
    svm.node_tree.links.new(g.outputs["BSDF"], svm.node_tree.nodes["Material Output"].inputs["Surface"])
    cases = [("SVM aniso Glossy", svm, False), ("OSL backend, same Glossy", svm, True),
             ("table aniso 10²x10² (OSL)", tabulated_material.make_tabulated_material(
                 tb.TabulatedBRDF.from_function(glossy, 10), "aniso table"), True),
             ("table iso 32²x32 (OSL)", tabulated_material.make_tabulated_material(
                 tb.TabulatedBRDF.from_function(glossy, 32, iso=True, n_theta=32), "iso table"), True)]
    tmp = tempfile.mkdtemp()
    times = {name: [] for name, _, _ in cases}
    for _ in range(args.repeats):
        for name, mat, osl in cases:                   # interleaved
            plane.data.materials.clear()
            plane.data.materials.append(mat)
            t = []
            for spp in (1, 1 + args.spp):
                render.configure_cycles(scene, samples=spp, res=(96, 96), seed=0, osl=osl)
                _, s = render.render_array(scene, tmp, "cost")
                t.append(s)
            times[name].append((t[1] - t[0]) / args.spp)
    base = statistics.median(times["SVM aniso Glossy"])
    osl_base = statistics.median(times["OSL backend, same Glossy"])
    rows = [[name, f"{1e3 * statistics.median(v):.2f}", f"{statistics.median(v) / base:.2f}x",
             f"{statistics.median(v) / osl_base:.2f}x"] for name, v in times.items()]
    load = os.getloadavg()
    report("tabulated_cost", ["material", "ms / sample (96x96 frame)", "vs SVM aniso Glossy", "vs OSL Glossy"], rows,
           notes=f"{args.repeats} interleaved repeats, medians, (t(1+{args.spp}) - t(1)) / {args.spp}; "
                 f"load average {load[0]:.1f} / {load[1]:.1f} on 2 cores")
    return 0
