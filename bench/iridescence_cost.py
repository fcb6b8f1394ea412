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

Run: ``.venv/bin/python -m bench iridescence_cost [--quick]``; ``--energy [rounds] [spp]``: the energy weight vs
eq. 6's only, long renders, alternating order (``bench/out/iridescence_energy_cost.md``).
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


def cost_table(render, im, sets, configs, *, n, rounds, res, tmp, alternate=False):
    """Interleaved rounds over (set, config) rows; returns {(set, config): [per-sample seconds]}.
    ``alternate``: odd rounds run the configs in reverse order (A/B, B/A, ...: a load drift within a round
    does not favour the config that always runs first)."""
    out = {}
    for r in range(rounds):
        for sname, S in sets:
            for cname, kw in (configs[::-1] if alternate and r % 2 else configs):
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


def bootstrap_median_ci(x, reps=4000, seed=0):
    """Percentile bootstrap 95 % interval of the median of ``x``."""
    import numpy as np

    x = np.asarray(x, float)
    rng = np.random.default_rng(seed)
    med = np.median(x[rng.integers(0, x.size, (reps, x.size))], axis=1)
    return float(np.percentile(med, 2.5)), float(np.percentile(med, 97.5))


def energy_cost(argv) -> int:
    """``--energy [rounds] [spp]``: only the energy weight vs eq. 6's weight (issue #17 item 5), long renders
    (per-sample cost from t(spp + 1) − t(1)), A/B then B/A in alternate rounds; writes iridescence_energy_cost.md."""
    from bench._util import report
    from bench.iridescence_fig import setup

    nums = [int(a) for a in argv if a.isdigit()]
    rounds = nums[0] if nums else 12
    n = nums[1] if len(nums) > 1 else 128
    res = (128, 128)
    render, im = setup()
    sets = scratch_sets(im, False)
    configs = [CONFIGS[2], CONFIGS[3]]
    load0 = os.getloadavg()
    res_t = cost_table(render, im, sets, configs, n=n, rounds=rounds, res=res, tmp=tempfile.mkdtemp(),
                       alternate=True)
    load1 = os.getloadavg()
    rows = []
    for sname, _S in sets:
        a, b = res_t[(sname, configs[0][0])], res_t[(sname, configs[1][0])]
        ratios = [x[0] / y[0] for x, y in zip(a, b)]
        lo, hi = bootstrap_median_ci(ratios)
        rows.append([sname, f"{statistics.median(x[0] for x in a) * 1e3:.2f}",
                     f"{statistics.median(y[0] for y in b) * 1e3:.2f}", f"{statistics.median(ratios):.3f}",
                     f"{lo:.3f}-{hi:.3f}", f"{sum(x[0] for x in a) / sum(y[0] for y in b):.3f}",
                     f"{min(ratios):.2f}-{max(ratios):.2f}"])
    notes = (f"Energy-consistent base weight (layer A, issue #17) vs eq. 6's (1 − ρ) weight, whole-frame sphere at "
             f"{res[0]}x{res[1]}, per-sample CPU cost = (t({n + 1} spp) − t(1 spp))/{n}, {rounds} rounds, the two configs "
             "adjacent in each round, A/B and B/A in alternate rounds.  Ratio: median of the per-round ratios, its "
             "percentile-bootstrap 95 % interval, the ratio of the summed costs, and the range of per-round ratios.  "
             f"Machine load (1-min average, {os.cpu_count()} cores) start / end: {load0[0]:.1f} / {load1[0]:.1f}.")
    report("iridescence_energy_cost", ["set", "energy CPU ms / sample", "eq. 6 CPU ms / sample",
                                       "energy / eq. 6 (median)", "95 % CI", "ratio of sums", "per-round range"],
           rows, notes)
    return 0


def main(argv) -> int:
    from bench._util import report
    from bench.iridescence_fig import setup

    if "--energy" in argv:
        return energy_cost(argv)
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
