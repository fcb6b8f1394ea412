"""Whole-frame cost of the iridescent layer (issue #15 item 6, issue #17 item 5).

The material covers the whole frame (a UV sphere of radius 1 m seen by an orthographic camera of
scale 1.2 m: every pixel hits the sphere), uniform white world, equal spp, adaptive sampling off,
per-sample cost = (t(N + 1 spp) − t(1 spp)) / N (scene sync, OSL compilation and file output
cancel).  The yardstick is the layer's base alone — an SVM anisotropic Glossy (Multiscatter GGX,
roughness 0.2, anisotropy 0.8) rendered with Cycles' default shading system (SVM) — measured in the
same run, rounds interleaved (A/B/A/B ...), medians over rounds.

Rows: the base on SVM; the same base under the OSL shading system (no layer: what OSL itself costs);
the layer (route A) with the default candidates; stage breakdown by disabling stages one at a time in
the generated source (no scratch in reach: grid lookup only; the candidates and eq. 6's ρ without the
lobe (with the energy weight, KS 0 would let OSL's optimiser drop the candidate loop too: route A
estimates E from its lobe); one candidate; eq. 6's weight; no base weight).

Run: ``.venv/bin/python -m bench iridescence_cost [--quick]``.
"""
from __future__ import annotations

import os
import resource
import statistics
import tempfile
import time

RADIUS = 1.0
ORTHO = 1.2


def add_uv_sphere(scene, material, radius=RADIUS, segments=96, rings=48):
    """A smooth UV-mapped sphere (U around, V pole to pole) at the origin."""
    import bmesh
    import bpy

    mesh = bpy.data.meshes.new("Sphere")
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius, calc_uvs=True)
    for f in bm.faces:
        f.smooth = True
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new("Sphere", mesh)
    scene.collection.objects.link(obj)
    mesh.materials.append(material)
    return obj


def glossy_base(tree):
    """The yardstick: an anisotropic Glossy (Multiscatter GGX, roughness 0.2, anisotropy 0.8)."""
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "MULTI_GGX"
    g.inputs["Roughness"].default_value = 0.2
    g.inputs["Anisotropy"].default_value = 0.8
    g.inputs["Color"].default_value = (0.9, 0.9, 0.9, 1.0)
    return g


def sphere_scene(render, im, S, *, layer=True, osl=True, spp=1, res=(160, 160), edit=None, **layer_kw):
    """The whole-frame scene; ``edit(src) -> src`` rewrites the generated layer source (stage breakdown)."""
    import bpy

    scene = render.reset_scene()
    render.uniform_world(scene, 1.0)
    mat = bpy.data.materials.new("Iridescent sphere")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(glossy_base(tree).outputs[0], out.inputs["Surface"])
    add_uv_sphere(scene, mat)
    render.add_camera(scene, location=(0.0, -5.0, 0.0), target=(0.0, 0.0, 0.0), ortho_scale=ORTHO)
    if layer:
        node = im.insert_layer(mat, S, scene=scene, **layer_kw)
        if edit is not None:
            text = node.script
            src = edit(text.as_string())
            text.clear()
            text.write(src)
            from scratch_materials.scratch_addon import osl_compile

            osl_compile.compile_script_node(node)
    render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=osl)
    return scene


def define(name, value):
    """An ``edit`` that overrides one ``#define`` of the generated source."""
    def edit(src):
        lines = src.splitlines()
        for i, line in enumerate(lines):
            if line.startswith(f"#define {name} "):
                lines[i] = f"#define {name} {value}"
                return "\n".join(lines) + "\n"
        return f"#define {name} {value}\n" + src
    return edit


def replace(old, new):
    """An ``edit`` that replaces the text ``old`` (which must occur) of the generated source by ``new``."""
    def edit(src):
        if old not in src:
            raise ValueError(f"stage edit: {old!r} not in the generated source")
        return src.replace(old, new)
    return edit


def cpu_seconds() -> float:
    """User + system CPU time of this process (all render threads)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def per_sample_cost(render, build, n, tmp, name):
    """Per-sample cost of the scene ``build(spp)``: (t(n + 1 spp) − t(1 spp)) / n, in CPU seconds of this
    process (robust to other processes sharing the cores) and in wall seconds; returns (cpu, wall)."""
    cpu, wall = {}, {}
    for spp in (1, n + 1):
        scene = build(spp)
        c0, t0 = cpu_seconds(), time.perf_counter()
        render.render_to_file(scene, f"{tmp}/{name}_{spp}.exr")
        cpu[spp], wall[spp] = cpu_seconds() - c0, time.perf_counter() - t0
    return (cpu[n + 1] - cpu[1]) / n, (wall[n + 1] - wall[1]) / n


def cost_table(render, im, sets, configs, *, n, rounds, res, tmp):
    """Interleaved rounds over (set, config) rows; returns {(set, config): [per-sample seconds]}."""
    out = {}
    for r in range(rounds):
        for sname, S in sets:
            for cname, kw in configs:
                key = (sname, cname)
                c = per_sample_cost(render, lambda spp: sphere_scene(render, im, S, spp=spp, res=res, **kw), n, tmp,
                                    f"{sname}_{cname}".replace(" ", "_"))
                out.setdefault(key, []).append(c)
                print(f"round {r}: {sname:10s} {cname:28s} {c[0] * 1e3:7.2f} ms CPU / {c[1] * 1e3:7.2f} ms wall "
                      "per sample", flush=True)
    return out


def scratch_sets(im, quick=False):
    """Named scratch sets on the sphere's UV (1 cm per UV unit)."""
    sets = [("default", im.generate_scratch_set(300, seed=0)),
            ("issue17", im.generate_scratch_set(300, length_range=(0.3, 0.6), width_range_um=(3.0, 3.0),
                                                depth_range_um=(0.1375, 0.1375), seed=1))]
    if not quick:
        sets.append(("dense", im.generate_scratch_set(3000, length_range=(0.3, 0.6), width_range_um=(3.0, 3.0),
                                                      depth_range_um=(0.1375, 0.1375), seed=2)))
    return sets


CONFIGS = [
    ("base SVM", dict(layer=False, osl=False)),
    ("base OSL", dict(layer=False, osl=True)),
    ("layer A", dict(route="lobes")),
    ("layer A, eq. 6 weight (before #17)", dict(route="lobes", base_weight="paper")),
    ("layer A, no base weight", dict(route="lobes", base_blend=False)),
    ("layer A, eq. 6 weight, no lobes (KS 0)", dict(route="lobes", base_weight="paper", edit=define("KS", "0"))),
    ("layer A, 1 candidate", dict(route="lobes", candidates=1)),
    ("layer A, nothing in reach", dict(route="lobes", edit=define("NX", "0"))),
    ("layer A, frame from dPdu (no Tangent node; measurement only)", dict(route="lobes", edit=replace(
        "vector T = Tangent;", "vector T = dPdu;"))),
]


def main(argv) -> int:
    from bench._util import report
    from bench.iridescence_fig import setup

    quick = "--quick" in argv
    render, im = setup()
    n = 16 if quick else 64
    rounds = 1 if quick else 5
    res = (64, 64) if quick else (128, 128)
    tmp = tempfile.mkdtemp()
    sets = scratch_sets(im, quick)
    load0 = os.getloadavg()
    res_t = cost_table(render, im, sets, CONFIGS, n=n, rounds=rounds, res=res, tmp=tmp)
    load1 = os.getloadavg()
    rows = []
    for sname, _S in sets:
        med = {c: statistics.median(v[0] for v in res_t[(sname, c)]) for c, _kw in CONFIGS}
        wall = {c: statistics.median(v[1] for v in res_t[(sname, c)]) for c, _kw in CONFIGS}
        for cname, _kw in CONFIGS:
            rows.append([sname, cname, f"{med[cname] * 1e3:.2f}", f"{wall[cname] * 1e3:.2f}",
                         f"{med[cname] / med['base SVM']:.2f}", f"{med[cname] / med['base OSL']:.2f}"])
        # the energy fix's cost: per round (same round, adjacent renders), then the median of the ratios
        ratios = [a[0] / b[0] for a, b in zip(res_t[(sname, "layer A")], res_t[(sname, CONFIGS[3][0])])]
        rows.append([sname, "energy weight / eq. 6 weight (median of per-round ratios)", "", "",
                     f"{statistics.median(ratios):.3f}", ""])
    notes = (f"Whole frame: UV sphere r = 1 m filling a {res[0]}x{res[1]} orthographic frame, uniform white world, "
             f"adaptive sampling off, per-sample cost = (t({n + 1} spp) − t(1 spp))/{n}, median of {rounds} "
             "interleaved rounds.  × base = per-sample cost / the SVM anisotropic Glossy (Multiscatter GGX, "
             "roughness 0.2, anisotropy 0.8) on SVM in the same round set.  CPU seconds of the rendering process "
             "(user + system, all threads): robust to other processes sharing the cores.  Rows below 'layer A' are "
             "the stage breakdown: the eq. 6 weight (the layer before issue #17), no base weight, eq. 6 weight without "
             "lobes (KS 0: candidates and ρ only), one candidate, no scratch in reach (grid lookup only), and the "
             "shading frame from dPdu instead of the Tangent node's UV tangent (wrong on most meshes: it only "
             "measures what the Tangent node's attribute lookup and object-to-world transform cost).  "
             f"Machine load (1-min load average, {os.cpu_count()} cores) at the start / end of the run: "
             f"{load0[0]:.1f} / {load1[0]:.1f}.")
    report("iridescence_cost", ["set", "setup", "CPU ms / sample", "wall ms / sample", "× base SVM (CPU)",
                                "× base OSL (CPU)"], rows, notes)
    return 0
