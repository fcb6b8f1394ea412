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

``jitter=True`` ("stochastic box lobes"): every lobe also has a tilt jitter j >= 0; the shader
draws its tilt uniformly in [t - j, t + j] per sample, which renders the lobe convolved with a box
of phi_i width 4 j (``cycles_ggx.cone_collapse_binned_jittered``; light sampling still sees an
ordinary closure).  The whole box stays above the horizon (|2t - phi_o| + 2 j <= pi/2 - margin).
Changes to the method: the greedy step also tries boxes on the plateau of the residual around
its peak; the LM also moves j (smooth factor frozen in the finite differences,
``cycles_ggx.JitteredAtoms``); slices above the target get a third start: narrow lobes jittered
over the K heaviest pieces of the slice's best (least-squares, dynamic programming)
piecewise-constant approximation.  Reported errors use the exact jittered model.

Units: angles in radians; weights are Cycles closure weights (dimensionless).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cycles.ggx import (BECKMANN, BSDF_ROUGHNESS_SQ_THRESH, GGX, JitteredAtoms, cone_collapse_binned,
                          cone_collapse_binned_jittered, dist_code)

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

    ``alpha_x`` is the (shared) along-scratch roughness; ``error`` the relative L1 error of the fit;
    ``jitters`` the tilt jitter of each lobe (radians, 0 = plain lobe).  Unused slots have weight 0.
    """

    weights: np.ndarray
    tilts: np.ndarray
    widths: np.ndarray
    alpha_x: float
    error: float
    dist: np.ndarray = None   # int8 codes per lobe: 0 = GGX, 1 = Beckmann
    jitters: np.ndarray = None  # tilt jitter per lobe (radians; 0 = plain lobe)

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


def lobe_model(phi_o, weights, tilts, widths, phi_edges, alpha_x=1e-3, theta_o=0.0, dist="ggx", jitters=None):
    """Bin-averaged sum_k w_k g(phi_i; phi_o, t_k, alpha_y_k) for lobes shaped [..., K] (radians).

    ``phi_o`` broadcasts against the leading dims; ``dist`` ("ggx", "beckmann" or codes [..., K]);
    ``jitters`` (radians of tilt, [..., K], None = 0): tilt-jittered lobes
    (``cycles_ggx.cone_collapse_binned_jittered``).  Returns [..., nbins] (the fitted rho cos(phi_i)).
    """
    w = np.asarray(weights, float)
    po = np.asarray(phi_o, float)[..., None]
    if jitters is None:
        atoms = cone_collapse_binned(po, phi_edges, tilts, widths, alpha_x, theta_o, dist=dist)
    else:
        atoms = cone_collapse_binned_jittered(po, phi_edges, tilts, widths, jitters, alpha_x, theta_o, dist=dist)
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

    def __init__(self, f, phi_o, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes=(GGX,),
                 jitter=False):
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
        self.jitter = bool(jitter)
        self.j = np.zeros((S, K))     # tilt jitter (radians): a box of phi_i width 4 j around c

    def atoms(self, idx, c, l, d=None, j=None, exact=False):
        """Bin-averaged cone collapse of lobes (c, l, d, j) [s, k] for slices idx -> [s, k, M].

        Jittered lobes: one tilt panel while fitting (the smooth factor at the posterior tilt; ~1 %
        off for wide lobes with wide jitter only), the default panels when ``exact`` (reported errors).
        """
        po = self.phi_o[idx][:, None]
        t = 0.5 * (c + po)
        d = self.d[idx, :c.shape[1]] if d is None else d
        if not self.jitter:
            return cone_collapse_binned(po, self.edges, t, np.exp(l), self.ax, dist=d)
        j = self.j[idx, :c.shape[1]] if j is None else j
        return cone_collapse_binned_jittered(po, self.edges, t, np.exp(l), j, self.ax, dist=d,
                                             nodes=None if exact else 1)

    def project(self, c, j):
        """Keep the lobe centre and its whole box above the horizon: |c| + 2 j <= cmax."""
        c = np.clip(c, -self.cmax, self.cmax)
        return c, np.clip(j, 0.0, 0.5 * (self.cmax - np.abs(c)))

    def model(self, idx, w=None, c=None, l=None, j=None, exact=False):
        w = self.w[idx] if w is None else w
        c = self.c[idx] if c is None else c
        l = self.l[idx] if l is None else l
        j = self.j[idx] if j is None else j
        return np.einsum("sk,skm->sm", w, self.atoms(idx, c, l, j=j, exact=exact))

    def errors(self, idx=None):
        idx = np.arange(len(self.f)) if idx is None else idx
        return relative_l1(self.model(idx, exact=True), self.f[idx])

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
        jj = np.zeros_like(cc)
        if self.jitter:
            # box candidates: the residual's plateau around the peak (where it stays above a
            # fraction of the peak), as a box of phi_i width 4 j, for each width of the grid
            # (box edges want narrow lobes: every other width of the lower part of the grid)
            cb, jb = self._plateaus(rs, peak)                           # [s, F]
            nf = cb.shape[1]
            sub = np.flatnonzero(np.tile(np.arange(self.width_grid.size) % 2 == 0, len(self.codes))
                                 & np.tile(self.width_grid <= 0.2, len(self.codes)))
            Wb = sub.size
            cc = np.concatenate([cc, np.repeat(cb, Wb, axis=1)], axis=1)
            jj = np.concatenate([jj, np.repeat(jb, Wb, axis=1)], axis=1)
            ll = np.concatenate([ll, np.tile(ll[:, sub], (1, nf))], axis=1)
            dd = np.concatenate([dd, np.tile(dd[:, sub], (1, nf))], axis=1)
            cc, jj = self.project(cc, jj)
        A = self.atoms(idx, cc, ll, dd, jj)                             # [s, W, M]
        num = np.einsum("sm,swm->sw", r, A)
        den = np.einsum("swm,swm->sw", A, A) + 1e-300
        wt = np.maximum(num / den, 0.0)
        cost = np.sum(np.abs(r[:, None, :] - wt[..., None] * A), axis=2)  # L1, the metric we report
        best = np.argmin(cost, axis=1)
        k = self.n[idx]
        s_ = np.arange(len(idx))
        self.w[idx, k] = wt[s_, best]
        self.c[idx, k] = cc[s_, best]
        self.l[idx, k] = ll[s_, best]
        self.d[idx, k] = dd[s_, best]
        self.j[idx, k] = jj[s_, best]
        self.n[idx] += 1

    _PLATEAU_FRACTIONS = (0.3, 0.6)

    def _plateaus(self, rs, peak):
        """Box candidates (centre c, jitter j) [s, F]: the contiguous run of bins around ``peak``
        where ``rs`` >= fraction * rs[peak], for each of :attr:`_PLATEAU_FRACTIONS`."""
        M = rs.shape[1]
        ii = np.arange(M)[None, :]
        top = rs[np.arange(len(rs)), peak][:, None]
        cs, js = [], []
        for frac in self._PLATEAU_FRACTIONS:
            below = rs < frac * top
            left = np.max(np.where(below & (ii < peak[:, None]), ii, -1), axis=1) + 1      # first bin of the run
            right = np.min(np.where(below & (ii > peak[:, None]), ii, M), axis=1)          # one past the last
            lo, hi = self.edges[left], self.edges[right]
            cs.append(0.5 * (lo + hi))
            js.append(0.125 * (hi - lo))                                                    # 4 j = width / 2 ... width
        c = np.stack(cs, axis=1)
        j = np.stack(js, axis=1)
        # each run as a box of its full width (4 j = hi - lo) and of half of it
        return np.concatenate([c, c], axis=1), np.concatenate([2.0 * j, j], axis=1)

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
        self.j[idx] = 0.0
        self.n[idx] = K
        self._nnls_weights(idx)

    def segment_start(self, idx):
        """K boxes on the K heaviest pieces of the slice's best piecewise-constant approximation.

        Optimal segmentation into K + 2 pieces (least squares; dynamic programming over the bin
        edges, vectorised over slices), each piece -> one narrow lobe jittered over the piece
        (4 j = piece width), weights by NNLS.  For profiles whose bounce orders each spread light
        evenly over an interval (circular grooves) this is already close to the answer.
        """
        f = self.f[idx]
        s, M = f.shape
        P = min(self.K + 2, M)
        cs = np.concatenate([np.zeros((s, 1)), np.cumsum(f, axis=1)], axis=1)             # [s, M+1]
        cs2 = np.concatenate([np.zeros((s, 1)), np.cumsum(f * f, axis=1)], axis=1)
        n_ = np.arange(M + 1)
        length = n_[None, :] - n_[:, None]                                                # [i, j] = j - i
        with np.errstate(divide="ignore", invalid="ignore"):
            cost = (cs2[:, None, :] - cs2[:, :, None]) - (cs[:, None, :] - cs[:, :, None]) ** 2 / length
        cost = np.where(length[None] > 0, np.maximum(cost, 0.0), np.inf)                  # [s, i, j]
        D = np.full((s, M + 1), np.inf)
        D[:, 0] = 0.0
        back = np.zeros((P, s, M + 1), dtype=int)
        for p in range(P):
            tot = D[:, :, None] + cost
            back[p] = np.argmin(tot, axis=1)
            D = np.min(tot, axis=1)
        # backtrack the P pieces [lo, hi) of every slice
        hi = np.full(s, M)
        rows = np.arange(s)
        lo_all, hi_all = np.zeros((s, P), dtype=int), np.zeros((s, P), dtype=int)
        for p in range(P - 1, -1, -1):
            lo = back[p, rows, hi]
            lo_all[:, p], hi_all[:, p] = lo, hi
            hi = lo
        mass = (cs[rows[:, None], hi_all] - cs[rows[:, None], lo_all])                    # [s, P]
        top = np.argsort(-mass, axis=1, kind="stable")[:, :self.K]
        lo_e = self.edges[np.take_along_axis(lo_all, top, axis=1)]
        hi_e = self.edges[np.take_along_axis(hi_all, top, axis=1)]
        c0, j0 = self.project(0.5 * (lo_e + hi_e), 0.25 * (hi_e - lo_e))
        bin_w = np.pi / M
        self.c[idx] = c0
        self.j[idx] = j0
        self.l[idx] = max(self.lmin, float(np.log(np.tan(0.25 * bin_w))))
        self.d[idx] = BECKMANN if BECKMANN in self.codes else self.codes[0]
        self.n[idx] = self.K
        self._nnls_weights(idx)

    def _nnls_weights(self, idx):
        """Non-negative least-squares weights of the current lobe shapes (projected coordinate descent)."""
        f = self.f[idx]
        K = self.K
        A = self.atoms(idx, self.c[idx], self.l[idx], j=self.j[idx])
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
        """Projected LM on (w, c, log ay[, j]) of the active lobes, IRLS weights for an L1-like cost."""
        if len(idx) == 0 or iters == 0:
            return
        K = int(self.n[idx].max())                                       # only the used lobe slots
        f = self.f[idx]
        active = np.arange(K)[None, :] < self.n[idx][:, None]           # [s, K]
        w, c, l = self.w[idx, :K].copy(), self.c[idx, :K].copy(), self.l[idx, :K].copy()
        j = self.j[idx, :K].copy()
        lam = np.full(len(idx), 1e-2)
        scale = self.scale[idx][:, None]
        eps_irls = 0.02 * scale                                          # IRLS floor (relative to peak)
        G = 4 if self.jitter else 3                                      # parameter groups
        actG = np.concatenate([active] * G, axis=1)
        eye = np.eye(G * K)
        d = self.d[idx, :K]

        po = self.phi_o[idx][:, None]
        state = None

        def resid(w_, c_, l_, j_, fresh=True):
            if self.jitter:
                # one-panel jittered atoms that keep their smooth factor for the Jacobian below; the
                # smooth factor (slow in the lobe shape) is refreshed every other iteration
                st = (JitteredAtoms(po, self.edges, 0.5 * (c_ + po), np.exp(l_), j_, self.ax, dist=d) if fresh
                      else state.moved(0.5 * (c_ + po), np.exp(l_), j_))
                return np.einsum("sk,skm->sm", w_, st.atoms) - f, st.atoms, st
            A_ = self.atoms(idx, c_, l_, d, j_)
            return np.einsum("sk,skm->sm", w_, A_) - f, A_, None

        r, A, state = resid(w, c, l, j)
        for it in range(iters):
            irls = 1.0 / np.sqrt(np.maximum(np.abs(r), eps_irls))        # |r| ~ r^2 / |r|
            cost = np.sum((r * irls) ** 2, axis=1)
            dc, dl, dj = 1e-4, 1e-3, 2e-3
            if self.jitter:
                # finite differences of the sharp (slope-CDF) factor only, smooth factor frozen;
                # jitter: forward secant (the box average is even in j, flat at j = 0)
                t = 0.5 * (c + po)
                Ac = 0.5 * state.d_dtilt()                               # t = (c + phi_o) / 2
                Al = (A - state.perturbed(t, np.exp(l - dl), j)) / dl
                Aj = (state.perturbed(t, np.exp(l), j + dj) - A) / dj
                parts = [A, w[..., None] * Ac, w[..., None] * Al, w[..., None] * Aj]
            else:
                Ac = (self.atoms(idx, c + dc, l, d, j) - A) / dc
                Al = (A - self.atoms(idx, c, l - dl, d, j)) / dl         # backward: alpha_y = 1 is a bound
                parts = [A, w[..., None] * Ac, w[..., None] * Al]
            J = np.concatenate(parts, axis=1)                            # [s, G K, M]
            J = np.where(actG[..., None], J * irls[:, None, :], 0.0)
            JtJ = J @ J.transpose(0, 2, 1)
            g = np.einsum("spm,sm->sp", J, r * irls)
            diag = np.where(actG, np.einsum("spp->sp", JtJ), 1.0)
            H = JtJ + eye * (lam[:, None] * diag + 1e-12 * np.max(diag, axis=1, keepdims=True) + (~actG))[:, :, None]
            try:
                step = -np.linalg.solve(H, g[..., None])[..., 0]
            except np.linalg.LinAlgError:
                step = -g / np.maximum(diag, 1e-300)
            step = np.where(actG, np.nan_to_num(step), 0.0)
            wn = np.maximum(w + step[:, :K], 0.0)
            cn = np.clip(c + step[:, K:2 * K], -self.cmax, self.cmax)
            ln = np.clip(l + np.clip(step[:, 2 * K:3 * K], -1.0, 1.0), self.lmin, self.lmax)
            jn = j
            if self.jitter:
                cn, jn = self.project(cn, j + np.clip(step[:, 3 * K:], -0.1, 0.1))
            rn, An, state_n = resid(wn, cn, ln, jn, fresh=it % 2 == 1 or it == iters - 1)
            cost_new = np.sum((rn * irls) ** 2, axis=1)
            better = cost_new < cost
            b = better[:, None]
            w, c, l, j = np.where(b, wn, w), np.where(b, cn, c), np.where(b, ln, l), np.where(b, jn, j)
            r = np.where(b, rn, r)
            A = np.where(b[..., None], An, A)
            if state is not None:
                state.merge(state_n, b)
            lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-7, 1e7)
        self.w[idx, :K], self.c[idx, :K], self.l[idx, :K], self.j[idx, :K] = w, c, l, j

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
        # (with jitter, a third start: boxes on the pieces of a piecewise-constant segmentation)
        starts = [self.quantile_start] + ([self.segment_start] if self.jitter else [])
        for start in starts:
            if not (todo.size and self.K >= 2):
                break
            saved = (self.w[todo].copy(), self.c[todo].copy(), self.l[todo].copy(), self.d[todo].copy(),
                     self.n[todo].copy(), self.j[todo].copy())
            start(todo)
            self.refine(todo, 3 * self.max_iter)
            e2 = self.errors(todo)
            worse = e2 >= err[todo]
            back = todo[worse]
            for arr, old in zip((self.w, self.c, self.l, self.d, self.n, self.j), saved):
                arr[back] = old[worse]
            err[todo] = np.minimum(e2, err[todo])
        # tidy: drop zero-weight lobes, sort by weight
        self.w[~np.isfinite(self.w)] = 0.0
        order = np.argsort(-self.w, axis=1, kind="stable")
        take = lambda a: np.take_along_axis(a, order, axis=1)  # noqa: E731
        self.w, self.c, self.l, self.d, self.j = take(self.w), take(self.c), take(self.l), take(self.d), take(self.j)
        unused = self.w <= 0
        self.d[unused] = 0
        self.j[unused] = 0.0
        self.c[unused] = 0.0
        self.l[unused] = 0.0
        self.w[unused] = 0.0
        tilts = 0.5 * (self.c + self.phi_o[:, None])
        tilts[unused] = 0.0
        # (w, t, a, err) like before for existing callers; the distribution codes are in self.d
        return self.w, tilts, np.exp(self.l), np.where(nonzero, self.errors(), 0.0)


def _fit_rows(f, phi, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes, jitter=False):
    """Run the batched fitter; ``codes == "auto"``: Beckmann lobes first (Gaussian slope tails make
    the sharp edges of scratch slices), then the slices still above the target are refitted with
    GGX lobes (heavy tails: better on the one-sided 1/sqrt caustic shoulders) and the better fit
    per slice is kept.  Returns (weights, tilts, widths, error, dist, jitters)."""
    def run(f_, phi_, codes_):
        fitter = _Fitter(f_, phi_, edges, K, alpha_x, min_width, error_target, margin, max_iter, codes_, jitter)
        return list(fitter.run()) + [fitter.d, fitter.j]

    if codes != "auto":
        return tuple(run(f, phi, codes))
    out = run(f, phi, (BECKMANN,))
    redo = np.flatnonzero(out[3] > error_target)
    if redo.size:
        alt = run(f[redo], phi[redo], (GGX,))
        better = alt[3] < out[3][redo]
        for j in range(len(out)):
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
              margin: float = 0.0, max_iter: int = 8, phi_o=None, dists="auto", jitter: bool = False):
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
    ``jitter=True``: every lobe also gets a tilt jitter j >= 0 (the shader draws its tilt uniformly
    in [t - j, t + j] per sample): a box of phi_i width 4 j with softened edges
    (``cycles_ggx.cone_collapse_binned_jittered``); the whole box stays within pi/2 - ``margin``.

    Returns a dict: ``weights``, ``tilts`` (radians), ``widths`` (alpha_y), ``jitters`` (radians of
    tilt, all 0 without ``jitter``), all float [S, K] (unused slots: weight 0), ``dist`` int8 [S, K]
    (0 = GGX, 1 = Beckmann: OSL ``microfacet("ggx"|"beckmann", N', u, alpha_x, width, 0, 0)``),
    ``error`` [S] (relative L1 per slice), ``n_lobes`` [S], ``phi_o`` [S] and ``alpha_x``.
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
    w, t, a, err, d, j = _fit_rows(f, phi, edges, K, alpha_x, min_width, error_target, margin, max_iter,
                                   _check_dists(dists), bool(jitter))
    return {"weights": w, "tilts": t, "widths": a, "jitters": j, "dist": d, "error": err,
            "n_lobes": np.count_nonzero(w > 0, axis=1), "phi_o": phi, "alpha_x": np.float64(alpha_x)}


def fit_lobes(slice_values, phi_o: float, K: int = 8, error_target: float = 0.03, alpha_x: float = 1e-4,
              min_width=None, margin: float = 0.0, max_iter: int = 8, dists="auto", jitter: bool = False) -> LobeSet:
    """Fit one slice: ``slice_values[i]`` = rho(phi_o, phi_i) cos(phi_i) over M uniform phi_i bins on [-pi/2, pi/2].

    Same model and method as :func:`fit_table` (eq. 5 of Raymond et al. 2016; radians; ``jitter``:
    lobes may be tilt-jittered boxes).  Returns a :class:`LobeSet` whose lobes, rendered by Cycles,
    reproduce the slice.
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
    w, t, a, err, d, j = _fit_rows(f[None, :], np.array([float(phi_o)]), phi_bin_edges(M), K, alpha_x, min_width,
                                   error_target, margin, max_iter, _check_dists(dists), bool(jitter))
    return LobeSet(weights=w[0], tilts=t[0], widths=a[0], alpha_x=float(alpha_x), error=float(err[0]), dist=d[0],
                   jitters=j[0])
