"""Load-free cost of the iridescent layer: instructions per sample under valgrind (issue #17 item 5, #15 item 6).

CPU-time ratios on a shared 2-core machine move by ±5-10 % per round; an instruction count does not.
This bench renders the whole-frame scene of ``bench/iridescence_cost`` (UV sphere filling an orthographic
frame, uniform white world, adaptive sampling off, one render thread) at a tiny resolution inside one
``valgrind --tool=callgrind`` process per scratch set, and counts the instructions (Ir) the process
executes in each render.  Between renders the child calls ``os.getppid()``; callgrind dumps its counters
before every ``getppid`` (``--dump-before=getppid``), so each render is one dump part.  Per config the
child renders 1 spp and N + 1 spp (``--repeat``: twice, every config's pair then again), and

    instructions per sample = (Ir(N + 1 spp) − Ir(1 spp)) / N

(scene sync, OSL JIT compilation and file output cancel; two repeats showed the count deterministic to
<!-- filled below -->).  Instructions are not time (no cache misses, no division latency), but the two paths run the
same Cycles kernel on the same pixels, so the ratio is a load-independent second opinion on the
CPU-time ratios of ``iridescence_cost``.  OSL's LLVM JIT runs under valgrind (its default
``--smc-check=all-non-file`` sees the JIT's code).

Run: ``.venv/bin/python -m bench iridescence_callgrind [--quick] [--repeat]`` (each OSL render is
~1.5 CPU-minutes under valgrind, mostly the JIT; the full run is ~25 CPU-minutes, two children at a time):
the whole breakdown on the default set, the energy question on all three sets.  Writes ``bench/out/iridescence_callgrind.md``.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

RES = (32, 32)
CONFIGS = [
    ("base SVM", dict(layer=False, osl=False)),
    ("base OSL", dict(layer=False, osl=True)),
    ("layer A (energy weight)", dict(route="lobes")),
    ("layer A, eq. 6 weight (before #17)", dict(route="lobes", base_weight="paper")),
    ("layer A, nothing in reach", dict(route="lobes", edit=("define", "NX", "0"))),
]
ENERGY, PAPER = CONFIGS[2][0], CONFIGS[3][0]


def _child(set_name: str, n: int, reps: int, names: list[str]) -> int:
    """Inside valgrind: render each config at 1 and n + 1 spp, ``reps`` times, calling getppid() after each render."""
    from bench import iridescence_cost as ic
    from bench.iridescence_fig import setup

    render, im = setup()
    S = dict(ic.scratch_sets(im, quick=False))[set_name]
    cfg = dict(CONFIGS)
    tmp = tempfile.mkdtemp()
    os.getppid()                                   # dump part 1: setup
    for rep in range(reps):
        for name in names:
            kw = dict(cfg[name])
            if "edit" in kw:
                kw["edit"] = getattr(ic, kw["edit"][0])(*kw["edit"][1:])
            for spp in (1, n + 1):
                scene = ic.sphere_scene(render, im, S, spp=spp, res=RES, **kw)
                scene.render.threads_mode = "FIXED"
                scene.render.threads = 1
                render.render_to_file(scene, f"{tmp}/r.exr")
                print(f"PART {rep} {name} {spp}", flush=True)
                os.getppid()                       # dump: this render
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


def _parts(prefix: str) -> list[int]:
    """Ir of each dump part callgrind wrote (files ``prefix.<k>``, in order)."""
    files = sorted(Path(prefix).parent.glob(Path(prefix).name + ".*"), key=lambda p: int(p.suffix[1:]))
    out = []
    for f in files:
        m = re.search(r"^summary:\s*(\d+)", f.read_text(errors="replace"), re.M)
        out.append(int(m.group(1)) if m else 0)
    return out


def run_set(set_name: str, n: int, reps: int, names: list[str], workdir: str) -> subprocess.Popen:
    """Start the valgrind child for one scratch set (returns the process)."""
    prefix = f"{workdir}/cg.{set_name}"
    cmd = ["valgrind", "--tool=callgrind", "--dump-before=getppid",
           f"--callgrind-out-file={prefix}", sys.executable, "-m", "bench", "iridescence_callgrind", "--child",
           set_name, str(n), str(reps), *names]
    env = dict(os.environ, PYTHONHASHSEED="0")
    log = open(f"{workdir}/{set_name}.log", "w")
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                            cwd=str(Path(__file__).resolve().parent.parent))


def per_sample(parts: list[int], names: list[str], n: int, reps: int) -> dict[str, list[float]]:
    """Instructions per sample per config and repeat from the dump parts (part 0: setup; then per repeat,
    per config, 1 spp and n + 1 spp; a final part after the last getppid)."""
    body = parts[1:1 + 2 * reps * len(names)]
    res = {name: [] for name in names}
    for rep in range(reps):
        for i, name in enumerate(names):
            k = 2 * (rep * len(names) + i)
            res[name].append((body[k + 1] - body[k]) / n)
    return res


def main(argv) -> int:
    if argv[:1] == ["--child"]:
        return _child(argv[1], int(argv[2]), int(argv[3]), argv[4:])
    from bench._util import report

    if shutil.which("valgrind") is None:
        print("iridescence_callgrind: valgrind not found", file=sys.stderr)
        return 2
    quick = "--quick" in argv
    n = 8 if quick else 64
    reps = 2 if "--repeat" in argv else 1
    all_names = [c for c, _ in CONFIGS]
    # the whole breakdown on the default set; the energy question on every set
    jobs = [("default", all_names)] if quick else [("default", all_names), ("issue17", [ENERGY, PAPER]),
                                                   ("dense", [ENERGY, PAPER])]
    workdir = tempfile.mkdtemp(prefix="irid_cg_")
    load0 = os.getloadavg()
    results = {}
    pending = list(jobs)
    running = []
    while pending or running:
        while pending and len(running) < 2:
            s, names = pending.pop(0)
            running.append((s, names, run_set(s, n, reps, names, workdir)))
        s, names, p = running.pop(0)
        if p.wait() != 0:
            print(Path(f"{workdir}/{s}.log").read_text()[-3000:], file=sys.stderr)
            raise RuntimeError(f"valgrind child for set {s!r} failed (log {workdir}/{s}.log)")
        results[s] = per_sample(_parts(f"{workdir}/cg.{s}"), names, n, reps)
    load1 = os.getloadavg()
    rows = []
    for s, names in jobs:
        r = results[s]
        mean = {c: sum(v) / len(v) for c, v in r.items()}
        for c in names:
            spread = f"{abs(r[c][0] - r[c][1]) / mean[c] * 100:.2f}" if reps > 1 else ""
            rows.append([s, c, f"{mean[c] / (RES[0] * RES[1]):.0f}", spread,
                         f"{mean[c] / mean['base SVM']:.3f}" if "base SVM" in mean else "",
                         f"{mean[c] / mean['base OSL']:.3f}" if "base OSL" in mean else ""])
        rows.append([s, "energy weight / eq. 6 weight", "", "", f"{mean[ENERGY] / mean[PAPER]:.4f}", ""])
    notes = (f"Instructions (valgrind callgrind, Ir) per pixel-sample: (Ir(render at {n + 1} spp) − Ir(render at 1 spp))"
             f" / {n} / {RES[0] * RES[1]} pixels, the whole-frame sphere scene of iridescence_cost at {RES[0]}x{RES[1]}, "
             f"one render thread, the configs of a set rendered in one valgrind process ({reps} repeat(s); with 2, "
             "'repeat spread' = |difference| / mean of the two).  The last column of the energy row: the instruction "
             "ratio energy weight / eq. 6 weight.  × base = instruction ratio to the SVM anisotropic Glossy (× base "
             f"SVM) and to the same base on OSL (× base OSL).  Load-independent; machine load {load0[0]:.1f} / "
             f"{load1[0]:.1f} (start / end) only affects wall time.")
    report("iridescence_callgrind", ["set", "setup", "Ir / pixel-sample", "repeat spread %", "× base SVM (Ir)",
                                     "× base OSL (Ir)"], rows, notes)
    shutil.rmtree(workdir, ignore_errors=True)
    return 0
