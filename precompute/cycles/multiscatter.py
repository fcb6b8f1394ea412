"""Cycles' *Multiscatter GGX* (the Glossy node's default distribution) as a factor on single-scatter GGX.

Read from ``intern/cycles/kernel/closure/bsdf_microfacet.h`` (Blender 4.0 ... 5.0),
``microfacet_ggx_preserve_energy``, called for ``CLOSURE_BSDF_MICROFACET_MULTI_GGX_ID`` through
``bsdf_microfacet_setup_fresnel_constant`` with the node's colour c as ``Fss`` (``svm/closure.h``):

- ``rough = sqrt(sqrt(alpha_x alpha_y))`` (= the node's Roughness), ``mu = N . wi`` (wi: towards the viewer);
- ``E = ggx_E(rough, mu)`` (a 32 x 32 table: the directional albedo of single-scatter GGX without Fresnel),
  ``E_avg = ggx_Eavg(rough)`` (32 entries: 2 ∫ E(mu) mu dmu), read with ``lookup_table_read_2D``: linear in
  ``rough`` and in ``mu``, nodes at i / 31;
- ``energy_scale = 1 + (1 - E) / E`` multiplies the single-scatter eval; for c != 1 the weight is multiplied by
  ``(1 + Fms (1 - E) / E) / energy_scale`` with Kulla & Conty's (2017, appendix) ``Fms = c E_avg / (1 - c (1 -
  E_avg))``.

So the closure's BRDF is ``c f_ss(wi, wo) (1 + Fms (1 - E(mu)) / E(mu))``: single-scatter GGX times a factor of the
**view** direction only (not reciprocal).  Cycles ships its tables precomputed (``scene/shader.tables``, Monte
Carlo); here the same quantities are integrated on the same nodes (:func:`ggx_E_table`: VNDF-stratified
quadrature, ~1e-4), so the lookups agree to that accuracy — a render test holds the two together.
"""
from __future__ import annotations

import functools

import numpy as np

from .lookup import lookup_table_read, lookup_table_read_2D

__all__ = ["TABLE_SIZE", "ggx_E_table", "ggx_E", "ggx_E_avg", "F_ms", "multiscatter_factor"]

#: Cycles' ``ggx_E`` table is TABLE_SIZE x TABLE_SIZE over (rough, mu), ``ggx_Eavg`` TABLE_SIZE over rough.
TABLE_SIZE = 32
#: mu at the table's first node (mu = 0 is the horizon, where the albedo has its limit)
_MU_MIN = 1e-4


def vndf_reflect(alpha: float, mu: np.ndarray, u1: np.ndarray, u2: np.ndarray):
    """Visible normals of isotropic GGX (Heitz 2018, Cycles ``microfacet_ggx_sample_vndf``) for views at cosines
    ``mu`` (K,) in the x-z plane, at the sample points (u1, u2) (P,): (h (K, P, 3), view (K, 1, 3), z of the mirror
    direction (K, P))."""
    s = np.sqrt(np.maximum(1.0 - mu * mu, 0.0))
    V = np.stack([alpha * s, np.zeros_like(mu), mu], -1)          # stretched view (isotropic: in the x-z plane)
    V /= np.linalg.norm(V, axis=-1, keepdims=True)
    lensq = V[:, 0] ** 2
    T1 = np.where(lensq[:, None] > 1e-7, np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    T2 = np.cross(V, T1)
    r = np.sqrt(u1)
    tx, ty = r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2)
    w = 0.5 * (1.0 + V[:, 2:3])
    ty = np.sqrt(np.maximum(1.0 - tx ** 2, 0.0)) * (1.0 - w) + ty * w                 # (K, n²)
    tz = np.sqrt(np.maximum(1.0 - tx ** 2 - ty ** 2, 0.0))
    H = tx[..., None] * T1[:, None] + ty[..., None] * T2[:, None] + tz[..., None] * V[:, None]
    H = np.stack([alpha * H[..., 0], alpha * H[..., 1], np.maximum(H[..., 2], 0.0)], -1)
    H /= np.linalg.norm(H, axis=-1, keepdims=True)
    view = np.stack([s, np.zeros_like(mu), mu], -1)[:, None, :]
    lz = 2.0 * np.sum(view * H, -1) * H[..., 2] - view[..., 2]
    return H, view, lz


def _albedo_vndf(alpha: float, mu: np.ndarray, n: int) -> np.ndarray:
    """Directional albedo of single-scatter GGX (no Fresnel) at view cosines ``mu`` (K,): E[G2 / G1(view)] over
    the visible normals (Heitz 2018 sampling on an n x n midpoint grid; the light below the horizon counts 0)."""
    if alpha <= 1e-7:
        return np.ones_like(mu)
    u = (np.arange(n) + 0.5) / n
    u1, u2 = np.meshgrid(u, u, indexing="ij")
    _, _, lz = vndf_reflect(alpha, mu, u1.ravel(), u2.ravel())

    def lam(c):                                                  # Heitz 2014 eq. 72
        c = np.clip(c, 1e-12, 1.0)
        return 0.5 * (np.sqrt(1.0 + alpha * alpha * (1.0 / (c * c) - 1.0)) - 1.0)

    lo = lam(mu)[:, None]
    g = np.where(lz > 0, (1.0 + lo) / (1.0 + lo + lam(lz)), 0.0)
    return g.mean(1)


@functools.lru_cache(maxsize=4)
def ggx_E_table(n: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """(E (32, 32) indexed [rough, mu], E_avg (32,)) on Cycles' nodes rough, mu = i / 31 (mu >= 1e-4).

    E(rough, mu) = ∫ f_ss(ωi, ωo) cos θi dωi for alpha = rough², F = 1 (single-scatter GGX, height-correlated
    Smith G2); E_avg = 2 ∫ E mu dmu (trapezoid on a 4x finer mu grid, linear in E between nodes as Cycles reads
    it).  ~0.5 s, cached."""
    nodes = np.arange(TABLE_SIZE) / (TABLE_SIZE - 1)
    mu = np.maximum(nodes, _MU_MIN)
    E = np.array([_albedo_vndf(r * r, mu, n) for r in nodes])
    fine = np.linspace(0.0, 1.0, 4 * (TABLE_SIZE - 1) + 1)
    Ef = np.array([np.interp(fine, nodes, e) for e in E])
    g = Ef * fine
    E_avg = 2.0 * ((g[:, 1:] + g[:, :-1]) * 0.5 * np.diff(fine)).sum(1)
    return E, E_avg


def ggx_E(rough, mu):
    """Cycles' ``lookup_table_read_2D(rough, mu, ggx_E)``: bilinear on the 32 x 32 nodes; arrays broadcast."""
    return lookup_table_read_2D(ggx_E_table()[0], rough, mu)


def ggx_E_avg(rough):
    """Cycles' ``lookup_table_read(rough, ggx_Eavg)``: linear on the 32 nodes."""
    return lookup_table_read(ggx_E_table()[1], rough)


def F_ms(Fss, E_avg):
    """Kulla & Conty's (2017, appendix) multi-bounce Fresnel as Cycles uses it: Fss E_avg / (1 - Fss (1 - E_avg)),
    with one Fss cancelled (the single-scatter lobe already holds one bounce's Fresnel).  Per channel; dimensionless."""
    Fss = np.asarray(Fss, np.float64)
    return Fss * E_avg / (1.0 - Fss * (1.0 - E_avg))


def multiscatter_factor(rough, mu, colour=1.0):
    """``1 + Fms (1 - E) / E``: Multiscatter GGX's BRDF over ``colour`` x single-scatter GGX (see the module doc).

    ``rough`` the node's Roughness (sqrt(alpha)), ``mu`` the cosine of the view at the closure normal, ``colour``
    the node's colour (per channel; broadcast).  Dimensionless."""
    E = np.maximum(ggx_E(rough, mu), 1e-6)
    Ea = ggx_E_avg(rough)
    return 1.0 + F_ms(colour, Ea) * (1.0 - E) / E
