"""The Glossy BSDF node's roughness mapping, in one place: Cycles' (roughness, anisotropy) <-> (alpha_u, alpha_v).

Cycles (SVM ``svm_closure.h``, OSL ``node_glossy_bsdf.osl``) maps the node's inputs to
``alpha = roughness^2`` and, for ``an > 0``, ``alpha_u = alpha (1 - an)``, ``alpha_v = alpha / (1 - an)``;
for ``an < 0`` ``alpha_u = alpha / (1 + an)``, ``alpha_v = alpha (1 + an)`` (u = tangent); ``an`` is
clamped to ``[-0.99, 0.99]``, ``roughness`` to ``[0, 1]`` and each alpha to ``[0, 1]``; ``|an| <= 1e-4``
is isotropic.  Every node builder that sets a Glossy node from alphas goes through
:func:`glossy_node_params`.
"""
from __future__ import annotations

import numpy as np

#: Cycles clamps the Glossy node's anisotropy to this magnitude (alpha ratio >= (1 - 0.99)^2 = 1e-4).
ANISO_MAX = 0.99
#: ``bsdf_microfacet_ggx_setup`` clamps each alpha to [0, 1].
CYCLES_ALPHA_MAX = 1.0
#: Below this |anisotropy| the SVM Glossy node is isotropic and ignores the tangent.
_ISO_EPS = 1e-4
_RATIO_MIN = (1.0 - ANISO_MAX) ** 2


def cycles_glossy_alphas(roughness, anisotropy):
    """Numpy twin of the Glossy node's roughness mapping (Cycles ``svm_closure.h`` / ``node_glossy_bsdf.osl``).

    Returns ``(alpha_u, alpha_v)`` (u = tangent) after Cycles' clamps: roughness to [0, 1],
    anisotropy to [-0.99, 0.99], |anisotropy| <= 1e-4 isotropic, each alpha to [0, 1].
    """
    r = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0)
    an = np.clip(np.asarray(anisotropy, dtype=np.float64), -ANISO_MAX, ANISO_MAX)
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(an))):
        raise ValueError("roughness, anisotropy: must be finite")
    a = r * r
    au = np.where(an < 0, a / (1.0 + an), a * (1.0 - an))
    av = np.where(an < 0, a * (1.0 + an), a / (1.0 - an))
    iso = np.abs(an) <= _ISO_EPS
    au, av = np.where(iso, a, au), np.where(iso, a, av)
    return np.minimum(au, CYCLES_ALPHA_MAX), np.minimum(av, CYCLES_ALPHA_MAX)


def representable_alphas(alpha_x, alpha_y):
    """Nearest alphas Cycles can represent: each <= 1, ratio >= (1 - 0.99)^2 (the smaller one is raised),
    and ratios within (1 - 1e-4)^2 of 1 made isotropic (the Glossy node ignores |anisotropy| <= 1e-4).

    Returns ``(alpha_x', alpha_y', clamped)``; inputs must be finite and > 0 (dimensionless).
    """
    ax = np.asarray(alpha_x, dtype=np.float64)
    ay = np.asarray(alpha_y, dtype=np.float64)
    if not (np.all(np.isfinite(ax)) and np.all(np.isfinite(ay)) and np.all(ax > 0) and np.all(ay > 0)):
        raise ValueError("alpha_x, alpha_y: must be finite and > 0")
    cx, cy = np.minimum(ax, CYCLES_ALPHA_MAX), np.minimum(ay, CYCLES_ALPHA_MAX)
    lo = _RATIO_MIN * (1.0 - 1e-12)  # (1 - 0.99)^2 rounds to 1e-4 * (1 + 2e-15): do not "clamp" 1e-4 itself
    cx = np.where(cx < lo * cy, _RATIO_MIN * cy, cx)
    cy = np.where(cy < lo * cx, _RATIO_MIN * cx, cy)
    # |anisotropy| <= 1e-4 is isotropic in Cycles: such pairs become their geometric mean
    ratio = np.minimum(cx, cy) / np.maximum(cx, cy)
    near_iso = (ratio < 1.0) & (ratio >= (1.0 - _ISO_EPS) ** 2)
    g = np.sqrt(cx * cy)
    cx, cy = np.where(near_iso, g, cx), np.where(near_iso, g, cy)
    return cx, cy, (np.abs(cx / ax - 1.0) > 1e-12) | (np.abs(cy / ay - 1.0) > 1e-12)  # beyond round-off


def glossy_from_alphas(alpha_u, alpha_v):
    """Inverse of :func:`cycles_glossy_alphas` for representable alphas: ``(roughness, anisotropy)``.

    ``roughness = (alpha_u alpha_v)^(1/4)``; ``anisotropy = 1 - sqrt(alpha_u / alpha_v)`` if
    ``alpha_u <= alpha_v`` else ``-(1 - sqrt(alpha_v / alpha_u))``.  Raises ``ValueError`` outside
    Cycles' range (use :func:`representable_alphas` first).
    """
    au = np.asarray(alpha_u, dtype=np.float64)
    av = np.asarray(alpha_v, dtype=np.float64)
    ok = np.isfinite(au) & np.isfinite(av) & (au > 0) & (av > 0) & (au <= CYCLES_ALPHA_MAX * (1 + 1e-12)) \
        & (av <= CYCLES_ALPHA_MAX * (1 + 1e-12))
    if not np.all(ok):
        raise ValueError(f"alpha_u, alpha_v: must lie in (0, {CYCLES_ALPHA_MAX}] (Cycles clamps larger alphas)")
    ratio = np.minimum(au, av) / np.maximum(au, av)
    if np.any(ratio < _RATIO_MIN * (1 - 1e-9)):
        raise ValueError(f"alpha_u, alpha_v: axis ratio must be >= {_RATIO_MIN:g} (|anisotropy| <= {ANISO_MAX})")
    roughness = (au * av) ** 0.25
    mag = 1.0 - np.sqrt(ratio)
    return roughness, np.where(au <= av, mag, -mag)


def glossy_node_params(alpha_x, alpha_y):
    """(Roughness, Anisotropy) of a Glossy node giving alphas ``(alpha_x along the tangent, alpha_y)``
    (scalars or arrays, dimensionless, each in (0, 1]); pairs outside Cycles' range are first moved to
    the nearest representable pair (:func:`representable_alphas`).  Scalars in, floats out."""
    ax, ay = np.asarray(alpha_x, dtype=np.float64), np.asarray(alpha_y, dtype=np.float64)
    for name, a in (("alpha_x", ax), ("alpha_y", ay)):
        if not (np.all(np.isfinite(a)) and np.all(a > 0) and np.all(a <= CYCLES_ALPHA_MAX)):
            raise ValueError(f"{name}: expected a roughness in (0, {CYCLES_ALPHA_MAX:g}], got {alpha_x if name == 'alpha_x' else alpha_y!r}")
    rough, an = glossy_from_alphas(*representable_alphas(ax, ay)[:2])
    if rough.ndim == 0:
        return float(rough), float(an)
    return rough, an
