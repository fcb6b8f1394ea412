"""Direction and normal discretisations for the bi-scale pipeline (Wu et al. 2011, §3.7).

The paper maps n, ωi and ωo onto regular 2D images with paraboloid maps.  We use
octahedral maps instead, because every cell of the square is a valid direction (no
wasted corners, no disc rim to extrapolate across) and bilinear interpolation on the
square is continuous over the whole (hemi)sphere:

* **Bidirectional domain** (ωi, ωo on the upper hemisphere Ω, z = large-scale
  normal): the *hemi-octahedral* map  p = (x, y) / (|x|+|y|+z),  s = px+py,
  t = px-py  sends Ω onto [-1, 1]^2.  A cell-centred ``res x res`` grid gives
  D = res^2 directions (the paper uses 88-132; ``res=10`` gives 100).  No node lies on
  the horizon (z > 0 everywhere); ``.eval`` clamps to the outermost cell centres.
* **Normal domain** (n on the whole sphere S^2, since facets may face sideways or
  down): the full octahedral map, node-centred ``res_n x res_n`` grid with odd
  ``res_n`` so that the pole (0, 0, 1) is exactly a node.  The discretised delta of
  eq. 11 is a bilinear splat onto the 4 surrounding nodes (a "linear" delta; the paper
  uses nearest node plus linear interpolation at render time).

All directions are unit 3-vectors (dimensionless); solid angles in steradians.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "hemi_oct_encode", "hemi_oct_decode", "direction_grid", "direction_solid_angles",
    "direction_bilinear", "oct_encode", "oct_decode", "normal_grid", "normal_splat",
    "pole_index",
]


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- hemisphere
def hemi_oct_encode(w: np.ndarray) -> np.ndarray:
    """Hemi-octahedral coordinates (s, t) in [-1, 1]^2 of directions w (..., 3), z >= 0."""
    w = np.asarray(w, dtype=np.float64)
    z = np.maximum(w[..., 2], 0.0)
    d = np.abs(w[..., 0]) + np.abs(w[..., 1]) + z
    d = np.where(d > 0, d, 1.0)
    px, py = w[..., 0] / d, w[..., 1] / d
    return np.stack([px + py, px - py], axis=-1)


def hemi_oct_decode(st: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) of hemi-octahedral coordinates (s, t) in [-1, 1]^2."""
    st = np.asarray(st, dtype=np.float64)
    px = 0.5 * (st[..., 0] + st[..., 1])
    py = 0.5 * (st[..., 0] - st[..., 1])
    z = 1.0 - np.abs(px) - np.abs(py)
    return _unit(np.stack([px, py, z], axis=-1))


def _centres(res: int) -> np.ndarray:
    return -1.0 + (2.0 * np.arange(res) + 1.0) / res


def direction_grid(res: int) -> np.ndarray:
    """Cell-centred hemi-octahedral grid: (res*res, 3) unit directions, index = row*res + col
    with row along s and col along t."""
    if not (isinstance(res, (int, np.integer)) and 2 <= res <= 64):
        raise ValueError(f"dir_res: expected an integer in [2, 64], got {res!r}")
    c = _centres(int(res))
    s, t = np.meshgrid(c, c, indexing="ij")
    return hemi_oct_decode(np.stack([s.ravel(), t.ravel()], axis=-1))


def direction_solid_angles(res: int, sub: int = 16) -> np.ndarray:
    """Solid angle (sr) of each cell of ``direction_grid(res)``; they sum to 2π.

    Computed by summing |∂w/∂s x ∂w/∂t| ds dt over ``sub x sub`` sub-cells (midpoint rule)."""
    h = 2.0 / res
    off = (np.arange(sub) + 0.5) / sub * h
    c = -1.0 + np.arange(res) * h
    S = (c[:, None] + off[None, :]).ravel()  # (res*sub,)
    ss, tt = np.meshgrid(S, S, indexing="ij")
    e = 1e-5
    w = lambda a, b: hemi_oct_decode(np.stack([a, b], -1))  # noqa: E731
    ds = (w(ss + e, tt) - w(ss - e, tt)) / (2 * e)
    dt = (w(ss, tt + e) - w(ss, tt - e)) / (2 * e)
    jac = np.linalg.norm(np.cross(ds, dt), axis=-1) * (h / sub) ** 2
    omega = jac.reshape(res, sub, res, sub).sum(axis=(1, 3)).ravel()
    return omega * (2.0 * np.pi / omega.sum())


def direction_bilinear(w: np.ndarray, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation taps on ``direction_grid(res)``: (idx (N, 4) int, weight (N, 4)).

    Directions below the horizon are treated as horizon directions (the caller zeroes
    them); outside the outermost cell centres values are clamped (constant extension)."""
    st = hemi_oct_encode(w)
    x = np.clip((st + 1.0) * 0.5 * res - 0.5, 0.0, res - 1.0)
    i0 = np.minimum(np.floor(x).astype(np.int64), res - 2)
    f = x - i0
    r0, c0 = i0[..., 0], i0[..., 1]
    fr, fc = f[..., 0], f[..., 1]
    idx = np.stack([r0 * res + c0, r0 * res + c0 + 1, (r0 + 1) * res + c0, (r0 + 1) * res + c0 + 1], -1)
    wt = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], -1)
    return idx, wt


# ----------------------------------------------------------------------------- full sphere
def oct_encode(n: np.ndarray) -> np.ndarray:
    """Octahedral coordinates (u, v) in [-1, 1]^2 of unit vectors n (..., 3) on S^2."""
    n = np.asarray(n, dtype=np.float64)
    d = np.abs(n).sum(axis=-1)
    d = np.where(d > 0, d, 1.0)
    px, py, pz = n[..., 0] / d, n[..., 1] / d, n[..., 2] / d
    sx = np.where(px >= 0, 1.0, -1.0)
    sy = np.where(py >= 0, 1.0, -1.0)
    lx = (1.0 - np.abs(py)) * sx
    ly = (1.0 - np.abs(px)) * sy
    lower = pz < 0
    return np.stack([np.where(lower, lx, px), np.where(lower, ly, py)], axis=-1)


def oct_decode(uv: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3) of octahedral coordinates (u, v) in [-1, 1]^2."""
    uv = np.asarray(uv, dtype=np.float64)
    u, v = uv[..., 0], uv[..., 1]
    z = 1.0 - np.abs(u) - np.abs(v)
    t = np.maximum(-z, 0.0)
    x = u - np.where(u >= 0, t, -t)
    y = v - np.where(v >= 0, t, -t)
    return _unit(np.stack([x, y, z], axis=-1))


def normal_grid(res_n: int) -> np.ndarray:
    """Node-centred octahedral grid over S^2: (res_n*res_n, 3) unit normals (odd res_n,
    so that the pole (0, 0, 1) is node ``pole_index(res_n)``)."""
    if not (isinstance(res_n, (int, np.integer)) and 5 <= res_n <= 201 and res_n % 2 == 1):
        raise ValueError(f"normal_res: expected an odd integer in [5, 201], got {res_n!r}")
    c = np.linspace(-1.0, 1.0, int(res_n))
    u, v = np.meshgrid(c, c, indexing="ij")
    n = oct_decode(np.stack([u.ravel(), v.ravel()], axis=-1))
    n[pole_index(res_n)] = (0.0, 0.0, 1.0)
    return n


def pole_index(res_n: int) -> int:
    """Index of the exact pole (0, 0, 1) in ``normal_grid(res_n)``."""
    h = res_n // 2
    return h * res_n + h


def normal_splat(n: np.ndarray, res_n: int) -> tuple[np.ndarray, np.ndarray]:
    """Discretised delta of eq. 11 as a bilinear splat: (idx (N, 4), weight (N, 4)) on
    ``normal_grid(res_n)``; weights sum to 1, and a normal on a node gets weight 1 there."""
    uv = oct_encode(n)
    x = (uv + 1.0) * 0.5 * (res_n - 1)
    i0 = np.clip(np.floor(x).astype(np.int64), 0, res_n - 2)
    f = np.clip(x - i0, 0.0, 1.0)
    r0, c0 = i0[..., 0], i0[..., 1]
    fr, fc = f[..., 0], f[..., 1]
    idx = np.stack([r0 * res_n + c0, r0 * res_n + c0 + 1, (r0 + 1) * res_n + c0, (r0 + 1) * res_n + c0 + 1], -1)
    wt = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], -1)
    return idx, wt
