"""Wave-optical iridescent scratch layer: numpy reference model.

Velinov, Werner & Hullin 2018, "Real-Time Rendering of Wave-Optical Effects on
Scratched Surfaces", CGF 37(2) — after Werner, Velinov, Jakob & Hullin 2017,
"Scratch Iridescence".  Equation numbers below refer to Velinov et al. 2018.

Units and frames
----------------
* Wavelength λ, scratch width W and depth D, coherence radius σ: **micrometres**
  (σ = 60 µm by default, Table 1).  Angles in radians.
* Scratches live in UV space (``precompute.iridescence.scratch_set.ScratchSet``); a UV length
  times ``uv_scale_um`` is micrometres.  The local shading frame is x = +U, y = +V,
  z = surface normal (UV assumed orthogonal and isotropically scaled).  The
  shading point of UV coordinate (u, v) sits at (u, v, 0) in *surface units*,
  and light geometry (sphere centre/radius, polygon vertices) is given in the
  same surface units and frame.
* Directions are unit vectors pointing away from the surface.

Model (per scratch m, eqs. 2-11, rectangular profile, infinite-scratch limit)
  ξ = (ω_i + ω_o)·(t, b)                               direction cosines
  |𝒲|² = W² sinc²(π W ξ₂/λ)                            eq. 3
  |𝒟|² = 2 − 2 cos(4π D/λ)                             eq. 11 (from eq. 4)
  |η|²  = |η_s|² |η_a|²,  |η_a|² = exp(−σ²k²ξ₁²),       eqs. 9-10
          |η_s|² = 2 A_C exp(−s_b²/σ²)
  f_r   = ((1 − ρ)|ℬ|² + Σ_m |𝒲|²|𝒟|²|η|²) / (A_C λ²)   eqs. 1, 6, 7
with A_C = πσ².  The base term (1 − ρ)|ℬ|²/(A_Cλ²) is "any physically based
material" (§3.1); this module returns the scratch term and ρ and blends a base
value supplied by the caller.

Deviations / choices (documented, each checked by a test):
* Polylines: each segment is an incoherent primitive.  For a *point* evaluation
  the spatial term of a finite segment is the infinite-line value eq. 10 times the
  fraction ½[erf(s_t2/σ) − erf(s_t1/σ)] of its Gaussian window covered by the
  segment, so consecutive collinear segments add up exactly to eq. 10.
* Eq. 16 as printed gives 2σ² e^{−s_b²/σ²} for α → 0, but its own limit must be
  eq. 10, 2πσ² e^{−s_b²/σ²}; we use the consistent form
  ``α·2σ³√π l/(a₁a₂) + (1 − α)|η_s|²(x)``.  The same α-blend is applied to ρ_𝒫
  (eq. 18) with the point value of eq. 17 when ``small_footprint_correction``.
* ρ is clamped to [0, 1] before blending (overlapping scratches).
* Base weight (``evaluate(blend=...)``): "energy" (default) weights the base per wavelength by what
  the scratches actually take from it, 1 − N(Σ_m |𝒟_m|²ρ̃_m F_m) — the cross term of eq. 6 that the
  paper drops, see ``precompute.iridescence.energy`` — and the scratch term by N(E)/E (1 unless
  overlapping scratches would scatter more than there is); "paper" is eq. 6's (1 − ρ); "none" keeps
  the base.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from ..validation import finite as _finite, positive as _positive
from . import cie, energy as _energy
from .lights import (SI_A0, SI_B0, angular_response, band_nodes, polygon_light_integral, polygon_light_integral_mc,
                     si, si_approx, sinc2_antiderivative, sphere_cone, sphere_light_integral, sphere_light_integral_mc)
from .scratch_set import (ScratchGrid, ScratchSet, brute_force_query, build_grid, random_scratches,
                          scratches_from_polylines, to_shader_arrays)

__all__ = [
    "SIGMA_UM", "RGB_WAVELENGTHS_UM", "SI_A0", "SI_B0",
    "si", "si_approx", "sinc2_antiderivative", "angular_response", "band_nodes",
    "sphere_cone", "sphere_light_integral", "sphere_light_integral_mc",
    "polygon_light_integral", "polygon_light_integral_mc",
    "depth_term", "width_term", "eta_s_sq", "scratch_coords",
    "area_density_point", "contained_length", "eta_footprint", "rho_footprint",
    "footprint_reference",
    "SphereLight", "PolygonLight", "Footprint", "EvalResult", "evaluate", "scratch_brdf", "evaluate_mc",
    "BLENDS", "pair_energy", "depth_term_angle",
    "ScratchSet", "ScratchGrid", "random_scratches", "scratches_from_polylines", "build_grid",
    "brute_force_query", "to_shader_arrays",
]

SIGMA_UM = 60.0
#: RGB mode evaluates the model at one representative wavelength per channel (µm).
RGB_WAVELENGTHS_UM = np.array([0.630, 0.532, 0.465])
#: Base weights of ``evaluate``: energy-consistent (issue #17), eq. 6's (1 − ρ), none.
BLENDS = ("energy", "paper", "none")


# ----------------------------------------------------------------------------- per-scratch terms
def depth_term(D_um, lam_um) -> np.ndarray:
    """|𝒟|² = 2 − 2 cos(4π D/λ), eq. 11 (from eq. 4).  D, λ in µm; dimensionless in [0, 4]."""
    return 2.0 - 2.0 * np.cos(4.0 * np.pi * np.asarray(D_um) / np.asarray(lam_um))


def depth_term_angle(D_um, lam_um, cos_sum) -> np.ndarray:
    """|𝒟|² = 2 − 2 cos(k D (cosθ_i + cosθ_o)): eq. 4 with the angle-dependent phase of Werner et al.
    2017 (Kirchhoff's q_z = k(ω_i,z + ω_o,z) instead of eq. 4's 2k; equal at normal incidence and
    reflection).  ``cos_sum`` = ω_i,z + ω_o,z (dimensionless, [0, 2]); D, λ in µm; in [0, 4].
    bench/iridescence_wave.py shows where the two depart (cos_sum ≲ 1.7 for D = λ/4)."""
    return 2.0 - 2.0 * np.cos(2.0 * np.pi * np.asarray(D_um) * np.asarray(cos_sum) / np.asarray(lam_um))


def width_term(W_um, xi2, lam_um) -> np.ndarray:
    """|𝒲|² = W² sinc²(π W ξ₂/λ), eq. 3 squared.  W, λ in µm → µm²."""
    W = np.asarray(W_um)
    return W * W * np.sinc(W * np.asarray(xi2) / np.asarray(lam_um)) ** 2


def scratch_coords(x_um, p0_um, p1_um):
    """Coordinates of point x relative to segment p0→p1 (all µm, (..., 2)).

    Returns ``(s_b, s_t1, s_t2)``: signed distance of x from the scratch line along
    the bitangent b = (−t_y, t_x) (eq. 2's s_b), and the tangential coordinates of
    the segment ends relative to the foot of the perpendicular from x.
    """
    d = p1_um - p0_um
    L = np.linalg.norm(d, axis=-1)
    t = d / np.where(L > 0.0, L, 1.0)[..., None]
    r0 = p0_um - x_um
    s_t1 = np.sum(r0 * t, axis=-1)
    s_b = r0[..., 1] * t[..., 0] - r0[..., 0] * t[..., 1]   # r0 · b with b = (−t_y, t_x)
    return s_b, s_t1, s_t1 + L


def eta_s_sq(s_b, sigma_um=SIGMA_UM, s_t1=-np.inf, s_t2=np.inf) -> np.ndarray:
    """Spatial term |η_s|² (µm²), eq. 10: ``2 A_C exp(−s_b²/σ²)``.

    With finite tangential end coordinates ``s_t1 < s_t2`` (µm) it is multiplied by
    the covered window fraction ½[erf(s_t2/σ) − erf(s_t1/σ)] (polyline-additive
    point evaluation, see module docstring); the defaults give eq. 10 exactly.
    """
    A_C = np.pi * sigma_um ** 2
    frac = 0.5 * (special.erf(np.asarray(s_t2) / sigma_um) - special.erf(np.asarray(s_t1) / sigma_um))
    return 2.0 * A_C * np.exp(-(np.asarray(s_b) / sigma_um) ** 2) * frac


def area_density_point(W_um, s_b, s_t1, s_t2, sigma_um=SIGMA_UM) -> np.ndarray:
    """Scratch area density ρ_c of one segment at a point, eq. 17 (first line, exact).

    ``(W/A_C) ∫_{s_t1}^{s_t2} exp(−(s_b² + s²)/(2σ²)) ds``
    ``= (W/A_C) e^{−s_b²/(2σ²)} √(π/2) σ [erf(s_t2/(√2σ)) − erf(s_t1/(√2σ))]``;
    for an infinite scratch this is the second line of eq. 17.  Dimensionless.
    """
    A_C = np.pi * sigma_um ** 2
    r2 = np.sqrt(2.0) * sigma_um
    return (np.asarray(W_um) / A_C) * np.exp(-np.asarray(s_b) ** 2 / (2 * sigma_um ** 2)) * np.sqrt(np.pi / 2) \
        * sigma_um * (special.erf(np.asarray(s_t2) / r2) - special.erf(np.asarray(s_t1) / r2))


def contained_length(p0, p1, center, a1, a2, e1) -> np.ndarray:
    """Length of segment p0→p1 inside the ellipse (line–ellipse intersection, §3.2, eq. 14).

    Ellipse: centre ``center``, semi-axis ``a1`` along unit ``e1`` and ``a2`` along
    its perpendicular.  All (..., 2)/(...) arrays in one length unit; returns
    ``l_contained`` in that unit (≥ 0).  The segment is mapped to the unit circle
    and |p(τ)|² = 1 is solved with the numerically stable quadratic formula.
    """
    e1 = np.asarray(e1, dtype=np.float64)
    e2 = np.stack([-e1[..., 1], e1[..., 0]], axis=-1)
    a1 = np.asarray(a1, dtype=np.float64)
    a2 = np.asarray(a2, dtype=np.float64)

    def to_unit(p):
        r = p - center
        return np.stack([np.sum(r * e1, axis=-1) / a1, np.sum(r * e2, axis=-1) / a2], axis=-1)

    A, B = to_unit(np.asarray(p0, float)), to_unit(np.asarray(p1, float))
    d = B - A
    qa = np.sum(d * d, axis=-1)
    qb = 2.0 * np.sum(A * d, axis=-1)
    qc = np.sum(A * A, axis=-1) - 1.0
    disc = qb * qb - 4.0 * qa * qc
    hit = (disc > 0.0) & (qa > 0.0)
    sq = np.sqrt(np.where(hit, disc, 0.0))
    qq = -0.5 * (qb + np.where(qb >= 0.0, sq, -sq))                # Numerical Recipes §5.6
    safe_qa = np.where(hit, qa, 1.0)
    r1 = qq / safe_qa
    r2 = np.where(qq != 0.0, qc / np.where(qq != 0.0, qq, 1.0), -r1)
    t0 = np.clip(np.minimum(r1, r2), 0.0, 1.0)
    t1 = np.clip(np.maximum(r1, r2), 0.0, 1.0)
    seg_len = np.linalg.norm(np.asarray(p1, float) - np.asarray(p0, float), axis=-1)
    return np.where(hit, np.maximum(t1 - t0, 0.0), 0.0) * seg_len


def _alpha(a1, a2, sigma_um):
    return np.minimum(0.5 * (np.pi * a1 * a2) / (np.pi * sigma_um ** 2), 1.0)


def eta_footprint(l_contained, a1, a2, eta_point, sigma_um=SIGMA_UM, small_footprint_correction=True) -> np.ndarray:
    """Footprint-averaged spatial term |η_𝒫|² (µm²), eqs. 15-16.

    ``l_contained``, ``a1``, ``a2`` in µm; ``eta_point`` = |η_s|² at the footprint
    centre (µm², ``eta_s_sq``).  Eq. 15: ``2σ³√π l/(a₁a₂)``; with the correction
    (eq. 16, α = min(A_𝒫/(2A_C), 1)) blended with the point value (see module
    docstring for the π of the point term).
    """
    large = 2.0 * sigma_um ** 3 * np.sqrt(np.pi) * l_contained / (a1 * a2)
    if not small_footprint_correction:
        return large
    al = _alpha(a1, a2, sigma_um)
    return al * large + (1.0 - al) * eta_point


def rho_footprint(W_um, l_contained, a1, a2, rho_point, sigma_um=SIGMA_UM, small_footprint_correction=True):
    """Footprint scratch area density ρ_𝒫 of one segment, eq. 18: ``2 W l/A_𝒫``.

    µm inputs; ``rho_point`` = eq. 17 at the footprint centre, blended with the
    same α as eq. 16 when ``small_footprint_correction``.  Dimensionless.
    """
    large = 2.0 * W_um * l_contained / (np.pi * a1 * a2)
    if not small_footprint_correction:
        return large
    al = _alpha(a1, a2, sigma_um)
    return al * large + (1.0 - al) * rho_point


def footprint_reference(scratches: ScratchSet, center_uv, a1_uv, a2_uv, e1, sigma_um=SIGMA_UM, n_r=96, n_theta=192):
    """Numerical reference for the footprint integrals (Fig. 5): averages over the ellipse.

    Returns ``(eta_P, rho_P)``: ``(1/A_𝒫)∫_𝒫 Σ_m |η_s^{(m)}|² dx`` (µm², eq. 13 with the
    finite-segment point term) and ``(1/A_𝒫)∫_𝒫 Σ_m ρ_c^{(m)} dx`` (eq. 18 first line,
    with eq. 17 exact), by midpoint quadrature on a polar grid uniform in area
    (``n_r × n_theta`` nodes).  Single footprint; vectorised over nodes × scratches.
    """
    s = scratches.uv_scale_um
    c = _finite("center_uv", center_uv).reshape(2) * s
    a1, a2 = float(a1_uv) * s, float(a2_uv) * s
    e1 = _finite("e1", e1).reshape(2)
    e1 = e1 / np.linalg.norm(e1)
    e2 = np.array([-e1[1], e1[0]])
    r = np.sqrt((np.arange(n_r) + 0.5) / n_r)
    th = (np.arange(n_theta) + 0.5) * 2 * np.pi / n_theta
    R, T = np.meshgrid(r, th, indexing="ij")
    x = c + (a1 * R * np.cos(T)).reshape(-1, 1) * e1 + (a2 * R * np.sin(T)).reshape(-1, 1) * e2     # (Q, 2)
    s_b, s1, s2 = scratch_coords(x[:, None, :], scratches.p0[None] * s, scratches.p1[None] * s)
    eta = eta_s_sq(s_b, sigma_um, s1, s2).sum(axis=1).mean()
    rho = area_density_point(scratches.width_um[None], s_b, s1, s2, sigma_um).sum(axis=1).mean()
    return eta, rho


# ----------------------------------------------------------------------------- lights, footprints
@dataclass(frozen=True)
class SphereLight:
    """Spherical light: ``center`` (3,) and ``radius`` in surface units, local frame (z = normal)."""

    center: np.ndarray
    radius: float


@dataclass(frozen=True)
class PolygonLight:
    """Convex planar polygon light, ``vertices`` (N, 3) in surface units, local frame,
    counter-clockwise seen from the emitting side (one-sided unless ``two_sided``)."""

    vertices: np.ndarray
    two_sided: bool = False


@dataclass(frozen=True)
class Footprint:
    """Pixel footprint ellipses: semi-axes ``a1`` along unit ``e1`` (P, 2) and ``a2`` (P,), UV units."""

    a1: np.ndarray
    a2: np.ndarray
    e1: np.ndarray


@dataclass(frozen=True)
class EvalResult:
    """Output of ``evaluate``.

    scratch : (P, C) outgoing radiance of the scratch term toward ω_o for a light of
        unit radiance, i.e. ∫_light f_r,scratch cosθ_i dω_i (dimensionless; C = 3 in
        'rgb' mode, C = L wavelengths in 'spectral' mode), times the overlap factor N(E)/E of
        the "energy" blend (1 unless E > ``energy.KNEE``).
    rho : (P,) eq. 17/18's scratch area density (the "paper" blend), in [0, 1].
    rgb : (P, 3) scratch term as linear Rec.709 RGB (spectral mode: via ``precompute.iridescence.cie``).
    total : (P, C) ``weight·base + scratch`` when a base was given, else None.
    wavelengths_um : (C,) wavelengths the channels were evaluated at.
    weight : (P, C) the base's weight: 1 − N(E) ("energy"), 1 − ρ ("paper") or 1 ("none").
    energy : (P, C) E = Σ_m |𝒟_m|²ρ̃_m F_m, the energy the scratches take from the base at this view
        before the overlap normalisation (``precompute.iridescence.energy``).
    """

    scratch: np.ndarray
    rho: np.ndarray
    rgb: np.ndarray
    total: np.ndarray | None
    wavelengths_um: np.ndarray
    weight: np.ndarray = None
    energy: np.ndarray = None


def _wavelengths(mode, wavelengths_um):
    if mode == "rgb":
        lam = RGB_WAVELENGTHS_UM if wavelengths_um is None else _finite("wavelengths_um", wavelengths_um).reshape(-1)
        if lam.shape != (3,):
            raise ValueError("wavelengths_um must have 3 entries (R, G, B) in 'rgb' mode")
    elif mode == "spectral":
        lam = cie.visible_wavelengths(32) if wavelengths_um is None else _finite("wavelengths_um", wavelengths_um).reshape(-1)
        if lam.size < 2 or np.any(np.diff(lam) <= 0):
            raise ValueError("wavelengths_um must be strictly increasing with >= 2 entries in 'spectral' mode")
    else:
        raise ValueError(f"mode must be 'rgb' or 'spectral' (got {mode!r})")
    if np.any(lam < 0.2) or np.any(lam > 2.0):
        raise ValueError("wavelengths_um must lie in [0.2, 2.0] micrometres")
    return lam


def _check_points(uv, wo):
    uv = _finite("uv", uv).reshape(-1, 2)
    wo = _finite("wo", wo).reshape(-1, 3)
    if wo.shape[0] != uv.shape[0]:
        raise ValueError(f"wo must have one direction per point ({uv.shape[0]}), got {wo.shape[0]}")
    n = np.linalg.norm(wo, axis=1)
    if np.any(n < 1e-12):
        raise ValueError("wo must be non-zero")
    wo = wo / n[:, None]
    if np.any(wo[:, 2] < 0.0):
        raise ValueError("wo must lie in the upper hemisphere (wo_z in [0, 1])")
    return uv, wo


def _pair_geometry(scratches, uv, pi, sid, sigma_um):
    s = scratches.uv_scale_um
    x = uv[pi] * s
    s_b, s1, s2 = scratch_coords(x, scratches.p0[sid] * s, scratches.p1[sid] * s)
    return s_b, s1, s2


def _light_factor(light, x3, wo_p, phi, W, lam, sigma_um, si_mode, n_band=1):
    """Angular factor A per (pair, λ) for pairs at surface positions x3 (K, 3)."""
    if isinstance(light, SphereLight):
        p_hat, ca = sphere_cone(_finite("light.center", light.center)[None] - x3, light.radius)
        ok = p_hat[:, 2] > -np.sqrt(1.0 - ca ** 2)                 # sphere entirely below horizon → skip (§3.4.1)
        A = sphere_light_integral(wo_p[:, None], p_hat[:, None], ca[:, None], phi[:, None], W[:, None], lam[None],
                                  sigma_um, si_mode, n_band=n_band)
        return np.where(ok[:, None], A, 0.0)
    if isinstance(light, PolygonLight):
        V = _finite("light.vertices", light.vertices)[None] - x3[:, None, :]      # (K, N, 3)
        return polygon_light_integral(wo_p[:, None], V[:, None], phi[:, None], W[:, None], lam[None], sigma_um,
                                      si_mode, two_sided=light.two_sided, n_band=n_band)
    raise ValueError("light must be a SphereLight or PolygonLight")


def pair_energy(eta_um2, W_um, D_um, phi, wo, lam_um, sigma_um=SIGMA_UM, exact: bool = False) -> np.ndarray:
    """|𝒟|²ρ̃F of scratch–point pairs: the energy each scratch takes from the base (per λ).

    ``eta_um2`` (K,) |η_s|² (point or footprint, µm²), ``W_um``, ``D_um``, ``phi`` (K,) width, depth
    (µm) and orientation (radians), ``wo`` (K, 3) local view directions, ``lam_um`` (L,) → (K, L).
    Eqs. 3, 9-11 integrated over ξ (``energy.coverage``), times the share above the horizon
    (``energy.propagating_fraction``, ``exact`` as there).
    """
    W = np.asarray(W_um, float)[:, None]
    c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
    wo_t = wo[:, 0:1] * c + wo[:, 1:2] * s
    wo_b = -wo[:, 0:1] * s + wo[:, 1:2] * c
    lam = np.asarray(lam_um, float)[None]
    F = _energy.propagating_fraction(wo_t, wo_b, W, lam, exact)
    return _energy.coverage(np.asarray(eta_um2)[:, None], W, sigma_um) * depth_term(np.asarray(D_um)[:, None], lam) * F


def evaluate(scratches: ScratchSet, uv, wo, light, *, grid: ScratchGrid | None = None, footprint: Footprint | None = None,
             mode: str = "rgb", wavelengths_um=None, sigma_um: float = SIGMA_UM, si_mode: str = "exact",
             small_footprint_correction: bool = True, n_band: int = 1, base=None, blend: str = "energy",
             exact_fraction: bool = False) -> EvalResult:
    """Scratch-layer response at shading points under an area light (eqs. 6, 7, 10-18, 27-41).

    Parameters
    ----------
    scratches : ScratchSet (UV segments, W, D in µm, uv_scale_um).
    uv : (P, 2) shading points in UV (surface units); the point is (u, v, 0).
    wo : (P, 3) view directions, local frame, upper hemisphere.
    light : SphereLight or PolygonLight (surface units, local frame), unit radiance.
    grid : spatial index (built on the fly if None); each point only visits
        segments within (footprint a₁ +) 3σ.
    footprint : pixel footprint ellipses (UV units) → eqs. 14-18; None → point
        evaluation (eqs. 10, 17).
    mode : 'rgb' (model at ``RGB_WAVELENGTHS_UM``) or 'spectral' (``wavelengths_um``,
        default 32 bins over 0.38-0.78 µm, converted with CIE CMFs).
    sigma_um : coherence radius σ (µm).  si_mode : 'exact' or 'approx' (eq. 29).
    n_band : ξ₁ cuts through the light (1 = the paper's eq. 27; see ``band_nodes``).
    base : optional (P, C) or (P,) base-layer radiance under the same light, blended
        as weight·base + scratch.
    blend : the base's weight: "energy" (default; 1 − N(E), module docstring), "paper" (eq. 6's
        1 − ρ) or "none" (1).
    exact_fraction : the propagating fraction F of the energy with the exact sinc² tail instead of
        the shader's rational fit (``energy.tail_fraction``).

    Returns ``EvalResult`` (see its docstring): the scratch radiance per unit light
    radiance ``Σ_m |𝒲|²|𝒟|²|η_{s|𝒫}|² A_m/(A_C λ²)`` where A_m is the closed-form
    angular factor of ``sphere_light_integral`` / ``polygon_light_integral``.
    """
    if not isinstance(scratches, ScratchSet):
        raise ValueError("scratches must be a ScratchSet")
    if blend not in BLENDS:
        raise ValueError(f"blend must be one of {', '.join(BLENDS)} (got {blend!r})")
    uv, wo = _check_points(uv, wo)
    sigma_um = float(_positive("sigma_um", sigma_um, 1e5))
    lam = _wavelengths(mode, wavelengths_um)
    P, L = uv.shape[0], lam.size
    s = scratches.uv_scale_um
    if footprint is not None:
        a1 = np.broadcast_to(_positive("footprint.a1", footprint.a1, 1e12), (P,)) * s
        a2 = np.broadcast_to(_positive("footprint.a2", footprint.a2, 1e12), (P,)) * s
        e1 = np.broadcast_to(_finite("footprint.e1", footprint.e1), (P, 2))
        en = np.linalg.norm(e1, axis=1)
        if np.any(en < 1e-12):
            raise ValueError("footprint.e1 must be non-zero")
        e1 = e1 / en[:, None]
        radius_um = np.maximum(a1, a2) + 3.0 * sigma_um
    else:
        radius_um = np.full(P, 3.0 * sigma_um)
    if grid is None:
        grid = build_grid(scratches)
    offsets, sid = grid.query(scratches, uv, radius_um / s)
    pi = np.repeat(np.arange(P), np.diff(offsets))
    s_b, s1, s2 = _pair_geometry(scratches, uv, pi, sid, sigma_um)
    W = scratches.width_um[sid]
    eta_pt = eta_s_sq(s_b, sigma_um, s1, s2)
    rho_pt = area_density_point(W, s_b, s1, s2, sigma_um)
    if footprint is not None:
        l_in = contained_length(scratches.p0[sid] * s, scratches.p1[sid] * s, uv[pi] * s, a1[pi], a2[pi], e1[pi])
        eta = eta_footprint(l_in, a1[pi], a2[pi], eta_pt, sigma_um, small_footprint_correction)
        rho_pair = rho_footprint(W, l_in, a1[pi], a2[pi], rho_pt, sigma_um, small_footprint_correction)
    else:
        eta, rho_pair = eta_pt, rho_pt
    x3 = np.concatenate([uv[pi], np.zeros((pi.size, 1))], axis=1)
    A = _light_factor(light, x3, wo[pi], scratches.phi[sid], W, lam, sigma_um, si_mode, n_band) if pi.size else np.zeros((0, L))
    A_C = np.pi * sigma_um ** 2
    D = scratches.depth_um[sid]
    contrib = (W ** 2)[:, None] * depth_term(D[:, None], lam[None]) * eta[:, None] * A \
        / (A_C * lam[None] ** 2)
    scratch = np.zeros((P, L))
    np.add.at(scratch, pi, contrib)
    rho = np.clip(np.bincount(pi, weights=rho_pair, minlength=P), 0.0, 1.0)
    E = np.zeros((P, L))
    if pi.size:
        np.add.at(E, pi, pair_energy(eta, W, D, scratches.phi[sid], wo[pi], lam, sigma_um, exact_fraction))
    if blend == "energy":
        N, factor = _energy.normalise(E)
        weight, scratch = 1.0 - N, scratch * factor
    else:
        weight = np.broadcast_to((1.0 - rho)[:, None] if blend == "paper" else np.ones((P, 1)), (P, L)).copy()
    rgb = scratch if mode == "rgb" else cie.spectrum_to_rgb(scratch, lam)
    total = None
    if base is not None:
        b = _finite("base", base)
        b = b[:, None] if b.ndim == 1 else b
        if b.shape not in ((P, L), (P, 1)):
            raise ValueError(f"base must have shape (P,), (P, 1) or (P, {L}) (got {b.shape})")
        total = weight * b + scratch
    return EvalResult(scratch, rho, rgb, total, lam, weight, E)


# ----------------------------------------------------------------------------- point BRDF and MC reference
def scratch_brdf(scratches: ScratchSet, uv, wi, wo, lam_um, *, sigma_um: float = SIGMA_UM,
                 phase: str = "normal") -> np.ndarray:
    """Scratch term of the SVBRDF f_r (1/sr), eqs. 1, 6, 7, 9-11 — brute force over all segments.

    ``phase``: "normal" = eq. 4's |𝒟|² (the paper, the shaders); "angle" = the angle-dependent phase
    per (ω_i, ω_o) (``depth_term_angle``; numpy only: its energy over the lobe has no closed form, so
    the layer's base weight cannot follow it exactly; bench/iridescence_wave.py); "view" = that phase
    at the lobe centre only (D → D ω_o,z; closed-form energy, but off at grazing views and for deep
    scratches — the bench's "view phase" column — so the shaders do not offer it).

    ``uv`` (P, 2), ``wi``/``wo`` (P, 3) local unit directions, ``lam_um`` (L,) → (P, L).
    Point evaluation (finite-segment |η_s|² as in ``eta_s_sq``); for testing and
    Monte Carlo references, O(P·M).
    """
    uv, wo = _check_points(uv, wo)
    wi = _finite("wi", wi).reshape(-1, 3)
    wi = wi / np.linalg.norm(wi, axis=1, keepdims=True)
    lam = _finite("lam_um", lam_um).reshape(-1)
    s = scratches.uv_scale_um
    s_b, s1, s2 = scratch_coords(uv[:, None] * s, scratches.p0[None] * s, scratches.p1[None] * s)   # (P, M)
    phi = scratches.phi
    t = np.stack([np.cos(phi), np.sin(phi)], axis=-1)
    b = np.stack([-np.sin(phi), np.cos(phi)], axis=-1)
    h = (wi + wo)[:, :2]
    xi1 = h @ t.T
    xi2 = h @ b.T
    A_C = np.pi * sigma_um ** 2
    k = 2 * np.pi / lam
    Wm = scratches.width_um
    if phase == "normal":
        dt = depth_term(scratches.depth_um[None, :, None], lam)
    elif phase == "angle":
        dt = depth_term_angle(scratches.depth_um[None, :, None], lam, (wi[:, 2] + wo[:, 2])[:, None, None])
    elif phase == "view":
        dt = depth_term(scratches.depth_um[None, :, None] * wo[:, 2, None, None], lam)
    else:
        raise ValueError(f"phase must be 'normal', 'view' or 'angle' (got {phase!r})")
    f = (width_term(Wm[None, :, None], xi2[..., None], lam) * dt
         * eta_s_sq(s_b, sigma_um, s1, s2)[..., None] * np.exp(-(sigma_um * k * xi1[..., None]) ** 2))
    return np.where(wi[:, 2:3] > 0.0, f.sum(axis=1) / (A_C * lam ** 2), 0.0)


def evaluate_mc(scratches: ScratchSet, uv, wo, light: SphereLight, lam_um, *, sigma_um: float = SIGMA_UM,
                n_samples: int = 1 << 14, seed: int = 0) -> np.ndarray:
    """Monte Carlo ∫_light f_r,scratch cosθ_i dω_i (point evaluation) by uniform cone sampling.

    Independent reference for ``evaluate(..., footprint=None)`` with a SphereLight:
    same quantity, computed from ``scratch_brdf`` (brute force over all segments,
    seeded scrambled Sobol points).  Returns (P, L).  Memory O(P·n_samples·M·L):
    test-sized inputs only.
    """
    from scipy.stats import qmc as _qmc

    from .lights import _onb

    uv, wo = _check_points(uv, wo)
    lam = _finite("lam_um", lam_um).reshape(-1)
    P = uv.shape[0]
    u = _qmc.Sobol(d=2, scramble=True, seed=seed).random(n_samples)
    x3 = np.concatenate([uv, np.zeros((P, 1))], axis=1)
    p_hat, ca = sphere_cone(_finite("light.center", light.center)[None] - x3, light.radius)   # (P, 3), (P,)
    cos_t = 1.0 - u[None, :, 0] * (1.0 - ca[:, None])                                         # (P, S)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
    e1, e2 = _onb(p_hat)
    ang = 2 * np.pi * u[None, :, 1]
    wi = cos_t[..., None] * p_hat[:, None] + (sin_t * np.cos(ang))[..., None] * e1[:, None] \
        + (sin_t * np.sin(ang))[..., None] * e2[:, None]
    f = scratch_brdf(scratches, np.repeat(uv, n_samples, 0), wi.reshape(-1, 3), np.repeat(wo, n_samples, 0), lam,
                     sigma_um=sigma_um).reshape(P, n_samples, lam.size)
    return (2 * np.pi * (1 - ca))[:, None] * np.mean(f * np.maximum(wi[..., 2:3], 0.0), axis=1)
