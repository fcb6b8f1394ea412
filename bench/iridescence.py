"""Benchmark of the scratch-iridescence reference model (Velinov et al. 2018).

Prints/writes: Si approximation error (eq. 29), closed-form sphere/polygon light
integrals vs Monte Carlo (error and time per evaluation), footprint integration vs
numerical integration over the ellipse (Fig. 5 trend), and images:
  docs/img/iridescence_fig5.png, docs/img/iridescence_si.png,
  docs/img/iridescence_lights.png, docs/img/iridescence_glints.png
Run: ``.venv/bin/python -m bench iridescence [--quick]``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from bench._util import out_path, pyplot, report, time_median
from scratch_materials.precompute.iridescence import model as ir

DOCS = Path(__file__).resolve().parent.parent / "docs" / "img"


def _save(fig, name):
    DOCS.mkdir(parents=True, exist_ok=True)
    tmp = DOCS / (name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(DOCS / name)
    fig.savefig(out_path(name), dpi=80)


def _dir(theta, phi):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) + 0 * phi], axis=-1)


def bench_si(plt):
    x = np.linspace(-10, 10, 200001)
    err = ir.si_approx(x) - ir.si(x)
    t_ex, _ = time_median(lambda: ir.si(x))
    t_ap, _ = time_median(lambda: ir.si_approx(x))
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.2))
    ax[0].plot(x, ir.si(x), label="Si exact")
    ax[0].plot(x, ir.si_approx(x), "--", label="eq. 29")
    ax[0].legend()
    ax[1].plot(x, err)
    ax[1].set_title("residual eq. 29 − Si")
    fig.tight_layout()
    _save(fig, "iridescence_si.png")
    plt.close(fig)
    return [["Si eq.29 max|err| on [-10,10]", float(np.abs(err).max()), f"{t_ap / x.size * 1e9:.1f} ns/eval"],
            ["Si eq.29 rms err on [-10,10]", float(np.sqrt(np.mean(err ** 2))), ""],
            ["Si exact (scipy sici)", 0.0, f"{t_ex / x.size * 1e9:.1f} ns/eval"]]


def bench_lights(plt, quick):
    n_mc = 1 << (16 if quick else 18)
    nv = 33 if quick else 91
    rows = []
    th = np.linspace(-np.radians(88), np.radians(88), nv)
    wo = np.stack([-np.sin(th), np.full_like(th, 0.01), np.cos(th)], -1)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    lam = np.array([0.45, 0.55, 0.65])[:, None]
    fig, axs = plt.subplots(2, 3, figsize=(12, 6))
    cases = [("sphere θl=30° α=0.05", "s", 0.5, 0.05), ("sphere θl=86° α=0.08 (clipped)", "s", 1.5, 0.08),
             ("sphere θl=70° α=0.2", "s", 1.22, 0.2)]
    # polygon: square facing the origin
    def quad(theta_l, size):
        c = _dir(theta_l, 0.0)
        n = -c
        e1 = np.cross(n, [0.0, 0.0, 1.0]); e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        h = size / 2
        V = np.array([c - h * e1 - h * e2, c + h * e1 - h * e2, c + h * e1 + h * e2, c - h * e1 + h * e2])
        return V if np.cross(V[1] - V[0], V[2] - V[0]) @ (-V[0]) > 0 else V[::-1]
    cases += [("quad θl=30° 0.1", "p", quad(0.5, 0.1), None), ("triangle θl=60° 0.2", "p", quad(1.05, 0.2)[:3], None),
              ("quad θl=90° 0.2 (half below)", "p", quad(np.pi / 2, 0.2), None)]
    for ax, (name, kind, a, b) in zip(axs.ravel(), cases):
        for si_mode, nb in (("exact", 1), ("approx", 1), ("exact", 8)):
            if kind == "s":
                f = lambda: ir.sphere_light_integral(wo[None], _dir(a, 0.0), np.cos(b), np.pi / 2, 3.0, lam,  # noqa
                                                     si_mode=si_mode, n_band=nb)
            else:
                f = lambda: ir.polygon_light_integral(wo[None], a, np.pi / 2, 3.0, lam, si_mode=si_mode,  # noqa
                                                      n_band=nb)
            t_cf, cf = time_median(f, repeats=3)
            if si_mode == "exact" and nb == 1:
                if kind == "s":
                    g = lambda: ir.sphere_light_integral_mc(wo[None], _dir(a, 0.0), np.cos(b), np.pi / 2, 3.0,  # noqa
                                                            lam, n_samples=n_mc, seed=1)
                else:
                    g = lambda: ir.polygon_light_integral_mc(wo[None], a, np.pi / 2, 3.0, lam,  # noqa
                                                             n_samples=n_mc, seed=1)
                t_mc, mc = time_median(g, repeats=1, warmup=0)
                ax.plot(np.degrees(th), mc[1], "k-", lw=2, label=f"MC {n_mc} spp")
            err = np.max(np.abs(cf - mc) / mc.max(axis=1, keepdims=True))
            l1 = np.max(np.abs(cf - mc).sum(axis=1) / mc.sum(axis=1))
            ax.plot(np.degrees(th), cf[1], "--", label=f"closed form Si={si_mode} n_band={nb}")
            rows.append([name, f"{si_mode}/n_band={nb}", float(err), float(l1),
                         f"{t_cf / cf.size * 1e6:.2f} us", f"{t_mc / mc.size * 1e3:.2f} ms"])
        ax.set_title(name, fontsize=9)
        ax.set_yscale("log")
        ax.set_xlabel("view angle θo (deg), λ = 0.55 µm")
    axs[0, 0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, "iridescence_lights.png")
    plt.close(fig)
    return rows


def bench_fig5(plt, quick):
    S = ir.random_scratches(40, length_range=(0.3, 0.6), domain=(0.3, 0.3, 0.7, 0.7), uv_scale_um=2000.0, seed=0,
                            width_range_um=(2.0, 2.0))
    sigma = 60.0
    ratios = np.geomspace(0.05, 50, 12 if quick else 25)
    nc = 6 if quick else 20
    rng = np.random.default_rng(0)
    centres = 0.45 + 0.1 * rng.random((nc, 2))
    s = S.uv_scale_um
    res = np.zeros((ratios.size, 3, 2))   # [numeric, analytic corrected, analytic uncorrected] × [eta, rho]
    for i, ratio in enumerate(ratios):
        r_um = np.sqrt(ratio) * sigma
        for c in centres:
            e_ref, r_ref = ir.footprint_reference(S, c, r_um / s, 0.6 * r_um / s, [1.0, 0.3], sigma, n_r=48, n_theta=96)
            res[i, 0] += [e_ref, r_ref]
            s_b, s1, s2 = ir.scratch_coords(c * s, S.p0 * s, S.p1 * s)
            e1 = np.array([1.0, 0.3]) / np.linalg.norm([1.0, 0.3])
            l_in = ir.contained_length(S.p0 * s, S.p1 * s, c * s, r_um, 0.6 * r_um, e1)
            for j, corr in ((1, True), (2, False)):
                res[i, j, 0] += ir.eta_footprint(l_in, r_um, 0.6 * r_um, ir.eta_s_sq(s_b, sigma, s1, s2), sigma,
                                                 corr).sum()
                res[i, j, 1] += ir.rho_footprint(S.width_um, l_in, r_um, 0.6 * r_um,
                                                 ir.area_density_point(S.width_um, s_b, s1, s2, sigma), sigma,
                                                 corr).sum()
    res /= nc
    ap_ac = ratios * 0.6
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    for k, title in enumerate(["|η_P|² (µm²) averaged over footprints", "ρ_P averaged over footprints"]):
        ax[k].plot(ap_ac, res[:, 0, k], "k-", lw=2, label="numeric (ellipse quadrature)")
        ax[k].plot(ap_ac, res[:, 2, k], "r--", label="eq. 15 / 18")
        ax[k].plot(ap_ac, res[:, 1, k], "b-.", label="with small-footprint correction (eq. 16)")
        for v in (1, 10, 20):
            ax[k].axvline(v, color="gray", ls=":")
        ax[k].set_xscale("log")
        ax[k].set_xlabel("A_P / A_C")
        ax[k].set_title(title, fontsize=9)
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, "iridescence_fig5.png")
    plt.close(fig)
    rows = []
    for i in range(0, ratios.size, max(1, ratios.size // 6)):
        rel = np.abs(res[i, 1:] - res[i, 0]) / res[i, 0]
        rows.append([f"{ap_ac[i]:.3g}", float(rel[0, 0]), float(rel[1, 0]), float(rel[0, 1]), float(rel[1, 1])])
    return rows


def render_glints(plt, quick):
    n = 96 if quick else 256
    S = ir.random_scratches(1500 if quick else 4000, length_range=(0.05, 0.5), uv_scale_um=2e4, seed=3)
    grid = ir.build_grid(S, cell_size=0.01)
    cam = np.array([0.5, -0.45, 0.75])
    target = np.array([0.5, 0.5, 0.0])
    fwd = target - cam; fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0, 0, 1.0]); right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    fov = np.radians(45)
    pix = 2 * np.tan(fov / 2) / n
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    x = (jj + 0.5 - n / 2) * pix
    y = (n / 2 - ii - 0.5) * pix
    d = fwd + x[..., None] * right + y[..., None] * up
    d = d.reshape(-1, 3)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tt = -cam[2] / d[:, 2]
    hit = cam + tt[:, None] * d
    uv = hit[:, :2]
    wo = -d
    # footprint ellipse: pixel cone radius at distance tt, stretched by 1/cos along the view's ground projection
    r = 0.5 * pix * tt
    cos_o = wo[:, 2]
    g = wo[:, :2] / np.maximum(np.linalg.norm(wo[:, :2], axis=1, keepdims=True), 1e-9)
    fp = ir.Footprint(r / np.maximum(cos_o, 0.05), r, g)
    light = ir.SphereLight(np.array([0.5, 1.6, 0.75]), 0.03)
    inside = (uv[:, 0] > 0) & (uv[:, 0] < 1) & (uv[:, 1] > 0) & (uv[:, 1] < 1)
    img = np.zeros((n * n, 3))
    idx = np.nonzero(inside)[0]
    lam = ir.RGB_WAVELENGTHS_UM if quick else np.linspace(0.39, 0.77, 16)
    mode = "rgb" if quick else "spectral"
    t0 = time.perf_counter()
    for chunk in np.array_split(idx, max(1, idx.size // 2048)):      # memory chunks of pixels
        res = ir.evaluate(S, uv[chunk], wo[chunk], light, grid=grid,
                          footprint=ir.Footprint(fp.a1[chunk], fp.a2[chunk], fp.e1[chunk]),
                          mode=mode, wavelengths_um=lam, base=np.zeros(chunk.size))
        img[chunk] = res.rgb
    t = time.perf_counter() - t0
    img = img.reshape(n, n, 3)
    expo = 1.0 / max(np.percentile(img.max(axis=2), 99.8), 1e-12)
    ldr = np.clip(img * expo, 0, 1) ** (1 / 2.2)
    ldr[~inside.reshape(n, n)] = 0.15
    fig = plt.figure(figsize=(5, 5))
    plt.imshow(ldr)
    plt.axis("off")
    plt.title(f"{len(S)} scratches, sphere light, {mode}", fontsize=8)
    fig.tight_layout()
    _save(fig, "iridescence_glints.png")
    plt.close(fig)
    return t, n, int(inside.sum())


def main(argv) -> int:
    quick = "--quick" in argv
    plt = pyplot()
    rows = bench_si(plt)
    report("iridescence_si", ["quantity", "value", "time"], rows)
    rows = bench_lights(plt, quick)
    report("iridescence_lights", ["light", "Si / band", "max|cf−mc|/peak", "L1 rel", "closed form / eval",
                                  "MC / eval"], rows,
           notes="Sweep of 33/91 view directions θo ∈ [−88°, 88°] (plane ⟂ scratch), λ = 0.45/0.55/0.65 µm, W = 3 µm.")
    rows = bench_fig5(plt, quick)
    report("iridescence_fig5", ["A_P/A_C", "η rel err (corr.)", "η rel err (eq.15)", "ρ rel err (corr.)",
                                "ρ rel err (eq.18)"], rows)
    t, n, npx = render_glints(plt, quick)
    print(f"glints: {n}x{n} image, {npx} surface pixels in {t:.2f} s ({t / max(npx, 1) * 1e6:.1f} us/pixel)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
