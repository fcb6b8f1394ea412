"""Multiple scattering on the Smith microsurface of a tabulated NDF (Heitz, Hanika, d'Eon, Dachsbacher
2016, "Multiple-Scattering Microfacet BSDFs with the Smith Model", §3-§5), for the Dong NDF material.

Dong's BRDF (``ndf_brdf``, Dong et al. 2015 eq. 1) is single scattering: F D G2 / (4 cos θi cos θo).
On a rough surface the light its Smith G2 removes is not lost: a mirror height field reflects it again
(the explicit rougher bench surface keeps albedo 1.00 where the single-scattering table has 0.89).
Heitz et al. model the microsurface as a random medium with the *same* NDF and Smith's uncorrelated
heights, and compute its full BRDF by a random walk; single scattering is its first order exactly, so
the multiply-scattered part (orders >= 2) can be added to Dong's table without touching it.

The walk (Heitz et al. 2016, Alg. 1 "sample", conductor phase function; uniform heights, for which
C1(h) = (h + 1)/2 and the walk's state is c = C1(h) in [0, 1]):

* a ray of direction ω_r at height c: upward (ω_r·n > 0) it leaves with probability
  G1(ω_r, c) = c^Λ(ω_r) (§4.1, eq. 17: Smith masking at height h for uncorrelated heights),
  else (and always downward) it hits the surface at the height c' = c / (1 - U)^{1/Λ(ω_r)}
  (inverting the CDF of the next intersection, §4.2 eq. 21); downward directions have
  Λ(-ω) = -1 - Λ(ω) (§4.1);
* at a hit, the micro-normal m is drawn from the distribution of normals visible from ω = -ω_r,
  D_ω(m) = ⟨ω·m⟩₊ D(m) / ∫ ⟨ω·m⟩₊ D dω (§5.1, Heitz 2014 eq. 38), and the ray is mirrored about m
  (a conductor; the material's colour F multiplies each bounce, applied by the caller per order).

For a tabulated NDF, Λ(ω) = ∫ D ⟨ω·m⟩₊ dω / cos θ − 1 comes from ``ndf_brdf._LambdaTable`` (the same Λ
Dong's table uses), and visible normals are drawn by rejection: a node of the NDF's disk table with
probability ∝ its projected-area mass D h² (``ndf_brdf._disk_nodes``) times its bound 1 / m_z,min,
a uniform point of its disk cell, accepted with probability ⟨ω·m⟩₊ / (m_z / m_z,min), m_z,min the
smallest m_z in the cell, so the accepted m has density ∝ ⟨ω·m⟩₊ D(m) dω exactly (D piecewise constant
on the cells).

By reciprocity of the model (§6), a walk started at ω_r = -ωo leaves with direction ωi distributed as
f(ωi, ωo) cos θi: ``walk`` returns the exit directions and orders, ``half_cells`` histograms the orders
>= 2 into the half-vector cells of Dong's table (``tabulated_brdf``, ρ = f cos θi cos θo J per unit
(s, t) area).  Units: none (directions, probabilities).
"""
from __future__ import annotations

import numpy as np

from .. import validation
from ..tables import tabulated_brdf as tb
from .ndf import NDFTable

__all__ = ["SmithMicrosurface", "half_cells", "MAX_ORDER"]

#: Orders tabulated one by one (2 .. MAX_ORDER - 1); the last entry holds every order >= MAX_ORDER
#: (with F = 1 they are < 0.1 % of the light on the rougher bench surface).
MAX_ORDER = 6
#: Bounces after which a walk is cut (its energy is dropped; the 64th bounce of a mirror is < 1e-6 of it).
_MAX_BOUNCES = 64


class SmithMicrosurface:
    """The random-walk microsurface of an ``NDFTable`` (module docstring): Λ, visible normals, heights."""

    def __init__(self, ndf: NDFTable, max_nodes: int = 129):
        from .ndf_brdf import _LambdaTable, _disk_nodes, _node_step

        nd = ndf.normalized()
        m, wt = _disk_nodes(nd, max_nodes)
        self._lambda_up = _LambdaTable(nd)
        self.cell = nd.h * _node_step(nd, max_nodes)           # disk-cell side of a kept node
        mass = wt * m[:, 2]                                    # D h² per node: ∫ D (m·n) dω over its cell
        r_far = np.hypot(np.abs(m[:, 0]) + 0.5 * self.cell, np.abs(m[:, 1]) + 0.5 * self.cell)
        keep = (mass > 0) & (r_far < 0.999)                    # cells reaching the rim carry ~no mass
        self.m, self.mz_min = m[keep], np.sqrt(1.0 - r_far[keep] ** 2)
        q = mass[keep] / self.mz_min
        self.cdf = np.cumsum(q) / q.sum()

    def lam(self, w) -> np.ndarray:
        """Λ(ω) (N,) for unit directions (N, 3) of either hemisphere: Λ(-ω) = -1 - Λ(ω) (§4.1)."""
        up = w[:, 2] >= 0
        wu = np.where(up[:, None], w, -w)
        lu = self._lambda_up(wu)
        return np.where(up, lu, -1.0 - lu)

    def visible_normals(self, u, rng, tries: int = 2000):
        """(micro-normals (N, 3), found (N,)) drawn from D_u(m) ∝ ⟨u·m⟩₊ D(m) for unit directions u (N, 3)
        (module docstring: rejection from the disk cells, exact for the piecewise-constant table).  A
        direction that sees almost no micro-facet (projected area ~0: acceptance < ~1/``tries``) may find
        none: ``found`` False (the walk lets such a ray leave; a ray there hits with probability ~0)."""
        out = np.tile([0.0, 0.0, 1.0], (len(u), 1))
        found = np.zeros(len(u), bool)
        todo = np.arange(len(u))
        for _ in range(tries):
            if not len(todo):
                break
            k = np.minimum(np.searchsorted(self.cdf, rng.random(len(todo))), len(self.cdf) - 1)
            d = (rng.random((len(todo), 2)) - 0.5) * self.cell
            mx, my = self.m[k, 0] + d[:, 0], self.m[k, 1] + d[:, 1]
            mz = np.sqrt(np.maximum(1.0 - mx * mx - my * my, 1e-12))
            m = np.stack([mx, my, mz], -1)
            ok = rng.random(len(todo)) * mz < np.maximum(np.sum(u[todo] * m, 1), 0.0) * self.mz_min[k]
            out[todo[ok]] = m[ok]
            found[todo[ok]] = True
            todo = todo[~ok]
        return out, found

    def next_height(self, w, c, U):
        """(c' (N,), escaped (N,)) of rays of direction w leaving height c = C1(h) (§4.1-4.2, module
        docstring); a horizontal ray stays at its height."""
        lam = self.lam(w)
        up = w[:, 2] > 1e-4
        flat = np.abs(w[:, 2]) <= 1e-4
        g1 = np.where(up, np.power(c, np.maximum(lam, 0.0)), 0.0)
        escaped = up & (U > 1.0 - g1)
        inv = 1.0 / np.where(np.abs(lam) > 1e-9, lam, 1e-9)
        with np.errstate(over="ignore", divide="ignore", under="ignore"):
            c_new = np.clip(c / np.power(np.maximum(1.0 - U, 1e-300), inv), 0.0, 1.0)
        return np.where(flat, c, c_new), escaped

    def walk(self, wo, rng):
        """Random walks started at ω_r = -ωo (ωo (N, 3), unit, upward): (exit directions (N, 3), scattering
        order (N,) int: 0 = never hit (cannot happen from above), -1 = cut after ``_MAX_BOUNCES``)."""
        wo = np.asarray(wo, np.float64)
        w = -wo.copy()
        c = np.ones(len(w))
        order = np.zeros(len(w), int)
        alive = np.arange(len(w))
        for _ in range(_MAX_BOUNCES):
            if not len(alive):
                break
            c_new, esc = self.next_height(w[alive], c[alive], rng.random(len(alive)))
            alive = alive[~esc]
            c[alive] = c_new[~esc]
            u = -w[alive]
            m, found = self.visible_normals(u, rng)
            alive, u, m = alive[found], u[found], m[found]
            order[alive] += 1
            w[alive] = 2.0 * np.sum(u * m, 1, keepdims=True) * m - u
        order[alive] = -1
        return w, order


def half_cells(ndf: NDFTable, res: int, extent: float, paths: int = 20_000, seed: int = 0,
               wo_nodes=None) -> np.ndarray:
    """Multiply-scattered part of the Smith microsurface's BRDF as half-vector cell averages:
    (MAX_ORDER - 1, res², n_o) with entry [k - 2] = orders k (the last: orders >= MAX_ORDER) of
    ρ = f cos θi cos θo J per unit (s, t) area (``tabulated_brdf`` half tables, F = 1), at the ωo nodes
    ``wo_nodes`` (default the half table's: ``direction_grid(res)``); ``paths`` walks per node.
    Estimator: a walk leaving along ωi (density f cos θi dωi) adds cos θo / (4 ωo·h) / (paths cell²) to
    h's cell (dωi = 4 (ωo·h) dωh, cell = 2 extent / res); exits with h outside the table are dropped."""
    validation.check_range("res", res, 2, tb.MAX_RES)
    validation.check_range("extent", extent, 1e-3, 1.0)
    paths = int(validation.check_range("paths", paths, 100, 10_000_000))
    res = int(res)
    surf = SmithMicrosurface(ndf)
    wo_nodes = tb.direction_grid(res) if wo_nodes is None else np.asarray(wo_nodes, np.float64)
    cell = 2.0 * extent / res
    out = np.zeros((MAX_ORDER - 1, res * res, len(wo_nodes)))
    rng = np.random.default_rng(seed)
    batch = max(1, 400_000 // paths)
    for b0 in range(0, len(wo_nodes), batch):
        nodes = np.arange(b0, min(b0 + batch, len(wo_nodes)))
        WO = np.repeat(wo_nodes[nodes], paths, 0)
        wi, order = surf.walk(WO, rng)
        o_idx = np.repeat(nodes, paths)
        ms = (order >= 2) & (wi[:, 2] > 0)
        wi, WO, o_idx, k = wi[ms], WO[ms], o_idx[ms], np.minimum(order[ms], MAX_ORDER) - 2
        h = wi + WO
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        st = tb.hemi_oct_encode(h)
        ij = np.floor((st + extent) / cell).astype(int)
        inside = np.all((ij >= 0) & (ij < res), 1)
        wgt = WO[:, 2] / (4.0 * np.maximum(np.sum(WO * h, 1), 1e-9)) / (paths * cell * cell)
        flat = (k * (res * res) + ij[:, 0] * res + ij[:, 1]) * len(wo_nodes) + o_idx
        out += np.bincount(flat[inside], wgt[inside], out.size).reshape(out.shape)
    return out
