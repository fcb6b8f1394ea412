"""Ellipsoid NDF (Dong et al. 2015, §8, eqs. 10-14) plus Beckmann / GGX comparison lobes and fits.

Conventions
-----------
* Directions are unit 3-vectors in the *surface frame*: ``n = (0, 0, 1)`` is the mean normal.
* The ellipsoid NDF has five parameters ``(alpha_x, alpha_y, theta_x, theta_y, theta_z)``
  (dimensionless roughnesses, angles in radians).  ``A = S R`` with
  ``S = diag(alpha_x, alpha_y, 1)`` and ``R = Rx(theta_x) Ry(theta_y) Rz(theta_z)`` (eqs. 11-12),
  using right-handed rotations ``Rx(t) = [[1,0,0],[0,c,-s],[0,s,c]]`` etc.
* Normalisation is the paper's: ``∫_{m·n>0} D(m) (m·n) dω = 1``.  In the orthographic disk
  coordinates ``(m_x, m_y)`` used by the tabulated NDFs, ``dω = dm_x dm_y / m_z``, so
  ``D(m) (m·n) dω = D(m) dm_x dm_y``: the projected-area density per unit disk area *is* ``D``.
* ``pdf(m) = D(m) (m·n)`` per steradian is what :func:`sample_ellipsoid` draws from.

Fits (:func:`fit_ellipsoid`, :func:`fit_beckmann`, :func:`fit_ggx`) minimise the L2 distance
``∫ (D_fit - D_tab)^2 dm_x dm_y`` over a node grid covering the table's support, with targets
averaged over each node's cell (4x4 supersampling).  L2 is unbiased for zero-mean histogram
noise (a Hellinger/sqrt objective was biased low by ~4 % on 640x480 filtered NDFs: E[sqrt(D)] <
sqrt(E[D])).  The squared Hellinger distance is reported as a scale-free fit quality.  The solver
is a batched Levenberg-Marquardt (vectorised over many tables at once, used for per-texel fits in §9).
"""
from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

__all__ = [
    "EllipsoidParams",
    "rotation_matrix",
    "ellipsoid_matrix",
    "ellipsoid_ndf",
    "ellipsoid_pdf",
    "canonical_params",
    "ellipsoid_g1",
    "sample_ellipsoid",
    "ggx_ndf",
    "beckmann_ndf",
    "fit_nodes",
    "box_nodes",
    "fit_ellipsoid",
    "fit_ellipsoid_samples",
    "fit_beckmann",
    "fit_ggx",
    "hellinger_distance",
]

ALPHA_MIN, ALPHA_MAX = 1e-4, 10.0
THETA_XY_MAX = np.pi / 2 - 1e-3


class EllipsoidParams(NamedTuple):
    """The five ellipsoid-NDF parameters of §8 (radians for the angles)."""

    alpha_x: float
    alpha_y: float
    theta_x: float
    theta_y: float
    theta_z: float


# ----------------------------------------------------------------------------- validation helpers


def _as_params(params) -> np.ndarray:
    """(..., 5) float array of validated ellipsoid parameters."""
    try:
        p = np.asarray(params, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"params: expected 5 numbers (alpha_x, alpha_y, theta_x, theta_y, theta_z), got {params!r}") from None
    if p.shape[-1:] != (5,):
        raise ValueError(f"params: expected 5 values (alpha_x, alpha_y, theta_x, theta_y, theta_z), got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("params: all values must be finite")
    a = p[..., :2]
    if np.any(a < ALPHA_MIN) or np.any(a > ALPHA_MAX):
        raise ValueError(f"params: alpha_x, alpha_y must lie in [{ALPHA_MIN}, {ALPHA_MAX}], got {a.min()}..{a.max()}")
    t = p[..., 2:4]
    if np.any(np.abs(t) > THETA_XY_MAX):
        raise ValueError(f"params: theta_x, theta_y must lie in (-pi/2, pi/2), got {t.min()}..{t.max()}")
    return p


def _as_dirs(m, name: str = "m") -> np.ndarray:
    """(N, 3) unit vectors; rejects non-finite or zero-length rows."""
    try:
        v = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an array of shape (N, 3) of numbers") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name}: expected an array of shape (N, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name}: all components must be finite")
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError(f"{name}: directions must have non-zero length")
    return v / norm


def _as_angle(t, name: str) -> np.ndarray:
    """A finite angle (radians, any real value: rotations are periodic) or array of them."""
    try:
        a = np.asarray(t, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an angle in radians (a finite number), got {t!r}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: must be a finite angle in radians, got {t!r}")
    return a


def _check_n_nodes(n_nodes) -> int:
    """Fit-grid size: an integer in [8, 512] (the fit needs several nodes per axis; 512^2 x 16 samples is the memory cap)."""
    if isinstance(n_nodes, (bool, np.bool_)) or not isinstance(n_nodes, (int, np.integer)) or not 8 <= n_nodes <= 512:
        raise ValueError(f"n_nodes: expected an integer in [8, 512], got {n_nodes!r}")
    return int(n_nodes)


def _as_alpha(a, name: str) -> np.ndarray:
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must lie in [{ALPHA_MIN}, {ALPHA_MAX}], got {a!r}") from None
    if not np.all(np.isfinite(a)) or np.any(a < ALPHA_MIN) or np.any(a > ALPHA_MAX):
        raise ValueError(f"{name}: must lie in [{ALPHA_MIN}, {ALPHA_MAX}]")
    return a


# ----------------------------------------------------------------------------- model


def rotation_matrix(theta_x, theta_y, theta_z) -> np.ndarray:
    """``R = Rx(theta_x) Ry(theta_y) Rz(theta_z)`` (eq. 12), batched: returns (..., 3, 3). Radians."""
    tx, ty, tz = np.broadcast_arrays(*(np.asarray(t, dtype=np.float64) for t in (theta_x, theta_y, theta_z)))
    o, z = np.ones_like(tx), np.zeros_like(tx)
    cx, sx, cy, sy, cz, sz = np.cos(tx), np.sin(tx), np.cos(ty), np.sin(ty), np.cos(tz), np.sin(tz)
    Rx = np.stack([o, z, z, z, cx, -sx, z, sx, cx], -1).reshape(tx.shape + (3, 3))
    Ry = np.stack([cy, z, sy, z, o, z, -sy, z, cy], -1).reshape(tx.shape + (3, 3))
    Rz = np.stack([cz, -sz, z, sz, cz, z, z, z, o], -1).reshape(tx.shape + (3, 3))
    return Rx @ Ry @ Rz


def ellipsoid_matrix(params) -> np.ndarray:
    """``A = S R`` of eq. 11 for parameters (..., 5); returns (..., 3, 3)."""
    p = _as_params(params)
    R = rotation_matrix(p[..., 2], p[..., 3], p[..., 4])
    S = np.stack([p[..., 0], p[..., 1], np.ones_like(p[..., 0])], -1)
    return S[..., :, None] * R


def _ellipsoid_eval(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Unchecked eq. 10: m (..., 3) unit, p broadcastable (..., 5); explicit components for speed."""
    ax, ay = p[..., 0], p[..., 1]
    cx, sx = np.cos(p[..., 2]), np.sin(p[..., 2])
    cy, sy = np.cos(p[..., 3]), np.sin(p[..., 3])
    cz, sz = np.cos(p[..., 4]), np.sin(p[..., 4])
    x, y, z = m[..., 0], m[..., 1], m[..., 2]
    # R m with R = Rx Ry Rz: first Rz, then Ry, then Rx
    x1, y1 = cz * x - sz * y, sz * x + cz * y
    x2, z2 = cy * x1 + sy * z, -sy * x1 + cy * z
    y3, z3 = cx * y1 - sx * z2, sx * y1 + cx * z2
    q = (x2 / ax) ** 2 + (y3 / ay) ** 2 + z3**2  # ||A^{-T} m||^2 = ||S^{-1} R m||^2
    # R z = Rx Ry z = (sy, -sx cy, cx cy);  ||A n|| = ||S R z||;  |A| = ax ay
    An = np.sqrt((ax * sy) ** 2 + (ay * sx * cy) ** 2 + (cx * cy) ** 2)
    d = 1.0 / (np.pi * ax * ay * An * q * q)
    return np.where(z > 0, d, 0.0)


def canonical_params(params, theta_z_ref: float = 0.0) -> np.ndarray:
    """Map parameters to the equivalent set with ``theta_z`` within pi/2 of ``theta_z_ref``.

    Exact identity: ``Rz(pi)`` commutes with ``S`` and ``Rz(pi) Rx(a) Ry(b) = Rx(-a) Ry(-b) Rz(pi)``,
    so ``(theta_x, theta_y, theta_z)`` and ``(-theta_x, -theta_y, theta_z + pi)`` give the same
    ``A^T A`` and hence the same NDF (eq. 10).
    """
    p = np.array(_as_params(params), dtype=np.float64)
    k = np.round((p[..., 4] - theta_z_ref) / np.pi)
    flip = (k % 2) != 0
    p[..., 4] -= k * np.pi
    p[..., 2] = np.where(flip, -p[..., 2], p[..., 2])
    p[..., 3] = np.where(flip, -p[..., 3], p[..., 3])
    return p


def ellipsoid_ndf(m, params) -> np.ndarray:
    """Ellipsoid NDF ``D(m)`` per steradian (eq. 10), zero for ``m·n <= 0``.

    ``m``: (N, 3) directions (normalised here); ``params``: 5 values or (N, 5).
    Reduces to GTR2aniso for ``theta = 0`` and to GGX for ``alpha_x = alpha_y`` as well.
    """
    m = _as_dirs(m)
    p = _as_params(params)
    return _ellipsoid_eval(m, p)


def ellipsoid_pdf(m, params) -> np.ndarray:
    """Density of :func:`sample_ellipsoid` per steradian: ``D(m) (m·n)``."""
    m = _as_dirs(m)
    return _ellipsoid_eval(m, _as_params(params)) * np.maximum(m[:, 2], 0.0)


def ellipsoid_g1(u, params) -> np.ndarray:
    """Shadowing/masking ``G1(u)`` of eq. 14 (so ``G = G1(psi) G1(omega)``, eq. 13); 0 below the horizon."""
    u = _as_dirs(u, "u")
    A = ellipsoid_matrix(params)
    Au = np.einsum("...ij,...j->...i", A, u)
    An = A[..., :, 2]
    nAn = np.linalg.norm(An, axis=-1)
    num = 2.0 * nAn**2 * np.abs(u[:, 2])
    den = np.linalg.norm(Au, axis=-1) * nAn + np.sum(Au * An, axis=-1)
    g = np.minimum(1.0, num / np.maximum(den, 1e-300))
    return np.where(u[:, 2] > 0, g, 0.0)


def sample_ellipsoid(params, u1, u2) -> np.ndarray:
    """Draw normals with density ``D(m)(m·n)`` (eq. 10) from uniform numbers ``u1, u2`` in [0, 1).

    Geometric construction (exact): rays along ``-n`` hitting the ellipsoid uniformly over its
    shadow map (via ``A``) to rays along ``-An`` hitting the unit sphere uniformly over *its*
    shadow; the hit point ``s`` on the sphere's half facing ``An`` gives the ellipsoid normal
    ``m ∝ A^T s``, and ``m·n ∝ s·(An) > 0``.
    """
    A = ellipsoid_matrix(params)
    u1 = np.asarray(u1, dtype=np.float64)
    u2 = np.asarray(u2, dtype=np.float64)
    if u1.shape != u2.shape or u1.ndim != 1:
        raise ValueError("u1, u2: expected 1D arrays of equal length")
    if np.any((u1 < 0) | (u1 >= 1) | (u2 < 0) | (u2 >= 1)) or not (np.all(np.isfinite(u1)) and np.all(np.isfinite(u2))):
        raise ValueError("u1, u2: must lie in [0, 1)")
    d = A[..., :, 2] / np.linalg.norm(A[..., :, 2], axis=-1, keepdims=True)
    # orthonormal basis (e1, e2, d) (Duff et al. 2017 branchless ONB)
    sign = np.where(d[..., 2] >= 0, 1.0, -1.0)
    a = -1.0 / (sign + d[..., 2])
    b = d[..., 0] * d[..., 1] * a
    e1 = np.stack([1 + sign * d[..., 0] ** 2 * a, sign * b, -sign * d[..., 0]], -1)
    e2 = np.stack([b, sign + d[..., 1] ** 2 * a, -d[..., 1]], -1)
    r = np.sqrt(u1)
    phi = 2 * np.pi * u2
    x, y = r * np.cos(phi), r * np.sin(phi)
    zc = np.sqrt(np.maximum(0.0, 1 - x * x - y * y))
    s = x[:, None] * e1 + y[:, None] * e2 + zc[:, None] * d
    m = np.einsum("...ji,...j->...i", A, s)  # A^T s
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


def _rotate_z(m: np.ndarray, theta_z) -> np.ndarray:
    c, s = np.cos(theta_z), np.sin(theta_z)
    return np.stack([c * m[..., 0] - s * m[..., 1], s * m[..., 0] + c * m[..., 1], m[..., 2]], -1)


def ggx_ndf(m, alpha_x, alpha_y=None, theta_z=0.0) -> np.ndarray:
    """Anisotropic GGX / GTR2aniso NDF per steradian (Walter et al. 2007; Burley 2012 eq. 13).

    Lobe axes rotated by ``theta_z`` like the ellipsoid's ``Rz`` (identical to ``ellipsoid_ndf`` with
    ``theta_x = theta_y = 0``).
    """
    m = _as_dirs(m)
    ax = _as_alpha(alpha_x, "alpha_x")
    ay = ax if alpha_y is None else _as_alpha(alpha_y, "alpha_y")
    mr = _rotate_z(m, _as_angle(theta_z, "theta_z"))
    q = (mr[..., 0] / ax) ** 2 + (mr[..., 1] / ay) ** 2 + mr[..., 2] ** 2
    return np.where(m[:, 2] > 0, 1.0 / (np.pi * ax * ay * q * q), 0.0)


def beckmann_ndf(m, alpha_x, alpha_y=None, theta_z=0.0) -> np.ndarray:
    """Anisotropic Beckmann NDF per steradian (Cook & Torrance 1982; Ward 1992 form).

    ``D = exp(-(x^2/ax^2 + y^2/ay^2)) / (pi ax ay cos^4 theta)`` with slopes ``(x, y) = m_xy / m_z``
    in the frame rotated by ``theta_z``; per-axis slope variance is ``alpha^2 / 2``.
    """
    m = _as_dirs(m)
    ax = _as_alpha(alpha_x, "alpha_x")
    ay = ax if alpha_y is None else _as_alpha(alpha_y, "alpha_y")
    mr = _rotate_z(m, _as_angle(theta_z, "theta_z"))
    return np.where(m[:, 2] > 0, _beckmann_eval(mr, ax, ay), 0.0)


def _beckmann_eval(mr: np.ndarray, ax, ay) -> np.ndarray:
    """``exp(-e) / (pi ax ay m_z^4)`` as ``exp(-e - 4 ln m_z) / (pi ax ay)``: just above the horizon
    ``m_z^4`` underflows to 0 before ``exp(-e)`` does (0/0), the exponent form goes to 0 as it should."""
    mz = np.maximum(mr[..., 2], 1e-300)
    with np.errstate(over="ignore"):
        e = (mr[..., 0] / (ax * mz)) ** 2 + (mr[..., 1] / (ay * mz)) ** 2
    return np.exp(-e - 4.0 * np.log(mz)) / (np.pi * ax * ay)


# ----------------------------------------------------------------------------- fitting


def fit_nodes(ndf, n_nodes: int = 96, mass: float = 0.999) -> tuple[np.ndarray, float, np.ndarray]:
    """Regular grid of disk nodes covering an NDF's support, for fitting.

    ``ndf`` needs ``.eval(m)``; if it has ``.support_box(mass)`` (tabulated NDFs) that box is
    used, else the support is located on a 257x257 disk grid.  Returns ``(m (M,3), cell_area,
    D (M,))`` with ``M <= n_nodes**2`` and ``D`` the average of ``ndf.eval`` over each node's cell.
    """
    n_nodes = _check_n_nodes(n_nodes)
    if not (isinstance(mass, (int, float, np.integer, np.floating)) and 0.5 <= float(mass) < 1.0):
        raise ValueError(f"mass: expected a fraction in [0.5, 1), got {mass!r}")
    if hasattr(ndf, "support_box"):
        x0, x1, y0, y1 = ndf.support_box(mass)
    else:
        g = np.linspace(-1, 1, 257)
        X, Y = np.meshgrid(g, g)
        inside = X**2 + Y**2 < 1
        m = np.stack([X[inside], Y[inside], np.sqrt(1 - X[inside] ** 2 - Y[inside] ** 2)], -1)
        d = ndf.eval(m)
        x0, x1, y0, y1 = _mass_box(m[:, 0], m[:, 1], d, mass)
    return box_nodes(ndf.eval, (x0, x1, y0, y1), n_nodes)


def _mass_box(x, y, w, mass):
    w = np.maximum(np.asarray(w, float), 0)
    tot = w.sum()
    if not np.isfinite(tot) or tot <= 0:
        raise ValueError("ndf: has no mass to fit (all values zero)")
    lo, hi = (1 - mass) / 2, 1 - (1 - mass) / 2

    def q(v):
        o = np.argsort(v)
        c = np.cumsum(w[o]) / tot
        return v[o][np.searchsorted(c, lo)], v[o][min(np.searchsorted(c, hi), len(v) - 1)]

    (x0, x1), (y0, y1) = q(x), q(y)
    return x0, x1, y0, y1


def box_nodes(eval_fn, box, n_nodes):
    """Fit nodes on ``box = (x0, x1, y0, y1)`` (padded 25 %); ``eval_fn(m)`` may return (..., M) batches."""
    n_nodes = _check_n_nodes(n_nodes)
    try:
        x0, x1, y0, y1 = (float(v) for v in box)
    except (TypeError, ValueError):
        raise ValueError(f"box: expected 4 numbers (x0, x1, y0, y1) in disk coordinates, got {box!r}") from None
    if not (np.all(np.isfinite([x0, x1, y0, y1])) and -1 <= x0 <= x1 <= 1 and -1 <= y0 <= y1 <= 1):
        raise ValueError(f"box: expected -1 <= x0 <= x1 <= 1 and -1 <= y0 <= y1 <= 1, got {box!r}")
    # pad by 25 % (and at least 0.01) so the tails are fitted too
    px, py = max(0.25 * (x1 - x0), 0.01), max(0.25 * (y1 - y0), 0.01)
    x0, x1 = max(x0 - px, -1.0), min(x1 + px, 1.0)
    y0, y1 = max(y0 - py, -1.0), min(y1 + py, 1.0)
    gx = np.linspace(x0, x1, n_nodes)
    gy = np.linspace(y0, y1, n_nodes)
    X, Y = np.meshgrid(gx, gy)
    r2 = X**2 + Y**2
    keep = r2 < 0.999
    m = np.stack([X[keep], Y[keep], np.sqrt(1 - r2[keep])], -1)
    hx, hy = gx[1] - gx[0], gy[1] - gy[0]
    ss = 4  # cell-average the target (reduces histogram noise without biasing it)
    o = (np.arange(ss) + 0.5) / ss - 0.5
    sx = np.broadcast_to(m[:, 0][:, None, None] + hx * o[None, None, :], (len(m), ss, ss)).ravel()
    sy = np.broadcast_to(m[:, 1][:, None, None] + hy * o[None, :, None], (len(m), ss, ss)).ravel()
    r2s = np.minimum(sx * sx + sy * sy, 1.0)
    sub = np.stack([sx, sy, np.sqrt(1.0 - r2s)], -1)
    vals = np.where(r2s < 1.0, np.asarray(eval_fn(np.where(r2s[:, None] < 1.0, sub, [0.0, 0.0, 1.0])), float), 0.0)
    d = np.maximum(vals.reshape(vals.shape[:-1] + (len(m), ss * ss)).mean(-1), 0.0)  # batched evals keep lead dims
    return m, hx * hy, d


def hellinger_distance(d_a: np.ndarray, d_b: np.ndarray, cell_area: float) -> np.ndarray:
    """Squared Hellinger distance ``∫ (sqrt(Da) - sqrt(Db))^2 dm_x dm_y`` on fit nodes (in [0, 2])."""
    return np.sum((np.sqrt(np.maximum(d_a, 0)) - np.sqrt(np.maximum(d_b, 0))) ** 2, axis=-1) * cell_area


def _lm(resid: Callable[[np.ndarray], np.ndarray], u0: np.ndarray, clip: Callable[[np.ndarray], np.ndarray],
        iters: int = 60, h: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Batched Levenberg-Marquardt: ``resid(u (B,P)) -> (B,M)``; loops over iterations only."""
    u = clip(u0.copy())
    r = resid(u)
    cost = np.sum(r * r, -1)
    lam = np.full(u.shape[0], 1e-3)
    P = u.shape[1]
    eye = np.eye(P)
    for _ in range(iters):
        J = np.stack([(resid(u + h * eye[k]) - r) / h for k in range(P)], -1)  # (B, M, P)
        JTJ = np.einsum("bmp,bmq->bpq", J, J)
        g = np.einsum("bmp,bm->bp", J, r)
        diag = np.einsum("bpp->bp", JTJ)
        Hm = JTJ + (lam[:, None] * (diag + 1e-12))[:, :, None] * eye
        step = -np.linalg.solve(Hm, g[..., None])[..., 0]
        u_new = clip(u + step)
        r_new = resid(u_new)
        c_new = np.sum(r_new * r_new, -1)
        ok = c_new < cost
        u = np.where(ok[:, None], u_new, u)
        r = np.where(ok[:, None], r_new, r)
        converged = np.abs(cost - c_new) <= 1e-9 * np.maximum(cost, 1e-30)
        cost = np.where(ok, c_new, cost)
        lam = np.where(ok, lam * 0.3, lam * 10.0)
        if np.all(converged | (lam > 1e8)):
            break
    return u, cost


def _moment_init(m: np.ndarray, d: np.ndarray):
    """Peak direction (weighted mean normal), principal angle and axis roughnesses, batched over d (B, M)."""
    w = d / np.maximum(d.sum(-1, keepdims=True), 1e-300)
    mean = w @ m  # (B, 3)
    mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
    sx, sy = m[:, 0] / m[:, 2], m[:, 1] / m[:, 2]
    msx, msy = w @ sx, w @ sy
    cxx = w @ sx**2 - msx**2
    cyy = w @ sy**2 - msy**2
    cxy = w @ (sx * sy) - msx * msy
    tr, det = cxx + cyy, cxx * cyy - cxy**2
    disc = np.sqrt(np.maximum(tr**2 / 4 - det, 0))
    l1, l2 = tr / 2 + disc, np.maximum(tr / 2 - disc, 1e-12)
    phi = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # direction of the major slope axis
    return mean, phi, np.sqrt(l1), np.sqrt(l2)


def fit_ellipsoid_samples(m: np.ndarray, d: np.ndarray, cell_area: float, init=None, iters: int = 60):
    """Fit ellipsoid parameters to tabulated values ``d`` (B, M) at nodes ``m`` (M, 3) (§8, Fig. 12).

    Batched over B tables (one LM run, vectorised).  ``init``: optional (B, 5) or (5,) starting
    parameters (used as one extra start).  Returns ``(params (B, 5), hellinger (B,))`` (squared
    Hellinger distance of each fit, in [0, 2]).
    """
    d = np.atleast_2d(np.asarray(d, dtype=np.float64))
    B = d.shape[0]
    wc = np.sqrt(cell_area)
    mean, phi, a1, a2 = _moment_init(m, d)
    # theta_z: ellipsoid x axis is along the major axis when R m rotates it onto x, i.e. theta_z = -phi
    tz = -phi
    # peak v = Rz(theta_z) mean = Ry(-ty) Rx(-tx) z = (-sin ty cos tx, sin tx, cos ty cos tx)
    v = _rotate_z(mean, tz)
    tx = np.arcsin(np.clip(v[:, 1], -0.99, 0.99))
    ty = np.arctan2(-v[:, 0], v[:, 2])
    starts = []
    for scale in ((0.6, 1.2) if init is None else (1.0,)):
        starts.append(np.stack([np.log(scale * a1), np.log(scale * a2), tx, ty, tz], -1))
        starts.append(np.stack([np.log(scale * a2), np.log(scale * a1), tx, ty, tz + np.pi / 2], -1))
    if init is not None:
        ip = np.broadcast_to(_as_params(init), (B, 5))
        starts.append(np.concatenate([np.log(ip[:, :2]), ip[:, 2:]], -1))
    S = len(starts)
    u0 = np.concatenate(starts, 0)  # (S*B, 5)
    target = np.tile(d, (S, 1))

    def to_params(u):
        return np.concatenate([np.exp(u[:, :2]), u[:, 2:]], -1)

    def clip(u):
        u = u.copy()
        u[:, :2] = np.clip(u[:, :2], np.log(ALPHA_MIN), np.log(ALPHA_MAX))
        u[:, 2:4] = np.clip(u[:, 2:4], -THETA_XY_MAX + 1e-3, THETA_XY_MAX - 1e-3)
        return u

    def resid(u):
        p = to_params(u)
        model = _ellipsoid_eval(m[None, :, :], p[:, None, :])
        return wc * (model - target)

    u, cost = _lm(resid, u0, clip, iters=iters)
    cost = cost.reshape(S, B)
    # (alpha_x, alpha_y, theta_z) and (alpha_y, alpha_x, theta_z + pi/2) are (near-)equivalent for
    # small tilts; among starts that fit as well as the best (within 1e-3 relative), prefer the one
    # whose theta_z is within pi/4 of the reference (init's, else 0: axes along the scan axes), so
    # labels are consistent between texels and strips (§9 synthesises each parameter separately)
    tz_ref = ip[None, :, 4] if init is not None else 0.0
    off = (u[:, 4].reshape(S, B) - tz_ref + np.pi / 2) % np.pi - np.pi / 2
    near_best = cost <= cost.min(0, keepdims=True) * (1 + 1e-3) + 1e-300
    cost = np.where(near_best & (np.abs(off) <= np.pi / 4), cost - np.inf, cost)
    best = np.argmin(cost, 0)
    u = u.reshape(S, B, 5)[best, np.arange(B)]
    p = to_params(u)
    p = canonical_params(p, 0.0 if init is None else float(np.mean(np.broadcast_to(_as_params(init), (B, 5))[:, 4])))
    hel = hellinger_distance(_ellipsoid_eval(m[None, :, :], p[:, None, :]), d, cell_area)
    return p, hel


def fit_ellipsoid(ndf, n_nodes: int = 96) -> EllipsoidParams:
    """Five-parameter ellipsoid fit (§8, Fig. 12) to any NDF object with ``.eval(m)``.

    Returns ``(alpha_x, alpha_y, theta_x, theta_y, theta_z)`` (radians); use
    :func:`fit_ellipsoid_samples` for the fit's Hellinger distance or for many tables at once.
    """
    m, cell, d = fit_nodes(ndf, _check_n_nodes(n_nodes))
    p, _ = fit_ellipsoid_samples(m, d[None], cell)
    return EllipsoidParams(*map(float, p[0]))


def _fit_lobe(ndf, kind: str, isotropic: bool, n_nodes: int):
    m, cell, d = fit_nodes(ndf, _check_n_nodes(n_nodes))
    d = d[None]
    _, phi, a1, a2 = _moment_init(m, d)
    wc = np.sqrt(cell)
    target = d
    if isotropic:
        a = np.sqrt(a1 * a2)
        u0 = np.stack([np.log(a * s) for s in (0.5, 1.0, 2.0)], 0).reshape(3, 1)
    else:
        u0 = np.concatenate([np.stack([np.log(s * a1), np.log(s * a2), -phi], -1) for s in (0.6, 1.2)], 0)
    f = beckmann_ndf if kind == "beckmann" else ggx_ndf

    def model(u):
        ax = np.exp(u[:, 0])[:, None]
        ay = ax if isotropic else np.exp(u[:, 1])[:, None]
        tz = 0.0 if isotropic else u[:, 2][:, None]
        mr = _rotate_z(np.broadcast_to(m, (u.shape[0],) + m.shape), tz)
        mz = m[None, :, 2]
        if kind == "beckmann":
            return _beckmann_eval(mr, ax, ay)
        q = (mr[..., 0] / ax) ** 2 + (mr[..., 1] / ay) ** 2 + mz**2
        return 1.0 / (np.pi * ax * ay * q * q)

    def clip(u):
        u = u.copy()
        u[:, :2 if not isotropic else 1] = np.clip(u[:, :2 if not isotropic else 1], np.log(ALPHA_MIN), np.log(ALPHA_MAX))
        return u

    u, cost = _lm(lambda u: wc * (model(u) - target), u0, clip)
    u = u[np.argmin(cost)][None]
    hel = float(hellinger_distance(model(u)[0], d[0], cell))
    u = u[0]
    if isotropic:
        a = float(np.exp(u[0]))
        return {"alpha_x": a, "alpha_y": a, "theta_z": 0.0, "hellinger": hel, "eval": lambda mm: f(mm, a)}
    ax, ay, tz = float(np.exp(u[0])), float(np.exp(u[1])), float((u[2] + np.pi / 2) % np.pi - np.pi / 2)
    return {"alpha_x": ax, "alpha_y": ay, "theta_z": tz, "hellinger": hel, "eval": lambda mm: f(mm, ax, ay, tz)}


def fit_beckmann(ndf, isotropic: bool = False, n_nodes: int = 96) -> dict:
    """Fit an (an)isotropic Beckmann lobe to an NDF (Fig. 12 comparison).

    Returns ``{"alpha_x", "alpha_y", "theta_z", "hellinger", "eval"}``; per-axis slope variance of
    the fitted lobe is ``alpha^2 / 2``.
    """
    return _fit_lobe(ndf, "beckmann", isotropic, n_nodes)


def fit_ggx(ndf, isotropic: bool = False, n_nodes: int = 96) -> dict:
    """Fit an (an)isotropic GGX / GTR2aniso lobe to an NDF (Fig. 12 comparison); same keys as :func:`fit_beckmann`."""
    return _fit_lobe(ndf, "ggx", isotropic, n_nodes)
