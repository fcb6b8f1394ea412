"""Scratch materials at scene scale (issue 15 item 5): what N materials add to a frame's sync and to the .blend.

A grid of N small UV-mapped planes, each with its own scratch material: the 10 scratch presets (not "demo") in turn, every
repeat of a preset with another tint (so materials that share tables differ only by per-material values).
Measured in one process, interleaved with the same grid under one plain Glossy material (baseline):

  OSL text MB     total size of the distinct OSL texts the materials hold (Text datablocks)
  bytecode copies compiled script nodes in the file (each stores its bytecode: ~1 MB per scratch shader);
                  one per distinct shader since the script node lives in a shared group (scratch_material.shader_group)
  .blend MB       the saved file (default save: zstd-compressed) minus the baseline grid's file
  sync s          t(1 spp, 64x64, OSL) - t(baseline): the per-frame cost of syncing / compiling the materials
                  (every render is a new Cycles session: Cycles optimises and JIT-compiles one OSL group per material)
  persistent s    the same with Render > Performance > Persistent Data on, after a first render (an animation's
                  later frames): what re-syncing costs when Cycles keeps its session
  svm sync s      the same as sync s with Shading System SVM (the node-group twins)

  build s         wall time to build the N scratch materials (the race's shared lobe group made this ~5x faster)
  image MB        the packed table images' bytes in the saved .blend (zstd), from writing them alone

    python -m bench scratch_scale [--counts 20 100] [--repeats 3] [--no-osl]

``--no-osl`` skips the OSL columns (the OSL texts and bytecode do not depend on the SVM layout; a frame's OSL sync is
dominated by Cycles' per-material JIT, issue 15 item 5: blocked on the OSL side).
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time


def _modules():
    from bench._util import blender

    blender()
    import bpy

    from scratch_materials.scratch_addon import api, materials, presets, render

    return bpy, api, materials, presets, render


TINTS = [(1.0, 1.0, 1.0), (1.0, 0.85, 0.6), (0.7, 0.85, 1.0), (1.0, 0.7, 0.7), (0.8, 1.0, 0.8),
         (0.9, 0.9, 0.6), (0.6, 0.6, 0.6), (1.0, 0.95, 0.9), (0.85, 0.75, 1.0), (0.75, 1.0, 1.0)]


def build_grid(n: int, scratch: bool):
    """Reset the file and build the grid of ``n`` planes (scratch materials, or one baseline Glossy)."""
    bpy, api, materials, presets, render = _modules()
    scene = render.reset_scene()
    names = [p.name for p in presets.PRESETS.values() if p.kind == "scratch" and p.name != "demo"]
    side = int(n ** 0.5 + 0.999)
    base_mat = materials.make_brushed_material() if not scratch else None
    for i in range(n):
        if scratch:
            preset = names[i % len(names)]
            mat = api.make_scratched_material(preset, name=f"M{i:03d} {preset}", tint=TINTS[(i // len(names)) % len(TINTS)])
        else:
            mat = base_mat
        obj = render.add_plane(scene, size=0.9, material=mat, name=f"P{i:03d}")
        obj.location = (i % side - side / 2, i // side - side / 2, 0.0)
    render.uniform_world(scene, 1.0)
    render.add_camera(scene, location=(0.0, 0.0, 10.0), target=(0.0, 0.0, 0.0), ortho_scale=side + 1.0)
    return scene


def main(argv: list[str]) -> int:
    from bench._util import report

    ap = argparse.ArgumentParser(prog="python -m bench scratch_scale")
    ap.add_argument("--counts", type=int, nargs="+", default=[20, 100])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-osl", action="store_true", help="SVM columns only")
    a = ap.parse_args(argv)
    paths = (False,) if a.no_osl else (True, False)
    bpy, api, materials, presets, render = _modules()
    tmp = tempfile.mkdtemp(prefix="bench_scratch_scale_")
    rows, loads = [], []
    for n in a.counts:
        sizes, t = {}, {}
        for scratch in (False, True):
            t0 = time.perf_counter()
            scene = build_grid(n, scratch)
            build_s = time.perf_counter() - t0
            path = os.path.join(tmp, f"grid{n}{scratch}.blend")
            bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
            sizes[scratch] = os.path.getsize(path) / 1e6
            if scratch:
                texts = {tx.as_string() for tx in bpy.data.texts if tx.name.endswith(".osl")}
                text_mb = sum(len(s) for s in texts) / 1e6
                n_texts = len(texts)
                trees = [m.node_tree for m in bpy.data.materials if m.node_tree] + list(bpy.data.node_groups)
                n_bytecode = sum(1 for tr in trees for nd in tr.nodes if nd.bl_idname == "ShaderNodeScript" and nd.bytecode)
                n_nodes = sum(len(tr.nodes) for tr in trees)
                n_inlined = sum(_inlined(m.node_tree) for m in bpy.data.materials if m.node_tree)
                img_path = os.path.join(tmp, "images.blend")
                bpy.data.libraries.write(img_path, set(bpy.data.images), compress=True)
                image_mb = os.path.getsize(img_path) / 1e6
                scratch_build = build_s
            for osl in paths:
                render.configure_cycles(scene, samples=1, res=(64, 64), osl=osl)
                render.render_array(scene, tmp, "warm")   # first render: compile caches warm
                t[(scratch, osl)] = []
            # interleave the two shading systems on this grid; the baseline grid alternates below
            for _ in range(a.repeats):
                for osl in paths:
                    scene.cycles.shading_system = osl
                    c0 = time.process_time()
                    t[(scratch, osl)].append(render.render_array(scene, tmp, "scale")[1])
                    t.setdefault((scratch, osl, "cpu"), []).append(time.process_time() - c0)
            if a.no_osl:
                continue
            # Persistent Data (OSL): Cycles keeps its session between renders and re-syncs what changed
            scene.cycles.shading_system = True
            scene.render.use_persistent_data = True
            render.render_array(scene, tmp, "warm")
            t[(scratch, "persistent")] = [render.render_array(scene, tmp, "scale")[1] for _ in range(a.repeats)]
            scene.render.use_persistent_data = False
        med = {k: statistics.median(v) for k, v in t.items()}
        nan = float("nan")
        rows.append((n, n_texts, text_mb, n_bytecode, n_nodes, scratch_build, image_mb, sizes[True] - sizes[False],
                     med[(True, True)] - med[(False, True)] if not a.no_osl else nan,
                     med[(True, "persistent")] - med[(False, "persistent")] if not a.no_osl else nan,
                     med[(True, False)] - med[(False, False)], med[(True, False, "cpu")] - med[(False, False, "cpu")],
                     n_inlined, med[(False, False)]))
        loads.append(os.getloadavg()[0])
    report("scratch_scale", ["materials", "distinct OSL texts", "OSL text MB", "bytecode copies", "nodes",
                             "build s", "image MB", ".blend MB added", "OSL sync s added", "OSL persistent s added",
                             "SVM sync s added", "SVM sync CPU s added", "nodes Cycles syncs",
                             "baseline SVM t(1 spp) s"],
           rows,
           f"Grid of N planes, the 10 scratch presets in turn, repeats with another tint; 64x64 px, 1 spp, CPU; "
           f"medians of {a.repeats} renders after a warm-up render (per frame, as in an animation), scratch and "
           f"baseline grids in one process; load (1 min) after each grid size {', '.join(f'{x:.1f}' for x in loads)} "
           f"on {os.cpu_count()} cores shared with other jobs (wall times: the sync columns grow with the load)."
           + (" OSL columns not run (--no-osl)." if a.no_osl else "")
           + " 'SVM sync CPU s added': the same difference in CPU time of the process (all threads; less sensitive to "
             "the other jobs' load than wall time).  'nodes Cycles syncs': the materials' nodes with every group "
             "node replaced by its group's nodes (Blender hands Cycles each group instance inlined; the race "
             "positions are instances of one group).")
    return 0


def _inlined(tree) -> int:
    """Nodes of ``tree`` with each group node counted as the (recursively inlined) nodes of its group."""
    n = 0
    for node in tree.nodes:
        if node.bl_idname == "ShaderNodeGroup" and node.node_tree is not None:
            n += _inlined(node.node_tree)
        else:
            n += 1
    return n
