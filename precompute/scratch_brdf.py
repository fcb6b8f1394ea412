"""Single-scratch BRDF tables (Raymond et al. 2016, §4.1-4.2, §5.1).

Angles (§4.1): for a direction w in the scratch frame (u along the scratch, n the surface
normal, v = n x u across it), ``theta = asin(w . u)`` and ``phi = atan2(w . v, w . n)``, both in
radians in [-pi/2, pi/2].  Light only leaves on the cone ``theta_i = -theta_o`` (eq. 1), so
the mirror scratch BRDF is a 2D function ``rho_m(phi_o, phi_i)``, simulated in the 2D (v, n)
plane of the profile.  With Fresnel (§4.2) three 2D tables suffice:
``rho0 = rho_s(theta_o = 0)``, ``rho_m = rho_s(pi/2)`` (F = 1 at grazing) and the exponent
``gamma`` of ``R_gamma(theta) = (2 |theta| / pi)^gamma``, fitted by direct inversion at pi/3:

    rho_s(theta_o, phi_o, phi_i) = R_gamma(theta_o) rho_m + (1 - R_gamma(theta_o)) rho0     (eq. 2)

Tables
------
``rho0``, ``rho_m``, ``gamma`` are float32, shape ``[M, M]`` (mono) or ``[M, M, C]`` (colour),
indexed ``[phi_o_bin, phi_i_bin]``; bin k covers ``[-pi/2 + k pi/M, -pi/2 + (k+1) pi/M]``
(centre ``-pi/2 + (k + 0.5) pi/M``).  An entry is the *cosine-weighted bin average*

    rho[o, i] = (1 / (C_o C_i)) * integral over bins o x i of rho(phi_o, phi_i) cos(phi_o) cos(phi_i),
    C_k = integral of cos(phi) over bin k = sin(edge_{k+1}) - sin(edge_k),

so that reciprocity holds bin by bin (``rho[o, i] == rho[i, o]``) and energy is exact at any M:
for a lossless profile ``sum_o C_o rho_m[o, i] == 1`` for every i (to the measured ``lost``
energy, < 1e-6).  The midpoint form ``(pi/M) sum_o rho_m[o, i] cos(phi_o centre)`` equals
``1 / sinc(pi / 2M) = 1 + (pi/M)^2 / 24`` (1.0001 at M = 64, 1.000005 at M = 256).

From the 2D table to a 3D BRDF (the cone measure)
-------------------------------------------------
With ``dw = cos(theta) dtheta dphi`` and ``w . n = cos(theta) cos(phi)``, the 3D BRDF is

    f(w_o, w_i) = rho_s(theta_o, phi_o, phi_i) * delta(theta_i + theta_o) / cos(theta_o)^2,

i.e. ``L_o(w_o) = integral over phi_i of rho_s(theta_o, phi_o, phi_i) L_i(-theta_o, phi_i) cos(phi_i) dphi_i``
(the paper's eq. 5).  The white-furnace albedo of a view ``w_o`` is therefore
``sum_i C_i rho_s[o, i]`` (exactly 1 for ``rho_m`` of a lossless profile), independent of theta_o.
A renderer that reads a slice as a piecewise-constant function of phi_i on each bin must weight
bin i by ``C_i`` (not by ``pi/M cos(phi_i centre)``) to keep that furnace exact.

Simulation
----------
``method="exact"`` (default): exact 2D beam tracing of the polyline (``precompute.scratch_beam``):
each incident direction gives a finite sum of exit directions.  They are traced at the M*K+1
bin edges (K = ``supersample``); each exit *path* (segment sequence) is followed between two
neighbouring edges, its exit angle moves as ``phi_o = (-1)^bounces phi_i + const`` (exact) and
its weight is interpolated linearly, and the cosine-weighted integral over the phi_i bin is
split exactly over the phi_o bins it crosses.  Error is second order in the bin width, noise-free.
Symmetric profiles trace only phi_i <= 0 (anti-diagonal symmetry ``rho(phi_o, phi_i) =
rho(-phi_o, -phi_i)``).  ``method="mc"``: Monte Carlo reference (``precompute.scratch_mc``).

Recursion limit: at most ``max_bounces`` (64) reflections, and tracing stops once every
incident direction has less than 1e-7 of its light inside; what is left is ``lost`` (max over
phi_i of the unaccounted fraction), stored with the table.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from . import cache as _cache
from . import exr_io
from .profiles import Profile
from .scratch_beam import trace_exact
from .scratch_mc import trace_mc

__all__ = [
    "ScratchBRDF",
    "simulate",
    "simulate_theta",
    "bin_edges",
    "bin_centres",
    "bin_cos_integrals",
    "gamma_from_slices",
    "VERSION",
    "MAX_BOUNCES",
    "MIN_ENERGY",
    "GAMMA_RANGE",
]

VERSION = "1"
MAX_BOUNCES = 64
MIN_ENERGY = 1e-7
GAMMA_RANGE = (0.01, 100.0)
THETA_FIT = np.pi / 3  # the direct-inversion slice of §4.2
_EDGE_EPS = 1e-6  # the bin edges at +-pi/2 are traced at +-(pi/2 - eps)
_GRADE_LEVELS = 8


def bin_edges(M: int) -> np.ndarray:
    """The M + 1 bin edges ``-pi/2 + k pi/M`` (radians)."""
    return -0.5 * np.pi + np.arange(M + 1) * (np.pi / M)


def bin_centres(M: int) -> np.ndarray:
    """Bin centres ``-pi/2 + (k + 0.5) pi/M`` (radians)."""
    return -0.5 * np.pi + (np.arange(M) + 0.5) * (np.pi / M)


def bin_cos_integrals(M: int) -> np.ndarray:
    """``C_k`` = integral of cos(phi) over bin k = ``sin(edge_{k+1}) - sin(edge_k)``."""
    return np.diff(np.sin(bin_edges(M)))


def _bin_index(phi, M: int):
    return np.clip(np.floor((np.asarray(phi, np.float64) + 0.5 * np.pi) * (M / np.pi)), 0, M - 1).astype(np.intp)


def gamma_from_slices(rho0, rho_third, rho_m):
    """Direct inversion of ``R_gamma(pi/3) = (2/3)^gamma`` (§4.2).

    ``r = (rho(pi/3) - rho0) / (rho_m - rho0)``, ``gamma = ln r / ln(2/3)``.  Fallbacks keep gamma
    finite: where ``rho_m - rho0 <= 1e-6 rho_m`` or ``rho_m <= 1e-9 max(rho_m)`` (no theta dependence:
    any gamma gives the same value) gamma = 1; r is clipped to [1e-12, 1] and gamma to ``GAMMA_RANGE`` = [0.01, 100].
    """
    rho0, rho_third, rho_m = (np.asarray(a, np.float64) for a in (rho0, rho_third, rho_m))
    diff = rho_m - rho0
    scale = max(float(np.max(rho_m, initial=0.0)), 1e-300)
    ok = (diff > 1e-6 * rho_m) & (rho_m > 1e-9 * scale)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(ok, (rho_third - rho0) / np.where(ok, diff, 1.0), 1.0)
    r = np.clip(r, 1e-12, 1.0)
    gamma = np.where(ok, np.log(r) / np.log(2.0 / 3.0), 1.0)
    return np.clip(gamma, *GAMMA_RANGE)


@dataclass(frozen=True, eq=False)
class ScratchBRDF:
    """Precomputed scratch BRDF (Raymond et al. 2016, eq. 2): ``rho0``, ``rho_m``, ``gamma`` tables.

    Arrays are float32, ``[M, M]`` or ``[M, M, C]``, indexed ``[phi_o_bin, phi_i_bin]`` (see module doc).
    ``bounces``: optional ``[3, M, M]`` split of ``rho_m`` into 1st, 2nd and >= 3rd bounce light.
    ``lost``: max over phi_i of the flux not accounted for by the simulation.
    """

    rho0: np.ndarray
    rho_m: np.ndarray
    gamma: np.ndarray
    bounces: np.ndarray | None = None
    lost: float = 0.0
    meta: dict = field(default_factory=dict)

    @property
    def resolution(self) -> int:
        return int(self.rho_m.shape[0])

    @property
    def channels(self) -> int:
        return 1 if self.rho_m.ndim == 2 else int(self.rho_m.shape[2])

    # ---- evaluation (eq. 2) ----
    def eval(self, theta_o, phi_o, phi_i) -> np.ndarray:
        """``rho_s(theta_o, phi_o, phi_i)`` by eq. 2 (radians, broadcastable arrays).

        Bins are read as piecewise constant; returns shape ``broadcast`` (mono) or ``broadcast + (C,)``.
        Directions below the horizon (|phi| > pi/2) give 0.  Multiply by
        ``delta(theta_i + theta_o) / cos(theta_o)^2`` for the 3D BRDF (module doc).
        """
        th, po, pi_ = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (theta_o, phi_o, phi_i)))
        M = self.resolution
        o, i = _bin_index(po, M), _bin_index(pi_, M)
        g = self.gamma[o, i].astype(np.float64)
        t = np.clip(2.0 * np.abs(np.nan_to_num(th)) / np.pi, 0.0, 1.0)
        if self.channels > 1:
            t = t[..., None]
        R = t**g
        val = R * self.rho_m[o, i] + (1.0 - R) * self.rho0[o, i]
        inside = (np.abs(po) <= 0.5 * np.pi) & (np.abs(pi_) <= 0.5 * np.pi)
        if self.channels > 1:
            inside = inside[..., None]
        return np.where(inside, val, 0.0)

    def albedo(self, theta_o: float = 0.5 * np.pi) -> np.ndarray:
        """Directional albedo ``sum_o C_o rho_s[o, i]`` for each phi_i bin (1 for a lossless ``rho_m``)."""
        M = self.resolution
        c = bin_centres(M)
        rho = self.eval(theta_o, c[:, None], c[None, :])
        w = bin_cos_integrals(M)
        return np.tensordot(w, rho, axes=(0, 0))

    # ---- importance sampling (§5.1): PDF_phi_o(phi_i) ~ rho_m(phi_o, phi_i) cos(phi_i) ----
    def _mono_m(self) -> np.ndarray:
        return self.rho_m if self.rho_m.ndim == 2 else self.rho_m[..., 0]

    @property
    def cdf(self) -> np.ndarray:
        """Per phi_o slice, the CDF over phi_i bin edges, shape ``[M, M + 1]`` (from ``rho_m``)."""
        mass = self._mono_m().astype(np.float64) * bin_cos_integrals(self.resolution)[None, :]
        c = np.concatenate([np.zeros((mass.shape[0], 1)), np.cumsum(mass, 1)], 1)
        tot = c[:, -1:]
        uniform = np.linspace(0.0, 1.0, c.shape[1])[None, :]
        return np.where(tot > 0, c / np.where(tot > 0, tot, 1.0), uniform)

    def pdf(self, phi_o, phi_i) -> np.ndarray:
        """Density (per radian of phi_i) of ``sample`` for view ``phi_o``: ``rho_m cos(phi_i) / norm``."""
        po, pi_ = np.broadcast_arrays(np.asarray(phi_o, np.float64), np.asarray(phi_i, np.float64))
        M = self.resolution
        cdf = self.cdf
        o, i = _bin_index(po, M), _bin_index(pi_, M)
        mass = cdf[o, i + 1] - cdf[o, i]
        C = bin_cos_integrals(M)[i]
        p = mass / C * np.cos(pi_)
        return np.where(np.abs(pi_) <= 0.5 * np.pi, np.maximum(p, 0.0), 0.0)

    def sample(self, phi_o, u) -> tuple[np.ndarray, np.ndarray]:
        """Draw phi_i for view ``phi_o`` from uniform ``u`` in [0, 1) by the inverse CDF; returns ``(phi_i, pdf)``."""
        po, u = np.broadcast_arrays(np.asarray(phi_o, np.float64), np.asarray(u, np.float64))
        M = self.resolution
        cdf = self.cdf
        o = _bin_index(po, M)
        uu = np.clip(u, 0.0, np.nextafter(1.0, 0.0))
        flat = (cdf + 2.0 * np.arange(M)[:, None]).ravel()  # rows made globally increasing
        pos = np.searchsorted(flat, uu + 2.0 * o, side="right") - 1
        i = np.clip(pos - o * (M + 1), 0, M - 1)
        lo, hi = cdf[o, i], cdf[o, i + 1]
        t = np.where(hi > lo, (uu - lo) / np.where(hi > lo, hi - lo, 1.0), 0.5)
        e = bin_edges(M)
        s = np.sin(e[i]) + np.clip(t, 0.0, 1.0) * (np.sin(e[i + 1]) - np.sin(e[i]))
        phi_i = np.arcsin(np.clip(s, -1.0, 1.0))
        return phi_i, self.pdf(po, phi_i)

    def inverse_cdf(self, n: int | None = None) -> np.ndarray:
        """Inverse-CDF table ``[M, n]``: phi_i reached at ``u = (k + 0.5) / n`` for each phi_o slice (§5.1)."""
        M = self.resolution
        n = M if n is None else int(n)
        if n < 1:
            raise ValueError(f"n: expected a positive integer, got {n}")
        u = (np.arange(n) + 0.5) / n
        phi_o = np.repeat(bin_centres(M)[:, None], n, 1)
        return self.sample(phi_o, np.broadcast_to(u, (M, n)))[0]

    # ---- persistence ----
    def arrays(self) -> dict[str, np.ndarray]:
        out = {"rho0": self.rho0, "rho_m": self.rho_m, "gamma": self.gamma,
               "lost": np.array([self.lost], np.float32)}
        if self.bounces is not None:
            out["bounces"] = self.bounces
        return out

    @classmethod
    def from_arrays(cls, arrays: dict, meta: dict | None = None) -> "ScratchBRDF":
        b = arrays.get("bounces")
        return cls(
            rho0=np.asarray(arrays["rho0"], np.float32), rho_m=np.asarray(arrays["rho_m"], np.float32),
            gamma=np.asarray(arrays["gamma"], np.float32),
            bounces=None if b is None else np.asarray(b, np.float32),
            lost=float(np.asarray(arrays.get("lost", [0.0])).ravel()[0]), meta=dict(meta or {}))

    def save(self, path: str | os.PathLike) -> None:
        """Write the tables to an EXR file (atomic; channels ``rho0``, ``rho_m``, ``gamma`` [.R/.G/.B])."""
        chans = {}
        names = ["R", "G", "B"] if self.channels == 3 else [str(c) for c in range(self.channels)]
        for key in ("rho0", "rho_m", "gamma"):
            a = getattr(self, key)
            if a.ndim == 2:
                chans[key] = a
            else:
                for c in range(a.shape[2]):
                    chans[f"{key}.{names[c]}"] = a[..., c]
        if self.bounces is not None:
            for b in range(self.bounces.shape[0]):
                chans[f"rho_m_bounce{b + 1}"] = self.bounces[b]
        meta = {"format": "scratch_brdf", "version": VERSION, "channels": self.channels, "lost": self.lost,
                "channel_names": names, "meta": _jsonable(self.meta)}
        exr_io.write_exr(path, chans, meta)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "ScratchBRDF":
        """Read tables written by ``save``."""
        chans, meta = exr_io.read_exr(path)
        if not meta or meta.get("format") != "scratch_brdf":
            raise exr_io.ExrError(f"{os.fspath(path)}: not a scratch BRDF table")
        C, names = int(meta["channels"]), meta["channel_names"]
        arrays = {}
        for key in ("rho0", "rho_m", "gamma"):
            arrays[key] = chans[key] if key in chans else np.stack([chans[f"{key}.{n}"] for n in names[:C]], -1)
        nb = sorted(k for k in chans if k.startswith("rho_m_bounce"))
        if nb:
            arrays["bounces"] = np.stack([chans[f"rho_m_bounce{b + 1}"] for b in range(len(nb))])
        arrays["lost"] = [meta.get("lost", 0.0)]
        return cls.from_arrays(arrays, meta.get("meta"))


def _jsonable(d):
    if isinstance(d, dict):
        return {str(k): _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    if isinstance(d, (np.floating, np.integer)):
        return d.item()
    if isinstance(d, np.ndarray):
        return d.tolist()
    return d


# ---------------------------------------------------------------------------------------------
# exact method: trace at bin edges, follow each path across a phi_i bin, integrate exactly
# ---------------------------------------------------------------------------------------------
def _exact_tables(profile: Profile, M: int, K: int, fresnel, cos_scales, split: bool, max_bounces: int):
    """Cosine-weighted bin averages ``acc[component, class, o, i]`` from exact beam tracing.

    Components: 0 = no Fresnel, then one per (Fresnel slice, channel).  Classes: bounce order
    1, 2, >= 3 when ``split`` (else one class).  Returns (tables, lost).
    """
    verts = profile.periodic_vertices()
    edges = _sub_edges(M, K)
    MK = edges.size - 1  # number of sub-bins
    nodes = np.clip(edges, -0.5 * np.pi + _EDGE_EPS, 0.5 * np.pi - _EDGE_EPS)
    sym = bool(profile.is_symmetric)
    traced = np.arange(MK // 2 + 1) if sym else np.arange(MK + 1)
    rec = trace_exact(verts, nodes[traced], fresnel, cos_scales, max_bounces=max_bounces, min_energy=MIN_ENERGY)
    e = traced[rec.sample]
    pid, nb, phi_o = rec.pid, rec.bounces, rec.phi_o
    W = rec.weight[:, None]
    if rec.fresnel is not None:
        W = np.concatenate([W, rec.fresnel.reshape(rec.fresnel.shape[0], -1)], 1)
    AB = rec.flux_ab
    lost = np.zeros(MK + 1)
    lost[traced] = rec.lost
    if sym:  # rho(phi_o, phi_i) = rho(-phi_o, -phi_i): mirror the records of phi_i < 0
        m = (MK - e) != e
        e = np.concatenate([e, MK - e[m]])
        pid = np.concatenate([pid, rec.pid_mirror[m]])
        nb = np.concatenate([nb, nb[m]])
        phi_o = np.concatenate([phi_o, -phi_o[m]])
        W = np.concatenate([W, W[m]])
        AB = np.concatenate([AB, AB[m] * np.array([1.0, -1.0])])
        lost[MK - traced] = np.maximum(lost[MK - traced], rec.lost)
    # Fresnel factor of each record (relative to its geometric weight)
    Fr = W[:, 1:] / np.maximum(W[:, :1], 1e-300)

    # each record is the left end of sub-bin e and the right end of sub-bin e - 1
    li, ri = np.flatnonzero(e < MK), np.flatnonzero(e > 0)
    b = np.concatenate([e[li], e[ri] - 1])
    rid = np.concatenate([li, ri])
    is_left = np.concatenate([np.ones(li.size, bool), np.zeros(ri.size, bool)])
    p = pid[rid]
    order = np.lexsort((p, b))
    b, rid, is_left, p = b[order], rid[order], is_left[order], p[order]
    start = np.flatnonzero(np.concatenate([[True], (b[1:] != b[:-1]) | (p[1:] != p[:-1])]))
    side = is_left[:, None]
    red = lambda v, sel: np.add.reduceat(np.where(sel, v, 0.0), start, axis=0)  # noqa: E731
    ABr, Frr = AB[rid], Fr[rid]
    abL, abR = red(ABr, side), red(ABr, ~side)
    nL, nR = red(np.ones((rid.size, 1)), side)[:, 0], red(np.ones((rid.size, 1)), ~side)[:, 0]
    FL = red(Frr, side) / np.maximum(nL, 1)[:, None]
    FR = red(Frr, ~side) / np.maximum(nR, 1)[:, None]
    hasL, hasR = nL > 0, nR > 0
    FL = np.where(hasL[:, None], FL, FR)
    FR = np.where(hasR[:, None], FR, FL)
    r0 = rid[start]
    gb = b[start]
    sgn = np.where(nb[r0] % 2 == 0, 1.0, -1.0)
    c = phi_o[r0] - sgn * nodes[e[r0]]  # exit angle of the path: phi_o = sgn * phi_i + c
    phi_a, phi_b = edges[gb], edges[gb + 1]
    pa, pb = nodes[gb], nodes[gb + 1]

    # split the sub-bin where the exit angle crosses a phi_o bin edge (at most one crossing)
    y_a, y_b = c + sgn * phi_a, c + sgn * phi_b
    y1, y2, ym = np.minimum(y_a, y_b), np.maximum(y_a, y_b), 0.5 * (y_a + y_b)
    jb = np.rint((ym + 0.5 * np.pi) * (M / np.pi))  # the phi_o bin edge nearest the image centre
    yb = -0.5 * np.pi + jb * (np.pi / M)
    cross = (yb > y1) & (yb < y2)
    k_mid = _bin_index(ym, M)
    k1 = np.where(cross, np.clip(jb - 1, 0, M - 1).astype(np.intp), k_mid)
    k2 = np.where(cross, np.clip(jb, 0, M - 1).astype(np.intp), k_mid)
    split_phi = np.where(cross, np.clip(sgn * (yb - c), phi_a, phi_b), phi_b)
    # a path only exists while it leaves above the horizon: clip phi_i to |c + sgn phi_i| <= pi/2
    v1, v2 = sgn * (-0.5 * np.pi - c), sgn * (0.5 * np.pi - c)
    lo_v, hi_v = np.minimum(v1, v2), np.maximum(v1, v2)
    phi_a = np.clip(phi_a, lo_v, hi_v)
    phi_b = np.clip(phi_b, lo_v, hi_v)
    split_phi = np.clip(split_phi, phi_a, phi_b)
    o_first = np.where(sgn > 0, k1, k2)
    o_second = np.where(sgn > 0, k2, k1)

    # A path bounded by the same two vertices at both ends of the sub-bin has the exact flux
    # A cos + B sin in between (times a Fresnel factor, interpolated linearly).  Paths that change
    # (visibility events: they appear, vanish or change occluder) get their flux interpolated
    # linearly, rescaled so that each sub-bin keeps exactly its incident energy.
    AL, BL = abL[:, 0], abL[:, 1]
    AR, BR = abR[:, 0], abR[:, 1]
    same = hasL & hasR & (np.abs(AL - AR) + np.abs(BL - BR) <= 1e-9 * (np.abs(AL) + np.abs(BL)) + 1e-15)
    slope = (FR - FL) / np.maximum(pb - pa, 1e-300)[:, None]
    al = np.concatenate([np.ones((gb.size, 1)), FL - slope * pa[:, None]], 1)
    be = np.concatenate([np.zeros((gb.size, 1)), slope], 1)
    fL = red(W[rid], side) * np.cos(pa)[:, None]
    fR = red(W[rid], ~side) * np.cos(pb)[:, None]
    dp = np.maximum(pb - pa, 1e-300)[:, None]
    fs = (fR - fL) / dp
    f0 = fL - fs * pa[:, None]

    def S(x):
        sx, cx = np.sin(x), np.cos(x)
        xs = x[:, None]
        exact = al * (AL * sx - BL * cx)[:, None] + be * (AL * (x * sx + cx) + BL * (sx - x * cx))[:, None]
        return np.where(same[:, None], exact, f0 * xs + 0.5 * fs * xs * xs)

    Sa, Ss, Sb = S(phi_a), S(split_phi), S(phi_b)
    I1, I2 = Ss - Sa, Sb - Ss
    # energy of each sub-bin: integral of cos(phi) (1 - lost), lost interpolated linearly
    target = (np.sin(edges[1:]) - np.sin(edges[:-1])) * (1.0 - 0.5 * (lost[:-1] + lost[1:]))
    tot = I1[:, 0] + I2[:, 0]
    got_same = np.bincount(gb, np.where(same, tot, 0.0), minlength=MK)
    got_lin = np.bincount(gb, np.where(same, 0.0, tot), minlength=MK)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(got_lin > 0, (target - got_same) / got_lin, 1.0)
    scale = np.where(np.isfinite(scale) & (scale > 0.5) & (scale < 2.0), scale, 1.0)
    fac = np.where(same, 1.0, scale[gb])[:, None]
    I1, I2 = I1 * fac, I2 * fac
    ibin = _bin_index(0.5 * (edges[gb] + edges[gb + 1]), M)
    cls = np.minimum(nb[r0], 3) - 1 if split else np.zeros(gb.size, np.intp)
    ncls = 3 if split else 1
    nW = W.shape[1]
    size = ncls * M * M
    idx1 = (cls * M + o_first) * M + ibin
    idx2 = (cls * M + o_second) * M + ibin
    acc = np.empty((nW, ncls, M, M))
    for comp in range(nW):
        a = np.bincount(idx1, I1[:, comp], minlength=size) + np.bincount(idx2, I2[:, comp], minlength=size)
        acc[comp] = a.reshape(ncls, M, M)
    Ck = bin_cos_integrals(M)
    acc /= (Ck[:, None] * Ck[None, :])
    np.maximum(acc, 0.0, out=acc)  # rounding of cancelling integrals (~1e-14)
    # lost flux per phi_i bin: the largest over its nodes
    lost_bins = np.zeros(M)
    np.maximum.at(lost_bins, _bin_index(0.5 * (edges[:-1] + edges[1:]), M), np.maximum(lost[:-1], lost[1:]))
    return acc, float(lost_bins.max(initial=0.0))


def _sub_edges(M: int, K: int) -> np.ndarray:
    """Edges of the phi_i sub-bins where paths are traced: K per bin, plus a graded refinement
    (halving ``_GRADE_LEVELS`` times) inside the two grazing bins, where the lit part of the
    profile shrinks to the rims and path weights stop being linear in phi_i.  Symmetric about 0."""
    d = np.pi / (M * K)
    half = -0.5 * np.pi + np.arange(0, (M * K) // 2 + 1) * d
    step = d * 0.5 ** np.arange(1, _GRADE_LEVELS + 1)
    grade = -0.5 * np.pi + step[step > 8 * _EDGE_EPS]  # stay clear of the traced end nodes
    neg = np.union1d(half, grade)
    neg = neg[neg <= 0.0]
    e = np.union1d(neg, -neg)
    return e


def _check_args(profile, resolution, fresnel, method, supersample, rays_per_slice, max_bounces):
    if not isinstance(profile, Profile):
        raise ValueError(f"profile: expected a precompute.profiles.Profile, got {type(profile).__name__}")
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or not 2 <= resolution <= 4096:
        raise ValueError(f"resolution: expected an integer in [2, 4096], got {resolution!r}")
    if fresnel is not None and not (callable(fresnel) and getattr(fresnel, "channels", 0) in (1, 3)):
        raise ValueError("fresnel: expected None or a precompute.fresnel model (callable with .channels of 1 or 3)")
    if method not in ("exact", "mc"):
        raise ValueError(f"method: expected 'exact' or 'mc', got {method!r}")
    if isinstance(supersample, bool) or not isinstance(supersample, (int, np.integer)) or not 1 <= supersample <= 64:
        raise ValueError(f"supersample: expected an integer in [1, 64], got {supersample!r}")
    if isinstance(rays_per_slice, bool) or not isinstance(rays_per_slice, (int, np.integer)) or not 1 <= rays_per_slice <= 10**8:
        raise ValueError(f"rays_per_slice: expected an integer in [1, 1e8], got {rays_per_slice!r}")
    if isinstance(max_bounces, bool) or not isinstance(max_bounces, (int, np.integer)) or not 1 <= max_bounces <= 10_000:
        raise ValueError(f"max_bounces: expected an integer in [1, 10000], got {max_bounces!r}")


def _slices(profile, M, fresnel, theta_o, method, supersample, rays_per_slice, seed, split, max_bounces):
    """rho_s at theta_o values (+ the lossless rho_m): returns (rho_m [M,M], rho_t [T,M,M,C] | None, bounces, lost)."""
    theta_o = np.atleast_1d(np.asarray(theta_o, np.float64))
    cos_scales = np.cos(theta_o) if fresnel is not None else np.zeros(0)
    if method == "exact":
        acc, lost = _exact_tables(profile, M, supersample, fresnel, tuple(cos_scales), split, max_bounces)
        rho_m = acc[0].sum(0)
        bounces = acc[0] if split else None
        rho_t = None
        if fresnel is not None and theta_o.size:
            C = fresnel.channels
            rho_t = np.moveaxis(acc[1:].sum(1).reshape(theta_o.size, C, M, M), 1, -1)
        return rho_m, rho_t, bounces, lost
    rho_m, rho_t, lost = trace_mc(profile.periodic_vertices(), M, rays_per_slice, seed, fresnel, tuple(cos_scales),
                                  max_bounces=max_bounces)
    return rho_m, rho_t, None, float(lost.max(initial=0.0))


def simulate_theta(profile: Profile, theta_o, resolution: int = 256, fresnel=None, *, method: str = "exact",
                   supersample: int = 1, rays_per_slice: int = 10_000, seed: int = 0,
                   max_bounces: int = MAX_BOUNCES) -> np.ndarray:
    """Simulated ``rho_s(theta_o, phi_o, phi_i)`` for each ``theta_o`` (radians), shape ``[T, M, M, C]``.

    The full 3D scratch BRDF that eq. 2 approximates (§4.2, Fig. 6); ``fresnel=None`` gives rho_m.
    """
    _check_args(profile, resolution, fresnel, method, supersample, rays_per_slice, max_bounces)
    th = np.atleast_1d(np.asarray(theta_o, np.float64))
    if not np.all(np.isfinite(th)) or np.any(np.abs(th) > 0.5 * np.pi):
        raise ValueError(f"theta_o: expected finite angles in [-pi/2, pi/2], got {th}")
    rho_m, rho_t, _, _ = _slices(profile, resolution, fresnel, np.abs(th), method, supersample, rays_per_slice,
                                 seed, False, max_bounces)
    if rho_t is None:
        return np.broadcast_to(rho_m[None, :, :, None], (th.size,) + rho_m.shape + (1,)).copy()
    return rho_t


def simulate(profile: Profile, resolution: int = 256, fresnel=None, *, method: str = "exact",
             supersample: int = 1, split_bounces: bool = False, rays_per_slice: int = 10_000, seed: int = 0,
             max_bounces: int = MAX_BOUNCES, cache: bool = False) -> ScratchBRDF:
    """Simulate the scratch BRDF of ``profile`` (Raymond et al. 2016, §4.1-4.2) on an M x M grid.

    ``fresnel``: None (lossless mirror: ``rho0 == rho_m``, gamma = 1) or a ``precompute.fresnel`` model;
    ``method``: "exact" (beam tracing, ``supersample`` K traces per bin edge interval) or "mc"
    (``rays_per_slice``, ``seed``); ``split_bounces``: also return rho_m split into 1st / 2nd / >= 3rd
    bounce light (Fig. 5); ``cache``: reuse an identical earlier result from ``precompute.cache``.
    """
    _check_args(profile, resolution, fresnel, method, supersample, rays_per_slice, max_bounces)
    M = int(resolution)

    def compute():
        rho_m, rho_t, bounces, lost = _slices(profile, M, fresnel, (0.0, THETA_FIT), method, supersample,
                                              rays_per_slice, seed, split_bounces, max_bounces)
        if rho_t is None:
            rho0 = rho_m.copy()
            gamma = np.ones_like(rho_m)
        else:
            rm = rho_m[..., None]
            rho0, rho60 = rho_t[0], rho_t[1]
            gamma = gamma_from_slices(rho0, rho60, np.broadcast_to(rm, rho0.shape))
            if rho0.shape[-1] == 1:
                rho0, gamma = rho0[..., 0], gamma[..., 0]
            else:
                rho_m = np.broadcast_to(rm, rho0.shape)
        out = {"rho0": rho0.astype(np.float32), "rho_m": np.ascontiguousarray(rho_m, np.float32),
               "gamma": gamma.astype(np.float32), "lost": np.array([lost], np.float32)}
        if bounces is not None:
            out["bounces"] = bounces.astype(np.float32)
        return out

    inputs = {"profile": profile, "resolution": M, "fresnel": fresnel, "method": method,
              "supersample": int(supersample), "split_bounces": bool(split_bounces), "max_bounces": int(max_bounces)}
    if method == "mc":
        inputs.update(rays_per_slice=int(rays_per_slice), seed=int(seed))
    arrays = _cache.cached_arrays("scratch_brdf", VERSION, inputs, compute, enabled=bool(cache))
    meta = {"profile": profile.name, "profile_params": dict(profile.params), "segments": profile.segments,
            "fresnel": None if fresnel is None else fresnel.cache_key(), "method": method,
            "supersample": int(supersample)}
    return ScratchBRDF.from_arrays(arrays, meta)
