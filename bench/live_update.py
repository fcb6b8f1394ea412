"""Live look-dev (issue 18): property change -> updated material, and the render cost of live sockets.

Timing: Fig. 1d's 32 layers on iron, quartic 0.08, density 0.2 (table lobes, resolution 256, OSL + SVM + EEVEE twins) in a
fresh table cache; each row sets one ``material.scratch`` setting (headless: applied synchronously, the
same code the UI runs after its debounce) and times until the material is updated:

  socket         density / tint / base colour: one socket write (no table, no shader text)
  table miss     profile value or metal never seen: tables computed (cache miss), OSL source compiled (in the
                 background, ``osl_compile.precompile``, while the table images are repointed in place; also
                 when the adaptive tables change shape: node count S, θo rank)
  forced rebuild the same kind of miss applied as a full rebuild (``sync(force=True)``: what a shape change
                 cost before), interleaved with the in-place rows
  preview        the worker's quick tables of a miss (``prepare(spec, "preview")``), shown first in the UI
  table hit      back to a value seen before: tables from the cache, bytecode and alias tables reused
  structure      layer count: full rebuild (api.make_scratched_material, atomic), tables from the cache
  UI miss        in the UI the tables compute in worker threads: the main thread is blocked only while a
                 result is applied (measured by driving ``live._tick`` with timers simulated; main-thread CPU
                 by ``time.thread_time``); change -> preview shown, change -> full tables shown; with 1 worker
                 (``live.WORKERS``, the default: preview, then full) and 2 (side by side), interleaved
  tables alone   ``table_lobes`` without the cache: as shipped / the geometry store off (``slices.GEOMETRY_BYTES
                 = 0``: Fresnel inside every trace, the θo basis tracing the refined nodes again) / the traces
                 split with a helper process (``slices.TRACE_HELPER``), interleaved
  helper         the in-place profile miss with the traces split with the helper process, interleaved
  in place, as before   the same miss with the shader compiled on the main thread after the tables
                 (``osl_compile.precompile`` off), interleaved with the in-place rows
  OSL compile    wall of the shader's compile (``osl_compile._compile_text``) inside the in-place misses.  Cycles'
                 ``_cycles.osl_compile`` holds the GIL (measured: a Python loop beside it waits for the whole
                 compile), so the "background" compile does not overlap the main thread: on an idle machine the
                 in-place miss takes about the main thread's CPU plus this

Cost (``--cost``): whole-frame render A/B of the same material built with the "Scratch Controls" node
(length, width, density, tint as sockets) and with those values compiled in as constants (``LIVE_CONTROLS =
False``): a UV plane filling an orthographic camera, equal spp, adaptive sampling off, Cycles SVM and OSL,
A/B interleaved, medians of ``--repeats``.

    python -m bench live_update [--repeats 5] [--cost] [--res 96 96] [--spp 16]
"""
from __future__ import annotations

import argparse
import contextlib
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
_MAIN: list = []
_DEFAULT_RES: list = []


_COMPILES: list = []


@contextlib.contextmanager
def _compile_times():
    """Wall seconds of every OSL compile (``osl_compile._compile_text``, in its thread) go to ``_COMPILES``."""
    from scratch_materials.scratch_addon import osl_compile

    real = osl_compile._compile_text

    def timed(text):
        t0 = time.perf_counter()
        try:
            return real(text)
        finally:
            _COMPILES.append(time.perf_counter() - t0)

    osl_compile._compile_text = timed
    try:
        yield
    finally:
        osl_compile._compile_text = real


def _timed(fn) -> float:
    """Wall seconds of ``fn()``; its CPU seconds (all threads) go to ``_CPU`` (the machine is shared: CPU time
    is what the edit would take on an idle machine, within the threads' parallelism) and the calling thread's
    to ``_MAIN`` (the critical path when the other threads, the OSL compile, run beside it on the 2nd core)."""
    c0, m0, t0 = time.process_time(), time.thread_time(), time.perf_counter()
    fn()
    _CPU.append(time.process_time() - c0)
    _MAIN.append(time.thread_time() - m0)
    return time.perf_counter() - t0


def _row(label, cache, times, cpu=None) -> tuple:
    cpu = _CPU[-len(times):] if cpu is None else cpu
    return (label, cache, statistics.median(times), statistics.median(cpu), len(times))


def _ui_block(live, mat, prop, value) -> dict:
    """One edit in UI mode (worker thread, timers simulated): longest main-thread block (wall, and CPU of the
    main thread), seconds from the change to the preview shown and to the full tables shown."""
    real_bg = live._background
    live._background = lambda: False
    import bpy

    from scratch_materials.scratch_addon import scratch_material

    reg, isreg = bpy.app.timers.register, bpy.app.timers.is_registered
    bpy.app.timers.register = lambda *a, **k: None
    bpy.app.timers.is_registered = lambda *a, **k: True
    out = {"block": 0.0, "block_cpu": 0.0, "preview": None, "full": None}
    try:
        t0, c0 = time.perf_counter(), time.thread_time()
        setattr(mat.scratch, prop, value)
        out["block"], out["block_cpu"] = time.perf_counter() - t0, time.thread_time() - c0
        live._pending[mat.name] = 0.0          # the debounce is over
        while True:
            t1, c1 = time.perf_counter(), time.thread_time()
            last = live.last_update()
            again = live._tick()
            out["block"] = max(out["block"], time.perf_counter() - t1)
            out["block_cpu"] = max(out["block_cpu"], time.thread_time() - c1)
            if live.last_update() is not last:
                when = time.perf_counter() - t0
                if mat.get(scratch_material.PREVIEW_KEY):
                    out["preview"] = when
                else:
                    out["full"] = when
            if again is None:
                break
            time.sleep(0.005)
        return out
    finally:
        live._background = real_bg
        bpy.app.timers.register, bpy.app.timers.is_registered = reg, isreg


@contextlib.contextmanager
def _before():
    """The in-place update as it was before this round (session 5; for an interleaved A/B): the new shader is
    compiled on the main thread when the material is updated, not in the background while its table images
    update (``osl_compile.precompile`` off)."""
    from scratch_materials.scratch_addon import osl_compile

    saved = osl_compile.precompile
    osl_compile.precompile = lambda src: None
    try:
        yield
    finally:
        osl_compile.precompile = saved


@contextlib.contextmanager
def _workers(live, n: int):
    """The live-edit worker pool with ``n`` threads (1: a miss's preview, then its full tables, on one core)."""
    saved = live.WORKERS
    if live._worker is not None:
        live._worker.shutdown(wait=True)
        live._worker = None
    live.WORKERS = n
    try:
        yield
    finally:
        if live._worker is not None:
            live._worker.shutdown(wait=True)
            live._worker = None
        live.WORKERS = saved


@contextlib.contextmanager
def _helper(on: bool):
    """The exact traces split with the helper process (``slices.TRACE_HELPER``; started here) or not."""
    from scratch_materials.precompute.scratch import slices

    saved = slices.TRACE_HELPER
    slices.TRACE_HELPER = bool(on) and slices.start_trace_helper()
    try:
        yield
    finally:
        slices.TRACE_HELPER = saved


def _table_rows(spec_of, repeats: int) -> list:
    """Tables alone (``precompute.scratch.lobes.table_lobes``, no cache) of a profile miss at the material's
    resolution, interleaved: as shipped (geometry store on, one process), the geometry store off
    (``slices.GEOMETRY_BYTES = 0``: Fresnel inside every trace, the θo basis traces the refined nodes again, as
    before this round), and the traces split with the helper process (``slices.TRACE_HELPER``); with the
    traces' share (``slices._trace``, wall and CPU of this process)."""
    import dataclasses

    from scratch_materials.precompute.scratch import material as pm, profiles, slices

    real_trace, real_bytes = slices._trace, slices.GEOMETRY_BYTES
    traced = []

    def timed_trace(*a, **k):
        c0, t0 = time.process_time(), time.perf_counter()
        try:
            return real_trace(*a, **k)
        finally:
            traced[-1][0] += time.perf_counter() - t0
            traced[-1][1] += time.process_time() - c0

    variants = {"shipped": (real_bytes, False), "no store": (0, False), "helper": (real_bytes, True)}
    labels = {"shipped": "as shipped (geometry store, one process)",
              "no store": "geometry store off (Fresnel inside every trace; before this round)",
              "helper": "traces split with the helper process (slices.TRACE_HELPER)"}
    spec = spec_of()
    out = {k: [] for k in variants}
    slices._trace = timed_trace
    try:
        for i in range(repeats):
            order = list(variants) if i % 2 == 0 else list(variants)[::-1]
            for j, key in enumerate(order):
                p = dataclasses.replace(spec, profile=profiles.quartic(0.0407 + 0.0071 * i + 0.0002 * j))
                slices.GEOMETRY_BYTES = variants[key][0]
                traced.append([0.0, 0.0])
                with _helper(variants[key][1]):
                    t = _timed(lambda p=p: pm.lobes.table_lobes(p.profile, pm.trace_fresnel(p), p.resolution,
                                                                p.slices, use_cache=False))
                out[key].append((t, _CPU[-1], traced[-1][0], traced[-1][1]))
    finally:
        slices._trace, slices.GEOMETRY_BYTES = real_trace, real_bytes
    M = spec.resolution
    med = lambda n, k: statistics.median([r[k] for r in out[n]])  # noqa: E731
    rows = []
    for key in variants:
        rows.append((f"tables alone (table_lobes, M = {M}), {labels[key]}", "miss", med(key, 0), med(key, 1),
                     len(out[key])))
        rows.append((f"  of which the exact traces (slices._trace)", "miss", med(key, 2), med(key, 3), len(out[key])))
    return rows


def default_resolution() -> int:
    """The table resolution of a new material (the panel's default, ``ScratchMaterialSettings.resolution``)."""
    import bpy

    return int(bpy.types.Material.bl_rna.properties["scratch"].fixed_type.bl_rna.properties["resolution"].default)


def timing(repeats: int) -> list:
    api, live, render, scratch_material = _setup()
    render.reset_scene()
    # the 'demo' preset of issue 18's measurements (pinned: the preset itself is the README image's material)
    _DEFAULT_RES.append(default_resolution())
    mat = api.make_scratched_material("demo", profile=("quartic", 0.08),
                                      layers=dict(n_layers=32, theta_deg=360.0, length=0.3, width=3e-4, density=0.2))
    rows = []
    s = mat.scratch
    for label, prop, values in (("socket: density", "density", [0.3, 0.5]),
                                ("socket: tint", "tint", [(1, 0.8, 0.6), (1, 1, 1)])):
        ts = [_timed(lambda v=v: setattr(s, prop, v)) for _ in range(repeats) for v in values]
        rows.append(_row(label, "-", ts))
    misses, forced, c_miss, c_forced, old_miss, c_old, h_miss, c_h, m_miss = [], [], [], [], [], [], [], [], []
    for i in range(repeats):          # A/B/C/D interleaved: in place, with the trace helper, in place as before
        v = 0.06 + 0.013 * (i + 1)    # (main-thread compile), forced rebuild; never seen: cache miss
        with _compile_times():
            misses.append(_timed(lambda v=v: setattr(s, "profile_value", v)))
        c_miss.append(_CPU[-1])
        m_miss.append(_MAIN[-1])
        assert live.last_update()["kind"] == "tables", live.last_update()
        with _helper(True):
            h_miss.append(_timed(lambda v=v: setattr(s, "profile_value", v + 0.0017)))
            c_h.append(_CPU[-1])
        assert live.last_update()["kind"] == "tables", live.last_update()
        with _before():
            old_miss.append(_timed(lambda v=v: setattr(s, "profile_value", v + 0.0031)))
            c_old.append(_CPU[-1])
            assert live.last_update()["kind"] == "tables", live.last_update()
        with live.suspended():
            s.profile_value = 0.0605 + 0.013 * (i + 1)
        forced.append(_timed(lambda: live.sync(mat, force=True)))
        c_forced.append(_CPU[-1])
    rows.append(_row("table: profile value (in place)", "miss", misses, c_miss))
    rows.append(("table: profile value (in place), CPU of the main thread alone (the OSL compile, in its thread, "
                 "holds the GIL: idle-machine wall ~ this + the compile)", "miss", "-", statistics.median(m_miss),
                 len(m_miss)))
    if _COMPILES:
        rows.append(("  its OSL compile (in its thread, wall; holds the GIL: not beside the main thread's work)", "miss",
                     statistics.median(_COMPILES), "-", len(_COMPILES)))
    rows.append(_row("table: profile value (in place), traces split with the helper process (CPU: this process)",
                     "miss", h_miss, c_h))
    rows.append(_row("table: profile value (in place), as before: shader compiled on the main thread, after the "
                     "tables", "miss", old_miss, c_old))
    rows.extend(_table_rows(spec_of=lambda: live._spec(mat), repeats=repeats))
    rows.append(_row("table: profile value, forced rebuild (old path of a shape change)", "miss", forced, c_forced))
    hits = [_timed(lambda v=v: setattr(s, "profile_value", v)) for v in [0.06 + 0.013 * (i + 1)
                                                                         for i in range(repeats)]]
    rows.append(_row("table: profile value", "hit", hits))
    metal_miss, m_metal = [], []
    for m in ("gold", "copper", "silver", "aluminium"):
        metal_miss.append(_timed(lambda m=m: setattr(s, "metal", m)))
        m_metal.append(_MAIN[-1])
        assert live.last_update()["kind"] in ("tables", "rebuild")
    rows.append(_row("table: metal (in place; a larger θo rank rebuilds)", "miss", metal_miss))
    rows.append(("table: metal (in place), CPU of the main thread alone", "miss", "-", statistics.median(m_metal),
                 len(m_metal)))
    spec = live._spec(mat)
    import dataclasses

    from scratch_materials.precompute.scratch import profiles

    pv = [_timed(lambda i=i: scratch_material.prepare(dataclasses.replace(spec, profile=profiles.quartic(
        0.0517 + 0.011 * i)), "preview")) for i in range(repeats)]
    rows.append(_row("preview tables of a profile miss (worker, prepare)", "miss", pv))
    rows.append(_row("table: metal", "hit", [_timed(lambda m=m: setattr(s, "metal", m))
                                             for m in ("iron", "gold", "copper", "iron")]))
    rows.append(_row("layers: seed (in place)", "hit", [_timed(lambda n=n: setattr(s, "seed", n)) for n in (1, 2, 0)]))
    ui = {2: [], 1: []}            # two workers (preview and full side by side) / one, interleaved
    for i in range(max(2, repeats // 2)):
        for n in ((2, 1) if i % 2 == 0 else (1, 2)):
            with _workers(live, n):
                ui[n].append(_ui_block(live, mat, "profile_value", 0.031 + 0.007 * i + 0.0003 * n))
    for n, label in ((1, "UI, 1 worker (default: preview, then full)"), (2, "UI, 2 workers (side by side)")):
        med = lambda k: statistics.median([u[k] for u in ui[n] if u[k] is not None])  # noqa: E731
        rows.append((f"{label}: profile value, longest main-thread block (wall)", "miss", med("block"), "-",
                     len(ui[n])))
        rows.append((f"{label}: profile value, longest main-thread block (main-thread CPU)", "miss", "-",
                     med("block_cpu"), len(ui[n])))
        rows.append((f"{label}: profile value, change -> preview shown", "miss", med("preview"), "-", len(ui[n])))
        rows.append((f"{label}: profile value, change -> full tables shown", "miss", med("full"), "-", len(ui[n])))
    rows.append(_row("structure: layer count (rebuild)", "hit", [_timed(lambda n=n: setattr(s, "n_layers", n))
                                                                 for n in (31, 32)]))
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
           f"32 layers (Fig. 1d), iron, quartic 0.08, table lobes, resolution 256 (a new material's default: "
           f"{_DEFAULT_RES[0]}), OSL + SVM + EEVEE twins; headless, synchronous "
           f"except the UI rows; CPU s = process CPU (all threads) of the edit; "
           f"load average {load[0]:.1f} on {os.cpu_count()} cores (shared machine: noisy).")
    return 0
