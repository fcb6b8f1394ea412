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

    def __init__(self, tri: np.ndarray, period: float, omega: np.ndarray, cells: int | None = None):
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
        self.U0, self.e1, self.e2, self.det, self.Z = U[keep, 0], e1[keep], e2[keep], det[keep], Z[keep]
        self.tri_id = np.nonzero(keep)[0]
        U = U[keep]
        T = U.shape[0]
        G = cells if cells is not None else int(np.clip(np.sqrt(max(T, 1)) * 1.0, 4, 256))
        self.G = G
        h = self.P / G
        self.h = h
        if T == 0:
            self.cell_start = np.zeros(G * G + 1, np.int64)
            self.piece_tri = np.zeros(0, np.int64)
            self.piece_shift = np.zeros((0, 2))
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
        c0 = np.floor((xmin - pad) / h).astype(np.int64)
        c1 = np.floor((xmax + pad) / h).astype(np.int64)
        valid = c1 >= c0
        t_of, row, c0, c1 = t_of[valid], row[valid], c0[valid], c1[valid]
        ncol = c1 - c0 + 1
        p_tri = np.repeat(t_of, ncol)
        p_row = np.repeat(row, ncol)
        p_col = np.repeat(c0, ncol) + (np.arange(ncol.sum()) - np.repeat(np.cumsum(ncol) - ncol, ncol))
        wr, wc = np.mod(p_row, G), np.mod(p_col, G)
        shift = np.stack([(p_col - wc) // G, (p_row - wr) // G], -1) * self.P  # lattice shift (x, y)
        cell = wr * G + wc
        order = np.argsort(cell, kind="stable")
        self.piece_tri = p_tri[order]
        self.piece_shift = shift[order]
        counts = np.bincount(cell, minlength=G * G)
        self.cell_start = np.concatenate([[0], np.cumsum(counts)])

    def _candidates(self, points: np.ndarray):
        """(ray index, piece index, wrapped sheared point) for every ray x piece-in-its-cell pair."""
        u = points[:, :2] - points[:, 2:3] * self.shear
        uw = np.mod(u, self.P)
        cx = np.minimum((uw[:, 0] / self.h).astype(np.int64), self.G - 1)
        cy = np.minimum((uw[:, 1] / self.h).astype(np.int64), self.G - 1)
        cell = cy * self.G + cx
        start = self.cell_start[cell]
        cnt = self.cell_start[cell + 1] - start
        ray = np.repeat(np.arange(points.shape[0]), cnt)
        piece = np.repeat(start, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        return ray, piece, uw

    def _hit_heights(self, points: np.ndarray, chunk: int = 2_000_000):
        """Yield (ray, height of the covering triangle, triangle id) for candidate pairs that
        cover the ray's sheared point."""
        ray, piece, uw = self._candidates(points)
        for a in range(0, ray.size, chunk):
            r, p = ray[a:a + chunk], piece[a:a + chunk]
            t = self.piece_tri[p]
            d = uw[r] + self.piece_shift[p] - self.U0[t]
            e1, e2, det = self.e1[t], self.e2[t], self.det[t]
            b1 = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / det
            b2 = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / det
            tol = 1e-9
            inside = (b1 >= -tol) & (b2 >= -tol) & (b1 + b2 <= 1.0 + tol)
            Zt = self.Z[t]
            zh = Zt[:, 0] + b1 * (Zt[:, 1] - Zt[:, 0]) + b2 * (Zt[:, 2] - Zt[:, 0])
            yield r[inside], zh[inside], self.tri_id[t[inside]]


def occluded(grid: TorusGrid, points: np.ndarray, eps: float) -> np.ndarray:
    """Boolean (N,): is there tile surface on the ray points + tω, t > 0 (shadow/masking, §3.3)?

    A hit counts if it is more than ``eps`` (length units) above the ray origin, which
    excludes the origin's own triangle."""
    points = np.asarray(points, dtype=np.float64)
    occ = np.zeros(points.shape[0], dtype=bool)
    for r, zh, _ in grid._hit_heights(points):
        hit = zh > points[r, 2] + eps
        occ[r[hit]] = True
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
                      eps: float | None = None) -> np.ndarray:
    """V[s, d] = 1 if point s sees direction d unoccluded in the repeated tile (§3.3).

    ``tri`` (T, 3, 3), ``points`` (S, 3) on the surface, ``directions`` (D, 3) with z > 0.
    Returns a bool array (S, D).  Loops over directions; each is one batched ray cast."""
    points = np.asarray(points, dtype=np.float64)
    directions = np.asarray(directions, dtype=np.float64)
    if eps is None:
        span = float(np.ptp(tri[..., 2])) if tri.size else 0.0
        eps = 1e-7 * (float(period) + span)
    V = np.empty((points.shape[0], directions.shape[0]), dtype=bool)
    for d, w in enumerate(directions):
        V[:, d] = ~occluded(TorusGrid(tri, period, w), points, eps)
    return V
