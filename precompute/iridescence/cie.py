"""CIE 1931 colour matching and spectrum → linear Rec.709 RGB.

Colour matching functions: the multi-lobe piecewise-Gaussian fit of
C. Wyman, P.-P. Sloan, P. Shirley, "Simple Analytic Approximations to the CIE XYZ
Color Matching Functions", JCGT 2(2), 2013 (their eq. 2, the "multi-lobe" fit).
XYZ → linear sRGB / Rec.709 primaries with the D65 matrix of IEC 61966-2-1
(Cycles' default scene-linear space).

Wavelengths are in **micrometres** everywhere in this package (0.38-0.78 µm visible).

Normalisation used by ``spectrum_to_rgb`` (defined here, documented once): a
*reflectance* spectrum R(λ) is mapped to the RGB reflectance that a neutral
(equal-energy) illuminant would produce, white-balanced so that R ≡ 1 gives
exactly (1, 1, 1):  ``rgb = M·∫R x̄ȳz̄ dλ / (M·∫ x̄ȳz̄ dλ)`` (per channel), with the
integrals taken by the trapezoidal rule on the caller's wavelength grid.
"""
from __future__ import annotations

import numpy as np

__all__ = ["cmf_xyz", "XYZ_TO_REC709", "xyz_to_rec709", "spectrum_to_rgb", "spectral_weights", "visible_wavelengths"]

# (amplitude, mu [nm], sigma below mu [nm], sigma above mu [nm]) — Wyman et al. 2013, eq. 2
_LOBES = {
    "x": ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    "y": ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    "z": ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
}

XYZ_TO_REC709 = np.array([
    [3.2404542, -1.5371385, -0.4985314],
    [-0.9692660, 1.8760108, 0.0415560],
    [0.0556434, -0.2040259, 1.0572252],
])


def _lobe(lam_nm, amp, mu, s1, s2):
    s = np.where(lam_nm < mu, s1, s2)
    return amp * np.exp(-0.5 * ((lam_nm - mu) / s) ** 2)


def cmf_xyz(lam_um) -> np.ndarray:
    """CIE 1931 2° colour matching functions x̄, ȳ, z̄ at wavelengths ``lam_um`` (µm).

    Returns an array of shape ``lam_um.shape + (3,)`` (dimensionless, ȳ peak ≈ 1
    near 0.555 µm).  Wyman, Sloan & Shirley 2013, multi-lobe fit.
    Raises ValueError for non-finite or non-positive wavelengths.
    """
    try:
        lam = np.asarray(lam_um, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"lam_um must be finite and > 0 (wavelength in micrometres), got {lam_um!r}") from None
    if not np.all(np.isfinite(lam)) or np.any(lam <= 0.0):
        raise ValueError("lam_um must be finite and > 0 (wavelength in micrometres)")
    nm = lam * 1000.0
    return np.stack([sum(_lobe(nm, *p) for p in _LOBES[c]) for c in "xyz"], axis=-1)


def xyz_to_rec709(xyz) -> np.ndarray:
    """CIE XYZ (..., 3) → linear Rec.709/sRGB primaries (D65 matrix), no clamping."""
    return np.asarray(xyz, dtype=np.float64) @ XYZ_TO_REC709.T


def visible_wavelengths(n: int = 32, lo_um: float = 0.38, hi_um: float = 0.78) -> np.ndarray:
    """``n`` equally spaced wavelengths (µm) covering [lo_um, hi_um] (bin centres)."""
    if not (isinstance(n, (int, np.integer)) and 3 <= n <= 4096):
        raise ValueError(f"n must be an integer in [3, 4096] (got {n!r})")
    if not (0.1 <= lo_um < hi_um <= 2.0):
        raise ValueError("lo_um, hi_um must satisfy 0.1 <= lo_um < hi_um <= 2.0 (micrometres)")
    edges = np.linspace(lo_um, hi_um, n + 1)
    return 0.5 * (edges[1:] + edges[:-1])


def spectral_weights(lam_um) -> np.ndarray:
    """(L, 3) matrix taking a reflectance spectrum sampled at ``lam_um`` to white-balanced RGB.

    ``rgb = spectrum @ spectral_weights(lam)``; a flat spectrum of ones maps to
    exactly (1, 1, 1) (see module docstring).  ``lam_um`` strictly increasing, L ≥ 2.
    """
    lam = np.asarray(lam_um, dtype=np.float64)
    if lam.ndim != 1 or lam.size < 2 or np.any(np.diff(lam) <= 0.0):
        raise ValueError("lam_um must be a strictly increasing 1-D array of at least 2 wavelengths (micrometres)")
    # bin widths: midpoints between samples (trapezoid-like, also right for bin centres)
    edges = np.concatenate([[lam[0] - 0.5 * (lam[1] - lam[0])], 0.5 * (lam[1:] + lam[:-1]),
                            [lam[-1] + 0.5 * (lam[-1] - lam[-2])]])
    dl = np.diff(edges)
    w = (cmf_xyz(lam) * dl[:, None]) @ XYZ_TO_REC709.T          # (L, 3)
    white = w.sum(axis=0)
    return w / white


def spectrum_to_rgb(spectrum, lam_um) -> np.ndarray:
    """Reflectance spectrum (..., L) sampled at ``lam_um`` (L,) → linear Rec.709 RGB (..., 3).

    White-balanced so that a flat unit spectrum gives (1, 1, 1); see module docstring.
    """
    s = np.asarray(spectrum, dtype=np.float64)
    lam = np.asarray(lam_um, dtype=np.float64)
    if s.shape[-1:] != lam.shape:
        raise ValueError(f"spectrum must end with the wavelength axis of length {lam.size} (got {s.shape})")
    return s @ spectral_weights(lam)
