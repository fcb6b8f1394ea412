"""Cycles' Principled BSDF (Blender 4.x / 5.0) for an opaque surface, as Fresnel and layering factors on GGX.

Read from ``intern/cycles/kernel/svm/closure.h`` (``CLOSURE_BSDF_PRINCIPLED_ID``) and
``kernel/closure/bsdf_microfacet.h`` / ``bsdf_util.h``; no coat, sheen, transmission, subsurface, thin film, diffuse
roughness or anisotropy (``principled_supported`` says which inputs that needs).  With metallic m, base colour b
(clamped to [0, 1]), roughness r (alpha = r²), IOR η, Specular IOR Level L and Specular Tint t:

- **metal** (weight m): GGX with the F82-tint Fresnel (Kutz et al., "Novel aspects of the Adobe Standard Material")
  ``F(c) = b + (1 - b)(1 - c)^5 - B c (1 - c)^6``, B = 0 for t = 1 (``fresnel_f82tint_B``), c = ωi·h;
  Multiscatter: ``Fss = mix(b, 1, 1/21) - B/126`` (``fresnel_f82_Fss``);
- **dielectric specular** (weight 1 - m): f0 = ((η - 1)/(η + 1))², scaled by 2L when L != 0.5 and η re-derived from
  it; GGX with the generalized-Schlick Fresnel in its "real curve" mode: ``F(c) = mix(f0 t, 1, s(c))``,
  ``s(c) = saturate((F_η(c) - f0)/(1 - f0))`` with F_η the unpolarised dielectric Fresnel; Multiscatter: ``Fss =
  mix(f0 t, 1, saturate((Fss_η - f0)/(1 - f0)))`` with Kulla & Conty's fit
  ``Fss_η = (η - 1)/(4.08567 + 1.00071 η)``;
- **diffuse** (Lambert, weight (1 - m) b): attenuated by the specular layer's albedo estimate,
  ``saturate(1 - max_c mix(f0 t_c, 1, S(r, μ, z)))`` (``closure_layering_weight``), S Cycles' ``ggx_gen_schlick_ior_s``
  table (16³ over rough, μ = the view's cosine, z = sqrt((η - 1)/(η + 1))): the mean of s(ωi·h) over the visible
  normals of the view, samples reflected below the horizon counting 0 (``cycles_precompute.cpp``).

Multiscatter GGX (the node's default distribution) multiplies each GGX part by ``1 + Fms (1 - E(μ))/E(μ)``
(``multiscatter``).  The S table is integrated here on Cycles' nodes (VNDF midpoint quadrature, not Cycles' shipped
Monte Carlo values); a render test holds the two together.  Dimensionless factors; angles as cosines.
"""
from __future__ import annotations

import functools

import numpy as np

from . import multiscatter
from .lookup import lookup_index, lookup_table_read_2D

__all__ = ["F0_from_ior", "ior_from_F0", "fresnel_dielectric", "fresnel_dielectric_Fss", "f82_tint_B",
           "real_curve_s", "gen_schlick_ior_s", "dielectric_f0_eta", "principled_supported", "PRINCIPLED_DEFAULTS",
           "PRINCIPLED_SOCKETS"]

#: Cycles' ``ggx_gen_schlick_ior_s`` table size per axis (rough, μ, z)
S_TABLE = 16
#: the node's defaults (Blender 4.x / 5.0) for the inputs the twin reads, and its default distribution (Multiscatter
#: GGX): the one copy the bake's reader (``scratch_addon.biscale_material``), ``biscale.brdfs`` and the truth builder use
PRINCIPLED_DEFAULTS = {"base_color": (0.8, 0.8, 0.8), "metallic": 0.0, "roughness": 0.5, "ior": 1.5,
                       "specular_ior_level": 0.5, "specular_tint": (1.0, 1.0, 1.0), "multiscatter": True}
#: the node's input socket of each ``PRINCIPLED_DEFAULTS`` key (``multiscatter``: the node's distribution)
PRINCIPLED_SOCKETS = {"base_color": "Base Color", "metallic": "Metallic", "roughness": "Roughness", "ior": "IOR",
                      "specular_ior_level": "Specular IOR Level", "specular_tint": "Specular Tint"}


def F0_from_ior(ior):
    """Normal-incidence reflectance ((η - 1)/(η + 1))²."""
    ior = np.asarray(ior, np.float64)
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_from_F0(f0):
    """Cycles ``ior_from_F0``: (1 + √f0)/(1 - √f0), f0 clamped to [0, 0.99]."""
    s = np.sqrt(np.clip(np.asarray(f0, np.float64), 0.0, 0.99))
    return (1.0 + s) / (1.0 - s)


def fresnel_dielectric(cos_i, eta):
    """Unpolarised dielectric Fresnel reflectance (Cycles ``fresnel_dielectric``); 1 under total internal reflection."""
    c = np.abs(np.asarray(cos_i, np.float64))
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.maximum(g2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        A = (g - c) / (g + c)
        B = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        F = 0.5 * A * A * (1.0 + B * B)
    return np.where(g2 > 0, np.nan_to_num(F, nan=1.0), 1.0)


def fresnel_dielectric_Fss(eta: float) -> float:
    """Cycles ``fresnel_dielectric_Fss``: Kulla & Conty's fit of 2 ∫ F_η(μ) μ dμ."""
    if eta < 1.0:
        return 0.997118 + eta * (0.1014 - eta * (0.965241 + eta * 0.130607))
    return (eta - 1.0) / (4.08567 + 1.00071 * eta)


def f82_tint_B(f0, tint):
    """Cycles ``fresnel_f82tint_B``: the F82 term's B making F(acos 1/7) = Schlick(acos 1/7) · tint (0 for tint 1)."""
    f0, tint = np.asarray(f0, np.float64), np.asarray(tint, np.float64)
    f = 6.0 / 7.0
    f5 = f ** 5
    return np.where(tint == 1.0, 0.0, (f0 + (1.0 - f0) * f5) * (7.0 / (f5 * f)) * (1.0 - tint))


def dielectric_f0_eta(ior: float, specular_ior_level: float) -> tuple[float, float]:
    """(f0, η) of the dielectric specular layer: f0 from the IOR, times 2L when L != 0.5 (η re-derived)."""
    eta = float(ior)
    f0 = float(F0_from_ior(eta))
    if specular_ior_level != 0.5:
        f0 *= 2.0 * specular_ior_level
        eta = float(ior_from_F0(f0))
        if ior < 1.0:
            eta = 1.0 / eta
    return f0, eta


def real_curve_s(cos_i, eta):
    """Generalized Schlick's "real curve" interpolation factor saturate((F_η(c) - F0_η)/(1 - F0_η))."""
    f0 = F0_from_ior(eta)
    return np.clip((fresnel_dielectric(cos_i, eta) - f0) / max(1.0 - f0, 1e-12), 0.0, 1.0)


@functools.lru_cache(maxsize=8)
def _s_slice(k: int, n: int = 48) -> np.ndarray:
    """S on Cycles' (rough, μ) 16 x 16 nodes of z node k (η = ior_from_F0(z⁴), z = clamp(k/15, 1e-4, 0.99))."""
    z = min(max(k / (S_TABLE - 1), 1e-4), 0.99)
    eta = float(ior_from_F0(z ** 4))
    nodes = np.arange(S_TABLE) / (S_TABLE - 1)
    mu = np.maximum(nodes, 1e-4)
    out = np.empty((S_TABLE, S_TABLE))
    u = (np.arange(n) + 0.5) / n
    u1, u2 = [a.ravel() for a in np.meshgrid(u, u, indexing="ij")]
    for i, r in enumerate(np.maximum(nodes, 1e-4)):
        h, view, lz = multiscatter.vndf_reflect(r * r, mu, u1, u2)
        vh = np.sum(view * h, -1)
        out[i] = np.where(lz > 0, real_curve_s(vh, eta), 0.0).mean(1)
    return out


def gen_schlick_ior_s(rough, mu, ior: float):
    """Cycles ``lookup_table_read_3D(rough, μ, z, ggx_gen_schlick_ior_s)``: trilinear on the 16³ nodes, z =
    sqrt(|η - 1|/(η + 1)).  ``rough``, ``mu`` broadcast; one η."""
    k, t = lookup_index(np.sqrt(abs((ior - 1.0) / (ior + 1.0))), S_TABLE)
    k, t = int(k), float(t)
    lo = lookup_table_read_2D(_s_slice(k), rough, mu)
    return lo if t == 0.0 else (1 - t) * lo + t * lookup_table_read_2D(_s_slice(k + 1), rough, mu)


def principled_supported(inputs: dict) -> bool:
    """True when the node's other inputs are at values the twin covers exactly (weights 0, film 0, alpha 1, ...).
    ``inputs``: {socket name: default value} of the unlinked sockets that matter."""
    zero = ("Coat Weight", "Sheen Weight", "Transmission Weight", "Subsurface Weight", "Thin Film Thickness",
            "Diffuse Roughness", "Anisotropic")
    return all(abs(float(inputs.get(k, 0.0))) <= 1e-6 for k in zero) and float(inputs.get("Alpha", 1.0)) >= 1.0 - 1e-6
