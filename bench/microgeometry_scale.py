"""Time and peak memory of the height-field NDFs vs scan size (Dong et al. 2015, §5.1 and App. A; issue #14).

Filtered NDF (sigma = 1 µm, pixel 0.5 µm, 1025^2 table) and Kirchhoff NDF (70 µm patches, lambda 0.555 µm)
of seeded Gaussian surfaces, each in a fresh subprocess (peak = ``ru_maxrss`` of the whole process, Python
and numpy included), for this tree and a baseline tree (``--baseline DIR``: a checkout of the code before
streaming, e.g. ``git archive main | tar -x -C DIR``), run interleaved (A/B/A/B...) and the median of
``--repeats`` kept.  The baseline is skipped where it would need several GiB (``--baseline-max``).

    python -m bench microgeometry_scale [--quick] [--baseline DIR] [--repeats 3]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import textwrap

from bench._util import ROOT, out_path, pyplot, report

_CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from scratch_materials.precompute.microgeometry import heightfield, ndf
n = {n}
hf = heightfield.gaussian_surface((n, n), 0.5, 0.2, 3.0, seed=1)
h = np.array(hf.heights)
t0 = time.perf_counter()
c0 = time.process_time()
if {what!r} == "filtered":
    T = ndf.filtered_ndf(h, 0.5, sigma_um=1.0)
else:
    T = ndf.kirchhoff_ndf(h, 0.5, wavelength_um=0.555, patch_um=70.0, resolution=257)
wall = time.perf_counter() - t0
cpu = time.process_time() - c0
np.save({out!r}, np.asarray(T.table, np.float64))
print(json.dumps(dict(wall=wall, cpu=cpu, maxrss=(int(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:'))) * 1024 if sys.platform.startswith('linux') else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024))))
"""


_FFT = """
import json, sys, time
import numpy as np
from scipy import fft as sfft
h = np.random.default_rng(1).standard_normal((4096, 4096)).astype(np.float32)
sfft.rfft2(h[:64, :64])
w, c = [], []
for _ in range(3):
    t0, c0 = time.perf_counter(), time.process_time()
    sfft.rfft2(h)
    w.append(time.perf_counter() - t0)
    c.append(time.process_time() - c0)
print(json.dumps(dict(wall=min(w), cpu=min(c))))
"""


def _run(root, what, n, out):
    code = textwrap.dedent(_CHILD).format(root=str(root), n=n, what=what, out=out)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if r.returncode:
        return None
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    import tempfile

    import numpy as np

    ap = argparse.ArgumentParser(prog="bench microgeometry_scale")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--baseline", default=None, help="directory of the baseline tree (optional)")
    ap.add_argument("--baseline-max", type=int, default=2048, help="largest side run on the baseline")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--filtered", type=int, nargs="*", default=[512, 1024, 2048, 4096])
    ap.add_argument("--kirchhoff", type=int, nargs="*", default=[256, 512, 1024])
    a = ap.parse_args(argv)
    if a.quick:
        a.filtered, a.kirchhoff, a.repeats = [256, 512], [128], 1
    load = os.getloadavg()[0]
    fft = json.loads(subprocess.run([sys.executable, "-c", _FFT], capture_output=True, text=True,
                                    check=True).stdout.strip().splitlines()[-1])
    print("bare rfft2 4096^2 float32:", fft, flush=True)
    rows, pts = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for what, sizes in (("filtered", a.filtered), ("kirchhoff", a.kirchhoff)):
            for n in sizes:
                new, old = [], []
                use_base = a.baseline is not None and n <= a.baseline_max
                for k in range(a.repeats):  # interleaved A/B
                    new.append(_run(ROOT, what, n, os.path.join(tmp, "new.npy")))
                    if use_base:
                        old.append(_run(a.baseline, what, n, os.path.join(tmp, "old.npy")))
                new = [r for r in new if r]
                old = [r for r in old if r]
                err = float("nan")
                if old:
                    A, B = np.load(os.path.join(tmp, "new.npy")), np.load(os.path.join(tmp, "old.npy"))
                    err = float(np.abs(A - B).sum() / max(np.abs(B).sum(), 1e-300))
                med = lambda rs, key: statistics.median(r[key] for r in rs) if rs else float("nan")  # noqa: E731
                tn, cn, to, co = med(new, "wall"), med(new, "cpu"), med(old, "wall"), med(old, "cpu")
                mn = max(r["maxrss"] for r in new) / 2**20 if new else float("nan")
                mo = max(r["maxrss"] for r in old) / 2**20 if old else float("nan")
                b = bool(old)
                rows.append([what, f"{n}^2", f"{tn:.2f}", f"{cn:.2f}", f"{mn:.0f}",
                             f"{to:.2f}" if b else "-", f"{co:.2f}" if b else "-", f"{mo:.0f}" if b else "-",
                             f"{to / tn:.2f}" if b else "-", f"{co / cn:.2f}" if b else "-",
                             f"{err:.1e}" if b else "-"])
                pts.append((what, n, tn, mn, cn))
                print(rows[-1], flush=True)
    load_end = os.getloadavg()[0]
    notes = (f"Median of {a.repeats} runs, fresh subprocess each, new/baseline interleaved; load average {load:.1f} "
             f"at the start and {load_end:.1f} at the end on the 2-core machine shared with other jobs: wall times "
             "are inflated and noisy (a process gets a fraction of a core), so compare the CPU columns "
             "(process CPU time of the call, all threads, user + system) and the ratios. The CPU time is about "
             "the wall time of one dedicated core (contention on the loaded machine inflates it, so it is an "
             "upper estimate; two idle cores share the tiles). Peak = max VmHWM over the runs "
             "(whole process, test surface included). 'rel L1' = table difference new vs baseline. Baseline "
             f"skipped above {a.baseline_max}^2. For scale: a bare scipy rfft2 of one 4096^2 float32 array takes "
             f"{fft['cpu']:.3f} s CPU ({fft['wall']:.3f} s wall) in the same run.")
    report("microgeometry_scale", ["NDF", "scan", "new s", "new CPU s", "new peak MiB", "baseline s",
                                   "baseline CPU s", "baseline peak MiB", "speed-up wall", "speed-up CPU",
                                   "rel L1 vs baseline"], rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(8, 3.2))
    for what in ("filtered", "kirchhoff"):
        p = [q for q in pts if q[0] == what]
        if not p:
            continue
        ax[0].loglog([q[1] ** 2 for q in p], [q[2] for q in p], "o-", label=f"{what} wall")
        ax[0].loglog([q[1] ** 2 for q in p], [q[4] for q in p], "s--", label=f"{what} CPU")
        ax[1].loglog([q[1] ** 2 for q in p], [q[3] for q in p], "o-", label=what)
    ax[0].set_xlabel("points"), ax[0].set_ylabel("s"), ax[1].set_xlabel("points"), ax[1].set_ylabel("peak MiB")
    ax[0].set_title(f"load {load:.0f}-{load_end:.0f}, 2 cores", fontsize=8)
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_path("microgeometry_scale.png"), dpi=120)
    return 0
