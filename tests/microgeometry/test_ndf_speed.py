"""The fast filtered NDF (streamed float32 tiles, worker-thread splats) equals a brute-force evaluation of the
paper's definition (Dong et al. 2015, §5.1; issue #14 item B).

Reference: at every measured point, the Gaussian-weighted least-squares plane (std ``sigma``, window truncated
at ``ceil(4 sigma)`` px, points outside the scan or missing have weight 0) is solved from its own 3x3 normal
equations in float64 (no FFT, no tiles, no float32), its normal is splatted with the public
:func:`splat_table`, and the table is normalised.  Timing lives in bench/microgeometry_scale.py.
"""
import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from scratch_materials.precompute.microgeometry import heightfield, ndf

PIXEL = 0.25
SIGMA = 0.5  # 2 px: window 17 x 17
RES = 257
#: float32 tiles vs the float64 per-point solve (measured: slopes within 2.4e-6..4.7e-6 of their spread,
#: tables 2.3e-6..2.9e-6 rel L1 for tiles 32..512; the float64 tiles: 5e-14); a kernel 2 % too wide or
#: truncated at 3 sigma instead of 4 gives > 1e-3
TOL_TABLE = 1e-5
TOL_SLOPE = 2e-5


def _scan():
    hf = heightfield.gaussian_surface((90, 110), PIXEL, 0.15, 1.0, seed=7)
    h = np.array(hf.heights)
    y, x = np.mgrid[0:h.shape[0], 0:h.shape[1]]
    h += 0.02 * x - 0.01 * y + 3.0  # tilt + offset: detilting and the tiles' own planes must handle them
    rng = np.random.default_rng(5)
    h[rng.random(h.shape) < 0.005] = np.nan  # sparse dropouts (well-conditioned fits all around)
    return h


def brute_force_slopes(h, pixel_um, sigma_um):
    """Per-point weighted plane fits (float64 normal equations) minus the slopes of the scan's least-squares
    plane (detilting, by a plain lstsq on the valid points); ``good`` = the well-conditioned fits."""
    ny, nx = h.shape
    yy, xx = np.mgrid[0:ny, 0:nx] * pixel_um
    v = np.isfinite(h)
    tilt = np.linalg.lstsq(np.stack([np.ones(v.sum()), xx[v], yy[v]], 1), h[v], rcond=None)[0][1:]
    hd = h
    s = sigma_um / pixel_um
    r = int(np.ceil(4 * s))
    t = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (t / s) ** 2)
    w2 = np.outer(g, g)
    pad = np.pad(hd, r, constant_values=np.nan)
    win = sliding_window_view(pad, (2 * r + 1, 2 * r + 1))  # [ny, nx, 2r+1, 2r+1], window centred on (j, i)
    m = np.isfinite(win)
    w = np.where(m, w2, 0.0)
    z = np.where(m, win, 0.0)
    U, V = np.meshgrid(t, t)  # u_x along columns, u_y along rows
    basis = [np.ones_like(U), U, V]
    A = np.empty((ny, nx, 3, 3))
    b = np.empty((ny, nx, 3))
    for i, p in enumerate(basis):
        b[..., i] = np.einsum("yxuv,uv->yx", w * z, p)
        for j, q in enumerate(basis):
            A[..., i, j] = np.einsum("yxuv,uv->yx", w, p * q)
    full_w = 2 * np.pi * s**2
    full_det = full_w**3 * s**4
    det = np.linalg.det(A)
    good = np.isfinite(h) & (A[..., 0, 0] > 0.05 * full_w) & (det > 1e-6 * full_det)
    coef = np.linalg.solve(np.where(good[..., None, None], A, np.eye(3)), b[..., None])[..., 0]
    return coef[..., 1] / pixel_um - tilt[0], coef[..., 2] / pixel_um - tilt[1], good  # detilted dh/dx, dh/dy


def brute_force_ndf(h, pixel_um, sigma_um, resolution):
    sx, sy, good = brute_force_slopes(h, pixel_um, sigma_um)
    sx, sy = sx[good], sy[good]
    q = 1.0 / np.sqrt(1 + sx * sx + sy * sy)
    node = ndf.splat_table(-sx * q, -sy * q, np.ones_like(sx), resolution)[0]
    return node / (node.sum() * (2.0 / (resolution - 1)) ** 2), int(good.sum())


def _rel_l1(a, b):
    return float(np.abs(a - b).sum() / np.abs(b).sum())


@pytest.fixture(scope="module")
def reference():
    h = _scan()
    return h, brute_force_slopes(h, PIXEL, SIGMA), brute_force_ndf(h, PIXEL, SIGMA, RES)


@pytest.mark.parametrize("tile", [32, 48, 512])  # many tiles (with halos across dropouts) and one
def test_fast_filtered_slopes_equal_brute_force(reference, tile):
    h, (bx, by, good), _ = reference
    sx, sy, ok = ndf.filtered_slopes(h, PIXEL, sigma_um=SIGMA, tile=tile)
    assert np.array_equal(ok, good)
    spread = np.std(bx[good])
    assert np.max(np.abs(sx[good] - bx[good])) < TOL_SLOPE * spread
    assert np.max(np.abs(sy[good] - by[good])) < TOL_SLOPE * spread


@pytest.mark.parametrize("tile", [32, 512])
def test_fast_filtered_ndf_equals_brute_force(reference, tile):
    h, _, (table, n) = reference
    T = ndf.filtered_ndf(h, PIXEL, sigma_um=SIGMA, resolution=RES, tile=tile)
    assert T.info["n_points"] == n
    assert _rel_l1(T.table, table) < TOL_TABLE


def test_float64_tiles_equal_brute_force_to_round_off(reference):
    """Same algorithm in float64: only round-off separates it from the per-point solve."""
    h, _, (table, n) = reference
    T = ndf.filtered_ndf(h, PIXEL, sigma_um=SIGMA, resolution=RES, tile=32, dtype=np.float64)
    assert T.info["n_points"] == n
    assert _rel_l1(T.table, table) < 1e-10


@pytest.mark.parametrize("broken", ["width+2%", "truncated at 3 sigma"])
def test_brute_force_check_fails_on_a_broken_kernel(reference, monkeypatch, broken):
    """The comparison above can fail: the fast path with a wrong kernel width or truncation is far off."""
    h, _, (table, _) = reference
    check = ndf._check_sigma

    def wrong(sigma_um, d, shape):
        s, r = check(sigma_um, d, shape)
        return (s * 1.02, r) if broken == "width+2%" else (s, int(np.ceil(3 * s)))

    monkeypatch.setattr(ndf, "_check_sigma", wrong)
    ndf._kernel_spectra.cache_clear()
    try:
        T = ndf.filtered_ndf(h, PIXEL, sigma_um=SIGMA, resolution=RES, tile=32)
    finally:
        ndf._kernel_spectra.cache_clear()
    assert _rel_l1(T.table, table) > 100 * TOL_TABLE
