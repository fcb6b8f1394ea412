"""A table-changing live edit (issue 18), this checkout against another one ("before"), in interleaved processes.

Each round runs one child process per side (order alternating A B / B A); a child imports the package from its
side's checkout and times, after one warm-up:

  tables alone   ``precompute.scratch.lobes.table_lobes`` of ``--edits`` profile values never seen (quartic
                 0.07-0.11, iron, M = 256, 64 start slices, no cache): process CPU, and the CPU of the exact traces
                 (``slices._trace``) inside it
  profile miss   the bench ``live_update`` fixture (32 layers Fig. 1d, iron, quartic 0.08, table lobes, resolution
                 256, OSL + SVM + EEVEE twins): ``--edits`` profile values never seen set on ``material.scratch``
                 (headless: applied in place at once): wall, process CPU (all threads) and the main thread's CPU

Rows: medians over the rounds of each child's medians.  The "before" side is any checkout of the package, e.g. a
worktree of main: ``git worktree add --detach /tmp/before main``.

    python -m bench live_tables_ab --before /tmp/before [--rounds 4] [--edits 5]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

_CHILD = r"""
import json, os, statistics, sys, tempfile, time
root, what, edits = sys.argv[1], sys.argv[2], int(sys.argv[3])
os.environ["SCRATCH_ADDON_CACHE"] = tempfile.mkdtemp(prefix="bench_ab_")
os.chdir(root)
sys.path.insert(0, root)
out = {}
if what == "tables":
    from scratch_materials.precompute.scratch import lobes, material as pm, profiles, slices
    assert lobes.__file__.startswith(root), lobes.__file__
    F = pm.trace_fresnel(pm.validate(fresnel="iron"))
    lobes.table_lobes(profiles.quartic(0.0611), F, 256, 64, use_cache=False)
    real, acc = slices._trace, [0.0]
    def timed(*a, **k):
        c = time.process_time()
        try:
            return real(*a, **k)
        finally:
            acc[0] += time.process_time() - c
    slices._trace = timed
    cpu, tr = [], []
    for i in range(edits):
        acc[0] = 0.0
        c = time.process_time()
        lobes.table_lobes(profiles.quartic(0.0713 + 0.0087 * i), F, 256, 64, use_cache=False)
        cpu.append(time.process_time() - c)
        tr.append(acc[0])
    out = {"tables_cpu": statistics.median(cpu), "traces_cpu": statistics.median(tr)}
else:
    from bench._util import blender
    blender(register=True)
    from scratch_materials.scratch_addon import api, live, render
    assert live.__file__.startswith(root), live.__file__
    render.reset_scene()
    mat = api.make_scratched_material("demo", profile=("quartic", 0.08),
                                      layers=dict(n_layers=32, theta_deg=360.0, length=0.3, width=3e-4, density=0.2))
    mat.scratch.profile_value = 0.0611
    W, C, T = [], [], []
    for i in range(edits):
        c0, m0, t0 = time.process_time(), time.thread_time(), time.perf_counter()
        mat.scratch.profile_value = 0.0713 + 0.0087 * i
        W.append(time.perf_counter() - t0)
        C.append(time.process_time() - c0)
        T.append(time.thread_time() - m0)
        assert live.last_update()["kind"] == "tables", live.last_update()
    out = {"miss_wall": statistics.median(W), "miss_cpu": statistics.median(C), "miss_main_cpu": statistics.median(T)}
print("RESULT " + json.dumps(out))
"""

_LABELS = (("tables_cpu", "tables alone (table_lobes, M = 256), process CPU s"),
           ("traces_cpu", "  of which the exact traces (slices._trace), CPU s"),
           ("miss_wall", "profile miss in place, wall s"),
           ("miss_cpu", "profile miss in place, process CPU s (all threads)"),
           ("miss_main_cpu", "profile miss in place, main thread CPU s"))


def _child(root: str, what: str, edits: int) -> dict:
    env = dict(os.environ, PYTHONPATH="")
    res = subprocess.run([sys.executable, "-c", _CHILD, root, what, str(edits)], capture_output=True, text=True,
                         env=env, check=False)
    line = next((ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"child ({root}, {what}) failed:\n{res.stdout[-2000:]}\n{res.stderr[-4000:]}")
    return json.loads(line[len("RESULT "):])


def run(before: str, rounds: int, edits: int) -> list:
    here = str(Path(__file__).resolve().parent.parent)
    sides = {"this checkout": here, "before": str(Path(before).resolve())}
    got = {s: {} for s in sides}
    for i in range(rounds):
        order = list(sides) if i % 2 == 0 else list(sides)[::-1]
        for what in ("tables", "miss"):
            for side in order:
                for k, v in _child(sides[side], what, edits).items():
                    got[side].setdefault(k, []).append(v)
    rows = []
    for key, label in _LABELS:
        a = statistics.median(got["before"][key])
        b = statistics.median(got["this checkout"][key])
        rows.append((label, a, b, b / a, rounds))
    return rows


def main(argv: list[str]) -> int:
    from bench._util import report

    ap = argparse.ArgumentParser(prog="python -m bench live_tables_ab")
    ap.add_argument("--before", required=True, help="a checkout of the package to compare with (e.g. main)")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--edits", type=int, default=5)
    a = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    rows = run(a.before, a.rounds, a.edits)
    load1 = os.getloadavg()[0]
    report("live_tables_ab", ["measure", "before", "this checkout", "ratio", "rounds"], rows,
           f"Child processes per side, interleaved (A B / B A per round), {a.edits} edits each after one warm-up, "
           f"medians of the children's medians; before = {a.before}; load average {load0:.1f} -> {load1:.1f} on "
           f"{os.cpu_count()} cores (shared machine: wall is noisy, CPU less so).")
    return 0
