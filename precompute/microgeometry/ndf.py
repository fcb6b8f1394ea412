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
import os
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy import fft as sfft
from scipy.ndimage import map_coordinates

from ..parallel import ordered_map
from .ellipsoid import ellipsoid_ndf, fit_beckmann, fit_ellipsoid, fit_ggx  # noqa: F401 - re-exports
from .heightfield import MAX_POINTS, HeightField, Plane, as_heightfield, fit_plane, is_periodic

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


#: largest NDF table side: a 4097^2 float64 table is 128 MiB (a few copies stay under the 1 GiB bound)
MAX_RESOLUTION = 4097


def _check_resolution(resolution) -> int:
    if (isinstance(resolution, (bool, np.bool_)) or not isinstance(resolution, (int, np.integer))
            or resolution < 9 or resolution > MAX_RESOLUTION or resolution % 2 == 0):
        raise ValueError(f"resolution: must be an odd integer in [9, {MAX_RESOLUTION}] (node at the disk centre), "
                         f"got {resolution!r}")
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


def _splat_cells(sx, sy, R: int):
    """Bilinear splat of the normals of slopes ``(sx, sy)`` (unit weight each), ``_SPLAT_CHUNK`` points at a time
    (bounded temporaries): yields ``(j, i, acc)``, the node sums ``acc`` (2D) of the table's nodes
    ``[j : j + acc.shape[0], i : i + acc.shape[1]]``.

    Per cell of the lower-left node ``(i0, j0)``: the count C and the sums X, Y, XY of tx, ty and tx ty, since
    the four bilinear weights are ``1 - tx - ty + tx ty``, ``tx - tx ty``, ``ty - tx ty`` and ``tx ty``."""
    sx = np.asarray(sx, np.float64).ravel()
    sy = np.asarray(sy, np.float64).ravel()
    h = 2.0 / (R - 1)
    for a in range(0, sx.size, _SPLAT_CHUNK):
        px, py = sx[a:a + _SPLAT_CHUNK], sy[a:a + _SPLAT_CHUNK]
        q = px * px
        q += py * py      # |slope|^2
        if not q.max() < 1e15:  # slopes so steep that m_z rounds to 0 (|m| = 1 on the disk's rim): dropped
            keep = q < 1e15
            px, py, q = px[keep], py[keep], q[keep]
            if not q.size:
                continue
        q += 1.0
        np.sqrt(q, out=q)
        q *= h
        np.reciprocal(q, out=q)  # 1 / (h sqrt(1 + |slope|^2))
        # node coordinates (m + 1) / h of the normal m = -(px, py) / sqrt(1 + |slope|^2)
        fx = px * q
        np.subtract(1.0 / h, fx, out=fx)
        np.clip(fx, 0, R - 1 - 1e-9, out=fx)
        fy = py * q
        np.subtract(1.0 / h, fy, out=fy)
        np.clip(fy, 0, R - 1 - 1e-9, out=fy)
        del q
        j0 = fy.astype(np.int64)
        fy -= j0                 # ty
        i0 = fx.astype(np.int64)
        fx -= i0                 # tx
        # node sums on the bounding box of the touched nodes (rows jl..jl+ny-1, columns il..il+W-1): with one
        # spare row and column, the +1 / +W neighbours of flat box indices never wrap
        jl, il = int(j0.min()), int(i0.min())
        W = int(i0.max()) - il + 2
        ny = int(j0.max()) - jl + 2
        j0 -= jl
        j0 *= W
        i0 -= il
        j0 += i0
        base = j0
        del i0, j0
        n = ny * W
        acc = np.bincount(base, minlength=n).astype(np.float64)
        X = np.bincount(base, fx, minlength=n)
        Y = np.bincount(base, fy, minlength=n)
        fx *= fy
        XY = np.bincount(base, fx, minlength=n)
        del base, fx, fy
        acc -= X
        acc -= Y
        acc += XY
        X -= XY
        Y -= XY
        acc[1:] += X[:-1]
        acc[W:] += Y[:-W]
        acc[W + 1:] += XY[:-W - 1]
        yield jl, il, acc.reshape(ny, W)


def _splat_slopes(flat: np.ndarray, sx, sy, R: int) -> None:
    """Add the bilinear splat of the normals of slopes ``(sx, sy)`` (unit weight each) to ``flat`` (R*R node
    sums, float64) in place (see :func:`_splat_cells`)."""
    table = flat.reshape(R, R)
    for j, i, acc in _splat_cells(sx, sy, R):
        table[j:j + acc.shape[0], i:i + acc.shape[1]] += acc


def _normalised_table(flat: np.ndarray, R: int, kind, info) -> NDFTable:
    total = flat.sum()
    if not total > 0:
        raise ValueError("heights: no usable points (every facet/point touches missing data)")
    h = 2.0 / (R - 1)
    flat /= total * h * h
    return NDFTable(flat.reshape(R, R), kind, info)


def _table_from_slopes(sx, sy, weights, resolution, kind, info) -> NDFTable:
    """Normals of slopes ``(sx, sy) = dh/dx, dh/dy`` -> normalised table; weights = projected area."""
    s = 1.0 / np.sqrt(1.0 + sx * sx + sy * sy)
    mx, my = -sx * s, -sy * s
    node_sum = splat_table(mx, my, weights, resolution)[0]
    return _normalised_table(node_sum.ravel(), resolution, kind, info)


def _prepare(heights, pixel_um, detilt: bool) -> tuple[HeightField, Plane | None]:
    """The height field and, with ``detilt``, its least-squares plane (subtracted on the fly, no copy)."""
    hf = as_heightfield(heights, pixel_um)
    return hf, (fit_plane(hf.heights, hf.pixel_um) if detilt else None)


def _tiles(ny: int, nx: int, T: int):
    for y0 in range(0, ny, T):
        for x0 in range(0, nx, T):
            yield y0, min(y0 + T, ny), x0, min(x0 + T, nx)


def _workers() -> int:
    return max(1, min(2, os.cpu_count() or 1))




# ============================================================================ naive NDF


def naive_ndf(heights, pixel_um=None, resolution: int = 1025, detilt: bool = True) -> NDFTable:
    """Naive geometric NDF (eq. 2 as a histogram; §5.1): two triangles per grid cell, weighted by area.

    Each triangle's normal goes into the table with its projected area ``pixel_um^2 / 2``
    (projected-area weighting makes the table ``D`` itself, see module doc).  Triangles with a
    missing (NaN) vertex are excluded.  ``heights`` (µm) may be a :class:`HeightField`.
    """
    resolution = _check_resolution(resolution)
    hf, plane = _prepare(heights, pixel_um, detilt)
    h, d = hf.heights, hf.pixel_um
    pb, pc = (plane.b, plane.c) if plane is not None else (0.0, 0.0)
    R = resolution
    flat = np.zeros(R * R)
    n_facets = 0
    rows = max(1, _TILE_POINTS // h.shape[1])  # row bands of ~_TILE_POINTS points: bounded temporaries
    for r0 in range(0, h.shape[0] - 1, rows):
        b = h[r0:r0 + rows + 1]
        h00, h10, h01, h11 = b[:-1, :-1], b[:-1, 1:], b[1:, :-1], b[1:, 1:]
        # lower-left triangle (p00, p10, p01) and upper-right triangle (p11, p01, p10); the plane's
        # slopes are subtracted exactly (detilting does not change a triangle's shape otherwise)
        sx = np.concatenate([(h10 - h00).ravel(), (h11 - h01).ravel()]) / d - pb
        sy = np.concatenate([(h01 - h00).ravel(), (h11 - h10).ravel()]) / d - pc
        ok = np.isfinite(sx) & np.isfinite(sy)
        n_facets += int(ok.sum())
        _splat_slopes(flat, sx[ok], sy[ok], R)
    return _normalised_table(flat, R, "naive", {"pixel_um": d, "n_facets": n_facets})


# ============================================================================ filtered NDF


@lru_cache(maxsize=8)
def _kernel_spectra(shape_pad: tuple[int, int], sig_px: float, radius: int, dtype: str = "float64"):
    """rFFTs of the six separable moment kernels (flipped for correlation), cached per size and precision."""
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (t / sig_px) ** 2)
    # correlation  sum_u w(u) f(p+u) == convolution with w(-u): flip odd kernels
    k0, k1, k2 = g, -t * g, t * t * g
    kern = {
        "0": np.outer(k0, k0), "x": np.outer(k0, k1), "y": np.outer(k1, k0),
        "xx": np.outer(k0, k2), "yy": np.outer(k2, k0), "xy": np.outer(k1, k1),
    }
    return {name: sfft.rfft2(k.astype(dtype), shape_pad) for name, k in kern.items()}


def _full_window_moments(sig_px: float, radius: int) -> tuple[float, float]:
    """``S0`` and ``Sxx = Syy`` of a window with every point measured (``Sx = Sy = Sxy = 0`` by symmetry)."""
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (t / sig_px) ** 2)
    return float(g.sum() ** 2), float((t * t * g).sum() * g.sum())


#: core tile side (px) of the streamed filtered NDF, points per band of the naive NDF, and the largest
#: filter (sigma in pixels: its window is 8 sigma + 1 px wide; wider filters need a coarser scan)
_TILE = 512
_TILE_POINTS = 1 << 20
_SPLAT_CHUNK = 1 << 20
#: largest padded FFT of one Kirchhoff patch (points): ~160 bytes per point of working memory
MAX_KIRCHHOFF_FFT = 1 << 21
MAX_SIGMA_PX = 128.0


def _check_sigma(sigma_um, d: float, shape) -> tuple[float, int]:
    try:
        sigma_um = float(sigma_um)
    except (TypeError, ValueError):
        raise ValueError(f"sigma_um: must be a positive filter width in micrometres, got {sigma_um!r}") from None
    if not (np.isfinite(sigma_um) and sigma_um > 0):
        raise ValueError(f"sigma_um: must be a positive filter width in micrometres, got {sigma_um!r}")
    sig_px = sigma_um / d
    if sig_px < 0.3:
        raise ValueError(f"sigma_um: {sigma_um} µm is below 0.3 pixels ({d} µm); use naive_ndf for unfiltered normals")
    if sig_px > MAX_SIGMA_PX:
        raise ValueError(f"sigma_um: {sigma_um} µm is {sig_px:.0f} pixels of {d} µm; at most {MAX_SIGMA_PX:g} pixels "
                         f"({MAX_SIGMA_PX * d:.4g} µm) are filtered (resample the scan coarser for wider filters)")
    ny, nx = shape
    radius = int(math.ceil(4.0 * sig_px))
    if radius > 2 * max(ny, nx):
        raise ValueError(f"sigma_um: {sigma_um} µm is far larger than the scan ({nx} x {ny} px of {d} µm)")
    return sig_px, radius


def _axis_moments(i0: int, i1: int, T: int, sig_px: float, radius: int) -> np.ndarray:
    """1D window moments ``m_k(p) = sum_t t^k g(t) I(p + r + t)``, k = 0, 1, 2, of the indicator ``I`` of block
    positions ``[i0, i1)`` for the ``T`` core positions p (block position ``p + r``), in float64."""
    t = np.arange(-radius, radius + 1, dtype=np.float64)
    g = np.exp(-0.5 * (t / sig_px) ** 2)
    pos = np.arange(T)[:, None] + radius + t[None, :].astype(np.int64)  # [T, 2r+1] block positions
    w = ((pos >= i0) & (pos < i1)) * g[None, :]
    return np.stack([w.sum(1), (w * t).sum(1), (w * t * t).sum(1)])


def _block_slopes(hf: HeightField, core, sig_px: float, radius: int, min_weight: float, dtype):
    """Local-plane slopes (per pixel) and ok mask of the core ``(y0, y1, x0, x1)`` of ``hf``.

    The block is the core plus a halo of ``radius`` pixels (outside the scan = missing), so every
    core point sees its whole window.  The block's own least-squares plane is removed in float64
    first and its slopes added back at the end: the FFTs (in ``dtype``) then see only the residual
    roughness, whatever the heights' offset and tilt.  Where the block is entirely inside the scan and
    has no missing point, the mask moments are the constants of a full window (3 FFTs instead of 11).
    """
    y0, y1, x0, x1 = core
    r = radius
    ny, nx = hf.shape
    Ty, Tx = y1 - y0, x1 - x0
    by0, bx0 = y0 - r, x0 - r
    cy0, cy1, cx0, cx1 = max(by0, 0), min(y1 + r, ny), max(bx0, 0), min(x1 + r, nx)
    sub = hf.heights[cy0:cy1, cx0:cx1]
    valid = np.isfinite(sub)
    inside = (cy0 == by0) and (cx0 == bx0) and (cy1 == y1 + r) and (cx1 == x1 + r)
    full = inside and bool(valid.all())
    all_valid = bool(valid.all())
    pl = fit_plane(sub, 1.0) if all_valid or valid.sum() >= 3 else None  # pixel units: slopes per pixel
    H = np.zeros((Ty + 2 * r, Tx + 2 * r), dtype)
    blk = H[cy0 - by0:cy1 - by0, cx0 - bx0:cx1 - bx0]
    if pl is not None:  # residual = heights - plane, in float64, one temporary
        res = np.subtract(sub, (pl.b * (np.arange(sub.shape[1]) - pl.x0))[None, :])
        res -= (pl.a + pl.c * (np.arange(sub.shape[0]) - pl.y0))[:, None]
    else:
        res = np.array(sub)
    if not all_valid:
        res[~valid] = 0.0
    np.copyto(blk, res, casting="unsafe")
    del res
    shape_pad = (sfft.next_fast_len(Ty + 2 * r, real=True), sfft.next_fast_len(Tx + 2 * r, real=True))
    K = _kernel_spectra(shape_pad, float(sig_px), r, np.dtype(dtype).name)
    sl = (slice(2 * r, 2 * r + Ty), slice(2 * r, 2 * r + Tx))  # window centred on block point p is at p + r
    workers = 1

    def conv(F, k, scale=None):
        """The moment ``k`` on the core points in float64 (times ``scale`` if given)."""
        out = sfft.irfft2(F * K[k], shape_pad, workers=workers, overwrite_x=True)[sl]
        return np.multiply(out, scale, dtype=np.float64) if scale is not None else out.astype(np.float64)

    FH = sfft.rfft2(H, shape_pad, workers=workers)
    del H
    full_w = 2 * np.pi * sig_px**2  # ~ sum of the full kernel
    full_det = full_w**3 * sig_px**4  # det of the unmasked interior normal matrix
    core_valid = valid[y0 - cy0:y0 - cy0 + Ty, x0 - cx0:x0 - cx0 + Tx]
    if full:
        S0, Sxx = _full_window_moments(sig_px, r)
        b, c = conv(FH, "x", 1.0 / Sxx), conv(FH, "y", 1.0 / Sxx)
        good = S0 > min_weight * full_w and S0 * Sxx * Sxx > 1e-6 * full_det
        ok = core_valid & good
    else:
        if valid.all():
            # the measured points of the block are a rectangle (the scan's border cuts it): the mask
            # moments are outer products of 1D window moments along y and x, no FFT needed
            my = _axis_moments(cy0 - by0, cy1 - by0, Ty, sig_px, r)
            mx = _axis_moments(cx0 - bx0, cx1 - bx0, Tx, sig_px, r)
            S0, Sx, Sy = np.outer(my[0], mx[0]), np.outer(my[0], mx[1]), np.outer(my[1], mx[0])
            Sxx, Syy, Sxy = np.outer(my[0], mx[2]), np.outer(my[2], mx[0]), np.outer(my[1], mx[1])
        else:
            M = np.zeros((Ty + 2 * r, Tx + 2 * r), dtype)
            M[cy0 - by0:cy1 - by0, cx0 - bx0:cx1 - bx0] = valid
            FM = sfft.rfft2(M, shape_pad, workers=workers)
            del M
            # moments in pixel units (u in px)
            S0, Sx, Sy = conv(FM, "0"), conv(FM, "x"), conv(FM, "y")
            Sxx, Syy, Sxy = conv(FM, "xx"), conv(FM, "yy"), conv(FM, "xy")
            del FM
        H0, Hx, Hy = conv(FH, "0"), conv(FH, "x"), conv(FH, "y")
        # solve [[S0,Sx,Sy],[Sx,Sxx,Sxy],[Sy,Sxy,Syy]] [a,b,c] = [H0,Hx,Hy] for b, c (Cramer, float64)
        c00 = Sxx * Syy - Sxy * Sxy
        c01 = Sxy * Sy - Sx * Syy
        c02 = Sx * Sxy - Sxx * Sy
        det = S0 * c00 + Sx * c01 + Sy * c02
        dd = np.where(det != 0, det, 1)
        b = (S0 * (Hx * Syy - Sxy * Hy) - H0 * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Hy - Hx * Sy)) / dd
        c = (S0 * (Sxx * Hy - Hx * Sxy) - Sx * (Sx * Hy - Hx * Sy) + H0 * (Sx * Sxy - Sxx * Sy)) / dd
        ok = core_valid & (S0 > min_weight * full_w) & (det > 1e-6 * full_det)
    if pl is not None:
        b += pl.b
        c += pl.c
    return b, c, ok


def _warm_allocator() -> None:
    """Let the C allocator keep the tiles' temporaries (~1-2 MiB each) instead of mapping fresh pages for each.

    glibc serves blocks above its mmap threshold (128 KiB at start) with fresh pages (faulted in and zeroed by
    the kernel on first touch, unmapped on free); freeing one mapped block raises the threshold to that block's
    size (up to 32 MiB).  Allocating and freeing one untouched 24 MiB block (no page is touched: it costs
    nothing) does that up front; a long-running Blender session is usually in that state already.  Measured on
    a 4096^2 scan, single thread: ~0.2-0.4 M page faults and 0.5-0.9 s of system time -> ~20 k and ~0.1 s.
    Harmless with other allocators."""
    np.empty(3 << 20)


def _prepare_filtered(heights, pixel_um, detilt: bool, periodic, sigma_um) -> tuple[HeightField, Plane | None, int]:
    """``_prepare`` for the σ filter: (height field, plane or None, wrap-around halo ``_periodic``).  A periodic
    tile keeps no plane (its mean slope is 0; a plane fitted to one period would tilt the NDF) and none is fitted."""
    hf = as_heightfield(heights, pixel_um)
    wrap = _periodic(hf, periodic, sigma_um)
    return hf, (fit_plane(hf.heights, hf.pixel_um) if detilt and not wrap else None), wrap


def _periodic(hf: HeightField, periodic, sigma_um) -> int:
    """The wrap-around halo (pixels) of a periodic scan, 0 if the scan is treated as finite.  ``periodic``:
    False (the paper: the border's windows are one-sided), True, or "auto" (``heightfield.is_periodic``)."""
    if periodic not in (False, True, "auto"):
        raise ValueError(f"periodic: expected True, False or 'auto', got {periodic!r}")
    if periodic is False or (periodic == "auto" and not is_periodic(hf.heights)):
        return 0
    if not np.all(np.isfinite(hf.heights)):
        raise ValueError("periodic: a scan with missing points cannot wrap around (use periodic=False)")
    _, radius = _check_sigma(sigma_um, hf.pixel_um, hf.shape)
    ny, nx = hf.shape
    if (ny + 2 * radius) * (nx + 2 * radius) > MAX_POINTS:
        if periodic == "auto":
            return 0
        raise ValueError(f"periodic: the scan with its {radius} px wrap-around halo exceeds {MAX_POINTS} points")
    return radius


def _filtered_tiles(hf: HeightField, plane, sigma_um, min_weight: float, border_sigmas: float, tile, dtype,
                    post=None, wrap: int = 0):
    """Yield ``(core, dh/dx, dh/dy, ok)`` per tile (µm/µm slopes; the plane's slopes subtracted), or
    ``post(core, dh/dx, dh/dy, ok)`` computed on the worker thread when ``post`` is given.  ``wrap`` > 0: the
    scan is a periodic tile, padded by ``wrap`` pixels of itself on every side (``_periodic``) so every point's
    window is whole (the explicit surface ``heightfield.smoothed_heights`` describes); cores in scan pixels."""
    d = hf.pixel_um
    sig_px, radius = _check_sigma(sigma_um, d, hf.shape)
    if wrap:
        hf = HeightField(np.pad(np.asarray(hf.heights), wrap, mode="wrap"), d)
        border_sigmas = 0.0
    if not (isinstance(min_weight, (int, float, np.integer, np.floating)) and 0.0 <= float(min_weight) < 1.0):
        raise ValueError(f"min_weight: expected a fraction in [0, 1), got {min_weight!r}")
    try:
        border_sigmas = float(border_sigmas)
    except (TypeError, ValueError):
        border_sigmas = float("nan")
    if not (np.isfinite(border_sigmas) and border_sigmas >= 0):
        raise ValueError(f"border_sigmas: expected a number of sigmas >= 0, got {border_sigmas!r}")
    ny, nx = hf.shape
    nb = int(math.ceil(border_sigmas * sig_px)) if border_sigmas > 0 else 0
    if nb and 2 * nb >= min(ny, nx):
        raise ValueError(f"border_sigmas: {border_sigmas} sigma leaves no interior in a {nx} x {ny} px scan")
    pb, pc = (plane.b, plane.c) if plane is not None else (0.0, 0.0)
    if tile is None:
        T = max(ny, nx)
    else:
        T = int(max(tile, 4 * radius))  # tiles at least as wide as the filter's window
        T = sfft.next_fast_len(T + 2 * radius, real=True) - 2 * radius  # block (core + halo) = a fast FFT size
    _warm_allocator()

    def job(core):
        y0, y1, x0, x1 = core     # scan pixels; + wrap in the padded field
        b, c, ok = _block_slopes(hf, (y0 + wrap, y1 + wrap, x0 + wrap, x1 + wrap), sig_px, radius, min_weight, dtype)
        if nb:
            yy = np.arange(y0, y1)[:, None]
            xx = np.arange(x0, x1)[None, :]
            ok &= (yy >= nb) & (yy < ny - nb) & (xx >= nb) & (xx < nx - nb)
        b /= d
        b -= pb
        c /= d
        c -= pc
        return (core, b, c, ok) if post is None else post(core, b, c, ok)

    workers = 1 if tile is None else _workers()
    yield from ordered_map(job, _tiles(ny - 2 * wrap, nx - 2 * wrap, T), workers)


def filtered_slopes(heights, pixel_um=None, sigma_um: float = 1.0, detilt: bool = True,
                    min_weight: float = 0.05, border_sigmas: float = 0.0, *, tile: int | None = _TILE,
                    dtype=np.float32, periodic=False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Slopes of the Gaussian-weighted least-squares plane at every data point (§5.1).

    At each measured point ``p`` solve ``min_{a,b,c} sum_u w(u) M(p+u) (h(p+u) - a - b u_x - c u_y)^2``
    with ``w`` a 2D Gaussian of std ``sigma_um`` (truncated at 4 sigma) and ``M`` the measured-point
    mask; the grid border counts as missing, so border points use a one-sided window.  All
    moment sums are FFT convolutions.  Returns ``(dh/dx, dh/dy, ok)``; ``ok`` is False on missing
    points and where the local fit is ill-conditioned (masked weight below ``min_weight`` of the
    full kernel, or a near-singular normal matrix).  ``border_sigmas > 0`` also drops points closer
    than that many sigma to the scan border (their one-sided windows smooth less, which widens
    the NDF slightly; the paper keeps every point, which is the default).  ``periodic``: True if the scan
    is a periodic tile (windows wrap around: every point's fit is a whole window, the slopes of
    ``heightfield.smoothed_heights``; no border, and no plane removed: a tile's mean slope is 0), "auto" (``heightfield.is_periodic``: seamless scans only), or
    False (default, the paper's finite scan).

    Streaming: the scan is processed in ``tile`` x ``tile`` cores (plus the window's halo), each with
    its own least-squares plane removed in float64, so the FFTs run in ``dtype`` (float32 by default:
    the slopes agree with the float64 whole-field result to ~1e-6 of their spread, see the tests) with
    memory O(tile^2).  ``tile=None, dtype=np.float64`` is the whole-field float64 computation.
    """
    hf, plane, wrap = _prepare_filtered(heights, pixel_um, detilt, periodic, sigma_um)
    ny, nx = hf.shape
    sx = np.zeros((ny, nx))
    sy = np.zeros((ny, nx))
    ok = np.zeros((ny, nx), bool)
    for (y0, y1, x0, x1), b, c, k in _filtered_tiles(hf, plane, sigma_um, min_weight, border_sigmas, tile, dtype,
                                                     wrap=wrap):
        sx[y0:y1, x0:x1] = np.where(k, b, 0.0)
        sy[y0:y1, x0:x1] = np.where(k, c, 0.0)
        ok[y0:y1, x0:x1] = k
    return sx, sy, ok


def filtered_ndf(heights, pixel_um=None, sigma_um: float = 1.0, resolution: int = 1025,
                 detilt: bool = True, border_sigmas: float = 0.0, *, tile: int | None = _TILE,
                 dtype=np.float32, periodic=False) -> NDFTable:
    """Filtered geometric NDF (§5.1): histogram of the normals of Gaussian-weighted local plane fits.

    Every well-conditioned measured point contributes its pixel area (projected-area weighting,
    so the normalised table is ``D(m)`` per steradian).  ``heights`` in µm (array or
    :class:`HeightField`), ``pixel_um`` and ``sigma_um`` (default 1 µm as in the paper) in µm.
    ``border_sigmas``, ``periodic``: see :func:`filtered_slopes` (0 / False = every point, one-sided windows at
    the border, as in the paper).  The slopes are
    computed and splatted tile by tile on two worker threads (``tile``, ``dtype``: see
    :func:`filtered_slopes`), so memory stays bounded (a 4096^2 scan: ~0.6 GiB peak of the whole process
    including its float64 copy, ~1.5 s of CPU time; bench/out/microgeometry_scale.md).
    """
    resolution = _check_resolution(resolution)
    hf, plane, wrap = _prepare_filtered(heights, pixel_um, detilt, periodic, sigma_um)
    R = resolution
    flat = np.zeros(R * R)
    table = flat.reshape(R, R)

    def splat(core, b, c, ok):  # on the worker thread: the tile's node sums (box corner + sums)
        n_ok = int(np.count_nonzero(ok))
        if n_ok < ok.size:
            b, c = b[ok], c[ok]
        return n_ok, list(_splat_cells(b, c, R))

    n = 0
    for n_ok, cells in _filtered_tiles(hf, plane, sigma_um, 0.05, border_sigmas, tile, dtype, post=splat, wrap=wrap):
        n += n_ok
        for j, i, acc in cells:
            table[j:j + acc.shape[0], i:i + acc.shape[1]] += acc
    if n == 0:
        raise ValueError("heights: no point has a well-conditioned local plane fit (too many missing points?)")
    return _normalised_table(flat, R, "filtered",
                             {"pixel_um": hf.pixel_um, "sigma_um": float(sigma_um), "n_points": n,
                              "periodic": bool(wrap)})


# ============================================================================ Kirchhoff


def _kirchhoff_field(heights: np.ndarray, d: float):
    """Per-pixel integrand pieces: weight (1 measured / 0 missing), slopes (central differences), heights."""
    h = np.asarray(heights, dtype=np.float64)
    gy, gx = np.gradient(h, d)
    w = np.isfinite(h) & np.isfinite(gx) & np.isfinite(gy)
    return w.astype(np.float64), np.where(w, gx, 0.0), np.where(w, gy, 0.0), np.where(w, h, 0.0)


def _num(name: str, value) -> float:
    """``value`` as a float (NaN if it is not a number: the caller's range check then names ``name``)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _check_wavelength(wavelength_um):
    wavelength_um = _num("wavelength_um", wavelength_um)
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
    k, tol = _num("k", k), _num("tol", tol)
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
    if Py * Px > MAX_KIRCHHOFF_FFT:
        raise ValueError(f"heights: a {nx} x {ny} px patch padded {pad}x needs {Px} x {Py} FFTs; at most "
                         f"{MAX_KIRCHHOFF_FFT / 2**20:g} M points per patch FFT (~{MAX_KIRCHHOFF_FFT * 160 / 2**30:.1f} GiB)"
                         " -- use a smaller patch_um or pad, or a coarser scan")
    qx_u = 2 * np.pi * sfft.fftfreq(Px, d)  # unshifted FFT order; the output is shifted at the end
    qy_u = 2 * np.pi * sfft.fftfreq(Py, d)
    rho2 = qy_u[:, None] ** 2 + qx_u[None, :] ** 2
    cos_min = math.cos(max_theta) if max_theta is not None else 0.0
    computed = rho2 <= (k * k) * (1.0 - cos_min**2)
    QZ = np.sqrt(np.maximum(k * k - rho2, 0.0))
    del rho2
    qz_lo = max(k * cos_min, float(QZ[computed].min()) if computed.any() else k)
    edges, N = _plan_levels(qz_lo, k, H, tol)
    I = np.zeros((Py, Px), np.complex128)
    for j in range(len(edges) - 1):  # loop over q_z levels (few)
        lo, hi = edges[j], edges[j + 1]
        sel = computed & (QZ >= lo) & ((QZ < hi) if j < len(edges) - 2 else (QZ <= hi))
        if not sel.any():
            continue
        iy, ix = np.nonzero(sel)
        del sel
        qz, qxs, qys = QZ[iy, ix], qx_u[ix], qy_u[iy]
        c = 0.5 * (lo + hi)
        delta = qz - c
        acc = np.zeros(iy.size, np.complex128)
        hn = w * np.exp(-1j * c * hc)
        coef = np.ones_like(delta, dtype=np.complex128)
        for n in range(N + 1):  # loop over Taylor orders (few)
            acc += coef * qz * sfft.fft2(hn, (Py, Px))[iy, ix]
            acc -= coef * qxs * sfft.fft2(hn * sx, (Py, Px))[iy, ix]
            acc -= coef * qys * sfft.fft2(hn * sy, (Py, Px))[iy, ix]
            hn *= hc
            coef = coef * (-1j * delta) / (n + 1)
        I[iy, ix] = acc * d * d * np.exp(-1j * qz * mid)
    return sfft.fftshift(qx_u), sfft.fftshift(qy_u), sfft.fftshift(I), sfft.fftshift(computed)


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
    hf, plane = _prepare(heights, pixel_um, detilt)
    d = hf.pixel_um
    try:
        pu = np.broadcast_to(np.asarray(patch_um, dtype=np.float64), (2,))
    except (TypeError, ValueError):
        raise ValueError(f"patch_um: must be positive patch size(s) in micrometres, got {patch_um!r}") from None
    if not np.all(np.isfinite(pu)) or np.any(pu <= 0):
        raise ValueError(f"patch_um: must be positive patch size(s) in micrometres, got {patch_um!r}")
    ny, nx = hf.shape
    px_x, px_y = (int(min(max(round(p / d), 4), n)) for p, n in zip(pu, (nx, ny)))
    if min(ny, nx) < 4:
        raise ValueError(f"heights: Kirchhoff needs at least 4x4 points, got {hf.shape}")
    if not (isinstance(pad, (int, np.integer)) and 1 <= pad <= 8):
        raise ValueError(f"pad: must be an integer zero-padding factor in [1, 8], got {pad!r}")
    if sfft.next_fast_len(pad * px_y) * sfft.next_fast_len(pad * px_x) > MAX_KIRCHHOFF_FFT:
        raise ValueError(f"patch_um: {patch_um} µm is {px_x} x {px_y} px of {d} µm; padded {pad}x that exceeds "
                         f"{MAX_KIRCHHOFF_FFT / 2**20:g} M points per patch FFT (memory) -- use a smaller patch_um "
                         f"(at most ~{math.isqrt(MAX_KIRCHHOFF_FFT) // pad * d:.4g} µm here) or pad")
    if max_theta is not None:
        try:
            max_theta = float(max_theta)
        except (TypeError, ValueError):
            max_theta = float("nan")
        if not (0.0 < max_theta <= 0.5 * np.pi):
            raise ValueError(f"max_theta: expected None or an angle in (0, pi/2] radians, got {max_theta!r}")
    k = 4 * np.pi / lam
    if max_theta is None:
        nd = naive_ndf(hf, None, resolution=257, detilt=detilt)
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
            if plane is not None:
                patch = patch - plane.values(y0, y0 + px_y, x0, x0 + px_x)
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
