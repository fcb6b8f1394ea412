"""Figure 5 of Raymond et al. 2016: profiles and their mirror scratch BRDFs, with 1st, 2nd and
higher-order bounces in red, green and blue.  ``python -m bench figure5`` writes
``docs/img/scratch_brdf_fig5.png`` (``--out`` to change, ``--resolution`` for M)."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bench._util import pyplot
from scratch_materials.precompute.scratch import profiles
from scratch_materials.precompute.scratch.brdf import simulate

ROOT = Path(__file__).resolve().parent.parent


def measured_like(seed: int = 7, n: int = 120):
    """A noisy, asymmetric profile with bulges above the base surface, like a profilometer trace."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 10.0, n)
    h = -1.6 * np.exp(-(((x - 4.2) / 2.2) ** 2)) - 0.6 * np.exp(-(((x - 6.8) / 1.0) ** 2))
    h += 0.5 * np.exp(-(((x - 1.0) / 0.5) ** 2)) + 0.35 * np.exp(-(((x - 9.0) / 0.6) ** 2))  # bulges
    h += 0.04 * np.cumsum(rng.standard_normal(n)) * 0.3 + 0.03 * rng.standard_normal(n)
    return profiles.tabulated(x, h, name="measured-like")


def figure(M: int = 256):
    cases = [("shallow quartic (0.1)", profiles.quartic(0.1)), ("steep quartic (0.5)", profiles.quartic(0.5)),
             ("V-groove 30 deg", profiles.v_groove(30)), ("measured-like, bulges", measured_like())]
    plt = pyplot()
    fig, axes = plt.subplots(2, len(cases), figsize=(3.2 * len(cases), 6.4),
                             gridspec_kw={"height_ratios": [1, 3]})
    for k, (title, prof) in enumerate(cases):
        b = simulate(prof, M, split_bounces=True)
        v = prof.periodic_vertices()
        ax = axes[0, k]
        ax.fill_between(v[:, 0], v[:, 1], v[:, 1].min() - 0.05, color="0.6")
        ax.plot(v[:, 0], v[:, 1], "k-", lw=1)
        ax.set_aspect("equal")
        ax.set_xlim(-0.55, 0.55)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
        # rho * cos(phi_o) * cos(phi_i) shows the energy; tone-map each bounce class to [0, 1]
        c = np.cos(-0.5 * np.pi + (np.arange(M) + 0.5) * np.pi / M)
        rgb = np.stack([b.bounces[i] * c[:, None] * c[None, :] for i in range(3)], -1)
        rgb = rgb / max(np.percentile(rgb.max(-1), 99.5), 1e-12)
        img = np.clip(rgb, 0, 1) ** (1 / 2.2)
        ax = axes[1, k]
        ax.imshow(img, origin="lower", extent=[-90, 90, -90, 90])  # rows: phi_o, columns: phi_i
        ax.set_xlabel("phi_i (deg)", fontsize=8)
        if k == 0:
            ax.set_ylabel("phi_o (deg)", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.suptitle("mirror scratch BRDF rho_m: 1st (R), 2nd (G), >=3rd (B) bounces", fontsize=10)
    fig.tight_layout()
    return fig


def main(argv) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench figure5")
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "scratch_brdf_fig5.png"))
    ap.add_argument("--resolution", type=int, default=256)
    args = ap.parse_args(argv)
    fig = figure(args.resolution)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print("wrote", args.out)
    return 0
