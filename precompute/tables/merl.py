"""Measured isotropic BRDFs in the MERL binary format (Matusik, Pfister, Brand, McMillan 2003, "A
Data-Driven Reflectance Model"), rendered through the tabulated-BRDF closure
(``precompute.tables.tabulated_brdf``).

File layout (the reference reader ``BRDFRead.cpp``): three int32 dims (90, 90, 180), then three
float64 channel blocks (R, G, B) of 90·90·180 values indexed [θh, θd, φd] in C order, scaled by
(1/1500, 1.15/1500, 1.66/1500) to BRDF values in 1/sr; negative values mark missing samples.
Half/difference angles (Rusinkiewicz 1998): h = normalize(ωi + ωo), θh its polar angle; ωi rotated
by -φh about n and by -θh about the binormal gives (θd, φd).  Bins: θh index = ⌊√(θh/(π/2))·90⌋
(denser near the specular peak), θd index = ⌊θd/(π/2)·90⌋, φd index = ⌊φd/π·180⌋ with φd folded
into [0, π) (reciprocity).  ``lookup`` is the reference's nearest-bin lookup, ``interpolate`` the file between
its bin centres (geometric along θh); ``to_tabulated`` resamples ``interpolate`` onto the closure's isotropic grid
(box-averaged over each half-vector cell by default: the half layout keeps sharp lobes' energy at every view, see its
docstring; what the table closure renders of it is deconvolved, ``tables.prefilter.deconvolve_cells``) and attaches
``floor_points``: the file's own θh bins near the peak, where the glossy floor must keep r >= 0 too, so it may be
as sharp as the file (a GGX α 0.02 file at 48² cells: floor α 0.02).  ``lobe_width`` measures the file's specular
peak and ``auto_resolution`` picks the grid that resolves it (the import's default).
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from .. import validation
from .tabulated_brdf import MAX_RES, TabulatedBRDF, reflect

__all__ = ["read_merl", "write_merl", "half_diff", "lookup", "interpolate", "bin_centres", "tabulate", "to_tabulated", "fill_missing",
           "half_vector_grid", "floor_points", "POINT_CELLS", "POINT_PHI", "POINT_BINS_PER_WIDTH",
           "lobe_width", "auto_resolution", "cell_angle", "AUTO_RES_MIN", "AUTO_RES_MAX", "AUTO_N_THETA", "SHAPE", "SCALE"]

SHAPE = (90, 90, 180)
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_N = SHAPE[0] * SHAPE[1] * SHAPE[2]


def read_merl(path) -> np.ndarray:
    """The BRDF (90, 90, 180, 3) in 1/sr from a MERL .binary file (missing samples -> 0).
    ValueError (naming the file) for anything that is not a complete MERL file."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            dims = np.fromfile(f, "<i4", 3)
            data = np.fromfile(f, "<f8", 3 * _N + 1)
    except OSError as exc:
        raise ValueError(f"path: cannot read {path!r} ({exc.strerror or exc})") from None
    if dims.size != 3 or tuple(int(d) for d in dims) != SHAPE:
        raise ValueError(f"path: {path!r} is not a MERL BRDF (expected dims {SHAPE}, got {dims.tolist()})")
    if data.size != 3 * _N:
        raise ValueError(f"path: {path!r} has {data.size} values, a MERL BRDF has {3 * _N} (truncated or padded)")
    t = data.reshape(3, *SHAPE).transpose(1, 2, 3, 0) * SCALE
    t = np.where(np.isfinite(t) & (t > 0), t, 0.0)
    return t


def write_merl(path, table) -> None:
    """Write ``table`` (90, 90, 180, 3), 1/sr, as a MERL .binary file (atomic: a temporary file renamed)."""
    t = validation.finite("table", table)
    if t.shape != (*SHAPE, 3):
        raise ValueError(f"table: expected shape {(*SHAPE, 3)}, got {t.shape}")
    path = os.fspath(path)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), suffix=".part")
    try:
        with os.fdopen(fd, "wb") as f:
            np.asarray(SHAPE, "<i4").tofile(f)
            (t / SCALE).transpose(3, 0, 1, 2).astype("<f8").tofile(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def _rot(v, axis, ang):
    """Rotate vectors v (N, 3) about the unit axis (N, 3) by ang (N,) (Rodrigues)."""
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, 1, keepdims=True) * (1 - c)


def half_diff(wi, wo):
    """(θh, θd, φd) radians of unit direction pairs (N, 3) (surface frame, z = normal); φd in [0, 2π)."""
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th = np.arccos(np.clip(h[:, 2], -1, 1))
    ph = np.arctan2(h[:, 1], h[:, 0])
    n = np.broadcast_to([0.0, 0.0, 1.0], wi.shape)
    b = np.broadcast_to([0.0, 1.0, 0.0], wi.shape)
    d = _rot(_rot(wi, n, -ph), b, -th)
    return th, np.arccos(np.clip(d[:, 2], -1, 1)), np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)


def _indices(th, td, pd):
    ih = np.clip((np.sqrt(np.maximum(th, 0) / (np.pi / 2)) * 90).astype(int), 0, 89)
    idd = np.clip((td / (np.pi / 2) * 90).astype(int), 0, 89)
    ip = np.clip((np.mod(pd, np.pi) / np.pi * 180).astype(int), 0, 179)
    return ih, idd, ip


def lookup(table, wi, wo) -> np.ndarray:
    """f(ωi, ωo) (N, 3) in 1/sr: the nearest-bin lookup of the MERL reference reader; 0 below the horizon."""
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    out = table[_indices(*half_diff(wi, wo))]
    return np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], out, 0.0)


def _linear_taps(u, n: int, periodic: bool = False):
    """Lower index, upper index and weight of the upper one for linear interpolation between bin centres at
    u = 0 .. n-1 (u in bin units, centre-relative): clamped at the ends, or wrapped (``periodic``)."""
    i0 = np.floor(u)
    w = u - i0
    i0 = i0.astype(int)
    if periodic:
        return np.mod(i0, n), np.mod(i0 + 1, n), w
    lo, hi = np.clip(i0, 0, n - 1), np.clip(i0 + 1, 0, n - 1)
    return lo, hi, np.where(u <= 0, 0.0, np.where(u >= n - 1, 1.0, w))


def interpolate(table, wi, wo) -> np.ndarray:
    """f(ωi, ωo) (N, 3) in 1/sr: the MERL table interpolated between bin centres, 0 below the horizon: linear in θd and
    φd (φd periodic with period π, reciprocity), and along θh geometric, f_a^(1-w) f_b^w with w linear in θh between
    the two nearest θh bin centres (linear where a value is 0); clamped at the θh and θd ends.  At bin centres it is
    ``lookup``.  Between them it follows a sharp peak instead of stepping: a GGX α 0.01 gold file at 48² cells, table
    albedo vs the analytic -0.4 % (nearest bin: +1.3 %; linear in MERL's θh index √(θh/(π/2)) 90: -1.1 %, it
    overestimates the tails and flattens the top); GGX α 0.02, random pairs with f > 10⁻³: median error 0.2 % (nearest
    bin 4.8 %: a θh bin is 0.7° wide at θh 12°, ±5 % on a tail ∝ θh⁻⁴)."""
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    th, td, pd = half_diff(wi, wo)
    taps = (_linear_taps(np.sqrt(np.maximum(th, 0) / (np.pi / 2)) * 90 - 0.5, SHAPE[0]),
            _linear_taps(td / (np.pi / 2) * 90 - 0.5, SHAPE[1]),
            _linear_taps(np.mod(pd, np.pi) / np.pi * 180 - 0.5, SHAPE[2], periodic=True))
    ends = []
    for a in (0, 1):                                   # bilinear in (θd, φd) at the two θh taps
        v = np.zeros((len(wi), 3))
        for b in (0, 1):
            for c in (0, 1):
                w = (taps[1][2] if b else 1 - taps[1][2]) * (taps[2][2] if c else 1 - taps[2][2])
                v += w[:, None] * table[taps[0][a], taps[1][b], taps[2][c]]
        ends.append(v)
    th_c = ((np.arange(SHAPE[0]) + 0.5) / SHAPE[0]) ** 2 * (np.pi / 2)      # the θh bin centres
    a0, a1 = th_c[taps[0][0]], th_c[taps[0][1]]
    w = np.where(a1 > a0, np.clip((th - a0) / np.where(a1 > a0, a1 - a0, 1.0), 0.0, 1.0), taps[0][2])[:, None]
    pos = (ends[0] > 0) & (ends[1] > 0)                # geometric along θh (a peak's tails are power laws)
    lin = (1 - w) * ends[0] + w * ends[1]
    geo = np.exp((1 - w) * np.log(np.where(pos, ends[0], 1.0)) + w * np.log(np.where(pos, ends[1], 1.0)))
    out = np.where(pos, geo, lin)
    return np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], out, 0.0)


def half_vector_grid(n_theta: int = 90, n_phi: int = 180) -> tuple[np.ndarray, np.ndarray]:
    """Midpoints h (n_theta n_phi, 3) of the upper hemisphere in MERL's warping θh = x² π/2 (dense at the specular
    peak) and their solid angles dωh (sr)."""
    x = (np.arange(n_theta) + 0.5) / n_theta
    th, dth = x * x * (np.pi / 2), 2 * x * (np.pi / 2) / n_theta
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)
    return h, (np.sin(TH) * dth[:, None]).ravel() * (2 * np.pi / n_phi)


def half_vector_albedo(f, wo, n_theta: int = 90, n_phi: int = 180) -> np.ndarray:
    """Directional albedo ∫ f cos θi dωi (N, 3) of a BRDF ``f(wi, wo) -> (M, 3)`` (1/sr) for views ``wo`` (N, 3):
    midpoint rule over the half vector in MERL's own warping θh = x² π/2 (``n_theta`` x ``n_phi`` points, dense at
    the specular peak), ωi = reflect(ωo, h), dωi = 4 |h·ωo| dωh.  Dimensionless.  With ``f`` = ``lookup`` of a file
    and ``n_theta`` = 90 one point per θh bin (GGX α 0.05 file: within 0.14 % of 1500 x 360 points)."""
    h, dwh = half_vector_grid(n_theta, n_phi)
    out = []
    for w in np.atleast_2d(np.asarray(wo, np.float64)):
        W = np.broadcast_to(w, h.shape)
        wi, ok = reflect(W, h)
        v = f(np.where(ok[:, None], wi, [0.0, 0.0, 1.0]), W)
        out.append((v * (ok * wi[:, 2] * 4.0 * np.abs(h @ w) * dwh)[:, None]).sum(0))
    return np.array(out)


def bin_centres():
    """(θh, θd, φd) of every bin's centre, each (90, 90, 180), radians."""
    th = ((np.arange(90) + 0.5) / 90) ** 2 * (np.pi / 2)
    td = (np.arange(90) + 0.5) / 90 * (np.pi / 2)
    pd = (np.arange(180) + 0.5) / 180 * np.pi
    return np.meshgrid(th, td, pd, indexing="ij")


def tabulate(f) -> np.ndarray:
    """A MERL table (90, 90, 180, 3) of an isotropic analytic BRDF ``f(wi, wo) -> (N, 3)`` (1/sr)
    sampled at the bin centres (pairs below the horizon get -1/SCALE, i.e. 'missing', as in MERL files:
    stored as 0 by ``read_merl``)."""
    TH, TD, PD = (a.ravel() for a in bin_centres())
    h = np.stack([np.sin(TH), np.zeros_like(TH), np.cos(TH)], -1)
    d = np.stack([np.sin(TD) * np.cos(PD), np.sin(TD) * np.sin(PD), np.cos(TD)], -1)
    b = np.broadcast_to([0.0, 1.0, 0.0], d.shape)
    wi = _rot(d, b, TH)                              # diff frame -> surface frame (φh = 0)
    wo = 2 * np.sum(wi * h, 1, keepdims=True) * h - wi
    out = np.zeros((len(wi), 3))
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    out[ok] = f(wi[ok], wo[ok])
    return out.reshape(*SHAPE, 3)


def fill_missing(table) -> np.ndarray:
    """``table`` (90, 90, 180, 3) with its missing bins (all channels <= 0: negative in the file, 0 after
    ``read_merl``) given the value of the nearest measured bin at smaller θd (same θh, φd), else at smaller θh.
    MERL files mark every bin whose centre pair lies below the horizon as missing (25 % of the bins of a file
    written by ``tabulate``), yet nearest-bin lookups of pairs above the horizon land in them: left at 0 they
    darken a rim at grazing angles and hide the BRDF's smooth floor (``tabulated_brdf.floor_split``)."""
    t = np.array(table, np.float64)
    for axis in (1, 0):                                     # θd first, then θh for columns missing from θd = 0
        ok = np.any(t > 0, axis=-1)
        shape = [1] * 3
        shape[axis] = SHAPE[axis]
        idx = np.where(ok, np.arange(SHAPE[axis]).reshape(shape), 0)
        idx = np.maximum.accumulate(idx, axis=axis)         # last measured index at or below
        filled = np.take_along_axis(t, idx[..., None], axis=axis)
        t = np.where(ok[..., None], t, filled)
    return t


#: the automatic resolution's range (``auto_resolution``): the floor keeps broad files cheap (a GGX α 0.2 + Lambert
#: file renders within 0.7 % of its analytic twin at 16², numpy twin of the merl_audit scenes), the cap is the
#: closure's (``tabulated_brdf.MAX_RES``; 48² x 32 x 3 = 221k floats, under the shader-source limit ``MAX_FLOATS``)
AUTO_RES_MIN = 24
AUTO_RES_MAX = MAX_RES
#: view angles of an automatic import: ρ = f cos θi cos θo J of the half layout is smooth in θo (gold GGX α 0.05
#: at 48²: 32 or 48 view angles, worst merl_audit view 1.1 % either way; import 6 vs 10 s CPU)
AUTO_N_THETA = 32
#: smallest peak (relative to the profile's floor) that ``lobe_width`` measures
PEAK_MIN = 0.05
#: resolved: a table cell at most this many peak half-widths (``lobe_width``) wide (gold GGX α 0.05 in the
#: merl_audit scenes, numpy twin, deconvolved residual: cells of 1.5 / 1.0 half-widths (32², 48²) 2.3 / 1.1 %)
CELLS_PER_WIDTH = 1.0


def lobe_width(table, theta_d_bins: int = 5) -> float:
    """Half width at half maximum (radians, along θh) of the specular peak of a MERL table (90, 90, 180, 3)
    (missing bins filled, ``fill_missing``): the profile p(θh) = mean over RGB, φd and the first ``theta_d_bins``
    θd bins (θd < 5°: no Fresnel / shadowing change across it) at MERL's θh bin centres, its minimum over θh (the
    diffuse floor) subtracted; the first θh past the maximum where it falls below half, linear between bin centres.
    A peak less than ``PEAK_MIN`` (5 %) above that floor is none (measurement noise on a matte file; a lobe that
    small carries little energy to blur).
    For a microfacet BRDF it is the NDF's: GGX D halves at tan θh = α √(√2 - 1) ≈ 0.644 α, Beckmann at
    α √(ln 2) ≈ 0.833 α (x cos⁴ θh aside).  π/2 when the profile has no peak (a Lambertian) or never halves."""
    t = np.asarray(table, np.float64)
    if t.shape != (*SHAPE, 3):
        raise ValueError(f"table: expected shape {(*SHAPE, 3)}, got {t.shape}")
    th = bin_centres()[0][:, 0, 0]
    p = t[:, : int(theta_d_bins)].mean(axis=(1, 2, 3))
    q = p - p.min()
    i0 = int(np.argmax(q))
    half = 0.5 * q[i0]
    below = np.flatnonzero(q[i0:] < half)
    if q[i0] <= PEAK_MIN * max(float(p.min()), 1e-30) or below.size == 0:
        return float(np.pi / 2)
    j = i0 + int(below[0])
    return float(th[j - 1] + (th[j] - th[j - 1]) * (q[j - 1] - half) / (q[j - 1] - q[j]))


def cell_angle(res: int) -> float:
    """Angular size (radians) of one cell of the closure's res x res half-vector grid near the normal, π / (2 res)
    (the hemi-octahedral square's side 2 spans π/2 from the normal to the horizon; ``tabulated_brdf``)."""
    return float(np.pi / (2 * res))


def auto_resolution(width: float) -> tuple[int, bool]:
    """The half-vector grid for a peak of half width ``width`` (radians, ``lobe_width``): the smallest res (a
    multiple of 4) whose cells (``cell_angle``) are at most ``CELLS_PER_WIDTH`` half-widths, clipped to
    [``AUTO_RES_MIN``, ``AUTO_RES_MAX``]; and whether the cap left the peak unresolved (sharper than the table)."""
    w = float(validation.check_range("width", width, 1e-6, np.pi / 2))
    need = int(np.ceil(np.pi / (2 * CELLS_PER_WIDTH * w) / 4.0 - 1e-9) * 4)
    return int(np.clip(need, AUTO_RES_MIN, AUTO_RES_MAX)), need > AUTO_RES_MAX


#: floor points (``floor_points``): MERL θh bins whose centre lies within this many table cells of the normal
POINT_CELLS = 4
#: floor points: half-vector azimuths per θh bin
POINT_PHI = 64
#: floor points resolve a GGX floor whose half width (tan w = 0.644 α) spans this many θh bin centres
POINT_BINS_PER_WIDTH = 3


def floor_points(table, brdf: TabulatedBRDF, measured=None, read=None) -> dict:
    """Constraint points of the glossy floor (``tabulated_brdf.floor_points``) from the file's own bins: for each view
    node of ``brdf`` (isotropic, half layout), half vectors at MERL's θh bin centres within ``POINT_CELLS`` cells of
    the normal x ``POINT_PHI`` azimuths, ωi = reflect(ωo, h), f read from ``table`` by ``read`` (default
    ``interpolate``; ``to_tabulated`` passes its own reader) at the bin's own θh: no quantisation along the peak.  MERL's θh bins are ~0.01-0.1° wide there (index
    √(θh/90°) 90), far finer than the table's cells (π/(2 res): 1.9° at 48²), so a floor as sharp as the file's
    peak keeps r >= 0 where the table cannot see it.  ``ok``: ωi above the horizon and the bin measured
    (``measured`` (90, 90, 180) bool, default all); ``alpha_min``: the GGX α whose half width spans
    ``POINT_BINS_PER_WIDTH`` θh bin centres (α 0.0019)."""
    th_c = bin_centres()[0][:, 0, 0]
    K = int(np.searchsorted(th_c, POINT_CELLS * cell_angle(brdf.res)))
    ph = (np.arange(POINT_PHI) + 0.5) / POINT_PHI * 2 * np.pi
    TH, PH = np.meshgrid(th_c[:K], ph, indexing="ij")
    h = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], -1).reshape(-1, 3)
    wo = brdf.view_nodes()
    wi, ok = reflect(np.broadcast_to(wo[:, None, :], (len(wo), len(h), 3)), np.broadcast_to(h, (len(wo), len(h), 3)))
    wi = np.where(ok[..., None], wi, [0.0, 0.0, 1.0])
    W = np.broadcast_to(wo[:, None, :], wi.shape).reshape(-1, 3)
    f = (read or interpolate)(table, wi.reshape(-1, 3), W).reshape(wi.shape)
    if measured is not None:
        ok &= np.asarray(measured, bool)[_indices(*half_diff(wi.reshape(-1, 3), W))].reshape(ok.shape)
    a_min = np.tan(th_c[POINT_BINS_PER_WIDTH - 1]) / 0.644
    return {"wi": wi, "f": f, "ok": ok, "alpha_min": float(a_min)}


def to_tabulated(table, res: int = 32, n_theta: int = 32, sub: int | None = None, half: bool = True,
                 fill: bool = True, deconvolve: bool = True, points: bool = True, linear: bool = True) -> TabulatedBRDF:
    """The MERL BRDF on the isotropic grid of the tabulated closure: ``res`` x ``res`` cells, each the average
    of ``sub``² nearest-bin lookups (default 4 for ``half``, else 2); ``n_theta`` view angles.

    ``half`` (default): the cells are half vectors over the whole hemisphere (``TabulatedBRDF`` half layout,
    extent 1), where a specular peak sits on the same cells at every view.  Measured on MERL files written from
    Cycles' GGX (x 0.8, + 0.02 Lambert), iso 32² x 32, rendered energy (the sampler's mean weight) vs the
    analytic albedo at θo = 0..75°: half layout -0.2..-0.4 % (α 0.2), -0.6..-0.8 % (0.08), -1.7..-2.2 % (0.04),
    -2.7..-3.2 % (0.02); the ωi layout (``half=False``) +0.4..-0.4 %, +1.2..-2.2 %, +2.4..-4.3 %, +7.2..-8.9 %
    (sharp lobes gain or lose energy depending on the view).  ``fill`` (default): missing bins first take the
    nearest measured value (``fill_missing``).  ``deconvolve`` (default; half layout): the table holds the cell
    averages, and what the table closure renders of them (the residual of the floors, ``tabulated_brdf.floor_parts``)
    gets node values whose bilinear reconstruction has those averages (``info["deconvolve_residual"]``,
    ``prefilter.deconvolve_cells``), instead of a blur by about a cell.  ``linear`` (default): the sub-points read
    ``interpolate`` (the file between its bin centres) instead of the nearest bin (``lookup``): the GGX α 0.04 file
    above renders +0.05..+0.21 % instead of -1.8..-2.1 %.  ``points`` (default; half layout): ``info["floor_points"]``
    = ``floor_points``, the glossy floor's constraints at the file's own θh bins near the peak
    (``tabulated_brdf.floor_points``)."""
    t = np.asarray(table, np.float64)
    if t.shape != (*SHAPE, 3):
        raise ValueError(f"table: expected shape {(*SHAPE, 3)}, got {t.shape}")
    sub = (4 if half else 2) if sub is None else sub
    measured = None
    if fill:                                               # missing bins take their measured neighbour's value
        measured = np.any(t > 0, axis=-1)
        t = fill_missing(t)
    for name, v in (("deconvolve", deconvolve), ("points", points), ("linear", linear)):
        if not isinstance(v, (bool, np.bool_)):
            raise ValueError(f"{name}: expected True or False, got {v!r}")
    info = {"source": "merl", "deconvolve_residual": bool(deconvolve and half)}
    read = interpolate if linear else lookup
    out = TabulatedBRDF.from_function(lambda wi, wo: read(t, wi, wo), res, iso=True, n_theta=n_theta, sub=sub,
                                      info=info, half=bool(half), extent=1.0)
    if points and half:
        out.info["floor_points"] = floor_points(t, out, measured, read)
    return out
