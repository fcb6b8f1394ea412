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
  rejections) is shared with GGX, see :mod:`precompute.cycles_ggx`.

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
]

_INV_SQRT_PI = 1.0 / np.sqrt(np.pi)


def beckmann_aniso_D(alpha_x, alpha_y, local_H):
    """Cycles ``bsdf_aniso_D<BECKMANN>``: exp(-(hx^2 + hy^2)/hz^2) / (pi ax ay hz^4), h = H/(ax, ay, 1).

    ``local_H`` [..., 3] in the closure frame (X = tangent, Z = N); per steradian.
    """
    Hs = local_H / np.stack(np.broadcast_arrays(alpha_x, alpha_y, 1.0), axis=-1)
    c2 = Hs[..., 2] ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return np.exp(-(Hs[..., 0] ** 2 + Hs[..., 1] ** 2) / c2) / (np.pi * alpha_x * alpha_y * c2 * c2)


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
