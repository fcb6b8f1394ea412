"""Small-scale BRDF models for the bi-scale pipeline (Wu et al. 2011, §3.5, §6, Table 3).

Every model is isotropic, so a BRDF rotated to a facet normal n (the paper's
f_r(n, ωi, ωo)) depends only on the three cosines  ci = n·ωi, co = n·ωo, cio = ωi·ωo;
no local frames are needed.  A material is split into *lobes*: a scalar BRDF times an
RGB colour, f_r,rgb = Σ_l colour_l · f_l(ci, co, cio).  Each lobe gets its own
pre-rotated matrix M (eq. 9), so colours are exact for the analytic models
(e.g. Schlick Fresnel F0 + (1-F0)(1-c)^5 = F0·[1-(1-c)^5] + 1·(1-c)^5 is two lobes).
Tabulated RGB BRDFs use the paper's principal-direction trick (§3.7): one lobe whose
colour is the first principal direction d of the RGB samples and whose scalar values are
the samples projected onto d.

Materials are dicts (ranges checked, ``ValueError`` otherwise):

* ``{"model": "lambert", "albedo": rgb}``
* ``{"model": "blinn_phong", "kd": rgb, "ks": rgb, "exponent": e}`` — normalised
  specular lobe ks (e+8)/(8π) (n·h)^e
* ``{"model": "cook_torrance", "alpha": a, "F0": rgb, "kd": rgb, "ks": s,
  "distribution": "beckmann" | "ggx" | "beckmann_smith", "fresnel": "schlick" | "none",
  "multiscatter": False | True}`` — D G F / (4 ci co); Beckmann uses the original
  Cook-Torrance V-cavity G, GGX the height-correlated Smith G, ``beckmann_smith`` Cycles' Beckmann (height-correlated
  Smith G with Walter's rational Λ, ``precompute.cycles.beckmann``).  ``fresnel="none"``: F = 1 and the colour
  ks·F0 at every angle (Cycles' Glossy BSDF, which has no Fresnel); ``multiscatter=True`` (GGX with ``fresnel="none"``
  only): Cycles' *Multiscatter GGX* — the single-scatter lobe times 1 + Fms (1 - E(co)) / E(co) of the view cosine
  co (``precompute.cycles.multiscatter``; not reciprocal, as in Cycles)
* ``{"model": "principled", "base_color": rgb, "metallic": m, "roughness": r, "ior": η,
  "specular_ior_level": L, "specular_tint": rgb, "multiscatter": True | False}`` — Cycles' Principled BSDF of an
  opaque surface (no coat, sheen, transmission, subsurface, thin film; ``precompute.cycles.principled``): an
  F82-tint GGX metal (weight m), a dielectric GGX specular with the real Fresnel curve and a Lambert base attenuated
  by that specular's albedo estimate (weight 1 - m); ``multiscatter`` (the node's default) as for cook_torrance
* ``{"model": "ward", "alpha": a, "rho_d": rgb, "rho_s": rgb}`` — isotropic Ward
* ``{"model": "tabulated", "table": (n_theta, n_theta, n_phi, 3)}`` — samples at
  θi, θo on linspace(0, π/2, n_theta) and φd = |φi-φo| on linspace(0, π, n_phi), trilinear

rgb may be a scalar or a 3-sequence in [0, 1].  Units: BRDF values in 1/sr.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..cycles import beckmann as _cycles_beckmann
from ..cycles import multiscatter as _multiscatter
from ..cycles import principled as _principled

__all__ = ["Lobe", "material_lobes", "eval_material", "MODELS"]

MODELS = ("lambert", "blinn_phong", "cook_torrance", "ward", "tabulated", "principled")
#: ``cook_torrance`` distributions (see the module doc)
DISTRIBUTIONS = ("beckmann", "ggx", "beckmann_smith")


@dataclass(frozen=True)
class Lobe:
    """A scalar isotropic BRDF f(ci, co, cio) (1/sr) with an RGB colour; ``key`` identifies
    the scalar function for caching M."""
    key: str
    f: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    colour: tuple
    #: False for Cycles' view-dependent factors (Multiscatter GGX's 1/E(co), the Principled base's layering):
    #: f(ci, co, cio) != f(co, ci, cio); the reciprocal matrix M (eq. 9) then takes the symmetric part
    reciprocal: bool = True
    #: the lobes of one microfacet material share their terms (half vector, D G, Fresnel's (1 - ωi·h)⁵, E(co)):
    #: ``shared(ci, co, cio)`` makes them for a batch (``_MicrofacetTerms``), ``of_shared(terms)`` is this lobe's
    #: value from them and ``f`` = of_shared ∘ shared; ``eval_material`` makes the terms once for all such lobes
    shared: Callable | None = None
    of_shared: Callable | None = None

    def cache_key(self):
        return {"lobe": self.key}

    def __call__(self, ci, co, cio):
        return self.f(ci, co, cio)


def _rgb(mat, name, default, lo=0.0, hi=1.0):
    v = mat.get(name, default)
    a = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)) if np.ndim(v) == 0 else np.asarray(v, np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or a.min() < lo or a.max() > hi:
        raise ValueError(f"{mat.get('model')}.{name}: expected a number or 3 numbers in [{lo}, {hi}], got {v!r}")
    return tuple(float(x) for x in a)


def _num(mat, name, default, lo, hi):
    v = mat.get(name, default)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{mat.get('model')}.{name}: expected a number in [{lo}, {hi}], got {v!r}") from None
    if not (np.isfinite(x) and lo <= x <= hi):
        raise ValueError(f"{mat.get('model')}.{name}: expected a number in [{lo}, {hi}], got {v!r}")
    return x


def _new(*arrays):
    """An empty float64 array of the arrays' broadcast shape (0-d included), for ufuncs writing in place."""
    return np.empty(np.broadcast_shapes(*(np.shape(a) for a in arrays)))


def _half(ci, co, cio):
    """n·h and ωi·h for h = (ωi+ωo)/|ωi+ωo| from the three cosines: |ωi+ωo| = L = √(2 + 2 cio), n·h = (ci + co)/L,
    ωi·h = L/2 (clamped to [0, 1]; in place, the values of the plain expressions)."""
    L = np.multiply(2.0, cio, out=_new(cio))
    L += 2.0
    np.sqrt(np.maximum(L, 1e-300, out=L), out=L)
    nh = np.add(ci, co, out=_new(ci, co, cio))
    nh /= L
    np.clip(nh, 0.0, 1.0, out=nh)
    L *= 0.5
    return nh, np.clip(L, 0.0, 1.0, out=L)


def _ggx_lambda(c, a2: float):
    """Smith Λ of GGX at a direction of cosine c (> 0): (√(1 + α² tan²θ) - 1) / 2, tan²θ = (1 - c²)/c² (in place)."""
    t = np.maximum(c, 1e-12, out=_new(c))
    t *= t
    u = np.subtract(1.0, t, out=_new(t))
    u *= a2
    u /= t
    u += 1.0
    np.sqrt(u, out=u)
    u -= 1.0
    u /= 2
    return u


def _lambert(ci, co, cio):
    return np.full(np.broadcast(ci, co, cio).shape, 1.0 / np.pi)


def _blinn_phong(e):
    def f(ci, co, cio):
        nh, _ = _half(ci, co, cio)
        return (e + 8.0) / (8.0 * np.pi) * nh ** e
    return f


class _MicrofacetTerms:
    """What the microfacet lobes of one material share at one batch of cosines (ci, co, cio), each made on first use
    and then reused by every lobe (``eval_material``: once per batch, not once per lobe):

    - ``nh``, ``vh``: n·h and ωi·h of the half vector; ``x`` = 1 - ωi·h, ``x5`` = x⁵ (Schlick's Fresnel weight);
    - ``DG``: distribution x shadowing D G (``dist``: "ggx" height-correlated Smith, "beckmann" the V-cavity G,
      "beckmann_smith" Cycles' Beckmann), ``four_cc`` = 4 ci co, ``ss`` = D G / (4 ci co): the microfacet BRDF with
      F = 1 (single-scatter GGX for "ggx"), 1/sr;
    - ``E``: Cycles' ggx_E(√α, co) (``precompute.cycles.multiscatter``), ``ms`` = (1 - E) / E: Multiscatter GGX's
      extra part per unit Fms (co = the view's cosine, Cycles' ``mu``);
    - ``s``: the real Fresnel curve's factor s(ωi·h) for ``eta`` (``precompute.cycles.principled.real_curve_s``).

    ``ci``, ``co``, ``cio`` broadcast; terms of co alone keep co's shape."""

    def __init__(self, alpha: float, dist: str, ci, co, cio, eta: float = 1.0):
        self.alpha, self.dist, self.eta = alpha, dist, eta
        self.ci, self.co, self.cio = ci, co, cio

    @functools.cached_property
    def _nh_vh(self):
        return _half(self.ci, self.co, self.cio)

    @property
    def nh(self):
        return self._nh_vh[0]

    @property
    def vh(self):
        return self._nh_vh[1]

    @functools.cached_property
    def x(self):
        return 1.0 - self.vh

    @functools.cached_property
    def x5(self):                               # x⁵ as products: pow() took 3.7 s of a 35 s bake (its slow cases)
        x2 = self.x * self.x
        return x2 * x2 * self.x

    @functools.cached_property
    def DG(self):
        a2 = self.alpha * self.alpha
        nh = self.nh
        c2 = np.maximum(nh * nh, 1e-150, out=_new(nh))
        if self.dist == "ggx":                  # D = α² / (π (c² (α² - 1) + 1)²), G = 1 / (1 + Λi + Λo); in place
            c2 *= a2 - 1.0                      # (the bake's BRDF time is mostly here), the same values
            c2 += 1.0
            np.square(c2, out=c2)
            c2 *= np.pi
            D = np.divide(a2, c2, out=c2)
            G = _ggx_lambda(self.ci, a2)
            G += 1.0
            G = np.add(G, _ggx_lambda(self.co, a2), out=_new(self.ci, self.co))
            return np.multiply(D, np.divide(1.0, G, out=G), out=D)
        ci_ = np.maximum(self.ci, 1e-12)
        co_ = np.maximum(self.co, 1e-12)
        D = np.exp(-(1.0 - c2) / (c2 * a2)) / (np.pi * a2 * c2 * c2)
        if self.dist == "beckmann":             # the original Cook-Torrance V-cavity G
            vh_ = np.maximum(self.vh, 1e-12)
            G = np.minimum(1.0, np.minimum(2 * nh * co_ / vh_, 2 * nh * ci_ / vh_))
        else:                                   # "beckmann_smith": Cycles' bsdf_D<BECKMANN>, G2 = 1 / (1 + Λi + Λo)
            li = _cycles_beckmann.beckmann_lambda_from_sqr_alpha_tan_n(a2 * (1 - ci_ * ci_) / (ci_ * ci_))
            lo = _cycles_beckmann.beckmann_lambda_from_sqr_alpha_tan_n(a2 * (1 - co_ * co_) / (co_ * co_))
            G = 1.0 / (1.0 + li + lo)
        return D * G

    @functools.cached_property
    def four_cc(self):
        return 4.0 * np.maximum(self.ci, 1e-12) * np.maximum(self.co, 1e-12)

    @functools.cached_property
    def ss(self):
        return self.DG / self.four_cc

    @functools.cached_property
    def E(self):
        return _multiscatter.ggx_E(np.sqrt(self.alpha), self.co)

    @functools.cached_property
    def ms(self):
        E = np.maximum(self.E, 1e-6)
        return (1.0 - E) / E

    @functools.cached_property
    def s(self):
        return _principled.real_curve_s(self.vh, self.eta)


def _shared_lobe(key: str, terms, of_terms, colour, reciprocal: bool = True) -> Lobe:
    """A lobe ``of_terms(terms(ci, co, cio))`` whose terms the material's other lobes share (``Lobe.shared``)."""
    return Lobe(key, lambda ci, co, cio: of_terms(terms(ci, co, cio)), tuple(float(x) for x in colour), reciprocal,
                terms, of_terms)


def _schlick_part(part):
    """Schlick's Fresnel F0 (1 - x⁵) + x⁵ (x = 1 - ωi·h) as a function of the terms: the whole term for a float F0
    ``part`` (grey), its "f0" part 1 - x⁵ or its "one" part x⁵ (a coloured F0: two lobes), or "none" (F = 1)."""
    if isinstance(part, float):
        return lambda T: part * (1.0 - T.x5) + T.x5
    return {"f0": lambda T: 1.0 - T.x5, "one": lambda T: T.x5, "none": lambda T: 1.0}[part]


def _microfacet_of(part):
    """The microfacet BRDF D G F / (4 ci co) (1/sr) as a function of the terms, F = ``_schlick_part(part)``."""
    F = _schlick_part(part)
    return lambda T: T.DG * F(T) / T.four_cc


def _microfacet(alpha, dist, part):
    """``_microfacet_of(part)`` as a scalar lobe f(ci, co, cio) of its own (no terms shared)."""
    of = _microfacet_of(part)
    return lambda ci, co, cio: of(_MicrofacetTerms(alpha, dist, ci, co, cio))


def _principled_lobes(mat) -> list:
    """Lobes of Cycles' Principled BSDF (opaque; see ``precompute.cycles.principled``), each GGX part with its
    Multiscatter copy when ``multiscatter``; all share one ``_MicrofacetTerms`` per batch (the metal's and the
    dielectric specular's GGX, Fresnel and E(co), the base's layering)."""
    pr = _principled
    dflt = pr.PRINCIPLED_DEFAULTS
    b = np.asarray(_rgb(mat, "base_color", dflt["base_color"]))
    metal = _num(mat, "metallic", dflt["metallic"], 0.0, 1.0)
    r = _num(mat, "roughness", dflt["roughness"], 0.0, 1.0)
    ior = _num(mat, "ior", dflt["ior"], 1e-3, 1e3)
    level = _num(mat, "specular_ior_level", dflt["specular_ior_level"], 0.0, 1e3)
    tint = np.asarray(_rgb(mat, "specular_tint", dflt["specular_tint"], 0.0, 1e3))
    multi = mat.get("multiscatter", dflt["multiscatter"])
    if not isinstance(multi, (bool, np.bool_)):
        raise ValueError(f"principled.multiscatter: expected True or False, got {multi!r}")
    alpha = max(r * r, 1e-3)
    Ea = float(_multiscatter.ggx_E_avg(np.sqrt(alpha)))
    key = f"pr:a={alpha!r}"
    w = 1.0 - metal
    f0, eta = pr.dielectric_f0_eta(ior, level) if w > 0 else (0.0, 1.0)
    terms = functools.partial(_MicrofacetTerms, alpha, "ggx", eta=eta)
    out: list[Lobe] = []

    def add(name, of, colour, Fss=None):
        out.append(_shared_lobe(f"{key}:{name}", terms, of, colour))
        if multi and Fss is not None:       # + colour Fms f (1 - E) / E
            Fms = _multiscatter.F_ms(Fss, Ea)
            out.append(_shared_lobe(f"{key}:{name}:ms", terms, lambda T: of(T) * T.ms, np.asarray(colour) * Fms,
                                    reciprocal=False))

    if metal > 0:                           # F82 tint: b + (1 - b) x⁵ - B c x⁶ (c = ωi·h, x = 1 - c)
        B = pr.f82_tint_B(b, np.minimum(tint, 1.0))
        Fss = b + (1.0 - b) / 21.0 - B / 126.0
        add("metal:f0", lambda T: T.ss * (1.0 - T.x5), metal * b, Fss)
        add("metal:one", lambda T: T.ss * T.x5, metal * np.ones(3), Fss)
        if np.any(B != 0):
            add("metal:B", lambda T: T.ss * (T.vh * (T.x5 * T.x)), -metal * B, Fss)
    if w > 0:
        f0t = np.clip(f0 * tint, 0.0, 1.0)
        if eta != 1.0:                      # F = mix(f0 t, 1, s(c)), s the real curve's factor
            f0r = float(pr.F0_from_ior(eta))
            s_avg = float(np.clip((pr.fresnel_dielectric_Fss(eta) - f0r) / max(1.0 - f0r, 1e-12), 0.0, 1.0))
            Fss = f0t + (1.0 - f0t) * s_avg
            Fms = _multiscatter.F_ms(Fss, Ea) if multi else np.zeros(3)
            if np.all(f0t == f0t[0]):       # grey (an untinted specular): one scalar lobe, F (1 + Fms m) folded in
                g0, gm = float(f0t[0]), float(Fms[0])

                def spec(T):
                    return T.ss * (g0 + (1.0 - g0) * T.s) * ((1.0 + gm * T.ms) if multi else 1.0)
                out.append(_shared_lobe(f"{key}:spec:{eta!r}:{g0!r}:{multi}", terms, spec, (w, w, w),
                                        reciprocal=not multi))
            else:
                add(f"spec:{eta!r}:f0", lambda T: T.ss * (1.0 - T.s), w * f0t, Fss)
                add(f"spec:{eta!r}:one", lambda T: T.ss * T.s, w * np.ones(3), Fss)

            def layered(T):                 # closure_layering_weight: 1 - max_c albedo_c, the specular's albedo
                S = pr.gen_schlick_ior_s(r, T.co, eta)[..., None]           # estimate mix(f0 t, 1, S(r, μ, z))
                A = f0t + (1.0 - f0t) * S                                   # x its weight: Multiscatter's
                if multi:                                                   # darkening E + Fms (1 - E)
                    E = T.E[..., None]
                    A = A * (E + Fms * (1.0 - E))
                return np.clip(1.0 - A.max(-1), 0.0, 1.0) / np.pi
            out.append(_shared_lobe(f"{key}:diffuse:{eta!r}:{tuple(f0t)!r}:{multi}", terms, layered, w * b,
                                    reciprocal=False))
        else:
            out.append(Lobe("lambert", _lambert, tuple(float(x) for x in w * b)))
    return out


def _ward(alpha):
    a2 = alpha * alpha

    def f(ci, co, cio):
        nh, _ = _half(ci, co, cio)
        c2 = np.maximum(nh * nh, 1e-150)
        return np.exp(-(1.0 - c2) / (c2 * a2)) / (4.0 * np.pi * a2 * np.sqrt(np.maximum(ci * co, 1e-24)))
    return f


def _tabulated(tab):
    """Trilinear interpolation of a scalar table over (θi, θo, φd)."""
    nt, _, nphi = tab.shape

    def f(ci, co, cio):
        ci_ = np.clip(ci, 0.0, 1.0)
        co_ = np.clip(co, 0.0, 1.0)
        si, so = np.sqrt(1 - ci_ ** 2), np.sqrt(1 - co_ ** 2)
        den = si * so
        cphi = np.where(den > 1e-12, (cio - ci_ * co_) / np.where(den > 1e-12, den, 1.0), 1.0)
        coords = [np.arccos(ci_) / (np.pi / 2) * (nt - 1), np.arccos(co_) / (np.pi / 2) * (nt - 1),
                  np.arccos(np.clip(cphi, -1, 1)) / np.pi * (nphi - 1)]
        sizes = (nt, nt, nphi)
        i0, fr = [], []
        for x, n in zip(coords, sizes):
            x = np.clip(x, 0, n - 1)
            k = np.minimum(np.floor(x).astype(np.int64), max(n - 2, 0))
            i0.append(k)
            fr.append(x - k)
        out = 0.0
        for a in (0, 1):
            for b in (0, 1):
                for c in (0, 1):
                    w = (fr[0] if a else 1 - fr[0]) * (fr[1] if b else 1 - fr[1]) * (fr[2] if c else 1 - fr[2])
                    ia = np.minimum(i0[0] + a, nt - 1)
                    ib = np.minimum(i0[1] + b, nt - 1)
                    ic = np.minimum(i0[2] + c, nphi - 1)
                    out = out + w * tab[ia, ib, ic]
        return out
    return f


def _digest(a):
    return hashlib.sha256(np.ascontiguousarray(a, np.float64).tobytes()).hexdigest()[:16]


def material_lobes(mat: dict) -> list[Lobe]:
    """Split a material dict (see module docstring) into scalar lobes with RGB colours."""
    if not isinstance(mat, dict) or "model" not in mat:
        raise ValueError(f"materials: each material must be a dict with a 'model' in {MODELS}, got {mat!r}")
    model = mat["model"]
    lobes: list[Lobe] = []
    if model == "lambert":
        lobes.append(Lobe("lambert", _lambert, _rgb(mat, "albedo", 0.8)))
    elif model == "blinn_phong":
        e = _num(mat, "exponent", 20.0, 0.0, 1e4)
        kd, ks = _rgb(mat, "kd", 0.5), _rgb(mat, "ks", 0.5)
        if max(kd) > 0:
            lobes.append(Lobe("lambert", _lambert, kd))
        lobes.append(Lobe(f"blinn_phong:e={e!r}", _blinn_phong(e), ks))
    elif model == "cook_torrance":
        alpha = _num(mat, "alpha", 0.2, 1e-3, 1.0)
        dist = mat.get("distribution", "beckmann")
        if dist not in DISTRIBUTIONS:
            raise ValueError(f"cook_torrance.distribution: expected one of {DISTRIBUTIONS}, got {dist!r}")
        fresnel = mat.get("fresnel", "schlick")
        if fresnel not in ("schlick", "none"):
            raise ValueError(f"cook_torrance.fresnel: expected 'schlick' or 'none', got {fresnel!r}")
        multi = mat.get("multiscatter", False)
        if not isinstance(multi, (bool, np.bool_)):
            raise ValueError(f"cook_torrance.multiscatter: expected True or False, got {multi!r}")
        if multi and (dist != "ggx" or fresnel != "none"):
            raise ValueError("cook_torrance.multiscatter: True needs distribution 'ggx' and fresnel 'none' "
                             f"(Cycles' Multiscatter GGX Glossy BSDF), got {dist!r} / {fresnel!r}")
        F0 = _rgb(mat, "F0", 0.95)
        ks = _num(mat, "ks", 1.0, 0.0, 1.0)
        kd = _rgb(mat, "kd", 0.0)
        if max(kd) > 0:
            lobes.append(Lobe("lambert", _lambert, kd))
        terms = functools.partial(_MicrofacetTerms, alpha, dist)
        ct = f"ct:{dist}:a={alpha!r}"
        if fresnel == "none":   # Cycles' Glossy BSDF: colour c = ks F0 at every angle
            c = np.asarray(F0) * ks
            lobes.append(_shared_lobe(f"{ct}:F=1", terms, lambda T: T.ss, c))
            if multi:           # + c Fms(c) f_ss (1 - E) / E  (Kulla & Conty 2017 appendix; Cycles 4.0+)
                Ea = float(_multiscatter.ggx_E_avg(np.sqrt(alpha)))
                lobes.append(_shared_lobe(f"{ct}:ms", terms, lambda T: T.ss * T.ms, c * _multiscatter.F_ms(c, Ea),
                                          reciprocal=False))
        elif min(F0) == max(F0):  # grey Fresnel: one lobe with the full Schlick term
            lobes.append(_shared_lobe(f"{ct}:F0={F0[0]!r}", terms, _microfacet_of(float(F0[0])), (ks, ks, ks)))
        else:                     # coloured Schlick F0: its F0 and 1 parts, one D G for both
            lobes.append(_shared_lobe(f"{ct}:f0part", terms, _microfacet_of("f0"), tuple(ks * c for c in F0)))
            lobes.append(_shared_lobe(f"{ct}:onepart", terms, _microfacet_of("one"), (ks, ks, ks)))
    elif model == "principled":
        lobes += _principled_lobes(mat)
    elif model == "ward":
        alpha = _num(mat, "alpha", 0.3, 1e-3, 1.0)
        rd, rs = _rgb(mat, "rho_d", 0.0), _rgb(mat, "rho_s", 0.5)
        if max(rd) > 0:
            lobes.append(Lobe("lambert", _lambert, rd))
        lobes.append(Lobe(f"ward:a={alpha!r}", _ward(alpha), rs))
    elif model == "tabulated":
        tab = np.asarray(mat.get("table"), dtype=np.float64)
        if tab.ndim != 4 or tab.shape[3] != 3 or tab.shape[0] != tab.shape[1] or tab.shape[0] < 2 or tab.shape[2] < 1:
            raise ValueError(f"tabulated.table: expected shape (n_theta>=2, n_theta, n_phi>=1, 3), got {tab.shape}")
        if not np.all(np.isfinite(tab)) or tab.min() < 0:
            raise ValueError("tabulated.table: values must be finite and >= 0 (1/sr)")
        flat = tab.reshape(-1, 3)
        # §3.7: first principal direction of the RGB samples (uncentred, so that d spans the mean colour)
        _, _, vt = np.linalg.svd(flat[:: max(1, len(flat) // 20000)], full_matrices=False)
        d = vt[0] * (1.0 if vt[0].sum() >= 0 else -1.0)
        proj = np.maximum(flat @ d, 0.0).reshape(tab.shape[:3])
        lobes.append(Lobe(f"tabulated:{_digest(proj)}:{_digest(d)}", _tabulated(proj), tuple(float(x) for x in d)))
    else:
        raise ValueError(f"materials: unknown model {model!r}; expected one of {MODELS}")
    return lobes


def _dot(a, b):
    """a · b over the last axis (length 3), broadcast, without the (..., 3) product array."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def eval_material(mat_or_lobes, n: np.ndarray, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """RGB f_r(n, ωi, ωo) (1/sr), shape (..., 3); zero where ωi or ωo is below the facet
    (the paper's clamped cosines).  n, wi, wo are unit vectors broadcastable to (..., 3)."""
    lobes = material_lobes(mat_or_lobes) if isinstance(mat_or_lobes, dict) else mat_or_lobes
    ci, co, cio = _dot(n, wi), _dot(n, wo), _dot(wi, wo)
    ok = (ci > 0) & (co > 0)
    # the lobes see cosines > 0 (1 elsewhere: those entries are 0 below), each cosine in its own shape (a term of the
    # view alone, E(co) or the Principled base's layering, is made per view, not per light x view); lobes sharing
    # terms (``Lobe.shared``: one microfacet material's half vector, D G, Fresnel, E) get them made once
    ci_, co_ = np.where(ci > 0, ci, 1.0), np.where(co > 0, co, 1.0)
    terms, values = {}, []
    for lobe in lobes:
        if lobe.shared is None:
            values.append(np.asarray(lobe(ci_, co_, cio)))
        else:
            if lobe.shared not in terms:
                terms[lobe.shared] = lobe.shared(ci_, co_, cio)
            values.append(np.asarray(lobe.of_shared(terms[lobe.shared])))
    shape = np.broadcast_shapes(ok.shape, *(v.shape for v in values))
    out = np.zeros(shape + (3,))
    for c in range(3):                      # Σ_lobes colour x value, channel by channel (no (..., 3) temporaries)
        acc = np.zeros(shape)
        for v, lobe in zip(values, lobes):
            acc += v * lobe.colour[c]
        out[..., c] = np.where(ok, acc, 0.0)
    return out
