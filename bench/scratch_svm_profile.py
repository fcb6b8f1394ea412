"""Load-free cost of the SVM scratch twin: callgrind instruction counts of the render kernel (issue 15 item 4).

Each set-up of ``bench/scratch_cost`` (whole frame: an orthographic UV sphere filling the view, white world) is
saved as a .blend (tiny: ``--res`` 32x32, ``--spp`` 4, one render thread) and rendered in its own process under
``valgrind --tool=callgrind`` with collection switched on only inside Cycles' path-tracing loop
(``ccl::PathTraceWorkCPU::render_samples_full_pipeline``): scene sync, Python and Blender start-up are not
counted.  Instruction counts are deterministic and independent of the machine's load (the ratio of two set-ups
is the ratio of their instructions, not of their time: memory stalls are not counted), and the bpy module has
symbols, so the table also says which Cycles functions take the instructions (self cost, top functions).

    python -m bench scratch_svm_profile [--only svm] [--res 32 32] [--spp 4] [--top 12]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TOGGLE = "ccl::PathTraceWorkCPU::render_samples_full_pipeline*"

_RENDER = """
import bpy, sys
bpy.ops.wm.open_mainfile(filepath=sys.argv[-1])
bpy.context.scene.render.filepath = sys.argv[-1] + ".png"
bpy.ops.render.render(write_still=False)
"""


def setups(only: str = ""):
    """(name, factory(materials, presets, scratch_material) -> material) of the profiled set-ups."""
    from bench import scratch_cost

    def scratch(n_layers, cost_off=0, density=None, race=None):
        def make(materials, presets, sm):
            if race is not None:   # force the layer race on (True) or off (False) for this build
                from scratch_materials.node_groups import scratch_svm

                old = scratch_svm.races
                scratch_svm.races = lambda lobe_data, layers: bool(race) and layers is not None and "cdf" in lobe_data
                try:
                    return make.inner(materials, presets, sm)
                finally:
                    scratch_svm.races = old
            return make.inner(materials, presets, sm)

        def inner(materials, presets, sm):
            fig1c = dict(presets.get("fig1c_scratched").params)
            layers = dict(fig1c["layers"], n_layers=n_layers)
            if density is not None:
                layers["density"] = density
            mat = materials.new_material(f"S{n_layers}.{cost_off}.{density}")
            return sm.build(mat, sm.validate(**dict(fig1c, layers=layers)), cost_off=cost_off)
        make.inner = inner
        return make

    def baseline(materials, presets, sm):
        return materials.make_brushed_material(roughness=0.2, anisotropy=0.8)

    def base_only(materials, presets, sm):
        fig1c = dict(presets.get("fig1c_scratched").params)
        mat = materials.new_material("base only")
        node = sm._base_node(mat.node_tree, sm.validate(**fig1c))
        mat.node_tree.links.new(node.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Surface"])
        return mat

    def floor(pick):
        """The floor of a 4-layer graph that tests each layer's coverage with a Voronoi node: the base, the 4
        texture-mapped Voronoi nodes, [F1 < d], the coverage sum and min(ᾱ, 1) behind a Mix Shader, and one plain
        Glossy as the scratch closure (``pick``: Θ of a covering layer picked and the Glossy's tangent rotated by
        it, as the real graph does); everything else the real graph runs is the lobe."""
        def make(materials, presets, sm):
            from scratch_materials.node_groups import scratch_svm
            from scratch_materials.precompute.scratch import layers as scratch_layers

            fig1c = dict(presets.get("fig1c_scratched").params)
            params = sm.validate(**dict(fig1c, layers=dict(fig1c["layers"], n_layers=4)))
            lp = params.layers
            theta_k, xi_k = scratch_layers.layer_transforms(lp)
            mat = materials.new_material(f"floor {pick}")
            tree = mat.node_tree
            g = scratch_svm._G(tree)
            base = sm._base_node(tree, params)
            uv = g.node("ShaderNodeUVMap").outputs["UV"]
            accs = scratch_svm.layer_coverage(g, uv, theta_k, xi_k, (lp.length, lp.width), float(lp.density) + 1e-7)
            acc = accs[-1]
            glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
            glossy.inputs["Roughness"].default_value = 0.05
            glossy.inputs["Anisotropy"].default_value = 0.9   # anisotropic: Cycles keeps the tangent (the pick)
            tan = g.node("ShaderNodeTangent", direction_type="UV_MAP")
            if pick:
                geo = g.node("ShaderNodeNewGeometry")
                wn = g.node("ShaderNodeTexWhiteNoise", noise_dimensions="3D")
                g._set(wn.inputs["Vector"], geo.outputs["Position"])
                target = g.math("MULTIPLY", wn.outputs["Value"], acc)
                theta = scratch_svm.picked_angle(g, target, accs, theta_k)
                rot = g.node("ShaderNodeVectorRotate", rotation_type="AXIS_ANGLE")
                g._set(rot.inputs["Vector"], tan.outputs["Tangent"])
                g._set(rot.inputs["Axis"], geo.outputs["Normal"])
                g._set(rot.inputs["Angle"], theta)
                g._set(glossy.inputs["Tangent"], rot.outputs["Vector"])
            else:
                g._set(glossy.inputs["Tangent"], tan.outputs["Tangent"])
            mixs = g.node("ShaderNodeMixShader")
            g._set(mixs.inputs["Fac"], g.math("MINIMUM", acc, 1.0))
            tree.links.new(base.outputs[0], mixs.inputs[1])
            tree.links.new(glossy.outputs[0], mixs.inputs[2])
            tree.links.new(mixs.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
            return mat
        return make

    rows = [("baseline: SVM aniso Glossy (MS GGX)", baseline), ("base only (Metallic, iron)", base_only),
            ("svm 4 layers floor: Voronoi coverage + one Glossy", floor(False)),
            ("svm 4 layers floor + layer pick and frame", floor(True)),
            ("svm 4 layers", scratch(4)), ("svm 16 layers", scratch(16)),
            ("svm 4 layers, race", scratch(4, race=True)), ("svm 16 layers, no race", scratch(16, race=False))]
    rows += [(f"svm 4 layers - {stage}", scratch(4, cost_off=bit)) for stage, bit in scratch_cost.STAGES.items()
             if bit != 2]
    rows.append(("svm 4 layers, all culled (d = 1e-5)", scratch(4, density=1e-5)))
    if "micro" in only:   # per-node costs (``MICRO``)
        rows += [(f"micro: {kind}", _micro(kind)) for kind in MICRO]
    if only:
        keys = only.split(",")
        rows = [r for r in rows if r[0].startswith("baseline") or any(k in r[0] for k in keys)]
    return rows


#: micro set-ups: the baseline Glossy with its roughness fed by 32 copies of one node kind (chained through a per-sample
#: value); (Ir(micro) - Ir(micro: none)) / 32 / samples = the SVM cost of one such node per shading point
MICRO = ("none", "math ADD(x, const)", "math ADD(x, const), Value3 linked", "math ADD(x, y), Value3 linked",
         "map range (linear, Steps linked)", "voronoi 2D F1", "image Closest", "white noise 4D color",
         "mapping (texture)", "vector rotate (axis angle)", "vector rotate (z axis)")
MICRO_N = 32


def _micro(kind):
    def make(materials, presets, sm):
        import bpy

        mat = materials.new_material(f"micro {kind}")
        tree = mat.node_tree
        nodes, links = tree.nodes, tree.links
        geo = nodes.new("ShaderNodeNewGeometry")
        dot = nodes.new("ShaderNodeVectorMath")
        dot.operation = "DOT_PRODUCT"
        links.new(geo.outputs["Position"], dot.inputs[0])
        links.new(geo.outputs["Incoming"], dot.inputs[1])
        x = dot.outputs["Value"]
        y = geo.outputs["Position"]
        img = None
        for i in range(MICRO_N if kind != "none" else 0):
            if kind.startswith("math"):
                m = nodes.new("ShaderNodeMath")
                m.operation = "ADD"
                links.new(x, m.inputs[0])
                if "y)" in kind:
                    links.new(dot.outputs["Value"], m.inputs[1])
                else:
                    m.inputs[1].default_value = 0.001 * (i + 1)
                if "Value3 linked" in kind:
                    links.new(dot.outputs["Value"], m.inputs[2])
                x = m.outputs[0]
            elif kind.startswith("map range"):
                m = nodes.new("ShaderNodeMapRange")
                m.inputs["From Min"].default_value = 0.001 * (i + 1)
                m.inputs["To Max"].default_value = 0.9
                links.new(x, m.inputs["Value"])
                links.new(dot.outputs["Value"], m.inputs[5])
                x = m.outputs[0]
            elif kind.startswith("voronoi"):
                m = nodes.new("ShaderNodeTexVoronoi")
                m.voronoi_dimensions = "2D"
                m.inputs["Randomness"].default_value = 1.0
                links.new(y, m.inputs["Vector"])
                y = m.outputs["Position"]
                x = m.outputs["Distance"]
            elif kind.startswith("image"):
                if img is None:
                    import numpy as np
                    from scratch_materials.node_groups.scratch_svm import _data_image
                    img = _data_image("micro image", np.random.default_rng(0).random((64, 64, 4)))
                m = nodes.new("ShaderNodeTexImage")
                m.image, m.interpolation, m.extension = img, "Closest", "EXTEND"
                links.new(y, m.inputs["Vector"])
                y = m.outputs["Color"]
                x = m.outputs["Alpha"]
            elif kind.startswith("white noise"):
                m = nodes.new("ShaderNodeTexWhiteNoise")
                m.noise_dimensions = "4D"
                links.new(y, m.inputs["Vector"])
                links.new(x, m.inputs["W"])
                y = m.outputs["Color"]
                x = m.outputs["Value"]
            elif kind.startswith("mapping"):
                m = nodes.new("ShaderNodeMapping")
                m.vector_type = "TEXTURE"
                m.inputs["Rotation"].default_value = (0.0, 0.0, 0.1 * i)
                m.inputs["Scale"].default_value = (1.1, 0.9, 1.0)
                links.new(y, m.inputs["Vector"])
                y = m.outputs["Vector"]
            elif kind.startswith("vector rotate"):
                m = nodes.new("ShaderNodeVectorRotate")
                m.rotation_type = "Z_AXIS" if "z axis" in kind else "AXIS_ANGLE"
                links.new(y, m.inputs["Vector"])
                if "z axis" not in kind:
                    links.new(geo.outputs["Normal"], m.inputs["Axis"])
                links.new(x, m.inputs["Angle"])
                y = m.outputs["Vector"]
        if kind.startswith(("mapping", "vector rotate")):
            sep = nodes.new("ShaderNodeSeparateXYZ")
            links.new(y, sep.inputs[0])
            x = sep.outputs[0]
        clamp = nodes.new("ShaderNodeMath")
        clamp.operation = "MULTIPLY_ADD"
        links.new(x, clamp.inputs[0])
        clamp.inputs[1].default_value = 1e-6
        clamp.inputs[2].default_value = 0.2
        glossy = nodes.new("ShaderNodeBsdfAnisotropic") if hasattr(bpy.types, "ShaderNodeBsdfAnisotropic") \
            else nodes.new("ShaderNodeBsdfGlossy")
        glossy.distribution = "MULTI_GGX"
        glossy.inputs["Anisotropy"].default_value = 0.8
        links.new(clamp.outputs[0], glossy.inputs["Roughness"])
        tan = nodes.new("ShaderNodeTangent")
        tan.direction_type = "UV_MAP"
        links.new(tan.outputs[0], glossy.inputs["Tangent"])
        links.new(glossy.outputs[0], nodes["Material Output"].inputs["Surface"])
        return mat
    return make


def build(folder: str, res, spp: int, only: str = "") -> list[tuple[str, str]]:
    """Save one .blend per set-up in ``folder``; returns [(name, path)]."""
    from bench._util import blender

    blender()
    import bpy

    from scratch_materials.scratch_addon import materials, presets, render
    from scratch_materials.scratch_addon import scratch_material as sm

    out = []
    for i, (name, make) in enumerate(setups(only)):
        bpy.ops.wm.read_homefile(use_empty=True)
        scene = render.reset_scene()
        mat = make(materials, presets, sm)
        render.uniform_world(scene, 1.0)
        render.add_sphere(scene, material=mat)
        render.add_camera(scene, location=(0.0, -4.0, 0.0), target=(0.0, 0.0, 0.0), ortho_scale=1.3)
        render.configure_cycles(scene, samples=spp, res=res, seed=0, threads=1)
        path = os.path.join(folder, f"setup{i}.blend")
        bpy.ops.wm.save_as_mainfile(filepath=path, compress=False)
        out.append((name, path))
    return out


def callgrind(path: str, top: int) -> tuple[int, list[tuple[int, str]]]:
    """(total Ir inside the path-tracing loop, [(self Ir, function)] top ``top``) of rendering ``path``."""
    cg = path + ".cg"
    cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={cg}", "--collect-atstart=no",
           f"--toggle-collect={TOGGLE}", sys.executable, "-c", _RENDER, path]
    subprocess.run(cmd, check=True, capture_output=True)
    return parse(cg, top)


def parse(cg: str, top: int) -> tuple[int, list[tuple[int, str]]]:
    """(total Ir, top functions by self Ir) of a callgrind output file."""
    ann = subprocess.run(["callgrind_annotate", "--threshold=100", cg], check=True, capture_output=True,
                         text=True).stdout
    total = 0
    m = re.search(r"^([\d,]+)\s+\(100\.0%\)\s+PROGRAM TOTALS", ann, re.M)
    if m:
        total = int(m.group(1).replace(",", ""))
    funcs = []
    for line in ann.splitlines():
        fm = re.match(r"^\s*([\d,]+)\s+\([\s\d.]+%\)\s+[^:\s]*:(.*)$", line)
        if fm and "PROGRAM TOTALS" not in line:
            name = "embree (ray traversal)" if "libembree" in fm.group(2) else _short(fm.group(2))
            funcs.append((int(fm.group(1).replace(",", "")), name))
    return total, funcs[:top]


#: Cycles functions (self cost) by shading stage, for ``breakdown``; the rest is the integrator, ray tracing and the
#: closures (the baseline's own work)
STAGE_FUNCS = (("layer Voronoi", ("voronoi_f1", "svm_node_tex_voronoi")),
               ("Mapping node (matrix per sample) + sin/cos (the closures' too)", ("svm_mapping", "sincosf", "svm_node_mapping")),
               ("image lookups", ("kernel_tex_image_interp", "svm_node_tex_image")),
               ("Math / Vector Math nodes", ("svm_math", "svm_vector_math", "powf", "atan2f", "atanf", "svm_node_math",
                                             "svm_node_vector_math")),
               ("Vector Rotate", ("svm_node_vector_rotate",)),
               ("White Noise", ("svm_node_tex_white_noise",)),
               ("SVM dispatch (svm_eval_nodes: per node, per unlinked input, inlined small nodes such as the texture "
                "mapping)", ("svm_eval_nodes",)))


def breakdown(cg: str) -> dict:
    """Self instructions of a callgrind file by ``STAGE_FUNCS`` stage (+ "rest" and "total")."""
    ann = subprocess.run(["callgrind_annotate", "--threshold=100", cg], check=True, capture_output=True,
                         text=True).stdout
    out = {name: 0 for name, _f in STAGE_FUNCS}
    out["rest (integrator, rays, closures)"] = 0
    total = 0
    for line in ann.splitlines():
        fm = re.match(r"^\s*([\d,]+)\s+\([\s\d.]+%\)\s+[^:\s]*:(.*)$", line)
        if not fm or "PROGRAM TOTALS" in line:
            continue
        ir, fn = int(fm.group(1).replace(",", "")), fm.group(2)
        total += ir
        short = _short(fn)
        for name, keys in STAGE_FUNCS:
            if any(k in short for k in keys):
                out[name] += ir
                break
        else:
            out["rest (integrator, rays, closures)"] += ir
    out["total"] = total
    return out


def breakdown_table(named: list[tuple[str, str]], n_samples: int, base_total: float) -> tuple[list, list]:
    """(headers, rows) of per-sample instructions by stage for [(column name, callgrind file)]."""
    cols = [(name, breakdown(cg)) for name, cg in named]
    stages = list(cols[0][1])
    rows = []
    for st in stages:
        rows.append([st] + [f"{c[st] / n_samples:,.0f}" for _n, c in cols])
    rows.append(["ratio to the baseline"] + [f"{c['total'] / base_total:.3f}x" for _n, c in cols])
    return ["stage (Ir per sample)"] + [n for n, _c in cols], rows


def _short(sig: str) -> str:
    """A readable function name: drop template arguments, parameter lists and the ccl:: namespace."""
    s = sig.strip()
    s = re.sub(r"\s*\[[^\]]*\]", "", s)
    depth, out = 0, []
    for ch in s:
        if ch in "<(":
            depth += 1
        elif ch in ">)":
            depth -= 1
        elif depth == 0:
            out.append(ch)
    s = "".join(out).replace("ccl::", "")
    return s.split()[-1] if s.split() else s


def main(argv: list[str]) -> int:
    from bench._util import report

    ap = argparse.ArgumentParser(prog="python -m bench scratch_svm_profile")
    ap.add_argument("--res", type=int, nargs=2, default=(32, 32))
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--only", default="")
    ap.add_argument("--top", type=int, default=10)
    ap.add_argument("--jobs", type=int, default=2, help="valgrind processes at once")
    ap.add_argument("--out", default="scratch_svm_profile")
    ap.add_argument("--keep", default="", help="folder to keep the .blend and callgrind files in")
    ap.add_argument("--reparse", action="store_true", help="re-read the callgrind files kept in --keep")
    ap.add_argument("--breakdown", nargs="*", default=None,
                    help="'column=file.cg' ...: per-stage table of kept callgrind files (first = the baseline)")
    a = ap.parse_args(argv)
    if a.breakdown is not None:
        named = [tuple(x.split("=", 1)) for x in a.breakdown]
        n = a.res[0] * a.res[1] * a.spp
        headers, rows = breakdown_table(named, n, breakdown(named[0][1])["total"])
        report(a.out, headers, rows, "callgrind self instructions of Cycles' path-tracing loop by function, grouped "
               "by stage (STAGE_FUNCS), per sample (32x32 px, 4 spp, one thread): deterministic, load-free.")
        return 0
    folder = a.keep or tempfile.mkdtemp(prefix="bench_svm_profile_")
    os.makedirs(folder, exist_ok=True)
    n_samples = a.res[0] * a.res[1] * a.spp
    if a.reparse:   # the callgrind files of an earlier run with --keep (same --only)
        built = [(name, os.path.join(folder, f"setup{i}.blend")) for i, (name, _m) in enumerate(setups(a.only))]
        results = {name: parse(path + ".cg", a.top) for name, path in built}
    else:
        from concurrent.futures import ThreadPoolExecutor

        built = build(folder, a.res, a.spp, a.only)
        with ThreadPoolExecutor(a.jobs) as pool:
            futures = {name: pool.submit(callgrind, path, a.top) for name, path in built}
        results = {name: f.result() for name, f in futures.items()}
    base = results[built[0][0]][0]
    none = results.get("micro: none", (None,))[0]

    def per_node(name, total):
        if not name.startswith("micro: ") or none is None or name == "micro: none" or total <= 0:
            return ""
        return f"{(total - none) / n_samples / MICRO_N:.0f}"

    rows = [(name, total / n_samples, total / base, per_node(name, total)) for name, (total, _f) in results.items()
            if total > 0]
    missing = [name for name, (total, _f) in results.items() if total <= 0]
    detail = []
    for name, (total, funcs) in results.items():
        detail.append(f"\n{name}: " + "; ".join(f"{f} {100 * ir / total:.0f} %" for ir, f in funcs if ir > 0.01 * total))
    notes = (f"callgrind (valgrind), {a.res[0]}x{a.res[1]} px, {a.spp} spp, one render thread; instructions (Ir) "
             f"counted inside {TOGGLE.rstrip('*')} only (no scene sync); 'Ir per sample' = total / "
             f"(pixels x spp); ratio against the baseline; 'Ir per node (micro)' = (micro - micro: none) / (pixels x spp x {MICRO_N}): one node of that kind per shading point (a Math node with a constant operand loads it with one more SVM node, NODE_VALUE_F, as every unlinked input it reads, used or not).  Deterministic: independent of the machine's load.\n"
             + (f"Not measured (the valgrind run did not finish): {', '.join(missing)}.\n" if missing else "")
             + "Self cost of the top functions (share of the set-up's instructions):" + "".join(
                 d for d in detail if not any(d.startswith(f"\n{m}:") for m in missing)))
    report(a.out, ["setup", "Ir per sample", "ratio", "Ir per node (micro)"], rows, notes)
    return 0
