"""Ellipsoid NDFs (Dong et al. 2015, §8-9) as Cycles Glossy-node parameters (pure numpy).

The ellipsoid NDF (eq. 10) with ``A = S R``, ``R = Rx(theta_x) Ry(theta_y) Rz(theta_z)`` (eqs. 11-12)
is an anisotropic GGX lobe in the rotated frame ``(X', Y', N') = (R^T x, R^T y, R^T z)``:
``||A^{-T} m||^2 = (X'.m / alpha_x)^2 + (Y'.m / alpha_y)^2 + (N'.m)^2``, so

    D_ellipsoid(m) = D_GGX(m; N', X', alpha_x, alpha_y) / ||A n||      (m.n > 0).

The two differ only by the constant ``||A n||`` (the ellipsoid is normalised about the mean normal
``n``, the GGX about its own axis ``N'``; ``||A n|| = 1`` when untilted and ``~cos(tilt)`` for the
small tilts of §9).  Cycles' Glossy BSDF (GGX) with closure normal ``N'`` and tangent ``X'``
therefore reproduces the ellipsoid NDF's *shape* exactly and its scale up to ``||A n||``.  (Cycles
also measures the cosines of the microfacet BRDF about ``N'`` rather than ``n``; at normal view the
two effects cancel to first order, see :func:`projection_factor`.)

Node parameters (what ``node_groups.microgeometry`` consumes)
---------------------------------------------------------------
* ``roughness``, ``anisotropy``: the Glossy node's inputs; Cycles maps them (SVM ``svm_closure.h``,
  OSL ``node_glossy_bsdf.osl``) to ``alpha = roughness^2`` and, for ``an > 0``,
  ``alpha_u = alpha (1 - an)``, ``alpha_v = alpha / (1 - an)``; for ``an < 0``
  ``alpha_u = alpha / (1 + an)``, ``alpha_v = alpha (1 + an)`` (u = tangent); ``an`` is clamped to
  ``[-0.99, 0.99]``, ``roughness`` to ``[0, 1]`` and each alpha to ``[0, 1]``.  Negative
  anisotropy keeps the map continuous where ``alpha_x`` and ``alpha_y`` cross between texels.
* ``rotation`` (turns): azimuth of the lobe axis ``X'`` about ``n``, counter-clockwise from the UV
  tangent: ``rotation = -theta_z / (2 pi)`` (not wrapped, so texture filtering never crosses a
  0/1 seam).
* ``tilt``: the closure normal ``N' = R^T z`` in the surface frame (UV tangent, bitangent, normal).

The node group builds the tangent as ``X' = normalize(B_r x N')`` with ``B_r`` the bitangent
rotated by ``rotation``; this is exactly ``R^T x`` for the ``Rx Ry Rz`` order (``X'`` lies in the
plane spanned by ``T_r`` and ``n``) - :func:`closure_frame` is the numpy twin of that construction.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cycles.glossy import (ANISO_MAX, CYCLES_ALPHA_MAX, cycles_glossy_alphas, glossy_from_alphas,  # noqa: F401
                             representable_alphas)
from .ellipsoid import (ALPHA_MAX, ALPHA_MIN, THETA_XY_MAX, _as_params, _ellipsoid_eval, fit_ellipsoid, fit_ggx,
                        fit_nodes, hellinger_distance, rotation_matrix)

__all__ = [
    "ANISO_MAX",
    "CYCLES_ALPHA_MAX",
    "GlossyParams",
    "LossReport",
    "cycles_glossy_alphas",
    "glossy_from_alphas",
    "representable_alphas",
    "glossy_from_ellipsoid",
    "ellipsoid_from_glossy",
    "closure_frame",
    "projection_factor",
    "glossy_from_ndf",
    "node_textures",
]

@dataclass(frozen=True)
class LossReport:
    """What the conversion to Cycles could not represent.

    ``n_total`` lobes, ``n_clamped`` of them had an alpha changed (alpha > 1 or axis ratio below
    ``(1 - 0.99)^2``); ``max_alpha_rel_change`` the largest relative change of an alpha;
    ``max_tilt_deg`` the largest angle between ``N'`` and ``n`` (degrees; represented exactly, but
    shading normals far from ``n`` render darker at grazing light); ``hellinger``: squared
    Hellinger distance between the requested and the represented NDF (single lobes only, else NaN).
    """

    n_total: int
    n_clamped: int
    max_alpha_rel_change: float
    max_tilt_deg: float
    hellinger: float = float("nan")

    @property
    def lossless(self) -> bool:
        return self.n_clamped == 0

    def __str__(self) -> str:
        s = (f"{self.n_clamped}/{self.n_total} lobes clamped to Cycles' range (max alpha change "
             f"{100 * self.max_alpha_rel_change:.2g} %), max tilt {self.max_tilt_deg:.3g} deg")
        if np.isfinite(self.hellinger):
            s += f", Hellinger^2 requested vs represented {self.hellinger:.3g}"
        return s


@dataclass(frozen=True)
class GlossyParams:
    """One lobe as node-group inputs (see module doc).  ``ellipsoid``: the represented 5 parameters."""

    roughness: float
    anisotropy: float
    rotation: float
    tilt: tuple[float, float, float]
    ellipsoid: tuple[float, float, float, float, float]
    loss: LossReport = field(compare=False, default=None)

    def as_inputs(self) -> dict:
        """Node-group input values: ``{"Roughness", "Anisotropy", "Rotation", "Tilt"}``."""
        return {"Roughness": self.roughness, "Anisotropy": self.anisotropy, "Rotation": self.rotation,
                "Tilt": tuple(self.tilt)}


# ----------------------------------------------------------------------------- ellipsoid <-> node parameters


def _tilt_and_rotation(p):
    R = rotation_matrix(p[..., 2], p[..., 3], p[..., 4])
    return R[..., 2, :], -p[..., 4] / (2.0 * np.pi)  # N' = R^T z (third row of R)


def glossy_from_ellipsoid(params):
    """Ellipsoid parameters (..., 5) (§8; radians) -> node-parameter arrays and a :class:`LossReport`.

    Returns ``({"roughness", "anisotropy", "rotation", "tilt" (..., 3), "ellipsoid" (..., 5)}, loss)``;
    ``ellipsoid`` holds the represented parameters (alphas clamped to Cycles' range).
    """
    p = _as_params(params)
    ax, ay, clamped = representable_alphas(p[..., 0], p[..., 1])
    rough, an = glossy_from_alphas(ax, ay)
    tilt, rot = _tilt_and_rotation(p)
    rel = np.maximum(np.abs(ax / p[..., 0] - 1.0), np.abs(ay / p[..., 1] - 1.0))
    tilt_deg = np.degrees(np.arccos(np.clip(tilt[..., 2], -1.0, 1.0)))
    rep = np.array(p, dtype=np.float64)
    rep[..., 0], rep[..., 1] = ax, ay
    loss = LossReport(int(np.size(rel)), int(np.sum(clamped)), float(np.max(rel)), float(np.max(tilt_deg)))
    return {"roughness": rough, "anisotropy": an, "rotation": rot, "tilt": tilt, "ellipsoid": rep}, loss


def ellipsoid_from_glossy(roughness, anisotropy, rotation, tilt):
    """Inverse of :func:`glossy_from_ellipsoid` (through Cycles' clamps): returns (..., 5) parameters.

    ``theta_z = -2 pi rotation``; with ``v = Rz(theta_z) N'`` = ``(-sin ty cos tx, sin tx, cos ty cos tx)``,
    ``theta_x = asin(v_y)``, ``theta_y = atan2(-v_x, v_z)``.  ``tilt`` (..., 3) need not be unit.
    """
    au, av = cycles_glossy_alphas(roughness, anisotropy)
    rot = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(tilt, dtype=np.float64)
    if t.shape[-1:] != (3,) or not np.all(np.isfinite(t)) or not np.all(np.isfinite(rot)):
        raise ValueError("tilt: expected finite (..., 3) vectors; rotation: finite turns")
    nrm = np.linalg.norm(t, axis=-1, keepdims=True)
    if np.any(nrm < 1e-12) or np.any(t[..., 2] <= 0):
        raise ValueError("tilt: the closure normal must point above the surface (tilt_z > 0)")
    t = t / nrm
    tz = -2.0 * np.pi * rot
    c, s = np.cos(tz), np.sin(tz)
    vx, vy, vz = c * t[..., 0] - s * t[..., 1], s * t[..., 0] + c * t[..., 1], t[..., 2]
    tx = np.arcsin(np.clip(vy, -1.0, 1.0))
    ty = np.arctan2(-vx, vz)
    return np.stack(np.broadcast_arrays(au, av, tx, ty, tz), -1)


def closure_frame(roughness, anisotropy, rotation, tilt):
    """Numpy twin of ``node_groups.microgeometry`` + the Glossy node: ``(N', X', alpha_u, alpha_v)``.

    In the surface frame (UV tangent, bitangent, normal): ``T_r = (cos 2 pi r, sin 2 pi r, 0)``,
    ``B_r = n x T_r``, ``N' = normalize(tilt)``, tangent ``X' = normalize(B_r x N')`` (Glossy Rotation
    input left at 0), alphas from :func:`cycles_glossy_alphas`.  Feed ``N', X'`` to
    :func:`precompute.cycles.ggx.bsdf_eval`.
    """
    t = np.asarray(tilt, dtype=np.float64)
    N = t / np.linalg.norm(t, axis=-1, keepdims=True)
    phi = 2.0 * np.pi * np.asarray(rotation, dtype=np.float64)
    B = np.stack(np.broadcast_arrays(-np.sin(phi), np.cos(phi), np.zeros_like(phi)), -1)
    X = np.cross(B, N)
    X = X / np.linalg.norm(X, axis=-1, keepdims=True)
    au, av = cycles_glossy_alphas(roughness, anisotropy)
    return N, X, au, av


def projection_factor(params, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Ratio of the ellipsoid microfacet BRDF (eq. 10, cosines about ``n``) to Cycles' tilted GGX.

    ``f_ell cos / eval_cycles = (N'.wi) / (||A n|| (n.wi)) * G_ell / G_cycles``; this returns the
    geometric part ``(N'.wi) / (||A n|| (n.wi))`` for view ``wi`` (1 when untilted; ``1 + O(t^2)``
    at normal view for small ``alpha``).  Informational: the node groups do not apply it.
    """
    p = _as_params(params)
    R = rotation_matrix(p[..., 2], p[..., 3], p[..., 4])
    Np = R[..., 2, :]
    Rn = R[..., :, 2]
    An = np.sqrt((p[..., 0] * Rn[..., 0]) ** 2 + (p[..., 1] * Rn[..., 1]) ** 2 + Rn[..., 2] ** 2)
    w = np.asarray(view, dtype=np.float64)
    w = w / np.linalg.norm(w)
    return (Np @ w) / (An * w[2])


# ----------------------------------------------------------------------------- NDFs and textures


def glossy_from_ndf(ndf, model: str = "ellipsoid", n_nodes: int = 96) -> GlossyParams:
    """Fit an NDF (anything with ``.eval(m)``, e.g. :class:`precompute.microgeometry.NDFTable`) and convert.

    ``model``: ``"ellipsoid"`` (§8, 5 parameters incl. tilt; Fig. 13 middle image) or ``"ggx"``
    (anisotropic GGX / GTR2aniso, untilted).  The returned :class:`LossReport` includes the squared
    Hellinger distance between the fitted and the represented lobe on the fit nodes.
    """
    if model == "ellipsoid":
        p = np.array(fit_ellipsoid(ndf, n_nodes), dtype=np.float64)
    elif model == "ggx":
        g = fit_ggx(ndf, isotropic=False, n_nodes=n_nodes)
        p = np.array([g["alpha_x"], g["alpha_y"], 0.0, 0.0, g["theta_z"]])
    else:
        raise ValueError(f"model: must be 'ellipsoid' or 'ggx', got {model!r}")
    p[:2] = np.clip(p[:2], ALPHA_MIN, ALPHA_MAX)
    p[2:4] = np.clip(p[2:4], -THETA_XY_MAX, THETA_XY_MAX)
    maps, loss = glossy_from_ellipsoid(p)
    m, cell, _ = fit_nodes(ndf, n_nodes)
    hel = float(hellinger_distance(_ellipsoid_eval(m, p), _ellipsoid_eval(m, maps["ellipsoid"]), cell))
    loss = LossReport(loss.n_total, loss.n_clamped, loss.max_alpha_rel_change, loss.max_tilt_deg, hel)
    return GlossyParams(float(maps["roughness"]), float(maps["anisotropy"]), float(maps["rotation"]),
                        tuple(float(v) for v in maps["tilt"]), tuple(float(v) for v in maps["ellipsoid"]), loss)


def node_textures(texture) -> tuple[dict[str, np.ndarray], LossReport]:
    """A synthesised (H, W, 5) parameter texture (§9, :mod:`precompute.microgeometry.synthesis`) -> packed images.

    Returns ``({"params": (H, W, 4), "tilt": (H, W, 4)}, loss)`` float32 RGBA, rows in texture order
    (row 0 = ``y = 0`` = Blender's bottom row, so ``v`` runs along the texture's ``y``):
    ``params = (roughness, anisotropy, rotation [turns], 1)``, ``tilt = (N'_t, N'_b, N'_n, 1)``.
    """
    t = np.asarray(texture, dtype=np.float64)
    if t.ndim != 3 or t.shape[2] != 5 or t.shape[0] < 1 or t.shape[1] < 1:
        raise ValueError(f"texture: expected shape (H, W, 5) of ellipsoid parameters, got {t.shape}")
    maps, loss = glossy_from_ellipsoid(t)
    one = np.ones(t.shape[:2])
    params = np.stack([maps["roughness"], maps["anisotropy"], maps["rotation"], one], -1).astype(np.float32)
    tilt = np.concatenate([maps["tilt"], one[..., None]], -1).astype(np.float32)
    return {"params": params, "tilt": tilt}, loss
