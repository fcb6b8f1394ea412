"""Explicit scratch microgeometry: the ground truth a scratch material stands for (Raymond et al. 2016, §4, eq. 7).

The scratch BRDF of §4.1-4.2 is the reflectance of *parallel grooves of one profile* (extruded 1D
profiles dug into a flat base, all inter-reflections inside the grooves).  Path tracing that geometry
directly is the strongest independent reference for the tables, the lobes and the shader: this module
builds it as plain triangle/quad meshes (numpy arrays; the Blender side only copies them into a mesh).

- ``groove_field``: a rectangle covered by ``n`` parallel grooves of a profile (the dense material,
  Fig. 1a), the profile polyline repeated across the grooves (v, the y axis) and extruded along the
  scratch direction (u, the x axis).  With the periodic vertices of ``Profile.periodic_vertices`` the
  geometry is exactly the periodic profile the 2D tracer simulates (bulges and closing steps included).
- ``layer_field``: grooves placed by the layer indicator of eq. 7 (``layers.layer_indicator``, Cycles'
  own Voronoi): inside a layer's scratched region dense grooves along its direction Θ_k, the flat base
  elsewhere.  Regions are resolved at the groove period (each groove keeps the runs where its centre
  line is scratched); overlapping layers are given to the layer of lowest index (``overlap`` reports the
  fraction of the area that the model would have averaged instead).

Units: metres (or any scene unit) for the mesh; profile coordinates are in scratch widths, so a groove
of period ``p`` has its profile scaled by ``p`` in both directions (the aspect ratio of the profile).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .layers import LayerParams, layer_indicator, layer_transforms
from .profiles import Profile

__all__ = ["Mesh", "groove_field", "layer_field"]


@dataclass
class Mesh:
    """A polygon mesh: ``verts [V, 3]`` float64, quads ``quads [Q, 4]`` and triangles ``tris [T, 3]``
    (vertex indices, counter-clockwise seen from above: normals point up, +z), and per-face metadata."""

    verts: np.ndarray
    quads: np.ndarray
    tris: np.ndarray
    meta: dict

    @property
    def n_faces(self) -> int:
        return int(self.quads.shape[0] + self.tris.shape[0])


def _check_profile(profile):
    if not isinstance(profile, Profile):
        raise ValueError(f"profile: expected a precompute.scratch.profiles.Profile, got {type(profile).__name__}")


def _polyline(profile: Profile, period: float, n: int, y0: float) -> np.ndarray:
    """The periodic profile repeated ``n`` times from ``y0`` across the grooves: points (y, z) [n P + 1, 2]."""
    v = profile.periodic_vertices()  # V_0 .. V_P, V_P = V_0 + (1, 0)
    P = v.shape[0] - 1
    one = v[:P]
    k = np.arange(n)[:, None, None]
    pts = (one[None] + np.stack([k[..., 0] * 1.0, np.zeros_like(k[..., 0], float)], -1)).reshape(-1, 2)
    pts = np.vstack([pts, v[P] + [n - 1.0, 0.0]])
    pts = pts - [v[0, 0], 0.0]  # groove 0 starts at y = 0
    return pts * period + [y0, 0.0]


def groove_field(profile: Profile, n: int, period: float, x_range=(-1.0, 1.0), y0: float | None = None,
                 x_segments: int = 1) -> Mesh:
    """``n`` parallel grooves of ``profile`` with period ``period`` across y, extruded along x over ``x_range``.

    The grooves are dug into the plane z = 0 (the profile's top is z = 0) and centred on y = 0 unless
    ``y0`` (the y of the first groove's left rim) is given; ``x_segments`` cuts the extrusion into that many
    pieces (shorter facets; measured to change nothing in Cycles for 1/64-period facets 10^5 times longer
    than wide).  Returns a ``Mesh`` of quads (flat facets; the
    closing vertical step of a profile with unequal ends is a vertical quad).
    """
    _check_profile(profile)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 1_000_000:
        raise ValueError(f"n: expected an integer in [1, 1e6], got {n!r}")
    if not (np.isfinite(period) and period > 0):
        raise ValueError(f"period: expected a positive length, got {period!r}")
    x0, x1 = (float(v) for v in x_range)
    if not (np.isfinite(x0) and np.isfinite(x1) and x1 > x0):
        raise ValueError(f"x_range: expected two increasing finite numbers, got {x_range!r}")
    if y0 is None:
        y0 = -0.5 * n * period
    if isinstance(x_segments, bool) or not isinstance(x_segments, (int, np.integer)) or not 1 <= x_segments <= 4096:
        raise ValueError(f"x_segments: expected an integer in [1, 4096], got {x_segments!r}")
    line = _polyline(profile, period, int(n), float(y0))       # [L, 2]
    L = line.shape[0]
    K = int(x_segments)
    xs = np.linspace(x0, x1, K + 1)
    verts = np.empty(((K + 1) * L, 3))
    verts[:, 0] = np.repeat(xs, L)
    verts[:, 1:] = np.tile(line, (K + 1, 1))
    i = (np.arange(K)[:, None] * L + np.arange(L - 1)[None, :]).ravel()
    # (x_k, y_i) -> (x_k+1, y_i) -> (x_k+1, y_i+1) -> (x_k, y_i+1): counter-clockwise from above (normals up, +z)
    quads = np.stack([i, L + i, L + i + 1, i + 1], 1)
    meta = {"profile": profile.name, "grooves": int(n), "period": float(period), "x_range": (x0, x1),
            "y_range": (float(y0), float(y0 + n * period))}
    return Mesh(verts, quads.astype(np.int64), np.zeros((0, 3), np.int64), meta)


def _cap_fans(base: np.ndarray, P: int) -> np.ndarray:
    """Fan triangles (V_0, V_t, V_t+1) of the end-cap polygons V_0 .. V_P of runs starting at ``base [R]``."""
    if P < 2:
        return np.zeros((0, 3), np.int64)
    t = np.arange(1, P)[None, :]
    b = base[:, None]
    return np.stack([np.broadcast_to(b, (b.shape[0], P - 1)), b + t, b + t + 1], -1).reshape(-1, 3)


def _runs(mask: np.ndarray):
    """Runs of True along the last axis of a 2D mask: (row, start, stop) with stop exclusive."""
    pad = np.zeros((mask.shape[0], 1), bool)
    d = np.diff(np.concatenate([pad, mask, pad], 1).astype(np.int8), axis=1)
    row, start = np.nonzero(d == 1)
    _, stop = np.nonzero(d == -1)
    return row, start, stop


def layer_field(profile: Profile, layers: LayerParams, period: float, uv_window, plane_size: float = 2.0,
                cell: float | None = None) -> Mesh:
    """Explicit grooves where the layers of eq. 7 put scratches, on the UV-mapped plane of ``plane_size``.

    The plane is ``scratch_addon.render.add_plane``'s: z = 0, x = (u - 1/2) plane_size, y = (v - 1/2)
    plane_size.  Inside ``uv_window = (u0, v0, u1, v1)``:

    - a flat *lid* at z = 0 (axis-aligned cells of size ``cell``, default ``period / 2``, merged into
      runs) with a hole at every cell whose centre is scratched by some layer
      (``layers.layer_indicator``, Cycles' own Voronoi);
    - under the holes of layer k, grooves of ``period`` (scene units) along its direction Θ_k
      (``layers.layer_transforms``): each groove keeps the runs of its centre line that lie within
      ``period / 2 + cell`` of a hole of layer k (so every hole has grooves under it; the rest is hidden
      under the lid), closed by vertical end caps.

    Where two layers overlap both groove sets are built (the ray tracer sees their upper envelope);
    the model averages the two BRDFs there instead: ``meta["overlap"]`` is that area fraction.
    ``meta["coverage"]`` is each layer's scratched fraction of the window, ``meta["scratched"]`` the union.
    """
    _check_profile(profile)
    if not isinstance(layers, LayerParams):
        raise ValueError(f"layers: expected a precompute.scratch.layers.LayerParams, got {type(layers).__name__}")
    try:
        u0, v0, u1, v1 = (float(v) for v in uv_window)
    except (TypeError, ValueError):
        raise ValueError(f"uv_window: expected (u0, v0, u1, v1), got {uv_window!r}") from None
    if not (0.0 <= u0 < u1 <= 1.0 and 0.0 <= v0 < v1 <= 1.0):
        raise ValueError(f"uv_window: expected 0 <= u0 < u1 <= 1 and 0 <= v0 < v1 <= 1, got {uv_window!r}")
    if not (np.isfinite(plane_size) and plane_size > 0):
        raise ValueError(f"plane_size: expected a positive length, got {plane_size!r}")
    wx, wy = (u1 - u0) * plane_size, (v1 - v0) * plane_size
    if not (np.isfinite(period) and 0 < period < 0.25 * min(wx, wy)):
        raise ValueError(f"period: expected a positive length below a quarter of the window, got {period!r}")
    cell = 0.5 * period if cell is None else float(cell)
    if not (np.isfinite(cell) and 0 < cell <= period):
        raise ValueError(f"cell: expected a length in (0, period], got {cell!r}")
    nx, ny = int(np.ceil(wx / cell)), int(np.ceil(wy / cell))
    if nx * ny > 64_000_000:
        raise ValueError(f"cell: {nx} x {ny} lid cells is too many (at most 6.4e7); use a larger period or window")
    X0, Y0 = (u0 - 0.5) * plane_size, (v0 - 0.5) * plane_size
    xs = X0 + (np.arange(nx) + 0.5) * cell
    ys = Y0 + (np.arange(ny) + 0.5) * cell
    to_uv = lambda x, y: np.stack(np.broadcast_arrays((x + 0.5 * plane_size) / plane_size,  # noqa: E731
                                                      (y + 0.5 * plane_size) / plane_size), -1)
    uv = to_uv(xs[None, :], ys[:, None])                                              # [ny, nx, 2]
    holes = np.stack([layer_indicator(uv, layers, k) for k in range(layers.n_layers)])  # [N, ny, nx]
    theta_k, _ = layer_transforms(layers)
    prof = profile.periodic_vertices()
    P = prof.shape[0] - 1
    off = (prof[:, 0] - 0.5 * (prof[0, 0] + prof[P, 0])) * period                    # across, centred
    hgt = prof[:, 1] * period
    verts, quads, tris = [], [], []
    nv = 0
    # --- the lid: runs of unscratched cells per row
    any_hole = holes.any(0)
    r, a, b = _runs(~any_hole)
    if r.size:
        x_lo, x_hi, y_lo, y_hi = X0 + a * cell, X0 + b * cell, Y0 + r * cell, Y0 + (r + 1) * cell
        v = np.stack([np.stack([x_lo, y_lo], -1), np.stack([x_hi, y_lo], -1), np.stack([x_hi, y_hi], -1),
                      np.stack([x_lo, y_hi], -1)], 1)                                  # [R, 4, 2]
        verts.append(np.concatenate([v, np.zeros(v.shape[:2] + (1,))], -1).reshape(-1, 3))
        quads.append(nv + np.arange(4 * r.size).reshape(-1, 4))
        nv += 4 * r.size
    # --- grooves of each layer under its holes
    reach = int(np.ceil((0.5 * period + cell) / cell))
    yy, xx = np.mgrid[-reach:reach + 1, -reach:reach + 1]
    disk = (xx * xx + yy * yy) <= (reach + 0.5) ** 2
    from scipy.ndimage import binary_dilation  # scipy is a declared dependency of the science

    centre = np.array([X0 + 0.5 * wx, Y0 + 0.5 * wy])
    half = 0.5 * np.hypot(wx, wy) + period
    step = 0.5 * cell
    along = -half + (np.arange(int(np.ceil(2 * half / step))) + 0.5) * step
    ng = int(np.ceil(2 * half / period))
    across = -half + (np.arange(ng) + 0.5) * period
    runs = 0
    for k in range(layers.n_layers):
        if not holes[k].any():
            continue
        need = binary_dilation(holes[k], structure=disk)
        c, s = np.cos(theta_k[k]), np.sin(theta_k[k])
        du, dv = np.array([c, s]), np.array([-s, c])
        pts = centre + along[None, :, None] * du + across[:, None, None] * dv           # [ng, na, 2]
        ix = np.floor((pts[..., 0] - X0) / cell).astype(np.int64)
        iy = np.floor((pts[..., 1] - Y0) / cell).astype(np.int64)
        ok = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        m = np.zeros(ok.shape, bool)
        m[ok] = need[iy[ok], ix[ok]]
        gi, st, sp = _runs(m)
        if gi.size == 0:
            continue
        runs += gi.size
        R = gi.size
        ends = (along[st] - 0.5 * step, along[sp - 1] + 0.5 * step)
        for aa in ends:
            p2 = centre + aa[:, None, None] * du + (across[gi][:, None] + off[None, :])[..., None] * dv  # [R, P+1, 2]
            verts.append(np.concatenate([p2, np.broadcast_to(hgt, (R, P + 1))[..., None]], -1).reshape(-1, 3))
        base0 = nv + np.arange(R) * (P + 1)
        base1 = base0 + R * (P + 1)
        i = np.arange(P)[None, :]
        quads.append(np.stack([base0[:, None] + i, base1[:, None] + i, base1[:, None] + i + 1,
                               base0[:, None] + i + 1], -1).reshape(-1, 4))      # counter-clockwise from above
        tris.append(_cap_fans(base0, P))
        tris.append(_cap_fans(base1, P))
        nv += 2 * R * (P + 1)
    meta = {"coverage": holes.mean(axis=(1, 2)).tolist(), "overlap": float((holes.sum(0) > 1).mean()),
            "scratched": float(any_hole.mean()), "runs": int(runs), "period": float(period), "cell": float(cell),
            "window": (u0, v0, u1, v1), "plane_size": float(plane_size), "profile": profile.name}
    V = np.concatenate(verts) if verts else np.zeros((0, 3))
    Q = np.concatenate(quads).astype(np.int64) if quads else np.zeros((0, 4), np.int64)
    T = np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)
    return Mesh(V, Q, T, meta)
