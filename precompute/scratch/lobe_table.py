"""Tabulated-tilt lobes: a φo slice of a scratch BRDF table rendered exactly by one sampled lobe.

The fitted lobes of ``lobe_fit`` approximate a slice rho(phi_o, phi_i) cos(phi_i) (Raymond et al.
2016, eq. 5) by K smooth lobes; the caustic spikes of smooth profiles (quartics: 1/sqrt folds a bin
wide) keep their error at 5-11 % rel. L1 (a 3-bin smoothing of the slice alone costs 5-6 %).  A
*table lobe* reproduces the slice bin by bin instead, and still keeps light sampling:

- aim bin b of the M phi_i bins gets a narrow tilted GGX closure whose tilt is drawn uniformly over
  the tilts that mirror phi_o into the bin, t in [(e_b + phi_o)/2, (e_{b+1} + phi_o)/2]: a box lobe
  (``cycles_ggx.cone_collapse_binned_jittered``, jitter = bin width / 4) of weight w_b;
- the weights solve  sum_b w_b A_b(phi_i) = rho cos  on the bins (A_b the bin-averaged box lobe with
  Cycles' G2 / horizon losses; diagonally dominant, a few projected Jacobi sweeps), then every slice
  is rescaled to the table's exact albedo;
- the shader picks bin b with probability p_b / P (p_b = w^m_b + mean(w^0_b), P = sum_b p_b, a CDF
  per slice and a binary search), draws the tilt inside the bin with the same random number, and
  weights the closure by W_b(theta_o) P / p_b with W_b = R_gamma_b(theta_o) w^m_b + (1 - R) w^0_b (eq. 2,
  gamma of the bin).  The average over samples is sum_b W_b A_b: the slice itself, exact up to the
  lobe blur inside a bin.  With K stratified closures (h_k = (k + h)/K), each gets weight / K.

The rendered closure is an ordinary ``microfacet("ggx", N', u, alpha_x, alpha_y)`` lobe, so NEE and
MIS work as for fitted lobes; a narrow lobe makes NEE rarely useful for small lights (noise like a
stochastic mirror), the price of exactness.  Units: radians; weights are Cycles closure weights.
"""
from __future__ import annotations

import numpy as np

from ..tables.alias import alias_pmf, alias_tables as _alias_table
from ..cycles.ggx import cone_collapse_binned_jittered, cone_collapse_binned_jittered_windows
from ..validation import check_int, check_range, finite
from .lobe_fit import phi_bin_centres, phi_bin_edges, relative_l1

__all__ = ["bin_atoms", "fit_bins", "default_width", "proposal", "sample_bins", "model", "box_albedo"]


def default_width(M: int) -> float:
    """GGX alpha_y of table lobes: tan(pi / (256 M)), floored at 3e-6 (Cycles needs alpha_x alpha_y > 2e-10).

    GGX slope tails are heavy: a box lobe spills ~ 2 alpha_y / (pi / M) of its weight into the
    neighbouring bins, which the non-negative weights cannot take back next to an empty bin (a
    V-groove's one-bin mirror peaks: 12 % rel. L1 at alpha_y = tan(pi / 16 M), 0.8 % at this width).
    """
    M = check_int("M", M, 1, 1 << 16)
    return float(max(np.tan(np.pi / M / 256.0), 3e-6))


#: largest table the lobes are built for (phi_i bins) and largest atom array (S x M x M floats: 512 MiB)
MAX_BINS = 4096
MAX_ATOMS = 1 << 26

#: bins on each side of a table lobe's own bin that get its spill (GGX tails); beyond, the spill of a
#: default-width lobe is < 3e-6 of its weight (measured at M = 256) and is dropped
BAND = 3


def bin_atoms(phi_o, M: int, alpha_y=None, alpha_x: float = 1e-4, band=BAND) -> np.ndarray:
    """Bin-averaged cone collapse A[s, b, m] of the box lobe aimed at bin b, for view angles phi_o [S].

    Tilt uniform over [(e_b + phi_o)/2, (e_{b+1} + phi_o)/2] (``cone_collapse_binned_jittered`` with
    centre (c_b + phi_o)/2 and jitter pi/(4 M)); what Cycles renders per unit closure weight, in 1/rad.
    Only the bins |m - b| <= ``band`` are evaluated (``cycles_ggx.cone_collapse_binned_jittered_windows``;
    ``band=None``: all M, the full-range function).
    """
    M = check_int("M (phi_i bins)", M, 4, MAX_BINS)
    phi_o = np.atleast_1d(finite("phi_o", phi_o))
    if phi_o.ndim != 1 or np.any(np.abs(phi_o) >= 0.5 * np.pi):
        raise ValueError("phi_o must be a 1D array of angles in (-pi/2, pi/2) radians")
    if phi_o.size * M * M > MAX_ATOMS:
        raise ValueError(f"phi_o: {phi_o.size} view angles x {M}^2 bins need {phi_o.size * M * M * 8 / 2**30:.1f} GiB "
                         f"of atoms; at most {MAX_ATOMS // (M * M)} view angles at M = {M}")
    if band is not None and not (isinstance(band, (int, np.integer)) and band >= 1):
        raise ValueError(f"band must be None or an integer >= 1; got {band!r}")
    ay = default_width(M) if alpha_y is None else check_range("alpha_y", alpha_y, 1e-9, 1.0)
    alpha_x = check_range("alpha_x", alpha_x, 0.0, 1.0)
    e = phi_bin_edges(M)
    tilt = 0.5 * (phi_bin_centres(M)[None, :] + phi_o[:, None])                       # [S, M]
    if band is None or 2 * band + 1 >= M:
        return cone_collapse_binned_jittered(phi_o[:, None], e, tilt, ay, np.pi / (4 * M), alpha_x)
    S = phi_o.size
    offs = np.arange(-band, band + 1)                                                 # window bins
    idx = np.arange(M)[:, None] + offs[None, :]                                       # [M, W]
    # window edges continue the uniform grid past +-pi/2 (those bins are empty: see the clip inside)
    win = -0.5 * np.pi + np.pi / M * (idx[..., None] + np.array([0, 1]))              # [M, W, 2]
    win_edges = np.concatenate([win[:, :, 0], win[:, -1:, 1]], axis=1)               # [M, W+1]
    vals = cone_collapse_binned_jittered_windows(
        np.repeat(phi_o, M), np.tile(win_edges, (S, 1)), tilt.ravel(), ay, np.pi / (4 * M), alpha_x)
    A = np.zeros((S, M, M))
    inside = (idx >= 0) & (idx < M)
    s_i, b_i, k_i = np.nonzero(np.broadcast_to(inside, (S, M, offs.size)))
    A[s_i, b_i, idx[b_i, k_i]] = vals.reshape(S, M, offs.size)[s_i, b_i, k_i]
    return A


def model(weights, atoms) -> np.ndarray:
    """sum_b w[s, b(, c)] A[s, b, m] -> [S, M(, C)]: what the sampled table lobe renders on average."""
    w = np.asarray(weights, float)
    if w.ndim == 2:
        return np.einsum("sb,sbm->sm", w, atoms)
    return np.einsum("sbc,sbm->smc", w, atoms)


def fit_bins(rows, phi_o, alpha_y=None, alpha_x: float = 1e-4, sweeps: int = 30, atoms=None):
    """Closure weights w [S, M(, C)] of the table lobes reproducing ``rows`` (rho at phi_o, [S, M(, C)]).

    Target f = rho cos(phi_i) in bin averages (rho C_i / (pi/M), C_i the integral of cos over bin i,
    as ``lobe_fit.fit_table``).  Projected Jacobi on sum_b w_b A_b = f (w >= 0), then each slice and
    channel is scaled to the table's albedo sum_i C_i rho_i (the lobes' total reflectance).
    Returns (w, error [S] rel. L1 of the model, worst channel, atoms [S, M, M]).
    """
    rows = finite("rows", rows)
    if rows.ndim not in (2, 3) or rows.shape[1] < 4 or 0 in rows.shape:
        raise ValueError(f"rows must be [S, M] or [S, M, C] table rows with M >= 4 phi_i bins; got shape {rows.shape}")
    scalar = rows.ndim == 2
    r3 = rows[..., None] if scalar else rows
    S, M, C = r3.shape
    if np.any(r3 < 0):
        raise ValueError("rows must be finite and >= 0")
    if not (isinstance(sweeps, (int, np.integer)) and 0 <= sweeps <= 1000):
        raise ValueError(f"sweeps must be an integer in [0, 1000]; got {sweeps!r}")
    if np.shape(np.atleast_1d(phi_o)) != (S,):
        raise ValueError(f"phi_o must hold one view angle per row: shape ({S},); got {np.shape(phi_o)}")
    e = phi_bin_edges(M)
    A = bin_atoms(phi_o, M, alpha_y, alpha_x) if atoms is None else np.asarray(atoms, float)
    if A.shape != (S, M, M):
        raise ValueError(f"atoms must have shape ({S}, {M}, {M}) (bin_atoms of these rows); got {A.shape}")
    f = r3 * (np.diff(np.sin(e)) / np.diff(e))[None, :, None]                         # [S, M, C]
    diag = np.einsum("sbb->sb", A)                                                     # [S, M]
    # bins no lobe can reach (the aim's tilted normal below the view) stay empty
    ok = diag > 1e-3 * np.max(diag, axis=1, keepdims=True)
    inv = np.where(ok, 1.0 / np.where(ok, diag, 1.0), 0.0)[..., None]
    w = f * inv
    for _ in range(sweeps):
        w = np.maximum(w + (f - np.einsum("sbc,sbm->smc", w, A)) * inv, 0.0)
    # exact albedo per slice and channel (white furnace: sum_i C_i rho_i)
    albedo = np.einsum("smc,m->sc", r3, np.diff(np.sin(e)))
    have = np.einsum("sbc,sb->sc", w, A.sum(-1) * (np.pi / M))
    w = w * np.where(have > 0, albedo / np.where(have > 0, have, 1.0), 0.0)[:, None, :]
    fit = np.einsum("sbc,sbm->smc", w, A)
    err = np.max(np.stack([relative_l1(fit[..., c], f[..., c]) for c in range(C)]), axis=0)
    return (w[..., 0] if scalar else w), err, A


def proposal(w_m, w_0=None):
    """The shader's bin-picking distribution: CDF [S, M+1] of p_b = w^m_b (+ mean_c w^0_b) and P [S].

    ``w_m`` [S, M] and ``w_0`` [S, M, C] are closure weights: finite and >= 0 (else ValueError)."""
    p = finite("w_m", w_m)
    if p.ndim != 2 or p.shape[1] < 1 or np.any(p < 0):
        raise ValueError(f"w_m must be [S, M] closure weights >= 0; got shape {p.shape}")
    if w_0 is not None:
        w0 = finite("w_0", w_0)
        if w0.shape[:2] != p.shape or w0.ndim != 3 or np.any(w0 < 0):
            raise ValueError(f"w_0 must be [S, M, C] closure weights >= 0 with [S, M] = {p.shape}; got shape {w0.shape}")
        p = p + w0.mean(-1)
    cum = np.concatenate([np.zeros((p.shape[0], 1)), np.cumsum(p, 1)], 1)
    if not np.all(np.isfinite(cum[:, -1])):
        raise ValueError("w_m: closure weights so large that their sum overflows (expected reflectances, ~<= 1e3)")
    total = cum[:, -1]
    cdf = cum / np.where(total > 0, total, 1.0)[:, None]
    # from the last non-empty bin on the CDF is exactly 1, so no h < 1 can land in a trailing empty bin
    return np.where((cum >= total[:, None]) & (total[:, None] > 0), 1.0, cdf), total


def sample_bins(cdf, s, h):
    """What the shader does with a uniform h in [0, 1): bin b (binary search) and the fraction inside it.

    ``cdf`` [S, M+1]; ``s``, ``h`` arrays of slice indices and random numbers -> (b, frac); the
    sampled aim is phi_i = e_b + frac pi/M and the tilt (phi_i + phi_o_s) / 2.
    """
    cdf = np.asarray(cdf, float)
    if cdf.ndim != 2 or cdf.shape[1] < 2:
        raise ValueError(f"cdf must be [S, M+1] with M >= 1; got shape {cdf.shape}")
    M = cdf.shape[1] - 1
    s, h = np.broadcast_arrays(np.asarray(s, int), np.asarray(h, float))
    if np.any((s < 0) | (s >= cdf.shape[0])):
        raise ValueError(f"s must be slice indices in [0, {cdf.shape[0] - 1}]")
    if not np.all((h >= 0) & (h < 1)):
        raise ValueError("h must be uniform random numbers in [0, 1)")
    lo = np.zeros(s.shape, int)
    hi = np.full(s.shape, M)
    for _ in range(int(np.ceil(np.log2(M))) + 1):        # the shader's loop: while (hi - lo > 1)
        mid = (lo + hi) // 2
        go = (hi - lo > 1)
        below = cdf[s, mid] <= h
        lo = np.where(go & below, mid, lo)
        hi = np.where(go & ~below, mid, hi)
    c0, c1 = cdf[s, lo], cdf[s, lo + 1]
    frac = np.where(c1 > c0, (h - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.5)
    return lo, np.clip(frac, 0.0, 1.0)


def box_albedo(phi_o, M: int, centroid, alpha_y=None, alpha_x: float = 1e-4, band=BAND, where=None) -> np.ndarray:
    """What Cycles renders per unit closure weight of each bin's lobe of the view slices: a [S, M].

    The lobe of bin b of the slice at ``phi_o[s]`` aims uniformly in ``[c - h, c + h]`` of the bin (c =
    ``centroid[s, b]``, a fraction of the bin; h = min(c, 1 - c)), so its tilt is uniform in a box of
    half width h pi / (2 M) around (aim + phi_o) / 2; Cycles' G2 and horizon losses make a < 1 near
    grazing.  Bins |m - b| <= ``band`` are evaluated (``cycles_ggx.cone_collapse_binned_jittered_windows``).
    ``where`` [S, M] (bool): only these lobes are evaluated (each lobe on its own: the same numbers), the
    others get 0 -- the table lobes skip the empty bins of a slice, most of them (74 % of quartic 0.08's).
    Used by ``precompute.scratch.lobes.table_lobes`` (weights = mass / a, Raymond et al. 2016 eq. 5).
    """
    from ..cycles.ggx import cone_collapse_binned_jittered_windows as windows

    phi_o = np.atleast_1d(np.asarray(phi_o, float))
    c = np.asarray(centroid, float)
    if not (isinstance(M, (int, np.integer)) and M >= 4) or c.shape != (phi_o.size, M):
        raise ValueError(f"centroid must be [S, M] with S = phi_o.size and M >= 4; got {c.shape}")
    if not np.all(np.isfinite(phi_o)) or np.any(np.abs(phi_o) >= 0.5 * np.pi):
        raise ValueError("phi_o must hold angles in (-pi/2, pi/2) radians")
    S = phi_o.size
    sel = np.ones((S, M), bool) if where is None else np.asarray(where, bool)
    if sel.shape != (S, M):
        raise ValueError(f"where must be a [S, M] = {(S, M)} boolean mask; got shape {sel.shape}")
    ay = default_width(M) if alpha_y is None else float(alpha_y)
    d = np.pi / M
    h = np.minimum(c, 1.0 - c)
    aim = -0.5 * np.pi + (np.arange(M)[None, :] + c) * d
    tilt = 0.5 * (aim + phi_o[:, None])
    offs = np.arange(-band, band + 1)
    idx = np.arange(M)[:, None] + offs[None, :]
    win = -0.5 * np.pi + d * (idx[..., None] + np.array([0, 1]))
    edges = np.concatenate([win[:, :, 0], win[:, -1:, 1]], axis=1)                    # [M, W+1]
    inside = (idx >= 0) & (idx < M)                                                    # [M, W]
    s_i, b_i = np.nonzero(sel)
    out = np.zeros((S, M))
    step = max(1, 200_000 // (2 * band + 1))
    for a in range(0, s_i.size, step):
        s_, b_ = s_i[a:a + step], b_i[a:a + step]
        vals = windows(phi_o[s_], edges[b_], tilt[s_, b_], ay, 0.5 * d * h[s_, b_], alpha_x)   # [n, W]
        out[s_, b_] = (vals * inside[b_]).sum(1) * d
    return out


def alias_table(cdf):
    """Walker's alias table of each slice's bin distribution p_b = cdf[b+1] - cdf[b] (Vose's construction).

    ``cdf`` [S, M+1] (``proposal``) -> (prob [S, M] float, alias [S, M] int).  Sampling with one uniform
    h in [0, 1) (``sample_alias``): u = h M, j = floor(u), f = u - j; bin b = j if f < prob_j, else alias_j.
    It picks bin b with probability exactly p_b (one table lookup instead of the binary search of
    ``sample_bins``); empty slices (all p_b = 0) get prob = 1, alias = own bin.
    """
    cdf = np.asarray(cdf, float)
    if cdf.ndim != 2 or cdf.shape[1] < 2:
        raise ValueError(f"cdf must be [S, M+1] with M >= 1; got shape {cdf.shape}")
    import hashlib

    key = (cdf.shape, hashlib.sha1(np.ascontiguousarray(cdf).tobytes()).digest())
    hit = _ALIAS.get(key)
    if hit is None:
        hit = _ALIAS[key] = _alias_table(cdf)
        while len(_ALIAS) > _ALIAS_MAX:
            try:
                _ALIAS.pop(next(iter(_ALIAS)), None)
            except (RuntimeError, StopIteration):   # another thread trimmed it meanwhile
                break
    return hit[0].copy(), hit[1].copy()


#: alias tables by their distribution (a live edit back to a value seen before, a cache hit, builds none:
#: the construction is a Python loop, ~15 ms for 85 x 256 bins); bounded (about 0.4 MB each at M = 256)
_ALIAS: dict = {}
_ALIAS_MAX = 32


def sample_alias(prob, alias, s, h):
    """What the shader does with a uniform h in [0, 1) and an alias table: (bin b, fraction inside it),
    the fraction uniform in [0, 1) given b (the rest of h after the pick)."""
    prob = np.asarray(prob, float)
    alias = np.asarray(alias, int)
    M = prob.shape[1]
    s, h = np.broadcast_arrays(np.asarray(s, int), np.asarray(h, float))
    u = h * M
    j = np.minimum(np.floor(u).astype(int), M - 1)
    f = u - j
    pj = prob[s, j]
    take = f >= pj
    b = np.where(take, alias[s, j], j)
    frac = np.where(take, (f - pj) / np.maximum(1.0 - pj, 1e-12), f / np.maximum(pj, 1e-12))
    return b, np.clip(frac, 0.0, 1.0)
