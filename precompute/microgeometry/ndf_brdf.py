"""A measured NDF (Dong et al. 2015, §5.1 filtered / §6 Kirchhoff, an ``ndf.NDFTable``) as its own
microfacet BRDF table for the tabulated-BRDF closure (``precompute.tables.tabulated_brdf``), instead
of only its ellipsoid fit (§8).

    f(ωi, ωo) = F · D(h) · G2(ωi, ωo) / (4 |ωi·n| |ωo·n|),   h = normalize(ωi + ωo)        (Dong eq. 1)

with D the table (per steradian, ∫ D (m·n) dω = 1), F a constant reflectance (the paper's metals:
F ≈ const over the narrow lobes), and the height-correlated Smith G2 = 1 / (1 + Λ(ωi) + Λ(ωo)), where
Λ comes from the NDF itself: ∫ D(m) ⟨ω·m⟩₊ dω = (1 + Λ(ω)) cos θ  (Heitz 2014, eq. 17; projected
area of the visible microfacets), integrated over the table's disk nodes (dω = dmx dmy / mz).

**Layout (adaptive resolution).**  Measured NDFs are sharp (filtered NDFs of polished metals: rms
slopes of a few 0.01): on the closure's ωi grid a 16² table cannot hold them (albedo 1.22 from
under-resolution).  The table is a *half-vector* table (``TabulatedBRDF(half=True)``): its cells tile
h over the diamond |px| + |py| <= Z that holds the NDF (``table_layout``: the zoom Z from the NDF's
support, the side ``res`` as fine as a shader table allows), each cell holds the
exact mass of D in the cell per unit (s, t) area (∫_cell D dωh / cell², sub-sampled at the NDF
table's own node spacing, so the mass is kept whatever the lobe width) times the cell-averaged G2 / 4
(ρ = f cos θi cos θo J).
"""
from __future__ import annotations

import sys

import numpy as np
from scipy.ndimage import convolve1d

from .. import validation
from ..tables import tabulated_brdf as tb
from ..tables.prefilter import deconvolve_cells as _rl_deconvolve
from ..tables.tabulated_brdf import TabulatedBRDF
from .ndf import NDFTable

__all__ = ["smith_lambda", "ndf_brdf", "deconvolve_cells", "multiple_scattering_cells", "table_layout", "MAX_HALF_RES"]

#: Largest half-vector grid side of an anisotropic NDF table: res⁴ · 3 floats <= tabulated_brdf.MAX_FLOATS.
MAX_HALF_RES = int((tb.MAX_FLOATS / 3) ** 0.25)


def _node_step(ndf: NDFTable, max_nodes: int = 129) -> int:
    """Fine nodes per kept node of ``_disk_nodes`` (its disk cells are ``step * ndf.h`` wide)."""
    return max(1, (ndf.resolution - 1) // (max_nodes - 1))


def _disk_nodes(ndf: NDFTable, max_nodes: int = 129):
    """(m (K, 3), weight D h² / mz (K,)) of the table's nodes inside the disk, downsampled by striding.
    Each kept node sums the fine nodes of the block *centred* on it (a block starting at the node would
    shift the mass by half a block: a biased mean slope, Λ 0.017 instead of 0 at 69° for a sharp lobe)."""
    step = _node_step(ndf, max_nodes)
    X, Y = ndf.grid()
    t = ndf.table
    if step > 1:
        k = np.ones(step + 1 if step % 2 == 0 else step)
        if step % 2 == 0:
            k[0] = k[-1] = 0.5          # a fine node between two kept ones is shared
        t = convolve1d(convolve1d(t, k, axis=0, mode="constant"), k, axis=1, mode="constant")
        R = (ndf.resolution - 1) // step * step + 1
        t, X, Y = t[:R:step, :R:step], X[:R:step, :R:step], Y[:R:step, :R:step]
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


class _LambdaTable:
    """Λ(ω) from the projected area a(ω) = ∫ D ⟨ω·m⟩₊ dω tabulated on a (θ, φ) grid (bilinear, periodic
    in φ): a is smooth and bounded up to the horizon, Λ = a / cos θ − 1 uses the exact cos θ."""

    def __init__(self, nd: NDFTable, n_theta: int = 91, n_phi: int = 96):
        m, wt = _disk_nodes(nd)
        self.th = np.linspace(0.0, 0.5 * np.pi, n_theta)
        self.n_phi = n_phi
        ph = np.arange(n_phi) * (2 * np.pi / n_phi)
        T, P = np.meshgrid(self.th, ph, indexing="ij")
        w = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
        self.a = (np.maximum(w @ m.T, 0.0) @ wt).reshape(n_theta, n_phi)

    def __call__(self, w) -> np.ndarray:
        th = np.arccos(np.clip(w[:, 2], 0.0, 1.0))
        x = th / self.th[-1] * (len(self.th) - 1)
        i0 = np.minimum(np.floor(x).astype(int), len(self.th) - 2)
        fx = x - i0
        y = np.mod(np.arctan2(w[:, 1], w[:, 0]), 2 * np.pi) / (2 * np.pi) * self.n_phi
        j0 = np.floor(y).astype(int) % self.n_phi
        j1 = (j0 + 1) % self.n_phi
        fy = y - np.floor(y)
        a = ((1 - fx) * ((1 - fy) * self.a[i0, j0] + fy * self.a[i0, j1])
             + fx * ((1 - fy) * self.a[i0 + 1, j0] + fy * self.a[i0 + 1, j1]))
        return np.maximum(a / np.maximum(w[:, 2], 1e-6) - 1.0, 0.0)


#: Richardson-Lucy iterations of ``deconvolve_cells`` (20 and 400 give second moments within 2e-4 of 100).
DECONVOLVE_ITERATIONS = 100


def deconvolve_cells(rho: np.ndarray, res: int, iterations: int = DECONVOLVE_ITERATIONS) -> np.ndarray:
    """Node values x >= 0 (res², ...) whose bilinear reconstruction has the cell averages ``rho``: the Richardson-Lucy
    deconvolution ``tables.prefilter.deconvolve_cells`` at the NDF table's iteration count.  (The linear inverse,
    ``prefilter.prefilter_cells``, rings where the lobe is under-resolved or the horizon cuts it off; clamping the
    ringing at 0 and rescaling the column took the mass from the peak: the rougher bench surface's table lost 1.5 %
    albedo and 0.0066 of E[dy²] at 70/90, 0.0047 at normal view; this keeps both within 0.0007.)"""
    return _rl_deconvolve(rho, res, iterations)


def table_layout(ndf: NDFTable, mass: float = 0.9995, max_res: int = MAX_HALF_RES) -> tuple[int, float, float]:
    """(res, extent Z, cells per σ) of the half-vector table of ``ndf``.  Z (hemi-octahedral units, <= 1):
    the diamond |px| + |py| <= Z holds the central ``mass`` of both disk marginals (|p| <= |m| for unit m),
    with a 5 % margin.  res = ``max_res`` (the shader's table budget; a sample's cost does not depend on
    res, and broad lobes lose 2.5 % at 45° already at 16²), so the adaptivity is the zoom: cells of
    2Z / res.  Cells per σ = σ_min res / (2Z), σ_min the NDF's narrowest width (half the central 68.3 %
    interval of the narrower disk marginal: σ for a Gaussian lobe, robust to GGX-like tails whose
    variance is infinite): a diagnostic (second moments blur by ~(2Z/res)²/8 per axis, mass is exact)."""
    validation.check_range("mass", mass, 0.5, 0.99999)
    validation.check_range("max_res", max_res, 2, MAX_HALF_RES)
    x0, x1, y0, y1 = ndf.support_box(mass)
    Z = float(min(1.0, 1.05 * (max(abs(x0), abs(x1)) + max(abs(y0), abs(y1))) + 2 * ndf.h))
    u0, u1, v0, v1 = ndf.support_box(0.6827)
    sigma_min = max(0.5 * (min(u1 - u0, v1 - v0) - 2 * ndf.h), 0.5 * ndf.h)   # support_box pads a node each side
    return int(max_res), Z, float(sigma_min * max_res / (2.0 * Z))


def ndf_brdf(ndf: NDFTable, res: int | None = None, F=1.0, sub: int = 3, extent: float | None = None,
             prefilter: bool = True, multiple_scattering: bool = False, ms_paths: int = 10_000,
             ms_seed: int = 0) -> TabulatedBRDF:
    """Anisotropic half-vector ``TabulatedBRDF`` (1/sr) of the microfacet BRDF of ``ndf`` (module
    docstring), reflectance ``F`` (scalar or RGB in [0, 1]).  ``res`` / ``extent``: the half-vector grid
    (default ``table_layout``: from the NDF's width); ``sub``: sub-points per cell axis for the G2 average
    (D is averaged at the NDF's own node spacing); ``prefilter``: node values whose bilinear reconstruction
    keeps each cell's mass (``deconvolve_cells``; False: the cell averages as node values, a blur by a cell).
    ``multiple_scattering``: add the light Dong's single-scattering model loses to its Smith G2, scattered
    again by the Smith microsurface of the same NDF (Heitz et al. 2016 random walk, orders >= 2, F^k per order
    k: ``multiple_scattering``; ``ms_paths`` walks per ωo node, seed ``ms_seed``; cached).  A mirror (F = 1)
    then keeps its energy: albedo 0.89 -> 0.99 at 70° on the rougher bench surface."""
    for name, flag in (("prefilter", prefilter), ("multiple_scattering", multiple_scattering)):
        if not isinstance(flag, (bool, np.bool_)):
            raise ValueError(f"{name}: expected True or False, got {flag!r}")
    ms_paths = int(validation.check_range("ms_paths", ms_paths, 1000, 1_000_000))
    F = np.broadcast_to(np.asarray(F, np.float64), 3)
    if np.any(F < 0) or np.any(F > 1):
        raise ValueError(f"F: expected a reflectance in [0, 1], got {F.tolist()}")
    validation.check_range("sub", sub, 1, 16)
    nd = ndf.normalized()
    auto_res, auto_Z, cps = table_layout(nd)
    res = auto_res if res is None else int(validation.check_range("res", res, 2, MAX_HALF_RES))
    Z = auto_Z if extent is None else float(validation.check_range("extent", extent, 1e-3, 1.0))
    D_cells = res * res
    # exact cell averages of D over the h cells (solid-angle weighted), sub-sampled at the NDF's node spacing
    cell = 2.0 * Z / res
    sub_d = int(np.clip(np.ceil(2.0 * cell / nd.h), 4, 32))
    st, dst = tb.cell_points(res, sub_d, Z)
    h = tb.hemi_oct_decode(st)
    dw = tb.jacobian(st) * dst
    D_st = (nd.eval(h) * dw).reshape(D_cells, -1).sum(1) / cell ** 2     # ∫_cell D dωh per unit (s, t) area
    # cell-averaged G2 / 4 per (h cell, ωo node): ρ = f cos θi cos θo J = F D J G2 / 4
    lam = _LambdaTable(nd)
    st, _ = tb.cell_points(res, int(sub), Z)
    h = tb.hemi_oct_decode(st)
    wo_nodes = tb.direction_grid(res)
    lam_o = lam(wo_nodes)
    rho = np.empty((D_cells, len(wo_nodes)))               # F = 1; F multiplies below
    for o, wo in enumerate(wo_nodes):
        wi, ok = tb.reflect(np.broadcast_to(wo, h.shape), h)
        G2 = np.where(ok, 1.0 / (1.0 + lam(np.where(ok[:, None], wi, [0, 0, 1.0])) + lam_o[o]), 0.0)
        n_ok = ok.reshape(D_cells, -1).sum(1)           # mean over ωi above the horizon (eval masks the rest)
        rho[:, o] = D_st * 0.25 * G2.reshape(D_cells, -1).sum(1) / np.maximum(n_ok, 1)
    if prefilter:
        rho = deconvolve_cells(rho, res)
    out = rho[:, :, None] * F[None, None, :]
    if multiple_scattering:
        ms = multiple_scattering_cells(nd, res, Z, ms_paths, ms_seed)   # (orders, res², n_o), F = 1
        powers = F[None, :] ** np.arange(2, ms.shape[0] + 2)[:, None]   # F^k per order k >= 2 (RGB)
        grey = bool(np.all(F == F[0]))
        ms = np.einsum("kio,kc->ioc", ms, powers[:, :1] if grey else powers)
        if prefilter:       # the multiply-scattered light lies near the horizon: cell averages would blur it below
            ms = deconvolve_cells(ms, res)
        out = out + ms
    return TabulatedBRDF(out, res, False, {"source": f"ndf:{ndf.kind}", "cells_per_sigma": cps * res / auto_res
                                           * auto_Z / Z, "prefilter": bool(prefilter),
                                           "multiple_scattering": bool(multiple_scattering)}, half=True, extent=Z)


def multiple_scattering_cells(ndf: NDFTable, res: int, extent: float, paths: int = 10_000, seed: int = 0):
    """``multiple_scattering.half_cells`` of ``ndf`` (normalised), cached by content (``tables.cache``: the
    walk costs ~10-20 s CPU on a rough NDF; a colour edit reuses it, F enters per order afterwards)."""
    from ..tables import cache
    from . import multiple_scattering as msc

    nd = ndf.normalized()
    inputs = {"ndf": nd.table.astype(np.float32), "res": int(res), "extent": float(extent), "paths": int(paths),
              "seed": int(seed)}
    version = cache.code_version(msc, sys.modules[__name__])
    got = cache.cached_arrays("ndf_multiple_scattering", version, inputs,
                              lambda: {"ms": msc.half_cells(nd, res, extent, paths, seed)})
    return np.asarray(got["ms"], np.float64)
