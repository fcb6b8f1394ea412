"""Whole-frame render cost of the scratch SV-BRDF vs the SVM anisotropic Glossy (Raymond et al. 2016, Table 2 shape).

Honest set-up (issue 15 item 3): an orthographic view filled by a UV sphere carrying the material (no background
pixel), a white world, CPU, equal samples, adaptive sampling off, every set-up built and rendered in the same
process, interleaved A/B/C... in each of ``--repeats`` rounds; medians.  Per-sample cost

    c = (t(spp) - t(1)) / (spp - 1)          (default spp = 129: (t(129) - t(1)) / 128)

removes the fixed scene-sync / OSL-JIT time; ratios are against the SVM anisotropic Glossy (Multiscatter GGX,
roughness 0.2, anisotropy 0.8) of the same run.

Rows
  baseline          SVM Glossy, Multiscatter GGX, anisotropic (node_groups/brushed.py)
  base only         the scratch material's base alone (Metallic BSDF, physical conductor, iron, roughness 0)
  osl base only     the same base rendered with Shading System OSL (Cycles' OSL Metallic node: what a culled
                    scratch material can cost at best on the OSL path)
  osl aniso GGX     osl/aniso_ggx.osl: the OSL twin of the baseline (what OSL itself costs)
  osl floor         the least a scratch shader can cost on the OSL path: an OSL script that picks, per sample,
                    the base closure (Metallic, iron, an input like the scratch shader's Base) or one narrow GGX
                    (tangent frame from a UV Tangent node), with fig1c's far-field scratched fraction
  osl N layers (L)  with ``--src L=TEMPLATE``: the same material with its script's text replaced by the file
                    TEMPLATE.format(n=N) (e.g. the shader of another commit, generated for fig1c with N layers):
                    before/after rows of one interleaved run
  osl / svm N       the fig1c_scratched preset (quartic 0.4, iron, mirror base) with N layers; "osl" renders
                    the OSL shader (Shading System OSL), "svm" the same material's node-group twin (Shading
                    System SVM, the default scene, the GPU path)
  - <stage>         the same with one stage switched off (``cost_off`` bits; the time it saves is its cost):
                    layer Voronoi (cell centres instead of hashed feature points), footprint α (OSL only:
                    binary [F1 <= d] at the point), slice/CDF search (bin straight from h), closure set-up
                    (untilted white lobe instead of the tilted, eq.-2-weighted one)
  - layer race      svm 16 layers as the picked-layer graph (every layer's Voronoi per sample) instead of
                    the race (node_groups/scratch_svm.py ``races``: layers visited in a random order behind
                    nested Mix Shaders, Cycles skips the rest once one covers the point)
  culled            4 layers at density 1e-5: c̄(d) < ALPHA_CULL, every layer culled at this footprint (OSL: the
                    shader returns the base closure before any scratch work, osl/scratch_svbrdf.osl)
  - early-out       (OSL, culled row) without the shader's early return of the base closure when every layer is
                    culled at the footprint (it then runs the frame, random numbers and α of every layer first)
  footprint α off   also switches the far-field shortcut off (α_k = c̄(d) without per-layer work where the
                    footprint spans many cells: the whole sphere here), so every layer runs the Voronoi loop: its
                    negative "stage cost" is what the far-field shortcut saves
  (the shaders read c̄(d) as d² times a table of c̄ / d² since issue 15's session 4: culling holds below
  d = sqrt(ALPHA_CULL / π) = 5.6e-4 as on the SVM path; the linear c̄ table before culled only below d = 1.25e-5)
  demo scene        the old bench's scene (torus under the studio world, ~30 % of the frame): labelled as such

    python -m bench scratch_cost [--quick] [--res 128 128] [--spp 129] [--repeats 3] [--only osl --out scratch_cost_osl]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: cost_off bits (osl/scratch_layer_alpha.h, osl/scratch_svbrdf.osl, node_groups/scratch_svm.py)
STAGES = {"layer Voronoi": 1, "footprint α": 2, "slice/CDF search": 4, "closure set-up": 8}
#: cost_off bit 16: the SVM twin's layer race off (node_groups/scratch_svm.py) and, in the OSL shader, its
#: early return of the base closure when every layer is culled off (osl/scratch_svbrdf.osl): one bit, two paths
RACE_OFF = EARLY_OUT_OFF = 16


#: the OSL floor row: base closure or one narrow GGX per sample (fig1c far field: 1 - (1 - c̄(0.3))^N scratched)
FLOOR_OSL = """#include "stdcycles.h"
shader scratch_cost_floor(closure color Base = 0, vector Tangent = 0, output closure color BSDF = 0)
{
    vector t = Tangent - dot(Tangent, N) * N;
    t = (length(t) > 1e-8) ? normalize(t) : dPdu;
    float h = hashnoise(P, dot(I, vector(93.989, 67.345, 24.113)) + 17.0);
    if (h < 0.72)
        BSDF = microfacet("ggx", N, t, 0.0001, 0.005, 0.0, 0);
    else
        BSDF = Base;
}
"""


def _modules():
    from bench._util import blender

    scratch_addon = blender()
    from scratch_materials.scratch_addon import materials, osl_compile, presets, render, scratch_material

    return scratch_addon, materials, osl_compile, presets, render, scratch_material


def main(argv: list[str]) -> int:
    import os

    from bench._util import out_path, report

    ap = argparse.ArgumentParser(prog="python -m bench scratch_cost")
    ap.add_argument("--quick", action="store_true", help="64x64, 33 spp, 1 round, fewer rows")
    ap.add_argument("--res", type=int, nargs=2, default=(128, 128))
    ap.add_argument("--spp", type=int, default=129)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--only", default="", help="comma-separated substrings: keep only rows whose name has one")
    ap.add_argument("--src", action="append", default=[], metavar="LABEL=TEMPLATE",
                    help="extra rows 'osl N layers (LABEL)': the fig1c material with the OSL text of TEMPLATE.format(n=N)")
    ap.add_argument("--out", default="scratch_cost", help="table name under bench/out/ (e.g. scratch_cost_osl with "
                                                          "--only osl: the OSL rows alone)")
    a = ap.parse_args(argv)
    if a.quick:
        a.res, a.spp, a.repeats = (64, 64), 33, 1
    addon, materials, osl_compile, presets, render, sm = _modules()
    tmp = tempfile.mkdtemp(prefix="bench_scratch_cost_")
    fig1c = dict(presets.get("fig1c_scratched").params)

    def scratch(n_layers, cost_off=0, density=None):
        def make():
            layers = dict(fig1c["layers"], n_layers=n_layers)
            if density is not None:
                layers["density"] = density
            mat = materials.new_material(f"S{n_layers}.{cost_off}.{density}")
            return sm.build(mat, sm.validate(**dict(fig1c, layers=layers)), cost_off=cost_off)
        return make

    def swapped(n_layers, path):
        def make():
            import bpy

            mat = scratch(n_layers)()
            node = sm.script_node(mat)
            text = bpy.data.texts.new(f"swapped {Path(path).name}")
            text.from_string(Path(path).read_text())
            node.script = text
            osl_compile.compile_script_node(node)
            return mat
        return make

    def osl_floor():
        mat = materials.new_material("osl floor")
        tree = mat.node_tree
        node = osl_compile.script_node_from_source(tree, "scratch_cost_floor.osl", FLOOR_OSL)
        base = sm._base_node(tree, sm.validate(**fig1c))
        tree.links.new(base.outputs[0], node.inputs["Base"])
        tan = tree.nodes.new("ShaderNodeTangent")
        tan.direction_type = "UV_MAP"
        tree.links.new(tan.outputs["Tangent"], node.inputs["Tangent"])
        tree.links.new(node.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
        return mat

    def baseline():
        return materials.make_brushed_material(roughness=0.2, anisotropy=0.8)

    def base_only():
        mat = materials.new_material("base only")
        node = sm._base_node(mat.node_tree, sm.validate(**fig1c))
        mat.node_tree.links.new(node.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Surface"])
        return mat

    def osl_aniso():
        from scratch_materials.osl import read_source

        mat = materials.new_material("osl aniso GGX")
        tree = mat.node_tree
        node = osl_compile.script_node_from_source(tree, "aniso_ggx.osl", read_source("aniso_ggx.osl"))
        node.inputs["Roughness"].default_value = 0.2
        node.inputs["Anisotropy"].default_value = 0.8
        node.inputs["Color"].default_value = (0.8, 0.8, 0.8) if len(node.inputs["Color"].default_value) == 3 \
            else (0.8, 0.8, 0.8, 1.0)
        tan = tree.nodes.new("ShaderNodeTangent")
        tan.direction_type = "UV_MAP"
        tree.links.new(tan.outputs["Tangent"], node.inputs["Tangent"])
        tree.links.new(node.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
        return mat

    # (name, material factory, OSL shading system, scene)
    setups = [("baseline: SVM aniso Glossy (MS GGX)", baseline, False, "frame"),
              ("base only (Metallic, iron)", base_only, False, "frame"),
              ("osl base only (Metallic, iron)", base_only, True, "frame"),
              ("osl aniso GGX (osl/aniso_ggx.osl)", osl_aniso, True, "frame"),
              ("osl floor: base or one GGX, picked", osl_floor, True, "frame")]
    counts = (4,) if a.quick else (4, 16)
    for spec in a.src:
        label, _, template = spec.partition("=")
        setups += [(f"osl {n} layers ({label})", swapped(n, template.format(n=n)), True, "frame") for n in counts]
    for path, osl in (("osl", True), ("svm", False)):
        setups += [(f"{path} {n} layers", scratch(n), osl, "frame") for n in counts]
        for stage, bit in STAGES.items():
            if path == "svm" and bit == 2:
                continue  # the SVM twin has no footprint (binary α)
            setups.append((f"{path} 4 layers - {stage}", scratch(4, cost_off=bit), osl, "frame"))
        if path == "svm" and not a.quick:
            setups.append(("svm 16 layers - layer race", scratch(16, cost_off=RACE_OFF), osl, "frame"))
        setups.append((f"{path} 4 layers, all culled (d = 1e-5)", scratch(4, density=1e-5), osl, "frame"))
        if osl:
            setups.append((f"{path} 4 layers, all culled (d = 1e-5) - early-out", scratch(4, cost_off=EARLY_OUT_OFF, density=1e-5),
                           osl, "frame"))
    setups += [("demo scene: baseline", baseline, False, "demo"),
               ("demo scene: osl 4 layers", scratch(4), True, "demo"),
               ("demo scene: svm 4 layers", scratch(4), False, "demo")]
    if a.only:
        keys = a.only.split(",")
        setups = [s for s in setups if s[0].startswith("baseline") or s[0] == "demo scene: baseline"
                  or any(k in s[0] for k in keys)]

    def scene_for(make, osl, kind, spp):
        scene = render.reset_scene()
        mat = make()
        if kind == "frame":
            render.uniform_world(scene, 1.0)
            render.add_sphere(scene, material=mat)
            render.add_camera(scene, location=(0.0, -4.0, 0.0), target=(0.0, 0.0, 0.0), ortho_scale=1.3)
            res = a.res
        else:
            render.studio_world(scene)
            render.add_torus(scene, material=mat)
            render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
            render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
            res = (int(a.res[0] * 1.5), a.res[1])
        render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=osl)
        return scene

    for _name, make, osl, kind in setups:  # warm the table cache so that timings are render-only
        scene_for(make, osl, kind, 1)
    t_n = {s[0]: [] for s in setups}
    t_1 = {s[0]: [] for s in setups}
    load = []
    w_n = {s[0]: [] for s in setups}

    def timed(scene):
        """(CPU seconds of this process's threads, wall seconds) of one render."""
        c0 = time.process_time()
        wall = render.render_array(scene, tmp, "cost")[1]
        return time.process_time() - c0, wall

    for _ in range(a.repeats):
        for name, make, osl, kind in setups:
            scene = scene_for(make, osl, kind, a.spp)
            cpu, wall = timed(scene)
            t_n[name].append(cpu)
            w_n[name].append(wall)
            scene.cycles.samples = 1
            t_1[name].append(timed(scene)[0])
        load.append(os.getloadavg()[0])
    per = {n: max(statistics.median(t_n[n]) - statistics.median(t_1[n]), 1e-9) / (a.spp - 1) for n in t_n}
    base = {"frame": per["baseline: SVM aniso Glossy (MS GGX)"], "demo": per["demo scene: baseline"]}
    kind_of = {s[0]: s[3] for s in setups}
    rows = []
    for n in t_n:
        ratio = per[n] / base[kind_of[n]]
        ref = n.split(" - ")[0] if " - " in n else None
        saved = "" if ref not in per else f"{(per[ref] - per[n]) / base['frame']:+.2f}x"
        spread = (max(t_n[n]) - min(t_n[n])) / max(statistics.median(t_n[n]), 1e-9)
        rows.append((n, 1e3 * per[n], ratio, saved, statistics.median(t_1[n]), statistics.median(w_n[n]),
                     f"{100 * spread:.0f} %"))
    notes = (f"Whole frame: {a.res[0]}x{a.res[1]} px orthographic view filled by a UV sphere (radius 1, 64x32), "
             f"white world, CPU, {a.spp} spp, adaptive sampling off; per-sample = (t({a.spp}) - t(1)) / {a.spp - 1} "
             "with t the CPU time of the render threads (process time: robust to the other jobs' load, which "
             "inflates wall time), "
             f"medians of {a.repeats} interleaved rounds in one process; 'ratio' against the baseline of the same "
             "scene in the same run.  'stage cost' = per-sample time the stage adds (full minus stage off, "
             "in baseline units).  'spread' = (max - min) / median of t(spp) (CPU).  Demo-scene rows: the old torus "
             f"scene ({int(a.res[0] * 1.5)}x{a.res[1]}), the torus covers ~30 % of the frame: ratios diluted by "
             f"background pixels.  Load average (1 min) during the rounds: {', '.join(f'{x:.1f}' for x in load)} "
             f"on {os.cpu_count()} cores shared with other jobs.")
    report(a.out, ["setup", "per-sample CPU ms", "ratio", "stage cost", "t(1) CPU s", f"wall s ({a.spp} spp)",
                            "spread"], rows, notes)
    return 0
