"""What the scratches take from the base: the energy-consistent base weight of the layer (issue #17).

Velinov, Werner & Hullin 2018, §3.1, eqs. 1-11 (equation numbers below are theirs).

The cross term eq. 6 drops
--------------------------
Inside the coherence window g(x) = exp(−|x|²/2σ²) a scratched lossless surface reflects the field
g·r with r(x) = 1 − Σ_m 𝒟_m χ_m(x) (χ_m the footprint of scratch m, 𝒟_m = 1 − e^{i4πD/λ}, eq. 4),
whose far field is ℬ − 𝒮 (eqs. 1-2).  Parseval (|r| = 1):

    ∫ |ℬ − 𝒮|² dξ / (A_C λ²) = ∫ |g r|² dx / A_C = 1,     A_C = πσ² = ∫ |g|² dx.

Expanding |ℬ − 𝒮|² = |ℬ|² + |𝒮|² − 2 Re ℬ*𝒮 (eq. 6, first line) term by term:

* ∫|ℬ|² dξ/(A_Cλ²) = 1: the base's own energy;
* ∫|𝒮_m|² dξ/(A_Cλ²) = |𝒟_m|² ρ̃_m (eqs. 3, 9-11: ∫W² sinc²(πWξ₂/λ) dξ₂ = Wλ and
  ∫exp(−σ²k²ξ₁²) dξ₁ = λ/(2√π σ)), and the scratch cross terms of eq. 7 integrate to 0 for
  scratches that do not overlap;
* 2 Re ∫ℬ*𝒮_m dξ/(A_Cλ²) = 2 Re(𝒟_m) ρ̃_m = |𝒟_m|² ρ̃_m, because 2 Re 𝒟 = 2 − 2cos(4πD/λ) = |𝒟|² (eq. 11).

with ρ̃_m = (1/A_C) ∫ |g|² χ_m dx the share of the window's *energy* that falls on scratch m
(``coverage``; in terms of eq. 10, ρ̃_m = |η_s|²_m W/(2√π σ A_C)).  So the cross term that eq. 6 replaces
by (1 − ρ_c) removes from the specular reflection exactly what the scratch term adds, per wavelength:
the energy-consistent base weight is 1 − Σ_m |𝒟_m|²ρ̃_m, not 1 − ρ_c (ℬ*𝒮 lives where ℬ lives, on the
base's own lobe, so it scales the base).  Eq. 17's ρ_c is a different number: its window is the field's
(e^{−r²/2σ²}, not the intensity's e^{−r²/σ²}), √2 larger on a scratch's axis and twice the true area
fraction on average (eq. 18: 2Wl/A_𝒫 where the scratch covers Wl/A_𝒫).  Zero-depth scratches (𝒟 = 0)
leave the base untouched exactly.

What reaches the hemisphere
---------------------------
The model's lobe (eq. 25) is a sinc² along the line ξ₁ = 0; only its chord ξ₂ ∈ [ω_o·b − ϱ, ω_o·b + ϱ],
ϱ = √(1 − (ω_o·t)²), is above the horizon (|ω_i| = 1, ω_i,z ≥ 0; the ξ₁ integral is eq. 26's δ).  The
rest is evanescent in this paraxial model (normal-incidence phase, eq. 4).  The layer moves only what
the scratches actually deliver,

    E = Σ_m |𝒟_m|² ρ̃_m F_m,    F_m = 1 − T(kW(ϱ + ω_o·b)) − T(kW(ϱ − ω_o·b))    (``propagating_fraction``)

with T(x) the sinc² tail beyond x (``tail_fraction``; closed form from eq. 27's antiderivative), and
leaves the evanescent share in the base, as the Harvey–Shack renormalisation does [Kry06]: a lossless
base stays lossless at every view.  The shader evaluates T by a rational function (``tail_fraction``,
exact=False; |error| ≤ 0.0087, no trigonometry), this module's default so it is the shader's twin.

Overlap
-------
Eq. 7 adds overlapping scratches incoherently, so E can exceed 1 (several λ/4 scratches on one
coherence area).  ``normalise`` maps E to N(E) = E up to ``KNEE``, to E − (E − KNEE)²/(4(1 − KNEE))
from there to ``SATURATION`` = 2 − KNEE and to 1 beyond (C¹, monotone, bounded by 1): the base is
weighted by 1 − N(E) ≥ 0 and the scratch term by N(E)/E ≤ 1, so the layer never creates energy and a
white furnace still sees exactly the base's albedo (E·N/E + 1 − N = 1).  Below the knee the layer is
the model unchanged; where the scratches take more than ``SATURATION`` times what is there the base
weight is exactly 0, as eq. 6's clamped (1 − ρ) is where ρ ≥ 1 (Cycles then drops the base closure;
the quadratic also costs the shader no exp).  The shader estimates E per sample (route A: from its
lobe's segment, route B: from the RIS candidates; unbiased; given the candidates and the segment the
scratch lobe's albedo is that estimate, so the furnace balance holds sample by sample) and applies N
to the estimate: where the estimate crosses the knee (dense sets) the scratches render a few % darker
than with the exact E of ``evaluate`` (exhaustive candidates, route B: exact).

Units: W, D, λ, σ in µm; everything returned is dimensionless.
"""
from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["KNEE", "SATURATION", "TAIL_COEF", "coverage", "tail_fraction", "propagating_fraction", "normalise", "base_weight"]

#: E up to which the layer is the model unchanged (see ``normalise``).
KNEE = 0.8
#: E from which the scratches take everything (N = 1, base weight 0): 2 − KNEE (``normalise``).
SATURATION = 2.0 - KNEE
#: Rational tail T(x) ≈ (1 + a₁x + a₂x²)/(2 + b₁x + b₂x² + π a₂ x³): exact at 0 and as 1/(πx) at ∞;
#: minimax fit to the exact tail on [0, 1e6], max |error| 0.0087 (at x ≈ 7.8, the first side lobe).
TAIL_COEF = (-0.31703603, 0.12523624, 0.29740418, -0.39897547)


def coverage(eta_sq_um2, W_um, sigma_um) -> np.ndarray:
    """ρ̃ = |η_s|² W / (2√π σ A_C): the share of the coherence window's energy on a scratch.

    From eq. 10 (|η_s|² point or footprint value, µm²) and the Parseval argument in the module
    docstring; for an infinite scratch at distance s_b, W e^{−s_b²/σ²}/(√π σ).  Then |𝒟|²ρ̃ is the
    energy of the scratch term (eqs. 3, 9-11 integrated over ξ).  W, σ in µm; dimensionless.
    """
    sigma_um = np.asarray(sigma_um, float)
    return np.asarray(eta_sq_um2) * np.asarray(W_um) / (2.0 * np.sqrt(np.pi) * sigma_um * np.pi * sigma_um ** 2)


def tail_fraction(x, exact: bool = False) -> np.ndarray:
    """Share of ∫ sinc²(πWξ₂/λ) dξ₂ beyond ξ₂ = x/(kW) (x ≥ 0, k = 2π/λ): T(x) ∈ [0, ½].

    Exact: T(x) = ½ − (2 Si(x) − x sinc²(x/2))/(2π) (eq. 27's antiderivative N, normalised by its
    total λ/W).  Default (the shader's): the rational fit ``TAIL_COEF``, |error| ≤ 0.0087.
    """
    x = np.maximum(np.asarray(x, float), 0.0)
    if exact:
        return 0.5 - (2.0 * special.sici(x)[0] - x * np.sinc(x / (2.0 * np.pi)) ** 2) / (2.0 * np.pi)
    a1, a2, b1, b2 = TAIL_COEF
    return (1.0 + x * (a1 + a2 * x)) / (2.0 + x * (b1 + x * (b2 + np.pi * a2 * x)))


def propagating_fraction(wo_t, wo_b, W_um, lam_um, exact: bool = False) -> np.ndarray:
    """F: share of a scratch's lobe energy that leaves above the horizon (see module docstring).

    ``wo_t``, ``wo_b``: the view direction's components along the scratch tangent t and bitangent b
    (local frame, |ω_o| = 1, ω_o,z ≥ 0); W, λ in µm.  The chord of the line ξ₁ = 0 inside the
    hemisphere is ξ₂ ∈ [ω_o·b − ϱ, ω_o·b + ϱ], ϱ = √(1 − (ω_o·t)²); F = 1 − T(kW(ϱ + ω_o·b)) −
    T(kW(ϱ − ω_o·b)) with ``tail_fraction``.  Dimensionless, in [0, 1].
    """
    wo_t, wo_b = np.asarray(wo_t, float), np.asarray(wo_b, float)
    rr = np.sqrt(np.maximum(0.0, 1.0 - wo_t * wo_t))
    kW = 2.0 * np.pi * np.asarray(W_um) / np.asarray(lam_um)
    return np.clip(1.0 - tail_fraction(kW * (rr + wo_b), exact) - tail_fraction(kW * (rr - wo_b), exact), 0.0, 1.0)


def normalise(E):
    """(N(E), N(E)/E): the energy the layer moves and the factor on the scratch term (module docstring).

    N(E) = E for E ≤ KNEE, E − (E − KNEE)²/(4(1 − KNEE)) up to SATURATION = 2 − KNEE, 1 above:
    continuous with its first derivative (1 at the knee, 0 at saturation), ≤ 1.  The factor is 1
    where E ≤ KNEE (also at E = 0).  The shader's twin: ``osl/iridescent_layer.osl`` (no exp).
    """
    E = np.maximum(np.asarray(E, float), 0.0)
    k = KNEE
    d = np.clip(E - k, 0.0, SATURATION - k)
    N = np.where(E <= k, E, np.minimum(E - d * d * (0.25 / (1.0 - k)), 1.0))
    return N, np.where(E <= k, 1.0, N / np.where(E > 0.0, E, 1.0))


def base_weight(E) -> np.ndarray:
    """1 − N(E): the energy-consistent weight of the base per wavelength (``normalise``), in (0, 1]."""
    return 1.0 - normalise(E)[0]
