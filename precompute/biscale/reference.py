"""Exact reference mode of a bi-scale effective BRDF (Wu, Dorsey, Rushmeier 2011, eq. 7): the tables
and the numpy twin of the OSL shader (``osl/biscale_reference.osl``, written by
``osl.biscale_reference.generate``) that importance-samples the tabulated BRDF and traces the sample
with ``ray_portal_bsdf``.

The table of ``precompute.biscale.EffectiveBRDF`` (standard BRDF f = f̄r / cos θi, 1/sr, on the
``dir_res`` x ``dir_res`` cell-centred hemi-octahedral grid of ``precompute.biscale.directions``)
is compiled into the source as constant arrays, with one proposal CDF per ωo row.  Per shading point
(surface frame: x = UV tangent made orthogonal to n, y = n x x, z = shading normal n; this is the
tile frame of ``precompute.biscale.fit``):

1. ωo (towards the viewer) -> hemi-octahedral (s, t) -> its 4 bilinear taps; one tap o is picked
   with probability equal to its bilinear weight (an unbiased estimate of the bilinear
   interpolation in ωo that ``EffectiveBRDF.eval`` performs);
2. a cell k of the ωi map is drawn from row o's CDF (probability P_k), and a point is jittered
   uniformly in (s, t) inside the cell; its direction ωi = v/|v|, v = (px, py, 1-|px|-|py|),
   px = (s+t)/2, py = (s-t)/2;
3. the solid-angle pdf is  p(ωi) = P_k / (h² J),  h = 2/res the cell side,
   J = dω/(ds dt) = 1 / (2 |v|³)  (radial projection of the octahedron face, see ``jacobian``);
4. weight = f(ωi, ωo_o) cos θi / p(ωi), with f bilinear in ωi exactly as ``EffectiveBRDF.eval``,
   and the closure is ``weight * ray_portal_bsdf(P, ωi)``.

The estimator's expectation is therefore ∫ ``EffectiveBRDF.eval``(ωi, ωo) L(ωi) cos θi dωi exactly
(no fitting, no interpolation other than ``.eval``'s own).  The proposal P_k ∝ (cell average of the
bilinear interpolant of row o's channel mean) x (∫_cell cos θ dω), mixed with a defensive
``DEFENSIVE`` fraction ∝ the cells' solid angles so that every cell where the interpolant can be
non-zero has P_k > 0.

``ray_portal_bsdf`` is exact but gets no light sampling (NEE), counts as a transparent bounce and
needs the OSL backend: this is a validation/reference renderer, the product path is the fitted
closure mixture (``precompute.biscale.fit``).  ``sample_numpy`` is the numpy twin of the shader's
sampling code (same arrays, same arithmetic) used by the tests without Blender.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ReferenceTables", "reference_tables", "jacobian", "sample_numpy", "MAX_DIR_RES", "DEFENSIVE"]

#: Largest direction grid compiled into a shader (res⁴·4 floats: 40,000 at 10, 82,944 at 12).
MAX_DIR_RES = 12
#: Fraction of the proposal spread over all cells ∝ solid angle (keeps the weights bounded).
DEFENSIVE = 0.02


def jacobian(st: np.ndarray) -> np.ndarray:
    """dω / (ds dt) of the hemi-octahedral map at (s, t) (..., 2): 1 / (2 |v|³).

    The map sends p = (px, py) on the upper octahedron face to v = (px, py, 1-|px|-|py|)/|v|.  A face
    area element dA = √3 dpx dpy seen from the origin subtends dω = (n̂·v̂) dA / |v|² with n̂·v̂ =
    1/(√3 |v|), so dω = dpx dpy / |v|³, and |∂(px, py)/∂(s, t)| = 1/2."""
    st = np.asarray(st, np.float64)
    px = 0.5 * (st[..., 0] + st[..., 1])
    py = 0.5 * (st[..., 0] - st[..., 1])
    z = 1.0 - np.abs(px) - np.abs(py)
    return 0.5 / np.sqrt(px * px + py * py + z * z) ** 3


@dataclass
class ReferenceTables:
    """Arrays compiled into the shader: ``F`` (D, D, 3) the standard BRDF table[i, o], ``cdf``
    (D, D + 1) the proposal CDF over ωi cells per ωo row, ``res``."""
    F: np.ndarray
    cdf: np.ndarray
    res: int


def _cell_integrals(res: int, sub: int = 16):
    """(∫_cell dω, ∫_cell cos θ dω) of every cell of the res x res grid, by a midpoint rule on
    ``sub`` x ``sub`` sub-cells with the analytic Jacobian."""
    h = 2.0 / res
    c = -1.0 + (np.arange(res * sub) + 0.5) * (h / sub)
    S, T = np.meshgrid(c, c, indexing="ij")
    st = np.stack([S, T], -1)
    J = jacobian(st) * (h / sub) ** 2
    px, py = 0.5 * (S + T), 0.5 * (S - T)
    z = 1.0 - np.abs(px) - np.abs(py)
    cos = z / np.sqrt(px * px + py * py + z * z)
    om = J.reshape(res, sub, res, sub).sum((1, 3)).ravel()
    omc = (J * cos).reshape(res, sub, res, sub).sum((1, 3)).ravel()
    return om, omc


def reference_tables(brdf) -> ReferenceTables:
    """Shader arrays for ``brdf`` (a ``precompute.biscale.EffectiveBRDF``), see the module docstring."""
    res = int(getattr(brdf, "dir_res", 0))
    if not (2 <= res <= MAX_DIR_RES):
        raise ValueError(f"dir_res: the reference mode compiles the table into OSL and needs dir_res in "
                         f"[2, {MAX_DIR_RES}], got {res}")
    D = res * res
    F = np.asarray(brdf.table, np.float64)
    if F.shape != (D, D, 3) or not np.all(np.isfinite(F)) or F.min() < 0:
        raise ValueError(f"brdf.table: expected finite non-negative (D, D, 3) with D = {D}, got shape {F.shape}")
    om, omc = _cell_integrals(res)
    # cell average of the bilinear (clamped) interpolant: (1/8, 3/4, 1/8) in s and in t, edges replicated
    g = F.mean(-1).reshape(res, res, D)                       # [row_s, col_t, o]
    k = np.array([0.125, 0.75, 0.125])
    gp = np.pad(g, ((1, 1), (0, 0), (0, 0)), mode="edge")
    g = k[0] * gp[:-2] + k[1] * gp[1:-1] + k[2] * gp[2:]
    gp = np.pad(g, ((0, 0), (1, 1), (0, 0)), mode="edge")
    g = k[0] * gp[:, :-2] + k[1] * gp[:, 1:-1] + k[2] * gp[:, 2:]
    q = g.reshape(D, D).T * omc[None, :]                     # [o, i]
    tot = q.sum(1, keepdims=True)
    q = np.where(tot > 0, q / np.where(tot > 0, tot, 1.0), om[None, :] / om.sum())
    q = (1.0 - DEFENSIVE) * q + DEFENSIVE * om[None, :] / om.sum()
    cdf = np.concatenate([np.zeros((D, 1)), np.cumsum(q, 1)], 1)
    cdf /= cdf[:, -1:]
    cdf[:, -1] = 1.0
    return ReferenceTables(F.astype(np.float32), cdf.astype(np.float32), res)


def sample_numpy(tables: ReferenceTables, wo: np.ndarray, u: np.ndarray):
    """Numpy twin of the shader's sampling: for view directions ``wo`` (N, 3) in the tile frame
    (z > 0) and uniform numbers ``u`` (N, 5) = (h_r, h_c, h_k, h_s, h_t), return (ωi (N, 3),
    weight (N, 3) = f cos θi / pdf, pdf (N,) per steradian)."""
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    u = np.atleast_2d(np.asarray(u, np.float64))
    res, F, cdf = tables.res, tables.F.astype(np.float64), tables.cdf.astype(np.float64)
    D = res * res
    cell = 2.0 / res
    d = np.abs(wo[:, 0]) + np.abs(wo[:, 1]) + wo[:, 2]
    px, py = wo[:, 0] / d, wo[:, 1] / d
    xr = np.clip((px + py + 1) * 0.5 * res - 0.5, 0, res - 1)
    xc = np.clip((px - py + 1) * 0.5 * res - 0.5, 0, res - 1)
    r0 = np.minimum(np.floor(xr).astype(int), res - 2)
    c0 = np.minimum(np.floor(xc).astype(int), res - 2)
    ro = np.where(u[:, 0] < xr - r0, r0 + 1, r0)
    co = np.where(u[:, 1] < xc - c0, c0 + 1, c0)
    o = ro * res + co
    rows = cdf[o]                                              # (N, D + 1)
    k = np.clip((rows[:, 1:] <= u[:, 2:3]).sum(1), 0, D - 1)
    pk = rows[np.arange(len(o)), k + 1] - rows[np.arange(len(o)), k]
    rk, ck = k // res, k % res
    s = -1.0 + (rk + u[:, 3]) * cell
    t = -1.0 + (ck + u[:, 4]) * cell
    qx, qy = 0.5 * (s + t), 0.5 * (s - t)
    v = np.stack([qx, qy, 1 - np.abs(qx) - np.abs(qy)], -1)
    ln = np.linalg.norm(v, axis=1)
    wl = v / ln[:, None]
    pdf = pk / (cell * cell * 0.5 / ln ** 3)
    yr = np.clip((s + 1) * 0.5 * res - 0.5, 0, res - 1)
    yc = np.clip((t + 1) * 0.5 * res - 0.5, 0, res - 1)
    a0 = np.minimum(np.floor(yr).astype(int), res - 2)
    b0 = np.minimum(np.floor(yc).astype(int), res - 2)
    fa, fb = yr - a0, yc - b0
    f = np.zeros((len(o), 3))
    for da in (0, 1):
        for db in (0, 1):
            w = (fa if da else 1 - fa) * (fb if db else 1 - fb)
            f += w[:, None] * F[(a0 + da) * res + b0 + db, o]
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(pk[:, None] > 0, f * wl[:, 2:3] / pdf[:, None], 0.0)
    return wl, weight, pdf
