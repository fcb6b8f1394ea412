"""Tilted-GGX lobe tables for a scratch BRDF, ready for the shader (Raymond et al. 2016 eqs. 2 and 5).

``lobe_tables(brdf, K, slices)`` fits, at the shader's ``slices`` φo slice centres (table rows
interpolated there, not averaged: averaging smears the moving mirror peaks), at most K lobes
(``precompute.scratch.lobe_fit``, GGX or Beckmann per lobe) to

- ρm (mono: Fresnel is 1 at grazing view, so ρm has no colour), and
- ρ0 per colour channel: lobe shapes (tilt, width) are fitted once on the channel mean and
  the non-negative weights are re-solved per channel with the shapes fixed, so a coloured
  conductor costs no extra closures.

and attaches to every lobe the γ of eq. 2 at the lobe centre (φi = 2·tilt − φo).  A lossless
profile (ρ0 = ρm) returns no ρ0 lobes.  With ``jitter=True`` every lobe also has a tilt jitter j
(the shader draws the tilt uniformly in [t − j, t + j] per sample: a box of φi width 4 j,
``cycles_ggx.cone_collapse_binned_jittered``).  Angles in radians.

``table_lobes(brdf, slices)`` is the exact alternative (``precompute.scratch.lobe_table``): per slice one
weight per φi bin for ρm and ρ0, γ per bin and the shader's bin-picking CDF; no fit.
"""
from __future__ import annotations

import numpy as np

import sys

from ..tables import cache
from ..cycles import beckmann as cycles_beckmann, ggx as cycles_ggx
from . import lobe_fit, lobe_table
from ..cycles.ggx import cone_collapse_binned, cone_collapse_binned_jittered
from .lobe_fit import phi_bin_centres, phi_bin_edges, relative_l1

__all__ = ["lobe_tables", "nnls_batched", "table_lobes"]

def nnls_batched(A: np.ndarray, b: np.ndarray, iters: int = 300) -> np.ndarray:
    """min ||A x - b||² s.t. x >= 0 for a batch: A [B, m, K], b [B, m] -> x [B, K].

    Projected coordinate descent on the normal equations (vectorised over the batch); K is small.
    """
    AtA = np.einsum("bmk,bml->bkl", A, A)
    Atb = np.einsum("bmk,bm->bk", A, b)
    diag = np.maximum(np.einsum("bkk->bk", AtA), 1e-30)
    x = np.zeros_like(Atb)
    K = A.shape[-1]
    for _ in range(iters):
        for k in range(K):
            r = Atb[:, k] - np.einsum("bl,bl->b", AtA[:, k, :], x) + AtA[:, k, k] * x[:, k]
            x[:, k] = np.maximum(r / diag[:, k], 0.0)
    return x


def _gamma_at_lobes(gamma: np.ndarray, phi_o: np.ndarray, tilts: np.ndarray) -> np.ndarray:
    """γ(φo, φi = 2 t − φo) by nearest φi bin (γ is smooth); ``gamma`` is [S, M] (already at the slices)."""
    M = gamma.shape[1]
    phi_c = 2.0 * tilts - phi_o[:, None]
    i = np.clip(np.floor((phi_c + 0.5 * np.pi) / np.pi * M).astype(int), 0, M - 1)
    return gamma[np.arange(gamma.shape[0])[:, None], i]


def lobe_tables(brdf, K: int = 8, slices: int = 64, error_target: float = 0.03, use_cache: bool = True,
                dists: str = "auto", jitter: bool = False) -> dict:
    """Lobes for the shader: dict with ``m`` and ``0`` (None when lossless) entries, each a dict of
    ``weights [S, K, 3]``, ``tilts [S, K]``, ``widths [S, K]``, ``jitters [S, K]`` (tilt jitter,
    radians; all 0 unless ``jitter``), ``dist [S, K]`` (0 = GGX, 1 = Beckmann), ``gamma [S, K]``,
    ``error [S]`` (rel. L1 of the fitted slice after the energy rescale, worst channel), plus
    ``alpha_x`` and ``phi_o [S]`` (the shader's slice centres).
    ``dists``: "auto" (per lobe, Beckmann or GGX, whichever fits better), "ggx" or "beckmann".
    ``jitter``: also fit a tilt jitter per lobe (``lobe_fit.fit_table(..., jitter=True)``); the
    energy rescale and the per-channel weights use the jittered lobes.
    """
    if not isinstance(K, (int, np.integer)) or not 1 <= K <= 16:
        raise ValueError(f"lobes (K) must be an integer in [1, 16], got {K!r}")
    if not isinstance(slices, (int, np.integer)) or not 4 <= slices <= 512:
        raise ValueError(f"slices must be an integer in [4, 512], got {slices!r}")
    if dists not in ("auto", "ggx", "beckmann"):
        raise ValueError(f"dists must be 'auto', 'ggx' or 'beckmann', got {dists!r}")
    if not isinstance(jitter, (bool, np.bool_)):
        raise ValueError(f"jitter must be True or False, got {jitter!r}")
    arrays = brdf.arrays()
    inputs = {"tables": {k: v for k, v in arrays.items() if k in ("rho0", "rho_m", "gamma")}, "K": int(K),
              "slices": int(slices), "error_target": float(error_target), "dists": dists, "jitter": bool(jitter)}

    def compute():
        return _lobe_tables(brdf, int(K), int(slices), float(error_target), dists, bool(jitter))

    version = cache.code_version(sys.modules[__name__], lobe_fit, cycles_ggx, cycles_beckmann)
    flat = cache.cached_arrays("scratch_lobes", version, inputs, compute, enabled=use_cache)
    out = {"alpha_x": float(flat["alpha_x"][0]), "phi_o": flat["phi_o"], "m": None, "0": None}
    for key in ("m", "0"):
        if f"{key}_weights" in flat:
            out[key] = {f: flat[f"{key}_{f}"] for f in ("weights", "tilts", "widths", "jitters", "dist", "gamma",
                                                        "error")}
            out[key]["dist"] = out[key]["dist"].astype(np.int8)
    return out


def _as_channels(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, np.float64)
    return a[..., None] if a.ndim == 2 else a


def _atoms(fit: dict, phi_o: np.ndarray, edges: np.ndarray, alpha_x: float) -> np.ndarray:
    """Bin-averaged cone collapse of every fitted lobe: [S, K, M] (what Cycles renders per unit weight)."""
    if np.any(fit["jitters"] > 0):
        return cone_collapse_binned_jittered(phi_o[:, None], edges, fit["tilts"], fit["widths"], fit["jitters"],
                                             alpha_x, dist=fit["dist"])
    return cone_collapse_binned(phi_o[:, None], edges, fit["tilts"], fit["widths"], alpha_x, dist=fit["dist"])


def _lobe_tables(brdf, K, slices, error_target, dists, jitter=False) -> dict:
    rho_m = _as_channels(brdf.rho_m)
    rho_0 = _as_channels(brdf.rho0)
    gamma = _as_channels(brdf.gamma)
    M = rho_m.shape[0]
    S = min(slices, M)
    phi_o = lobe_fit.slice_centres(S)
    rows_m = lobe_fit.rows_at(rho_m.mean(-1), phi_o)          # [S, M]: the rows at the shader's slice centres
    rows_0 = lobe_fit.rows_at(rho_0, phi_o)                    # [S, M, C]
    gam = lobe_fit.rows_at(gamma.mean(-1), phi_o)              # [S, M]
    edges = phi_bin_edges(M)
    target_m = rows_m * np.cos(phi_bin_centres(M))[None, :]
    out = {"phi_o": phi_o}

    fm = lobe_fit.fit_table(rows_m, K=K, error_target=error_target, phi_o=phi_o, dists=dists, jitter=jitter)
    ax = float(fm["alpha_x"])
    out["alpha_x"] = np.array([ax])
    A_m = _atoms(fm, phi_o, edges, ax)
    w_m = _conserve_energy(fm["weights"][..., None], A_m, rows_m[..., None], edges)[..., 0]
    err_m = relative_l1(np.einsum("sk,skm->sm", w_m, A_m), target_m)
    out.update({"m_weights": np.repeat(w_m[..., None], 3, -1), "m_tilts": fm["tilts"], "m_widths": fm["widths"],
                "m_jitters": fm["jitters"],
                "m_dist": fm["dist"].astype(np.float64), "m_gamma": _gamma_at_lobes(gam, phi_o, fm["tilts"]),
                "m_error": err_m})
    if not np.allclose(rho_0, rho_m, rtol=1e-6, atol=1e-9):
        f0 = lobe_fit.fit_table(rows_0.mean(-1), K=K, error_target=error_target, phi_o=phi_o, dists=dists,
                                jitter=jitter)
        A_0 = _atoms(f0, phi_o, edges, ax)                                                  # [S, K, M]
        used = (f0["weights"] > 0)[:, :, None]
        A = np.swapaxes(A_0 * used, 1, 2)                                                   # [S, M, K]
        target = rows_0 * np.cos(phi_bin_centres(M))[None, :, None]                          # [S, M, C]
        C = rows_0.shape[-1]
        wc = np.stack([nnls_batched(A, target[..., c]) for c in range(C)], -1)               # [S, K, C]
        wc = _conserve_energy(wc, A_0, rows_0, edges)
        fits = np.einsum("skm,skc->smc", A_0, wc)
        err = np.max([relative_l1(fits[..., c], target[..., c]) for c in range(C)], axis=0)
        if C == 1:
            wc = np.repeat(wc, 3, -1)
        out.update({"0_weights": wc, "0_tilts": f0["tilts"], "0_widths": f0["widths"], "0_jitters": f0["jitters"],
                    "0_dist": f0["dist"].astype(np.float64), "0_gamma": _gamma_at_lobes(gam, phi_o, f0["tilts"]),
                    "0_error": err})
    return out


def _conserve_energy(w: np.ndarray, atoms: np.ndarray, rows: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Scale each slice's (per-channel) weights so the lobes reflect exactly the table's albedo.

    The L1 fit leaves a few percent of energy error; the white-furnace albedo of view φo is
    Σ_i C_i ρ[o, i] (C_i = ∫ cos over bin i, see ``scratch_brdf``) and a lobe's is its cone
    collapse integrated over φi.  ``w`` [S, K, C], ``atoms`` [S, K, M], ``rows`` [S, M, C].
    """
    C_i = np.diff(np.sin(edges))
    target = np.einsum("smc,m->sc", rows, C_i)                          # [S, C]
    lobe_albedo = (atoms * np.diff(edges)).sum(-1)                      # [S, K]
    have = np.einsum("skc,sk->sc", w, lobe_albedo)
    scale = np.where(have > 0, target / np.where(have > 0, have, 1.0), 0.0)
    return w * scale[:, None, :]


#: ``view_slices`` settings of ``table_lobes(quality="preview")``: a live edit's first, quick tables (about a
#: quarter of the φo nodes, moment tolerance 3 % instead of 0.3 %, θo basis rank <= 3 at 3 %), on the same
#: φo grid G, bins M and θo samples as the full tables, so one node tree renders both
PREVIEW = dict(tol_phi=3e-2, max_nodes=33, max_rank=3, tol_theta=3e-2)
QUALITIES = ("full", "preview")


def _table_lobe_inputs(profile, fresnel, resolution, slices, quality):
    inputs = {"profile": profile, "fresnel": fresnel, "resolution": int(resolution), "slices": int(slices)}
    if quality == "preview":
        inputs["quality"] = "preview"
    return inputs, cache.code_version(sys.modules[__name__], lobe_table, sys.modules[__package__ + ".slices"],
                                      cycles_ggx)


def table_lobes_cached(profile, fresnel=None, resolution: int = 256, slices: int = 64, quality: str = "full") -> bool:
    """True if ``table_lobes`` with these arguments is a cache hit (read, not computed)."""
    from . import slices as _view  # noqa: F401 - code_version reads the module

    inputs, version = _table_lobe_inputs(profile, fresnel, resolution, slices, quality)
    return cache.is_cached("scratch_table_lobes", version, inputs)


def table_lobes(profile, fresnel=None, resolution: int = 256, slices: int = 64, use_cache: bool = True,
                quality: str = "full") -> dict:
    """Tabulated-tilt lobes for the shader from exact view slices (``precompute.scratch.slices``; Raymond et
    al. 2016 eqs. 2, 5): per φo node s and φi bin b a narrow GGX lobe aimed at the bin's exit centroid.

    ``profile`` a ``profiles.Profile``; ``fresnel`` None (lossless) or a ``precompute.fresnel`` model;
    ``resolution`` M φi bins; ``slices`` the uniform start of the adaptive φo nodes (refined where the
    interpolated slice errs, ``slices.view_slices``).  Returns a dict:

    - ``phi [S]`` node angles (rad), ``cell [G]`` node interval of each of G uniform φo cells;
    - ``cdf [S, M+1]``, ``total [S]``: the bin-picking distribution p_b = w_b / P of the closure weights
      w_b = mass_b / a_b (a_b what Cycles renders per unit weight, ``lobe_table.box_albedo``);
    - ``alias_prob [S, M]``, ``alias_idx [S, M]``: the alias table of that distribution
      (``lobe_table.alias_table``; the shaders' bin pick);
    - ``cen [S, M]``: the aim code, centroid fraction c (aim uniform in [c - h, c + h] of the bin,
      h = min(c, 1 - c)) plus 2 for even-bounce bins (their exit moves with φo like φo + const);
    - ``coef [S, M / y_group, K, 3]``, ``basis [K, NT, 3]`` (None when lossless): the sampled closure's
      weight is ``P max(Σ_k coef B_k(v), 0)`` per channel, v = 1 - sqrt(cos θo) sampled on NT points;
    - ``alpha_x``, ``alpha_y``, ``y_group``, ``error_m`` (worst interpolated-slice moment error, tolerance
      relaxed beyond 80 deg) and ``error_0`` (worst θo-basis error), ``lost`` (flux the lobes cannot render).
    Cached by a hash of the inputs and the code.  ``quality`` "preview": coarser tables computed about 4x
    faster (``PREVIEW``; same G, M and θo samples), which live edits show while the full ones compute.
    """
    from . import slices as view

    if not isinstance(slices, (int, np.integer)) or not 4 <= slices <= 512 or slices % 2:
        raise ValueError(f"slices must be an even integer in [4, 512], got {slices!r}")
    if not isinstance(resolution, (int, np.integer)) or resolution not in (64, 128, 256, 512):
        raise ValueError(f"resolution must be one of 64, 128, 256, 512; got {resolution!r}")
    if quality not in QUALITIES:
        raise ValueError(f"quality must be one of {', '.join(QUALITIES)}; got {quality!r}")
    levels = max(0, int(np.ceil(np.log2(1024 / slices))))
    inputs, version = _table_lobe_inputs(profile, fresnel, resolution, slices, quality)

    def compute():
        if quality == "preview":   # a quarter of the start intervals (>= 8), refined down to the same grid
            base = max(8, int(slices) // 4)
            vs = view.view_slices(profile, int(resolution), fresnel, base=base,
                                  levels=levels + int(np.log2(int(slices) // base)), **PREVIEW)
        else:
            vs = view.view_slices(profile, int(resolution), fresnel, base=int(slices), levels=levels, cache=use_cache)
        return _table_lobes(vs)

    flat = cache.cached_arrays("scratch_table_lobes", version, inputs, compute, enabled=use_cache)
    out = {k: flat[k] for k in ("phi", "cdf", "total", "cen")}
    out["cell"] = flat["cell"].astype(np.int64)
    for k in ("alpha_x", "alpha_y", "error_m", "error_0", "lost"):
        out[k] = float(flat[k][0])
    out["y_group"] = int(flat["y_group"][0])
    out["coef"] = flat.get("coef")
    out["basis"] = flat.get("basis")
    # the alias table of the bin-picking distribution: what both render paths sample bins with (one lookup)
    out["alias_prob"], out["alias_idx"] = lobe_table.alias_table(out["cdf"])
    return out


def _table_lobes(vs) -> dict:
    M = vs.bins
    ax = 1e-4
    ay = lobe_table.default_width(M)
    phi_eval = np.clip(vs.phi, -0.5 * np.pi + 1e-4, 0.5 * np.pi - 1e-4)
    a = lobe_table.box_albedo(phi_eval, M, vs.centroid, ay, ax, where=vs.mass > 0)   # empty bins: w = 0 anyway
    ok = a > 1e-3
    w = np.where(ok, vs.mass / np.where(ok, a, 1.0), 0.0)
    cdf, total = lobe_table.proposal(w)
    out = {"phi": vs.phi, "cell": vs.cell_interval.astype(np.float64), "cdf": cdf, "total": total,
           "cen": vs.centroid + 2.0 * vs.even, "alpha_x": np.array([ax]), "alpha_y": np.array([ay]),
           "error_m": np.array([vs.errors["phi"]]), "error_0": np.array([vs.errors["theta"]]),
           "lost": np.array([float(np.max(vs.mass.sum(1) - (vs.mass * ok).sum(1), initial=0.0)) + vs.errors["lost"]]),
           "y_group": np.array([float(vs.y_group)])}
    if vs.basis is not None:
        coef, basis = vs.coef, vs.basis
        if coef.shape[-1] == 1:
            coef, basis = np.repeat(coef, 3, -1), np.repeat(basis, 3, -1)
        out.update(coef=coef, basis=basis)
    return out
