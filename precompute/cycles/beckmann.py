"""The Beckmann microfacet distribution exactly as Cycles (Blender 5.0) evaluates it.

Read from ``intern/cycles/kernel/closure/bsdf_microfacet.h`` (the templated
``bsdf_microfacet_eval<BECKMANN>`` shared with GGX; OSL ``microfacet("beckmann", N, T, ax, ay, eta, 0)``
calls ``bsdf_microfacet_beckmann_setup``: alpha_x, alpha_y saturated to [0, 1], no Fresnel):

- ``bsdf_aniso_D<BECKMANN>``: with H scaled by (1/ax, 1/ay, 1),
  ``D = exp(-(Hx^2 + Hy^2) / Hz^2) / (pi ax ay Hz^4)``  (per steradian);
- ``bsdf_lambda_from_sqr_alpha_tan_n<BECKMANN>``: **not** the exact Smith Lambda
  ``(erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi))`` but Walter et al. 2007's rational approximation
  ("below Equation 69" of Heitz 2014), with ``s = (ax Vx)^2 + (ay Vy)^2) / Vz^2`` = 1/a^2::

      Lambda = 0                                                    if s < 0.39  (a >= 1.6)
      Lambda = ((0.396 a - 1.259) a + 1) / ((2.181 a + 3.535) a)     otherwise, a = 1/sqrt(s)

- everything else (height-correlated G2 = 1/(1 + Lambda_I + Lambda_O), eval = D G2 / (4 N.wi),
  rejections) is shared with GGX, see :mod:`precompute.cycles.ggx`.

The slope-space view used by the cone collapse: Beckmann slopes (s_x, s_y) have the Gaussian
density ``P22 = exp(-(s_x/ax)^2 - (s_y/ay)^2) / (pi ax ay)``; the marginal of x = s_y / ay is
``exp(-x^2) / sqrt(pi)`` with CDF ``(1 + erf x) / 2``.  All functions are vectorised numpy;
angles in radians, roughness dimensionless.
"""
from __future__ import annotations

import numpy as np
from scipy.special import erfc

__all__ = [
    "beckmann_aniso_D",
    "beckmann_lambda_from_sqr_alpha_tan_n",
    "beckmann_aniso_lambda",
    "slope_pdf",
    "slope_tail",
    "slope_mass_and_mean",
    "angle_tail_integral",
]

_INV_SQRT_PI = 1.0 / np.sqrt(np.pi)


def beckmann_aniso_D(alpha_x, alpha_y, local_H):
    """Cycles ``bsdf_aniso_D<BECKMANN>``: exp(-(hx^2 + hy^2)/hz^2) / (pi ax ay hz^4), h = H/(ax, ay, 1).

    ``local_H`` [..., 3] in the closure frame (X = tangent, Z = N); per steradian.
    """
    Hs = local_H / np.stack(np.broadcast_arrays(alpha_x, alpha_y, 1.0), axis=-1)
    c2 = Hs[..., 2] ** 2
    # as exp(-t - 2 ln c2): just above the horizon c2^2 underflows to 0 before exp(-t) does (0/0 = NaN);
    # this form gives the limit 0.  Exactly on the horizon (c2 = 0) the value is 0 as well.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (Hs[..., 0] ** 2 + Hs[..., 1] ** 2) / c2
        d = np.exp(-t - 2.0 * np.log(c2)) / (np.pi * alpha_x * alpha_y)
    return np.where(c2 > 0, d, 0.0)


def beckmann_lambda_from_sqr_alpha_tan_n(sqr_alpha_tan_n):
    """Cycles ``bsdf_lambda_from_sqr_alpha_tan_n<BECKMANN>`` (Walter et al. 2007 approximation, see module doc)."""
    s = np.asarray(sqr_alpha_tan_n, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = 1.0 / np.sqrt(s)
        lam = ((0.396 * a - 1.259) * a + 1.0) / ((2.181 * a + 3.535) * a)
    # s = inf (V on the horizon) -> a = 0 -> Lambda = inf; keep that limit (G2 -> 0)
    lam = np.where(np.isinf(s), np.inf, lam)
    return np.where(s < 0.39, 0.0, lam)


def beckmann_aniso_lambda(alpha_x, alpha_y, local_V):
    """Cycles ``bsdf_aniso_lambda<BECKMANN>``: Lambda of ((ax Vx)^2 + (ay Vy)^2) / Vz^2 (closure frame)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((alpha_x * local_V[..., 0]) ** 2 + (alpha_y * local_V[..., 1]) ** 2) / local_V[..., 2] ** 2
    return beckmann_lambda_from_sqr_alpha_tan_n(s)


def slope_pdf(x):
    """Density of the Beckmann slope marginal in units of alpha: exp(-x^2) / sqrt(pi)."""
    x = np.asarray(x, dtype=float)
    return _INV_SQRT_PI * np.exp(-x * x)


def slope_tail(x):
    """1 - CDF(|x|) = erfc(|x|) / 2 of the Beckmann slope marginal (no cancellation in the tails)."""
    return 0.5 * erfc(np.abs(x))


def slope_mass_and_mean(x_lo, x_hi):
    """Mass and mean of the marginal on [x_lo, x_hi]; int x p(x) dx = -exp(-x^2) / (2 sqrt(pi))."""
    t_lo, t_hi = slope_tail(x_lo), slope_tail(x_hi)
    mass = np.where(x_lo >= 0, t_lo - t_hi, np.where(x_hi <= 0, t_hi - t_lo, 1.0 - t_lo - t_hi))
    first = 0.5 * _INV_SQRT_PI * (np.exp(-x_lo * x_lo) - np.exp(-x_hi * x_hi))
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(mass > 1e-300, first / mass, 0.5 * (x_lo + x_hi))
    return np.maximum(mass, 0.0), np.clip(np.nan_to_num(mean), x_lo, x_hi)


#: Gauss-Legendre rule for :func:`angle_tail_integral` (16 nodes on [0, min(X, 6)]: error < 2e-8 alpha)
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
#: erfc(6) / 2 ~ 1e-17: the slope tail beyond x = 6 is below double precision of the integral
_X_SAT = 6.0
#: alpha up to which the moment series of :func:`angle_tail_integral` is used (10 terms: error < 4e-10 alpha)
_SERIES_ALPHA = 0.2
_SERIES_TERMS = 10


def angle_tail_integral(w, alpha, saturated=None):
    """T(w) = int_0^w (1 - CDF(tan(a) / alpha)) da of the Beckmann slope-angle distribution (radians).

    a = atan(alpha x) is the angle of a slope x drawn from the Beckmann marginal exp(-x^2)/sqrt(pi)
    (module doc); the tilt-jittered cone collapse of a lobe (Raymond et al. 2016, eq. 5) integrates
    its CDF over the tilt.

    With x = tan(a) / alpha (da = alpha dx / (1 + alpha^2 x^2)):
    T(w) = alpha G(X), G(X) = int_0^X erfc(x) / (2 (1 + alpha^2 x^2)) dx, X = min(tan(w) / alpha, 6)
    (the integrand is < 1e-17 beyond x = 6).  For alpha <= 0.2 the series
    G = (1/2) sum_k (-alpha^2)^k M_k(X) with the closed-form moments
    M_k(X) = int_0^X x^2k erfc(x) dx = X^(2k+1) erfc(X) / (2k+1) + 2 I_k(X) / ((2k+1) sqrt(pi)),
    I_k = int_0^X x^(2k+1) exp(-x^2) dx = k I_(k-1) - X^2k exp(-X^2) / 2, I_0 = (1 - exp(-X^2)) / 2,
    10 terms (absolute error < 4e-10 alpha); above, a 16-node Gauss-Legendre rule on [0, X]
    (< 2e-8 alpha).  ``w`` in [0, pi/2] and ``alpha`` in (0, 1] broadcast.  ``saturated``: optional
    T(pi/2) (the value for X >= 6), broadcastable to ``w``; then only the points with X < 6 are
    computed.  Used for the exact jitter average of the slope CDF
    (``cycles_ggx.cone_collapse_binned_jittered``).
    """
    w, alpha = np.broadcast_arrays(np.asarray(w, float), np.asarray(alpha, float))
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        X = np.minimum(np.tan(np.clip(w, 0.0, 0.5 * np.pi)) / alpha, _X_SAT)
    X = np.where(np.isfinite(X), X, _X_SAT)
    if saturated is None:
        out = np.empty(X.shape)
        part = np.ones(X.shape, bool)
    else:
        out = np.array(np.broadcast_to(saturated, X.shape), dtype=float)
        part = X < _X_SAT
    ser = part & (alpha <= _SERIES_ALPHA)
    gl = part & ~ser
    out[ser] = alpha[ser] * _tail_series(X[ser], alpha[ser])
    out[gl] = alpha[gl] * _tail_gl(X[gl], alpha[gl])
    return out


def _tail_gl(X, alpha):
    x = 0.5 * X[..., None] * (1.0 + _GL_X)                       # nodes on [0, X]
    f = erfc(x) / (1.0 + (alpha[..., None] * x) ** 2)
    return 0.25 * X * (f @ _GL_W)


def _tail_series(X, alpha):
    y = X * X
    ex, ec = np.exp(-y), erfc(X)
    i_k = 0.5 * (1.0 - ex)
    x2k = np.ones_like(X)                                          # X^2k
    ck = np.ones_like(X)                                           # (-alpha^2)^k
    tot = np.zeros_like(X)
    for k in range(_SERIES_TERMS):                                 # a few series terms, vectorised over points
        if k:
            i_k = k * i_k - 0.5 * x2k * y * ex
            x2k = x2k * y
            ck = ck * -(alpha * alpha)
        tot += ck * (x2k * X * ec + 2.0 * _INV_SQRT_PI * i_k) / (2 * k + 1)
    return 0.5 * tot
