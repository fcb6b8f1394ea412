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

Grazing views (issue 16 item 2, "at every view"): the lamp's highlight on a glossy wall seen at θo 75-85° moves fast with
the view and is sharp in ωi, so the bake's table is ωi 31² (``CLOSURE_RES``) on 31 x 31 view nodes 2.5x denser beyond
65° (``VIEW_NODES``, ``VIEW_GRAZING``): 2,770,563 floats, above ``MAX_FLOATS``, rendered through the node graph on every
path (``scratch_addon.tabulated_material``).  Explicit-geometry renders (SVM, 256 spp, ``bench/out/biscale_truth_svm_views.md``):
groove 80/180 5.5 -> 2.8 %, pyramid 80/0 3.4 -> 1.9 % (seed 0).  Between the view nodes the closure follows the lobe
(``tabulate_tile(view_shift=True)``, ``TabulatedBRDF.view_shift``): off the axes the highlight moves with the view and
blending the bracketing rows left the groove at 78/200 3.8 / 3.0 % dark (seeds 0 / 1); with the shift 2.0 / 1.2 %.
The shift's anchor leans to each row's peak (``tabulated_brdf.view_centroids``, centroid of g², session 10): a metal
floor's highlight under broad dielectric walls (Principled pyramid, 55/300) was moved by the walls' mass centroid,
lamp term +4.9 % over eq. 8, now +1.8 % (a node at the view +1.2 %).
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
           "MAX_DIR_RES", "CLOSURE_RES", "MAX_CLOSURE_RES", "VIEW_NODES", "VIEW_GRAZING", "VIEW_ANCHOR", "VIEW_ANCHOR_GI", "with_indirect", "view_events", "tile_view_grid", "EVENT_STEP_DEG", "MAX_EVENTS",
           "mirror_symmetric", "EVENT_FACETS"]

#: Resolution of tiles with only rough / diffuse materials (the reference mode's default).
MIN_DIR_RES = 10
#: Largest automatic resolution: the bake's cost grows as dir_res⁴ (10: ~80 s, 14: ~250 s for a
#: 10,000-facet groove here); larger values can be asked for explicitly up to what a shader holds.
MAX_DIR_RES = 14
#: Largest resolution whose anisotropic table fits a shader (3 res⁴ floats <= MAX_FLOATS).
MAX_SHADER_DIR_RES = int((MAX_FLOATS / 3) ** 0.25)
#: Largest direction resolution of the closure's table made by ``tabulate_tile`` (3 res² x n_o floats <=
#: ``tabulated_brdf.MAX_TABLE_FLOATS``; above ``MAX_FLOATS`` it renders through the node graph on every path).
MAX_CLOSURE_RES = 40
#: Smallest direction resolution of the closure's table made by ``tabulate_tile`` (bilinear error
#: ~ cell²: pyramid tile, 35° view, lamp direction: -4.1 % at the bake's 10, -1.9 % at 16, -1.1 % at 19
#: against the ray-traced tile, measured; the lamp's highlight on the groove's GGX α 0.2 wall seen at
#: θo 75-85° from the lamp's side, a sun in the bench lamp's direction, view node at the view: -2.7 / -1.2 /
#: -0.1 / 0.0 % at 19 / 23 / 27 / 31, the glossy pyramid at 78/200 -3.5 / -2.6 / -2.2 / -1.8 %:
#: ``bench/out/biscale_truth_svm_views.md``).
CLOSURE_RES = 31
#: View nodes per axis of the closure's view grid (``tile_view_grid``; the graph's F atlas is 2D for view
#: grids: (31 x 33)² texels at ``CLOSURE_RES``).
VIEW_NODES = 31
#: Node density of the view grid (``view_grid_nodes(grazing=...)``): 2.5 x denser beyond |a| = 65° (nodes
#: ~3° apart over 65-85°, ~8° below): the bright grazing side of a glossy wall moves fast with the view.
VIEW_GRAZING = (math.radians(65.0), 2.5)
#: Anchor power of the lobe-following view interpolation (``TabulatedBRDF.view_anchor``: the centroid of g^p of each
#: view node's row, ``tabulated_brdf.view_centroids``).  A tile's rows mix highlights that move with the view (a metal
#: floor's, a wall's) with broad parts that stay put; p = 2 leans to the highlight (Principled pyramid 55/300, lamp
#: term vs eq. 8: +4.9 % with the mass centroid, +1.8 %; p = 4 +1.1 % but the audit's bump +3.4 -> +4.7 %).
VIEW_ANCHOR = 2.0
#: Anchor power of a table that also holds the inter-reflected light (``bake.bake_tables``): the mass centroid.  With
#: p = 2 the anchor of a row whose direct highlight and inter-reflected peak are of similar height jumps between
#: them from one view node to the next: the groove (diffuse + glossy) table + inter-reflections rendered 13.0 % off
#: the explicit tiles' full GI at θo 35° (p = 1: 2.5 %; SVM 128 spp, tests/biscale/test_biscale_truth_gi).
VIEW_ANCHOR_GI = 1.0
#: Facets per block of the visibility products (memory: _CHUNK x res² floats).
_CHUNK = 32768
#: Most distinct facet normals summed exactly; beyond it the normals are splatted onto the bake's grid.
MAX_EXACT_NORMALS = 512
#: Step (degrees) of the view sweeps that find a tile's visibility events (``view_events``).
EVENT_STEP_DEG = 1.0
#: Most events put on nodes per view axis (the rest of the nodes stay spread over the range).
MAX_EVENTS = 6
#: Facets of the fixed sample that scores the visibility events (``view_events``; independent of the bake).
EVENT_FACETS = 10000
#: Seed of that sample's stratification jitter (fixed: the events do not depend on the bake's seed).
EVENT_SEED = 20110725
#: Largest tile (faces) tested for mirror symmetry (``mirror_symmetric``, cost faces²).
MAX_SYMMETRY_FACES = 512


def sharpest_alpha(materials) -> float:
    """Smallest microfacet-equivalent roughness α among small-scale material dicts
    (``precompute.biscale.brdfs``): cook_torrance / ward α, principled Roughness², Blinn-Phong e -> sqrt(2 / (e + 2));
    Lambert: inf; tabulated: 0.1 (unknown sharpness: the automatic maximum)."""
    out = math.inf
    for m in materials:
        model = m.get("model") if isinstance(m, dict) else None
        if model in ("cook_torrance", "ward"):
            out = min(out, float(m.get("alpha", 0.2 if model == "cook_torrance" else 0.3)))
        elif model == "principled":
            out = min(out, max(float(m.get("roughness", 0.5)) ** 2, 1e-3))
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
    dir_res + 2), at most ``MAX_CLOSURE_RES``."""
    return int(min(MAX_CLOSURE_RES, max(CLOSURE_RES, int(dir_res) + 2)))


def _event_sample(tile, n: int):
    """Seed-independent facets scoring the visibility events: per face ``round(n A_f / A)`` (at least one)
    points, stratified in barycentric coordinates by a fixed generator (``EVENT_SEED``), ΔA = A_f / n_f.
    Returns (positions (S, 3), face normals (S, 3), ΔA (S,), face (S,)); the bake's seed does not enter."""
    V, F = tile.vertices, tile.faces
    area, fn = face_geometry(V, F)
    k = np.maximum(np.round(n * area / max(area.sum(), 1e-300)).astype(int), 1)
    face = np.repeat(np.arange(len(F)), k)
    rng = np.random.default_rng(EVENT_SEED)
    # stratified along the sample index of each face (a golden-ratio lattice plus a fixed jitter)
    j = np.arange(len(face)) - np.repeat(np.cumsum(k) - k, k)
    r1 = np.mod((j + rng.random(len(face))) / np.repeat(k, k), 1.0)
    r2 = np.mod(j * 0.5 * (np.sqrt(5.0) - 1.0) + rng.random(len(face)) / np.repeat(k, k), 1.0)
    sq = np.sqrt(r1)
    bary = np.stack([1 - sq, sq * (1 - r2), sq * r2], 1)
    pos = np.einsum("nk,nkd->nd", bary, V[F[face]])
    return pos, fn[face], (area / k)[face], face


def mirror_symmetric(tile, axis: int, tol: float = 1e-6) -> bool:
    """True when the periodic surface of ``tile`` (``geometry.Tile``) is its own mirror image under
    coordinate[axis] -> t - coordinate[axis] for some t (a groove across x, a pyramid): then its visibility
    events along that view axis come in pairs ±e (the view angle a -> -a).  Geometric, triangulation-
    independent test: the mirror images of points inside every face (centroid and three interior points)
    lie inside a face of the periodic surface with the mirrored normal (within ``tol`` x period), for a t
    that maps the highest vertex onto a vertex.  Tiles with more than ``MAX_SYMMETRY_FACES`` faces: False
    (the test costs faces²)."""
    V, F, P = np.asarray(tile.vertices, float), np.asarray(tile.faces), float(tile.period)
    if len(F) > MAX_SYMMETRY_FACES:
        return False
    k, o = int(axis), 1 - int(axis)
    area, fn = face_geometry(V, F)
    keep = area > 1e-12 * P * P
    tri, fn = V[F[keep]], fn[keep]
    bc = np.array([[1, 1, 1], [4, 1, 1], [1, 4, 1], [1, 1, 4]], float) / np.array([[3.0], [6.0], [6.0], [6.0]])
    pts = np.einsum("qk,fkd->fqd", bc, tri).reshape(-1, 3)
    nrm = np.repeat(fn, len(bc), axis=0)
    nrm_m = nrm.copy()
    nrm_m[:, k] *= -1.0
    # barycentric solve of every (point, face) pair, periodic in x and y
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    g = np.stack([np.einsum("fd,fd->f", e1, e1), np.einsum("fd,fd->f", e1, e2), np.einsum("fd,fd->f", e2, e2)], 1)
    det = g[:, 0] * g[:, 2] - g[:, 1] ** 2
    top = int(np.argmax(V[:, 2] * 4 + V[:, o] * 1e-3))
    same = (np.abs(V[:, 2] - V[top, 2]) < tol * P) & \
        (np.abs(np.mod(V[:, o] - V[top, o] + 0.5 * P, P) - 0.5 * P) < tol * P)
    for t in np.unique(np.round(np.mod(V[top, k] + V[same, k], P), 9)):
        q = pts.copy()
        q[:, k] = t - q[:, k]
        found = np.zeros(len(q), bool)
        for sx in (-1, 0, 1):
            for sy in (-1, 0, 1):
                d = q[:, None, :] + np.array([sx * P, sy * P, 0.0]) - tri[None, :, 0]      # (Q, F, 3)
                b1 = np.einsum("qfd,fd->qf", d, e1)
                b2 = np.einsum("qfd,fd->qf", d, e2)
                u = (g[:, 2] * b1 - g[:, 1] * b2) / det
                v = (g[:, 0] * b2 - g[:, 1] * b1) / det
                off = np.abs(np.einsum("qfd,fd->qf", d, fn))
                ok = (u > -tol) & (v > -tol) & (u + v < 1 + tol) & (off < tol * P) & \
                    (np.abs(nrm_m @ fn.T - 1.0) < 1e-6)
                found |= ok.any(1)
        if found.all():
            return True
    return False


def view_events(tile, axis: int, step_deg: float = EVENT_STEP_DEG, limit_deg: float = 80.0,
                max_events: int = MAX_EVENTS) -> np.ndarray:
    """Projected view angles (radians, sorted) where the tile's visible area kinks along one view axis:
    ``axis`` 0 sweeps a = atan2(ox, oz) at b = 0, 1 sweeps b = atan2(oy, oz) at a = 0
    (``tabulated_brdf`` view grids).  A face starting to hide another (a groove's floor behind its wall)
    or turning away happens where a view ray grazes two of the tile's vertices (or the periodic copies of
    one): the candidates are the angles atan2(Δx + kP, Δz) of every vertex pair (Δz > 0, k = -2..2; Δy
    for axis 1), exact.  The visible projected area per face, A_f = Σ_{s in f} V_s(ω) (n_s·ω)+ ΔA_s
    (eq. 10 per face), on a ``step_deg`` sweep tells which candidates are events: a kink gives second
    differences Σ_f |Δ² A_f| ~ slope jump x step around it, a facet changing visibility ~ its area; a
    candidate's score sums them over the sweep samples closer than one step.  Kept: candidates whose score
    exceeds 1/3 of the best candidate's and 3x the sweep's median, at most ``max_events``, 3° apart.

    The same for every bake seed: the facets are a fixed stratified sample (``_event_sample``,
    ``EVENT_FACETS``), not the bake's.  Mirror-symmetric tiles (``mirror_symmetric`` along the axis) get
    symmetric events: the score of ±c is their mean and events are kept in pairs (a lone half of a pair
    that does not fit ``max_events`` is dropped).  Before both (the bake's seeded facets, one-sided
    scores), a symmetric groove got an event at +76.4° only for seed 0, +58.4° for seeds 2-3, +77.1° for
    seed 4, none for 1 and 5, and the glossy pyramid a different six of its eight event pairs per seed.
    For tiles extruded along y (grooves) the events along a are lines of the whole view grid; elsewhere
    they are where the sweep crossed them.  Cost: one visibility pass of ``EVENT_FACETS`` points over
    2 x ``limit_deg`` / ``step_deg`` directions."""
    h = np.radians(float(step_deg))
    lim = np.radians(float(limit_deg))
    m = int(round(lim / h))
    a = h * np.arange(-m, m + 1)                                # symmetric about 0
    d = np.zeros((len(a), 3))
    d[:, int(axis)] = np.tan(a)
    d[:, 2] = 1.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    base = tile.tile if hasattr(tile, "tile") else tile
    pos, nrm, dA, face = _event_sample(base, EVENT_FACETS)
    tri = base.vertices[base.faces]
    V = visibility_matrix(tri, base.period, pos, d, point_normals=nrm, closed=is_closed_surface(base))
    area = np.zeros((len(base.faces), len(a)))
    for c in range(0, len(V), _CHUNK):
        np.add.at(area, face[c:c + _CHUNK],
                  V[c:c + _CHUNK] * np.clip(nrm[c:c + _CHUNK] @ d.T, 0.0, None) * dA[c:c + _CHUNK, None])
    d2 = np.zeros(len(a))
    d2[1:-1] = np.abs(area[:, :-2] - 2.0 * area[:, 1:-1] + area[:, 2:]).sum(0)   # at a[1:-1]
    if d2.max() <= 0:
        return np.zeros(0)
    P = float(base.period)
    vx, vz = base.vertices[:, int(axis)], base.vertices[:, 2]
    dx = (vx[None, :] - vx[:, None])[..., None] + P * np.arange(-2, 3)
    dz = np.broadcast_to((vz[None, :] - vz[:, None])[..., None], dx.shape)
    cand = np.unique(np.round(np.arctan2(dx[dz > 1e-9 * P], dz[dz > 1e-9 * P]), 9))
    sym = mirror_symmetric(base, axis)
    if sym:
        cand = np.unique(np.concatenate([cand, -cand]))
    cand = cand[(cand > a[1]) & (cand < a[-2])]
    if cand.size == 0:
        return np.zeros(0)

    def score_at(c):                                          # Σ d2 over samples within one step of c
        w = np.abs(a[None, :] - c[:, None]) < h * (1 - 1e-6)
        return (w * d2[None, :]).sum(1)

    score = score_at(cand)
    if sym:
        score = 0.5 * (score + score_at(-cand))
    ok = (score > score.max() / 3.0) & (score > 3.0 * np.median(d2[1:-1] + np.roll(d2, -1)[1:-1]))
    far = np.radians(3.0)
    out = []
    for k in np.argsort(-score, kind="stable"):
        if not ok[k] or len(out) >= max_events:
            break
        new = [cand[k]] + ([-cand[k]] if sym and abs(cand[k]) > 1e-9 else [])
        new = [e for e in new if all(abs(e - x) > far for x in out)]
        if len(out) + len(new) > max_events or (sym and len(new) == 1 and abs(cand[k]) > 1e-9):
            continue
        out.extend(float(e) for e in new)
    return np.sort(np.array(out))


def tile_view_grid(tile, n_a: int = VIEW_NODES, n_b: int = VIEW_NODES, grazing=VIEW_GRAZING):
    """View grid (view_a, view_b) (radians) of the closure table for ``tile`` (``BiscaleTile``): ``n_a`` x
    ``n_b`` nodes over ±85° with the tile's visibility events (``view_events``) on nodes, ``grazing``
    (``view_grid_nodes``: denser beyond 65°; None: even spacing, the 19 x 19 grid of earlier bakes)."""
    return (view_grid_nodes(int(n_a), view_events(tile, 0), grazing=grazing),
            view_grid_nodes(int(n_b), view_events(tile, 1), grazing=grazing))


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


def tabulate_tile(tile, materials, res: int | None = None, view=None, view_shift: bool = True,
                  view_anchor: float = VIEW_ANCHOR) -> TabulatedBRDF:
    """The tile's effective BRDF (Wu et al. 2011, eq. 8 / eq. 7) tabulated for the closure at ``res``
    (default ``closure_res(dir_res)``) directly from its facets: for every pair of fine grid
    directions (ωi, ωo),

        f(ωi, ωo) = Σ_s V_s(ωi) V_s(ωo) ΔA_s α_s f_r(n_s, ωi, ωo) (n_s·ωi)+ (n_s·ωo)+ / (a_v(ωo) cos θi)

    (1/sr, RGB), with V ray cast for the fine directions and a_v (eq. 10) from the same visibility;
    made reciprocal as the bake ((T + Tᵀ)/2, i.e. num / 2 x (1 / (a_v(ωo) cos θi) + 1 / (a_v(ωi) cos θo)),
    num the symmetric sum).  ``res`` default: ``closure_res`` on a view grid, at most ``MAX_SHADER_DIR_RES`` (19) on
    the hemi-octahedral ωo grid.  ``tile``: ``BiscaleTile`` (its facets, colour weights
    and groups), ``materials``: the small-scale material dicts.  ``view``: ωo on the hemi-octahedral grid
    (None), on a view grid (view_a, view_b) of projected view angles, or "auto" (``tile_view_grid``: the
    tile's visibility events on nodes; ``tabulated_brdf`` docstring).  ``view_shift`` (view grids; default True): the
    closure interpolates between view nodes by following the lobe (``TabulatedBRDF.view_shift``: each node's row moved
    by the interpolated centroid minus its own), not by blending rows whose highlights sit apart; ``view_anchor``: the power p
    of that centroid (of g^p, ``VIEW_ANCHOR``).  Cost: one visibility pass over
    res² directions plus, per (material, colour, normal) group, a (res² x S_g) @ (S_g x res²) product
    and one BRDF evaluation on res⁴ pairs.  Returns an anisotropic ``TabulatedBRDF``."""
    if res is None:     # hemi-octahedral ωo (view None): at most what OSL compiles (its graph atlas is n_o (res + 2) tall)
        res = closure_res(tile.opts["dir_res"]) if view is not None else min(closure_res(tile.opts["dir_res"]),
                                                                              MAX_SHADER_DIR_RES)
    res = int(res)
    if not 2 <= res <= MAX_CLOSURE_RES:
        raise ValueError(f"res: the table closure holds direction resolutions 2..{MAX_CLOSURE_RES}, got {res}")
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
    if vg:
        if not isinstance(view_shift, (bool, np.bool_)):
            raise ValueError(f"view_shift: must be True or False, got {view_shift!r}")
        vg["view_shift"] = bool(view_shift)
        vg["view_anchor"] = float(view_anchor)
    return TabulatedBRDF(T, res, False, {"source": "biscale", "tabulated_from": "facets", "dir_res": res,
                                         "n_facets": int(len(tile.pos)), "view_grid": int(bool(vg))}, **vg)


def with_indirect(table: TabulatedBRDF, indirect: np.ndarray) -> TabulatedBRDF:
    """``table`` plus the inter-reflected part ``indirect`` (same layout: (res², n_o, 3), ``interreflect.resample_wi``
    / ``resample``), marked ``interreflections``; a view grid keeps its nodes and shift, anchored by
    ``VIEW_ANCHOR_GI`` (the mass centroid: see there)."""
    vg = {} if table.view_a is None else {"view_a": table.view_a, "view_b": table.view_b,
                                          "view_shift": table.view_shift, "view_anchor": VIEW_ANCHOR_GI}
    return type(table)(table.table + indirect, table.res, table.iso, {**table.info, "interreflections": 1}, **vg)
