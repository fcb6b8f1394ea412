"""Represent φo-slices of a scratch BRDF table as sums of tilted Cycles GGX lobes.

For a view direction with angle phi_o, the paper's rendering integral (Raymond et al. 2016, eq. 5)
is L_r = int rho(phi_o, phi_i) cos(phi_i) L_i(-theta_o, phi_i) dphi_i.  A tilted anisotropic GGX
closure (normal N' = cos t n + sin t v, tangent u, alpha_x tiny, alpha_y = width) contributes
int g(phi_i) L_i dphi_i with g its cone collapse (``cycles_ggx.cone_collapse``), *including* what
Cycles loses (height-correlated Smith G, light directions below n or N').  So we fit, per slice::

    rho(phi_o, phi_i) cos(phi_i)  ~=  sum_k w_k g(phi_i; phi_o, t_k, alpha_y_k),   w_k >= 0

in bin averages over the table's phi_i bins, and the closure weights w_k then render the slice
without a separate albedo compensation.  Lobe centres (phi_i = 2 t - phi_o, the mirror direction
of phi_o about N') are kept above the horizon (|2t - phi_o| <= pi/2 - margin).

Method (vectorised over slices; loops over lobes and iterations only):
1. greedy: put the next lobe at the peak of the positive residual, pick its width from a log grid
   by least squares (non-negative weight);
2. refine all lobes of all unfinished slices with a batched, projected Levenberg-Marquardt on
   (w, centre, log alpha_y) with finite-difference Jacobians, on an IRLS-reweighted L2 cost that
   approximates the L1 error metric;
3. stop adding lobes to a slice as soon as its relative L1 error sum|fit - f| / sum|f| meets the target;
4. slices still above the target after K lobes get a second start (all K lobes on the quantiles of
   the slice's mass, NNLS weights, longer LM) and keep the better of the two fits;
5. ``dists="auto"``: steps 1-4 with Beckmann lobes (Gaussian slope tails: sharp box edges), then
   with GGX lobes for the slices still above the target; the better per slice is kept.

Units: angles in radians; weights are Cycles closure weights (dimensionless).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cycles_ggx import BECKMANN, BSDF_ROUGHNESS_SQ_THRESH, GGX, cone_collapse_binned, dist_code

__all__ = ["LobeSet", "fit_lobes", "fit_table", "lobe_model", "relative_l1", "phi_bin_centres", "phi_bin_edges",
           "rows_at", "slice_centres"]

_HALF_PI = 0.5 * np.pi


def phi_bin_edges(M: int) -> np.ndarray:
    """Edges of the M phi bins of a scratch BRDF table: -pi/2 + k pi/M, k = 0..M (radians)."""
    return -_HALF_PI + np.pi * np.arange(M + 1) / M


def phi_bin_centres(M: int) -> np.ndarray:
    """Bin centres -pi/2 + (k + 1/2) pi/M (radians), the table's phi_o / phi_i samples."""
    return -_HALF_PI + np.pi * (np.arange(M) + 0.5) / M


@dataclass(frozen=True)
class LobeSet:
    """Tilted GGX lobes for one phi_o slice: closure weights, tilts t (radians), widths alpha_y.

    ``alpha_x`` is the (shared) along-scratch roughness; ``error`` the relative L1 error of the fit.
    Unused slots have weight 0.
    """

    weights: np.ndarray
    tilts: np.ndarray
    widths: np.ndarray
    alpha_x: float
    error: float
    dist: np.ndarray = None   # int8 codes per lobe: 0 = GGX, 1 = Beckmann

    @property
    def n_lobes(self) -> int:
        return int(np.count_nonzero(self.weights > 0))


def relative_l1(fit, target) -> np.ndarray:
    """Relative L1 error per slice (last axis): sum|fit - target| / sum|target| (0 for an all-zero target)."""
    fit = np.asarray(fit, float)
    target = np.asarray(target, float)
    den = np.sum(np.abs(target), axis=-1)
    num = np.sum(np.abs(fit - target), axis=-1)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.where(num > 0, np.inf, 0.0))


def lobe_model(phi_o, weights, tilts, widths, phi_edges, alpha_x=1e-3, theta_o=0.0, dist="ggx"):
    """Bin-averaged sum_k w_k g(phi_i; phi_o, t_k, alpha_y_k) for lobes shaped [..., K] (radians).

    ``phi_o`` broadcasts against the leading dims; ``dist`` ("ggx", "beckmann" or codes [..., K]);
    returns [..., nbins] (the fitted rho cos(phi_i)).
    """
    w = np.asarray(weights, float)
    atoms = cone_collapse_binned(np.asarray(phi_o, float)[..., None], phi_edges, tilts, widths, alpha_x, theta_o,
                                 dist=dist)
    return np.einsum("...k,...km->...m", w, atoms)


# ----------------------------------------------------------------------------- validation
def _check_common(K, error_target, alpha_x, min_width, max_iter):
    if not (isinstance(K, (int, np.integer)) and 1 <= K <= 64):
        raise ValueError(f"K must be an integer in [1, 64] (Cycles allows 64 closures per point); got {K!r}")
    if not (np.isfinite(error_target) and 0 <= error_target < 1):
        raise ValueError(f"error_target must be in [0, 1); got {error_target!r}")
    if not (np.isfinite(alpha_x) and 0 < alpha_x <= 0.1):
        raise ValueError(f"alpha_x must be in (0, 0.1] (a narrow cone); got {alpha_x!r}")
    if min_width is not None and not (np.isfinite(min_width) and alpha_x < min_width <= 1.0
                                      and alpha_x * min_width > BSDF_ROUGHNESS_SQ_THRESH):
        raise ValueError(f"min_width must be in (alpha_x, 1] with alpha_x*min_width > 2e-10; got {min_width!r}")
    if not (isinstance(max_iter, (int, np.integer)) and 0 <= max_iter <= 1000):
        raise ValueError(f"max_iter must be an integer in [0, 1000]; got {max_iter!r}")


# ----------------------------------------------------------------------------- batched fitter
class _Fitter:
    """Batched greedy + Levenberg-Marquardt fit of S slices at once (internal)."""

    def __init__(self, f, phi_o, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes=(GGX,)):
        self.f = f                    # [S, M] target rho cos(phi_i), bin averages
        self.phi_o = phi_o            # [S]
        self.edges = edges
        self.K = K
        self.ax = alpha_x
        self.lmin = np.log(min_width)
        self.lmax = 0.0               # alpha_y <= 1 (Cycles saturates)
        self.cmax = _HALF_PI - margin
        self.target = error_target
        self.max_iter = max_iter
        S, M = f.shape
        self.w = np.zeros((S, K))
        self.c = np.zeros((S, K))     # lobe centre phi_i = 2 t - phi_o
        self.l = np.zeros((S, K))     # log alpha_y
        self.d = np.zeros((S, K), dtype=np.int8)   # distribution code per lobe
        self.codes = tuple(codes)
        self.n = np.zeros(S, dtype=int)
        self.centres = 0.5 * (edges[:-1] + edges[1:])
        self.scale = np.maximum(np.max(np.abs(f), axis=1), 1e-300)  # [S]
        self.width_grid = np.exp(np.linspace(self.lmin, 0.0, 14))

    def atoms(self, idx, c, l, d=None):
        """Bin-averaged cone collapse of lobes (c, l, d) [s, k] for slices idx -> [s, k, M]."""
        po = self.phi_o[idx][:, None]
        t = 0.5 * (c + po)
        d = self.d[idx, :c.shape[1]] if d is None else d
        return cone_collapse_binned(po, self.edges, t, np.exp(l), self.ax, dist=d)

    def model(self, idx, w=None, c=None, l=None):
        w = self.w[idx] if w is None else w
        c = self.c[idx] if c is None else c
        l = self.l[idx] if l is None else l
        return np.einsum("sk,skm->sm", w, self.atoms(idx, c, l))

    def errors(self, idx=None):
        idx = np.arange(len(self.f)) if idx is None else idx
        return relative_l1(self.model(idx), self.f[idx])

    def add_lobe(self, idx):
        """Greedy step: new lobe at the positive-residual peak, width and weight by least squares."""
        f = self.f[idx]
        r = f - self.model(idx)
        rp = np.maximum(r, 0.0)
        # light smoothing so a single noisy bin does not win over a broad bump
        rs = rp + 0.5 * (np.roll(rp, 1, axis=1) + np.roll(rp, -1, axis=1))
        peak = np.argmax(rs, axis=1)
        c0 = np.clip(self.centres[peak], -self.cmax, self.cmax)
        lg = np.tile(np.log(self.width_grid), len(self.codes))
        dg = np.repeat(np.array(self.codes, np.int8), self.width_grid.size)
        W = lg.size
        cc = np.repeat(c0[:, None], W, axis=1)
        ll = np.repeat(lg[None, :], len(idx), axis=0)
        dd = np.repeat(dg[None, :], len(idx), axis=0)
        A = self.atoms(idx, cc, ll, dd)                                 # [s, W, M]
        num = np.einsum("sm,swm->sw", r, A)
        den = np.einsum("swm,swm->sw", A, A) + 1e-300
        wt = np.maximum(num / den, 0.0)
        cost = np.sum(np.abs(r[:, None, :] - wt[..., None] * A), axis=2)  # L1, the metric we report
        best = np.argmin(cost, axis=1)
        k = self.n[idx]
        self.w[idx, k] = wt[np.arange(len(idx)), best]
        self.c[idx, k] = c0
        self.l[idx, k] = lg[best]
        self.d[idx, k] = dg[best]
        self.n[idx] += 1

    def quantile_start(self, idx):
        """K lobes at the (k + 1/2)/K quantiles of the slice's mass; width from the quantile interval."""
        f = self.f[idx]
        cdf = np.cumsum(f, axis=1)
        cdf = cdf / np.maximum(cdf[:, -1:], 1e-300)
        K, M = self.K, f.shape[1]
        q = (np.arange(K) + 0.5) / K
        qe = np.arange(K + 1) / K
        pos = lambda qq: self.centres[np.clip(np.sum(cdf[:, :, None] < qq[None, None, :], axis=1), 0, M - 1)]  # noqa: E731
        c0 = np.clip(pos(q), -self.cmax, self.cmax)
        e = pos(qe)
        span = np.maximum(np.diff(e, axis=1), np.pi / M)
        # a lobe's phi_i extent is ~ 2 atan(alpha_y) per slope unit: alpha ~ tan(span / 4)
        l0 = np.clip(np.log(np.tan(0.25 * span)), self.lmin, self.lmax)
        code = BECKMANN if BECKMANN in self.codes else self.codes[0]
        self.c[idx] = c0
        self.l[idx] = l0
        self.d[idx] = code
        self.n[idx] = K
        A = self.atoms(idx, c0, l0)
        # non-negative least-squares weights by projected coordinate descent (K small)
        AtA = np.einsum("skm,slm->skl", A, A)
        Atf = np.einsum("skm,sm->sk", A, f)
        diag = np.maximum(np.einsum("skk->sk", AtA), 1e-300)
        w = np.maximum(Atf / diag, 0.0) / K
        for _ in range(50):
            for k in range(K):
                r = Atf[:, k] - np.einsum("sl,sl->s", AtA[:, k, :], w) + AtA[:, k, k] * w[:, k]
                w[:, k] = np.maximum(r / diag[:, k], 0.0)
        self.w[idx] = w

    def refine(self, idx, iters):
        """Projected LM on (w, c, log ay) of the active lobes, IRLS weights for an L1-like cost."""
        if len(idx) == 0 or iters == 0:
            return
        K = int(self.n[idx].max())                                       # only the used lobe slots
        f = self.f[idx]
        active = np.arange(K)[None, :] < self.n[idx][:, None]           # [s, K]
        w, c, l = self.w[idx, :K].copy(), self.c[idx, :K].copy(), self.l[idx, :K].copy()
        lam = np.full(len(idx), 1e-2)
        scale = self.scale[idx][:, None]
        eps_irls = 0.02 * scale                                          # IRLS floor (relative to peak)
        act3 = np.concatenate([active, active, active], axis=1)
        eye = np.eye(3 * K)

        def resid(w_, c_, l_):
            A_ = self.atoms(idx, c_, l_)
            return np.einsum("sk,skm->sm", w_, A_) - f, A_

        r, A = resid(w, c, l)
        for _ in range(iters):
            irls = 1.0 / np.sqrt(np.maximum(np.abs(r), eps_irls))        # |r| ~ r^2 / |r|
            cost = np.sum((r * irls) ** 2, axis=1)
            dc, dl = 1e-4, 1e-3
            Ac = (self.atoms(idx, c + dc, l) - A) / dc
            Al = (A - self.atoms(idx, c, l - dl)) / dl                   # backward: alpha_y = 1 is a bound
            J = np.concatenate([A, w[..., None] * Ac, w[..., None] * Al], axis=1)  # [s, 3K, M]
            J = np.where(act3[..., None], J * irls[:, None, :], 0.0)
            JtJ = J @ J.transpose(0, 2, 1)
            g = np.einsum("spm,sm->sp", J, r * irls)
            diag = np.where(act3, np.einsum("spp->sp", JtJ), 1.0)
            H = JtJ + eye * (lam[:, None] * diag + 1e-12 * np.max(diag, axis=1, keepdims=True) + (~act3))[:, :, None]
            try:
                step = -np.linalg.solve(H, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                step = -g / np.maximum(diag, 1e-300)
            step = np.where(act3, np.nan_to_num(step), 0.0)
            wn = np.maximum(w + step[:, :K], 0.0)
            cn = np.clip(c + step[:, K:2 * K], -self.cmax, self.cmax)
            ln = np.clip(l + np.clip(step[:, 2 * K:], -1.0, 1.0), self.lmin, self.lmax)
            rn, An = resid(wn, cn, ln)
            cost_new = np.sum((rn * irls) ** 2, axis=1)
            better = cost_new < cost
            b = better[:, None]
            w, c, l = np.where(b, wn, w), np.where(b, cn, c), np.where(b, ln, l)
            r = np.where(b, rn, r)
            A = np.where(b[..., None], An, A)
            lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-7, 1e7)
        self.w[idx, :K], self.c[idx, :K], self.l[idx, :K] = w, c, l

    def run(self):
        nonzero = np.sum(np.abs(self.f), axis=1) > 0
        err = np.where(nonzero, np.inf, 0.0)
        todo = np.flatnonzero(nonzero)
        for k in range(self.K):
            if todo.size == 0:
                break
            self.add_lobe(todo)
            self.refine(todo, self.max_iter)
            err[todo] = self.errors(todo)
            todo = todo[err[todo] > self.target]
        # a last polish for slices that stay above the target with all K lobes
        if todo.size:
            self.refine(todo, 2 * self.max_iter)
            err[todo] = self.errors(todo)
        # second start for those: all K lobes at once, placed on the quantiles of the slice's
        # mass with widths from the quantile intervals, then the same LM; keep the better fit
        if todo.size and self.K >= 2:
            saved = (self.w[todo].copy(), self.c[todo].copy(), self.l[todo].copy(), self.d[todo].copy(),
                     self.n[todo].copy())
            self.quantile_start(todo)
            self.refine(todo, 3 * self.max_iter)
            e2 = self.errors(todo)
            worse = e2 >= err[todo]
            back = todo[worse]
            for arr, old in zip((self.w, self.c, self.l, self.d, self.n), saved):
                arr[back] = old[worse]
            err[todo] = np.minimum(e2, err[todo])
        # tidy: drop zero-weight lobes, sort by weight
        self.w[~np.isfinite(self.w)] = 0.0
        order = np.argsort(-self.w, axis=1, kind="stable")
        take = lambda a: np.take_along_axis(a, order, axis=1)  # noqa: E731
        self.w, self.c, self.l, self.d = take(self.w), take(self.c), take(self.l), take(self.d)
        unused = self.w <= 0
        self.d[unused] = 0
        self.c[unused] = 0.0
        self.l[unused] = 0.0
        self.w[unused] = 0.0
        tilts = 0.5 * (self.c + self.phi_o[:, None])
        tilts[unused] = 0.0
        # (w, t, a, err) like before for existing callers; the distribution codes are in self.d
        return self.w, tilts, np.exp(self.l), np.where(nonzero, self.errors(), 0.0)


def _fit_rows(f, phi, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes):
    """Run the batched fitter; ``codes == "auto"``: Beckmann lobes first (Gaussian slope tails make
    the sharp edges of scratch slices), then the slices still above the target are refitted with
    GGX lobes (heavy tails: better on the one-sided 1/sqrt caustic shoulders) and the better fit
    per slice is kept."""
    def run(f_, phi_, codes_):
        fitter = _Fitter(f_, phi_, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes_)
        return list(fitter.run()) + [fitter.d]

    if codes != "auto":
        return tuple(run(f, phi, codes))
    out = run(f, phi, (BECKMANN,))
    redo = np.flatnonzero(out[3] > error_target)
    if redo.size:
        alt = run(f[redo], phi[redo], (GGX,))
        better = alt[3] < out[3][redo]
        for j in range(5):
            sel = redo[better]
            out[j][sel] = alt[j][better]
    return tuple(out)


def _check_rows(rho, phi_o):
    rho = np.asarray(rho, dtype=float)
    if phi_o is None:
        if rho.ndim != 2 or rho.shape[0] != rho.shape[1] or rho.shape[0] < 4:
            raise ValueError(f"rho must be a square M x M table with M >= 4 (or pass phi_o); got shape {rho.shape}")
        phi_o = phi_bin_centres(rho.shape[0])
    else:
        phi_o = np.atleast_1d(np.asarray(phi_o, dtype=float))
        if rho.ndim != 2 or rho.shape[1] < 4 or phi_o.shape != (rho.shape[0],):
            raise ValueError(f"rho must be an [S, M] array of rows (M >= 4) with phi_o of shape [S]; "
                             f"got rho {rho.shape}, phi_o {phi_o.shape}")
        if not np.all(np.isfinite(phi_o)) or np.any(np.abs(phi_o) >= _HALF_PI):
            raise ValueError("phi_o must be finite and in (-pi/2, pi/2) radians")
    if not np.all(np.isfinite(rho)):
        raise ValueError("rho must be finite")
    tol = 1e-6 * max(float(np.max(np.abs(rho))), 1e-300)
    if np.any(rho < -tol):
        raise ValueError("rho must be >= 0 (values down to -1e-6 * max are treated as rounding and clipped)")
    return np.maximum(rho, 0.0), phi_o


def _check_dists(dists):
    if isinstance(dists, str) and dists.lower() == "auto":
        return "auto"
    if isinstance(dists, str):
        dists = {"mixed": ("ggx", "beckmann")}.get(dists.lower(), (dists,))
    try:
        codes = tuple(sorted({int(dist_code(d)) for d in dists}))
    except (TypeError, ValueError):
        raise ValueError(f"dists must be 'ggx', 'beckmann', 'mixed' or a sequence of them; got {dists!r}") from None
    if not codes:
        raise ValueError("dists must name at least one distribution")
    return codes


def rows_at(rho, phi_o) -> np.ndarray:
    """Rows of a table ``rho[M, M(, C)]`` at view angles ``phi_o`` [S] (radians), linear in phi_o.

    Linear interpolation between the bin-centre rows (constant beyond the outer centres): what the
    shader's stochastic pick between the two nearest slices reproduces on average.  Returns [S, M(, C)].
    """
    rho = np.asarray(rho, dtype=float)
    if rho.ndim < 2 or rho.shape[0] != rho.shape[1]:
        raise ValueError(f"rho must be an M x M (x C) table; got shape {rho.shape}")
    phi_o = np.asarray(phi_o, dtype=float)
    if phi_o.ndim != 1 or not np.all(np.isfinite(phi_o)) or np.any(np.abs(phi_o) > _HALF_PI):
        raise ValueError("phi_o must be a 1D array of angles in [-pi/2, pi/2] radians")
    M = rho.shape[0]
    x = np.clip((phi_o + _HALF_PI) / np.pi * M - 0.5, 0.0, M - 1.0)
    i0 = np.minimum(np.floor(x).astype(int), M - 2)
    a = (x - i0).reshape((-1,) + (1,) * (rho.ndim - 1))
    return (1.0 - a) * rho[i0] + a * rho[i0 + 1]


def slice_centres(S: int) -> np.ndarray:
    """phi_o of the S shader slices: -pi/2 + (s + 1/2) pi/S (radians)."""
    if not (isinstance(S, (int, np.integer)) and S >= 1):
        raise ValueError(f"S must be a positive integer; got {S!r}")
    return phi_bin_centres(S)


def fit_table(rho, K: int = 8, error_target: float = 0.03, alpha_x: float = 1e-4, min_width=None,
              margin: float = 0.0, max_iter: int = 8, phi_o=None, dists="auto"):
    """Fit phi_o slices of a scratch BRDF table with <= K tilted Cycles microfacet lobes each.

    ``rho`` is either the square table rho[phi_o_bin, phi_i_bin] (``phi_o=None``: one slice per row,
    at the bin centres) or an [S, M] array of rows at the view angles ``phi_o`` [S] (radians; e.g.
    ``rows_at(table, slice_centres(S))``, the slices the shader uses).  The target of a slice is
    rho(phi_o, phi_i) cos(phi_i) (Raymond et al. 2016, eq. 5) in bin averages over the M phi_i bins
    (centres -pi/2 + (k + 1/2) pi/M), i.e. rho[o, i] C_i / (pi/M) for the cosine-weighted bin
    averages of ``scratch_brdf`` (C_i = integral of cos over bin i); the model is what Cycles
    evaluates for the lobes (``cycles_ggx.cone_collapse_binned``, Smith G and horizon losses
    included).  Slices stop getting lobes once their relative L1 error <= ``error_target``.
    ``dists``: "ggx", "beckmann", "mixed" (each greedy lobe picks the better of the two) or "auto"
    (default: all-Beckmann fit, then an all-GGX refit of the slices above the target; the better per
    slice is kept).
    ``min_width`` (alpha_y floor) defaults to 2.5 alpha_x; lobe centres stay within pi/2 - ``margin``.

    Returns a dict: ``weights``, ``tilts`` (radians), ``widths`` (alpha_y), all float [S, K] (unused
    slots: weight 0), ``dist`` int8 [S, K] (0 = GGX, 1 = Beckmann: OSL ``microfacet("ggx"|"beckmann",
    N', u, alpha_x, width, 0, 0)``), ``error`` [S] (relative L1 per slice), ``n_lobes`` [S],
    ``phi_o`` [S] and ``alpha_x``.
    """
    rho, phi = _check_rows(rho, phi_o)
    M = rho.shape[1]
    if min_width is None:
        min_width = 2.5 * alpha_x
    _check_common(K, error_target, alpha_x, min_width, max_iter)
    if not (np.isfinite(margin) and 0.0 <= margin < 0.5 * np.pi):
        raise ValueError(f"margin must be in [0, pi/2) radians; got {margin!r}")
    edges = phi_bin_edges(M)
    # scratch_brdf tables hold cosine-weighted bin averages: the bin average of rho cos(phi_i) over
    # bin i is rho[o, i] C_i / (pi/M), C_i = sin(edge_{i+1}) - sin(edge_i).
    f = rho * (np.diff(np.sin(edges)) / np.diff(edges))[None, :]
    w, t, a, err, d = _fit_rows(f, phi, edges, K, alpha_x, min_width, error_target, margin, max_iter,
                                _check_dists(dists))
    return {"weights": w, "tilts": t, "widths": a, "dist": d, "error": err,
            "n_lobes": np.count_nonzero(w > 0, axis=1), "phi_o": phi, "alpha_x": np.float64(alpha_x)}


def fit_lobes(slice_values, phi_o: float, K: int = 8, error_target: float = 0.03, alpha_x: float = 1e-4,
              min_width=None, margin: float = 0.0, max_iter: int = 8, dists="auto") -> LobeSet:
    """Fit one slice: ``slice_values[i]`` = rho(phi_o, phi_i) cos(phi_i) over M uniform phi_i bins on [-pi/2, pi/2].

    Same model and method as :func:`fit_table` (eq. 5 of Raymond et al. 2016; radians).  Returns a
    :class:`LobeSet` whose lobes, rendered by Cycles, reproduce the slice.
    """
    f = np.asarray(slice_values, dtype=float)
    if f.ndim != 1 or f.size < 4:
        raise ValueError(f"slice_values must be a 1D array of >= 4 bins; got shape {f.shape}")
    if not np.all(np.isfinite(f)) or np.any(f < 0):
        raise ValueError("slice_values must be finite and >= 0")
    if not (np.isfinite(phi_o) and abs(phi_o) < 0.5 * np.pi):
        raise ValueError(f"phi_o must be in (-pi/2, pi/2) radians; got {phi_o!r}")
    M = f.size
    if min_width is None:
        min_width = 2.5 * alpha_x
    _check_common(K, error_target, alpha_x, min_width, max_iter)
    if not (np.isfinite(margin) and 0.0 <= margin < 0.5 * np.pi):
        raise ValueError(f"margin must be in [0, pi/2) radians; got {margin!r}")
    w, t, a, err, d = _fit_rows(f[None, :], np.array([float(phi_o)]), phi_bin_edges(M), K, alpha_x, min_width,
                                error_target, margin, max_iter, _check_dists(dists))
    return LobeSet(weights=w[0], tilts=t[0], widths=a[0], alpha_x=float(alpha_x), error=float(err[0]), dist=d[0])
