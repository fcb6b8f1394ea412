"""Inter-reflections inside the bi-scale tile: the part of the effective BRDF that Wu, Dorsey and
Rushmeier (2011) leave out (their eq. 7 sums one bounce only; their Fig. 12 shows the darkening).

The tile repeats, so light reflected by one facet reaches the others *and* those of the periodic
neighbours.  We path trace inside the infinitely repeated tile (Monte Carlo, numpy, batched over
paths) from the viewer's side:

* for every outgoing direction ωo of a coarse direction grid, ``n_paths`` primary rays from ωo hit
  the tile uniformly over its projected footprint (``visibility.first_hit``), so the mean over paths
  is the macro-surface radiance seen from ωo (the a_v(ωo) normalisation of eq. 8 comes for free);
* at every later path vertex x_k (k >= 2: bounce one and more — the single-bounce term is the exact
  eq. 8 of ``table.tabulate_tile``) next-event estimation towards *every* incident direction ωi of
  the grid at once:  β f_r(n, ωi, ω_prev) (n·ωi)+ V(x_k, ωi)  with V by the exact periodic ray cast
  of ``visibility.visibility_matrix`` (the light is a direction, so no MIS is needed);
* the next direction is drawn from a one-sample mixture of a cosine lobe and a GGX half-vector lobe
  around the facet normal (roughness from the material, ``table.sharpest_alpha``), weight
  f_r cos / pdf_mix (unbiased for every small-scale model, including tabulated ones), and the next
  vertex is found by ``periodic_ray_cast`` (exact: the ray walks the lattice of tile copies);
  Russian roulette after ``rr_depth`` bounces.

The indirect table f_ind(ωi, ωo) = L_ind(ωo) / cos θi (1/sr, RGB) has two estimators per entry: the
camera path from ωo with NEE towards ωi, and (reciprocity) the camera path from ωi with NEE towards ωo.
They are combined by multiple importance sampling (balance heuristic on the full path densities in area
measure: primary hit (n·ω)/cos θ, the sampling mixture's density at every vertex, forward and reverse;
the 1/d² terms are shared): a caustic such as lamp -> glossy wall -> diffuse floor -> viewer is hard to
hit from the viewer's side and easy from the light's (measured, groove, view 0/0, 289 paths: seed spread
4.8 % -> 1.8 % of the env + lamp integral).  The primary hit and the first bounce's direction are
stratified jointly (scrambled 5D Halton).  ``tile_indirect(view=...)`` computes the table at a view grid's
nodes (two paired runs), so that the closure's ωo axis has the tile's visibility events on nodes for the
inter-reflected light too; the ωi axis is resampled bilinearly onto the closure's grid.

``indirect_estimate`` is the cheap per-tile decision (``interreflections="auto"``): the first-bounce
ratio  Σ_s ΔA_s ρ_s (1 - F_s) / Σ_s ΔA_s  with F_s the cosine-weighted sky-view fraction of facet s
(from the visibility already computed for eq. 8) and ρ_s the facet material's albedo; inter-
reflections are switched on when it exceeds ``AUTO_THRESHOLD`` (1 %).

Units: lengths in the tile's unit, BRDF values in 1/sr.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from .brdfs import eval_material, material_lobes
from .directions import direction_bilinear, direction_grid, direction_solid_angles
from .geometry import face_geometry, is_closed_surface
from .visibility import TorusGrid, first_hit, occluded

__all__ = ["periodic_ray_cast", "indirect_table", "indirect_estimate", "resample", "resample_wi", "resample_views",
           "material_albedo",
           "check_mode", "tile_indirect", "indirect_res", "paths_for", "AUTO_THRESHOLD", "INDIRECT_RES", "N_PATHS", "MODES", "MAX_TILES"]

#: "auto": on when ``indirect_estimate`` > AUTO_THRESHOLD; True / False: forced.
MODES = ("auto", True, False)
#: Inter-reflections change the effective BRDF by more than this (first-bounce estimate): on.
AUTO_THRESHOLD = 0.01
#: Direction resolution of the indirect table for diffuse / rough tiles (resampled onto the closure's grid);
#: glossy small-scale materials raise it (``indirect_res``) up to the closure's own resolution.
INDIRECT_RES = 10
#: Paths per outgoing direction at ``INDIRECT_RES``; finer grids get ``N_PATHS`` x 10 / res each
#: (the total grows as res: a sharper table needs more paths for the same noise per render).
N_PATHS = 512
#: Longest horizontal run of a ray, in periods (a ray grazing along a groove crosses many copies; beyond
#: this it is taken as escaped upwards / absorbed downwards: for a tile of relief h, only rays within
#: atan(h / (MAX_TILES P)) of the horizon, < 1e-3 of the cosine-weighted sphere for h <= P).
MAX_TILES = 64
_CHUNK = 1_000_000
#: Most paths traced at once (all outgoing directions together; ~1 KiB of state per path).
MAX_TOTAL_PATHS = 2_000_000


# ----------------------------------------------------------------------------- periodic ray cast
class _CellGrid:
    """Triangles of one tile binned (by their xy bounding box) on a G x G grid of the footprint."""

    def __init__(self, tri: np.ndarray, period: float, cells: int | None = None):
        self.P = float(period)
        T = len(tri)
        G = cells if cells is not None else int(np.clip(round(math.sqrt(T) / 2), 1, 64))
        self.G, self.h = G, self.P / G
        self.tri = tri
        self.zmin, self.zmax = float(tri[..., 2].min()), float(tri[..., 2].max())
        pad = 1e-9 * self.P
        lo = np.clip(np.floor((tri[..., :2].min(1) - pad) / self.h), 0, G - 1).astype(np.int64)
        hi = np.clip(np.floor((tri[..., :2].max(1) + pad) / self.h), 0, G - 1).astype(np.int64)
        nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
        cnt = nx * ny
        t_of = np.repeat(np.arange(T), cnt)
        k = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        cx = lo[t_of, 0] + k % nx[t_of]
        cy = lo[t_of, 1] + k // nx[t_of]
        cell = cy * G + cx
        order = np.argsort(cell, kind="stable")
        self.cell_tri = t_of[order]
        self.cell_start = np.concatenate([[0], np.cumsum(np.bincount(cell, minlength=G * G))])
        self.v0 = tri[:, 0]
        self.e1 = tri[:, 1] - tri[:, 0]
        self.e2 = tri[:, 2] - tri[:, 0]


def _walk(grid: _CellGrid, o: np.ndarray, d: np.ndarray, max_tiles: float):
    """Lattice sub-cells (ray, integer cell x, integer cell y) crossed by rays o + t d inside the
    slab zmin <= z <= zmax: the start cell plus the cell entered at every crossing of a grid line
    (no sort needed: a straight segment enters each convex cell once)."""
    h = grid.h
    dz = d[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_max = np.where(dz > 1e-12, (grid.zmax - o[:, 2]) / dz,
                         np.where(dz < -1e-12, (grid.zmin - o[:, 2]) / dz, np.inf))
    t_max = np.maximum(t_max, 0.0)
    lh = np.linalg.norm(d[:, :2], axis=1)
    t_max = np.minimum(t_max, max_tiles * grid.P / np.maximum(lh, 1e-300))   # horizontal run <= max_tiles P
    rays, cxs, cys = [np.arange(len(o))], [np.floor(o[:, 0] / h)], [np.floor(o[:, 1] / h)]
    for ax in (0, 1):
        a0 = o[:, ax] / h
        a1 = (o[:, ax] + t_max * d[:, ax]) / h
        lo_line = np.where(d[:, ax] > 0, np.floor(a0) + 1, np.floor(a1) + 1)
        n = np.where(d[:, ax] > 0, np.floor(a1) - np.floor(a0),
                     np.where(d[:, ax] < 0, np.floor(a0) - np.floor(a1), 0)).astype(np.int64)
        r = np.repeat(np.arange(len(o)), n)
        k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        line = lo_line[r] + k                                   # grid line index crossed
        t = (line * h - o[r, ax]) / d[r, ax]
        other = 1 - ax
        c_ax = np.where(d[r, ax] > 0, line, line - 1)
        c_ot = np.floor((o[r, other] + t * d[r, other]) / h)
        rays.append(r)
        (cxs, cys)[ax].append(c_ax)
        (cxs, cys)[other].append(c_ot)
    return np.concatenate(rays), np.concatenate(cxs).astype(np.int64), np.concatenate(cys).astype(np.int64), t_max


def periodic_ray_cast(tri: np.ndarray, period: float, o: np.ndarray, d: np.ndarray, t_min: float | None = None,
                      max_tiles: float = MAX_TILES, grid: _CellGrid | None = None):
    """Closest hit of rays o + t d (t > ``t_min``) with the tile ``tri`` (T, 3, 3) repeated with
    period P in x and y: returns (t (N,), triangle id (N,), hit point (N, 3) wrapped into the
    footprint); t = inf, id = -1 where the ray escapes (or runs farther than ``max_tiles`` periods).
    Exact Möller-Trumbore tests against the triangles of every lattice cell the ray crosses."""
    P = float(period)
    grid = grid or _CellGrid(tri, P)
    o = np.asarray(o, np.float64).copy()
    d = np.asarray(d, np.float64)
    t_min = 1e-7 * (P + grid.zmax - grid.zmin) if t_min is None else t_min
    o[:, :2] = np.mod(o[:, :2], P)
    r, cx, cy, t_max = _walk(grid, o, d, max_tiles)
    G = grid.G
    wx, wy = np.mod(cx, G), np.mod(cy, G)
    shift = np.stack([(cx - wx) // G * P, (cy - wy) // G * P, np.zeros(len(cx))], 1)
    cell = wy * G + wx
    start = grid.cell_start[cell]
    cnt = grid.cell_start[cell + 1] - start
    best_t = np.full(len(o), np.inf)
    best_id = np.full(len(o), -1, np.int64)
    # (ray, cell) pairs -> (ray, triangle) pairs, in chunks of bounded size
    csum = np.cumsum(cnt)
    a = 0
    while a < len(cnt):
        b = int(np.searchsorted(csum, (csum[a - 1] if a else 0) + _CHUNK, side="right"))
        b = max(b, a + 1)
        c_cnt = cnt[a:b]
        pr = np.repeat(np.arange(a, b), c_cnt)
        k = np.arange(c_cnt.sum()) - np.repeat(np.cumsum(c_cnt) - c_cnt, c_cnt)
        t_id = grid.cell_tri[np.repeat(start[a:b], c_cnt) + k]
        ray = r[pr]
        oo = o[ray] - shift[pr]                                 # ray origin in the triangle's copy frame
        dd = d[ray]
        e1, e2 = grid.e1[t_id], grid.e2[t_id]
        pv = np.cross(dd, e2)
        det = (e1 * pv).sum(1)
        ok = np.abs(det) > 1e-14 * P * P
        inv = 1.0 / np.where(ok, det, 1.0)
        tv = oo - grid.v0[t_id]
        u = (tv * pv).sum(1) * inv
        qv = np.cross(tv, e1)
        v = (dd * qv).sum(1) * inv
        t = (e2 * qv).sum(1) * inv
        eps = 1e-9
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > t_min) & (t <= t_max[ray] * (1 + 1e-9) + t_min)
        ray, t, t_id = ray[hit], t[hit], t_id[hit]
        np.minimum.at(best_t, ray, t)
        win = t <= best_t[ray]
        best_id[ray[win]] = t_id[win]
        a = b
    pt = o + np.where(np.isfinite(best_t), best_t, 0.0)[:, None] * d
    pt[:, :2] = np.mod(pt[:, :2], P)
    best_id[~np.isfinite(best_t)] = -1
    return best_t, best_id, pt


def _nee_visibility(tri, period, points, normals, dirs, closed, grids):
    """V (N, D) bool: point sees direction d in the repeated tile — ``visibility.visibility_matrix`` with
    the per-direction torus grids built once per path-tracing call (``grids``: list, filled lazily) and
    the facing test as one matrix product."""
    P = float(period)
    span = float(np.ptp(tri[..., 2]))
    eps = 1e-7 * (P + span)
    front = normals @ dirs.T > 0                                  # (N, D)
    Vt = np.zeros((len(dirs), len(points)), bool)
    c = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    zmax_tri = tri[..., 2].max(1)
    if not grids:
        for w in dirs:
            occ = (c @ w < 0) if closed else None
            zt = zmax_tri[occ] if occ is not None else zmax_tri
            grids.append(None if zt.size == 0 else (TorusGrid(tri, P, w, occluders=occ), float(zt.max())))
    z = points[:, 2]
    for d in range(len(dirs)):
        f = front[:, d]
        if grids[d] is None:
            Vt[d] = f
            continue
        g, ztop = grids[d]
        idx = np.flatnonzero(f & (z < ztop - eps))
        Vt[d] = f
        if idx.size:
            Vt[d, idx] = ~occluded(g, points[idx], eps)
    return Vt.T


# ----------------------------------------------------------------------------- sampling
def _frame(n):
    """Orthonormal tangents (t, b) for unit normals n (N, 3) (Duff et al. 2017)."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t = np.stack([1 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]], 1)
    bb = np.stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]], 1)
    return t, bb


def _ggx_D(nh, alpha):
    a2 = alpha * alpha
    return a2 / (np.pi * ((nh * nh) * (a2 - 1.0) + 1.0) ** 2)


def _sample_dirs(rng, n, wo, w_spec, alpha, u=None):
    """One-sample mixture: cosine lobe about n (prob 1 - w_spec) or GGX(α) half vector about n mirrored
    from ωo (prob w_spec).  ``u`` (N, 3): the uniforms (u1, u2, pick) to use (default: drawn from ``rng``).
    Returns (ω (N, 3), pdf (N,)) in solid angle (mixture pdf)."""
    N = len(n)
    t, b = _frame(n)
    if u is None:
        u1, u2, pick = rng.random(N), rng.random(N), rng.random(N)
    else:
        u1, u2, pick = u[:, 0], u[:, 1], u[:, 2]
    phi = 2 * np.pi * u2
    spec = pick < w_spec
    # cosine
    r = np.sqrt(u1)
    wc = (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + np.sqrt(np.maximum(1 - u1, 0))[:, None] * n
    # GGX half vector
    a = np.where(np.isfinite(alpha), alpha, 1.0)
    tan2 = a * a * u1 / np.maximum(1 - u1, 1e-12)
    ch = 1 / np.sqrt(1 + tan2)
    sh = np.sqrt(np.maximum(1 - ch * ch, 0))
    hv = (sh * np.cos(phi))[:, None] * t + (sh * np.sin(phi))[:, None] * b + ch[:, None] * n
    ws = 2 * (wo * hv).sum(1, keepdims=True) * hv - wo
    w = np.where(spec[:, None], ws, wc)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    return w, _dir_pdf(n, wo, w, w_spec, a)


def _dir_pdf(n, wo, w, w_spec, alpha):
    """Solid-angle density of ``_sample_dirs`` drawing ω = ``w`` at normal ``n`` for the view ``wo``
    (arrays broadcast over leading axes, last axis 3; ``w_spec`` / ``alpha`` broadcast like n[..., 0])."""
    cos = (n * w).sum(-1)
    hm = wo + w
    hm = hm / np.maximum(np.linalg.norm(hm, axis=-1, keepdims=True), 1e-300)
    nh = np.clip((n * hm).sum(-1), 0, 1)
    oh = np.abs((wo * hm).sum(-1))
    a = np.where(np.isfinite(alpha), alpha, 1.0)
    pdf_s = np.where(w_spec > 0, _ggx_D(nh, a) * nh / np.maximum(4 * oh, 1e-12), 0.0)
    pdf = (1 - w_spec) * np.maximum(cos, 0) / np.pi + w_spec * pdf_s
    return np.where(cos > 0, pdf, 0.0)


def _sampling_params(mat: dict):
    """(w_spec, α) of the sampling mixture for a small-scale material dict."""
    from .table import sharpest_alpha

    a = sharpest_alpha([mat])
    if not math.isfinite(a):
        return 0.0, math.inf
    model = mat.get("model")
    spec = {"cook_torrance": "ks", "ward": "rho_s", "blinn_phong": "ks"}.get(model)
    diff = {"cook_torrance": "kd", "ward": "rho_d", "blinn_phong": "kd"}.get(model)
    ks = float(np.mean(mat.get(spec, 1.0))) if spec else 1.0
    kd = float(np.mean(mat.get(diff, 0.0))) if diff else 0.5
    return float(np.clip(ks / max(ks + kd, 1e-9), 0.2, 0.8)), max(a, 1e-3)


def material_albedo(mat: dict, n_theta: int = 24, n_phi: int = 48) -> np.ndarray:
    """Directional albedo ∫ f_r cos θi dωi (RGB) of a small-scale material at normal view (midpoint rule)."""
    from ..tables.tabulated_brdf import hemisphere_midpoints

    wi, dw = hemisphere_midpoints(n_theta, n_phi)
    f = eval_material(material_lobes(mat), np.array([0.0, 0.0, 1.0]), wi, np.array([0.0, 0.0, 1.0]))
    return (f * wi[:, 2:3]).sum(0) * dw


# ----------------------------------------------------------------------------- the tile
def _face_colours(tile):
    """Per-face colour weight α (§3.7): the mean of its facets' weights (exact for per-face weights)."""
    F = len(tile.tile.faces)
    acc = np.zeros((F, 3))
    np.add.at(acc, tile.face, tile.alpha)
    cnt = np.bincount(tile.face, minlength=F)[:, None]
    return np.where(cnt > 0, acc / np.maximum(cnt, 1), 1.0)


def indirect_res(materials, closure_res: int = 19) -> int:
    """Direction resolution of the indirect table: ceil(1.2 π / α_min) clamped to [INDIRECT_RES,
    closure_res] (a glossy wall mirrors light onto its neighbours: the indirect term is as sharp as the
    sharpest lobe).  Measured, groove with GGX α = 0.2 walls, lamp directions, 35° / 60° views against
    path tracing at exactly those directions: res 10 -12 % / -20 % of the indirect term, res 19 -4 % / +9 %
    (reference noise ~3 %)."""
    from .table import sharpest_alpha

    a = sharpest_alpha(materials)
    if not math.isfinite(a):
        return INDIRECT_RES
    return int(np.clip(math.ceil(1.2 * math.pi / max(a, 1e-3)), INDIRECT_RES, closure_res))


def paths_for(res: int) -> int:
    """Paths per outgoing direction at ``res``: ``N_PATHS`` x INDIRECT_RES / res (>= 64).  Measured, groove
    tile at res 19, lamp + environment integrals of the indirect term at four views: seed-to-seed
    spread 4-7 % with 142 paths (N_PATHS x 100 / res²), hence more."""
    return int(max(64, round(N_PATHS * INDIRECT_RES / res)))


def indirect_estimate(tile, materials, V=None, dirs=None) -> float:
    """Cheap first-bounce estimate of how much inter-reflections add (fraction of the direct term):
    Σ_s ΔA_s ρ_s (1 - F_s) / Σ_s ΔA_s, F_s = Σ_d V_s(ω_d) (n_s·ω_d)+ Δω_d / π the facet's cosine-
    weighted sky view (``dirs`` and ``V`` default to the tile's eq. 8 grid and visibility), ρ_s the
    largest RGB albedo of its material.  0 for a flat tile."""
    if dirs is None:
        V, dirs = tile.visibility, tile.dirs
    res = int(round(math.sqrt(len(dirs))))
    dw = direction_solid_angles(res)
    F_s = np.zeros(len(tile.pos))
    for a in range(0, len(tile.pos), 32768):
        b = a + 32768
        F_s[a:b] = (V[a:b] * np.clip(tile.n[a:b] @ dirs.T, 0.0, None) * dw).sum(1) / np.pi
    rho = np.array([material_albedo(m).max() for m in materials])[tile.facet_material]
    rho = rho * tile.alpha.max(1)
    return float((tile.dA * rho * np.clip(1.0 - F_s, 0.0, 1.0)).sum() / tile.dA.sum())


def _qmc_points(n: int, rng) -> np.ndarray:
    """``n`` points of a scrambled 5D Halton sequence (scipy.stats.qmc, seeded by ``rng``): the primary hit's
    footprint position and the first bounce's direction and lobe pick, stratified jointly."""
    from scipy.stats import qmc

    return qmc.Halton(d=5, scramble=True, seed=rng).random(n)


def indirect_table(tile, materials, res: int = INDIRECT_RES, n_paths: int = N_PATHS, max_bounces: int = 64,
                   rr_depth: int = 3, seed: int = 0, max_tiles: float = MAX_TILES, first_bounce: int = 2,
                   wo=None, wi=None, qmc: bool = True, mis: bool = True):
    """Inter-reflected part of the tile's effective BRDF (bounces >= 2 inside the periodic tile),
    f_ind(ωi, ωo) (1/sr, RGB) on ``direction_grid(res)``: table (D, D, 3), row ωi, column ωo,
    reciprocal.  ``tile``: ``BiscaleTile``; ``materials``: small-scale material dicts.  Monte Carlo:
    ``n_paths`` camera paths per ωo, next-event estimation to all ωi at every vertex after the first,
    ``max_bounces`` inside the tile, Russian roulette after ``rr_depth``; deterministic for a ``seed``.
    ``first_bounce`` = 1 also estimates the single-bounce term (eq. 8; a check of the normalisation
    against ``table.tabulate_tile``).  ``wo`` (O, 3) / ``wi`` (I, 3): arbitrary outgoing / incident
    directions instead of the grid (then the table is (I, O, 3), not made reciprocal).
    ``qmc``: the primary hit and the first bounce's direction from one scrambled 5D Halton set per ωo.
    ``mis``: on the grid, each entry is the sum of the two estimators (camera path from ωo with NEE to ωi,
    and from ωi with NEE to ωo, the transpose) weighted by the balance heuristic of their path densities
    (a caustic lamp -> glossy wall -> diffuse floor -> viewer is hard from the viewer's side and easy from
    the light's); False: their plain mean.  ``mis="pair"`` with ``wo`` and ``wi``: this side's weighted
    estimator only, to be added to the transposed run with ``wo`` and ``wi`` swapped (``tile_indirect``).  Returns
    (table, info dict with the path statistics)."""
    if not 2 <= int(res) <= 32:
        raise ValueError(f"res: expected an integer in [2, 32], got {res!r}")
    if not 1 <= int(n_paths) <= 1_000_000:
        raise ValueError(f"n_paths: expected an integer in [1, 1000000], got {n_paths!r}")
    if not 1 <= int(max_bounces) <= 1000:
        raise ValueError(f"max_bounces: expected an integer in [1, 1000], got {max_bounces!r}")
    rng = np.random.default_rng(seed)
    T = tile.tile
    P = float(T.period)
    tri = T.vertices[T.faces]
    _, fn = face_geometry(T.vertices, T.faces)
    closed = is_closed_surface(T)
    fmat = np.minimum(T.face_material, len(materials) - 1)
    fcol = _face_colours(tile)
    lobes = [material_lobes(m) for m in materials]
    samp = np.array([_sampling_params(m) for m in materials])     # (M, 2): w_spec, α
    grid = _CellGrid(tri, P)
    grids = []                                                   # torus grids of the NEE directions
    dirs = direction_grid(int(res)) if wi is None else np.asarray(wi, np.float64).reshape(-1, 3)
    dirs_o = direction_grid(int(res)) if wo is None else np.asarray(wo, np.float64).reshape(-1, 3)
    D, Do = len(dirs), len(dirs_o)
    if Do * math.ceil(math.sqrt(int(n_paths))) ** 2 > MAX_TOTAL_PATHS:   # all paths live at once: bounded memory
        raise ValueError(f"n_paths: at most {MAX_TOTAL_PATHS // Do} paths per outgoing direction for {Do} "
                         f"directions (memory), got {n_paths!r}")
    # --- primary hits: stratified over the sheared footprint, per ωo
    m_side = max(1, int(math.ceil(math.sqrt(n_paths))))
    n_p = m_side * m_side
    pos, fid, oidx, wprev, u_first = [], [], [], [], []
    z_top = float(tri[..., 2].max()) + P
    for o, w in enumerate(dirs_o):
        g = TorusGrid(tri, P, w)
        if qmc:     # (footprint x, y, first direction u1, u2, lobe pick): one scrambled 5D Halton set per ωo
            q = _qmc_points(n_p, rng)
            u, u1 = q[:, :2] * P, q[:, 2:]
        else:
            ij = np.stack(np.meshgrid(np.arange(m_side), np.arange(m_side), indexing="ij"), -1).reshape(-1, 2)
            u, u1 = (ij + rng.random((n_p, 2))) * (P / m_side), rng.random((n_p, 3))
        z, tid = first_hit(g, u, z_top)
        ok = tid >= 0
        p = np.concatenate([u + z[:, None] * g.shear, z[:, None]], 1)
        pos.append(p[ok]), fid.append(tid[ok]), oidx.append(np.full(ok.sum(), o)), wprev.append(np.tile(w, (ok.sum(), 1)))
        u_first.append(u1[ok])
    pos, fid, oidx, wprev, u_first = map(np.concatenate, (pos, fid, oidx, wprev, u_first))
    beta = np.ones((len(pos), 3))
    # MIS (balance heuristic) between the two estimators of one table entry: the camera path from ωo with
    # NEE towards ωi (this one) and the camera path from ωi with NEE towards ωo (its transpose).  ratio:
    # p_B / p_A of the path so far (vertex densities in area measure; the 1/d² terms are shared)
    sym = wi is None and wo is None
    mis = (bool(mis) and sym) or (isinstance(mis, str) and mis == "pair")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = dirs_o[oidx, 2] / np.maximum((fn[fid] * wprev).sum(1), 1e-12)   # 1 / prim(v1 | ωo)
    acc = np.zeros((Do, D * 3))
    n_vertices, depth_max = 0, 0
    for depth in range(1, max_bounces + 1):                      # depth: index of the current vertex
        if len(pos) == 0:
            break
        depth_max = depth
        n_vertices += len(pos)
        n = fn[fid]
        m = fmat[fid]
        if depth >= first_bounce:
            # --- next-event estimation to every ωi at this vertex
            Vi = _nee_visibility(tri, P, pos, n, dirs, closed, grids)                  # (N, D)
            bc = beta * fcol[fid]
            for a in range(0, len(pos), 4096):
                sl = slice(a, a + 4096)
                ns, ms, wp = n[sl], m[sl], wprev[sl]
                contrib = np.zeros((len(ns), D, 3))
                for mi in np.unique(ms):
                    s = np.flatnonzero(ms == mi)
                    fi = eval_material(lobes[mi], ns[s, None, :], dirs[None, :, :], wp[s, None, :])
                    cosi = np.clip(ns[s] @ dirs.T, 0.0, None)
                    wgt_i = cosi * Vi[sl][s]
                    if mis:     # weight of this strategy: 1 / (1 + p_B / p_A), p_B's last vertex seen from ωi
                        r = ratio[sl][s, None] * cosi / dirs[None, :, 2]
                        if depth >= 2:
                            rev = _dir_pdf(ns[s, None, :], dirs[None, :, :], wp[s, None, :], samp[mi, 0], samp[mi, 1])
                            r = r * rev / np.maximum(np.abs((ns[s] * wp[s]).sum(1)), 1e-12)[:, None]
                        with np.errstate(invalid="ignore", over="ignore"):
                            wgt_i = wgt_i / (1.0 + np.nan_to_num(r, nan=0.0, posinf=1e300))
                    contrib[s] = fi * wgt_i[..., None] * bc[sl][s, None, :]
                S = sp.csr_matrix((np.ones(len(ns)), (oidx[sl], np.arange(len(ns)))), shape=(Do, len(ns)))
                acc += S @ contrib.reshape(len(ns), -1)
        if depth == max_bounces:
            break
        # --- sample the next direction, trace to the next vertex
        w_spec, alpha = samp[m, 0], samp[m, 1]
        wnew, pdf = _sample_dirs(rng, n, wprev, w_spec, alpha, u_first if depth == 1 else None)
        f = np.zeros((len(pos), 3))
        for mi in np.unique(m):
            s = m == mi
            f[s] = eval_material(lobes[mi], n[s], wnew[s], wprev[s])
        cos = np.clip((n * wnew).sum(1), 0.0, None)
        with np.errstate(divide="ignore", invalid="ignore"):
            wgt = np.where(pdf[:, None] > 0, f * fcol[fid] * cos[:, None] / np.where(pdf > 0, pdf, 1.0)[:, None], 0.0)
        beta = beta * wgt
        if mis:         # vertex j's terms of p_B / p_A: c_out / fwd, and (j >= 2) rev / c_in
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                ratio = ratio * cos / pdf
                if depth >= 2:
                    ratio = ratio * _dir_pdf(n, wnew, wprev, w_spec, alpha) / np.maximum(np.abs((n * wprev).sum(1)), 1e-12)
        live = beta.max(1) > 0
        if depth >= rr_depth:                                    # Russian roulette
            q = np.clip(beta.max(1), 0.05, 1.0)
            live &= rng.random(len(q)) < q
            beta = beta / q[:, None]
        o_off = pos + 1e-7 * (P + grid.zmax - grid.zmin) * n
        t, tid2, hit = periodic_ray_cast(tri, P, o_off[live], wnew[live], grid=grid, max_tiles=max_tiles)
        got = tid2 >= 0
        keep = np.flatnonzero(live)[got]
        pos, fid, oidx, wprev, beta, ratio = hit[got], tid2[got], oidx[keep], -wnew[keep], beta[keep], ratio[keep]
        front = (fn[fid] * wprev).sum(1) > 0                     # hits on a back face: numerical slivers
        pos, fid, oidx, wprev, beta, ratio = pos[front], fid[front], oidx[front], wprev[front], beta[front], ratio[front]
    L = acc.reshape(Do, D, 3) / n_p                              # [o, i, c]: radiance towards ωo
    table = L.transpose(1, 0, 2) / dirs[:, 2][:, None, None]     # f = L / cos θi, row ωi
    if mis and sym:             # the two MIS-weighted estimators of each entry (reciprocity: f(ωi, ωo) = f(ωo, ωi))
        table = table + table.transpose(1, 0, 2)
    elif sym:
        table = 0.5 * (table + table.transpose(1, 0, 2))
    return table, {"res": int(res), "n_paths": n_p, "vertices": int(n_vertices), "max_depth": depth_max,
                   "seed": int(seed)}


def resample(table: np.ndarray, res_from: int, res_to: int, wo_to=None) -> np.ndarray:
    """A (D, D, 3) table on ``direction_grid(res_from)`` bilinearly resampled in ωi and ωo onto
    ``direction_grid(res_to)`` (``directions.direction_bilinear``, reciprocity kept); ``wo_to`` (O, 3):
    the ωo axis onto these directions instead (a view grid's nodes, ``TabulatedBRDF.view_nodes``)."""
    Df = res_from * res_from

    def weights(w):
        idx, wt = direction_bilinear(w, res_from)
        W = np.zeros((len(w), Df))
        np.add.at(W, (np.repeat(np.arange(len(w)), 4), idx.ravel()), wt.ravel())
        return W
    Wi = weights(direction_grid(res_to))
    Wo = Wi if wo_to is None else weights(np.asarray(wo_to, np.float64).reshape(-1, 3))
    return np.einsum("ia,abc,jb->ijc", Wi, table, Wo, optimize=True)


def resample_wi(table: np.ndarray, res_from: int, res_to: int) -> np.ndarray:
    """The ωi axis of a (res_from², O, 3) table bilinearly resampled onto ``direction_grid(res_to)``."""
    idx, wt = direction_bilinear(direction_grid(res_to), res_from)
    W = np.zeros((res_to * res_to, res_from * res_from))
    np.add.at(W, (np.repeat(np.arange(res_to * res_to), 4), idx.ravel()), wt.ravel())
    return np.einsum("ia,abc->ibc", W, table, optimize=True)


def resample_views(table: np.ndarray, res_from: int, view_a, view_b, res_to: int) -> np.ndarray:
    """A (res_from², NA NB, 3) table whose ωo axis is a view grid (``tabulated_brdf`` docstring) resampled
    onto ``direction_grid(res_to)`` in ωi and ωo (bilinear in ωi's (s, t) and in the view angles)."""
    dirs = direction_grid(res_to)
    D = len(dirs)
    idx, wt = direction_bilinear(dirs, res_from)
    Wi = np.zeros((D, res_from * res_from))
    np.add.at(Wi, (np.repeat(np.arange(D), 4), idx.ravel()), wt.ravel())
    return np.einsum("ia,abc,jb->ijc", Wi, table, _view_weights(dirs, view_a, view_b), optimize=True)


def _view_weights(wo_to, view_a, view_b) -> np.ndarray:
    """(O, NA NB) bilinear weights of the directions ``wo_to`` (O, 3) on the view grid (``tabulated_brdf.view_taps``)."""
    from ..tables.tabulated_brdf import view_taps

    wo_to = np.asarray(wo_to, np.float64).reshape(-1, 3)
    idx, wt = view_taps(wo_to, view_a, view_b)
    W = np.zeros((len(wo_to), len(view_a) * len(view_b)))
    np.add.at(W, (np.repeat(np.arange(len(wo_to)), idx.shape[1]), idx.ravel()), wt.ravel())
    return W


def resample_view_nodes(table: np.ndarray, view_a, view_b, wo_to) -> np.ndarray:
    """The ωo axis of a (D, NA NB, 3) table on a view grid (``view_a``, ``view_b``) bilinearly resampled in the
    view angles onto the directions ``wo_to`` (O, 3) (e.g. a finer view grid's nodes): (D, O, 3)."""
    return np.einsum("abc,jb->ajc", table, _view_weights(wo_to, view_a, view_b), optimize=True)


def check_mode(interreflections):
    """``interreflections``: "auto", True / "on" or False / "off" -> "auto" | True | False (ValueError otherwise)."""
    v = interreflections.lower() if isinstance(interreflections, str) else interreflections
    table = {"auto": "auto", "on": True, "off": False, True: True, False: False}
    if isinstance(v, (bool, np.bool_, str)) and v in table:
        return table[bool(v) if isinstance(v, np.bool_) else v]
    raise ValueError(f"interreflections: expected 'auto', True ('on') or False ('off'), got {interreflections!r}")


def tile_indirect(tile, materials, interreflections="auto", res: int | None = None, n_paths: int | None = None,
                  view=None):
    """The decision and, when on, the indirect table of ``tile`` (``BiscaleTile``) for ``materials``:
    returns (table (D, D, 3) on ``direction_grid(res)`` or None, info dict with ``estimate`` (the
    first-bounce ratio of ``indirect_estimate``), ``interreflections`` (bool) and ``seconds``).
    ``res`` default ``indirect_res(materials)``, ``n_paths`` default ``paths_for(res)``.  ``view``: ωo on
    these directions (O, 3) (a view grid's nodes) instead of the grid: the table is (res², O, 3), the two
    MIS-weighted runs (``indirect_table(mis="pair")``, from ωo and from ωi) added.
    Memoised on the tile by the materials and colour weights (an edit back to a previous material is
    free)."""
    import hashlib
    import json
    import time

    mode = check_mode(interreflections)
    t0 = time.perf_counter()
    est = indirect_estimate(tile, materials)
    on = est > AUTO_THRESHOLD if mode == "auto" else mode
    info = {"estimate": est, "interreflections": bool(on), "mode": str(mode)}
    if not on:
        info["seconds"] = time.perf_counter() - t0
        return None, info
    res = indirect_res(materials) if res is None else int(res)
    n_paths = paths_for(res) if n_paths is None else int(n_paths)
    h = hashlib.sha256(json.dumps(materials, sort_keys=True, default=lambda x: np.asarray(x).tolist()).encode())
    h.update(np.ascontiguousarray(tile.alpha).tobytes())
    if view is not None:
        view = np.asarray(view, np.float64).reshape(-1, 3)
        h.update(view.tobytes())
    key = (h.hexdigest(), int(res), int(n_paths))
    memo = tile.__dict__.setdefault("_indirect_memo", {})
    if key not in memo:
        if len(memo) >= 8:
            memo.pop(next(iter(memo)))
        seed = int(tile.opts["seed"])
        if view is None:
            memo[key] = indirect_table(tile, materials, res=res, n_paths=n_paths, seed=seed)
        else:
            grid = direction_grid(res)
            ta, ia = indirect_table(tile, materials, res=res, n_paths=n_paths, seed=seed, wo=view, wi=grid, mis="pair")
            tb, ib = indirect_table(tile, materials, res=res, n_paths=n_paths, seed=seed + 1, wo=grid, wi=view,
                                    mis="pair")
            memo[key] = (ta + tb.transpose(1, 0, 2), {**ia, "vertices": ia["vertices"] + ib["vertices"],
                                                      "max_depth": max(ia["max_depth"], ib["max_depth"]),
                                                      "view_nodes": len(view)})
    table, mc = memo[key]
    info.update(mc, seconds=time.perf_counter() - t0)
    return table, info
