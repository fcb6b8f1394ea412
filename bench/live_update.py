"""Live look-dev (issue 18): property change -> updated material, and the render cost of live sockets.

Timing: the default preset material ("demo": 4 layers, table lobes, resolution 256, OSL + SVM twin) in a
fresh table cache; each row sets one ``material.scratch`` setting (headless: applied synchronously, the
same code the UI runs after its debounce) and times until the material is updated:

  socket         density / tint / base colour: one socket write (no table, no shader text)
  table miss     profile value or metal never seen: tables computed (cache miss), OSL source compiled, table
                 images rewritten in place
  table hit      back to a value seen before: tables from the cache, bytecode reused
  structure      layer count: full rebuild (api.make_scratched_material, atomic), tables from the cache
  UI block miss  in the UI the tables compute in a worker thread: the main thread is blocked only while the
                 result is applied (measured by driving ``live._tick`` with timers simulated)

Cost (``--cost``): whole-frame render A/B of the same material built with the "Scratch Controls" node
(length, width, density, tint as sockets) and with those values compiled in as constants (``LIVE_CONTROLS =
False``): a UV plane filling an orthographic camera, equal spp, adaptive sampling off, Cycles SVM and OSL,
A/B interleaved, medians of ``--repeats``.

    python -m bench live_update [--repeats 5] [--cost] [--res 96 96] [--spp 16]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time


def _setup():
    os.environ["SCRATCH_ADDON_CACHE"] = tempfile.mkdtemp(prefix="bench_live_cache_")
    from bench._util import blender

    blender(register=True)
    from scratch_materials.scratch_addon import api, live, render, scratch_material

    return api, live, render, scratch_material


_CPU: list = []


def _timed(fn) -> float:
    """Wall seconds of ``fn()``; its CPU seconds (all threads) go to ``_CPU`` (the machine is shared: CPU time
    is what the edit would take on an idle machine, within the threads' parallelism)."""
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    _CPU.append(time.process_time() - c0)
    return time.perf_counter() - t0


def _row(label, cache, times) -> tuple:
    cpu = _CPU[-len(times):]
    return (label, cache, statistics.median(times), statistics.median(cpu), len(times))


def _ui_block(live, mat, prop, value) -> tuple[float, float]:
    """(longest main-thread block, change -> updated material) for one edit in UI mode (worker thread)."""
    real_bg = live._background
    live._background = lambda: False
    import bpy

    reg, isreg = bpy.app.timers.register, bpy.app.timers.is_registered
    bpy.app.timers.register = lambda *a, **k: None
    bpy.app.timers.is_registered = lambda *a, **k: True
    try:
        t0 = time.perf_counter()
        setattr(mat.scratch, prop, value)
        block = time.perf_counter() - t0
        live._pending[mat.name] = 0.0          # the debounce is over
        while True:
            t1 = time.perf_counter()
            again = live._tick()
            block = max(block, time.perf_counter() - t1)
            if again is None:
                break
            time.sleep(0.01)
        return block, time.perf_counter() - t0
    finally:
        live._background = real_bg
        bpy.app.timers.register, bpy.app.timers.is_registered = reg, isreg


def timing(repeats: int) -> list:
    api, live, render, scratch_material = _setup()
    render.reset_scene()
    mat = api.make_scratched_material("demo")
    rows = []
    s = mat.scratch
    for label, prop, values in (("socket: density", "density", [0.3, 0.5]),
                                ("socket: tint", "tint", [(1, 0.8, 0.6), (1, 1, 1)])):
        ts = [_timed(lambda v=v: setattr(s, prop, v)) for _ in range(repeats) for v in values]
        rows.append(_row(label, "-", ts))
    misses = []
    for i in range(repeats):
        v = 0.06 + 0.013 * (i + 1)                       # never seen: cache miss
        misses.append(_timed(lambda v=v: setattr(s, "profile_value", v)))
        assert live.last_update()["kind"] == "tables"
    rows.append(_row("table: profile value", "miss", misses))
    hits = [_timed(lambda v=v: setattr(s, "profile_value", v)) for v in [0.05] + [0.06 + 0.013 * (i + 1)
                                                                               for i in range(repeats)]]
    rows.append(_row("table: profile value", "hit", hits))
    rows.append(_row("table: metal", "miss", [_timed(lambda m=m: setattr(s, "metal", m)) for m in ("gold", "copper")]))
    rows.append(_row("table: metal", "hit", [_timed(lambda m=m: setattr(s, "metal", m))
                                             for m in ("iron", "gold", "copper", "iron")]))
    rows.append(_row("layers: seed (in place)", "hit", [_timed(lambda n=n: setattr(s, "seed", n)) for n in (1, 2, 0)]))
    rows.append(_row("structure: layer count (rebuild)", "hit", [_timed(lambda n=n: setattr(s, "n_layers", n))
                                                                 for n in (5, 4)]))
    blocks, totals = [], []
    for i in range(max(1, repeats // 2)):
        b, t = _ui_block(live, mat, "profile_value", 0.031 + 0.007 * i)
        blocks.append(b)
        totals.append(t)
    rows.append(("UI, worker thread: profile value, longest main-thread block", "miss", statistics.median(blocks), "-",
                 len(blocks)))
    rows.append(("UI, worker thread: profile value, change -> updated", "miss", statistics.median(totals), "-",
                 len(totals)))
    return rows


def cost(repeats: int, spp: int, res) -> list:
    """Per-sample render cost, sockets (A) vs constants (B): both materials in one scene, the plane's material
    swapped between renders, order ABBA..., per sample = (t(spp) - t(spp / 4)) / (3 spp / 4): sync excluded."""
    api, live, render, scratch_material = _setup()
    tmp = tempfile.mkdtemp(prefix="bench_live_")
    rows = []
    for osl in (False, True):
        scene = render.reset_scene()
        scratch_material.LIVE_CONTROLS = True
        mats = {True: api.make_scratched_material("demo", resolution=128, name="sockets")}
        scratch_material.LIVE_CONTROLS = False
        mats[False] = api.make_scratched_material("demo", resolution=128, name="constants")
        scratch_material.LIVE_CONTROLS = True
        render.uniform_world(scene, strength=1.0)
        plane = render.add_plane(scene, size=2.0, material=mats[True])
        render.add_light(scene, "AREA", location=(1.0, -1.0, 3.0), energy=150.0, size=0.25)
        render.add_camera(scene, location=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), ortho_scale=1.6)
        render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=osl)
        scene.cycles.use_adaptive_sampling = False

        def per_sample(controls):
            plane.data.materials[0] = mats[controls]
            scene.cycles.samples = 4
            render.render_to_file(scene, os.path.join(tmp, "warm.png"))   # shader compile / kernel load
            scene.cycles.samples = spp // 4
            t_low = render.render_to_file(scene, os.path.join(tmp, "t.png"))
            scene.cycles.samples = spp
            t_high = render.render_to_file(scene, os.path.join(tmp, "t.png"))
            return (t_high - t_low) / (spp - spp // 4)

        times = {True: [], False: []}
        for i in range(repeats):
            for controls in ((True, False) if i % 2 == 0 else (False, True)):
                times[controls].append(per_sample(controls))
        a, b = statistics.median(times[True]), statistics.median(times[False])
        rows.append(("OSL" if osl else "SVM", a, b, a / b, repeats))
    return rows


def main(argv: list[str]) -> int:
    from bench._util import report

    ap = argparse.ArgumentParser(prog="python -m bench live_update")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cost", action="store_true", help="render A/B: live sockets vs compiled constants")
    ap.add_argument("--res", type=int, nargs=2, default=(96, 96))
    ap.add_argument("--spp", type=int, default=64)
    a = ap.parse_args(argv)
    load = os.getloadavg()
    if a.cost:
        rows = cost(a.repeats, a.spp, tuple(a.res))
        report("live_update_cost", ["path", "sockets s/spp", "constants s/spp", "ratio", "runs"], rows,
               f"Per-sample cost (t({a.spp} spp) - t({a.spp // 4} spp)) / {a.spp - a.spp // 4}, whole frame "
               f"{a.res[0]}x{a.res[1]}, adaptive off, UV plane filling an ortho camera, "
               f"'demo' preset at resolution 128, both materials in one scene, order ABBA, medians; load average {load[0]:.1f} on "
               f"{os.cpu_count()} cores.")
        return 0
    rows = timing(a.repeats)
    report("live_update", ["edit", "cache", "wall s (median)", "CPU s (median)", "n"], rows,
           f"'demo' preset (4 layers, table lobes, resolution 256, OSL + SVM twin); headless, synchronous; "
           f"load average {load[0]:.1f} on {os.cpu_count()} cores (shared machine: noisy).")
    return 0
