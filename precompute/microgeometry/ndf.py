"""NDFs from measured microgeometry (Dong et al. 2015, §5.1, §6, Appendix A).

Public API
----------
* :func:`naive_ndf` - triangle-histogram NDF of the raw height field (§5.1, "straightforward way").
* :func:`filtered_ndf` - filtered geometric NDF: a Gaussian-weighted least-squares plane fit at each
  data point (§5.1, default sigma = 1 µm), computed for all points at once with FFT convolutions.
* :func:`kirchhoff_ndf` - Kirchhoff distribution ``D_K`` (eq. 6) at fixed ``lambda_q``, per coherence
  patch then averaged (Appendix A), evaluated exactly on an FFT frequency grid (see
  :func:`kirchhoff_integral_fft`) instead of the paper's Monte Carlo; :func:`kirchhoff_integral_direct`
  is the direct-sum reference.
* :func:`fit_ellipsoid`, :func:`ellipsoid_ndf` - re-exported from :mod:`precompute.microgeometry.ellipsoid`.

Table format (§5.1): the hemisphere around the mean normal ``n = +z`` is projected orthographically
onto the unit disk, ``m -> (m_x, m_y)``, embedded in ``[-1, 1]^2`` and tabulated on
``resolution x resolution`` nodes (1025 by default; node ``(j, i)`` is ``(m_x, m_y) =
(-1 + i h, -1 + j h)``, ``h = 2 / (resolution - 1)``).  Because ``dω = dm_x dm_y / m_z``, the
projected-area density per unit disk area equals ``D(m)`` itself, so the table stores ``D`` per
steradian and ``∫ D(m)(m·n) dω = ∫ D dm_x dm_y``.  Samples are splatted bilinearly onto the nodes and
:meth:`NDFTable.eval` interpolates bilinearly, so the table's integral is exactly 1 after
normalisation.

Units: heights, pixel sizes, sigma and wavelengths in micrometres; ``q`` in rad/µm.

Missing data (NaN) are handled without bias: the plane fit is a normalised convolution (weights
and weighted data both masked, so a missing point simply drops out of each local fit and points
whose fit is ill-conditioned are skipped); the naive NDF drops triangles touching a missing
vertex; ``D_K`` zeroes the integrand on missing pixels and divides by the *measured* area
(``nan_policy="weight"``) or skips patches with missing points (``nan_policy="skip"``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import map_coordinates

from .ellipsoid import ellipsoid_ndf, fit_beckmann, fit_ellipsoid, fit_ggx  # noqa: F401 - re-exports
from .heightfield import HeightField, as_heightfield

__all__ = [
    "NDFTable",
    "naive_ndf",
    "filtered_ndf",
    "filtered_slopes",
    "splat_table",
    "kirchhoff_ndf",
    "kirchhoff_integral_direct",
    "kirchhoff_integral_fft",
    "kirchhoff_patch_dk",
    "fit_ellipsoid",
    "ellipsoid_ndf",
    "fit_beckmann",
    "fit_ggx",
]


# ============================================================================ table


def _check_resolution(resolution) -> int:
    if not isinstance(resolution, (int, np.integer)) or resolution < 9 or resolution > 8193 or resolution % 2 == 0:
        raise ValueError(f"resolution: must be an odd integer in [9, 8193] (node at the disk centre), got {resolution!r}")
    return int(resolution)


@dataclass
class NDFTable:
    """Tabulated NDF on the orthographic disk (§5.1): ``table[j, i] = D(m)`` at ``(m_x, m_y) = (-1 + i h, -1 + j h)``."""

    table: np.ndarray
    kind: str = "tabulated"
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        t = np.asarray(self.table, dtype=np.float64)
        if t.ndim != 2 or t.shape[0] != t.shape[1]:
            raise ValueError(f"table: expected a square 2D array, got {t.shape}")
        _check_resolution(t.shape[0])
        if not np.all(np.isfinite(t)) or np.any(t < 0):
            raise ValueError("table: values must be finite and non-negative")
        self.table = t

    @property
    def resolution(self) -> int:
        return self.table.shape[0]

    @property
    def h(self) -> float:
        """Node spacing in disk coordinates."""
        return 2.0 / (self.resolution - 1)

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        g = np.linspace(-1.0, 1.0, self.resolution)
        return np.meshgrid(g, g)

    def integral(self) -> float:
        """``∫ D(m)(m·n) dω`` of the bilinear interpolant (= sum of nodes times ``h^2``)."""
        return float(self.table.sum() * self.h**2)

    def normalized(self) -> "NDFTable":
        s = self.integral()
        if not s > 0:
            raise ValueError("table: has zero mass and cannot be normalised")
        return NDFTable(self.table / s, self.kind, dict(self.info))

    def eval(self, m) -> np.ndarray:
        """``D(m)`` per steradian for unit vectors ``m`` (N, 3) (z = mean normal); 0 below the horizon."""
        m = np.asarray(m, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != 3:
            raise ValueError(f"m: expected shape (N, 3), got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValueError("m: components must be finite")
        nrm = np.linalg.norm(m, axis=1)
        if np.any(nrm < 1e-12):
            raise ValueError("m: directions must have non-zero length")
        m = m / nrm[:, None]
        return np.where(m[:, 2] > 0, self.eval_disk(m[:, 0], m[:, 1]), 0.0)

    def eval_disk(self, mx, my) -> np.ndarray:
        """Bilinear interpolation at disk coordinates (0 outside ``[-1, 1]^2``)."""
        R = self.resolution
        fx = (np.asarray(mx, float) + 1.0) / self.h
        fy = (np.asarray(my, float) + 1.0) / self.h
        inside = (fx >= 0) & (fx <= R - 1) & (fy >= 0) & (fy <= R - 1)
        return np.where(inside, map_coordinates(self.table, [np.clip(fy, 0, R - 1), np.clip(fx, 0, R - 1)],
                                                order=1, mode="nearest"), 0.0)

    def support_box(self, mass: float = 0.999) -> tuple[float, float, float, float]:
        """Disk-coordinate box ``(x0, x1, y0, y1)`` holding the central ``mass`` of each marginal."""
        if not 0 < mass < 1:
            raise ValueError("mass: must lie in (0, 1)")
        t = self.table
        tot = t.sum()
        if not tot > 0:
            raise ValueError("table: has no mass")
        g = np.linspace(-1, 1, self.resolution)
        lo, hi = (1 - mass) / 2, 1 - (1 - mass) / 2
        cx = np.cumsum(t.sum(0)) / tot
        cy = np.cumsum(t.sum(1)) / tot
        pick = lambda c: (g[max(np.searchsorted(c, lo) - 1, 0)], g[min(np.searchsorted(c, hi) + 1, len(g) - 1)])  # noqa: E731
        (x0, x1), (y0, y1) = pick(cx), pick(cy)
        return float(x0), float(x1), float(y0), float(y1)

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean slope ``E[(x, y)]`` and slope covariance (2x2) under the projected-area measure.

        Slopes are ``(x, y) = -(m_x, m_y) / m_z`` (the surface gradient); for a Beckmann lobe the
        per-axis variance is ``alpha^2 / 2``.
        """
        X, Y = self.grid()
        r2 = X**2 + Y**2
        inside = r2 < 1 - 1e-9
        w = np.where(inside, self.table, 0.0)
        w = w / w.sum()
        mz = np.sqrt(np.where(inside, 1 - r2, 1.0))
        sx, sy = -X / mz, -Y / mz
        mean = np.array([np.sum(w * sx), np.sum(w * sy)])
        dx, dy = sx - mean[0], sy - mean[1]
        cov = np.array([[np.sum(w * dx * dx), np.sum(w * dx * dy)], [np.sum(w * dx * dy), np.sum(w * dy * dy)]])
        return mean, cov


def splat_table(mx: np.ndarray, my: np.ndarray, weights: np.ndarray, resolution: int,
                batch: np.ndarray | None = None, n_batch: int = 1) -> np.ndarray:
    """Bilinear splat of disk points into ``(n_batch, R, R)`` node sums (vectorised histogram).

    ``batch`` assigns each point to one table (e.g. its texel).  Points outside the unit disk are
    dropped (they cannot be normals of the upper hemisphere).
    """
    R = resolution
    h = 2.0 / (R - 1)
    mx, my, w = (np.asarray(a, dtype=np.float64).ravel() for a in (mx, my, weights))
    b = np.zeros(mx.shape, np.int64) if batch is None else np.asarray(batch, np.int64).ravel()
    keep = (mx * mx + my * my < 1.0) & (w > 0)
    mx, my, w, b = mx[keep], my[keep], w[keep], b[keep]
    fx = np.clip((mx + 1.0) / h, 0, R - 1 - 1e-9)
    fy = np.clip((my + 1.0) / h, 0, R - 1 - 1e-9)
    i0, j0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    tx, ty = fx - i0, fy - j0
    base = b * R * R + j0 * R + i0
    idx = np.concatenate([base, base + 1, base + R, base + R + 1])
    val = np.concatenate([w * (1 - tx) * (1 - ty), w * tx * (1 - ty), w * (1 - tx) * ty, w * tx * ty])
    return np.bincount(idx, val, minlength=n_batch * R * R).reshape(n_batch, R, R)


def _table_from_slopes(sx, sy, weights, resolution, kind, info) -> NDFTable:
    """Normals of slopes ``(sx, sy) = dh/dx, dh/dy`` -> normalised table; weights = projected area."""
    s = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
    mx, my = -sx * s, -sy * s
    node_sum = splat_table(mx, my, weights, resolution)[0]
    total = node_sum.sum()
    if not total > 0:
        raise ValueError("heights: no usable points (every facet/point touches missing data)")
    h = 2.0 / (resolution - 1)
    return NDFTable(node_sum / (total * h * h), kind, info)


def _prepare(heights, pixel_um, detilt: bool) -> HeightField:
    hf = as_heightfield(heights, pixel_um)
    return hf.detilted() if detilt else hf


# ============================================================================ naive NDF


def naive_ndf(heights, pixel_um=None, resolution: int = 1025, detilt: bool = True) -> NDFTable:
    """Naive geometric NDF (eq. 2 as a histogram; §5.1): two triangles per grid cell, weighted by area.

    Each triangle's normal goes into the table with its projected area ``pixel_um^2 / 2``
    (projected-area weighting makes the table ``D`` itself, see module doc).  Triangles with a
    missing (NaN) vertex are excluded.  ``heights`` (µm) may be a :class:`HeightField`.
    """
    resolution = _check_resolution(resolution)
    hf = _prepare(heights, pixel_um, detilt)
    h, d = hf.heights, hf.pixel_um
    h00, h10, h01, h11 = h[:-1, :-1], h[:-1, 1:], h[1:, :-1], h[1:, 1:]
    # lower-left triangle (p00, p10, p01) and upper-right triangle (p11, p01, p10)
    sx = np.concatenate([(h10 - h00).ravel(), (h11 - h01).ravel()]) / d
    sy = np.concatenate([(h01 - h00).ravel(), (h11 - h10).ravel()]) / d
    ok = np.isfinite(sx) & np.isfinite(sy)
    return _table_from_slopes(sx[ok], sy[ok], np.ones(ok.sum()), resolution, "naive",
                              {"pixel_um": d, "n_facets": int(ok.sum())})


# ============================================================================ filtered NDF


@lru_cache(maxsize=8)
def _kernel_spectra(shape_pad: tuple[int, int], sig_px: float, radius: int):
    """rFFTs of the six separable moment kernels (flipped for correlation), cached per size."""
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (t / sig_px) ** 2)
    # correlation  sum_u w(u) f(p+u) == convolution with w(-u): flip odd kernels
    k0, k1, k2 = g, -t * g, t * t * g
    kern = {
        "0": np.outer(k0, k0), "x": np.outer(k0, k1), "y": np.outer(k1, k0),
        "xx": np.outer(k0, k2), "yy": np.outer(k2, k0), "xy": np.outer(k1, k1),
    }
    return {name: sfft.rfft2(k, shape_pad) for name, k in kern.items()}


def filtered_slopes(heights, pixel_um=None, sigma_um: float = 1.0, detilt: bool = True,
                    min_weight: float = 0.05, border_sigmas: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slopes of the Gaussian-weighted least-squares plane at every data point (§5.1).

    At each measured point ``p`` solve ``min_{a,b,c} sum_u w(u) M(p+u) (h(p+u) - a - b u_x - c u_y)^2``
    with ``w`` a 2D Gaussian of std ``sigma_um`` (truncated at 4 sigma) and ``M`` the measured-point
    mask; the grid border counts as missing, so border points use a one-sided window.  All
    moment sums are FFT convolutions.  Returns ``(dh/dx, dh/dy, ok)``; ``ok`` is False on missing
    points and where the local fit is ill-conditioned (masked weight below ``min_weight`` of the
    full kernel, or a near-singular normal matrix).  ``border_sigmas > 0`` also drops points closer
    than that many sigma to the scan border (their one-sided windows smooth less, which widens
    the NDF slightly; the paper keeps every point, which is the default).
    """
    hf = _prepare(heights, pixel_um, detilt)
    if not (np.isfinite(sigma_um) and sigma_um > 0):
        raise ValueError(f"sigma_um: must be a positive filter width in micrometres, got {sigma_um!r}")
    d = hf.pixel_um
    sig_px = sigma_um / d
    if sig_px < 0.3:
        raise ValueError(f"sigma_um: {sigma_um} µm is below 0.3 pixels ({d} µm); use naive_ndf for unfiltered normals")
    ny, nx = hf.shape
    radius = int(math.ceil(4.0 * sig_px))
    if radius > 2 * max(ny, nx):
        raise ValueError(f"sigma_um: {sigma_um} µm is far larger than the scan ({nx} x {ny} px of {d} µm)")
    M = hf.valid.astype(np.float64)
    hc = np.where(hf.valid, hf.heights - np.nanmean(hf.heights), 0.0)
    shape_pad = (sfft.next_fast_len(ny + 2 * radius, real=True), sfft.next_fast_len(nx + 2 * radius, real=True))
    K = _kernel_spectra(shape_pad, float(sig_px), radius)
    FM = sfft.rfft2(M, shape_pad)
    FH = sfft.rfft2(hc, shape_pad)
    sl = (slice(radius, radius + ny), slice(radius, radius + nx))

    def conv(F, k):
        return sfft.irfft2(F * K[k], shape_pad)[sl]

    # moments in pixel units (u in px)
    S0, Sx, Sy = conv(FM, "0"), conv(FM, "x"), conv(FM, "y")
    Sxx, Syy, Sxy = conv(FM, "xx"), conv(FM, "yy"), conv(FM, "xy")
    H0, Hx, Hy = conv(FH, "0"), conv(FH, "x"), conv(FH, "y")
    # solve [[S0,Sx,Sy],[Sx,Sxx,Sxy],[Sy,Sxy,Syy]] [a,b,c] = [H0,Hx,Hy] for b, c (Cramer)
    c00 = Sxx * Syy - Sxy * Sxy
    c01 = Sxy * Sy - Sx * Syy
    c02 = Sx * Sxy - Sxx * Sy
    det = S0 * c00 + Sx * c01 + Sy * c02
    # b = det([[S0,H0,Sy],[Sx,Hx,Sxy],[Sy,Hy,Syy]]) / det
    b = (S0 * (Hx * Syy - Sxy * Hy) - H0 * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Hy - Hx * Sy)) / np.where(det != 0, det, 1)
    c = (S0 * (Sxx * Hy - Hx * Sxy) - Sx * (Sx * Hy - Hx * Sy) + H0 * (Sx * Sxy - Sxx * Sy)) / np.where(det != 0, det, 1)
    full = 2 * np.pi * sig_px**2  # ~ sum of the full kernel
    full_det = full**3 * sig_px**4  # det of the unmasked interior normal matrix
    ok = hf.valid & (S0 > min_weight * full) & (det > 1e-6 * full_det)
    if border_sigmas > 0:
        nb = int(math.ceil(border_sigmas * sig_px))
        if 2 * nb >= min(ny, nx):
            raise ValueError(f"border_sigmas: {border_sigmas} sigma leaves no interior in a {nx} x {ny} px scan")
        inner = np.zeros_like(ok)
        inner[nb:ny - nb, nb:nx - nb] = True
        ok &= inner
    return np.where(ok, b / d, 0.0), np.where(ok, c / d, 0.0), ok


def filtered_ndf(heights, pixel_um=None, sigma_um: float = 1.0, resolution: int = 1025,
                 detilt: bool = True, border_sigmas: float = 0.0) -> NDFTable:
    """Filtered geometric NDF (§5.1): histogram of the normals of Gaussian-weighted local plane fits.

    Every well-conditioned measured point contributes its pixel area (projected-area weighting,
    so the normalised table is ``D(m)`` per steradian).  ``heights`` in µm (array or
    :class:`HeightField`), ``pixel_um`` and ``sigma_um`` (default 1 µm as in the paper) in µm.
    ``border_sigmas``: see :func:`filtered_slopes` (0 = every point, as in the paper).
    """
    resolution = _check_resolution(resolution)
    hf = _prepare(heights, pixel_um, detilt)
    sx, sy, ok = filtered_slopes(hf, None, sigma_um, detilt=False, border_sigmas=border_sigmas)
    if not ok.any():
        raise ValueError("heights: no point has a well-conditioned local plane fit (too many missing points?)")
    return _table_from_slopes(sx[ok], sy[ok], np.ones(ok.sum()), resolution, "filtered",
                              {"pixel_um": hf.pixel_um, "sigma_um": float(sigma_um), "n_points": int(ok.sum())})


# ============================================================================ Kirchhoff


def _kirchhoff_field(heights: np.ndarray, d: float):
    """Per-pixel integrand pieces: weight (1 measured / 0 missing), slopes (central differences), heights."""
    h = np.asarray(heights, dtype=np.float64)
    gy, gx = np.gradient(h, d)
    w = np.isfinite(h) & np.isfinite(gx) & np.isfinite(gy)
    return w.astype(np.float64), np.where(w, gx, 0.0), np.where(w, gy, 0.0), np.where(w, h, 0.0)


def _check_wavelength(wavelength_um):
    if not (np.isfinite(wavelength_um) and 1e-3 <= wavelength_um <= 1e3):
        raise ValueError(f"wavelength_um: must be a wavelength in [1e-3, 1e3] micrometres, got {wavelength_um!r}")
    return float(wavelength_um)


def kirchhoff_integral_direct(heights, pixel_um, q) -> np.ndarray:
    """Direct sum of the surface integral in eq. 6 (reference; O(N_pixels * N_q)).

    ``I(q) = sum_p dA (q_z - q_x dh/dx - q_y dh/dy) exp(-i (q_x x_p + q_y y_p + q_z h_p))``, i.e.
    ``∫ (q·m) e^{-i q·s} ds`` with ``m ds = (-h_x, -h_y, 1) dx dy``, midpoint rule per pixel, pixel
    ``(j, i)`` at ``(i, j) * pixel_um``; missing pixels contribute 0.  ``q`` (N, 3) in rad/µm.
    """
    d = float(pixel_um)
    w, sx, sy, h = _kirchhoff_field(heights, d)
    ny, nx = h.shape
    yy, xx = np.mgrid[0:ny, 0:nx] * d
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    keep = w.ravel() > 0
    X, Y, Hh, SX, SY = (a.ravel()[keep] for a in (xx, yy, h, sx, sy))
    out = np.empty(len(q), np.complex128)
    chunk = max(1, 2_000_000 // max(len(X), 1))
    for s in range(0, len(q), chunk):  # chunks of q bound memory; the sum itself is vectorised
        qq = q[s:s + chunk]
        phase = np.exp(-1j * (qq[:, :1] * X + qq[:, 1:2] * Y + qq[:, 2:3] * Hh))
        amp = qq[:, 2:3] - qq[:, :1] * SX - qq[:, 1:2] * SY
        out[s:s + chunk] = (amp * phase).sum(1) * d * d
    return out


def _taylor_terms(x: float, tol: float, n_max: int = 80) -> int | None:
    """Smallest N with x^(N+1)/(N+1)! <= tol (Taylor remainder of exp(-i delta h)); None if > n_max."""
    if x <= 0:
        return 0
    lt, lx = math.log(tol), math.log(x)
    for n in range(n_max + 1):
        if (n + 1) * lx - math.lgamma(n + 2) <= lt:
            return n
    return None


def _plan_levels(qz_lo: float, qz_hi: float, H: float, tol: float, max_ffts: int = 3000):
    """Split [qz_lo, qz_hi] into L equal levels minimising L * (terms per level)."""
    best = None
    for L in range(1, 513):
        N = _taylor_terms((qz_hi - qz_lo) / (2 * L) * H, tol)
        if N is None:
            continue
        cost = L * (N + 1)
        if best is None or cost < best[0]:
            best = (cost, L, N + 1)
    if best is None or 3 * best[0] > max_ffts:
        raise ValueError(f"heights: height range {2 * H:.3g} µm is too large for |q| range {qz_hi - qz_lo:.3g} rad/µm "
                         "(surface far rougher than the wavelength; use a longer wavelength_um, smaller max_theta "
                         "or the geometric NDF)")
    _, L, N = best
    edges = np.linspace(qz_lo, qz_hi, L + 1)
    return edges, N


def kirchhoff_integral_fft(heights, pixel_um, k: float, pad: int = 2, max_theta: float | None = None,
                           tol: float = 1e-12):
    """Eq. 6's surface integral on the whole FFT frequency grid with ``|q| = k`` (exact fast scheme).

    For ``q = (q_x, q_y, q_z)`` with ``q_z = sqrt(k^2 - q_x^2 - q_y^2)`` the integral is a 2D DFT of
    ``(q_z - q_x h_x - q_y h_y) exp(-i q_z h)`` -- except that ``q_z`` varies with the output
    frequency.  We split the ``q_z`` range into levels and expand around each level's centre ``c``:
    ``exp(-i q_z h) = exp(-i c h) sum_n (-i (q_z - c))^n h^n / n!``; each term is three FFTs
    (of ``h^n e^{-ich}``, ``h_x h^n e^{-ich}``, ``h_y h^n e^{-ich}``).  Heights are centred so
    ``|h| <= H``; terms are added until the remainder bound ``(|q_z - c| H)^{N+1}/(N+1)! <= tol``
    (relative to the integrand's magnitude), which makes the result equal to
    :func:`kirchhoff_integral_direct` to round-off at the grid frequencies.

    ``pad``: zero-padding factor (2 samples ``|I|^2`` at Nyquist for the intensity).  ``max_theta``:
    only half-vectors within this angle (radians) of ``n`` are computed (others 0).
    Returns ``(qx (Nx,), qy (Ny,), I (Ny, Nx) complex, computed (Ny, Nx) bool)`` with ascending
    (fftshifted) frequency axes in rad/µm.
    """
    d = float(pixel_um)
    if not (isinstance(pad, (int, np.integer)) and 1 <= pad <= 8):
        raise ValueError(f"pad: must be an integer zero-padding factor in [1, 8], got {pad!r}")
    if not (np.isfinite(k) and k > 0):
        raise ValueError(f"k: must be a positive wavenumber |q| in rad/µm, got {k!r}")
    if not (np.isfinite(tol) and 0 < tol < 1):
        raise ValueError(f"tol: must lie in (0, 1), got {tol!r}")
    w, sx, sy, h = _kirchhoff_field(heights, d)
    ny, nx = h.shape
    if w.sum() == 0:
        raise ValueError("heights: no measured point with finite slopes in this patch")
    hv = h[w > 0]
    mid = 0.5 * (hv.max() + hv.min())
    hc = np.where(w > 0, h - mid, 0.0)  # centred; the phase exp(-i q_z mid) is restored at the end
    H = max(0.5 * (hv.max() - hv.min()), 1e-12)
    Py, Px = sfft.next_fast_len(pad * ny), sfft.next_fast_len(pad * nx)
    qx = 2 * np.pi * sfft.fftshift(sfft.fftfreq(Px, d))
    qy = 2 * np.pi * sfft.fftshift(sfft.fftfreq(Py, d))
    QX, QY = np.meshgrid(qx, qy)
    rho2 = QX**2 + QY**2
    cos_min = math.cos(max_theta) if max_theta is not None else 0.0
    computed = rho2 <= (k * k) * (1.0 - cos_min**2)
    QZ = np.sqrt(np.maximum(k * k - rho2, 0.0))
    qz_lo = max(k * cos_min, float(QZ[computed].min()) if computed.any() else k)
    edges, N = _plan_levels(qz_lo, k, H, tol)
    I = np.zeros((Py, Px), np.complex128)
    for j in range(len(edges) - 1):  # loop over q_z levels (few)
        lo, hi = edges[j], edges[j + 1]
        sel = computed & (QZ >= lo) & ((QZ < hi) if j < len(edges) - 2 else (QZ <= hi))
        if not sel.any():
            continue
        c = 0.5 * (lo + hi)
        base = w * np.exp(-1j * c * hc)
        delta = QZ[sel] - c
        acc = np.zeros(sel.sum(), np.complex128)
        hn = base.copy()
        coef = np.ones_like(delta, dtype=np.complex128)
        for n in range(N + 1):  # loop over Taylor orders (few)
            F0 = sfft.fftshift(sfft.fft2(hn, (Py, Px)))[sel]
            Fx = sfft.fftshift(sfft.fft2(hn * sx, (Py, Px)))[sel]
            Fy = sfft.fftshift(sfft.fft2(hn * sy, (Py, Px)))[sel]
            acc += coef * (QZ[sel] * F0 - QX[sel] * Fx - QY[sel] * Fy)
            hn = hn * hc
            coef = coef * (-1j * delta) / (n + 1)
        I[sel] = acc * d * d * np.exp(-1j * QZ[sel] * mid)
    return qx, qy, I, computed


def kirchhoff_patch_dk(heights, pixel_um, wavelength_um: float, pad: int = 2, max_theta: float | None = None,
                       tol: float = 1e-12):
    """``D_K`` (eq. 6) of one patch on its FFT grid: ``|I|^2 / (4 pi^2 A_perp)``, ``A_perp`` = measured area.

    ``wavelength_um`` is the effective Kirchhoff wavelength ``lambda_q`` (eq. 5), so ``|q| = 4 pi / lambda_q``.
    Returns ``(qx, qy, D_K, computed)``.
    """
    lam = _check_wavelength(wavelength_um)
    k = 4 * np.pi / lam
    d = float(pixel_um)
    qx, qy, I, computed = kirchhoff_integral_fft(heights, d, k, pad, max_theta, tol)
    area = np.isfinite(np.asarray(heights, float)).sum() * d * d
    return qx, qy, (I.real**2 + I.imag**2) / (4 * np.pi**2 * area), computed


def kirchhoff_ndf(heights, pixel_um=None, wavelength_um: float = 0.555, patch_um: float | tuple = 70.0,
                  resolution: int = 1025, pad: int = 2, max_theta: float | None = None, tol: float = 1e-10,
                  nan_policy: str = "weight", normalize: bool = False, detilt: bool = True) -> NDFTable:
    """Kirchhoff distribution ``D_K(4 pi h / lambda_q)`` (eq. 6) averaged over coherence patches (App. A).

    The height field is cut into non-overlapping patches of about ``patch_um`` (µm, scalar or
    ``(x, y)``; the paper uses one 70 x 53 µm profilometer scan per patch, ~ the coherence area of
    sunlight); ``D_K`` is computed per patch with :func:`kirchhoff_integral_fft`, averaged, and
    resampled (bilinear) onto the disk table at ``(m_x, m_y) = (q_x, q_y) / |q|``.

    ``wavelength_um`` = ``lambda_q`` (µm).  ``max_theta`` (radians) limits the computed half-vectors
    (default: from the naive NDF, where 99.99 % of its mass lies, plus 5 degrees).  Frequencies
    above the sampling limit ``pi / pixel_um`` cannot be represented and stay 0.
    ``nan_policy``: ``"weight"`` (missing pixels contribute nothing; ``A_perp`` is the measured
    area) or ``"skip"`` (patches with any missing point are left out).  The table keeps the raw
    physical scale of ``D_K`` (its integral is reported as ``info["raw_integral"]``) unless
    ``normalize=True``.
    """
    resolution = _check_resolution(resolution)
    lam = _check_wavelength(wavelength_um)
    if nan_policy not in ("weight", "skip"):
        raise ValueError(f"nan_policy: must be 'weight' or 'skip', got {nan_policy!r}")
    hf = _prepare(heights, pixel_um, detilt)
    d = hf.pixel_um
    pu = np.broadcast_to(np.asarray(patch_um, dtype=np.float64), (2,))
    if not np.all(np.isfinite(pu)) or np.any(pu <= 0):
        raise ValueError(f"patch_um: must be positive patch size(s) in micrometres, got {patch_um!r}")
    ny, nx = hf.shape
    px_x, px_y = (int(min(max(round(p / d), 4), n)) for p, n in zip(pu, (nx, ny)))
    if min(ny, nx) < 4:
        raise ValueError(f"heights: Kirchhoff needs at least 4x4 points, got {hf.shape}")
    k = 4 * np.pi / lam
    if max_theta is None:
        nd = naive_ndf(hf, None, resolution=257, detilt=False)
        X, Y = nd.grid()
        r = np.sqrt(X**2 + Y**2).ravel()
        o = np.argsort(r)
        c = np.cumsum(nd.table.ravel()[o])
        r_max = r[o][min(np.searchsorted(c, 0.9999 * c[-1]), len(r) - 1)]
        max_theta = min(math.asin(min(r_max, 1.0)) + math.radians(5.0), math.radians(89.0))
    # patches: y0:y0+px_y, x0:x0+px_x ; a loop over few patches (each an FFT job)
    acc, n_used, grid = None, 0, None
    for y0 in range(0, ny - px_y + 1, px_y):
        for x0 in range(0, nx - px_x + 1, px_x):
            patch = hf.heights[y0:y0 + px_y, x0:x0 + px_x]
            valid = np.isfinite(patch)
            if valid.sum() < 16 or (nan_policy == "skip" and not valid.all()):
                continue
            qx, qy, dk, _ = kirchhoff_patch_dk(patch, d, lam, pad, max_theta, tol)
            acc = dk if acc is None else acc + dk
            grid = (qx, qy)
            n_used += 1
    if n_used == 0:
        raise ValueError("heights: no usable Kirchhoff patch (too small or too many missing points)")
    dk = acc / n_used
    qx, qy = grid
    dq = (qx[1] - qx[0], qy[1] - qy[0])
    raw = float(dk.sum() * dq[0] * dq[1] / k**2)  # ∫ D_K dm_x dm_y with m_xy = q_xy / k
    g = np.linspace(-1, 1, resolution)
    MX, MY = np.meshgrid(g, g)
    fx = (MX * k - qx[0]) / dq[0]
    fy = (MY * k - qy[0]) / dq[1]
    inside = (fx >= 0) & (fx <= len(qx) - 1) & (fy >= 0) & (fy <= len(qy) - 1) & (MX**2 + MY**2 < 1)
    table = np.where(inside, map_coordinates(dk, [np.clip(fy, 0, len(qy) - 1), np.clip(fx, 0, len(qx) - 1)],
                                             order=1, mode="nearest"), 0.0)
    out = NDFTable(np.maximum(table, 0.0), "kirchhoff",
                   {"pixel_um": d, "wavelength_um": lam, "patches": n_used, "patch_px": (px_x, px_y),
                    "max_theta": float(max_theta), "raw_integral": raw,
                    "nyquist_m": float(np.pi / (d * k))})
    if normalize:
        out = NDFTable(out.table / out.integral(), out.kind, out.info)
    return out
