"""Fresnel reflectance for the micro-BRDF inside a scratch (Raymond et al. 2016, §4.2).

The scratch simulation (``precompute.scratch_brdf``) attenuates a path at *every*
specular bounce by a Fresnel factor evaluated with the 3D angle of incidence.  A
Fresnel model here is a small immutable object that maps ``cos(incidence)`` arrays
(any shape ``S``, values in [0, 1]) to reflectance of shape ``S + (C,)`` where ``C``
is the number of colour channels (1 = mono, 3 = RGB).  So ``simulate`` handles mono
and RGB the same way.

Models
- ``schlick(ior=1.5)`` / ``schlick(f0=...)``: Schlick 1994, ``F = F0 + (1-F0)(1-c)^5``,
  ``F0 = ((n-1)/(n+1))^2`` for a dielectric in air (the paper's dielectric choice).
- ``lazanyi(n, k)``: Lazanyi & Szirmay-Kalos 2005 ("Fresnel term approximations for
  metals", WSCG), ``F = ((n-1)^2 + 4 n (1-c)^5 + k^2) / ((n+1)^2 + k^2) - a c (1-c)^alpha``
  (the paper's conductor choice; ``a = 0`` by default, i.e. the plain metal-Schlick form).
- ``conductor(n, k)``: exact unpolarised Fresnel reflectance of a conductor with complex
  IOR ``n + i k`` seen from air (``(Rs + Rp) / 2``); ``k = 0`` gives the exact dielectric.
- ``conductor_preset(name)``: ``conductor`` with tabulated n, k at R/G/B = 650/550/450 nm.
- ``tabulated(model, tol=1e-5)``: ``model`` sampled on a uniform grid of cos θ, linear in between, the
  grid the coarsest (power of two) whose interpolation error against the exact formula is below ``tol``:
  what the tracer evaluates at every bounce (about 4x cheaper than the exact conductor formula).

Every model gives ``F(cos=0) = 1`` (grazing), which the scratch BRDF relies on:
``rho_s(theta_o = pi/2) = rho_m``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Fresnel",
    "Schlick",
    "Lazanyi",
    "Conductor",
    "schlick",
    "lazanyi",
    "conductor",
    "conductor_preset",
    "Tabulated",
    "tabulated",
    "PRESETS",
    "WAVELENGTHS_NM",
]

#: wavelengths (nm) at which the R, G, B channels of the presets are tabulated
WAVELENGTHS_NM = (650.0, 550.0, 450.0)

# Complex refractive index n + i k at 650 / 550 / 450 nm (R, G, B), read off the cited
# tables (values quoted from memory to ~2 digits; good enough for appearance, not metrology).
PRESETS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    # Fe: Johnson & Christy, Phys. Rev. B 9, 5056 (1974).  Red matches Raymond et al. 2016,
    # §4.2 ("n = 2.91, k = 3.09 ... iron at a wavelength of 650nm").
    "iron": ((2.91, 2.89, 2.55), (3.09, 2.93, 2.92)),
    # Au: Johnson & Christy, Phys. Rev. B 6, 4370 (1972).
    "gold": ((0.166, 0.43, 1.40), (3.15, 2.46, 1.88)),
    # Cu: Johnson & Christy (1972).
    "copper": ((0.214, 0.94, 1.24), (3.67, 2.58, 2.40)),
    # Al: Rakic, Appl. Opt. 37, 5271 (1998) (Lorentz-Drude fit).
    "aluminium": ((1.49, 0.96, 0.62), (7.82, 6.69, 5.47)),
    # Ag: Johnson & Christy (1972).
    "silver": ((0.14, 0.12, 0.13), (4.15, 3.45, 2.60)),
}
_ALIASES = {"aluminum": "aluminium", "fe": "iron", "au": "gold", "cu": "copper", "al": "aluminium", "ag": "silver"}


def _channels(value, name: str, *, low: float, high: float = np.inf, low_open: bool = False) -> np.ndarray:
    """A scalar or a 3-tuple as a float64 array of 1 or 3 channels, range-checked."""
    try:
        a = np.atleast_1d(np.asarray(value, dtype=np.float64))
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number or 3 numbers (R, G, B), got {value!r}") from None
    if a.ndim != 1 or a.size not in (1, 3):
        raise ValueError(f"{name}: expected a scalar or 3 values (R, G, B), got shape {np.shape(value)}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be finite, got {a.tolist()}")
    bad = (a <= low) if low_open else (a < low)
    if np.any(bad) or np.any(a > high):
        lo = "(" if low_open else "["
        raise ValueError(f"{name}: allowed range is {lo}{low}, {high}], got {a.tolist()}")
    return a


def _cos(cos_theta) -> np.ndarray:
    c = np.asarray(cos_theta, dtype=np.float64)
    return np.clip(np.nan_to_num(c, nan=0.0), 0.0, 1.0)[..., None]


class Fresnel:
    """Base class: ``F(cos_theta) -> reflectance[..., C]`` with values in [0, 1]."""

    channels: int = 1

    def __call__(self, cos_theta) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def cache_key(self) -> dict:  # pragma: no cover - abstract
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class Schlick(Fresnel):
    """Schlick 1994: ``F = F0 + (1 - F0)(1 - cos)^5``, per channel (Raymond et al. 2016, §4.2)."""

    f0: np.ndarray

    @property
    def channels(self) -> int:
        return int(self.f0.size)

    def __call__(self, cos_theta) -> np.ndarray:
        c = _cos(cos_theta)
        return self.f0 + (1.0 - self.f0) * (1.0 - c) ** 5

    def cache_key(self) -> dict:
        return {"model": "schlick", "f0": [float(v) for v in self.f0]}


@dataclass(frozen=True, eq=False)
class Lazanyi(Fresnel):
    """Lazanyi & Szirmay-Kalos 2005 metal approximation (Raymond et al. 2016, §4.2).

    ``F = ((n-1)^2 + 4 n (1-c)^5 + k^2) / ((n+1)^2 + k^2) - a c (1-c)^alpha``, clipped to [0, 1].
    """

    n: np.ndarray
    k: np.ndarray
    a: np.ndarray
    alpha: float = 6.0

    @property
    def channels(self) -> int:
        return int(max(self.n.size, self.k.size, self.a.size))

    def __call__(self, cos_theta) -> np.ndarray:
        c = _cos(cos_theta)
        n, k = self.n, self.k
        f = ((n - 1.0) ** 2 + 4.0 * n * (1.0 - c) ** 5 + k**2) / ((n + 1.0) ** 2 + k**2)
        f = f - self.a * c * (1.0 - c) ** self.alpha
        return np.clip(f, 0.0, 1.0)

    def cache_key(self) -> dict:
        return {"model": "lazanyi", "n": [float(v) for v in self.n], "k": [float(v) for v in self.k],
                "a": [float(v) for v in self.a], "alpha": float(self.alpha)}


@dataclass(frozen=True, eq=False)
class Conductor(Fresnel):
    """Exact unpolarised Fresnel reflectance from air onto complex IOR ``eta = n + i k``.

    With ``s = sqrt(eta^2 - sin^2)`` (principal root):
    ``Rs = |c - s|^2 / |c + s|^2``, ``Rp = |eta^2 c - s|^2 / |eta^2 c + s|^2``, ``F = (Rs + Rp) / 2``
    (Born & Wolf, Principles of Optics, §14.2).
    """

    n: np.ndarray
    k: np.ndarray
    name: str = ""

    @property
    def channels(self) -> int:
        return int(max(self.n.size, self.k.size))

    def __call__(self, cos_theta) -> np.ndarray:
        # the same formula in real arithmetic (Pharr et al., PBRT 3rd ed. §8.2.1, FrConductor):
        # with s = a + i b, a^2 + b^2 = |eta^2 - sin^2| and a = sqrt((|.| + Re(.)) / 2)
        c = _cos(cos_theta)
        c2 = c * c
        s2 = 1.0 - c2
        n2, k2 = self.n * self.n, self.k * self.k
        t0 = (n2 - k2 - 1.0) + c2  # = n^2 - k^2 - sin^2 without the cancellation of 1 - cos^2 near grazing
        a2b2 = np.sqrt(t0 * t0 + 4.0 * n2 * k2)
        a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
        t1 = a2b2 + c2
        t2 = 2.0 * c * a
        # t1 + t2 = 0 only at exact grazing (c = 0) with eta = 1 (n = 1, k = 0, no interface): there
        # F takes its grazing limit 1, like every other model (the limit n -> 1 of F(cos = 0) = 1)
        den = t1 + t2
        rs = np.where(den > 0, (t1 - t2) / np.where(den > 0, den, 1.0), 1.0)
        t3 = c2 * a2b2 + s2 * s2
        t4 = t2 * s2
        den_p = t3 + t4  # 0 only where n^2 and k^2 underflow at normal incidence: there rp = rs
        rp = rs * np.where(den_p > 0, (t3 - t4) / np.where(den_p > 0, den_p, 1.0), 1.0)
        return np.clip(0.5 * (rs + rp), 0.0, 1.0)

    def cache_key(self) -> dict:
        return {"model": "conductor", "n": [float(v) for v in self.n], "k": [float(v) for v in self.k]}


@dataclass(frozen=True, eq=False)
class Tabulated(Fresnel):
    """A Fresnel model sampled at ``cos = i / N`` (i = 0..N), linear in between (``tabulated``).

    ``value [N+1, C]`` the samples, ``slope [N, C]`` their differences, ``source`` the exact model,
    ``error`` the measured worst absolute error against it (``tabulated``).
    """

    value: np.ndarray
    slope: np.ndarray
    source: Fresnel
    error: float

    @property
    def channels(self) -> int:
        return int(self.value.shape[1])

    def __call__(self, cos_theta) -> np.ndarray:
        c = np.asarray(cos_theta, dtype=np.float64)
        n = self.slope.shape[0]
        x = np.fmin(np.fmax(c, 0.0), 1.0) * n          # clipped to [0, 1]; NaN -> 0 (fmax drops NaN)
        i = np.minimum(x.astype(np.intp), n - 1)
        t = (x - i)[..., None]
        # (np.take: the row gathers of value[i], slope[i] without fancy indexing's overhead; the same numbers)
        return np.take(self.value, i, axis=0) + t * np.take(self.slope, i, axis=0)

    def cache_key(self) -> dict:
        return {"model": "tabulated", "source": self.source.cache_key(), "cells": int(self.slope.shape[0])}


#: finest grid ``tabulated`` tries (2^16 cells: 1.5 MB for RGB)
_MAX_CELLS = 1 << 16


def _interpolation_error(model: Fresnel, value: np.ndarray) -> float:
    """Worst |linear interpolation - exact| of ``model`` sampled as ``value`` at 7 points inside each cell
    (a smooth F errs most near a cell's middle; a kink, e.g. a dielectric's critical angle, anywhere)."""
    n = value.shape[0] - 1
    t = np.arange(1, 8) / 8.0
    c = (np.arange(n)[:, None] + t[None, :]) / n
    lin = value[:-1, None, :] + t[None, :, None] * (value[1:] - value[:-1])[:, None, :]
    return float(np.max(np.abs(lin - model(c))))


def tabulated(model: Fresnel, tol: float = 1e-5) -> Fresnel:
    """``model`` on the coarsest uniform cos θ grid (N = 2^j cells, linear between samples) whose
    interpolation error, measured against ``model`` at 7 points inside every cell, is below ``tol``
    (absolute reflectance, dimensionless).  The samples at the grid points are ``model``'s own, so
    ``F(cos = 0) = 1`` and ``F(cos = 1) = F0`` hold exactly.  A model that no grid up to 2^16 cells meets
    (a kink sharper than ``tol`` allows) or a model cheaper than the lookup (Schlick) comes back as is.
    Cached per model parameters (the grid is built once per metal).
    """
    if not isinstance(model, Fresnel) or isinstance(model, (Tabulated, Schlick)):
        return model
    tol = float(tol)
    if not (np.isfinite(tol) and 0.0 < tol < 1.0):
        raise ValueError(f"tol: allowed range is (0, 1), got {tol!r}")
    key = (repr(model.cache_key()), tol)
    hit = _TABLES.get(key)
    if hit is not None:
        return hit
    n = 256
    while n <= _MAX_CELLS:
        value = model(np.linspace(0.0, 1.0, n + 1))
        err = _interpolation_error(model, value)
        if err < tol:
            out = Tabulated(value, np.diff(value, axis=0), model, err)
            if len(_TABLES) > 64:  # bounded: a long session of metal edits
                _TABLES.clear()
            _TABLES[key] = out
            return out
        n *= 2
    return model


_TABLES: dict = {}


def schlick(ior=1.5, *, f0=None) -> Schlick:
    """Schlick's approximation for a dielectric of refractive index ``ior`` (> 0; scalar or RGB).

    ``f0`` (normal-incidence reflectance in [0, 1], scalar or RGB) may be given instead of ``ior``.
    """
    if f0 is not None:
        return Schlick(_channels(f0, "f0", low=0.0, high=1.0))
    n = _channels(ior, "ior", low=0.0, high=1e3, low_open=True)
    return Schlick(((n - 1.0) / (n + 1.0)) ** 2)


def lazanyi(n, k, *, a=0.0, alpha: float = 6.0) -> Lazanyi:
    """Lazanyi-Szirmay-Kalos conductor approximation for ``n + i k`` (scalars or RGB triples).

    ``a``/``alpha``: optional error-compensation term ``- a cos (1 - cos)^alpha`` (default off).
    """
    n = _channels(n, "n", low=0.0, high=1e3, low_open=True)
    k = _channels(k, "k", low=0.0, high=1e3)
    a = _channels(a, "a", low=0.0, high=1e3)
    try:
        alpha = float(alpha)
    except (TypeError, ValueError):
        raise ValueError(f"alpha: expected one number in (0, 100], got {alpha!r}") from None
    if not (np.isfinite(alpha) and 0.0 < alpha <= 100.0):
        raise ValueError(f"alpha: allowed range is (0, 100], got {alpha!r}")
    _same_channels(n=n, k=k, a=a)
    return Lazanyi(n, k, a, float(alpha))


def conductor(n, k) -> Conductor:
    """Exact unpolarised conductor Fresnel for complex IOR ``n + i k`` (scalars or RGB triples)."""
    n = _channels(n, "n", low=0.0, high=1e3, low_open=True)
    k = _channels(k, "k", low=0.0, high=1e3)
    _same_channels(n=n, k=k)
    return Conductor(n, k)


def conductor_preset(name: str) -> Conductor:
    """Exact conductor Fresnel for a named metal (see ``PRESETS``; R/G/B at 650/550/450 nm)."""
    key = _ALIASES.get(str(name).lower(), str(name).lower())
    if key not in PRESETS:
        raise ValueError(f"name: unknown metal {name!r}; choose one of {sorted(PRESETS)}")
    n, k = PRESETS[key]
    return Conductor(np.array(n), np.array(k), key)


def _same_channels(**arrays: np.ndarray) -> None:
    sizes = {k: v.size for k, v in arrays.items()}
    if len({s for s in sizes.values() if s != 1}) > 1:
        raise ValueError(f"channel counts differ: {sizes} (use 1 or 3 values for each)")
