"""Benchmark: NDFs from microgeometry (Dong et al. 2015) -- run time vs error against references.

``python -m bench microgeometry [--quick]``

* 640x480 synthetic scan (110 nm pixels, as the paper's profilometer): filtered NDF time (median
  of 5; target <= 0.5 s) and D_K table time (one 70 x 53 µm coherence patch; target <= 10 s).
* filtered NDF: table resolution vs time and roughness error (Beckmann alpha vs the value known
  from the surface spectrum times the filter's transfer function).
* Kirchhoff: Taylor tolerance vs time and error against a tol=1e-14 run (itself checked against
  the direct sum on a small patch).
Writes ``bench/out/microgeometry.{md,png}`` and ``docs/img/microgeometry_ndfs.png``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bench._util import out_path, pyplot, report, time_median
from scratch_materials.precompute.microgeometry.heightfield import gaussian_surface, spectral_slope_covariance
from scratch_materials.precompute.microgeometry.ndf import (ellipsoid_ndf, filtered_ndf, fit_beckmann, fit_ellipsoid,
                                          kirchhoff_integral_direct, kirchhoff_integral_fft, kirchhoff_ndf, naive_ndf)

DOCS_IMG = Path(__file__).resolve().parent.parent / "docs" / "img"


def _timed(fn):
    t0 = time.perf_counter()
    r = fn()
    return time.perf_counter() - t0, r


def docs_figure(quick: bool) -> Path:
    """Naive vs filtered vs Kirchhoff NDF and the ellipsoid fit for a synthetic brushed surface."""
    plt = pyplot()
    shape = (240, 320) if quick else (480, 640)
    hf = gaussian_surface(shape, 0.11, 0.08, (15.0, 1.5), seed=7)  # scratches along x
    nd_n = naive_ndf(hf)
    nd_f = filtered_ndf(hf)
    nd_k = kirchhoff_ndf(hf, wavelength_um=0.555, patch_um=70.0).normalized()
    p = fit_ellipsoid(nd_f)
    R = nd_f.resolution
    g = np.linspace(-1, 1, R)
    X, Y = np.meshgrid(g, g)
    ins = X**2 + Y**2 < 1
    m = np.stack([X[ins], Y[ins], np.sqrt(1 - X[ins] ** 2 - Y[ins] ** 2)], -1)
    ell = np.zeros((R, R))
    ell[ins] = ellipsoid_ndf(m, p)
    zoom = 0.35
    sl = slice(int((1 - zoom) / 2 * (R - 1)), int((1 + zoom) / 2 * (R - 1)) + 1)
    fig, axs = plt.subplots(1, 4, figsize=(15, 4.2))
    vmax = np.percentile(nd_f.table[sl, sl], 99.9)
    for ax, t, title in zip(axs, [nd_n.table, nd_f.table, nd_k.table, ell],
                            ["naive (§5.1)", "filtered, σ = 1 µm (§5.1)", "Kirchhoff D_K, λq = 0.555 µm (eq. 6)",
                             "ellipsoid fit to filtered (eq. 10)"]):
        ax.imshow(t[sl, sl], origin="lower", extent=[-zoom, zoom, -zoom, zoom], cmap="magma", vmin=0, vmax=vmax)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("m_x")
    axs[0].set_ylabel("m_y")
    fig.suptitle(f"Synthetic brushed surface ({shape[1]}x{shape[0]} px, 0.11 µm): "
                 f"ellipsoid αx={p[0]:.3f} αy={p[1]:.3f} θ=({p[2]:.3f}, {p[3]:.3f}, {p[4]:.2f})", fontsize=10)
    fig.tight_layout()
    DOCS_IMG.mkdir(parents=True, exist_ok=True)
    path = DOCS_IMG / "microgeometry_ndfs.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main(argv) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench microgeometry")
    ap.add_argument("--quick", action="store_true", help="smoke run (< 30 s)")
    args = ap.parse_args(argv)
    quick = args.quick
    rows = []
    pix = 0.11

    # --- headline timings on a 640x480 scan
    scan = gaussian_surface((480, 640), pix, 0.15, 3.0, seed=1)
    t_f, nd = time_median(lambda: filtered_ndf(scan), repeats=3 if quick else 5)
    rows.append(["filtered NDF 640x480 -> 1025^2 (median)", t_f, "target <= 0.5 s", f"∫D(m·n)dω - 1 = {nd.integral() - 1:.1e}"])
    t_n, _ = time_median(lambda: naive_ndf(scan), repeats=3 if quick else 5)
    rows.append(["naive NDF 640x480 -> 1025^2 (median)", t_n, "", ""])
    kd_scan = scan if not quick else scan.crop(0, 240, 0, 320)
    t_k, kd = _timed(lambda: kirchhoff_ndf(kd_scan, wavelength_um=0.555, patch_um=(70.4, 52.8)))
    rows.append([f"D_K table {kd_scan.shape[1]}x{kd_scan.shape[0]}, λq=0.555 µm, 1 patch", t_k, "target <= 10 s",
                 f"raw ∫D_K = {kd.info['raw_integral']:.4f}"])

    # --- filtered NDF: resolution vs time and roughness error
    big = gaussian_surface((512, 512) if quick else (1024, 1024), 0.2, 0.2, 3.0, seed=0)
    alpha_true = np.sqrt(2 * spectral_slope_covariance(big.heights, 0.2, sigma_um=1.0)[0, 0])
    res_list = [129, 257, 513, 1025]
    res_err, res_t = [], []
    for r in res_list:
        t, ndr = time_median(lambda r=r: filtered_ndf(big, resolution=r), repeats=1 if quick else 3)
        a = fit_beckmann(ndr, isotropic=True)["alpha_x"]
        res_err.append(abs(a / alpha_true - 1))
        res_t.append(t)
        rows.append([f"filtered {big.shape[1]}^2, res {r}", t, f"alpha err {res_err[-1]:.2%}", f"alpha {a:.4f} vs {alpha_true:.4f}"])

    # --- Kirchhoff: tolerance vs time and error
    kp = gaussian_surface((96, 128) if quick else (240, 320), pix, 0.15, 3.0, seed=2).heights
    k = 4 * np.pi / 0.555
    _, _, I_ref, comp = kirchhoff_integral_fft(kp, pix, k, max_theta=0.8, tol=1e-14)
    tiny = kp[:12, :16]
    qx, qy, I_t, ct = kirchhoff_integral_fft(tiny, pix, k, max_theta=0.8, tol=1e-14)
    QX, QY = np.meshgrid(qx, qy)
    q = np.stack([QX[ct], QY[ct], np.sqrt(k * k - QX[ct] ** 2 - QY[ct] ** 2)], -1)
    t_direct, I_d = _timed(lambda: kirchhoff_integral_direct(tiny, pix, q))
    direct_err = np.max(np.abs(I_t[ct] - I_d)) / np.max(np.abs(I_d))
    rows.append(["D_K FFT vs direct sum, 16x12 patch", t_direct, f"max rel err {direct_err:.1e}", f"{ct.sum()} q values"])
    tols = [1e-1, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12]
    k_err, k_t = [], []
    for tol in tols:
        t, (_, _, I, _) = time_median(lambda tol=tol: kirchhoff_integral_fft(kp, pix, k, max_theta=0.8, tol=tol),
                                      repeats=1, warmup=0)
        e = np.max(np.abs(I[comp] - I_ref[comp])) / np.max(np.abs(I_ref[comp]))
        k_err.append(max(e, 1e-17))
        k_t.append(t)
        rows.append([f"D_K {kp.shape[1]}x{kp.shape[0]} tol {tol:.0e}", t, f"max rel err {e:.1e}", ""])

    report("microgeometry", ["case", "time [s]", "error / target", "note"], rows,
           notes="Synthetic Gaussian surfaces (seeded).  Errors: Beckmann alpha vs the spectrum-derived value; "
                 "D_K vs the tol=1e-14 run, which matches the direct sum to round-off.")
    plt = pyplot()
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    axs[0].loglog(res_t, res_err, "o-")
    for r, t, e in zip(res_list, res_t, res_err):
        axs[0].annotate(str(r), (t, e))
    axs[0].set_xlabel("time [s]")
    axs[0].set_ylabel("|alpha / alpha_true - 1|")
    axs[0].set_title("filtered NDF: table resolution")
    axs[1].loglog(k_t, k_err, "o-")
    for tol, t, e in zip(tols, k_t, k_err):
        axs[1].annotate(f"{tol:.0e}", (t, e))
    axs[1].set_xlabel("time [s]")
    axs[1].set_ylabel("max rel error of I(q)")
    axs[1].set_title("Kirchhoff FFT: Taylor tolerance")
    fig.tight_layout()
    fig.savefig(out_path("microgeometry.png"), dpi=90)
    plt.close(fig)
    print("figure:", docs_figure(quick))
    return 0
