"""Tilted-GGX lobe tables for a scratch BRDF, ready for the shader (Raymond et al. 2016 eqs. 2 and 5).

``lobe_tables(brdf, K, slices)`` fits, for ``slices`` φo values, at most K lobes
(``precompute.lobe_fit``) to

- ρm (mono: Fresnel is 1 at grazing view, so ρm has no colour), and
- ρ0 per colour channel: lobe shapes (tilt, width) are fitted once on the channel mean and
  the non-negative weights are re-solved per channel with the shapes fixed, so a coloured
  conductor costs no extra closures.

and attaches to every lobe the γ of eq. 2 at the lobe centre (φi = 2·tilt − φo).  A lossless
profile (ρ0 = ρm) returns no ρ0 lobes.  Angles in radians.
"""
from __future__ import annotations

import numpy as np

import sys

from . import cache, cycles_ggx, lobe_fit
from .cycles_ggx import cone_collapse_binned
from .lobe_fit import phi_bin_centres, phi_bin_edges, relative_l1

__all__ = ["lobe_tables", "downsample_slices", "nnls_batched"]

def downsample_slices(rho: np.ndarray, slices: int) -> np.ndarray:
    """Average groups of φo rows of ``rho[M, M(, C)]`` into ``slices`` rows (M divisible by slices)."""
    M = rho.shape[0]
    if slices > M or M % slices:
        raise ValueError(f"slices must divide the table resolution {M}; got {slices}")
    g = M // slices
    return rho.reshape(slices, g, *rho.shape[1:]).mean(axis=1)


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


def lobe_tables(brdf, K: int = 8, slices: int = 64, error_target: float = 0.03, use_cache: bool = True) -> dict:
    """Lobes for the shader: dict with ``m`` and ``0`` (None when lossless) entries, each a dict of
    ``weights [S, K, 3]``, ``tilts [S, K]``, ``widths [S, K]``, ``gamma [S, K]``, ``error [S]`` (rel. L1 of
    the fitted slice, worst channel), plus ``alpha_x`` and ``phi_o [S]``.
    """
    if not isinstance(K, (int, np.integer)) or not 1 <= K <= 16:
        raise ValueError(f"lobes (K) must be an integer in [1, 16], got {K!r}")
    arrays = brdf.arrays()
    inputs = {"tables": {k: v for k, v in arrays.items() if k in ("rho0", "rho_m", "gamma")}, "K": int(K),
              "slices": int(slices), "error_target": float(error_target)}

    def compute():
        return _lobe_tables(brdf, int(K), int(slices), float(error_target))

    version = cache.code_version(sys.modules[__name__], lobe_fit, cycles_ggx)
    flat = cache.cached_arrays("scratch_lobes", version, inputs, compute, enabled=use_cache)
    out = {"alpha_x": float(flat["alpha_x"][0]), "phi_o": flat["phi_o"], "m": None, "0": None}
    for key in ("m", "0"):
        if f"{key}_weights" in flat:
            out[key] = {f: flat[f"{key}_{f}"] for f in ("weights", "tilts", "widths", "gamma", "error")}
    return out


def _as_channels(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, np.float64)
    return a[..., None] if a.ndim == 2 else a


def _lobe_tables(brdf, K, slices, error_target) -> dict:
    rho_m = _as_channels(brdf.rho_m)
    rho_0 = _as_channels(brdf.rho0)
    gamma = _as_channels(brdf.gamma)
    M = rho_m.shape[0]
    S = min(slices, M)
    rows_m = downsample_slices(rho_m.mean(-1), S)          # [S, M]
    rows_0 = downsample_slices(rho_0, S)                   # [S, M, C]
    gam = downsample_slices(gamma.mean(-1), S)             # [S, M]
    phi_o = phi_bin_centres(S)
    phi_i = phi_bin_centres(M)
    edges = phi_bin_edges(M)
    out = {"phi_o": phi_o}

    def fit_rows(rows):
        return _fit_rows(rows, phi_o, K, error_target)

    fm = fit_rows(rows_m)
    out["alpha_x"] = np.array([fm["alpha_x"]])
    fm["weights"] = _conserve_energy(fm, rows_m[..., None], phi_o, edges)[..., 0]
    w = np.repeat(fm["weights"][..., None], 3, -1)
    out.update({"m_weights": w, "m_tilts": fm["tilts"], "m_widths": fm["widths"],
                "m_gamma": _gamma_at_lobes(gam, phi_o, fm["tilts"]), "m_error": fm["error"]})
    lossless = np.allclose(rho_0, rho_m, rtol=1e-6, atol=1e-9)
    if not lossless:
        f0 = fit_rows(rows_0.mean(-1))
        C = rows_0.shape[-1]
        A = cone_collapse_binned(phi_o[:, None], edges, f0["tilts"], f0["widths"], fm["alpha_x"])  # [S, K, M]
        A = np.swapaxes(A, 1, 2) * (f0["weights"][:, None, :] > 0)                                   # [S, M, K]
        target = rows_0 * np.cos(phi_i)[None, :, None]                                               # [S, M, C]
        wc = np.stack([nnls_batched(A, target[..., c]) for c in range(C)], -1)                        # [S, K, C]
        wc = _conserve_energy({**f0, "weights": wc, "alpha_x": fm["alpha_x"]}, rows_0, phi_o, edges)
        fits = np.einsum("smk,skc->smc", A, wc)
        err = np.max([relative_l1(fits[..., c], target[..., c]) for c in range(C)], axis=0)
        if C == 1:
            wc = np.repeat(wc, 3, -1)
        out.update({"0_weights": wc, "0_tilts": f0["tilts"], "0_widths": f0["widths"],
                    "0_gamma": _gamma_at_lobes(gam, phi_o, f0["tilts"]), "0_error": err})
    return out


def _conserve_energy(fit: dict, rows: np.ndarray, phi_o: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Scale each slice's (per-channel) weights so the lobes reflect exactly the table's albedo.

    The L1 fit leaves a few percent of energy error; the white-furnace albedo of view φo is
    Σ_i C_i ρ[o, i] (C_i = ∫ cos over bin i, see ``scratch_brdf``) and a lobe's is its cone
    collapse integrated over φi.  ``rows`` is [S, M, C]; returns weights [S, K, C].
    """
    C_i = np.diff(np.sin(edges))
    target = np.einsum("smc,m->sc", rows, C_i)                                          # [S, C]
    atoms = cone_collapse_binned(phi_o[:, None], edges, fit["tilts"], fit["widths"], fit["alpha_x"])  # [S, K, M]
    lobe_albedo = (atoms * np.diff(edges)).sum(-1)                                       # [S, K]
    w = np.asarray(fit["weights"], float)
    w = w[..., None] if w.ndim == 2 else w                                               # [S, K, C]
    have = np.einsum("skc,sk->sc", w, lobe_albedo)
    scale = np.where(have > 0, target / np.where(have > 0, have, 1.0), 0.0)
    return w * scale[:, None, :]


def _fit_rows(rows, phi_o, K, error_target, alpha_x=1e-4):
    """Fit S slices at φo = ``phi_o`` of an [S, M] table with the batched fitter of ``lobe_fit``."""
    from .lobe_fit import _Fitter

    M = rows.shape[1]
    f = rows * np.cos(phi_bin_centres(M))[None, :]
    fitter = _Fitter(f, phi_o, phi_bin_edges(M), K, alpha_x, 2.5 * alpha_x, error_target, 0.0, 12)
    w, t, a, err = fitter.run()
    return {"weights": w, "tilts": t, "widths": a, "error": err, "alpha_x": alpha_x}
