"""Height-field input for measured microgeometry (Dong et al. 2015, §4).

A :class:`HeightField` holds a regular grid of surface heights in micrometres, the lateral pixel
size in micrometres, and missing points as NaN (profilometers return no height on steep or
ambiguous spots; the paper sees < 5 % of such points).  Array axis 0 is ``y`` (rows), axis 1 is
``x`` (columns); the lateral position of ``heights[j, i]`` is ``(i * pixel_um, j * pixel_um)``.

Readers (:func:`load_heightfield`):

* ``.npy`` - a 2D float array; ``.npz`` - key ``heights`` (or the only array) and optional scalar
  ``pixel_um``;
* ``.exr`` - a float EXR read with :func:`precompute.tables.exr_io.read_exr`, channel ``Z``/``height``/``Y``
  or the only channel; ``pixel_um`` may come from the file's metadata;
* ``.txt``, ``.csv``, ``.asc``, ``.dat`` - a plain grid of numbers (whitespace or comma separated,
  ``#`` comments, ``nan`` or empty cells for missing points);
* instrument formats (``.sur``, ``.plu``, ``.datx``, ``.x3p``, ``.vk4`` ...) are *not* parsed here:
  the well-kept ``surfalize`` package reads them and is used if it is installed (it is not a
  requirement of this project; install it yourself to enable these formats).

Height units: values are taken as micrometres unless ``height_scale`` says otherwise (e.g.
``height_scale=1e-3`` for nanometre data).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..validation import check_seed

__all__ = ["HeightField", "load_heightfield", "save_heightfield", "HeightFieldError", "INSTRUMENT_SUFFIXES",
           "as_heightfield", "detilt", "fit_plane", "Plane", "gaussian_surface", "spectral_slope_covariance",
           "smoothed_heights", "MAX_POINTS", "MAX_SIDE"]

INSTRUMENT_SUFFIXES = (".sur", ".plu", ".plux", ".datx", ".x3p", ".vk4", ".vk6", ".vk7", ".sdf", ".opd", ".nms", ".gwy")
TEXT_SUFFIXES = (".txt", ".csv", ".asc", ".dat", ".xyz")


#: largest accepted height field: 2**25 points (e.g. 5792^2 or 8192 x 4096).  The field is kept as a float64
#: copy (256 MiB at the limit) and every NDF streams it in tiles, so peak memory stays under 1 GiB.
MAX_POINTS = 1 << 25
#: largest |height| accepted (µm): squares of heights and slopes stay far from float64 overflow
MAX_HEIGHT_UM = 1e9
#: longest side of a synthetic test surface
MAX_SIDE = 8192


class HeightFieldError(ValueError):
    """A height-field file or array is unusable (bad shape, no data, unreadable)."""


@dataclass(frozen=True)
class HeightField:
    """Heights (µm) on a square grid of pitch ``pixel_um`` (µm); NaN marks missing points."""

    heights: np.ndarray
    pixel_um: float
    source: str = field(default="", compare=False)

    def __post_init__(self):
        h = np.asarray(self.heights)
        if h.dtype.kind not in "fiu":
            raise HeightFieldError(f"heights: expected a real numeric array, got dtype {h.dtype}")
        if h.ndim != 2:
            raise HeightFieldError(f"heights: expected a 2D array, got shape {h.shape}")
        if min(h.shape) < 2:
            raise HeightFieldError(f"heights: need at least 2x2 points, got shape {h.shape}")
        if h.size > MAX_POINTS:  # before the copy
            raise HeightFieldError(f"heights: {h.shape[1]} x {h.shape[0]} = {h.size / 1e6:.1f} M points exceeds the "
                                   f"{MAX_POINTS / 1e6:.1f} M-point limit (kept as float64 and streamed under 1 GiB); "
                                   "crop the scan or split it into parts")
        try:
            p = float(self.pixel_um) if np.ndim(self.pixel_um) == 0 else float("nan")
        except (TypeError, ValueError):
            p = float("nan")
        if not (np.isfinite(p) and 1e-6 <= p <= 1e6):
            raise HeightFieldError(f"pixel_um: must be a finite pixel size in [1e-6, 1e6] micrometres, got {self.pixel_um!r}")
        h = np.array(h, dtype=np.float64)  # own copy
        hi, lo = np.fmax.reduce(h, axis=None), np.fmin.reduce(h, axis=None)  # NaN-ignoring, no temporaries
        if not (np.isfinite(hi) and np.isfinite(lo)):
            np.copyto(h, np.nan, where=np.isinf(h))  # +-inf from instruments are missing points too
            hi, lo = np.fmax.reduce(h, axis=None), np.fmin.reduce(h, axis=None)
        if np.isnan(hi):
            raise HeightFieldError("heights: every point is missing (NaN)")
        big = float(max(hi, -lo))
        if big > MAX_HEIGHT_UM:
            raise HeightFieldError(f"heights: values up to {big:.3g} µm exceed +-{MAX_HEIGHT_UM:g} µm (1 km); "
                                   "wrong units? (height_scale converts to micrometres)")
        if not (np.isfinite(p) and 1e-6 <= p <= 1e6):
            raise HeightFieldError(f"pixel_um: must be a finite pixel size in [1e-6, 1e6] micrometres, got {self.pixel_um!r}")
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)
        object.__setattr__(self, "pixel_um", p)

    @property
    def shape(self) -> tuple[int, int]:
        return self.heights.shape

    @property
    def valid(self) -> np.ndarray:
        """Boolean mask of measured (non-NaN) points."""
        return np.isfinite(self.heights)

    @property
    def missing_fraction(self) -> float:
        return float(1.0 - self.valid.mean())

    @property
    def size_um(self) -> tuple[float, float]:
        """Lateral extent ``(width_x, height_y)`` in µm."""
        ny, nx = self.shape
        return nx * self.pixel_um, ny * self.pixel_um

    def detilted(self) -> "HeightField":
        """Copy with the least-squares plane through the valid points removed (mean normal -> +z)."""
        return HeightField(detilt(self.heights, self.pixel_um), self.pixel_um, self.source)

    def crop(self, y0: int, y1: int, x0: int, x1: int) -> "HeightField":
        return HeightField(self.heights[y0:y1, x0:x1], self.pixel_um, self.source)

    def cache_key(self) -> dict:
        return {"heights": self.heights, "pixel_um": self.pixel_um}


def as_heightfield(heights, pixel_um=None) -> HeightField:
    """Accept a :class:`HeightField` or a 2D array plus ``pixel_um``."""
    if isinstance(heights, HeightField):
        if pixel_um is not None and float(pixel_um) != heights.pixel_um:
            raise HeightFieldError("pixel_um: conflicts with the HeightField's own pixel size")
        return heights
    if pixel_um is None:
        raise HeightFieldError("pixel_um: required (micrometres per pixel) when heights is a plain array")
    return HeightField(heights, pixel_um)


@dataclass(frozen=True)
class Plane:
    """The least-squares plane ``h = a + b (x - x0) + c (y - y0)`` through the valid points of a height
    field (µm; ``b``, ``c`` are slopes dh/dx, dh/dy; ``x0``, ``y0`` the mean position of the valid points)."""

    a: float
    b: float
    c: float
    x0: float
    y0: float
    pixel_um: float

    def values(self, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
        """The plane on rows ``y0:y1`` and columns ``x0:x1`` (pixel indices; any range, also outside the scan)."""
        d = self.pixel_um
        x = np.arange(x0, x1) * d - self.x0
        y = np.arange(y0, y1) * d - self.y0
        return (self.a + self.c * y)[:, None] + (self.b * x)[None, :]


_ROWS = 256  # rows per chunk of the streamed plane fit (bounded temporaries on large scans)


def fit_plane(heights: np.ndarray, pixel_um: float) -> Plane:
    """Least-squares plane through the valid (finite) points, from streamed sums over row chunks.

    Normal equations of ``a + b (x - x0) + c (y - y0)`` (``x0, y0`` the mean position of the valid points):
    one pass accumulates the point count and the sums of x, y, x^2, xy, y^2, h, xh, yh about the grid's centre
    (matrix-vector products per row chunk, no boolean copies), then centres them on ``(x0, y0)``.  No
    ``(N, 3)`` design matrix, so memory stays O(row chunk) on large scans.
    """
    h = np.asarray(heights)
    ny, nx = h.shape
    d = float(pixel_um)
    xp, yp = 0.5 * (nx - 1) * d, 0.5 * (ny - 1) * d  # provisional centre: keeps the sums well conditioned
    xc = np.arange(nx) * d - xp
    S = np.zeros(9)  # n, Sx, Sy, Sxx, Sxy, Syy, Sh, Sxh, Syh about (xp, yp)
    for r0 in range(0, ny, _ROWS):
        blk = np.asarray(h[r0:r0 + _ROWS], np.float64)
        rows = blk.shape[0]
        yc = np.arange(r0, r0 + rows) * d - yp
        ok = np.isfinite(blk)
        if ok.all():
            cnt, colcnt, rowx, hz = np.full(rows, float(nx)), np.full(nx, float(rows)), np.full(rows, xc.sum()), blk
        else:
            okf = ok.astype(np.float64)
            cnt, colcnt, rowx, hz = okf.sum(1), okf.sum(0), okf @ xc, np.where(ok, blk, 0.0)
        hr = hz.sum(1)
        S += [cnt.sum(), colcnt @ xc, cnt @ yc, colcnt @ (xc * xc), yc @ rowx, cnt @ (yc * yc),
              hr.sum(), (hz @ xc).sum(), yc @ hr]
    n = S[0]
    if n < 3:
        raise HeightFieldError("heights: need at least 3 measured points to fit a plane")
    mx, my = S[1] / n, S[2] / n  # mean position of the valid points relative to (xp, yp)
    A = np.array([[n, 0.0, 0.0],
                  [0.0, S[3] - n * mx * mx, S[4] - n * mx * my],
                  [0.0, S[4] - n * mx * my, S[5] - n * my * my]])
    rhs = np.array([S[6], S[7] - mx * S[6], S[8] - my * S[6]])
    coef = np.linalg.lstsq(A, rhs, rcond=None)[0]  # lstsq: a line of points (rank 2) still gets a plane
    return Plane(float(coef[0]), float(coef[1]), float(coef[2]), float(xp + mx), float(yp + my), d)


def detilt(heights: np.ndarray, pixel_um: float) -> np.ndarray:
    """Remove the least-squares plane ``a + b x + c y`` fitted to the valid points; NaNs kept (float64 copy)."""
    h = np.array(heights, dtype=np.float64)
    pl = fit_plane(h, pixel_um)
    for r0 in range(0, h.shape[0], _ROWS):
        h[r0:r0 + _ROWS] -= pl.values(r0, min(r0 + _ROWS, h.shape[0]), 0, h.shape[1])
    return h


def _pick_npz(z, path):
    keys = list(z.keys())
    if "heights" in keys:
        h = z["heights"]
    else:
        arrays = [k for k in keys if k != "pixel_um" and z[k].ndim == 2]
        if len(arrays) != 1:
            raise HeightFieldError(f"{path}: .npz needs a 'heights' array (found keys {keys})")
        h = z[arrays[0]]
    px = float(z["pixel_um"]) if "pixel_um" in keys and np.ndim(z["pixel_um"]) == 0 else None
    return h, px


def _read_text(path):
    rows = []
    with open(path, "r", encoding="utf-8", errors="strict") as f:
        for line in f:
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            cells = line.replace(";", ",").split(",") if "," in line or ";" in line else line.split()
            try:
                rows.append([float(c) if c.strip() not in ("", "-") else np.nan for c in cells])
            except ValueError as exc:
                raise HeightFieldError(f"{path}: non-numeric cell in text grid ({exc})") from exc
    if not rows:
        raise HeightFieldError(f"{path}: empty text grid")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise HeightFieldError(f"{path}: ragged text grid (row lengths {sorted(widths)})")
    return np.array(rows, dtype=np.float64)


def _read_exr(path):
    from ..tables.exr_io import read_exr  # noqa: PLC0415 - OpenEXR only when needed

    chans, meta = read_exr(path)
    for name in ("Z", "height", "heights", "Y", "R"):
        if name in chans:
            h = chans[name]
            break
    else:
        if len(chans) != 1:
            raise HeightFieldError(f"{path}: EXR needs a 'Z' or 'height' channel (found {sorted(chans)})")
        h = next(iter(chans.values()))
    px = None
    if isinstance(meta, dict) and "pixel_um" in meta:
        px = float(meta["pixel_um"])
    return h.astype(np.float64), px


def _read_instrument(path):
    try:
        from surfalize import Surface  # noqa: PLC0415 - optional, well-kept instrument reader
    except ImportError as exc:
        raise HeightFieldError(
            f"{path}: instrument format; install the 'surfalize' package to read it, or export the scan "
            "as .npy/.npz/.txt/.exr") from exc
    s = Surface.load(path)
    step_x, step_y = float(s.step_x), float(s.step_y)
    if not np.isclose(step_x, step_y, rtol=1e-3):
        raise HeightFieldError(f"{path}: non-square pixels ({step_x} x {step_y} µm) are not supported")
    return np.asarray(s.data, dtype=np.float64), step_x


def load_heightfield(path: str | os.PathLike, pixel_um: float | None = None, height_scale: float = 1.0) -> HeightField:
    """Read a height field (heights in µm after ``height_scale``; ``pixel_um`` in µm).

    ``pixel_um`` overrides a value stored in the file; one of the two is required.  Raises
    :class:`HeightFieldError` (a ``ValueError``) for missing, unreadable or malformed files.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise HeightFieldError(f"{path}: no such file")
    if not (np.isfinite(height_scale) and height_scale > 0):
        raise HeightFieldError(f"height_scale: must be a positive finite factor to micrometres, got {height_scale}")
    suffix = os.path.splitext(path)[1].lower()
    stored_px = None
    try:
        if suffix == ".npy":
            h = np.load(path, allow_pickle=False)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                h, stored_px = _pick_npz(z, path)
        elif suffix == ".exr":
            h, stored_px = _read_exr(path)
        elif suffix in TEXT_SUFFIXES:
            h = _read_text(path)
        elif suffix in INSTRUMENT_SUFFIXES:
            h, stored_px = _read_instrument(path)
        else:
            raise HeightFieldError(f"{path}: unknown height-field format {suffix!r} "
                                   f"(use .npy, .npz, .exr, {', '.join(TEXT_SUFFIXES)})")
    except HeightFieldError:
        raise
    except (OSError, ValueError, EOFError, UnicodeDecodeError) as exc:
        raise HeightFieldError(f"{path}: unreadable height field ({exc})") from exc
    px = pixel_um if pixel_um is not None else stored_px
    if px is None:
        raise HeightFieldError(f"pixel_um: {path} stores no pixel size; pass pixel_um (micrometres)")
    h = np.asarray(h)
    if h.dtype.kind not in "fiu":
        raise HeightFieldError(f"{path}: heights must be numeric, got dtype {h.dtype}")
    return HeightField(h.astype(np.float64) * height_scale, px, source=path)


def save_heightfield(path: str | os.PathLike, hf: HeightField) -> None:
    """Write a :class:`HeightField` as ``.npz`` (heights + pixel_um) or float ``.exr`` (channel ``Z``)."""
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".npz":
        tmp = path + ".tmp.npz"
        np.savez(tmp, heights=hf.heights, pixel_um=np.float64(hf.pixel_um))
        os.replace(tmp, path)
    elif suffix == ".exr":
        from ..tables.exr_io import write_exr  # noqa: PLC0415

        write_exr(path, {"Z": hf.heights.astype(np.float32)}, meta={"pixel_um": hf.pixel_um, "units": "um"})
    else:
        raise HeightFieldError(f"path: save_heightfield writes .npz or .exr, got {suffix!r}")


# ----------------------------------------------------------------------------- synthetic surfaces


def gaussian_surface(shape: tuple[int, int], pixel_um: float, rms_height_um: float, corr_um,
                     seed: int = 0) -> HeightField:
    """Seeded periodic Gaussian random surface with a Gaussian spectrum (test surfaces, issue item 7).

    Height covariance ``C(x, y) = s^2 exp(-x^2/lx^2 - y^2/ly^2)`` with ``corr_um = lx`` or
    ``(lx, ly)``; ``lx >> ly`` gives a brushed surface with scratches along x.  Exact amplitude
    spectrum with uniformly random phases, so the realisation's height variance equals
    ``rms_height_um^2`` exactly and its slope variances equal :func:`spectral_slope_covariance`
    (continuum value ``2 s^2 / l^2`` per axis when ``l >> pixel_um``).
    """
    try:
        ny, nx = (int(v) for v in shape)
        lx, ly = np.broadcast_to(np.asarray(corr_um, dtype=np.float64), (2,))
        rms_height_um, pixel_um = float(rms_height_um), float(pixel_um)
    except (TypeError, ValueError):
        raise HeightFieldError(f"shape, corr_um, rms_height_um, pixel_um: expected (ny, nx) integers and positive "
                               f"numbers, got {shape!r}, {corr_um!r}, {rms_height_um!r}, {pixel_um!r}") from None
    if not (2 <= ny <= MAX_SIDE and 2 <= nx <= MAX_SIDE):
        raise HeightFieldError(f"shape: each side must lie in [2, {MAX_SIDE}], got {shape}")
    vals = np.array([lx, ly, rms_height_um, pixel_um])
    if not (np.all(np.isfinite(vals)) and np.all(vals > 0)):
        raise HeightFieldError("corr_um, rms_height_um, pixel_um: must be positive and finite")
    seed = check_seed("seed", seed)
    # real FFTs of real noise (Hermitian half spectrum): the same surface as full complex FFTs, half the memory
    kx = 2 * np.pi * np.fft.rfftfreq(nx, pixel_um)
    ky = 2 * np.pi * np.fft.fftfreq(ny, pixel_um)
    rng = np.random.default_rng(seed)
    spec = np.fft.rfft2(rng.standard_normal((ny, nx)))
    spec /= np.maximum(np.abs(spec), 1e-300)
    spec *= np.exp(-(ky[:, None] ** 2 * ly**2) / 8.0)  # sqrt of the PSD exp(-k^2 l^2 / 4), separable
    spec *= np.exp(-(kx[None, :] ** 2 * lx**2) / 8.0)
    spec[0, 0] = 0.0
    h = np.fft.irfft2(spec, (ny, nx))
    del spec
    h *= rms_height_um / np.sqrt(np.mean(h * h))
    return HeightField(h, pixel_um, source=f"gaussian_surface(seed={seed})")


#: A scan is a periodic tile when both wrap-around seams are as smooth as its interior: the rms height step across
#: each seam at most this many times the rms step between interior neighbours along the same axis (a measured,
#: non-periodic scan's seam steps are of the order of its rms height: tens to hundreds of neighbour steps).
PERIODIC_SEAM_RATIO = 3.0


def is_periodic(heights) -> bool:
    """True if ``heights`` (2D, µm) tile seamlessly: no missing point, and the steps across both wrap-around
    seams (last column -> first, last row -> first) have an rms at most ``PERIODIC_SEAM_RATIO`` times that of
    the steps between interior neighbours along the same axis (synthetic FFT surfaces; not measured scans)."""
    h = np.asarray(heights)
    if h.ndim != 2 or min(h.shape) < 4 or h.dtype.kind not in "fiu":
        return False
    ny, nx = h.shape
    sq = np.zeros(2)            # sums of squared neighbour steps along y and x, in row blocks (bounded memory)
    for y0 in range(0, ny, 256):
        blk = np.asarray(h[y0:min(y0 + 257, ny)], np.float64)
        if not np.all(np.isfinite(blk)):
            return False
        sq[0] += float(np.sum(np.diff(blk, axis=0) ** 2))
        sq[1] += float(np.sum(np.diff(blk[:256], axis=1) ** 2))
    rms_inner = np.sqrt(sq / np.array([(ny - 1) * nx, ny * (nx - 1)]))
    seams = (np.asarray(h[0], np.float64) - np.asarray(h[-1], np.float64),
             np.asarray(h[:, 0], np.float64) - np.asarray(h[:, -1], np.float64))
    for rms, seam in zip(rms_inner, seams):
        if not rms > 0 or float(np.sqrt(np.mean(seam * seam))) > PERIODIC_SEAM_RATIO * rms:
            return False
    return True


def spectral_slope_covariance(heights: np.ndarray, pixel_um: float, sigma_um: float = 0.0) -> np.ndarray:
    """Slope covariance of a *periodic* height field from its spectrum, optionally Gaussian-filtered.

    ``sigma_um > 0`` applies the transfer function ``exp(-sigma^2 |k|^2 / 2)`` to the slopes: the
    Gaussian-weighted least-squares plane slope equals the Gaussian-smoothed gradient (integrate
    ``∫ w(u) u_x h(p+u) du`` by parts), so this is the independent reference for
    :func:`precompute.microgeometry.filtered_slopes` away from the border.
    """
    h = np.asarray(heights, dtype=np.float64)
    ny, nx = h.shape
    F = np.fft.fft2(h - h.mean())
    kx = 2 * np.pi * np.fft.fftfreq(nx, pixel_um)
    ky = 2 * np.pi * np.fft.fftfreq(ny, pixel_um)
    KX, KY = np.meshgrid(kx, ky)
    P = np.abs(F) ** 2 / (nx * ny) ** 2 * np.exp(-(sigma_um**2) * (KX**2 + KY**2))
    return np.array([[np.sum(KX * KX * P), np.sum(KX * KY * P)], [np.sum(KX * KY * P), np.sum(KY * KY * P)]])


def smoothed_heights(heights, pixel_um: float, sigma_um: float) -> np.ndarray:
    """A *periodic* height field (µm) convolved with the 2D Gaussian of std ``sigma_um`` (µm), via FFT.

    The explicit surface the filtered NDF (§5.1) describes: the Gaussian-weighted least-squares plane
    slope at a point equals the Gaussian-smoothed gradient (see :func:`spectral_slope_covariance`), so the
    normals of this surface are the filtered NDF's normals (away from a finite scan's border, where the
    filter's window is one-sided).  Used by the explicit-geometry ground truth of the NDF materials."""
    h = np.asarray(heights, dtype=np.float64)
    if h.ndim != 2 or not np.all(np.isfinite(h)):
        raise HeightFieldError("heights: expected a finite 2D array (a periodic tile, no missing points)")
    pixel_um, sigma_um = float(pixel_um), float(sigma_um)
    if not (np.isfinite(pixel_um) and pixel_um > 0 and np.isfinite(sigma_um) and sigma_um >= 0):
        raise HeightFieldError(f"pixel_um, sigma_um: expected a positive pixel size and a sigma >= 0, "
                               f"got {pixel_um!r}, {sigma_um!r}")
    ny, nx = h.shape
    kx = 2 * np.pi * np.fft.rfftfreq(nx, pixel_um)
    ky = 2 * np.pi * np.fft.fftfreq(ny, pixel_um)
    gain = np.exp(-0.5 * sigma_um ** 2 * (ky[:, None] ** 2 + kx[None, :] ** 2))
    return np.fft.irfft2(np.fft.rfft2(h) * gain, (ny, nx))
