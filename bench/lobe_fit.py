"""Benchmark: number of tilted Cycles lobes K vs fit error vs fit time (issue #4, lobe fitting).

For each profile (quartic 0.1/0.3/1.0 with 4096 segments, V-grooves 45/20 deg, circular 0.5,
a measured-like tabulated profile) and each table (rho_m; rho0 with iron Fresnel: channel mean,
and per channel R/G/B at K = 8), fit the S = 128 shader slices (rows of the M = 256 table at
phi_o = -pi/2 + (s + 1/2) pi/S, ``lobe_fit.rows_at``) with ``lobe_fit.fit_table(..., phi_o=...)``
and report the per-slice relative L1 error (median, p95, max), mean lobes used and fit time, for
``dists="auto"`` (Beckmann + GGX) and ``"ggx"`` (the previous GGX-only model).
``--jitter off|on|both``: plain lobes, tilt-jittered "box" lobes (``fit_table(..., jitter=True)``) or
both (column ``jitter``; ``box_frac`` = fraction of the used lobes with a jitter).
``--profiles``: only these profile names.
``--quick``: M = 64, S = 32, K in {1, 4, 8}, two profiles, "auto" only.
Rows with dists = "table": tabulated-tilt lobes (``precompute.scratch.lobe_table``), for comparison (``--no-table``: skip).
"""
from __future__ import annotations

import time

import numpy as np

from bench._util import out_path, pyplot, report


def measured_like(seed: int = 3, sigma: float = 8.0, amp: float = 0.004):
    """x in [0, 1] (257 samples), h = -0.25 sin^2(pi x) + amp * (Gaussian-smoothed unit noise, sigma samples)."""
    from scratch_materials.precompute.scratch import profiles

    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, 257)
    k = np.exp(-0.5 * (np.arange(-32, 33) / sigma) ** 2)
    n = np.convolve(rng.normal(size=257 + 64), k / k.sum(), mode="same")[32:-32]
    return profiles.tabulated(x, -0.25 * np.sin(np.pi * x) ** 2 + amp * n / n.std(), name="measured_like")


def _profiles(quick: bool, seg: int):
    from scratch_materials.precompute.scratch import profiles

    out = [("quartic_0.1", profiles.quartic(0.1, segments=seg)), ("vgroove_45", profiles.v_groove(45.0))]
    if not quick:
        out += [("quartic_0.3", profiles.quartic(0.3, segments=seg)), ("quartic_1.0", profiles.quartic(1.0, segments=seg)),
                ("vgroove_20", profiles.v_groove(20.0)), ("circular_0.5", profiles.circular(0.5, segments=seg)),
                ("measured_like", measured_like())]
    return out


def main(argv) -> int:
    from scratch_materials.precompute.scratch import fresnel, lobe_fit, lobe_table, brdf as scratch_brdf

    import argparse

    ap = argparse.ArgumentParser(prog="python -m bench lobe_fit")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--ks", type=int, nargs="+", default=None, help="lobe budgets K to sweep")
    ap.add_argument("--dists", nargs="+", default=None, help="auto / ggx / beckmann")
    ap.add_argument("--segments", type=int, default=None, help="polyline segments of the analytic profiles")
    ap.add_argument("--supersample", type=int, default=None, help="scratch_brdf.simulate supersample")
    ap.add_argument("--jitter", choices=["off", "on", "both"], default="off",
                    help="tilt-jittered (box) lobes: off, on or both")
    ap.add_argument("--profiles", nargs="+", default=None, help="only these profiles (names as in the table)")
    ap.add_argument("--no-table", dest="table", action="store_false",
                    help="skip the tabulated-tilt lobes (precompute.scratch.lobe_table) rows")
    ap.add_argument("--only-table", action="store_true",
                    help="only the tabulated-tilt lobes rows (report bench/out/lobe_table.md)")
    a = ap.parse_args(argv)
    quick = a.quick
    tables_err = {}
    M, S = (64, 32) if quick else (256, 128)
    Ks = a.ks or ([1, 4, 8] if quick else [1, 2, 3, 4, 6, 8, 12, 16])
    dist_modes = a.dists or (["auto"] if quick else ["auto", "ggx"])
    jit_modes = {"off": [False], "on": [True], "both": [False, True]}[a.jitter]
    seg = a.segments or (1024 if quick else 4096)
    fr = fresnel.conductor_preset("iron")
    phi_o = lobe_fit.slice_centres(S)
    rows, curves = [], {}

    def run(name, tname, table, K, mode, jit=False):
        t0 = time.perf_counter()
        r = lobe_fit.fit_table(lobe_fit.rows_at(table, phi_o), K=K, phi_o=phi_o, dists=mode, jitter=jit)
        dt = time.perf_counter() - t0
        e = r["error"]
        used = r["weights"] > 0
        frac = lambda m: float(np.mean(m[used])) if np.any(used) else 0.0  # noqa: E731
        rows.append([name, tname, mode, "on" if jit else "off", K, float(np.median(e)), float(np.percentile(e, 95)),
                     float(e.max()), float(r["n_lobes"].mean()), frac(r["dist"] == 1), frac(r["jitters"] > 0), dt])
        print(" ".join(str(x) if not isinstance(x, float) else f"{x:.4f}" for x in rows[-1]), flush=True)
        return e

    for name, prof in _profiles(quick, seg):
        if a.profiles and name not in a.profiles:
            continue
        brdf = scratch_brdf.simulate(prof, resolution=M, fresnel=fr, cache=True, supersample=a.supersample)
        rm = np.asarray(brdf.rho_m, float)
        rm = rm if rm.ndim == 2 else rm[..., 0]
        r0 = np.asarray(brdf.rho0, float)
        tables = [("rho_m", rm), ("rho0_mean", r0.mean(-1) if r0.ndim == 3 else r0)]
        for tname, table in tables:
            if a.table:
                # tabulated-tilt lobes (precompute.scratch.lobe_table): no fit, one sampled closure
                t0 = time.perf_counter()
                _w, e, _A = lobe_table.fit_bins(lobe_fit.rows_at(table, phi_o), phi_o)
                rows.append([name, tname, "table", "-", 1, float(np.median(e)), float(np.percentile(e, 95)),
                             float(e.max()), 1.0, 0.0, 0.0, time.perf_counter() - t0])
                print(" ".join(str(x) if not isinstance(x, float) else f"{x:.4f}" for x in rows[-1]), flush=True)
                tables_err[(name, tname)] = (float(np.median(e)), float(np.percentile(e, 95)))
            for mode in ([] if a.only_table else dist_modes):
                for jit in jit_modes:
                    for K in Ks:
                        e = run(name, tname, table, K, mode, jit)
                        curves.setdefault((name, tname, mode, jit), []).append((K, np.median(e), np.percentile(e, 95)))
        if r0.ndim == 3 and not quick and not a.only_table:
            for c, cname in enumerate("RGB"):
                for jit in jit_modes:
                    run(name, f"rho0_{cname}", r0[..., c], 8, "auto", jit)
    report("lobe_table" if a.only_table else "lobe_fit", ["profile", "table", "dists", "jitter", "K", "err_median", "err_p95", "err_max", "lobes_used",
                        "beckmann_frac", "box_frac", "fit_s"], rows,
           notes=f"Analytic profiles with {seg} segments. M = {M} phi_i bins, S = {S} slices at phi_o = -pi/2 + (s+1/2) pi/S (rows linearly interpolated). "
                 "Relative L1 per slice between the lobes' cone-collapsed Cycles response (Smith G and horizon "
                 "losses included) and rho cos(phi_i) bin averages; error_target = 0.03 (slices stop adding lobes "
                 "once met). dists: auto = Beckmann fit + GGX refit of slices above target, better kept; ggx = GGX "
                 "only. jitter on: each lobe may also have a tilt jitter j (a box of phi_i width 4 j, "
                 "cycles_ggx.cone_collapse_binned_jittered); box_frac = fraction of used lobes with j > 0. "
                 "Fit time on 2 shared cores. Render cost per K: see bench/out/osl_vs_svm.md "
                 "(8 OSL lobes ~ +45 % over 1 lobe). dists = table: tabulated-tilt lobes "
                 "(precompute.scratch.lobe_table: the slice sampled bin by bin by one narrow lobe; K = 1 closure, no fit; "
                 "fit_s = weights + atoms).")
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.5))
    for (name, tname, mode, jit), c in curves.items():
        c = np.array(c)
        ls = "--" if jit else ("-" if mode == "auto" else ":")
        axs[0].plot(c[:, 0], c[:, 1], "o" + ls, ms=3, label=f"{name} {tname} {mode}" + (" jitter" if jit else ""))
        axs[1].plot(c[:, 0], c[:, 2], "o" + ls, ms=3)
    for (name, tname), (med, p95) in tables_err.items():
        axs[0].plot([1], [max(med, 1e-5)], "kx", ms=5)
        axs[1].plot([1], [max(p95, 1e-5)], "kx", ms=5)
    for ax, title in zip(axs, ["median rel. L1 (x: table lobes)", "p95 rel. L1 (x: table lobes)"]):
        ax.axhline(0.03, color="k", lw=0.8, ls="--")
        ax.set_xlabel("K (lobes)")
        ax.set_yscale("log")
        ax.set_title(title)
    axs[0].legend(fontsize=5, ncol=2)
    fig.tight_layout()
    if a.only_table:
        return 0
    fig.savefig(out_path("lobe_fit.png"), dpi=90)
    return 0
