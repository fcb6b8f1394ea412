"""Directional visibility against an infinitely repeated tile (Wu et al. 2011, §3.3).

The paper rasterises shadow maps of the tile duplicated around itself.  We cast rays
exactly instead, vectorised in numpy, and handle the repetition exactly (not just the 8
neighbours, which is wrong at grazing angles where a ray crosses many tiles):

*Sheared coordinates.*  For a direction ω with ω_z > 0, map every point p to
u = p_xy - p_z ω_xy / ω_z (the point where the line through p along ω meets z = 0) and
keep its height z.  A ray p + tω becomes a vertical line at fixed u going up in z, and
translating the tile by the period P along x or y translates u by P.  So "is there
surface above p along ω in the repeated tile" becomes "does any sheared triangle,
wrapped onto the torus [0, P)^2, cover u(p) mod P with a height above z(p)".

*Uniform grid on the torus.*  Sheared triangles are scan-converted (exact per-row
x-extent, so long grazing slivers cost their area, not their bounding box) into a
G x G cell grid with wrap-around, remembering the lattice shift of each piece.  Each ray
is tested (2D barycentrics + interpolated height) against the pieces in its cell only.
Everything is batched numpy over rays x candidate triangles; the Python loop is over
directions only.

Units: positions in the tile's length unit (P = period); directions are unit vectors.
"""
from __future__ import annotations

import numpy as np

__all__ = ["TorusGrid", "occluded", "first_hit", "visibility_matrix"]


def _check_direction(omega):
    omega = np.asarray(omega, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(omega)) or omega[2] <= 1e-6:
        raise ValueError(f"omega: direction must be finite with z > 1e-6 (above the tile), got {omega}")
    return omega / np.linalg.norm(omega)


class TorusGrid:
    """Sheared triangles of a periodic tile, binned on a G x G torus grid for one direction ω.

    ``tri``: (T, 3, 3) triangle vertex positions; ``period``: tile size P; ``omega``: unit
    direction with ω_z > 0 along which rays travel (rays are tested going *towards* ω)."""

    def __init__(self, tri: np.ndarray, period: float, omega: np.ndarray, cells: int | None = None,
                 occluders: np.ndarray | None = None):
        omega = _check_direction(omega)
        self.P = float(period)
        self.omega = omega
        self.shear = omega[:2] / omega[2]
        T = tri.shape[0]
        U = tri[..., :2] - tri[..., 2:3] * self.shear  # (T, 3, 2) sheared xy
        Z = tri[..., 2].copy()
        e1 = U[:, 1] - U[:, 0]
        e2 = U[:, 2] - U[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        scale = np.abs(U).max() + 1.0
        keep = np.abs(det) > 1e-14 * scale * scale  # edge-on triangles cover no area
        if occluders is not None:
            keep &= occluders
        self.U0, self.e1, self.e2, self.det, self.Z = U[keep, 0], e1[keep], e2[keep], det[keep], Z[keep]
        self.tri_id = np.nonzero(keep)[0]
        # affine maps u -> (b1, b2, z) per triangle (rows of coef @ (ux, uy, 1)): barycentrics
        # b1 = ((u-U0) x e2)/det, b2 = (e1 x (u-U0))/det and the plane height z
        e1k, e2k, dk, U0k, Zk = self.e1, self.e2, self.det, self.U0, self.Z
        b1 = np.stack([e2k[:, 1], -e2k[:, 0], -(U0k[:, 0] * e2k[:, 1] - U0k[:, 1] * e2k[:, 0])], -1) / dk[:, None]
        b2 = np.stack([-e1k[:, 1], e1k[:, 0], -(e1k[:, 0] * U0k[:, 1] - e1k[:, 1] * U0k[:, 0])], -1) / dk[:, None]
        zc = b1 * (Zk[:, 1] - Zk[:, 0])[:, None] + b2 * (Zk[:, 2] - Zk[:, 0])[:, None]
        zc[:, 2] += Zk[:, 0]
        self.coef = np.stack([b1, b2, zc], 1)  # (T, 3, 3)
        U = U[keep]
        T = U.shape[0]
        G = cells if cells is not None else int(np.clip(np.sqrt(max(T, 1)), 4, 256))  # ~1 triangle per cell
        self.G = G
        h = self.P / G
        self.h = h
        if T == 0:
            self.cell_start = np.zeros(G * G + 1, np.int64)
            self.piece_tri = np.zeros(0, np.int64)
            self.piece_shift = np.zeros((0, 2))
            self.piece_zmax = np.zeros(0)
            self.cell_zmax = np.full(G * G, -np.inf)
            return
        # --- scan conversion: (triangle, row) pairs with exact x-extent inside the row band
        y = U[..., 1]
        r0 = np.floor(y.min(1) / h).astype(np.int64)
        r1 = np.floor(y.max(1) / h).astype(np.int64)
        nrow = r1 - r0 + 1
        t_of = np.repeat(np.arange(T), nrow)
        row = np.repeat(r0, nrow) + (np.arange(nrow.sum()) - np.repeat(np.cumsum(nrow) - nrow, nrow))
        y0 = row * h
        y1 = y0 + h
        Ut = U[t_of]  # (R, 3, 2)
        xs, ys = Ut[..., 0], Ut[..., 1]
        inband = (ys >= y0[:, None]) & (ys <= y1[:, None])
        xmin = np.where(inband, xs, np.inf).min(1)
        xmax = np.where(inband, xs, -np.inf).max(1)
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ya, yb, xa, xb = ys[:, a], ys[:, b], xs[:, a], xs[:, b]
            dy = yb - ya
            safe = np.where(dy != 0, dy, 1.0)
            for yl in (y0, y1):
                ok = ((ya - yl) * (yb - yl) <= 0) & (dy != 0)
                xi = xa + (yl - ya) * (xb - xa) / safe
                xmin = np.where(ok, np.minimum(xmin, xi), xmin)
                xmax = np.where(ok, np.maximum(xmax, xi), xmax)
        pad = 1e-9 * h
        with np.errstate(invalid="ignore"):  # rows that only touch a vertex have an empty extent (inf)
            fin = np.isfinite(xmin) & np.isfinite(xmax)
            c0 = np.where(fin, np.floor((np.where(fin, xmin, 0.0) - pad) / h), 0).astype(np.int64)
            c1 = np.where(fin, np.floor((np.where(fin, xmax, 0.0) + pad) / h), -1).astype(np.int64)
        valid = c1 >= c0
        t_of, row, c0, c1 = t_of[valid], row[valid], c0[valid], c1[valid]
        ncol = c1 - c0 + 1
        p_tri = np.repeat(t_of, ncol)
        p_row = np.repeat(row, ncol)
        p_col = np.repeat(c0, ncol) + (np.arange(ncol.sum()) - np.repeat(np.cumsum(ncol) - ncol, ncol))
        wr, wc = np.mod(p_row, G), np.mod(p_col, G)
        shift = np.stack([(p_col - wc) // G, (p_row - wr) // G], -1) * self.P  # lattice shift (x, y)
        cell = wr * G + wc
        order = np.argsort(cell.astype(np.int32) if G * G < 2 ** 31 else cell, kind="stable")
        self.piece_tri = p_tri[order]
        self.piece_shift = shift[order]
        counts = np.bincount(cell, minlength=G * G)
        self.cell_start = np.concatenate([[0], np.cumsum(counts)])
        # highest point of each piece's triangle and of each cell (cheap conservative culls)
        self.piece_zmax = self.Z.max(1)[self.piece_tri]
        cz = np.full(G * G, -np.inf)
        np.maximum.at(cz, cell, self.Z.max(1)[p_tri])
        self.cell_zmax = cz

    def _cells(self, points: np.ndarray):
        u = points[:, :2] - points[:, 2:3] * self.shear
        uw = np.mod(u, self.P)
        cx = np.minimum((uw[:, 0] / self.h).astype(np.int64), self.G - 1)
        cy = np.minimum((uw[:, 1] / self.h).astype(np.int64), self.G - 1)
        return cy * self.G + cx, uw

    def _candidates(self, points: np.ndarray):
        """(ray index, piece index, wrapped sheared point) for every ray x piece-in-its-cell pair."""
        cell, uw = self._cells(points)
        start = self.cell_start[cell]
        cnt = self.cell_start[cell + 1] - start
        ray = np.repeat(np.arange(points.shape[0]), cnt)
        piece = np.repeat(start, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        return ray, piece, uw

    def _hit_heights(self, points: np.ndarray, chunk: int = 2_000_000):
        """Yield (ray, height of the covering triangle, triangle id) for candidate pairs that
        cover the ray's sheared point."""
        ray, piece, uw = self._candidates(points)
        tol = 1e-9
        for a in range(0, ray.size, chunk):
            r, p = ray[a:a + chunk], piece[a:a + chunk]
            t = self.piece_tri[p]
            u = uw[r] + self.piece_shift[p]          # sheared point in the piece's lattice copy
            A = self.coef[t]                           # (n, 3, 3)
            v = A[:, :, 0] * u[:, 0:1] + A[:, :, 1] * u[:, 1:2] + A[:, :, 2]   # (b1, b2, z)
            inside = (v[:, 0] >= -tol) & (v[:, 1] >= -tol) & (v[:, 0] + v[:, 1] <= 1.0 + tol)
            yield r[inside], v[inside, 2], self.tri_id[t[inside]]


def occluded(grid: TorusGrid, points: np.ndarray, eps: float) -> np.ndarray:
    """Boolean (N,): is there tile surface on the ray points + tω, t > 0 (shadow/masking, §3.3)?

    A hit counts if it is more than ``eps`` (length units) above the ray origin, which
    excludes the origin's own triangle.  Rays higher than everything in their cell, and
    candidate triangles lower than the ray origin, are culled before the exact test."""
    points = np.asarray(points, dtype=np.float64)
    occ = np.zeros(points.shape[0], dtype=bool)
    cell, _ = grid._cells(points)
    live = np.flatnonzero(points[:, 2] + eps < grid.cell_zmax[cell])
    if live.size == 0:
        return occ
    pts = points[live]
    ray, piece, uw = grid._candidates(pts)
    high = grid.piece_zmax[piece] > pts[ray, 2] + eps
    ray, piece = ray[high], piece[high]
    t = grid.piece_tri[piece]
    u = uw[ray] + grid.piece_shift[piece]
    A = grid.coef[t]
    v = A[:, :, 0] * u[:, 0:1] + A[:, :, 1] * u[:, 1:2] + A[:, :, 2]   # (b1, b2, z)
    tol = 1e-9
    hit = (v[:, 0] >= -tol) & (v[:, 1] >= -tol) & (v[:, 0] + v[:, 1] <= 1.0 + tol) & (v[:, 2] > pts[ray, 2] + eps)
    occ[live[ray[hit]]] = True
    return occ


def first_hit(grid: TorusGrid, u: np.ndarray, z_top: float) -> tuple[np.ndarray, np.ndarray]:
    """Closest hit of primary rays coming *from* ω (travelling along -ω) through sheared
    points u (N, 2) at height ``z_top`` above the tile: returns (height (N,), triangle id (N,));
    id -1 where the ray escapes (hole in the tile)."""
    pts = np.concatenate([np.asarray(u, np.float64) + z_top * grid.shear, np.full((len(u), 1), float(z_top))], 1)
    # a point at z_top whose sheared coordinate is u: p_xy = u + z_top*shear
    best = np.full(len(u), -np.inf)
    tid = np.full(len(u), -1, np.int64)
    for r, zh, t in grid._hit_heights(pts):
        np.maximum.at(best, r, zh)
        top = zh >= best[r]
        tid[r[top]] = t[top]
    return best, tid


def visibility_matrix(tri: np.ndarray, period: float, points: np.ndarray, directions: np.ndarray,
                      eps: float | None = None, point_normals: np.ndarray | None = None,
                      closed: bool = False) -> np.ndarray:
    """V[s, d] = 1 if point s sees direction d unoccluded in the repeated tile (§3.3).

    ``tri`` (T, 3, 3), ``points`` (S, 3) on the surface, ``directions`` (D, 3) with z > 0.
    Returns a bool array (S, D).  Loops over directions; each is one batched ray cast.

    Culling (exact, never changes a result it is allowed for):

    * ``point_normals`` (S, 3): a point whose surface normal faces away from ω (n·ω <= 0)
      is self-occluded, V = 0, without a ray (the ray enters its own solid);
    * points higher than every occluder cannot be occluded (rays go up): V = 1;
    * ``closed=True`` (the tile is one connected, consistently oriented closed periodic
      surface, see ``biscale_geometry.is_closed_surface``; needs ``point_normals``): a ray
      leaving a front-facing point is outside the solid, so the first surface it meets is
      entered from outside, i.e. through a triangle whose normal faces *against* ω.  Only
      those triangles (n_t·ω < 0) are occluders.  At normal incidence on a height field
      there are none at all."""
    points = np.asarray(points, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    if closed and point_normals is None:
        raise ValueError("closed: occluder culling needs point_normals (S, 3)")
    if eps is None:
        span = float(np.ptp(tri[..., 2])) if tri.size else 0.0
        eps = 1e-7 * (float(period) + span)
    if closed or point_normals is not None:
        c = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])   # un-normalised triangle normals
    V = np.empty((points.shape[0], directions.shape[0]), dtype=bool)
    zmax_tri = tri[..., 2].max(1)
    for d, w in enumerate(directions):
        w = _check_direction(w)
        test = np.ones(points.shape[0], bool)
        vis = np.ones(points.shape[0], bool)
        if point_normals is not None:
            front = point_normals @ w > 0
            vis &= front
            test &= front
        occ = (c @ w < 0) if closed else None
        zt = zmax_tri[occ] if occ is not None else zmax_tri
        if zt.size == 0:
            V[:, d] = vis
            continue
        test &= points[:, 2] < zt.max() - eps
        idx = np.flatnonzero(test)
        if idx.size:
            vis[idx] = ~occluded(TorusGrid(tri, period, w, occluders=occ), points[idx], eps)
        V[:, d] = vis
    return V
