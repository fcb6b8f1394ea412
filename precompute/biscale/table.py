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
"""
from __future__ import annotations

import math

import numpy as np

from ..tables.tabulated_brdf import MAX_FLOATS, TabulatedBRDF, direction_grid
from .brdfs import eval_material, material_lobes
from .directions import normal_grid, normal_splat
from .geometry import face_geometry, is_closed_surface
from .visibility import visibility_matrix

__all__ = ["to_tabulated", "tabulate_tile", "closure_res", "table_dir_res", "sharpest_alpha", "MIN_DIR_RES",
           "MAX_DIR_RES", "CLOSURE_RES"]

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


def tabulate_tile(tile, materials, res: int | None = None) -> TabulatedBRDF:
    """The tile's effective BRDF (Wu et al. 2011, eq. 8 / eq. 7) tabulated for the closure at ``res``
    (default ``closure_res(dir_res)``) directly from its facets: for every pair of fine grid
    directions (ωi, ωo),

        f(ωi, ωo) = Σ_s V_s(ωi) V_s(ωo) ΔA_s α_s f_r(n_s, ωi, ωo) (n_s·ωi)+ (n_s·ωo)+ / (a_v(ωo) cos θi)

    (1/sr, RGB), with V ray cast for the fine directions and a_v (eq. 10) from the same visibility;
    made reciprocal as the bake ((T + Tᵀ)/2).  ``tile``: ``BiscaleTile`` (its facets, colour weights
    and groups), ``materials``: the small-scale material dicts.  Cost: one visibility pass over
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
    tri = tile.tile.vertices[tile.tile.faces]
    _, fn = face_geometry(tile.tile.vertices, tile.tile.faces)
    V = visibility_matrix(tri, tile.tile.period, tile.pos, dirs, point_normals=fn[tile.face],
                          closed=is_closed_surface(tile.tile))                       # (S, D) bool
    a_v = np.zeros(D)
    for a in range(0, len(V), _CHUNK):                          # eq. 10, in facet chunks (bounded memory)
        b = a + _CHUNK
        a_v += (V[a:b] * np.clip(tile.n[a:b] @ dirs.T, 0.0, None) * tile.dA[a:b, None]).sum(0)
    normals, nidx, nwt = _normal_groups(tile)
    lobes = [material_lobes(m) for m in materials]
    num = np.zeros((D, D, 3))
    for m, beta, w in tile._groups():                           # (material, colour) groups, §3.7
        for j in np.unique(nidx[w > 0]):
            ws = (nwt * (nidx == j)).sum(1) * w                 # ΔA_s α_s δ̃(n_s, n_j)
            sel = np.flatnonzero(ws > 0)
            if sel.size == 0:
                continue
            W = np.zeros((D, D), np.float32)                   # Σ_s ws V_s(ωi) V_s(ωo)
            for a in range(0, sel.size, _CHUNK):
                Vs = V[sel[a:a + _CHUNK]].astype(np.float32)
                W += (Vs * ws[sel[a:a + _CHUNK], None].astype(np.float32)).T @ Vs
            nj = normals[j]
            c = np.clip(dirs @ nj, 0.0, None)
            f = eval_material(lobes[m], nj, dirs[:, None, :], dirs[None, :, :])   # (D, D, 3)
            num += (W * np.outer(c, c))[..., None] * f * np.asarray(beta)[None, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        T = np.where(a_v[None, :, None] > 1e-12, num / (a_v[None, :, None] * dirs[:, 2][:, None, None]), 0.0)
    T = np.maximum(0.5 * (T + T.transpose(1, 0, 2)), 0.0)
    return TabulatedBRDF(T, res, False, {"source": "biscale", "tabulated_from": "facets", "dir_res": res,
                                         "n_facets": int(len(tile.pos))})
