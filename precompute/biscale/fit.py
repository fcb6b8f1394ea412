"""Fit a bi-scale effective BRDF table with Cycles closures (Wu et al. 2011, §5 "rendering":
the large-scale material must render in a production renderer).

The fitted material is what Cycles evaluates for

    Diffuse BSDF (colour kd)  +  Σ_l Glossy BSDF (GGX, colour c_l, normal N_l, tangent T_l, α_x,l, α_y,l)

i.e. the cosine-weighted BRDF (what the integrator multiplies by the incident radiance)

    f̄r_fit(ωi, ωo) = kd cos θi / π + Σ_l c_l · eval_GGX(N_l, T_l, α_x,l, α_y,l; view ωo, light ωi),

with ``eval_GGX`` the numpy twin of Cycles' closure (``precompute.cycles.ggx.bsdf_eval``: D G2 /
(4 N·ωo), height-correlated Smith G, lights below the closure normal rejected).  Lobe normals
may be tilted: N_l = cos t n + sin t (cos φ u + sin φ v), tangents T_l = cos ψ u + sin ψ v in the
surface frame (u = UV tangent = tile x axis, v = n x u, n = large-scale normal = tile z axis).

Fitting (variable projection): colours are linear, so for given lobe shapes (t, φ, ψ, α_x, α_y)
they are a non-negative least-squares solve per RGB channel; the shapes are found greedily
(matching pursuit over a dictionary of isotropic lobes on a grid of tilts/azimuths/roughnesses)
and then refined jointly by ``scipy.optimize.least_squares``.  Residuals are weighted by the
solid angles of the two grid cells (so the loss approximates ∫∫ (f̄r_fit - f̄r)^2 dωi dωo).

Error measures (reported): relative L1 Σ|f̄r_fit - f̄r| / Σ|f̄r| and PSNR (peak = max f̄r, as
``precompute.biscale.psnr``) over all grid pairs.  Angles in radians.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, nnls

from ..cycles.glossy import glossy_node_params  # noqa: F401 - re-export (node builders' mapping)

from ..cycles import ggx as cycles_ggx
from .directions import direction_grid, direction_solid_angles

__all__ = ["GGXLobe", "ClosureFit", "lobe_frame", "lobe_eval", "fit_closures", "glossy_node_params"]

_ALPHA_MIN, _ALPHA_MAX = 0.01, 1.0
_TILT_MAX = 1.2


@dataclass
class GGXLobe:
    """One Cycles GGX reflection closure in the surface frame (angles in radians)."""
    tilt: float
    tilt_azimuth: float
    tangent_azimuth: float
    alpha_x: float
    alpha_y: float
    colour: np.ndarray = field(default_factory=lambda: np.ones(3))

    def frame(self):
        return lobe_frame(self.tilt, self.tilt_azimuth, self.tangent_azimuth)

    def to_dict(self) -> dict:
        return {"tilt": self.tilt, "tilt_azimuth": self.tilt_azimuth, "tangent_azimuth": self.tangent_azimuth,
                "alpha_x": self.alpha_x, "alpha_y": self.alpha_y, "colour": [float(c) for c in self.colour]}


def lobe_frame(tilt, tilt_azimuth, tangent_azimuth):
    """Closure normal N = cos t z + sin t (cos φ x + sin φ y) and tangent T = cos ψ x + sin ψ y."""
    st = np.sin(tilt)
    N = np.array([st * np.cos(tilt_azimuth), st * np.sin(tilt_azimuth), np.cos(tilt)])
    T = np.array([np.cos(tangent_azimuth), np.sin(tangent_azimuth), 0.0])
    if abs(T @ N) > 0.999:  # tangent (almost) along N: any other horizontal direction
        T = np.array([-np.sin(tangent_azimuth), np.cos(tangent_azimuth), 0.0])
    return N, T


def lobe_eval(tilt, tilt_azimuth, tangent_azimuth, alpha_x, alpha_y, wi, wo) -> np.ndarray:
    """Cycles' GGX closure eval (= f cos(light), 1/sr) for light ωi and view ωo (P, 3), weight 1."""
    N, T = lobe_frame(tilt, tilt_azimuth, tangent_azimuth)
    ev, _ = cycles_ggx.bsdf_eval(N, T, alpha_x, alpha_y, wo, wi)
    return ev


@dataclass
class ClosureFit:
    """Diffuse colour + GGX lobes approximating an effective BRDF; ``rel_l1``/``psnr`` of f̄r."""
    diffuse: np.ndarray
    lobes: list
    rel_l1: float
    psnr: float
    info: dict = field(default_factory=dict)

    def eval_cos(self, wi, wo) -> np.ndarray:
        """Cosine-weighted BRDF f̄r (P, 3) that Cycles integrates, light ωi, view ωo (P, 3)."""
        wi = np.atleast_2d(np.asarray(wi, np.float64))
        wo = np.atleast_2d(np.asarray(wo, np.float64))
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.clip(wi[:, 2], 0, None)[:, None] / np.pi * self.diffuse[None]
        for lb in self.lobes:
            out = out + lobe_eval(lb.tilt, lb.tilt_azimuth, lb.tangent_azimuth, lb.alpha_x, lb.alpha_y,
                                  wi, wo)[:, None] * lb.colour[None]
        return np.where(above[:, None], out, 0.0)

    def to_dict(self) -> dict:
        return {"diffuse": [float(c) for c in self.diffuse], "lobes": [lb.to_dict() for lb in self.lobes],
                "rel_l1": self.rel_l1, "psnr": self.psnr}


# ----------------------------------------------------------------------------- fitting
def _solve_colours(B, Y, w):
    """NNLS per channel of (B c ≈ Y) with row weights w; B (P, L), Y (P, 3) -> C (L, 3)."""
    Bw = B * w[:, None]
    C = np.zeros((B.shape[1], 3))
    scale = np.maximum(np.linalg.norm(Bw, axis=0), 1e-300)
    for ch in range(3):
        c, _ = nnls(Bw / scale, Y[:, ch] * w, maxiter=50 * B.shape[1])
        C[:, ch] = c / scale
    return C


def _unpack(x, n):
    p = x.reshape(n, 5)
    return p[:, 0], p[:, 1], p[:, 2], np.exp(p[:, 3]), np.exp(p[:, 4])


def fit_closures(brdf, n_lobes: int = 3, tilted: bool = True, max_nfev: int = 60, seed: int = 0) -> ClosureFit:
    """Fit ``brdf`` (a ``precompute.biscale.EffectiveBRDF``) with a diffuse lobe plus up to
    ``n_lobes`` GGX lobes (tilted when ``tilted``), see the module docstring.  Returns a
    ``ClosureFit`` whose errors are measured on the D x D grid pairs."""
    if not (isinstance(n_lobes, (int, np.integer)) and 0 <= n_lobes <= 8):
        raise ValueError(f"n_lobes: expected an integer in [0, 8], got {n_lobes!r}")
    table = np.asarray(brdf.table, np.float64)
    res = int(brdf.dir_res)
    dirs = direction_grid(res)
    D = len(dirs)
    if table.shape != (D, D, 3) or not np.all(np.isfinite(table)):
        raise ValueError(f"brdf.table: expected finite (D, D, 3) with D = dir_res^2 = {D}, got {table.shape}")
    om = direction_solid_angles(res)
    ii, oo = np.meshgrid(np.arange(D), np.arange(D), indexing="ij")
    ii, oo = ii.ravel(), oo.ravel()
    wi, wo = dirs[ii], dirs[oo]
    Y = table[ii, oo] * wi[:, 2:3]                       # target f̄r = f cos θi
    w = np.sqrt(om[ii] * om[oo])
    b_diff = wi[:, 2] / np.pi

    def basis(x, n):
        cols = [b_diff]
        if n:
            t, ph, ps, ax, ay = _unpack(x, n)
            cols += [lobe_eval(t[k], ph[k], ps[k], ax[k], ay[k], wi, wo) for k in range(n)]
        return np.stack(cols, 1)

    # greedy matching pursuit over a dictionary of isotropic lobes
    tilts = [0.0] + ([0.15, 0.3, 0.5, 0.75] if tilted else [])
    azis = np.arange(12) * (np.pi / 6)
    alphas = [0.04, 0.1, 0.2, 0.35, 0.6]
    cand = [(t, (a if t > 0 else 0.0), 0.0, al) for t in tilts for a in (azis if t > 0 else [0.0]) for al in alphas]
    cand_cols = np.stack([lobe_eval(t, a, p, al, al, wi, wo) for t, a, p, al in cand], 1)   # (P, C)
    lum = np.array([0.2126, 0.7152, 0.0722])
    x = np.zeros(0)
    n = 0
    for _ in range(n_lobes):
        B = basis(x, n)
        C = _solve_colours(B, Y, w)
        r = ((Y - B @ C) @ lum) * w
        if np.sum(((Y - B @ C) * w[:, None]) ** 2) <= 1e-10 * np.sum((Y * w[:, None]) ** 2):
            break  # already exact (e.g. a flat tile of a Cycles-representable material)
        cw = cand_cols * w[:, None]
        score = np.where(cw.T @ r > 0, (cw.T @ r) ** 2 / np.maximum((cw ** 2).sum(0), 1e-300), 0.0)
        if score.max() <= 1e-12 * max(float((Y @ lum * w) @ (Y @ lum * w)), 1e-300):
            break
        t, a, p, al = cand[int(np.argmax(score))]
        x = np.concatenate([x, [t, a, p, np.log(al), np.log(al)]])
        n += 1

    def resid(xv):
        B = basis(xv, n)
        C = _solve_colours(B, Y, w)
        return ((B @ C - Y) * w[:, None]).ravel()

    nfev = 0
    if n:
        lo = np.tile([0.0, -4 * np.pi, -4 * np.pi, np.log(_ALPHA_MIN), np.log(_ALPHA_MIN)], n)
        hi = np.tile([_TILT_MAX if tilted else 1e-9, 4 * np.pi, 4 * np.pi, np.log(_ALPHA_MAX), np.log(_ALPHA_MAX)], n)
        x0 = np.clip(x, lo, hi)
        sol = least_squares(resid, x0, bounds=(lo, hi), max_nfev=max_nfev, x_scale=np.tile([0.3, 1, 1, 1, 1], n),
                            diff_step=1e-3)
        x = sol.x if sol.cost <= 0.5 * float(resid(x0) @ resid(x0)) else x0
        nfev = sol.nfev
    B = basis(x, n)
    C = _solve_colours(B, Y, w)
    model = B @ C
    lobes = []
    if n:
        t, ph, ps, ax, ay = _unpack(x, n)
        for k in range(n):
            if C[k + 1].max() <= 0:
                continue  # NNLS switched it off
            lobes.append(GGXLobe(float(t[k]), float(np.mod(ph[k], 2 * np.pi)), float(np.mod(ps[k], np.pi)),
                                 float(ax[k]), float(ay[k]), C[k + 1].copy()))
    rel = float(np.abs(model - Y).sum() / max(np.abs(Y).sum(), 1e-300))
    mse = float(np.mean((model - Y) ** 2))
    peak = float(np.abs(Y).max())
    p = float("inf") if mse == 0 else float(10 * np.log10(peak * peak / mse)) if peak > 0 else 0.0
    return ClosureFit(C[0].copy(), lobes, rel, p, {"nfev": nfev, "n_lobes": len(lobes), "dir_res": res})
