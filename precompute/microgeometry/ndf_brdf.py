"""A measured NDF (Dong et al. 2015, §5.1 filtered / §6 Kirchhoff, an ``ndf.NDFTable``) as its own
microfacet BRDF table for the tabulated-BRDF closure (``precompute.tables.tabulated_brdf``), instead
of only its ellipsoid fit (§8).

    f(ωi, ωo) = F · D(h) · G2(ωi, ωo) / (4 |ωi·n| |ωo·n|),   h = normalize(ωi + ωo)        (Dong eq. 1)

with D the table (per steradian, ∫ D (m·n) dω = 1), F a constant reflectance (the paper's metals:
F ≈ const over the narrow lobes), and the height-correlated Smith G2 = 1 / (1 + Λ(ωi) + Λ(ωo)), where
Λ comes from the NDF itself: ∫ D(m) ⟨ω·m⟩₊ dω = (1 + Λ(ω)) cos θ  (Heitz 2014, eq. 17; projected
area of the visible microfacets), integrated over the table's disk nodes (dω = dmx dmy / mz).
Each ωi cell is box-averaged over ``sub``² points, so lobes narrower than a cell keep their energy.
"""
from __future__ import annotations

import numpy as np

from ..tables.tabulated_brdf import TabulatedBRDF
from .ndf import NDFTable

__all__ = ["smith_lambda", "ndf_brdf"]


def _disk_nodes(ndf: NDFTable, max_nodes: int = 129):
    """(m (K, 3), weight D h² / mz (K,)) of the table's nodes inside the disk, downsampled by striding."""
    step = max(1, (ndf.resolution - 1) // (max_nodes - 1))
    X, Y = ndf.grid()
    t = ndf.table
    # box-sum the table over step x step blocks so no mass is lost by striding
    if step > 1:
        R = (ndf.resolution - 1) // step * step + 1
        t = t[:R, :R]
        X, Y = X[:R:step, :R:step], Y[:R:step, :R:step]
        pad = np.pad(t, ((0, step - 1), (0, step - 1)))
        t = sum(pad[i::step, j::step][:X.shape[0], :X.shape[1]] for i in range(step) for j in range(step))
    r2 = X ** 2 + Y ** 2
    inside = (r2 < 1 - 1e-9) & (t > 0)
    mz = np.sqrt(1 - r2[inside])
    m = np.stack([X[inside], Y[inside], mz], -1)
    return m, t[inside] * ndf.h ** 2 / mz


def smith_lambda(ndf: NDFTable, w) -> np.ndarray:
    """Λ(ω) (N,) of the NDF for unit directions ω (N, 3) (z > 0): ∫ D ⟨ω·m⟩₊ dω / cos θ − 1."""
    nd = ndf.normalized()
    m, wt = _disk_nodes(nd)
    w = np.atleast_2d(np.asarray(w, np.float64))
    proj = np.maximum(w @ m.T, 0.0) @ wt
    return np.maximum(proj / np.maximum(w[:, 2], 1e-6) - 1.0, 0.0)


def ndf_brdf(ndf: NDFTable, res: int = 16, F=1.0, sub: int = 3) -> TabulatedBRDF:
    """Anisotropic ``TabulatedBRDF`` (1/sr) of the microfacet BRDF of ``ndf`` (module docstring) on the
    ``res`` x ``res`` grid of the closure, reflectance ``F`` (scalar or RGB in [0, 1])."""
    F = np.broadcast_to(np.asarray(F, np.float64), 3)
    if np.any(F < 0) or np.any(F > 1):
        raise ValueError(f"F: expected a reflectance in [0, 1], got {F.tolist()}")
    nd = ndf.normalized()
    lam_cache = {}   # the ωi sample points are the same for every ωo node: Λ(ωi) is computed once

    def lam(w):
        key = hash(w.tobytes())
        if key not in lam_cache:
            if len(lam_cache) > 4:
                lam_cache.pop(next(iter(lam_cache)))
            lam_cache[key] = smith_lambda(nd, w)
        return lam_cache[key]

    def f(wi, wo):
        h = wi + wo
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        D = nd.eval(h)
        G2 = 1.0 / (1.0 + lam(np.ascontiguousarray(wi)) + smith_lambda(nd, wo[:1])[0])
        v = D * G2 / (4.0 * np.maximum(wi[:, 2], 1e-6) * np.maximum(wo[:, 2], 1e-6))
        return v[:, None] * F[None]

    return TabulatedBRDF.from_function(f, res, iso=False, sub=sub, info={"source": f"ndf:{ndf.kind}"})
