"""Run time vs error of the single-scratch BRDF precompute (Raymond et al. 2016, §4.1-4.2, §6.1).

Methods: exact beam tracing (``method="exact"``, ``supersample`` K = 1, 2, 3, 4, 8; default
``default_supersample(M)``) and Monte Carlo
(``method="mc"``, rays per phi_i slice).  Error: relative L1 of ``rho_m`` against a converged
reference at the same resolution (exact, K = 32), both plain (sum |d| / sum ref over table
entries) and energy-weighted (entries weighted by C_o C_i: the fraction of misplaced light), and
the reciprocity residual ``sum |rho - rho^T| / sum rho`` of each table.
Times: median of 5 runs (exact; with the default 2 threads and with 1, interleaved) / 1 run (MC, slow),
full product (RGB iron Fresnel, 3 slices).

    python -m bench scratch_brdf [--quick]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from bench._util import out_path, pyplot, report, time_median
from scratch_materials.precompute.scratch import fresnel, profiles
from scratch_materials.precompute.scratch.brdf import bin_cos_integrals, default_supersample, simulate


def errors(rho, ref):
    C = bin_cos_integrals(ref.shape[0])
    w = C[:, None] * C[None, :]
    rho = rho[..., 0] if rho.ndim == 3 else rho  # rho_m is the same in every channel
    d = np.abs(rho.astype(np.float64) - ref)
    return d.sum() / np.abs(ref).sum(), (d * w).sum() / (np.abs(ref) * w).sum()


def recip(rho):
    rho = (rho[..., 0] if rho.ndim == 3 else rho).astype(np.float64)
    return np.abs(rho - rho.T).sum() / np.abs(rho).sum()


def main(argv) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench scratch_brdf")
    ap.add_argument("--quick", action="store_true", help="small smoke run (< 30 s)")
    ap.add_argument("--depth", type=float, default=0.5, help="quartic depth/width ratio (default: steep 0.5)")
    ap.add_argument("--segments", type=int, default=256)
    args = ap.parse_args(argv)
    prof = profiles.quartic(args.depth, segments=args.segments)
    f = fresnel.conductor_preset("iron")
    if args.quick:
        res, ks, mc = [64, 128], [1, 2], {64: [1000]}
        ref_k, repeats = 8, 3
    else:
        res, ks = [64, 128, 256, 512], [1, 2, 3, 4, 8]
        mc = {64: [1000, 4000, 16000], 128: [1000, 4000], 256: [1000, 4000], 512: [1000]}
        ref_k, repeats = 64, 5
    rows, pts = [], []
    for M in res:
        t0 = time.perf_counter()
        ref = simulate(prof, M, supersample=ref_k).rho_m.astype(np.float64)
        print(f"M={M}: reference (exact, K={ref_k}) in {time.perf_counter() - t0:.1f} s", flush=True)
        for K in sorted(set(ks) | {default_supersample(M)}):
            t2, t1 = [], []
            simulate(prof, M, f, supersample=K)  # warm-up
            for _ in range(repeats):  # interleaved: the ratio is measured in one run
                t2.append(time_median(lambda: simulate(prof, M, f, supersample=K), repeats=1, warmup=0)[0])
                t, b = time_median(lambda: simulate(prof, M, f, supersample=K, workers=1), repeats=1, warmup=0)
                t1.append(t)
            t, t1 = float(np.median(t2)), float(np.median(t1))
            e, ew = errors(b.rho_m, ref)
            name = f"exact K={K}" + (" (default)" if K == default_supersample(M) else "")
            rows.append([M, name, t * 1e3, t1 * 1e3, 100 * e, 100 * ew, 100 * recip(b.rho_m), f"{b.lost:.1e}"])
            pts.append(("exact", K, M, t, e))
            print(rows[-1], flush=True)
        for n in mc.get(M, []):
            t, b = time_median(lambda: simulate(prof, M, f, method="mc", rays_per_slice=n), repeats=1, warmup=0)
            e, ew = errors(b.rho_m, ref)
            rows.append([M, f"mc {n} rays/slice", t * 1e3, "-", 100 * e, 100 * ew, 100 * recip(b.rho_m), "-"])
            pts.append(("mc", n, M, t, e))
            print(rows[-1], flush=True)
    notes = (f"Profile: quartic depth/width {args.depth}, {prof.segments} segments; Fresnel: iron (RGB, exact conductor); "
             f"reference: exact K={ref_k}. Machine: {os.cpu_count()} cores (shared). Target: 256x256, <= 0.5 % rel. L1, <= 300 ms. "
             "Default of simulate(): supersample = default_supersample(M) = max(2, ceil(768 / M)) -> K=12/6/3/2 "
             "at M=64/128/256/512; 'time ms' uses the default 2 threads, 'time ms 1 thread' one (interleaved runs).")
    report("scratch_brdf", ["M", "method", "time ms", "time ms 1 thread", "rel L1 %", "energy-weighted rel L1 %",
                            "reciprocity %", "lost"], rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    for M, mk in zip(res, "osD^"):
        for kind, col in (("exact", "C0"), ("mc", "C3")):
            p = [(t, e) for k, _, m, t, e in pts if k == kind and m == M]
            if p:
                t, e = zip(*p)
                ax.loglog(np.array(t) * 1e3, np.array(e) * 100, mk + "-", color=col, label=f"{kind} M={M}")
    ax.axhline(0.5, color="gray", ls=":")
    ax.axvline(300, color="gray", ls=":")
    ax.set_xlabel("time (ms, 2 cores)")
    ax.set_ylabel("rel. L1 error of rho_m (%)")
    ax.set_title("single-scratch BRDF precompute: time vs error")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out_path("scratch_brdf.png"), dpi=120)
    print("wrote", out_path("scratch_brdf.png"))
    return 0
