"""Figure: φo slices of quartic scratch tables, K = 8 fitted lobes vs tabulated-tilt lobes (issue #4).

For quartic 0.1 / 0.3 / 1.0 (4096 segments, M = 256) and three view angles, plots the target
ρ cos φi (bin averages) with what Cycles renders on average for 8 fitted lobes (``lobe_fit``) and
for the table lobes (``lobe_table``); titles give each slice's rel. L1 error.  Writes
``bench/out/lobe_slices.png`` and a one-row table per slice.

    python -m bench lobe_slices
"""
from __future__ import annotations

import numpy as np


def main(argv) -> int:
    from bench._util import out_path, pyplot, report
    from scratch_materials.precompute.scratch import lobe_fit as lf, lobe_table as lt, profiles, brdf as scratch_brdf

    M, S = 256, 128
    phi = lf.slice_centres(S)
    picks = [20, 54, 72]
    e = lf.phi_bin_edges(M)
    c = 0.5 * (e[1:] + e[:-1])
    plt = pyplot()
    fig, axs = plt.subplots(3, 3, figsize=(13, 8.5), sharex=True)
    rows = []
    for r, depth in enumerate((0.1, 0.3, 1.0)):
        table = scratch_brdf.simulate(profiles.quartic(depth, segments=4096), resolution=M, cache=True).rho_m
        sl = lf.rows_at(np.asarray(table, float), phi[picks])
        f = sl * (np.diff(np.sin(e)) / np.diff(e))
        fit = lf.fit_table(sl, K=8, phi_o=phi[picks])
        m_fit = lf.lobe_model(phi[picks], fit["weights"], fit["tilts"], fit["widths"], e,
                              alpha_x=float(fit["alpha_x"]), dist=fit["dist"])
        w, err_t, A = lt.fit_bins(sl, phi[picks])
        m_tab = lt.model(w, A)
        for i, s in enumerate(picks):
            ax = axs[r, i]
            ax.plot(c, f[i], "k", lw=1.4, label="table ρ cos φi")
            ax.plot(c, m_fit[i], "r", lw=0.8, label="8 fitted lobes")
            ax.plot(c, m_tab[i], "c--", lw=0.8, label="table lobes")
            ax.set_title(f"quartic {depth}, φo = {phi[s]:.2f}: fit {100 * fit['error'][i]:.1f} %, "
                         f"table {100 * err_t[i]:.3f} %", fontsize=8)
            rows.append([depth, float(phi[s]), float(fit["error"][i]), float(err_t[i])])
    axs[0, 0].legend(fontsize=7)
    for ax in axs[-1]:
        ax.set_xlabel("φi (rad)")
    fig.tight_layout()
    fig.savefig(out_path("lobe_slices.png"), dpi=80)
    report("lobe_slices", ["quartic depth", "phi_o", "fit K=8 rel. L1", "table rel. L1"], rows,
           "M = 256, 4096-segment profiles; models are what Cycles renders on average (cone collapse).")
    return 0
