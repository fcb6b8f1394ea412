"""Benchmark: number of tilted GGX lobes K vs fit error vs fit time (issue #4, lobe fitting).

For each profile (shallow/steep quartic, V-grooves, a measured-like tabulated profile) and each
table (rho_m; rho0 with iron-like Fresnel), fit K = 1..8 lobes per phi_o slice with
``precompute.lobe_fit.fit_table`` and report the per-slice relative L1 error (median, p95, max),
the mean number of lobes used and the fit time.  ``render_s`` is a hook column for the lead's Cycles
render cost per K (left empty here).  ``--quick``: M = 64, K in {1, 4, 8}, two profiles.
"""
from __future__ import annotations

import time

import numpy as np

from bench._util import out_path, pyplot, report


def _profiles(quick: bool):
    from precompute import profiles

    out = [("quartic_0.2", profiles.quartic(0.2, segments=1024 if quick else 4096)),
           ("vgroove_45", profiles.v_groove(45.0))]
    if not quick:
        rng = np.random.default_rng(7)
        x = np.linspace(-1, 1, 257)
        h = -0.35 * (1 - x**2) ** 1.5 * (1 + 0.35 * x)
        k = np.arange(1, 7)[:, None]
        h += 0.03 * np.sum(rng.normal(size=(6, 1)) * np.sin(np.pi * k * (x + 1) / 2) / k, 0)
        out += [("quartic_1.0", profiles.quartic(1.0, segments=4096)),
                ("vgroove_20", profiles.v_groove(20.0)),
                ("measured_like", profiles.tabulated(x, h, name="measured_like"))]
    return out


def main(argv) -> int:
    from precompute import fresnel, lobe_fit, scratch_brdf

    quick = "--quick" in argv
    M = 64 if quick else 256
    Ks = [1, 4, 8] if quick else list(range(1, 9))
    fr = None if quick else fresnel.conductor_preset("iron") if hasattr(fresnel, "conductor_preset") else None
    rows, curves = [], {}
    for name, prof in _profiles(quick):
        try:
            brdf = scratch_brdf.simulate(prof, resolution=M, fresnel=fr)
        except Exception as exc:  # a Fresnel preset name may differ; fall back to the mirror table
            print(f"{name}: simulate with fresnel failed ({exc}); using rho_m only")
            brdf = scratch_brdf.simulate(prof, resolution=M)
        rm = np.asarray(brdf.rho_m)
        tables = [("rho_m", rm if rm.ndim == 2 else rm[..., 0])]
        if fr is not None:
            r0 = np.asarray(brdf.rho0)
            tables.append(("rho0" if r0.ndim == 2 else "rho0[R]", r0 if r0.ndim == 2 else r0[..., 0]))
        for tname, rho in tables:
            for K in Ks:
                t0 = time.perf_counter()
                r = lobe_fit.fit_table(rho, K=K)
                dt = time.perf_counter() - t0
                e = r["error"]
                rows.append([name, tname, M, K, float(np.median(e)), float(np.percentile(e, 95)), float(e.max()),
                             float(r["n_lobes"].mean()), dt, ""])
                curves.setdefault((name, tname), []).append((K, np.median(e), np.percentile(e, 95)))
                print(f"{name} {tname} K={K}: median {np.median(e):.4f} p95 {np.percentile(e, 95):.4f} "
                      f"max {e.max():.4f} lobes {r['n_lobes'].mean():.2f} time {dt:.2f}s", flush=True)
    report("lobe_fit", ["profile", "table", "M", "K", "err_median", "err_p95", "err_max", "lobes_used",
                        "fit_s", "render_s"], rows,
           notes="Relative L1 per phi_o slice between the lobes' cone-collapsed Cycles response "
                 "(Smith G and horizon losses included) and rho cos(phi_i). error_target = 0.03 "
                 "(slices stop adding lobes once met). render_s: to be filled by the lead (Cycles).")
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(11, 4))
    for (name, tname), c in curves.items():
        c = np.array(c)
        axs[0].plot(c[:, 0], c[:, 1], "o-", label=f"{name} {tname}")
        axs[1].plot(c[:, 0], c[:, 2], "o-", label=f"{name} {tname}")
    for ax, title in zip(axs, ["median rel. L1", "p95 rel. L1"]):
        ax.axhline(0.03, color="k", lw=0.8, ls="--")
        ax.set_xlabel("K (lobes)")
        ax.set_yscale("log")
        ax.set_title(title)
    axs[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_path("lobe_fit.png"), dpi=90)
    return 0
