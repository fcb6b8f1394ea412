"""Cost of the scratch BRDF simulation vs profile size, A/B against an earlier tracer, and the error that
polyline simplification adds (Raymond et al. 2016, §4.1; issue #14).

Each run is a fresh subprocess (peak = VmHWM of the whole process: Python, numpy and scipy included;
wall time and the process's CPU time of ``simulate``).  With ``--baseline-rev REV`` the same case also runs
on the repository at git revision REV (exported with ``git archive`` to a temporary folder), interleaved
A/B/A/B (``--reps`` pairs): the table gives the medians and the ratio, and the error of this tree's tables
against the baseline's (relative L1 of ``rho_m`` and of ``rho0``, channels summed: float rounding and
summation order only, if the tracers agree).  ``est s`` is ``brdf.estimate_cost`` (the up-front estimate
``simulate`` checks against ``max_seconds``).  With ``--reference`` the unsimplified run of each profile is
the reference of the simplification error (``rel L1 simpl``).

Profiles: ``smooth-4096`` (a sin^2 groove, depth 0.3, 4,096 samples), ``measured-4096`` (the same plus
instrument-like noise, a 16-sample box filter of white noise, rms 5e-5 widths: its segment slopes are
(nearly) independent, rms ~0.07 rad, ~6 bins at M = 256, far above the tolerance, so simplification keeps it
-- it does scatter light: simplifying it to 1 / 2 / 4 bins adds 7 / 15 / 25 % rel. L1 to rho_m at M = 256), ``quartic-100k`` (the issue's 100,000
segments).  Tolerance ``bins``: no first-bounce exit direction moves by more than ``bins * pi / M``
(``profiles.simplify``; ``simulate``'s "auto" is 0.25 bins).

    python -m bench scratch_tracer_scale [--quick] [--res 256] [--bins 0.25 1] [--baseline-rev REV] [--reps 2]

``--fast``: the fast method (``simulate(method="fast")``) against the exact one (its oracle), interleaved
exact/fast/exact/fast, on ``smooth-4096``, ``measured-4096``, ``quartic-100k`` and ``vgroove`` (45 degrees, where
the fast method is the exact one): time, the stride it chose and its error estimate, and the error it adds:
relative L1 and relative max of rho_m and rho0 (channels summed), and the moments of each phi_i column
(cosine-weighted mean and standard deviation of phi_o, largest difference over the columns, degrees).

    python -m bench scratch_tracer_scale --fast [--res 256] [--reps 2] [--max-table-error 0.05] [--baseline-rev REV]

With ``--baseline-rev`` the fast method of revision REV runs too, interleaved exact / fast (REV) / fast: its CPU and
wall medians, and the ratio of its CPU time to this tree's.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap

from bench._util import ROOT, out_path, pyplot, report

_CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
import numpy as np
from scratch_materials.precompute.scratch import fresnel, profiles
from scratch_materials.precompute.scratch import brdf
name, M, tol, method, mte = {name!r}, {M}, {tol!r}, {method!r}, {mte!r}
rng = np.random.default_rng(7)
if name == "vgroove":
    prof = profiles.v_groove(45.0)
elif name.startswith("quartic"):
    prof = profiles.quartic(0.3, segments=100000)
else:
    n = int(name.split("-")[1])
    x = np.linspace(0.0, 1.0, n)
    h = -0.3 * np.sin(np.pi * x) ** 2
    if name.startswith("measured"):
        h = h + np.convolve(rng.standard_normal(n + 15), np.ones(16) / 16, "valid") * 2e-4
    prof = profiles.tabulated(x, h)
fr = fresnel.conductor([0.2, 0.9, 1.1], [3.0, 2.5, 2.0])
kw = dict(method=method, max_table_error=mte) if method == "fast" else {{}}
est = brdf.estimate_cost(prof, M, fr, max_exit_error=tol, **kw).seconds
t0, c0 = time.perf_counter(), time.process_time()
b = brdf.simulate(prof, M, fr, max_exit_error=tol, max_seconds=float("inf"), **kw)
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
np.save({out!r}, np.stack([b.rho_m[..., 0], b.rho0.sum(-1)]))
print(json.dumps(dict(wall=wall, cpu=cpu, est=est, maxrss=(int(next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM:'))) * 1024 if sys.platform.startswith('linux') else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024),
                      segments=int(b.meta["segments"]), source=int(prof.segments), fast=b.meta.get("fast"))))
"""


def _case(root: str, name: str, M: int, tol, tmp: str, tag: str, method: str = "exact", mte: float = 0.05) -> dict:
    import numpy as np

    out = os.path.join(tmp, f"{tag}-{name}-{M}-{tol}-{method}.npy")
    code = textwrap.dedent(_CHILD).format(root=str(root), name=name, M=M, tol=tol, out=out, method=method, mte=mte)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if r.returncode:
        return {"error": r.stderr.strip().splitlines()[-1]}
    d = json.loads(r.stdout.strip().splitlines()[-1])
    d["tables"] = np.load(out)
    return d


def _rel_l1(a, b) -> tuple[float, float]:
    import numpy as np

    A, B = a.astype(np.float64), b.astype(np.float64)
    return (float(np.abs(A[0] - B[0]).sum() / np.abs(B[0]).sum()), float(np.abs(A[1] - B[1]).sum() / np.abs(B[1]).sum()))


def _moments(t):
    """Cosine-weighted mean and standard deviation of phi_o (degrees) of every phi_i column of ``t`` [M, M]."""
    import numpy as np

    M = t.shape[0]
    e = -0.5 * np.pi + np.arange(M + 1) * (np.pi / M)
    c, C = 0.5 * (e[1:] + e[:-1]), np.diff(np.sin(e))
    w = t.astype(np.float64) * C[:, None]
    tot = np.maximum(w.sum(0), 1e-300)
    mean = (w * c[:, None]).sum(0) / tot
    var = (w * (c[:, None] - mean) ** 2).sum(0) / tot
    return np.degrees(mean), np.degrees(np.sqrt(np.maximum(var, 0.0))), w.sum(0)


def _fast_errors(a, b) -> dict:
    """Error of tables ``a`` against the reference ``b`` ([2, M, M]: rho_m, rho0 channels summed)."""
    import numpy as np

    out = {}
    for k, key in enumerate(("m", "0")):
        A, B = a[k].astype(np.float64), b[k].astype(np.float64)
        out["l1" + key] = float(np.abs(A - B).sum() / np.abs(B).sum())
        out["max" + key] = float(np.abs(A - B).max() / np.abs(B).max())
    ma, sa, wa = _moments(a[0])
    mb, sb, wb = _moments(b[0])
    lit = wb > 1e-3 * wb.max()
    out["dmean"] = float(np.max(np.abs(ma - mb)[lit], initial=0.0))
    out["dstd"] = float(np.max(np.abs(sa - sb)[lit], initial=0.0))
    return out


def _fast_figure(tables: dict, name: str, M: int, stride) -> None:
    """rho_m of the exact and the fast table and their difference (bench/out/scratch_tracer_fast_<M>.png)."""
    import numpy as np

    plt = pyplot()
    ex, fa = tables["exact"][0].astype(np.float64), tables["fast"][0].astype(np.float64)
    fig, axs = plt.subplots(1, 3, figsize=(10, 3.4))
    vmax = np.percentile(ex, 99.5)
    ext = [-90, 90, -90, 90]
    for ax, t, title in ((axs[0], ex, "exact"), (axs[1], fa, f"fast (stride {stride})")):
        im = ax.imshow(t, origin="lower", extent=ext, vmin=0, vmax=vmax, cmap="magma")
        ax.set_title(f"{name} rho_m, {title}", fontsize=8)
        ax.set_xlabel("phi_i (deg)", fontsize=7)
        ax.set_ylabel("phi_o (deg)", fontsize=7)
        fig.colorbar(im, ax=ax, fraction=0.046)
    im = axs[2].imshow(fa - ex, origin="lower", extent=ext, cmap="RdBu_r", vmin=-0.2 * vmax, vmax=0.2 * vmax)
    axs[2].set_title(f"fast - exact (rel L1 {np.abs(fa - ex).sum() / np.abs(ex).sum():.3f})", fontsize=8)
    axs[2].set_xlabel("phi_i (deg)", fontsize=7)
    fig.colorbar(im, ax=axs[2], fraction=0.046)
    fig.tight_layout()
    fig.savefig(out_path(f"scratch_tracer_fast_{M}.png"), dpi=110)


def _baseline_tree(a, tmp: str) -> str | None:
    """The tree to A/B against: ``--baseline-dir``, or ``--baseline-rev`` extracted under ``tmp``, or None."""
    if a.baseline_dir or not a.baseline_rev:
        return a.baseline_dir
    base = os.path.join(tmp, "baseline")
    os.makedirs(base)
    arc = subprocess.run(["git", "-C", str(ROOT), "archive", a.baseline_rev], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", base], input=arc.stdout, check=True)
    return base


def _fast_main(a) -> int:
    import numpy as np

    load0 = os.getloadavg()
    rows = []
    names = a.profiles if a.profiles_given else ["measured-4096", "smooth-4096", "quartic-100k", "vgroove"]
    with tempfile.TemporaryDirectory() as tmp:
        base = _baseline_tree(a, tmp)
        for M in a.res:
            for name in names:
                ex, fa, fb = [], [], []
                for _ in range(max(1, a.reps)):  # interleaved: all see the same machine load
                    ex.append(_case(ROOT, name, M, "auto", tmp, "exact"))
                    if base is not None:
                        fb.append(_case(base, name, M, "auto", tmp, "base", "fast", a.max_table_error))
                    fa.append(_case(ROOT, name, M, "auto", tmp, "fast", "fast", a.max_table_error))
                bad = [r for r in ex + fa + fb if "error" in r]
                if bad:
                    rows.append([name, M] + [""] * 17 + [bad[0]["error"][:80]])
                    continue
                med = lambda rs, k: statistics.median(x[k] for x in rs)  # noqa: E731
                f = fa[-1]
                err = _fast_errors(f["tables"], ex[-1]["tables"])
                info = f["fast"] or {}
                if name == "measured-4096":
                    _fast_figure({"exact": ex[-1]["tables"], "fast": f["tables"]}, name, M, info.get("stride"))
                rows.append([name, M, f["segments"], f"{med(ex, 'wall'):.2f}", f"{med(ex, 'cpu'):.2f}",
                             f"{ex[-1]['est']:.1f}", f"{med(fa, 'wall'):.2f}", f"{med(fa, 'cpu'):.2f}",
                             f"{f['est']:.1f}", f"{max(x['maxrss'] for x in fa) / 2**20:.0f}",
                             f"{med(ex, 'cpu') / med(fa, 'cpu'):.1f}", info.get("stride", ""),
                             f"{info.get('table_error_estimate', float('nan')):.4f}",
                             f"{err['l1m']:.4f} / {err['l10']:.4f}", f"{err['maxm']:.3f} / {err['max0']:.3f}",
                             f"{err['dmean']:.3f} / {err['dstd']:.3f}"]
                            + ([f"{med(fb, 'wall'):.2f}", f"{med(fb, 'cpu'):.2f}", f"{med(fb, 'cpu') / med(fa, 'cpu'):.2f}"]
                               if fb else ["", "", ""]) + [""])
                print(rows[-1], flush=True)
    load1 = os.getloadavg()
    notes = (f"Medians of {a.reps} run(s) per method, each a fresh subprocess (2 threads), exact and fast interleaved. "
             f"Machine load average (1/5/15 min) {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at the start, "
             f"{load1[0]:.1f}/{load1[1]:.1f}/{load1[2]:.1f} at the end (2 cores shared with other jobs: wall times "
             "follow the load, CPU times much less). RGB conductor Fresnel (3 channels), simplification 'auto'. "
             f"fast: simulate(method='fast', max_table_error={a.max_table_error:g}); 'stride' = phi_i bins per traced "
             "sub-bin (0 = exact); 'estimate' = its a-posteriori error estimate (rel. L1 of rho_m against the same "
             "traces at half the directions). Errors of the fast tables against "
             "the exact ones: relative L1 and relative max (|diff| max / ref max) of rho_m / rho0 (channels summed); "
             "moments = largest difference over the lit phi_i columns of the cosine-weighted mean / standard "
             "deviation of phi_o (degrees). 'est s' = brdf.estimate_cost."
             + (f" 'base fast': the fast method of revision {a.baseline_rev}, interleaved (exact / base fast / fast); "
                "'fast speed-up' = its CPU time / this tree's." if a.baseline_rev else ""))
    report("scratch_tracer_fast" + (a.tag if a.tag is not None else "_" + "_".join(str(m) for m in a.res)),
           ["profile", "M", "traced segments", "exact wall s", "exact CPU s", "exact est s", "fast wall s",
            "fast CPU s", "fast est s", "fast peak MiB", "CPU speed-up", "stride", "estimate",
            "rel L1 rho_m / rho0", "rel max rho_m / rho0", "moments dmean / dstd (deg)", "base fast wall s",
            "base fast CPU s", "fast speed-up", "note"], rows, notes)
    return 0


def main(argv=None) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(prog="bench scratch_tracer_scale")
    ap.add_argument("--quick", action="store_true", help="M = 32, smooth profile only (< 30 s)")
    ap.add_argument("--res", type=int, nargs="+", default=[256])
    ap.add_argument("--bins", type=float, nargs="+", default=[0.25, 1.0])
    ap.add_argument("--profiles", nargs="+", default=["smooth-4096", "measured-4096", "quartic-100k"])
    ap.add_argument("--baseline-rev", default=None, help="git revision to A/B against (e.g. the previous tracer)")
    ap.add_argument("--baseline-dir", default=None, help="or: a folder holding that revision's tree")
    ap.add_argument("--reps", type=int, default=2, help="A/B pairs per case (medians are reported)")
    ap.add_argument("--reference", action="store_true", help="also run unsimplified (simplification error)")
    ap.add_argument("--tag", default=None, help="suffix of the output names (default _<res>)")
    ap.add_argument("--fast", action="store_true", help="the fast method against the exact one (time and error)")
    ap.add_argument("--max-table-error", type=float, default=0.05)
    a = ap.parse_args(argv)
    a.profiles_given = argv is not None and "--profiles" in argv or "--profiles" in sys.argv
    if a.fast:
        return _fast_main(a)
    if a.quick:
        a.res, a.profiles, a.bins = [32], ["smooth-4096"], [0.25, 1.0]
    tag = a.tag if a.tag is not None else "_" + "_".join(str(m) for m in a.res)
    load0 = os.getloadavg()
    rows, plot = [], []
    with tempfile.TemporaryDirectory() as tmp:
        base = _baseline_tree(a, tmp)
        for M in a.res:
            for name in a.profiles:
                ref = _case(ROOT, name, M, 0.0, tmp, "ref") if a.reference else None
                if ref is not None and "error" in ref:
                    rows.append([name, M, "off", "", "", "", "", "", "", "", "", "", "", ref["error"][:80]])
                    ref = None
                for bins in a.bins:
                    tol = bins * np.pi / M
                    runs, bruns = [], []
                    for _ in range(max(1, a.reps)):  # interleaved A/B: both see the same machine load
                        if base is not None:
                            bruns.append(_case(base, name, M, tol, tmp, "base"))
                        runs.append(_case(ROOT, name, M, tol, tmp, "new"))
                    if any("error" in r for r in runs):
                        err = next(r for r in runs if "error" in r)["error"]
                        rows.append([name, M, bins, "", "", "", "", "", "", "", "", "", "", err[:80]])
                        continue
                    r = runs[-1]
                    med = lambda rs, k: statistics.median(x[k] for x in rs)  # noqa: E731
                    wall, cpu, peak = med(runs, "wall"), med(runs, "cpu"), max(x["maxrss"] for x in runs) / 2**20
                    bw = bc = ratio = e_bm = e_b0 = float("nan")
                    bruns = [x for x in bruns if "error" not in x]
                    if bruns:
                        bw, bc = med(bruns, "wall"), med(bruns, "cpu")
                        ratio = bw / wall
                        e_bm, e_b0 = _rel_l1(r["tables"], bruns[-1]["tables"])
                    e_sm = float("nan")
                    if ref is not None:
                        e_sm = _rel_l1(r["tables"], ref["tables"])[0]
                        plot.append((name, M, bins, wall, e_sm))
                    rows.append([name, M, bins, r["source"], r["segments"], f"{r['est']:.1f}", f"{wall:.2f}",
                                 f"{cpu:.2f}", f"{peak:.0f}", f"{bw:.2f}", f"{bc:.2f}", f"{ratio:.2f}",
                                 f"{e_bm:.1e} / {e_b0:.1e}", f"{e_sm:.2e}"])
                    print(rows[-1], flush=True)
    load1 = os.getloadavg()
    notes = (f"Medians of {a.reps} run(s) per case, each a fresh subprocess (workers = default, 2 threads), "
             + (f"A/B interleaved with the tracer of revision {a.baseline_rev} ('base'). " if a.baseline_rev else "")
             + f"Machine load average (1/5/15 min) {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at the start, "
             f"{load1[0]:.1f}/{load1[1]:.1f}/{load1[2]:.1f} at the end (2 cores shared with other jobs: compare within "
             "a row). RGB conductor Fresnel (3 channels), default supersampling. 'bins' = max first-bounce exit-"
             "direction change in table bins (pi / M); 'auto' in simulate() is 0.25 bins for profiles of > 512 "
             "segments. 'est s' = brdf.estimate_cost (reference-machine wall seconds). 'vs base' = relative L1 "
             "of rho_m / rho0 against the baseline's tables; 'rel L1 simpl' = rho_m against the unsimplified run "
             "(--reference).")
    report("scratch_tracer_scale" + tag, ["profile", "M", "bins", "points", "traced segments", "est s", "wall s",
                                          "CPU s", "peak MiB", "base wall s", "base CPU s", "speed-up",
                                          "vs base (rho_m / rho0)", "rel L1 simpl"], rows, notes)
    timed = [r for r in rows if r[9] not in ("", "nan")]
    if timed:  # wall time, this tree vs the baseline, per case
        plt = pyplot()
        fig, ax = plt.subplots(figsize=(6, 3.5))
        xs = np.arange(len(timed))
        ax.bar(xs - 0.2, [float(r[9]) for r in timed], 0.4, label=f"base ({a.baseline_rev})")
        ax.bar(xs + 0.2, [float(r[6]) for r in timed], 0.4, label="this tree")
        ax.set_xticks(xs, [f"{r[0]}\nM={r[1]} {r[2]}b" for r in timed], fontsize=6)
        ax.set_ylabel("wall time (s, median)")
        ax.set_yscale("log")
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out_path(f"scratch_tracer_scale{tag}_ab.png"), dpi=120)
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
        fig.savefig(out_path(f"scratch_tracer_scale{tag}.png"), dpi=120)
    return 0
