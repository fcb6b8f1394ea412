"""Cost of the scratch BRDF simulation vs profile size, and the error that polyline simplification adds
(Raymond et al. 2016, §4.1; issue #14).

Each case runs in a fresh subprocess (peak RSS = ``ru_maxrss`` of the whole process).  For each profile
and table resolution M the simulation runs with the polyline simplified so that no first-bounce exit
direction moves by more than ``bins * pi / M`` (``profiles.simplify``; "auto" = 0.25 bins) and without
simplification (the reference, ``max_exit_error=0``); the error is the relative L1 distance of the
simplified tables to the reference (``rho_m``; ``rho0`` with RGB Fresnel, channel-summed), and the largest
change of directional albedo ``sum_o C_o rho_m`` over phi_i.

Profiles: ``smooth-4096`` (a sin^2 groove, depth 0.3, 4,096 samples), ``measured-4096`` (the same plus
instrument-like noise, 16-sample-correlated, rms 5e-5 widths: the noise slopes (~0.01 rad) exceed the
tolerance, so it is kept -- it does scatter light), ``quartic-100k`` (the issue's 100,000 segments).

    python -m bench scratch_tracer_scale [--quick] [--res 256] [--bins 0.25 1 2]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap

from bench._util import ROOT, out_path, pyplot, report

_CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from scratch_materials.precompute.scratch import fresnel, profiles
from scratch_materials.precompute.scratch.brdf import bin_cos_integrals, simulate
name, M, tol = {name!r}, {M}, {tol!r}
rng = np.random.default_rng(7)
if name.startswith("quartic"):
    prof = profiles.quartic(0.3, segments=100000)
else:
    n = int(name.split("-")[1])
    x = np.linspace(0.0, 1.0, n)
    h = -0.3 * np.sin(np.pi * x) ** 2
    if name.startswith("measured"):
        h = h + np.convolve(rng.standard_normal(n + 15), np.ones(16) / 16, "valid") * 2e-4
    prof = profiles.tabulated(x, h)
fr = fresnel.conductor([0.2, 0.9, 1.1], [3.0, 2.5, 2.0])
t0 = time.perf_counter()
b = simulate(prof, M, fr, max_exit_error=tol, max_seconds=float("inf"))
wall = time.perf_counter() - t0
np.save({out!r}, np.stack([b.rho_m[..., 0], b.rho0.sum(-1)]))
print(json.dumps(dict(wall=wall, maxrss=(int(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:'))) * 1024 if sys.platform.startswith('linux') else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024),
                      segments=int(b.meta["segments"]), source=int(prof.segments))))
"""


def _case(name: str, M: int, tol, tmp: str) -> dict:
    import numpy as np

    out = os.path.join(tmp, f"{name}-{M}-{tol}.npy")
    code = textwrap.dedent(_CHILD).format(root=str(ROOT), name=name, M=M, tol=tol, out=out)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if r.returncode:
        return {"error": r.stderr.strip().splitlines()[-1]}
    d = json.loads(r.stdout.strip().splitlines()[-1])
    d["tables"] = np.load(out)
    return d


def main(argv=None) -> int:
    import tempfile

    import numpy as np

    from scratch_materials.precompute.scratch.brdf import bin_cos_integrals

    ap = argparse.ArgumentParser(prog="bench scratch_tracer_scale")
    ap.add_argument("--quick", action="store_true", help="M = 32, smooth profile only (< 30 s)")
    ap.add_argument("--res", type=int, nargs="+", default=[256])
    ap.add_argument("--bins", type=float, nargs="+", default=[0.25, 1.0, 2.0])
    ap.add_argument("--profiles", nargs="+", default=["smooth-4096", "measured-4096", "quartic-100k"])
    ap.add_argument("--tag", default="", help="suffix of the output names (bench/out/scratch_tracer_scale<tag>.md)")
    ap.add_argument("--no-reference", action="store_true", help="skip the unsimplified reference runs")
    a = ap.parse_args(argv)
    if a.quick:
        a.res, a.profiles, a.bins = [32], ["smooth-4096"], [0.25, 1.0]
    load = os.getloadavg()[0]
    rows, plot = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for M in a.res:
            C = bin_cos_integrals(M)
            for name in a.profiles:
                ref = None if a.no_reference else _case(name, M, 0.0, tmp)
                if ref is not None and "error" not in ref:
                    rows.append([name, M, "off", ref["source"], ref["segments"], f"{ref['wall']:.2f}",
                                 f"{ref['maxrss'] / 2**20:.0f}", "0", "0", "0"])
                elif ref is not None:
                    rows.append([name, M, "off", "", "", "", "", ref["error"][:80], "", ""])
                    ref = None
                for bins in a.bins:
                    r = _case(name, M, bins * np.pi / M, tmp)
                    if "error" in r:
                        rows.append([name, M, bins, "", "", "", "", r["error"][:80], "", ""])
                        continue
                    e_m = e_0 = e_alb = float("nan")
                    if ref is not None:
                        A, B = r["tables"].astype(np.float64), ref["tables"].astype(np.float64)
                        e_m = np.abs(A[0] - B[0]).sum() / np.abs(B[0]).sum()
                        e_0 = np.abs(A[1] - B[1]).sum() / np.abs(B[1]).sum()
                        e_alb = float(np.max(np.abs(C @ A[0] - C @ B[0])))
                        plot.append((name, M, bins, r["wall"], e_m))
                    rows.append([name, M, bins, r["source"], r["segments"], f"{r['wall']:.2f}",
                                 f"{r['maxrss'] / 2**20:.0f}", f"{e_m:.2e}", f"{e_0:.2e}", f"{e_alb:.1e}"])
                    print(rows[-1], flush=True)
    notes = (f"One run per case (fresh subprocess, workers = default), machine load average {load:.1f} at the start "
             "(2 cores shared with other jobs: wall times are noisy, compare within a column). RGB conductor "
             "Fresnel (3 channels), default supersampling. 'bins' = max first-bounce exit-direction change in "
             "table bins (pi / M); 'auto' in simulate() is 0.25 bins for profiles of > 512 segments. Errors vs "
             "the unsimplified run of the same profile: relative L1 of rho_m and of rho0 (channels summed), "
             "largest |change| of the directional albedo.")
    report("scratch_tracer_scale" + a.tag, ["profile", "M", "bins", "points", "traced segments", "wall s", "peak MiB",
                             "rel L1 rho_m", "rel L1 rho0", "max d albedo"], rows, notes)
    if plot:
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for name in sorted({p[0] for p in plot}):
            pts = [(p[3], p[4], p[2]) for p in plot if p[0] == name]
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=name)
            for w, e, bins in pts:
                ax.annotate(f"{bins:g}", (w, e), fontsize=7)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("rel. L1 error of rho_m vs unsimplified")
        ax.set_yscale("log")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out_path(f"scratch_tracer_scale{a.tag}.png"), dpi=120)
    return 0
