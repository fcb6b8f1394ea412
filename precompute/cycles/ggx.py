"""Numpy twin of the Cycles (Blender 5.0) GGX reflection closure, and its tilted-lobe cone collapse.

What Cycles does for OSL ``microfacet("ggx", N, T, ax, ay, eta, 0)``
--------------------------------------------------------------------
Read from ``intern/cycles`` (Blender 4.2 ... 5.0 kernels):

- ``kernel/osl/closures_setup.h`` ``osl_closure_microfacet_setup``: ``refract == 0`` and a
  distribution that is neither "beckmann" nor "ashikhmin_shirley" calls
  ``bsdf_microfacet_ggx_setup``: ``alpha_x, alpha_y`` are clamped to [0, 1] (``saturatef``),
  ``fresnel_type = NONE`` (reflectance 1: **no Fresnel**, ``eta`` is unused for reflection),
  ``energy_scale = 1`` (no multiple-scattering compensation; only "multi_ggx" has it).
  The closure normal is ``maybe_ensure_valid_specular_reflection(sd, normalize(N))``.
- ``kernel/closure/bsdf_util.h`` ``maybe_ensure_valid_specular_reflection``: only when the
  material has ``use_bump_map_correction`` (``SD_USE_BUMP_MAP_CORRECTION``) and N != Ng, it calls
  ``ensure_valid_specular_reflection(Ng, wi, N)``, which rotates N toward Ng (inside the N-Ng plane)
  until the mirror direction of the view is ``min(0.9 Iz, 0.01)`` above the horizon.
  With the option off (our scratch materials) the tilted normal is used as is.
- ``kernel/closure/bsdf_microfacet.h`` ``bsdf_microfacet_eval<GGX>`` (wi = towards the viewer,
  wo = towards the light, Cycles naming): zero unless ``cos_NI = N.wi > 0``, ``ax*ay >
  BSDF_ROUGHNESS_SQ_THRESH`` (2e-10, ``kernel/svm/types.h``; else the closure is singular: no
  ``SD_BSDF_HAS_EVAL``, no light sampling, mirror sampling only) and ``N.wo >= 0`` (``N.wo < 0``
  is "transmission", rejected for a reflection closure).  Frame ``make_orthonormals_tangent(N, T)``:
  ``Y = normalize(N x T)``, ``X = Y x N``.  ``D = bsdf_aniso_D`` (anisotropic GGX),
  ``Lambda = bsdf_aniso_lambda`` (Heitz 2014 eq. 72), **height-correlated** Smith
  ``G2 = 1 / (1 + Lambda_I + Lambda_O)``, and::

      eval = D * G2 / (4 cos_NI)         (= f * cos(light), what the integrator multiplies by)
      pdf  = D / (4 cos_NI (1 + Lambda_I))   (VNDF pdf, Heitz 2018)

  The eval function does **not** test Ng; ``bsdf_microfacet_sample`` rejects a sampled
  direction with ``Ng.wo < 0`` or ``N.wo < 0`` (returns ``LABEL_NONE``: that energy is lost).
- ``kernel/closure/bsdf.h`` ``bsdf_eval`` multiplies by ``bump_shadowing_term(sd, sc, wo, true)``,
  which is 0 when ``(Ns.wo)(Ns.N)(N.wo) < 0`` (Ns = smooth normal = Ng on a flat plane), i.e. a light
  below the surface is rejected in evaluation too; for glossy closures it is 1 otherwise (the Conty
  softening only applies to diffuse closures).  In ``bsdf_sample`` that term is applied with
  ``is_eval=false`` and is 1 for glossy closures, so sampling and evaluation agree: both drop
  light directions below Ng.  Together with Smith G this is the "lobe albedo loss".

Conventions here: the scratch frame (u, v, n) is the world (x, y, z) frame, n the flat surface
normal (= Ng = smooth normal), u the scratch direction, v = n x u.  Paper angles (Raymond et al.
2016 §4.1): omega = (sin theta, cos theta sin phi, cos theta cos phi).  ``omega_o`` is the view
direction (Cycles ``wi``), ``omega_i`` the light direction (Cycles ``wo``).  A *tilted lobe* has
closure normal N' = cos(t) n + sin(t) v and tangent T = u; all angles are in radians.
"""
from __future__ import annotations

import numpy as np

from scipy.special import erf

from . import beckmann as _bk

__all__ = [
    "GGX",
    "BECKMANN",
    "dist_code",
    "BSDF_ROUGHNESS_SQ_THRESH",
    "direction",
    "angles",
    "tilted_normal",
    "make_orthonormals_tangent",
    "ggx_aniso_D",
    "ggx_aniso_lambda",
    "ensure_valid_specular_reflection",
    "bsdf_eval",
    "bsdf_sample",
    "tilted_lobe_eval",
    "effective_tilt",
    "cone_collapse",
    "cone_collapse_binned",
    "cone_collapse_binned_jittered",
    "JitteredAtoms",
    "JITTER_MIN",
    "albedo",
]

#: ``kernel/svm/types.h``: a microfacet closure with alpha_x*alpha_y <= this is singular (no eval).
BSDF_ROUGHNESS_SQ_THRESH = 2e-10

#: distribution codes (``dist`` arrays of the lobe fit): OSL ``microfacet("ggx", ...)`` / ``("beckmann", ...)``
GGX = 0
BECKMANN = 1
_DIST_NAMES = {"ggx": GGX, "beckmann": BECKMANN}

_Z = np.array([0.0, 0.0, 1.0])
_U = np.array([1.0, 0.0, 0.0])


# ----------------------------------------------------------------------------- small vector helpers
def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _normalize(a):
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def _check_alpha(name, a):
    a = np.asarray(a, dtype=float)
    if not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ValueError(f"{name} must be finite and >= 0 (Cycles clamps it to [0, 1]); got {a!r}")
    return a


def dist_code(dist):
    """Distribution code(s): "ggx" -> 0 (:data:`GGX`), "beckmann" -> 1 (:data:`BECKMANN`); int arrays pass through."""
    if isinstance(dist, str):
        if dist.lower() not in _DIST_NAMES:
            raise ValueError(f"dist must be 'ggx' or 'beckmann' (or codes 0/1); got {dist!r}")
        return np.array(_DIST_NAMES[dist.lower()])
    d = np.asarray(dist)
    if d.dtype.kind not in "iub" or not np.all((d == GGX) | (d == BECKMANN)):
        raise ValueError(f"dist must be 'ggx' or 'beckmann' or an integer array of codes 0 (GGX) / 1 (Beckmann); got {dist!r}")
    return d.astype(np.int8)


def _D(code, ax, ay, local_H):
    if np.all(code == GGX):
        return ggx_aniso_D(ax, ay, local_H)
    if np.all(code == BECKMANN):
        return _bk.beckmann_aniso_D(ax, ay, local_H)
    return np.where(code == BECKMANN, _bk.beckmann_aniso_D(ax, ay, local_H), ggx_aniso_D(ax, ay, local_H))


def _lambda_from_s(code, s):
    """Cycles ``bsdf_lambda_from_sqr_alpha_tan_n<GGX|BECKMANN>`` of s = ((ax Vx)^2 + (ay Vy)^2) / Vz^2."""
    ggx = lambda: 0.5 * (np.sqrt(1.0 + s) - 1.0)  # noqa: E731
    if np.all(code == GGX):
        return ggx()
    if np.all(code == BECKMANN):
        return _bk.beckmann_lambda_from_sqr_alpha_tan_n(s)
    return np.where(code == BECKMANN, _bk.beckmann_lambda_from_sqr_alpha_tan_n(s), ggx())


def _lambda(code, ax, ay, local_V):
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((ax * local_V[..., 0]) ** 2 + (ay * local_V[..., 1]) ** 2) / local_V[..., 2] ** 2
    return _lambda_from_s(code, s)


def direction(theta, phi):
    """Unit vector of paper angles (theta, phi) (Raymond et al. 2016 §4.1), radians, frame (u, v, n)."""
    theta = np.asarray(theta, dtype=float)
    phi = np.asarray(phi, dtype=float)
    c = np.cos(theta)
    return np.stack(np.broadcast_arrays(np.sin(theta), c * np.sin(phi), c * np.cos(phi)), axis=-1)


def angles(omega):
    """Inverse of :func:`direction`: (theta, phi) = (asin(w.u), atan2(w.v, w.n)) in radians (§4.1)."""
    omega = np.asarray(omega, dtype=float)
    return np.arcsin(np.clip(omega[..., 0], -1.0, 1.0)), np.arctan2(omega[..., 1], omega[..., 2])


def tilted_normal(tilt):
    """Closure normal N' = cos(t) n + sin(t) v of a lobe tilted by ``tilt`` (radians) inside the n-v plane."""
    tilt = np.asarray(tilt, dtype=float)
    return np.stack(np.broadcast_arrays(np.zeros_like(tilt), np.sin(tilt), np.cos(tilt)), axis=-1)


def make_orthonormals_tangent(N, T):
    """Cycles ``make_orthonormals_tangent``: Y = normalize(N x T), X = Y x N (``util/math`` / ``mapping.h``)."""
    Y = _normalize(np.cross(N, T))
    X = np.cross(Y, N)
    return X, Y


def ggx_aniso_D(alpha_x, alpha_y, local_H):
    """Cycles ``bsdf_aniso_D<GGX>``: 1 / (pi ax ay |H/(ax, ay, 1)|^4), H in the closure frame (per steradian)."""
    Hs = local_H / np.stack(np.broadcast_arrays(alpha_x, alpha_y, 1.0), axis=-1)
    return 1.0 / (np.pi * alpha_x * alpha_y * _dot(Hs, Hs) ** 2)


def ggx_aniso_lambda(alpha_x, alpha_y, local_V):
    """Cycles ``bsdf_aniso_lambda<GGX>`` (Heitz 2014, eq. 72): 0.5 (sqrt(1 + (ax^2 Vx^2 + ay^2 Vy^2)/Vz^2) - 1)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((alpha_x * local_V[..., 0]) ** 2 + (alpha_y * local_V[..., 1]) ** 2) / local_V[..., 2] ** 2
    return 0.5 * (np.sqrt(1.0 + s) - 1.0)


def ensure_valid_specular_reflection(Ng, I, N):
    """Cycles ``ensure_valid_specular_reflection(Ng, I, N)`` (``kernel/closure/bsdf_util.h``).

    Raises the shading normal N toward Ng (inside the N-Ng plane) just enough that the mirror
    reflection of the view direction I lies ``min(0.9 I.Ng, 0.01)`` above the surface.  This is what
    the material option ``use_bump_map_correction`` does to every glossy closure normal.
    """
    Ng, I, N = np.broadcast_arrays(np.asarray(Ng, float), np.asarray(I, float), np.asarray(N, float))
    R = 2.0 * _dot(N, I)[..., None] * N - I
    Iz = _dot(I, Ng)
    threshold = np.minimum(0.9 * Iz, 0.01)
    ok = _dot(Ng, R) >= threshold
    Xr = N - _dot(N, Ng)[..., None] * Ng
    nrm = np.linalg.norm(Xr, axis=-1, keepdims=True)
    X = np.where(nrm > 0, Xr / np.where(nrm > 0, nrm, 1.0), N)
    Ix = _dot(I, X)
    a = Ix**2 + Iz**2
    b = 2.0 * (a + Iz * threshold)
    c = (threshold + Iz) ** 2
    disc = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        Nz2 = np.where(Ix < 0, 0.25 * (b + disc) / a, 0.25 * (b - disc) / a)
    Nz2 = np.nan_to_num(Nz2, nan=1.0)
    Nx = np.sqrt(np.maximum(1.0 - Nz2, 0.0))
    Nz = np.sqrt(np.maximum(Nz2, 0.0))
    Nnew = Nx[..., None] * X + Nz[..., None] * Ng
    return np.where(ok[..., None], N, Nnew)


# ----------------------------------------------------------------------------- eval / sample
def _closure_normal(N, Ng, wi, bump_map_correction):
    N = _normalize(np.asarray(N, dtype=float))
    if bump_map_correction:
        same = np.all(N == Ng, axis=-1, keepdims=True)
        N = np.where(same, N, ensure_valid_specular_reflection(Ng, wi, N))
    return N


def bsdf_eval(N, T, alpha_x, alpha_y, wi, wo, Ng=_Z, bump_map_correction=False, dist="ggx"):
    """What Cycles' ``bsdf_eval`` returns for one OSL ``microfacet(dist, N, T, ax, ay, eta, 0)`` closure.

    Mirrors ``bsdf_eval`` (``kernel/closure/bsdf.h``: ``bump_shadowing_term(..., is_eval=true)``) and
    ``bsdf_microfacet_eval<GGX>`` (``kernel/closure/bsdf_microfacet.h``), closure weight 1.

    Parameters are broadcastable arrays of 3-vectors (``N`` closure normal, ``T`` tangent, ``wi``
    towards the viewer, ``wo`` towards the light, ``Ng`` the geometric = smooth normal) and
    roughnesses ``alpha_x`` (along T), ``alpha_y`` (dimensionless, clamped to [0, 1] like
    ``bsdf_microfacet_ggx_setup`` / ``..._beckmann_setup``).  ``dist``: "ggx" or "beckmann" (or
    codes 0/1, broadcastable; Beckmann D and Cycles' approximate Beckmann Lambda from
    :mod:`precompute.cycles.beckmann`).  Returns ``(eval, pdf)``: eval = D G2 / (4 N.wi) = f cos(light)
    (per steradian of ``wo``) and the VNDF pdf D / (4 N.wi (1 + Lambda(wi))).
    """
    code = dist_code(dist)
    ax = np.minimum(_check_alpha("alpha_x", alpha_x), 1.0)
    ay = np.minimum(_check_alpha("alpha_y", alpha_y), 1.0)
    Ng = np.asarray(Ng, dtype=float)
    wi = np.asarray(wi, dtype=float)
    wo = np.asarray(wo, dtype=float)
    N = _closure_normal(N, Ng, wi, bump_map_correction)
    T = np.asarray(T, dtype=float)

    cos_NI = _dot(N, wi)
    cos_NO = _dot(N, wo)
    # bump_shadowing_term(sd, sc, wo, is_eval=true): (Ns.wo)(Ns.N)(N.wo) < 0 -> 0.
    shadow_ok = ~((_dot(Ng, wo) * _dot(Ng, N) * cos_NO) < 0.0) | np.all(N == Ng, axis=-1)
    valid = (cos_NI > 0) & (ax * ay > BSDF_ROUGHNESS_SQ_THRESH) & (cos_NO >= 0.0) & shadow_ok

    H = _normalize(wi + wo)
    X, Y = make_orthonormals_tangent(N, T)
    loc = lambda V: np.stack(np.broadcast_arrays(_dot(X, V), _dot(Y, V), _dot(N, V)), axis=-1)  # noqa: E731
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        axs = np.where(valid, ax, 1.0)
        ays = np.where(valid, ay, 1.0)
        D = _D(code, axs, ays, loc(H))
        lam_I = _lambda(code, axs, ays, loc(wi))
        lam_O = _lambda(code, axs, ays, loc(wo))
        common = D / cos_NI * 0.25
        ev = common / (1.0 + lam_I + lam_O)
        pdf = common / (1.0 + lam_I)
    ev = np.where(valid, np.nan_to_num(ev, nan=0.0, posinf=0.0), 0.0)
    pdf = np.where(valid, np.nan_to_num(pdf, nan=0.0, posinf=0.0), 0.0)
    return ev, pdf


def _sample_vndf(local_wi, ax, ay, u1, u2):
    """Cycles ``microfacet_ggx_sample_vndf`` (Heitz 2018, JCGT 7(4)); polar disk mapping (same density)."""
    wi_ = _normalize(np.stack([ax * local_wi[..., 0], ay * local_wi[..., 1], local_wi[..., 2]], axis=-1))
    lensq = wi_[..., 0] ** 2 + wi_[..., 1] ** 2
    big = lensq > 1e-7
    inv = np.where(big, 1.0 / np.sqrt(np.where(big, lensq, 1.0)), 0.0)
    T1 = np.where(big[..., None], np.stack([-wi_[..., 1] * inv, wi_[..., 0] * inv, 0 * inv], -1),
                  np.array([1.0, 0.0, 0.0]))
    T2 = np.where(big[..., None], np.cross(wi_, T1), np.array([0.0, 1.0, 0.0]))
    r = np.sqrt(u1)
    tx, ty = r * np.cos(2 * np.pi * u2), r * np.sin(2 * np.pi * u2)
    s = 0.5 * (1.0 + wi_[..., 2])
    ty = np.sqrt(np.maximum(1.0 - tx**2, 0.0)) * (1.0 - s) + ty * s
    tz = np.sqrt(np.maximum(1.0 - tx**2 - ty**2, 0.0))
    H_ = tx[..., None] * T1 + ty[..., None] * T2 + tz[..., None] * wi_
    return _normalize(np.stack([ax * H_[..., 0], ay * H_[..., 1], np.maximum(0.0, H_[..., 2])], axis=-1))


def bsdf_sample(N, T, alpha_x, alpha_y, wi, u1, u2, Ng=_Z, bump_map_correction=False):
    """Cycles ``bsdf_microfacet_sample<GGX>`` for a reflection-only GGX closure (no Fresnel).

    ``u1, u2`` in [0, 1) (arrays).  Returns ``(wo, eval, pdf)``; rejected samples (``Ng.wo < 0`` or
    ``N.wo < 0``: ``LABEL_NONE`` in Cycles) have eval = pdf = 0.  ``eval / pdf = G2 / G1(wi)``.
    Singular closures (ax*ay <= 2e-10) are not modelled (``ValueError``).
    """
    ax = np.minimum(_check_alpha("alpha_x", alpha_x), 1.0)
    ay = np.minimum(_check_alpha("alpha_y", alpha_y), 1.0)
    if np.any(ax * ay <= BSDF_ROUGHNESS_SQ_THRESH):
        raise ValueError("alpha_x*alpha_y must be > 2e-10 (Cycles treats smaller lobes as singular mirrors)")
    Ng = np.asarray(Ng, dtype=float)
    wi = np.asarray(wi, dtype=float)
    N = _closure_normal(N, Ng, wi, bump_map_correction)
    X, Y = make_orthonormals_tangent(N, np.asarray(T, dtype=float))
    cos_NI = _dot(N, wi)
    local_I = np.stack(np.broadcast_arrays(_dot(X, wi), _dot(Y, wi), cos_NI), axis=-1)
    u1, u2 = np.broadcast_arrays(np.asarray(u1, float), np.asarray(u2, float))
    local_I = np.broadcast_to(local_I, u1.shape + (3,))
    local_H = _sample_vndf(local_I, ax, ay, u1, u2)
    X, Y, N3 = (np.broadcast_to(a, u1.shape + (3,)) for a in (X, Y, N))
    H = local_H[..., :1] * X + local_H[..., 1:2] * Y + local_H[..., 2:] * N3
    cos_HI = _dot(H, np.broadcast_to(wi, H.shape))
    wo = 2.0 * cos_HI[..., None] * H - wi
    local_O = 2.0 * cos_HI[..., None] * local_H - local_I
    ok = (cos_NI > 0) & (_dot(Ng, wo) >= 0) & (_dot(N3, wo) >= 0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        D = ggx_aniso_D(ax, ay, local_H)
        lam_I = ggx_aniso_lambda(ax, ay, local_I)
        lam_O = ggx_aniso_lambda(ax, ay, local_O)
        common = D / cos_NI * 0.25
        ev = np.where(ok, common / (1.0 + lam_I + lam_O), 0.0)
        pdf = np.where(ok, common / (1.0 + lam_I), 0.0)
    return wo, np.nan_to_num(ev), np.nan_to_num(pdf)


# ----------------------------------------------------------------------------- tilted lobes on the cone
def tilted_lobe_eval(theta_o, phi_o, theta_i, phi_i, tilt, alpha_y, alpha_x=1e-3, bump_map_correction=False,
                     dist="ggx"):
    """:func:`bsdf_eval` of a tilted lobe (N' = cos t n + sin t v, T = u) in paper angles (radians).

    Returns ``(eval, pdf)`` per steradian of the light direction omega_i(theta_i, phi_i).
    """
    wi = direction(theta_o, phi_o)
    wo = direction(theta_i, phi_i)
    return bsdf_eval(tilted_normal(tilt), _U, alpha_x, alpha_y, wi, wo, _Z, bump_map_correction, dist)


def effective_tilt(tilt, theta_o, phi_o, bump_map_correction=False):
    """Tilt (radians) of the closure normal Cycles actually uses.

    Without bump-map correction it is ``tilt``; with it, ``ensure_valid_specular_reflection`` keeps
    the normal inside the n-v plane but may rotate it toward n (``kernel/closure/bsdf_util.h``).
    """
    tilt = np.asarray(tilt, dtype=float)
    if not bump_map_correction:
        return tilt
    N = ensure_valid_specular_reflection(_Z, direction(theta_o, phi_o), tilted_normal(tilt))
    return np.arctan2(N[..., 1], N[..., 2])


def _check_cone_args(alpha_x, alpha_y):
    ax = np.asarray(alpha_x, dtype=float)
    ay = np.asarray(alpha_y, dtype=float)
    if not (np.all(np.isfinite(ay)) and np.all(ay > 0) and np.all(ay <= 1.0)):
        raise ValueError("alpha_y must be in (0, 1] (Cycles clamps roughness to [0, 1])")
    if not (np.all(np.isfinite(ax)) and np.all(ax >= 0) and np.all(ax <= 1.0)):
        raise ValueError("alpha_x must be in [0, 1]")
    if np.any((ax > 0) & (ax * ay <= BSDF_ROUGHNESS_SQ_THRESH)):
        raise ValueError("alpha_x*alpha_y must be > 2e-10: smaller lobes are singular in Cycles (no eval/NEE)")
    return ax, ay


def _slope_tail(x):
    """1 - CDF(|x|) of the GGX slope marginal in units of alpha_y, in a cancellation-free form.

    The marginal p(x) = (1/2)(1 + x^2)^{-3/2} has CDF(x) = (1 + x / sqrt(1 + x^2)) / 2, so
    1 - CDF(|x|) = 1 / (2 sqrt(1 + x^2) (sqrt(1 + x^2) + |x|)).
    """
    r = np.sqrt(1.0 + x * x)
    return 0.5 / (r * (r + np.abs(x)))


def _slope_mass_and_mean(x_lo, x_hi):
    """Mass and mean of the slope marginal p(x) on [x_lo, x_hi] (x = s / alpha_y), accurate in the tails.

    Mean: int x p(x) dx = -(1/2)(1 + x^2)^{-1/2}.
    """
    t_lo, t_hi = _slope_tail(x_lo), _slope_tail(x_hi)
    mass = np.where(x_lo >= 0, t_lo - t_hi, np.where(x_hi <= 0, t_hi - t_lo, 1.0 - t_lo - t_hi))
    first = 0.5 / np.sqrt(1.0 + x_lo * x_lo) - 0.5 / np.sqrt(1.0 + x_hi * x_hi)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = np.where(mass > 1e-300, first / mass, 0.5 * (x_lo + x_hi))
    return np.maximum(mass, 0.0), np.clip(mean, x_lo, x_hi)


def _cone_smooth_factor(phi_o, phi_i, t, alpha_y, alpha_x, theta_o, code=GGX):
    """Factor F of the cone collapse g = p(s) |ds/dphi_i| F: sec(a-t) cos((phi_o-phi_i)/2) / cos(phi_o-t) G2.

    With A = phi_o - t, B = phi_i - t: a - t = (A + B)/2 and (phi_o - phi_i)/2 = (A - B)/2, so the
    ratio is computed from half-angle sines/cosines (few transcendentals on the big arrays).
    """
    A = phi_o - t
    B = phi_i - t
    cA, sA = np.cos(0.5 * A), np.sin(0.5 * A)
    cB, sB = np.cos(0.5 * B), np.sin(0.5 * B)
    co = np.cos(A)
    ci = cB * cB - sB * sB                                       # cos(phi_i - t)
    tth2 = np.tan(theta_o) ** 2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # Lambda in the closure frame: local V = (sin th, cos th sin(phi-t), cos th cos(phi-t)) (X = u).
        lam_o = _lambda_from_s(code, (alpha_y**2 * (1.0 - co * co) + alpha_x**2 * tth2) / (co * co))
        lam_i = _lambda_from_s(code, (alpha_y**2 * (1.0 - ci * ci) + alpha_x**2 * tth2) / (ci * ci))
        F = (cA * cB + sA * sB) / ((cA * cB - sA * sB) * co * (1.0 + lam_o + lam_i))
    valid = (np.cos(phi_o) > 0) & (co > 0) & (ci > 0) & (np.abs(phi_i) < 0.5 * np.pi) & np.isfinite(F)
    return np.where(valid, F, 0.0)


def cone_collapse(phi_o, phi_i, tilt, alpha_y, alpha_x=1e-3, theta_o=0.0, bump_map_correction=False, dist="ggx"):
    """Effective 1D function g(phi_i) of one tilted lobe on the reflection half-cone (radians in, 1/rad out).

    g(phi_i) = integral over theta_i of eval(omega_o, omega_i) cos(theta_i) dtheta_i, so that the
    radiance a lobe reflects from light that is smooth in theta is L_r = int g(phi_i) L_i(-theta_o,
    phi_i) dphi_i: the quantity to compare with rho(phi_o, phi_i) cos(phi_i) of eq. 5 (Raymond et
    al. 2016).  Closed form in the limit alpha_x -> 0 of the GGX D (its x-slope marginal is a delta on
    the cone theta_i = -theta_o); with s = tan(a - t), a = (phi_o + phi_i)/2::

        g = p(s) sec^2(a-t)/2 * sec(a-t) cos((phi_o-phi_i)/2) / cos(phi_o-t) * G2(omega_o, omega_i)
        p(s) = 1 / (2 ay (1 + s^2/ay^2)^{3/2})          (GGX slope marginal)
        p(s) = exp(-s^2/ay^2) / (sqrt(pi) ay)           (Beckmann, ``dist="beckmann"``)

    (derivation: d omega_i = 4 (h.omega_o) d omega_h, D d omega_h = P22 ds_x ds_y / cos theta_h,
    h.omega_o = cos theta_o cos((phi_o-phi_i)/2), N'.omega_o = cos theta_o cos(phi_o - t)).
    theta_o only enters G2 through the alpha_x term (negligible for alpha_x ~ 1e-3).  Zero where
    Cycles rejects: view below N' or n, light below N' (Smith/eval) or below n (bump_shadowing_term,
    sampling).  ``tilt`` t in radians; with ``bump_map_correction`` the corrected tilt is used.
    """
    code = dist_code(dist)
    ax, ay = _check_cone_args(alpha_x, alpha_y)
    phi_o, phi_i = np.asarray(phi_o, float), np.asarray(phi_i, float)
    t = effective_tilt(tilt, theta_o, phi_o, bump_map_correction)
    a_t = 0.5 * (phi_o + phi_i) - t
    x = np.tan(a_t) / ay
    p = np.where(code == BECKMANN, _bk.slope_pdf(x), 0.5 / (1.0 + x * x) ** 1.5) / ay
    return p * 0.5 / np.cos(a_t) ** 2 * _cone_smooth_factor(phi_o, phi_i, t, ay, ax, theta_o, code)


def cone_collapse_binned(phi_o, phi_edges, tilt, alpha_y, alpha_x=1e-3, theta_o=0.0, bump_map_correction=False,
                         dist="ggx"):
    """Bin average of :func:`cone_collapse` over phi_i bins ``[phi_edges[k], phi_edges[k+1]]`` (radians).

    The sharp factor p(s) ds is integrated exactly through its CDF (in a tail-accurate form); the
    smooth factor (Jacobian remainder, G2 and the rejection mask) is taken at the p-weighted mean
    position inside the valid part of each bin (bins next to the tilted normal's horizon, where
    G2 -> 0 inside the bin, are accurate to ~1 % of the lobe peak only).
    Accurate for any width, including lobes much narrower than a bin.  Broadcasting: ``phi_o``,
    ``tilt``, ``alpha_y`` (and ``dist``: "ggx", "beckmann" or an array of codes 0/1, the Beckmann
    bins use the erf form of the Gaussian slope CDF) broadcast against each other (shape S); output
    shape S + (nbins,).
    """
    code = dist_code(dist)
    ax, ay = _check_cone_args(alpha_x, alpha_y)
    phi_o = np.asarray(phi_o, float)
    t = np.asarray(effective_tilt(tilt, theta_o, phi_o, bump_map_correction), float)
    e = np.asarray(phi_edges, float)
    if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0):
        raise ValueError("phi_edges must be a strictly increasing 1D array of >= 2 bin edges")
    phi_o, t, ay, ax, code = (np.asarray(x)[..., None] for x in np.broadcast_arrays(phi_o, t, ay, ax, code))
    # valid light interval: above n (|phi_i| < pi/2) and above N' (|phi_i - t| < pi/2)
    ec = np.clip(e, np.maximum(-0.5 * np.pi, t - 0.5 * np.pi), np.minimum(0.5 * np.pi, t + 0.5 * np.pi))
    a_t = np.clip(0.5 * (phi_o + ec) - t, -0.5 * np.pi + 1e-12, 0.5 * np.pi - 1e-12)
    x = np.tan(a_t) / ay
    if np.all(code == GGX):
        mass, x_mean = _slope_mass_and_mean(x[..., :-1], x[..., 1:])
    elif np.all(code == BECKMANN):
        mass, x_mean = _bk.slope_mass_and_mean(x[..., :-1], x[..., 1:])
    else:
        mg, xg = _slope_mass_and_mean(x[..., :-1], x[..., 1:])
        mb, xb = _bk.slope_mass_and_mean(x[..., :-1], x[..., 1:])
        beck = code == BECKMANN
        mass, x_mean = np.where(beck, mb, mg), np.where(beck, xb, xg)
    # smooth factor at the p-weighted mean position inside the bin (exact for narrow lobes)
    phi_eval = 2.0 * (np.arctan(x_mean * ay) + t) - phi_o
    F = _cone_smooth_factor(phi_o, phi_eval, t, ay, ax, theta_o, code)
    return np.where(ec[..., 1:] > ec[..., :-1], mass * F, 0.0) / np.diff(e)


def albedo(tilt, alpha_x, alpha_y, theta_o=0.0, phi_o=0.0, n=768, bump_map_correction=False, quantity="eval",
           dist="ggx"):
    """Directional albedo of one tilted lobe: integral of :func:`bsdf_eval` over all light directions.

    Numerical integration in the closure's slope space (independent of the cone collapse): with
    slopes (s_x, s_y) = r (ax cos psi, ay sin psi) and u = r^2/(1+r^2), the GGX slope density
    P22 ds_x ds_y = du dpsi / (2 pi) is uniform, and
    int eval d omega_i = E[G2 (h.omega_o) / ((N'.omega_o)(N'.h)) * valid], with valid the Cycles
    rejections (light below N' or n).  A midpoint rule on an n x n grid of (u, psi) is used
    (error ~1/n at the rejection boundaries).  ``quantity="pdf"`` integrates the pdf instead (the
    probability that a BSDF sample is not rejected).  Angles in radians; returns a float array.
    ``dist="beckmann"``: Beckmann slopes have P22 = exp(-r^2) / (pi ax ay), uniform in u = 1 - exp(-r^2).
    """
    code = int(dist_code(dist))
    if quantity not in ("eval", "pdf"):
        raise ValueError("quantity must be 'eval' or 'pdf'")
    if not (isinstance(n, (int, np.integer)) and 8 <= n <= 8192):
        raise ValueError("n must be an integer in [8, 8192]")
    ax = np.minimum(_check_alpha("alpha_x", alpha_x), 1.0)
    ay = np.minimum(_check_alpha("alpha_y", alpha_y), 1.0)
    if np.any(ax * ay <= BSDF_ROUGHNESS_SQ_THRESH):
        raise ValueError("alpha_x*alpha_y must be > 2e-10 (Cycles treats smaller lobes as singular)")
    tilt, ax, ay, theta_o, phi_o = np.broadcast_arrays(
        np.asarray(tilt, float), ax, ay, np.asarray(theta_o, float), np.asarray(phi_o, float))
    out = np.empty(tilt.shape)
    uu = (np.arange(n) + 0.5) / n
    psi = 2 * np.pi * (np.arange(n) + 0.5) / n
    r = (np.sqrt(-np.log1p(-uu)) if code == BECKMANN else np.sqrt(uu / (1.0 - uu)))[:, None]
    for idx in np.ndindex(tilt.shape):  # loop over a few parameter sets only; the quadrature is vectorised
        wi = direction(theta_o[idx], phi_o[idx])
        N = _closure_normal(tilted_normal(tilt[idx]), _Z, wi, bump_map_correction)
        X, Y = make_orthonormals_tangent(N, _U)
        lI = np.array([wi @ X, wi @ Y, wi @ N])
        if lI[2] <= 0:
            out[idx] = 0.0
            continue
        sx = ax[idx] * r * np.cos(psi)
        sy = ay[idx] * r * np.sin(psi)
        lH = _normalize(np.stack(np.broadcast_arrays(-sx, -sy, 1.0), axis=-1))
        cos_HI = lH @ lI
        lO = 2.0 * cos_HI[..., None] * lH - lI
        wo = lO[..., :1] * X + lO[..., 1:2] * Y + lO[..., 2:] * N
        valid = (lO[..., 2] >= 0) & (wo[..., 2] >= 0) & (cos_HI > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam_I = _lambda(code, ax[idx], ay[idx], lI)
            lam_O = _lambda(code, ax[idx], ay[idx], lO)
            w = cos_HI / (lI[2] * lH[..., 2])
            f = w / (1.0 + lam_I + lam_O) if quantity == "eval" else w / (1.0 + lam_I)
        out[idx] = np.mean(np.where(valid, np.nan_to_num(f), 0.0))
    return out


# ----------------------------------------------------------------------------- jittered (box) lobes
#: jitters below this (radians) are rendered as the plain lobe (the exact jitter average would only
#: lose digits to cancellation there; the difference is O(jitter^2 / alpha_y^2) < 1e-6)
JITTER_MIN = 1e-7
#: default panel width (radians of tilt) of the jitter quadrature: the smooth factor (G2, Jacobian)
#: is taken once per panel and phi_i bin
_PANEL = 0.05


def _ggx_angle_tail_integral(w, ay):
    """T(w) = int_0^w (1 - CDF(tan(a) / ay)) da for the GGX slope angle a (radians, w in [0, pi/2]).

    1 - CDF = (1 - sin a / sqrt(1 - k^2 cos^2 a)) / 2, k^2 = 1 - ay^2, whose antiderivative is
    a / 2 + arcsin(k cos a) / (2 k), so T = w/2 + (arcsin(k cos w) - arcsin(k)) / (2 k).  With
    r = sqrt(1 - k^2 cos^2 w) = sqrt(sin^2 w + ay^2 cos^2 w) the arcsin difference is
    atan(k X / Y), X = -sin^2 w / (r + ay cos w), Y = k^2 cos w + ay r > 0 (no cancellation for
    narrow lobes, no 0/0 at ay = 1): T = w/2 + X / (2 Y) atan(z)/z, z = k X / Y.
    """
    k = np.sqrt(np.maximum((1.0 - ay) * (1.0 + ay), 0.0))
    sw, cw = np.sin(w), np.cos(w)
    r = np.sqrt(sw * sw + (ay * cw) ** 2)
    X = -sw * sw / (r + ay * cw)
    Y = k * k * cw + ay * r
    z = k * X / Y
    small = np.abs(z) < 1e-8
    atanc = np.where(small, 1.0, np.arctan(z) / np.where(small, 1.0, z))
    return 0.5 * w + 0.5 * X / Y * atanc


def _angle_cdf_integral(code, a, ay):
    """Q(a) = int_0^a P(a') da', P the CDF of the slope angle a' = atan(alpha_y x) (P = 0 / 1 beyond -/+ pi/2).

    By the symmetry P(-a) = 1 - P(a): Q(a) = max(a, 0) - T(|a|), T the tail integral.
    """
    w = np.minimum(np.abs(a), 0.5 * np.pi)
    if np.all(code == GGX):
        T = _ggx_angle_tail_integral(w, ay)
    else:
        # Beckmann: the Gauss-Legendre integral only where the tail has not died out (x < 6)
        T_sat = _bk.angle_tail_integral(0.5 * np.pi, ay)
        if np.all(code == BECKMANN):
            T = _bk.angle_tail_integral(w, ay, saturated=T_sat)
        else:
            T = np.where(code == BECKMANN, _bk.angle_tail_integral(w, ay, saturated=T_sat),
                         _ggx_angle_tail_integral(w, ay))
    return np.maximum(a, 0.0) - T


def _angle_cdf(code, a, ay):
    """P(a): CDF of the slope angle atan(alpha_y x) (GGX: (1 + sin a / sqrt(sin^2 a + ay^2 cos^2 a)) / 2,
    Beckmann: (1 + erf(tan(a) / ay)) / 2), 0 / 1 beyond -/+ pi/2."""
    w = np.minimum(np.abs(a), 0.5 * np.pi)
    ggx = lambda: 0.5 * np.sin(w) / np.sqrt(np.sin(w) ** 2 + (ay * np.cos(w)) ** 2)  # noqa: E731  P(|a|) - 1/2
    beck = lambda: 0.5 * erf(np.minimum(np.tan(w) / ay, _bk._X_SAT))                 # noqa: E731
    if np.all(code == GGX):
        half = ggx()
    elif np.all(code == BECKMANN):
        half = beck()
    else:
        half = np.where(code == BECKMANN, beck(), ggx())
    return 0.5 + np.sign(a) * half


def _check_jitter(jitter):
    J = np.asarray(jitter, dtype=float)
    if not (np.all(np.isfinite(J)) and np.all(J >= 0.0) and np.all(J <= 0.5 * np.pi)):
        raise ValueError(f"jitter must be finite and in [0, pi/2] radians of tilt; got {jitter!r}")
    return J


def cone_collapse_binned_jittered(phi_o, phi_edges, tilt, alpha_y, jitter, alpha_x=1e-3, theta_o=0.0, dist="ggx",
                                  nodes=None):
    """Bin averages of a *jittered* tilted lobe: E_u[:func:`cone_collapse_binned` (tilt + u)], u ~ U(-jitter, jitter).

    The shader draws t' = t + jitter (2 h - 1) per sample (h a uniform hash), so what it renders on
    average is the lobe convolved with a box in tilt: on the cone (Raymond et al. 2016, eq. 5) the
    mirror direction phi_i = 2 t' - phi_o sweeps [2 t - phi_o - 2 jitter, 2 t - phi_o + 2 jitter],
    a box of width 4 jitter with edges softened by the lobe.  With b = (phi_o + phi_i)/2, the
    slope angle a = b - t' (x = tan(a)/alpha_y has the GGX / Beckmann slope marginal, CDF P of a)
    and J = jitter::

        bin mass = E_u[P(a_hi - u) - P(a_lo - u)] = [Q(a_hi + J) - Q(a_hi - J) - Q(a_lo + J) + Q(a_lo - J)] / (2 J)

    with Q(a) = int_0^a P = max(a, 0) - T(|a|), T the tail integral (closed form for GGX; moment
    series / 16-node Gauss-Legendre for Beckmann, ``cycles_beckmann.angle_tail_integral``): the
    sharp factor is exact for any width, so boxes of lobes much narrower than a bin are exact too.
    The smooth factor F of :func:`cone_collapse` (Jacobian remainder, Cycles' G2 and rejections)
    depends on the tilt: the jitter interval is split into ``nodes`` equal panels (default: panels
    of <= 0.05 rad of the narrower of the jitter and 6 atan(alpha_y), the spread of the tilts that
    send light to one phi_i; at most 64), the panel masses are exact as above, and per panel and bin
    F is taken at a representative phi_i of the bin (a blend of the middle of the part the panel's
    box covers and the lobe's slope-marginal mean, by the ratio of box and lobe widths) and at the
    posterior mean tilt of that phi_i.  Against a brute-force average of :func:`cone_collapse_binned`
    over the tilt: ~0.1 % rel. L1 per lobe (~1-3 % with ``nodes=1`` for wide lobes with wide
    jitter); bins next to a horizon are less accurate, like :func:`cone_collapse_binned`'s.

    ``jitter`` in radians of tilt, in [0, pi/2]; below :data:`JITTER_MIN` the plain
    :func:`cone_collapse_binned` is returned (bit-identical for jitter = 0).  ``phi_o``, ``tilt``,
    ``alpha_y``, ``jitter``, ``alpha_x``, ``theta_o`` and ``dist`` broadcast (shape S); output
    S + (nbins,) in 1/rad.  ``nodes``: None (automatic) or a fixed panel count in [1, 256].
    """
    code = dist_code(dist)
    ax, ay = _check_cone_args(alpha_x, alpha_y)
    J = _check_jitter(jitter)
    e = np.asarray(phi_edges, float)
    if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0):
        raise ValueError("phi_edges must be a strictly increasing 1D array of >= 2 bin edges")
    if nodes is not None and not (isinstance(nodes, (int, np.integer)) and 1 <= nodes <= 256):
        raise ValueError(f"nodes must be None or an integer in [1, 256]; got {nodes!r}")
    phi_o, t, ay, ax, code, J, th = np.broadcast_arrays(np.asarray(phi_o, float), np.asarray(tilt, float), ay, ax,
                                                        code, J, np.asarray(theta_o, float))
    out = np.zeros(phi_o.shape + (e.size - 1,))
    jit = J >= JITTER_MIN
    if not np.all(jit):
        out[~jit] = cone_collapse_binned(phi_o[~jit], e, t[~jit], ay[~jit], ax[~jit], th[~jit][:, None],
                                          dist=code[~jit])
    if not np.any(jit):
        return out
    # panels per lobe: the smooth factor varies with the tilt only where the posterior spread of
    # the tilt is wide (wide lobes); narrow lobes pin the tilt of each phi_i, one panel suffices
    if nodes is None:
        n_of = np.clip(np.ceil(np.minimum(J, 6.0 * np.arctan(ay)) / _PANEL), 1, 64).astype(int)
    else:
        n_of = np.full(J.shape, int(nodes))
    for n in np.unique(n_of[jit]):
        sel = jit & (n_of == n)
        out[sel] = _jittered_bins(*(x[sel][:, None, None] for x in (phi_o, t, ay, ax, code, J, th)), e, int(n))
    return out


def cone_collapse_binned_jittered_windows(phi_o, window_edges, tilt, alpha_y, jitter, alpha_x=1e-3, dist="ggx"):
    """:func:`cone_collapse_binned_jittered` (one tilt panel) on a window of bins per lobe.

    ``window_edges`` [P, E] holds each lobe's own increasing bin edges (radians; edges beyond
    +-pi/2 give empty bins); ``phi_o``, ``tilt``, ``alpha_y``, ``jitter``, ``alpha_x``, ``dist`` are
    [P] (or broadcast to it).  Returns [P, E-1] bin averages (1/rad).  For narrow lobes, whose
    weight lies in a few bins around their box, this is the same number for a fraction of the work
    of a full-range evaluation (used by ``lobe_table``, Raymond et al. 2016 eq. 5).
    """
    code = dist_code(dist)
    ax, ay = _check_cone_args(alpha_x, alpha_y)
    J = np.maximum(_check_jitter(jitter), JITTER_MIN)
    e = np.asarray(window_edges, float)
    if e.ndim != 2 or e.shape[1] < 2 or np.any(np.diff(e, axis=1) <= 0):
        raise ValueError("window_edges must be [P, E] with strictly increasing rows of >= 2 edges")
    P = e.shape[0]
    po, tt, a_y, a_x, cd, JJ = (np.broadcast_to(np.asarray(x), (P,)).reshape(P, 1, 1).astype(t)
                                for x, t in ((phi_o, float), (tilt, float), (ay, float), (ax, float),
                                             (code, np.int8), (J, float)))
    th = np.zeros((P, 1, 1))
    ew = e[:, None, :]                                                  # [P, 1, E]
    ec, b, u = _jittered_geometry(po, tt, JJ, ew, 1)
    mass = _jittered_mass(cd, b, tt, u, a_y)                            # [P, 1, E-1]
    F = _jittered_smooth(po, tt, a_y, a_x, cd, th, b, u)
    val = (mass * F)[:, 0, :] / (2.0 * JJ[:, 0]) / np.diff(e, axis=1)
    return np.where(ec[:, 0, 1:] > ec[:, 0, :-1], val, 0.0)


def _jittered_geometry(po, tt, JJ, e, n):
    """Clipped edges ec [P, 1, M+1], their half angles b and the n + 1 panel bounds u [P, n+1, 1]."""
    # valid light interval over all jittered tilts (above n and above some N'); F rejects the rest
    ec = np.clip(e, np.maximum(-0.5 * np.pi, tt - JJ - 0.5 * np.pi), np.minimum(0.5 * np.pi, tt + JJ + 0.5 * np.pi))
    u = JJ * (2.0 * np.arange(n + 1) / n - 1.0)[None, :, None]
    return ec, 0.5 * (po + ec), u


def _jittered_mass(cd, b, tt, u, a_y):
    """Exact panel masses int_panel int_bin p_a(b - t - u) db du -> [P, n, M] (see the docstring above)."""
    Qv = _angle_cdf_integral(cd, b - tt - u, a_y)                     # [P, n+1, M+1]
    dQ = Qv[:, :-1, :] - Qv[:, 1:, :]                                 # int over panel j of P(b - t - u) du
    return np.maximum(dQ[..., 1:] - dQ[..., :-1], 0.0)


def _jittered_smooth(po, tt, a_y, a_x, cd, th, b, u):
    """Smooth factor F [P, n, M] per panel and bin, at a representative phi_i and its posterior tilt."""
    # representative half angle per panel and bin, a blend of the two limits: a box much wider
    # than the lobe covers the bin evenly (middle of the covered part, else the nearest edge); a
    # lobe much wider than the box has its slope-marginal mean in the bin (as cone_collapse_binned)
    lim = 0.5 * np.pi - 1e-12
    lo = np.clip(tt + u[:, :-1], b[..., :-1], b[..., 1:])
    hi = np.clip(tt + u[:, 1:], b[..., :-1], b[..., 1:])
    t_mid = tt + 0.5 * (u[:, :-1] + u[:, 1:])
    xb = np.tan(np.clip(b - t_mid, -lim, lim)) / a_y                 # [P, n, M+1]
    x_in = _slope_mean(cd, xb[..., :-1], xb[..., 1:])
    s = np.arctan(a_y)
    beta = (u[:, 1:] - u[:, :-1]) / (u[:, 1:] - u[:, :-1] + 2.0 * s)
    b_eval = beta * 0.5 * (lo + hi) + (1.0 - beta) * (t_mid + np.arctan(x_in * a_y))   # [P, n, M]
    # posterior mean tilt at b_eval: slope-marginal mean on the window of slope angles of the panel
    x_lo = np.tan(np.clip(b_eval - tt - u[:, 1:], -lim, lim)) / a_y
    x_hi = np.tan(np.clip(b_eval - tt - u[:, :-1], -lim, lim)) / a_y
    x_mean = _slope_mean(cd, x_lo, x_hi)
    t_eval = np.clip(b_eval - np.arctan(x_mean * a_y), tt + u[:, :-1], tt + u[:, 1:])
    return _cone_smooth_factor(po, 2.0 * b_eval - po, t_eval, a_y, a_x, th, cd)


def _slope_mean(cd, x_lo, x_hi):
    """Mean of the GGX / Beckmann slope marginal restricted to [x_lo, x_hi] (codes ``cd``)."""
    if np.all(cd == GGX):
        return _slope_mass_and_mean(x_lo, x_hi)[1]
    if np.all(cd == BECKMANN):
        return _bk.slope_mass_and_mean(x_lo, x_hi)[1]
    return np.where(cd == BECKMANN, _bk.slope_mass_and_mean(x_lo, x_hi)[1], _slope_mass_and_mean(x_lo, x_hi)[1])


def _jittered_bins(po, tt, a_y, a_x, cd, JJ, th, e, n):
    """Core of :func:`cone_collapse_binned_jittered` for P lobes (parameters shaped [P, 1, 1]), n panels -> [P, M]."""
    ec, b, u = _jittered_geometry(po, tt, JJ, e, n)
    mass = _jittered_mass(cd, b, tt, u, a_y)
    F = _jittered_smooth(po, tt, a_y, a_x, cd, th, b, u)
    val = np.einsum("pnm,pnm->pm", mass, F) / (2.0 * JJ[:, 0]) / np.diff(e)
    return np.where(ec[:, 0, 1:] > ec[:, 0, :-1], val, 0.0)


class JitteredAtoms:
    """One-panel jittered lobes for an optimiser: atoms, and atoms of perturbed lobes with the smooth factor frozen.

    ``JitteredAtoms(phi_o, phi_edges, tilt, alpha_y, jitter, alpha_x, dist)`` (broadcast to shape S)
    evaluates :func:`cone_collapse_binned_jittered` with ``nodes=1`` and the jitter raised to at least
    :data:`JITTER_MIN` (plain lobes then differ from :func:`cone_collapse_binned` by < 1e-8 in mass;
    their smooth factor is taken at a slightly different point, < ~0.3 % of a bin).  ``.atoms``
    [S + (M,)]; ``.perturbed(tilt, alpha_y, jitter)`` re-integrates only the exact slope-CDF part
    (the sharp factor) of lobes with other shapes and reuses this smooth factor (G2, Jacobian): the
    cheap finite-difference Jacobian of a Levenberg-Marquardt step (the smooth factor varies on a
    scale of ~0.1 rad); ``.moved(...)`` is the same as a new object; ``.d_dtilt()`` the analytic
    tilt derivative.  Used by ``lobe_fit`` to fit jittered lobes to rho cos(phi_i) (Raymond et al.
    2016, eq. 5).  Angles in radians.
    """

    def __init__(self, phi_o, phi_edges, tilt, alpha_y, jitter, alpha_x=1e-3, dist="ggx", theta_o=0.0):
        code = dist_code(dist)
        ax, ay = _check_cone_args(alpha_x, alpha_y)
        J = np.maximum(_check_jitter(jitter), JITTER_MIN)
        self.e = np.asarray(phi_edges, float)
        arrs = np.broadcast_arrays(np.asarray(phi_o, float), np.asarray(tilt, float), ay, ax, code, J,
                                   np.asarray(theta_o, float))
        self.shape = arrs[0].shape
        po, tt, a_y, a_x, cd, JJ, th = (np.reshape(x, (-1, 1, 1)) for x in arrs)
        self.po, self.cd = po, cd
        ec, b, u = _jittered_geometry(po, tt, JJ, self.e, 1)
        self.F = _jittered_smooth(po, tt, a_y, a_x, cd, th, b, u)[:, 0, :] / np.diff(self.e)     # [P, M]
        self.atoms = self._combine(_jittered_mass(cd, b, tt, u, a_y), JJ, ec)
        self._a, self._ay, self._JJ, self._ec = b - tt - u, a_y, JJ, ec    # for d_dtilt

    def d_dtilt(self):
        """d atoms / d tilt (smooth factor frozen, edge clipping ignored) -> S + (M,).

        d/dt [Q(b - t + J) - Q(b - t - J)] = P(b - t - J) - P(b - t + J), P the slope-angle CDF.
        """
        Pv = _angle_cdf(self.cd, self._a, self._ay)                      # [P, 2, M+1]
        dD = Pv[:, 1, :] - Pv[:, 0, :]
        return self._combine((dD[:, 1:] - dD[:, :-1])[:, None, :], self._JJ, self._ec)

    def _combine(self, mass, JJ, ec):
        val = mass[:, 0, :] * self.F / (2.0 * JJ[:, 0])
        val = np.where(ec[:, 0, 1:] > ec[:, 0, :-1], val, 0.0)
        return val.reshape(self.shape + (self.e.size - 1,))

    def perturbed(self, tilt, alpha_y, jitter):
        """Atoms of lobes with other (tilt, alpha_y, jitter), same phi_o and smooth factor -> S + (M,)."""
        return self.moved(tilt, alpha_y, jitter).atoms

    def moved(self, tilt, alpha_y, jitter) -> "JitteredAtoms":
        """A copy for lobes with other (tilt, alpha_y, jitter) that keeps this smooth factor (sharp factor exact)."""
        tt, a_y, JJ = (np.reshape(np.broadcast_to(np.asarray(x, float), self.shape), (-1, 1, 1))
                       for x in (tilt, alpha_y, np.maximum(jitter, JITTER_MIN)))
        ec, b, u = _jittered_geometry(self.po, tt, JJ, self.e, 1)
        out = object.__new__(JitteredAtoms)
        out.e, out.shape, out.po, out.cd, out.F = self.e, self.shape, self.po, self.cd, self.F
        out.atoms = out._combine(_jittered_mass(self.cd, b, tt, u, a_y), JJ, ec)
        out._a, out._ay, out._JJ, out._ec = b - tt - u, a_y, JJ, ec
        return out

    def merge(self, other: "JitteredAtoms", take) -> None:
        """In place: lobes where ``take`` (broadcastable to the lobe shape S) get ``other``'s atoms and smooth factor."""
        m = np.broadcast_to(np.asarray(take, bool), self.shape)
        flat = m.reshape(-1, 1)
        self.F = np.where(flat, other.F, self.F)
        self.atoms = np.where(m[..., None], other.atoms, self.atoms)
        for name in ("_a", "_ay", "_JJ", "_ec"):
            setattr(self, name, np.where(flat[..., None], getattr(other, name), getattr(self, name)))
