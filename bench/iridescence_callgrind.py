"""Load-free cost of the iridescent layer: instructions per sample under valgrind (issue #17 item 5, #15 item 6).

CPU-time ratios on a shared 2-core machine move by ±5-10 % per round; an instruction count does not.
This bench renders the whole-frame scene of ``bench/iridescence_cost`` (UV sphere filling an orthographic
frame, uniform white world, adaptive sampling off, one render thread) at a tiny resolution inside one
``valgrind --tool=callgrind`` process per scratch set, and counts the instructions (Ir) the process
executes in each render.  Between renders the child calls ``os.getppid()``; callgrind dumps its counters
before every ``getppid`` (``--dump-before=getppid``), so each render is one dump part.  Per config the
child renders 1 spp and N + 1 spp (``--repeat``: twice, every config's pair then again), and

    instructions per sample = (Ir(N + 1 spp) − Ir(1 spp)) / N

counting only the inclusive Ir of Cycles' ``PathTraceWorkCPU::render_samples_full_pipeline`` (the
bpy module keeps its symbol table): scene building, sync, the OSL JIT and file output are left out
(they vary by ~1e7 instructions between identical renders), the per-sample work is deterministic
(two identical renders in one process: 11,511,265 and 11,511,387 Ir, 1e-5).  Instructions are not time (no cache misses, no division latency), but the two paths run the
same Cycles kernel on the same pixels, so the ratio is a load-independent second opinion on the
CPU-time ratios of ``iridescence_cost``.  OSL's LLVM JIT runs under valgrind (its default
``--smc-check=all-non-file`` sees the JIT's code).

Run: ``.venv/bin/python -m bench iridescence_callgrind [--quick] [--repeat]`` (each OSL render is
~1.5 CPU-minutes under valgrind, mostly the JIT; the full run is ~25 CPU-minutes, two children at a time):
the whole breakdown on the default set, the energy question on all three sets.  Writes ``bench/out/iridescence_callgrind.md``.
"""
from __future__ import annotations

import os
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


#: Cycles' per-sample work on the CPU (path tracing of a tile, every kernel and shader it runs): its
#: inclusive Ir excludes scene building, sync and the OSL JIT, whose instruction counts vary by ~1e7
#: between identical renders.
SAMPLE_FN = "ccl::PathTraceWorkCPU::render_samples_full_pipeline"


def _inclusive_ir(path: Path, fn: str = SAMPLE_FN) -> int:
    """Inclusive Ir of the function ``fn`` in one callgrind dump (via ``callgrind_annotate``; 0 if absent)."""
    out = subprocess.run(["callgrind_annotate", "--inclusive=yes", "--threshold=100", str(path)],
                         capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        if fn + "(" in line:
            return int(line.split()[0].replace(",", ""))
    return 0


def _parts(prefix: str) -> list[int]:
    """Per-sample-work Ir (``SAMPLE_FN``) of each dump part callgrind wrote (files ``prefix.<k>``, in order)."""
    files = sorted(Path(prefix).parent.glob(Path(prefix).name + ".*"), key=lambda p: int(p.suffix[1:]))
    return [_inclusive_ir(f) for f in files if f.suffix[1:].isdigit()]


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


def write_report(results: dict, reps: int, load_note: str, extra_notes: str = "") -> str:
    """``bench/out/iridescence_callgrind.md`` from {set: {config: (N, [Ir per sample, one per repeat])}}."""
    from bench._util import report

    rows = []
    for s, r in results.items():
        mean = {c: sum(v) / len(v) for c, (_n, v) in r.items()}
        for c, (n, v) in r.items():
            rows.append([s, c, n + 1, f"{mean[c] / (RES[0] * RES[1]):.1f}",
                         f"{abs(v[0] - v[1]) / mean[c] * 100:.3f}" if len(v) > 1 else "",
                         f"{mean[c] / mean['base SVM']:.3f}" if "base SVM" in mean else "",
                         f"{mean[c] / mean['base OSL']:.3f}" if "base OSL" in mean else "",
                         f"{mean[c] / mean[PAPER]:.4f}" if PAPER in mean and c.startswith("layer A") else ""])
    notes = (f"Instructions (valgrind callgrind: Ir of Cycles' {SAMPLE_FN}, inclusive) per pixel-sample = "
             f"(Ir(render at N + 1 spp) − Ir(render at 1 spp)) / N / {RES[0] * RES[1]} pixels; the whole-frame sphere "
             f"scene of iridescence_cost at {RES[0]}x{RES[1]}, one render thread, the configs of a set rendered in one "
             f"valgrind process ({reps} repeat(s); with 2, 'repeat spread' = |difference| / mean).  × base SVM / × base "
             "OSL: instruction ratio to the SVM anisotropic Glossy / to the same base on OSL; × eq. 6: to the layer "
             f"with eq. 6's (1 − ρ) base weight (issue #17 item 5: energy weight / eq. 6 weight).  Load-independent; "
             f"{load_note}.  {extra_notes}")
    return report("iridescence_callgrind", ["set", "setup", "spp", "Ir / pixel-sample", "repeat spread %",
                                            "× base SVM (Ir)", "× base OSL (Ir)", "× eq. 6 weight (Ir)"], rows, notes)


def main(argv) -> int:
    if argv[:1] == ["--child"]:
        return _child(argv[1], int(argv[2]), int(argv[3]), argv[4:])
    if argv[:1] == ["--parse"]:        # --parse PREFIX N CONFIG...: per-sample Ir of a child's dump parts
        names = argv[3:]
        for c, v in per_sample(_parts(argv[1]), names, int(argv[2]), 1).items():
            print(f"{c}: {v[0] / (RES[0] * RES[1]):.1f} Ir per pixel-sample")
        return 0
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
    write_report({s: {c: (n, v) for c, v in results[s].items()} for s, _names in jobs}, reps,
                 f"machine load {load0[0]:.1f} / {load1[0]:.1f} (start / end) only affects wall time")
    shutil.rmtree(workdir, ignore_errors=True)
    return 0
