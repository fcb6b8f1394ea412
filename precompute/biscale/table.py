"""The bi-scale effective BRDF (Wu, Dorsey, Rushmeier 2011, eq. 7) as a tabulated-BRDF closure
(``precompute.tables.tabulated_brdf``): the product path that renders the table itself, with light
sampling, instead of a fitted closure mixture (§5 "rendering").

``to_tabulated`` reuses the table as it is (same cell-centred hemi-octahedral grid for ωi and ωo,
standard BRDF in 1/sr, anisotropic); ``table_dir_res`` picks the direction resolution from the
sharpest small-scale material, so that a glossy lobe spans at least two cells.

``tabulate_tile`` is the product path: the closure's table on a *finer* direction grid
(``closure_res``) evaluated directly from the tile's facets (eq. 8 with the visibility ray cast for
exactly the fine directions), not interpolated from the coarse bake.  Bilinear interpolation
between ``dir_res`` 10 directions misses shadowing boundaries by 3-4 % (measured, pyramid tile, 35°
view); the closure interpolates the fine table instead.  The sum over facets is grouped by facet
normal (flat-shaded tiles: one normal per face, exact; otherwise the bake's normal splat δ̃ of
eq. 11), so the cost is one visibility pass plus one D x D matrix product per (material, colour,
normal) group, not the bake's dir_res⁴ SVD pipeline.

The view axis (ωo) can be a *view grid* of projected view angles (``tabulated_brdf`` docstring) with the
tile's visibility events on nodes (``view_events``, ``tile_view_grid``; ``tabulate_tile(view="auto")``, the
bake's default): a groove hides its floor progressively from θo = 32° to 54° (walls 0.25 x 0.4, floor
0.3), kinks that fall between hemi-octahedral ωo nodes.  Measured against eq. 8 at the exact views (same
ωi grid, env 0.5 + 0.5 ωi + the bench's area lamp): θo/φo 60/20 lamp part +5.3 % with the 19² hemi-
octahedral nodes, +0.2 % on the 19 x 19 view grid; env + lamp within 0.6 % at 0/0, 35/0, 60/90, 60/20
(hemi-octahedral: up to 1.9 %).
"""
from __future__ import annotations

import math

import numpy as np

from ..tables.tabulated_brdf import MAX_FLOATS, TabulatedBRDF, direction_grid, view_directions, view_grid_nodes
from .brdfs import eval_material, material_lobes
from .directions import normal_grid, normal_splat
from .geometry import face_geometry, is_closed_surface
from .visibility import visibility_matrix

__all__ = ["to_tabulated", "tabulate_tile", "closure_res", "table_dir_res", "sharpest_alpha", "MIN_DIR_RES",
           "MAX_DIR_RES", "CLOSURE_RES", "view_events", "tile_view_grid", "EVENT_STEP_DEG", "MAX_EVENTS"]

#: Resolution of tiles with only rough / diffuse materials (the reference mode's default).
MIN_DIR_RES = 10
#: Largest automatic resolution: the bake's cost grows as dir_res⁴ (10: ~80 s, 14: ~250 s for a
#: 10,000-facet groove here); larger values can be asked for explicitly up to what a shader holds.
MAX_DIR_RES = 14
#: Largest resolution whose anisotropic table fits a shader (3 res⁴ floats <= MAX_FLOATS).
MAX_SHADER_DIR_RES = int((MAX_FLOATS / 3) ** 0.25)
#: Smallest direction resolution of the closure's table made by ``tabulate_tile`` (bilinear error
#: ~ cell²: pyramid tile, 35° view, lamp direction: -4.1 % at the bake's 10, -1.9 % at 16, -1.1 % at 19
#: against the ray-traced tile, measured).
CLOSURE_RES = MAX_SHADER_DIR_RES
#: Facets per block of the visibility products (memory: _CHUNK x res² floats).
_CHUNK = 32768
#: Most distinct facet normals summed exactly; beyond it the normals are splatted onto the bake's grid.
MAX_EXACT_NORMALS = 512
#: Step (degrees) of the view sweeps that find a tile's visibility events (``view_events``).
EVENT_STEP_DEG = 1.0
#: Most events put on nodes per view axis (the rest of the nodes stay spread over the range).
MAX_EVENTS = 6


def sharpest_alpha(materials) -> float:
    """Smallest microfacet-equivalent roughness α among small-scale material dicts
    (``precompute.biscale.brdfs``): cook_torrance / ward α, Blinn-Phong e -> sqrt(2 / (e + 2));
    Lambert: inf; tabulated: 0.1 (unknown sharpness: the automatic maximum)."""
    out = math.inf
    for m in materials:
        model = m.get("model") if isinstance(m, dict) else None
        if model in ("cook_torrance", "ward"):
            out = min(out, float(m.get("alpha", 0.2 if model == "cook_torrance" else 0.3)))
        elif model == "blinn_phong":
            out = min(out, math.sqrt(2.0 / (float(m.get("exponent", 20.0)) + 2.0)))
        elif model == "tabulated":
            out = min(out, 0.1)
    return out


def table_dir_res(materials) -> int:
    """Direction resolution for the table closure: ceil(π / α_min) (a hemi-octahedral cell spans about
    π / res rad, a GGX lobe of roughness α about ±2α around the mirror direction, so two cells per
    half-width), clamped to [MIN_DIR_RES, MAX_DIR_RES]."""
    a = sharpest_alpha(materials)
    res = MIN_DIR_RES if not math.isfinite(a) else math.ceil(math.pi / max(a, 1e-3))
    return int(np.clip(res, MIN_DIR_RES, MAX_DIR_RES))


def to_tabulated(brdf) -> TabulatedBRDF:
    """``EffectiveBRDF`` -> anisotropic ``TabulatedBRDF`` on the same grid (table[i, o], 1/sr)."""
    res = int(brdf.dir_res)
    if res > MAX_SHADER_DIR_RES:
        raise ValueError(f"dir_res: the table closure holds at most dir_res {MAX_SHADER_DIR_RES}, got {res}")
    return TabulatedBRDF(np.asarray(brdf.table, np.float64), res, False,
                         {"source": "biscale", **{k: v for k, v in brdf.info.items() if isinstance(v, (int, float, str))}})


def closure_res(dir_res: int) -> int:
    """Direction resolution of the closure's table for a bake at ``dir_res``: max(CLOSURE_RES,
    dir_res + 2), at most ``MAX_SHADER_DIR_RES`` (what a shader holds, 3 res⁴ <= MAX_FLOATS)."""
    return int(min(MAX_SHADER_DIR_RES, max(CLOSURE_RES, int(dir_res) + 2)))


def view_events(tile, axis: int, step_deg: float = EVENT_STEP_DEG, limit_deg: float = 80.0,
                max_events: int = MAX_EVENTS) -> np.ndarray:
    """Projected view angles (radians, sorted) where the tile's visible area kinks along one view axis:
    ``axis`` 0 sweeps a = atan2(ox, oz) at b = 0, 1 sweeps b = atan2(oy, oz) at a = 0
    (``tabulated_brdf`` view grids).  A face starting to hide another (a groove's floor behind its wall)
    or turning away happens where a view ray grazes two of the tile's vertices (or the periodic copies of
    one): the candidates are the angles atan2(Δx + kP, Δz) of every vertex pair (Δz > 0, k = -2..2; Δy
    for axis 1), exact.  The facets' visible projected area per face, A_f = Σ_{s in f} V_s(ω) (n_s·ω)+ ΔA_s
    (eq. 10 per face), on a ``step_deg`` sweep tells which candidates are events: a kink gives second
    differences Σ_f |Δ² A_f| ~ slope jump x step around it, a facet changing visibility ~ its area.  Kept:
    candidates whose score (the two samples around them) exceeds 1/3 of the best candidate's and 3x the
    sweep's median, at most ``max_events``, 3° apart.  For tiles extruded along y (grooves) the events
    along a are lines of the whole view grid; elsewhere they are where the sweep crossed them.  Cost: one
    visibility pass over 2 x ``limit_deg`` / ``step_deg`` directions."""
    h = np.radians(float(step_deg))
    lim = np.radians(float(limit_deg))
    a = np.arange(-lim, lim + 0.5 * h, h)
    d = np.zeros((len(a), 3))
    d[:, int(axis)] = np.tan(a)
    d[:, 2] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    tri = tile.tile.vertices[tile.tile.faces]
    _, fn = face_geometry(tile.tile.vertices, tile.tile.faces)
    V = visibility_matrix(tri, tile.tile.period, tile.pos, d, point_normals=fn[tile.face],
                          closed=is_closed_surface(tile.tile))
    area = np.zeros((len(tile.tile.faces), len(a)))
    for c in range(0, len(V), _CHUNK):
        np.add.at(area, tile.face[c:c + _CHUNK],
                  V[c:c + _CHUNK] * np.clip(tile.n[c:c + _CHUNK] @ d.T, 0.0, None) * tile.dA[c:c + _CHUNK, None])
    d2 = np.abs(area[:, :-2] - 2.0 * area[:, 1:-1] + area[:, 2:]).sum(0)        # at a[1:-1]
    pair = d2[:-1] + d2[1:]                                   # pair[j]: around the interval (a[j+1], a[j+2])
    if pair.size == 0 or pair.max() <= 0:
        return np.zeros(0)
    P = float(tile.tile.period)
    vx, vz = tile.tile.vertices[:, int(axis)], tile.tile.vertices[:, 2]
    dx = (vx[None, :] - vx[:, None])[..., None] + P * np.arange(-2, 3)
    dz = np.broadcast_to((vz[None, :] - vz[:, None])[..., None], dx.shape)
    cand = np.unique(np.round(np.arctan2(dx[dz > 1e-9 * P], dz[dz > 1e-9 * P]), 9))
    cand = cand[(cand > a[1]) & (cand < a[-2])]
    if cand.size == 0:
        return np.zeros(0)
    j = np.clip(np.floor((cand - a[0]) / h).astype(int) - 1, 0, len(pair) - 1)
    score = pair[j]
    ok = (score > score.max() / 3.0) & (score > 3.0 * np.median(pair))
    out = []
    for k in np.argsort(-score):
        if not ok[k] or len(out) >= max_events:
            break
        if all(abs(cand[k] - e) > np.radians(3.0) for e in out):
            out.append(float(cand[k]))
    return np.sort(np.array(out))


def tile_view_grid(tile, n_a: int = CLOSURE_RES, n_b: int = CLOSURE_RES):
    """View grid (view_a, view_b) (radians) of the closure table for ``tile`` (``BiscaleTile``): ``n_a`` x
    ``n_b`` nodes over ±85° with the tile's visibility events (``view_events``) on nodes."""
    return (view_grid_nodes(int(n_a), view_events(tile, 0)), view_grid_nodes(int(n_b), view_events(tile, 1)))


def _normal_groups(tile):
    """Facet normals for the sum of eq. 8: (normals (G, 3), idx (S, k), weight (S, k)).  Exact (k = 1)
    when the tile has at most ``MAX_EXACT_NORMALS`` distinct facet normals (flat shading), else the
    bake's bilinear splat δ̃ on ``normal_grid(normal_res)`` (k = 4, eq. 11)."""
    key = np.round(tile.n, 9)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    if len(uniq) <= MAX_EXACT_NORMALS:
        nrm = uniq / np.linalg.norm(uniq, axis=1, keepdims=True)
        return nrm, inv.reshape(-1, 1), np.ones((len(inv), 1))
    res_n = int(tile.opts["normal_res"])
    idx, wt = normal_splat(tile.n, res_n)
    return normal_grid(res_n), idx, wt


def tabulate_tile(tile, materials, res: int | None = None, view=None) -> TabulatedBRDF:
    """The tile's effective BRDF (Wu et al. 2011, eq. 8 / eq. 7) tabulated for the closure at ``res``
    (default ``closure_res(dir_res)``) directly from its facets: for every pair of fine grid
    directions (ωi, ωo),

        f(ωi, ωo) = Σ_s V_s(ωi) V_s(ωo) ΔA_s α_s f_r(n_s, ωi, ωo) (n_s·ωi)+ (n_s·ωo)+ / (a_v(ωo) cos θi)

    (1/sr, RGB), with V ray cast for the fine directions and a_v (eq. 10) from the same visibility;
    made reciprocal as the bake ((T + Tᵀ)/2, i.e. num / 2 x (1 / (a_v(ωo) cos θi) + 1 / (a_v(ωi) cos θo)),
    num the symmetric sum).  ``tile``: ``BiscaleTile`` (its facets, colour weights
    and groups), ``materials``: the small-scale material dicts.  ``view``: ωo on the hemi-octahedral grid
    (None), on a view grid (view_a, view_b) of projected view angles, or "auto" (``tile_view_grid``: the
    tile's visibility events on nodes; ``tabulated_brdf`` docstring).  Cost: one visibility pass over
    res² directions plus, per (material, colour, normal) group, a (res² x S_g) @ (S_g x res²) product
    and one BRDF evaluation on res⁴ pairs.  Returns an anisotropic ``TabulatedBRDF``."""
    res = closure_res(tile.opts["dir_res"]) if res is None else int(res)
    if not 2 <= res <= MAX_SHADER_DIR_RES:
        raise ValueError(f"res: the table closure holds direction resolutions 2..{MAX_SHADER_DIR_RES}, got {res}")
    if not isinstance(materials, (list, tuple)) or len(materials) == 0:
        raise ValueError("materials: expected a non-empty list of material dicts")
    if tile.tile.face_material.max() >= len(materials):
        raise ValueError(f"face_material: indices must be in [0, {len(materials) - 1}], "
                         f"got max {tile.tile.face_material.max()}")
    dirs = direction_grid(res)                                  # (D, 3), the closure's cell centres
    D = len(dirs)
    vg = {}
    if isinstance(view, str) and view == "auto":
        view = tile_view_grid(tile)
    if view is not None:
        if not (isinstance(view, (tuple, list)) and len(view) == 2):
            raise ValueError(f"view: expected None, 'auto' or (view_a, view_b), got {view!r}")
        vg = dict(view_a=np.asarray(view[0], np.float64), view_b=np.asarray(view[1], np.float64))
        dirs_o = view_directions(vg["view_a"], vg["view_b"])
    else:
        dirs_o = dirs
    Do = len(dirs_o)
    both = np.concatenate([dirs, dirs_o]) if vg else dirs
    tri = tile.tile.vertices[tile.tile.faces]
    _, fn = face_geometry(tile.tile.vertices, tile.tile.faces)
    V = visibility_matrix(tri, tile.tile.period, tile.pos, both, point_normals=fn[tile.face],
                          closed=is_closed_surface(tile.tile))                       # (S, D [+ Do]) bool
    a_v = np.zeros(len(both))
    for a in range(0, len(V), _CHUNK):                          # eq. 10, in facet chunks (bounded memory)
        b = a + _CHUNK
        a_v += (V[a:b] * np.clip(tile.n[a:b] @ both.T, 0.0, None) * tile.dA[a:b, None]).sum(0)
    a_vo = a_v[D:] if vg else a_v
    a_v = a_v[:D]
    normals, nidx, nwt = _normal_groups(tile)
    lobes = [material_lobes(m) for m in materials]
    num = np.zeros((D, Do, 3))
    for m, beta, w in tile._groups():                           # (material, colour) groups, §3.7
        for j in np.unique(nidx[w > 0]):
            ws = (nwt * (nidx == j)).sum(1) * w                 # ΔA_s α_s δ̃(n_s, n_j)
            sel = np.flatnonzero(ws > 0)
            if sel.size == 0:
                continue
            W = np.zeros((D, Do), np.float32)                  # Σ_s ws V_s(ωi) V_s(ωo)
            for a in range(0, sel.size, _CHUNK):
                Vs = V[sel[a:a + _CHUNK]].astype(np.float32)
                W += (Vs[:, :D] * ws[sel[a:a + _CHUNK], None].astype(np.float32)).T @ Vs[:, -Do:]
            nj = normals[j]
            c = np.clip(dirs @ nj, 0.0, None)
            co = np.clip(dirs_o @ nj, 0.0, None)
            f = eval_material(lobes[m], nj, dirs[:, None, :], dirs_o[None, :, :])   # (D, Do, 3)
            num += (W * np.outer(c, co))[..., None] * f * np.asarray(beta)[None, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):     # num / 2 (1 / (a_v(ωo) cos θi) + 1 / (a_v(ωi) cos θo))
        inv_o = np.where(a_vo > 1e-12, 1.0 / a_vo, 0.0)[None, :] / dirs[:, 2][:, None]
        inv_i = np.where(a_v > 1e-12, 1.0 / a_v, 0.0)[:, None] / dirs_o[:, 2][None, :]
    T = np.maximum(0.5 * num * (inv_o + inv_i)[..., None], 0.0)
    return TabulatedBRDF(T, res, False, {"source": "biscale", "tabulated_from": "facets", "dir_res": res,
                                         "n_facets": int(len(tile.pos)), "view_grid": int(bool(vg))}, **vg)
