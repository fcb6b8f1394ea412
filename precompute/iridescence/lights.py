"""Angular integrals of the scratch-iridescence response over area lights.

Velinov, Werner & Hullin 2018, "Real-Time Rendering of Wave-Optical Effects on
Scratched Surfaces" (CGF 37(2)), §3.4, eqs. 19-41; model of Werner et al. 2017.

Conventions (all public functions of this module)
-------------------------------------------------
* Local shading frame: the surface normal is +z, the tangent plane is z = 0.
  Directions (``wo``, light directions) are unit 3-vectors pointing *away* from
  the surface.
* A scratch is a straight segment whose in-plane direction makes the angle
  ``phi`` (radians) with +x; its tangent is ``t = (cos phi, sin phi, 0)`` and its
  bitangent ``b = (-sin phi, cos phi, 0)``.
* Direction cosines (paper §3.1): ``xi = (wi + wo)·(t, b)`` i.e. ``xi_1`` along the
  scratch, ``xi_2`` across it.
* Wavelength ``lam``, width ``W`` and coherence radius ``sigma`` in micrometres;
  ``k = 2 pi / lam``.

The quantity every light function returns is the dimensionless *angular factor*

    A = ∫_{light ∩ upper hemisphere} sinc²(π W ξ₂/λ) · exp(−σ²k²ξ₁²) cosθ_i dω_i
      = ∫∫ sinc²(π W ξ₂/λ) · exp(−σ²k²ξ₁²) dξ₁ dξ₂          (eqs. 19-25)

(``sinc(x) = sin(x)/x``), i.e. the part of eq. 25 that depends on the light.  The
radiance of one scratch under a light of unit radiance is then
``W² |D|² |η_s|² A / (A_C λ²)`` (eqs. 1-11, see ``precompute.iridescence``).

Closed forms (eq. 27): the Gaussian in ξ₁ is far narrower than any light
(eq. 26), so the light is cut along the line ξ₁ = 0 and
``A ≈ Σ_intervals N(q₁) − N(q₀)``.  In 3D that line is the small circle
``ω(ψ) = c t + ρ (cos ψ b + sin ψ n)`` with ``c = −ωo·t``, ``ρ = √(1−c²)``; its
upper half ψ ∈ [0, π] is the horizon-clipped chord, and ``ξ₂ = ρ cos ψ + ωo·b``.
The boundary crossings of eq. 32 (sphere) / eq. 38 (polygon edges) are both of the
form ``a cos γ + b sin γ = c`` and are solved as ``γ = atan2(b, a) ± acos(c/√(a²+b²))``,
which is the same root pair as the tan-half-angle quadratic of eqs. 33-35/39-40
but needs no special case for a vanishing denominator.  Horizon clipping
(eqs. 36-37) is the intersection with ψ ∈ [0, π]; the degenerate cases of §3.4.1
(projected ellipse collapsing to a line at grazing angles, sphere entirely below
the horizon) and the double-root case of eq. 41 (crossing exactly at a polygon
vertex) fall out of this formulation without branches.

Monte Carlo counterparts integrate the exact integrand above by uniform cone
sampling (sphere) and uniform area sampling converted to solid angle (polygon),
using seeded scrambled Sobol points (randomised QMC) or plain pseudo-random points.
"""
from __future__ import annotations

import numpy as np
from scipy import special
from scipy.stats import qmc

from ..validation import check_seed, finite as _finite, in_range as _in_range

__all__ = [
    "si",
    "si_approx",
    "SI_A0",
    "SI_B0",
    "sinc2_antiderivative",
    "angular_response",
    "sphere_light_integral",
    "sphere_light_integral_mc",
    "polygon_light_integral",
    "polygon_light_integral_mc",
    "sphere_cone",
    "band_nodes",
]

# Eq. 29 constants (least-squares fit on [-10, 10] quoted in the paper).
SI_A0 = 0.66142739
SI_B0 = 0.38272292


# ----------------------------------------------------------------------------- validation
def _unit(name: str, v) -> np.ndarray:
    a = _finite(name, v)
    if a.shape[-1:] != (3,):
        raise ValueError(f"{name} must have a trailing dimension of 3 (got shape {a.shape})")
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError(f"{name} must be non-zero vectors")
    return a / n


def _check_common(W, lam, sigma):
    W = _in_range("W (width, um)", W, 0.0, 1e4, lo_open=True)
    lam = _in_range("lam (wavelength, um)", lam, 0.05, 50.0)
    sigma = _in_range("sigma (coherence radius, um)", sigma, 0.0, 1e5, lo_open=True)
    return W, lam, sigma


def _check_wo(wo):
    wo = _unit("wo", wo)
    if np.any(wo[..., 2] < 0.0):
        raise ValueError("wo must lie in the upper hemisphere (wo_z in [0, 1])")
    return wo


# ----------------------------------------------------------------------------- Si(x)
def si(x) -> np.ndarray:
    """Sine integral Si(x) = ∫₀ˣ sin t / t dt (eq. 28), exact to double precision.

    Uses ``scipy.special.sici`` (Cephes; absolute error ~1e-16 on the range the
    model needs).  ``x`` dimensionless, any shape; raises ValueError on NaN/inf.
    """
    x = _finite("x", x)
    return special.sici(x)[0]


def si_approx(x) -> np.ndarray:
    """GPU-friendly approximation of Si(x), eq. 29 of Velinov et al. 2018.

    ``Si(x) ≈ π/2 tanh(x) − a₀x / (1 + (x − sgn(x) b₀)²) + sgn(x)(1 − cos x)/(1 + |x|)``
    with a₀ = 0.66142739, b₀ = 0.38272292.  Odd in x, exact at 0, → ±π/2 at ±∞.
    ``x`` dimensionless; raises ValueError on NaN/inf.
    """
    x = _finite("x", x)
    s = np.sign(x)
    return (0.5 * np.pi * np.tanh(x)
            - SI_A0 * x / (1.0 + (x - s * SI_B0) ** 2)
            + s * (1.0 - np.cos(x)) / (1.0 + np.abs(x)))


def _si_fn(si_mode: str):
    if si_mode == "exact":
        return lambda x: special.sici(x)[0]
    if si_mode == "approx":
        return si_approx
    raise ValueError(f"si_mode must be 'exact' or 'approx' (got {si_mode!r})")


def sinc2_antiderivative(q, W, lam, sigma, si_mode: str = "exact") -> np.ndarray:
    """N(q) of eq. 27: antiderivative in ξ₂ of ∫ sinc²(πWξ₂/λ) exp(−σ²k²ξ₁²) dξ₁.

    ``N(q) = √π/(σk) · (2 Si(kWq)/(kW) − 4 sin²(kWq/2)/(k²W²q))`` (the Gaussian in ξ₁
    integrated over ℝ, the sinc² by parts).  Written as
    ``√π/(σk)/(kW) · (2 Si(x) − x sinc²(x/2))`` with x = kWq so q = 0 is regular.
    ``q`` direction cosine (dimensionless); W, lam, sigma in µm.
    """
    k = 2.0 * np.pi / lam
    kW = k * W
    x = kW * q
    sif = _si_fn(si_mode)
    return (np.sqrt(np.pi) / (sigma * k)) * (2.0 * sif(x) - x * np.sinc(x / (2.0 * np.pi)) ** 2) / kW


def angular_response(xi1, xi2, W, lam, sigma) -> np.ndarray:
    """Separable angular part of one scratch, eq. 25 / eqs. 3 and 10 (without W²):

    ``sinc²(π W ξ₂/λ) · exp(−σ² k² ξ₁²)`` — dimensionless, ≤ 1.
    """
    k = 2.0 * np.pi / lam
    return np.sinc(W * xi2 / lam) ** 2 * np.exp(-(sigma * k * xi1) ** 2)


# ----------------------------------------------------------------------------- geometry helpers
def _scratch_frame(phi):
    c, s = np.cos(phi), np.sin(phi)
    z = np.zeros_like(c)
    t = np.stack([c, s, z], axis=-1)
    b = np.stack([-s, c, z], axis=-1)
    return t, b


def _onb(n):
    """Branchless orthonormal basis around unit n (Duff et al. 2017, [DBC*17])."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    bb = n[..., 0] * n[..., 1] * a
    t1 = np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * bb, -sign * n[..., 0]], axis=-1)
    t2 = np.stack([bb, sign + n[..., 1] ** 2 * a, -n[..., 1]], axis=-1)
    return t1, t2


def _interval_sum(psi_lo, psi_hi, rho, o_b, W, lam, sigma, si_mode):
    """Σ N(ξ₂(ψ_lo)) − N(ξ₂(ψ_hi)) over ψ-intervals ⊂ [0, π] (empty ones give 0)."""
    valid = psi_hi > psi_lo
    q_hi = rho * np.cos(np.where(valid, psi_lo, 0.0)) + o_b  # ξ₂ decreases with ψ
    q_lo = rho * np.cos(np.where(valid, psi_hi, 0.0)) + o_b
    dn = sinc2_antiderivative(q_hi, W, lam, sigma, si_mode) - sinc2_antiderivative(q_lo, W, lam, sigma, si_mode)
    return np.where(valid, dn, 0.0)


def sphere_cone(center, radius):
    """Direction and cosine of the half-angle of the cone subtended by a sphere.

    ``center`` (..., 3) relative to the shading point, ``radius`` (...) in the same
    units.  Returns ``(p_hat, cos_alpha)`` with ``sin α = r/|p|``.  This is eq. 31
    with the disk radius of the paper chosen so the disk's rim is the sphere's
    silhouette.  Raises ValueError when the shading point is inside the sphere.
    """
    center = _finite("center", center)
    radius = _in_range("radius", radius, 0.0, np.inf, lo_open=True)
    d = np.linalg.norm(center, axis=-1)
    if np.any(d <= radius):
        raise ValueError("radius must be smaller than the distance to the light centre (shading point inside the sphere)")
    p_hat = center / d[..., None]
    return p_hat, np.sqrt(np.maximum(0.0, 1.0 - (radius / d) ** 2))


def band_nodes(n_band: int, sigma, lam):
    """ξ₁ offsets and weights of the cut(s) through the light (extension of eq. 27).

    The paper integrates the Gaussian exp(−σ²k²ξ₁²) over ℝ and evaluates the light's
    extent on the single line ξ₁ = 0 (``n_band = 1``, weight 1).  With ``n_band`` > 1
    the ξ₁ integral is done by ``n_band``-point Gauss–Hermite quadrature instead
    (cuts at ξ₁ = z_j/(σk), weights w_j/√π), which follows the light's rim and the
    horizon curvature across the band.  Returns arrays broadcastable to
    ``(..., n_band)``.
    """
    if not (isinstance(n_band, (int, np.integer)) and 1 <= n_band <= 32):
        raise ValueError(f"n_band must be an integer in [1, 32] (got {n_band!r})")
    zh, wh = np.polynomial.hermite.hermgauss(int(n_band))
    k = 2.0 * np.pi / np.asarray(lam)
    z = zh / (np.asarray(sigma) * k)[..., None]
    return z, wh / np.sqrt(np.pi)


# ----------------------------------------------------------------------------- sphere light
def sphere_light_integral(wo, light_dir, cos_alpha, phi, W, lam, sigma=60.0, si_mode: str = "exact",
                          n_band: int = 1) -> np.ndarray:
    """Closed-form angular factor A of one scratch under a spherical light (eqs. 27, 30-37).

    Parameters (all broadcast together)
    ----------
    wo : (..., 3) unit view direction, upper hemisphere.
    light_dir : (..., 3) unit direction to the light centre (may be below the horizon).
    cos_alpha : (...) cosine of the cone half-angle subtended by the light, in (0, 1].
    phi : (...) scratch orientation in radians.
    W, lam, sigma : scratch width, wavelength, coherence radius in µm.
    si_mode : 'exact' (scipy Si) or 'approx' (eq. 29).
    n_band : number of ξ₁ slices (see ``band_nodes``); 1 = the paper's single cut.

    Returns A (dimensionless, ≥ 0, finite); see the module docstring.  The
    intersection of the line ξ₁ = 0 with the cap (eq. 32) is the arc
    ``|ψ − φ₀| ≤ acos κ`` of the small circle, clipped to the upper half ψ ∈ [0, π]
    (horizon clipping, eqs. 36-37).
    """
    wo = _check_wo(wo)
    p = _unit("light_dir", light_dir)
    cos_alpha = _in_range("cos_alpha", cos_alpha, 0.0, 1.0, lo_open=True)
    phi = _finite("phi", phi)
    W, lam, sigma = _check_common(W, lam, sigma)
    t, b = _scratch_frame(phi)
    z, w = band_nodes(n_band, sigma, lam)             # (..., n_band) ξ₁ offsets and weights
    c = z - np.sum(wo * t, axis=-1)[..., None]        # ω_i·t on the slice ξ₁ = z (z = 0: the paper's cut)
    o_b = np.sum(wo * b, axis=-1)[..., None]
    rho = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    p_t = np.sum(p * t, axis=-1)[..., None]
    p_b = np.sum(p * b, axis=-1)[..., None]
    p_n = p[..., 2][..., None]
    cos_alpha = np.asarray(cos_alpha)[..., None]
    W, lam, sigma = (np.asarray(v)[..., None] for v in (W, lam, sigma))
    amp = rho * np.hypot(p_b, p_n)
    rhs = cos_alpha - c * p_t                        # need amp·cos(ψ − φ₀) ≥ rhs
    safe = amp > 1e-300
    kappa = np.where(safe, rhs / np.where(safe, amp, 1.0), np.where(rhs <= 0.0, -np.inf, np.inf))
    beta = np.arccos(np.clip(kappa, -1.0, 1.0))      # arc half-width; 0 ⇒ empty, π ⇒ full circle
    beta = np.where(kappa >= 1.0, -1.0, beta)        # strictly empty (tangency has zero measure)
    phi0 = np.arctan2(p_n, p_b)
    total = 0.0
    for shift in (-2.0 * np.pi, 0.0, 2.0 * np.pi):  # arc may wrap around ±π
        lo = np.maximum(phi0 - beta + shift, 0.0)
        hi = np.minimum(phi0 + beta + shift, np.pi)
        total = total + _interval_sum(lo, hi, rho, o_b, W, lam, sigma, si_mode)
    return np.maximum(np.sum(w * total, axis=-1), 0.0)


def _points(n_samples: int, dim: int, seed: int, qmc_points: bool) -> np.ndarray:
    if not (isinstance(n_samples, (int, np.integer)) and 16 <= n_samples <= 1 << 24):
        raise ValueError(f"n_samples must be an integer in [16, 2**24] (got {n_samples!r})")
    seed = check_seed("seed", seed)
    if qmc_points:
        m = int(np.ceil(np.log2(n_samples)))
        return qmc.Sobol(d=dim, scramble=True, seed=seed).random_base2(m)[:n_samples]
    return np.random.default_rng(seed).random((n_samples, dim))


def sphere_light_integral_mc(wo, light_dir, cos_alpha, phi, W, lam, sigma=60.0,
                             n_samples: int = 1 << 16, seed: int = 0, qmc_points: bool = True) -> np.ndarray:
    """Monte Carlo estimate of the same A as ``sphere_light_integral`` (reference).

    Uniform sampling of the cone subtended by the sphere (pdf 1/Ω,
    Ω = 2π(1 − cos α)); the estimator is ``Ω · mean(F(ξ) · max(ω_z, 0))`` with F the
    exact eq. 25 integrand ``angular_response`` and directions below the horizon
    contributing zero.  Vectorised over (batch × samples); same arguments as the
    closed form plus ``n_samples`` (≥ 16), ``seed`` and ``qmc_points`` (scrambled Sobol).
    """
    wo = _check_wo(wo)
    p = _unit("light_dir", light_dir)
    cos_alpha = _in_range("cos_alpha", cos_alpha, 0.0, 1.0, lo_open=True)
    phi = _finite("phi", phi)
    W, lam, sigma = _check_common(W, lam, sigma)
    shape = np.broadcast_shapes(wo.shape[:-1], p.shape[:-1], cos_alpha.shape, phi.shape, W.shape, lam.shape, sigma.shape)
    wo = np.broadcast_to(wo, shape + (3,))[..., None, :]
    p = np.broadcast_to(p, shape + (3,))
    ca = np.broadcast_to(cos_alpha, shape)[..., None]
    u = _points(n_samples, 2, seed, qmc_points)
    cos_t = 1.0 - u[:, 0] * (1.0 - ca)
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    ang = 2.0 * np.pi * u[:, 1]
    e1, e2 = _onb(p)
    wi = (cos_t[..., None] * p[..., None, :]
          + (sin_t * np.cos(ang))[..., None] * e1[..., None, :]
          + (sin_t * np.sin(ang))[..., None] * e2[..., None, :])
    t, b = _scratch_frame(np.broadcast_to(phi, shape))
    h = wi + wo
    xi1 = np.sum(h * t[..., None, :], axis=-1)
    xi2 = np.sum(h * b[..., None, :], axis=-1)
    f = angular_response(xi1, xi2, np.broadcast_to(W, shape)[..., None], np.broadcast_to(lam, shape)[..., None],
                         np.broadcast_to(sigma, shape)[..., None])
    omega = 2.0 * np.pi * (1.0 - ca[..., 0])
    return omega * np.mean(f * np.maximum(wi[..., 2], 0.0), axis=-1)


# ----------------------------------------------------------------------------- polygon light
def _check_polygon(vertices, two_sided):
    V = _finite("vertices", vertices)
    if V.ndim < 2 or V.shape[-1] != 3 or V.shape[-2] < 3:
        raise ValueError(f"vertices must have shape (..., N>=3, 3) (got {V.shape})")
    if V.shape[-2] > 64:
        raise ValueError("vertices: at most 64 vertices per polygon")
    nrm = np.zeros(V.shape[:-2] + (3,))
    for j in range(1, V.shape[-2] - 1):              # Newell-free fan normal (few vertices)
        nrm = nrm + np.cross(V[..., j, :] - V[..., 0, :], V[..., j + 1, :] - V[..., 0, :])
    area2 = np.linalg.norm(nrm, axis=-1)
    scale = np.max(np.linalg.norm(V - V[..., :1, :], axis=-1), axis=-1)
    if np.any(area2 <= 1e-12 * np.maximum(scale, 1e-300) ** 2):
        raise ValueError("vertices: polygon has (near) zero area")
    n_l = nrm / area2[..., None]
    off = np.abs(np.einsum("...nk,...k->...n", V - V[..., :1, :], n_l))
    if np.any(off > 1e-6 * scale[..., None] + 1e-12):
        raise ValueError("vertices: polygon must be planar (tolerance 1e-6 of its size)")
    # convexity: all fan/edge turns have the same orientation about n_l
    Vn = np.roll(V, -1, axis=-2)
    Vnn = np.roll(V, -2, axis=-2)
    turns = np.einsum("...nk,...k->...n", np.cross(Vn - V, Vnn - Vn), n_l)
    if np.any(turns < -1e-9 * scale[..., None] ** 2):
        raise ValueError("vertices: polygon must be convex with consistent winding (split concave lights into triangles)")
    dist = -np.einsum("...k,...k->...", V[..., 0, :], n_l)   # >0: shading point on the front side
    if np.any(np.abs(dist) <= 1e-9 * scale):
        raise ValueError("vertices: shading point lies in the light's plane")
    front = dist > 0.0 if not two_sided else np.ones(dist.shape, dtype=bool)
    return V, n_l, 0.5 * area2, front


def polygon_light_integral(wo, vertices, phi, W, lam, sigma=60.0, si_mode: str = "exact",
                           two_sided: bool = False, n_band: int = 1) -> np.ndarray:
    """Closed-form angular factor A of one scratch under a convex polygonal light (eqs. 27, 36, 38-41).

    Parameters
    ----------
    wo : (..., 3) unit view direction (upper hemisphere).
    vertices : (..., N, 3) polygon vertices *relative to the shading point* (any length
        unit); planar, convex, counter-clockwise seen from the emitting side
        (emitting normal = right-hand rule).  Concave lights: pass triangles and sum.
    phi, W, lam, sigma, si_mode : as in ``sphere_light_integral``.
    two_sided : emit from both faces (default: back side gives 0).
    n_band : number of ξ₁ cuts (``band_nodes``); 1 = the paper.

    Each edge is the great arc ``C(γ) = U cos γ + Γ̂ sin γ`` (eq. 36); its crossings
    with the plane ξ₁ = 0 solve eq. 38.  Crossings are sorted along the small
    circle (ψ, equivalent to sorting by ξ₂ in the upper half, as the bitonic sort of
    §3.4.2), the interval between consecutive crossings is kept when its midpoint
    lies in the spherical polygon, and the horizon clip restricts ψ to [0, π]; a
    crossing exactly at a vertex (eq. 41) only yields a zero-length interval.
    Returns A (dimensionless, ≥ 0, finite).
    """
    wo = _check_wo(wo)
    V, n_l, _, front = _check_polygon(vertices, two_sided)
    phi = _finite("phi", phi)
    W, lam, sigma = _check_common(W, lam, sigma)
    shape = np.broadcast_shapes(wo.shape[:-1], V.shape[:-2], phi.shape, W.shape, lam.shape, sigma.shape)
    nv = V.shape[-2]
    V = np.broadcast_to(V, shape + (nv, 3))
    front = np.broadcast_to(front, shape)
    U = V / np.linalg.norm(V, axis=-1, keepdims=True)
    Un = np.roll(U, -1, axis=-2)
    dot = np.clip(np.sum(U * Un, axis=-1), -1.0, 1.0)
    gamma_max = np.arccos(dot)                                     # eq. 36 range
    G = Un - U * dot[..., None]
    Gn = np.linalg.norm(G, axis=-1, keepdims=True)
    G_hat = G / np.where(Gn > 0.0, Gn, 1.0)
    z, wz = band_nodes(n_band, np.broadcast_to(sigma, shape), np.broadcast_to(lam, shape))
    shape = shape + (int(n_band),)                                 # slices are an extra batch axis
    V = V[..., None, :, :]
    U, Un, gamma_max, G_hat = U[..., None, :, :], Un[..., None, :, :], gamma_max[..., None, :], G_hat[..., None, :, :]
    front = front[..., None]
    phi, W, lam, sigma = (np.asarray(v)[..., None] for v in (phi, W, lam, sigma))
    t, b = _scratch_frame(np.broadcast_to(phi, shape))
    wo_b = np.broadcast_to(wo[..., None, :], shape + (3,))
    c = z - np.sum(wo_b * t, axis=-1)
    o_b = np.sum(wo_b * b, axis=-1)
    rho = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    # eq. 38: (U·t) cos γ + (Γ̂·t) sin γ = c  →  γ = γ₀ ± acos(c/R)
    a_ = np.sum(U * t[..., None, :], axis=-1)
    b_ = np.sum(G_hat * t[..., None, :], axis=-1)
    R = np.hypot(a_, b_)
    ok = R > 1e-300
    ratio = np.where(ok, c[..., None] / np.where(ok, R, 1.0), 2.0)
    has = np.abs(ratio) <= 1.0
    g0 = np.arctan2(b_, a_)
    dg = np.arccos(np.clip(ratio, -1.0, 1.0))
    psis = []
    for sgn in (-1.0, 1.0):
        g = np.mod(g0 + sgn * dg, 2.0 * np.pi)
        g = np.where(g > 2.0 * np.pi - 1e-12, 0.0, g)                # γ ≈ 2π is the start vertex
        valid = has & (g <= gamma_max + 1e-12)
        w = U * np.cos(g)[..., None] + G_hat * np.sin(g)[..., None]
        psi = np.arctan2(w[..., 2], np.sum(w * b[..., None, :], axis=-1))
        psi = np.where(valid & (psi >= 0.0), psi, np.pi)          # off-chord crossings → dummy at π
        psis.append(psi)
    nb = 2 * nv
    brk = np.concatenate([np.zeros(shape + (1,))] + psis + [np.full(shape + (1,), np.pi)], axis=-1)
    brk = np.sort(np.clip(brk, 0.0, np.pi), axis=-1)                  # (…, 2N+2)
    lo, hi = brk[..., :-1], brk[..., 1:]
    mid = 0.5 * (lo + hi)
    wm = (c[..., None, None] * t[..., None, :]
          + (rho[..., None] * np.cos(mid))[..., None] * b[..., None, :]
          + (rho[..., None] * np.sin(mid))[..., None] * np.array([0.0, 0.0, 1.0]))
    # convex spherical polygon: inside ⇔ det(U_j, U_j+1, ω) has the orientation's sign for all j
    edge_n = np.cross(U, Un)                                          # (…, N, 3)
    orient = np.sign(np.sum(np.cross(U[..., 0, :], U[..., 1, :]) * U[..., 2, :], axis=-1))
    dets = np.einsum("...mk,...nk->...mn", wm, edge_n) * orient[..., None, None]
    inside = np.all(dets >= 0.0, axis=-1)
    del nb
    dn = _interval_sum(lo, np.where(inside, hi, lo), rho[..., None], o_b[..., None],
                       np.broadcast_to(W, shape)[..., None], np.broadcast_to(lam, shape)[..., None],
                       np.broadcast_to(sigma, shape)[..., None], si_mode)
    return np.sum(wz * np.where(front, np.maximum(np.sum(dn, axis=-1), 0.0), 0.0), axis=-1)


def polygon_light_integral_mc(wo, vertices, phi, W, lam, sigma=60.0, n_samples: int = 1 << 16, seed: int = 0,
                              qmc_points: bool = True, two_sided: bool = False) -> np.ndarray:
    """Monte Carlo estimate of the same A as ``polygon_light_integral`` (reference).

    Uniform area sampling of the polygon (triangle fan, triangle picked by area,
    uniform barycentrics), converted to solid angle with ``dω = |cos θ_l| dA / d²``;
    estimator ``mean(F(ξ) max(ω_z, 0) |cos θ_l| A / d²)``.  Same arguments as the
    closed form plus ``n_samples`` (≥ 16), ``seed``, ``qmc_points``.
    """
    wo = _check_wo(wo)
    V, n_l, area, front = _check_polygon(vertices, two_sided)
    phi = _finite("phi", phi)
    W, lam, sigma = _check_common(W, lam, sigma)
    shape = np.broadcast_shapes(wo.shape[:-1], V.shape[:-2], phi.shape, W.shape, lam.shape, sigma.shape)
    nv = V.shape[-2]
    V = np.broadcast_to(V, shape + (nv, 3))
    n_l = np.broadcast_to(n_l, shape + (3,))
    area = np.broadcast_to(area, shape)
    front = np.broadcast_to(front, shape)
    u = _points(n_samples, 3, seed, qmc_points)
    A0 = V[..., 0:1, :]
    tri_area = 0.5 * np.linalg.norm(np.cross(V[..., 1:-1, :] - A0, V[..., 2:, :] - A0), axis=-1)   # (…, N-2)
    cdf = np.cumsum(tri_area, axis=-1)
    cdf = cdf / cdf[..., -1:]
    idx = np.sum(u[:, 0][..., None] >= cdf[..., None, :-1], axis=-1) if nv > 3 else np.zeros(shape + (n_samples,), int)
    idx = np.broadcast_to(idx, shape + (n_samples,))
    B = np.take_along_axis(V[..., 1:-1, :], idx[..., None], axis=-2)
    C = np.take_along_axis(V[..., 2:, :], idx[..., None], axis=-2)
    su = np.sqrt(u[:, 1])[..., None]
    pts = (1.0 - su) * A0 + (su * (1.0 - u[:, 2][..., None])) * B + (su * u[:, 2][..., None]) * C
    d2 = np.sum(pts * pts, axis=-1)
    wi = pts / np.sqrt(d2)[..., None]
    cos_l = np.abs(np.sum(wi * n_l[..., None, :], axis=-1))
    t, b = _scratch_frame(np.broadcast_to(phi, shape))
    h = wi + np.broadcast_to(wo, shape + (3,))[..., None, :]
    xi1 = np.sum(h * t[..., None, :], axis=-1)
    xi2 = np.sum(h * b[..., None, :], axis=-1)
    f = angular_response(xi1, xi2, np.broadcast_to(W, shape)[..., None], np.broadcast_to(lam, shape)[..., None],
                         np.broadcast_to(sigma, shape)[..., None])
    est = area * np.mean(f * np.maximum(wi[..., 2], 0.0) * cos_l / d2, axis=-1)
    return np.where(front, est, 0.0)
