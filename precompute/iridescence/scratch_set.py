"""Scratch sets as vector primitives and a uniform-grid spatial index (Velinov et al. 2018, §3.1, §4).

A scratch set is a list of straight segments in UV (surface) space, each with a
width W and depth D in micrometres; ``uv_scale_um`` converts UV lengths to µm
(µm per UV unit).  Curved scratches are polylines split into segments (each
segment is one incoherent primitive, eq. 7).

The spatial index is a uniform grid over UV storing, per cell, the ids of all
segments that pass through the cell, as CSR arrays (``cell_start``,
``cell_items``).  ``query`` returns, for each query disk (footprint centre and
radius, e.g. footprint semi-major axis + 3σ), exactly the segments whose distance
to the centre is ≤ the radius — everything vectorised over queries and pairs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..validation import check_seed, finite as _finite

__all__ = [
    "ScratchSet",
    "random_scratches",
    "scratches_from_polylines",
    "ScratchGrid",
    "build_grid",
    "point_segment_distance",
    "brute_force_query",
    "to_shader_arrays",
]


@dataclass(frozen=True)
class ScratchSet:
    """Segments ``p0 → p1`` (M, 2) in UV units, ``width_um`` / ``depth_um`` (M,) in µm.

    ``uv_scale_um`` — micrometres per UV unit (> 0).  ``curve_id`` (M,) tells which
    polyline/scratch a segment came from (informational).
    """

    p0: np.ndarray
    p1: np.ndarray
    width_um: np.ndarray
    depth_um: np.ndarray
    uv_scale_um: float
    curve_id: np.ndarray = field(default=None)

    def __post_init__(self):
        p0 = _finite("p0", self.p0).reshape(-1, 2) if np.size(self.p0) else np.zeros((0, 2))
        p1 = _finite("p1", self.p1).reshape(-1, 2) if np.size(self.p1) else np.zeros((0, 2))
        if p0.shape != p1.shape:
            raise ValueError(f"p0 and p1 must have the same shape (M, 2) (got {p0.shape}, {p1.shape})")
        m = p0.shape[0]
        w = np.broadcast_to(_finite("width_um", self.width_um), (m,)).astype(np.float64)
        d = np.broadcast_to(_finite("depth_um", self.depth_um), (m,)).astype(np.float64)
        if m and (w.min() <= 0.0 or w.max() > 1000.0):
            raise ValueError("width_um must lie in (0, 1000] micrometres")
        if m and (d.min() < 0.0 or d.max() > 1000.0):
            raise ValueError("depth_um must lie in [0, 1000] micrometres")
        s = float(self.uv_scale_um)
        if not (np.isfinite(s) and 0.0 < s <= 1e12):
            raise ValueError("uv_scale_um must lie in (0, 1e12] (micrometres per UV unit)")
        cid = np.arange(m) if self.curve_id is None else np.broadcast_to(np.asarray(self.curve_id, dtype=np.int64), (m,))
        for name, v in (("p0", p0), ("p1", p1), ("width_um", w), ("depth_um", d), ("curve_id", cid)):
            v = np.ascontiguousarray(v)
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        object.__setattr__(self, "uv_scale_um", s)

    def __len__(self) -> int:
        return self.p0.shape[0]

    @property
    def phi(self) -> np.ndarray:
        """Orientation angle (radians) of each segment's tangent in UV space."""
        d = self.p1 - self.p0
        return np.arctan2(d[:, 1], d[:, 0])

    @property
    def length_uv(self) -> np.ndarray:
        return np.linalg.norm(self.p1 - self.p0, axis=1)

    def cache_key(self) -> dict:
        return {"p0": self.p0, "p1": self.p1, "w": self.width_um, "d": self.depth_um, "s": self.uv_scale_um}


def random_scratches(count: int, *, length_range=(0.05, 0.3), width_range_um=(0.8, 6.0), depth_range_um=(0.8, 6.0),
                     orientation: str = "uniform", angle: float = 0.0, kappa: float = 4.0,
                     domain=(0.0, 0.0, 1.0, 1.0), uv_scale_um: float = 1e4, seed: int = 0) -> ScratchSet:
    """Random straight scratches (defaults follow §5: W, D uniform in [0.8, 6] µm).

    ``count`` ≥ 0; ``length_range`` (UV units) and width/depth ranges (µm) are
    uniform; centres uniform in ``domain = (u0, v0, u1, v1)``; ``orientation`` is
    'uniform' (isotropic), 'fixed' (all at ``angle`` radians) or 'von_mises'
    (mean ``angle``, concentration ``kappa`` ≥ 0, on the axial circle, i.e.
    angles mod π).  Deterministic for a given ``seed``.
    """
    if not (isinstance(count, (int, np.integer)) and 0 <= count <= 10_000_000):
        raise ValueError(f"count must be an integer in [0, 1e7] (got {count!r})")

    def _rng_pair(name, r, lo, hi):
        r = _finite(name, r)
        if r.shape != (2,) or not (lo <= r[0] <= r[1] <= hi):
            raise ValueError(f"{name} must be (min, max) with {lo} <= min <= max <= {hi}")
        return r

    lr = _rng_pair("length_range", length_range, 0.0, 1e9)
    wr = _rng_pair("width_range_um", width_range_um, 1e-6, 1000.0)
    dr = _rng_pair("depth_range_um", depth_range_um, 0.0, 1000.0)
    dom = _finite("domain", domain)
    if dom.shape != (4,) or not (dom[0] < dom[2] and dom[1] < dom[3]):
        raise ValueError("domain must be (u0, v0, u1, v1) with u0 < u1 and v0 < v1")
    if orientation not in ("uniform", "fixed", "von_mises"):
        raise ValueError("orientation must be 'uniform', 'fixed' or 'von_mises'")
    if not (np.isfinite(kappa) and kappa >= 0.0):
        raise ValueError("kappa must be finite and >= 0")
    rng = np.random.default_rng(check_seed("seed", seed))
    c = dom[:2] + rng.random((count, 2)) * (dom[2:] - dom[:2])
    if orientation == "uniform":
        th = rng.random(count) * np.pi
    elif orientation == "fixed":
        th = np.full(count, float(angle))
    else:  # axial von Mises: sample on the doubled angle
        th = 0.5 * rng.vonmises(2.0 * float(angle), float(kappa), count)
    length = lr[0] + rng.random(count) * (lr[1] - lr[0])
    d = 0.5 * length[:, None] * np.stack([np.cos(th), np.sin(th)], axis=1)
    w = wr[0] + rng.random(count) * (wr[1] - wr[0])
    dep = dr[0] + rng.random(count) * (dr[1] - dr[0])
    return ScratchSet(c - d, c + d, w, dep, uv_scale_um)


def scratches_from_polylines(polylines, width_um, depth_um, uv_scale_um: float) -> ScratchSet:
    """Scratches from user-drawn curves: a list of (N_i ≥ 2, 2) point arrays in UV space.

    ``width_um`` / ``depth_um``: scalars or one value per polyline (µm).  Each
    consecutive point pair becomes one segment; zero-length segments are dropped.
    Pure function (the bpy side converts a Blender curve to UV polylines).
    """
    pls = [_finite("polylines", p) for p in polylines]
    for i, p in enumerate(pls):
        if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
            raise ValueError(f"polylines[{i}] must have shape (N>=2, 2) (got {p.shape})")
    n = len(pls)
    w = np.broadcast_to(_finite("width_um", width_um), (n,)) if n else np.zeros(0)
    d = np.broadcast_to(_finite("depth_um", depth_um), (n,)) if n else np.zeros(0)
    if n == 0:
        return ScratchSet(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), uv_scale_um)
    counts = np.array([p.shape[0] for p in pls])
    pts = np.concatenate(pls, axis=0)
    curve = np.repeat(np.arange(n), counts)
    last = np.cumsum(counts) - 1
    start = np.setdiff1d(np.arange(pts.shape[0] - 1), last)      # segment i → i+1 within a curve
    p0, p1, cid = pts[start], pts[start + 1], curve[start]
    keep = np.linalg.norm(p1 - p0, axis=1) > 0.0
    return ScratchSet(p0[keep], p1[keep], w[cid[keep]], d[cid[keep]], uv_scale_um, curve_id=cid[keep])


def point_segment_distance(x, p0, p1) -> np.ndarray:
    """Euclidean distance from points x (..., 2) to segments p0→p1 (..., 2), broadcast."""
    d = p1 - p0
    L2 = np.sum(d * d, axis=-1)
    t = np.where(L2 > 0.0, np.sum((x - p0) * d, axis=-1) / np.where(L2 > 0.0, L2, 1.0), 0.0)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(x - (p0 + t[..., None] * d), axis=-1)


@dataclass(frozen=True)
class ScratchGrid:
    """Uniform grid over UV: cell (ix, iy) has id ``iy * nx + ix``; its segment ids are
    ``cell_items[cell_start[id]:cell_start[id + 1]]`` (CSR)."""

    origin: np.ndarray       # (2,) UV of the grid's lower-left corner
    cell_size: float         # UV units
    nx: int
    ny: int
    cell_start: np.ndarray   # (nx*ny + 1,) int64
    cell_items: np.ndarray   # (K,) int64 segment ids

    def _cell_range(self, lo, hi):
        ilo = np.floor((lo - self.origin) / self.cell_size).astype(np.int64)
        ihi = np.floor((hi - self.origin) / self.cell_size).astype(np.int64)
        n = np.array([self.nx, self.ny])
        return np.clip(ilo, 0, n - 1), np.clip(ihi, 0, n - 1), (ihi >= 0) & (ilo <= n - 1)

    def query(self, scratches: ScratchSet, centers, radius):
        """Segments within ``radius`` (UV units) of each centre, exactly.

        ``centers`` (P, 2), ``radius`` scalar or (P,) ≥ 0.  Returns CSR
        ``(offsets (P+1,), ids)``: the ids for query i are
        ``ids[offsets[i]:offsets[i+1]]`` (sorted).  Vectorised over queries and pairs.
        """
        c = _finite("centers", centers).reshape(-1, 2)
        r = np.broadcast_to(_finite("radius", radius), (c.shape[0],))
        if np.any(r < 0.0):
            raise ValueError("radius must be >= 0")
        P = c.shape[0]
        if P == 0 or len(scratches) == 0:
            return np.zeros(P + 1, np.int64), np.zeros(0, np.int64)
        lo, hi, ok = self._cell_range(c - r[:, None], c + r[:, None])
        ok = ok.all(axis=1)
        span = np.where(ok[:, None], hi - lo + 1, 0)
        ncell = span[:, 0] * span[:, 1]
        qi = np.repeat(np.arange(P), ncell)                                   # (query, cell) pairs
        k = np.arange(qi.size) - np.repeat(np.cumsum(ncell) - ncell, ncell)
        cx = lo[qi, 0] + k % span[qi, 0]
        cy = lo[qi, 1] + k // span[qi, 0]
        cell = cy * self.nx + cx
        cnt = self.cell_start[cell + 1] - self.cell_start[cell]
        qj = np.repeat(qi, cnt)                                              # (query, segment) pairs
        kk = np.arange(qj.size) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        sid = self.cell_items[np.repeat(self.cell_start[cell], cnt) + kk]
        key = np.unique(qj * len(scratches) + sid)
        qj, sid = key // len(scratches), key % len(scratches)
        near = point_segment_distance(c[qj], scratches.p0[sid], scratches.p1[sid]) <= r[qj]
        qj, sid = qj[near], sid[near]
        offsets = np.concatenate([[0], np.cumsum(np.bincount(qj, minlength=P))])
        return offsets.astype(np.int64), sid.astype(np.int64)


#: at most this many (cell, segment) entries in a grid (int32 while building, int64 CSR: ~0.4 GB at the bound);
#: an automatic cell size grows until the estimate fits, an explicit one that cannot fit is refused up front
MAX_GRID_ITEMS = 20_000_000
#: (segment, cell) bounding-box candidates tested per chunk while building (~0.1 GB of temporaries)
GRID_CHUNK = 1_000_000
#: segments per block while building / estimating (bounds the per-segment temporaries)
GRID_BLOCK = 1_000_000


def _grid_items_estimate(p0, p1, origin, cell_size: float) -> int:
    """Upper estimate of the cells a segment list touches: a segment crossing |Δix| + |Δiy| cell borders touches
    that many + 1 cells; the conservative half-diagonal test keeps up to ~3x that."""
    n = 0.0
    for a in range(0, len(p0), GRID_BLOCK):
        ia = np.floor((p0[a:a + GRID_BLOCK] - origin) / cell_size)
        ib = np.floor((p1[a:a + GRID_BLOCK] - origin) / cell_size)
        n += float(np.sum(3.0 * (np.abs(ib - ia).sum(axis=1) + 1.0)))
    return int(n)


def build_grid(scratches: ScratchSet, cell_size: float | None = None, max_cells: int = 1 << 20) -> ScratchGrid:
    """Uniform grid index over the scratches' UV bounding box (§4).

    ``cell_size`` in UV units (default: about √M cells per side, at most
    ``max_cells`` cells, coarser if the index would hold more than ``MAX_GRID_ITEMS`` entries).  A segment
    is stored in every cell of its bounding box whose centre is within half a cell diagonal of the segment
    (a conservative segment/cell overlap test), so no overlapping cell is missed.  Bounded memory: the
    candidates are tested in chunks of ``GRID_CHUNK``; an explicit ``cell_size`` whose index would exceed
    ``MAX_GRID_ITEMS`` raises ValueError with the estimate before any work.
    """
    M = len(scratches)
    if M == 0:
        return ScratchGrid(np.zeros(2), 1.0, 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64))
    pts = np.concatenate([scratches.p0, scratches.p1])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ext = np.maximum(hi - lo, 1e-12 * max(1.0, float(np.abs(pts).max())))
    auto = cell_size is None
    if auto:
        cell_size = float(max(ext.max() / max(np.sqrt(M), 1.0), np.sqrt(ext[0] * ext[1] / max_cells), 1e-300))
    cell_size = float(cell_size)
    if not (np.isfinite(cell_size) and cell_size > 0.0):
        raise ValueError("cell_size must be finite and > 0 (UV units)")
    est = _grid_items_estimate(scratches.p0, scratches.p1, lo, cell_size)
    while est > MAX_GRID_ITEMS:
        if not auto:
            raise ValueError(f"cell_size: {cell_size:g} UV units puts ~{est:.3g} (cell, scratch) entries in the grid "
                             f"index, above {MAX_GRID_ITEMS:.3g} (memory); use a larger cell_size (or None)")
        if 3 * M > MAX_GRID_ITEMS:
            raise ValueError(f"scratches: {M} scratches need at least ~{3 * M:.3g} grid entries, above "
                             f"{MAX_GRID_ITEMS:.3g} (memory)")
        cell_size *= min(max(1.5 * est / MAX_GRID_ITEMS, 1.25), 64.0)
        est = _grid_items_estimate(scratches.p0, scratches.p1, lo, cell_size)
    nx, ny = (np.floor(ext / cell_size).astype(np.int64) + 1).tolist()
    if nx * ny > max_cells:
        raise ValueError(f"cell_size too small: {nx}x{ny} cells exceed max_cells={max_cells}")
    grid = ScratchGrid(lo.copy(), cell_size, nx, ny, np.zeros(nx * ny + 1, np.int64), np.zeros(0, np.int64))
    half_diag = 0.5 * np.sqrt(2.0) * cell_size * (1.0 + 1e-9)
    cells, items = [], []
    for s0 in range(0, M, GRID_BLOCK):            # blocks of segments, then chunks of ~GRID_CHUNK candidates
        p0, p1 = scratches.p0[s0:s0 + GRID_BLOCK], scratches.p1[s0:s0 + GRID_BLOCK]
        blo, bhi, _ = grid._cell_range(np.minimum(p0, p1), np.maximum(p0, p1))
        cum = np.cumsum(corridor_bound(p0, p1, blo, bhi))
        a = 0
        while a < len(p0):
            b = max(int(np.searchsorted(cum, (cum[a - 1] if a else 0) + GRID_CHUNK, side="right")), a + 1)
            si, cx, cy = corridor_cells((p0[a:b] - lo) / cell_size, (p1[a:b] - lo) / cell_size, blo[a:b], bhi[a:b])
            si = si + a
            centre = lo + (np.stack([cx, cy], axis=1) + 0.5) * cell_size
            keep = point_segment_distance(centre, p0[si], p1[si]) <= half_diag
            cells.append((cy * nx + cx)[keep].astype(np.int32))       # nx ny <= max_cells, M <= 1e7
            items.append((si[keep] + s0).astype(np.int32))
            a = b
    start, items = csr_from_pairs(np.concatenate(cells), np.concatenate(items), nx * ny)
    return ScratchGrid(lo.copy(), cell_size, nx, ny, start, items)


#: half a cell diagonal in cell units, with the same relative tolerance as ``build_grid``'s test
_H = 0.5 * np.sqrt(2.0) * (1.0 + 1e-6)


def corridor_bound(p0, p1, blo, bhi, width: float = 2.0 * _H) -> np.ndarray:
    """Upper bound of ``corridor_cells``' candidates per segment: major-axis columns x at most
    2 width + 2 rows (slope <= 1)."""
    span = bhi - blo + 1
    major = np.where(np.abs(p1 - p0)[:, 0] >= np.abs(p1 - p0)[:, 1], 0, 1)
    cols = np.take_along_axis(span, major[:, None], 1)[:, 0]
    rows = np.take_along_axis(span, 1 - major[:, None], 1)[:, 0]
    return cols * np.minimum(rows, int(np.ceil(2.0 * width)) + 2)


def corridor_cells(g0, g1, blo, bhi, a: float = 0.5 - _H, b: float = 0.5 + _H):
    """Candidate cells (item, cx, cy) of segments ``g0 -> g1`` (grid coordinates, cell units) inside each segment's
    cell box ``blo..bhi``: cell (c, r) is a candidate if the segment has a point in [c + a, c + b] x [r + a, r + b]
    (the region a kept cell's test can reach: default, a centre within half a cell diagonal (``build_grid``);
    a = -R, b = 1 + R: a cell box within R cells (``layer.reach_grid``)).  Per column of the segment's major
    axis, the rows its minor coordinate spans over that column's region (<= 2 (b - a) + 2 rows, slope <= 1),
    instead of the whole box (a diagonal segment across n cells: O(n), not n²)."""
    d = g1 - g0
    major = np.where(np.abs(d[:, 0]) >= np.abs(d[:, 1]), 0, 1)
    ar = np.arange(len(g0))
    u0, u1 = g0[ar, major], g1[ar, major]
    v0, v1 = g0[ar, 1 - major], g1[ar, 1 - major]
    du = u1 - u0
    slope = np.where(du != 0.0, (v1 - v0) / np.where(du != 0.0, du, 1.0), 0.0)
    c_lo, c_hi = blo[ar, major], bhi[ar, major]
    r_box_lo, r_box_hi = blo[ar, 1 - major], bhi[ar, 1 - major]
    n_col = c_hi - c_lo + 1
    item = np.repeat(ar, n_col)                                            # (segment, column) pairs
    c = c_lo[item] + np.arange(item.size) - np.repeat(np.cumsum(n_col) - n_col, n_col)
    umin, umax = np.minimum(u0, u1)[item], np.maximum(u0, u1)[item]
    ua = np.maximum(c + a, umin)
    ub = np.minimum(c + b, umax)
    va = v0[item] + (ua - u0[item]) * slope[item]
    vb = v0[item] + (ub - u0[item]) * slope[item]
    r_lo = np.maximum(np.ceil(np.minimum(va, vb) - b), r_box_lo[item]).astype(np.int64)
    r_hi = np.minimum(np.floor(np.maximum(va, vb) - a), r_box_hi[item]).astype(np.int64)
    n_row = np.where(ua <= ub, np.maximum(r_hi - r_lo + 1, 0), 0)
    k = np.repeat(np.arange(item.size), n_row)                             # (segment, column, row) triples
    r = r_lo[k] + np.arange(k.size) - np.repeat(np.cumsum(n_row) - n_row, n_row)
    it, cc = item[k], c[k]
    mj = major[it]
    return it, np.where(mj == 0, cc, r), np.where(mj == 0, r, cc)


def cell_pairs(blo: np.ndarray, bhi: np.ndarray):
    """Every (item, cx, cy) with item i's cell index inside its inclusive box ``blo[i]..bhi[i]`` (vectorised)."""
    span = bhi - blo + 1
    n = span[:, 0] * span[:, 1]
    item = np.repeat(np.arange(len(blo)), n)
    k = np.arange(item.size) - np.repeat(np.cumsum(n) - n, n)
    return item, blo[item, 0] + k % span[item, 0], blo[item, 1] + k // span[item, 0]


def csr_from_pairs(cell: np.ndarray, item: np.ndarray, n_cells: int):
    """CSR lists (``start`` [n_cells + 1], ``items``) from (cell, item) pairs, items in input order per cell."""
    order = np.argsort(cell, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(cell, minlength=n_cells))])
    return start.astype(np.int64), item[order].astype(np.int64)


def brute_force_query(scratches: ScratchSet, centers, radius):
    """Reference for ``ScratchGrid.query``: tests every (centre, segment) pair. Same CSR output."""
    c = _finite("centers", centers).reshape(-1, 2)
    r = np.broadcast_to(_finite("radius", radius), (c.shape[0],))
    d = point_segment_distance(c[:, None, :], scratches.p0[None], scratches.p1[None])
    qi, sid = np.nonzero(d <= r[:, None])
    offsets = np.concatenate([[0], np.cumsum(np.bincount(qi, minlength=c.shape[0]))])
    return offsets.astype(np.int64), sid.astype(np.int64)


def to_shader_arrays(scratches: ScratchSet, grid: ScratchGrid | None = None) -> dict:
    """Flat arrays for the Cycles shader.

    Layout (all little-endian, C order):
      ``segments``  float32 (M*6,): per segment ``u0, v0, u1, v1, W_um, D_um``
      ``grid_params`` float32 (6,): ``origin_u, origin_v, cell_size, nx, ny, uv_scale_um``
      ``cell_start`` int32 (nx*ny+1,), ``cell_items`` int32 (K,): CSR of the grid
      (cell id = iy*nx + ix, ix = floor((u - origin_u)/cell_size)).
    """
    if grid is None:
        grid = build_grid(scratches)
    seg = np.concatenate([scratches.p0, scratches.p1, scratches.width_um[:, None], scratches.depth_um[:, None]], axis=1)
    if grid.cell_items.size and grid.cell_items.max() >= 2**31 - 1:
        raise ValueError("scratches: too many segments for int32 indices")
    return {
        "segments": seg.astype(np.float32).ravel(),
        "grid_params": np.array([grid.origin[0], grid.origin[1], grid.cell_size, grid.nx, grid.ny,
                                 scratches.uv_scale_um], dtype=np.float32),
        "cell_start": grid.cell_start.astype(np.int32),
        "cell_items": grid.cell_items.astype(np.int32),
    }
