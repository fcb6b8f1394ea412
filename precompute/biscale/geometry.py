"""Small-scale tile geometry for bi-scale materials (Wu et al. 2011, §3.2 and §4.2).

A *tile* is a triangle mesh over the square footprint [0, P]^2 that is repeated
periodically over the large-scale surface (z = large-scale normal).  Lengths are in
the tile's unit (P = ``period``; any unit, e.g. micrometres — the effective BRDF is
scale invariant).

Tileable means (checked by ``validate_tile``):

1. every vertex has x, y in [0, P] (tolerance 1e-6 P);
2. the surface covers the footprint exactly once: the signed area of the faces
   projected onto z = 0 (counter-clockwise seen from above = positive) equals P^2 within
   1e-3 (no holes, no duplicated layers, faces wound so that normals point out of the
   surface / upwards);
3. opposite borders match: every vertex on x = 0 lies (in (y, z)) on the polyline of mesh
   edges on x = P and vice versa, and the same for y = 0 / y = P (tolerance 1e-5 P).

Faces of (near-)zero area are dropped.  Non-manifold edges are harmless (the pipeline
samples faces and casts rays; it never walks the mesh).

Generators (all return a ``Tile``): ``flat_tile``, ``groove_tile``, ``pyramid_tile``,
``rods_tile``, ``woven_tile``, ``heightfield_tile``.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "Tile", "validate_tile", "face_geometry", "sample_facets", "is_closed_surface",
    "flat_tile", "groove_tile", "pyramid_tile", "rods_tile", "woven_tile", "heightfield_tile",
]


class Tile(NamedTuple):
    vertices: np.ndarray      # (V, 3) float64
    faces: np.ndarray         # (F, 3) int64, counter-clockwise seen from outside
    face_material: np.ndarray  # (F,) int64 material index
    period: float             # footprint side P


# ----------------------------------------------------------------------------- validation
def face_geometry(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Areas (F,) and unit normals (F, 3) of the faces (right-handed winding)."""
    tri = vertices[faces]
    c = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    a2 = np.linalg.norm(c, axis=1)
    n = c / np.where(a2 > 0, a2, 1.0)[:, None]
    return 0.5 * a2, n


def _border_mismatch(V, E, axis, P, tol):
    """Largest distance from a border vertex on coordinate[axis]=0 (resp. P) to the polyline of
    border edges on the opposite side, measured in the two other coordinates."""
    other = [k for k in range(3) if k != axis]
    worst = 0.0
    for side, opp in ((0.0, P), (P, 0.0)):
        pts = V[np.abs(V[:, axis] - side) <= tol][:, other]
        if len(pts) == 0:
            continue
        on = np.abs(V[:, axis] - opp) <= tol
        ed = E[on[E[:, 0]] & on[E[:, 1]]]
        if len(ed) == 0:
            return np.inf
        a, b = V[ed[:, 0]][:, other], V[ed[:, 1]][:, other]
        ab = b - a
        L2 = np.maximum((ab ** 2).sum(1), 1e-300)
        t = np.clip(((pts[:, None, :] - a[None]) * ab[None]).sum(-1) / L2[None], 0.0, 1.0)
        d = np.linalg.norm(a[None] + t[..., None] * ab[None] - pts[:, None, :], axis=-1).min(1)
        worst = max(worst, float(d.max()))
    return worst


def validate_tile(vertices, faces, face_material=None, period: float = 1.0, n_materials: int | None = None,
                  check_borders: bool = True) -> Tile:
    """Check a tile mesh (see module docstring for "tileable") and return a cleaned ``Tile``
    (float64 vertices with x, y clipped into [0, P], int64 faces, zero-area faces dropped).

    Raises ``ValueError`` naming the offending parameter."""
    try:
        P = float(period)
    except (TypeError, ValueError):
        raise ValueError(f"period: expected a positive finite number, got {period!r}") from None
    if not (np.isfinite(P) and P > 0):
        raise ValueError(f"period: expected a positive finite number, got {period!r}")
    V = np.asarray(vertices, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        raise ValueError(f"vertices: expected shape (V>=3, 3), got {V.shape}")
    if not np.all(np.isfinite(V)):
        raise ValueError("vertices: contains NaN or inf")
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise ValueError(f"faces: expected shape (F>=1, 3) of vertex indices, got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        if not np.all(np.isfinite(F)) or np.any(F != np.round(F)):
            raise ValueError("faces: expected integer vertex indices")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"faces: vertex indices must be in [0, {len(V) - 1}], got range [{F.min()}, {F.max()}]")
    if face_material is None:
        M = np.zeros(len(F), np.int64)
    else:
        M = np.asarray(face_material)
        if M.shape != (len(F),):
            raise ValueError(f"face_material: expected shape ({len(F)},), got {M.shape}")
        if not np.issubdtype(M.dtype, np.integer):
            if not np.all(np.isfinite(M)) or np.any(M != np.round(M)):
                raise ValueError("face_material: expected integer material indices")
        M = M.astype(np.int64)
        hi = (n_materials - 1) if n_materials is not None else None
        if M.min() < 0 or (hi is not None and M.max() > hi):
            raise ValueError(f"face_material: indices must be in [0, {hi if hi is not None else 'n-1'}], "
                             f"got range [{M.min()}, {M.max()}]")
    tol = 1e-6 * P
    xy = V[:, :2]
    if xy.min() < -tol or xy.max() > P + tol:
        raise ValueError(f"vertices: x and y must lie within the tile [0, period={P:g}] "
                         f"(got range [{xy.min():.6g}, {xy.max():.6g}]); the tile is not tileable")
    V = V.copy()
    V[:, :2] = np.clip(xy, 0.0, P)
    area, _ = face_geometry(V, F)
    keep = area > 1e-12 * P * P
    if not keep.any():
        raise ValueError("faces: every face has zero area")
    F, M = F[keep], M[keep]
    tri = V[F]
    e1, e2 = tri[:, 1, :2] - tri[:, 0, :2], tri[:, 2, :2] - tri[:, 0, :2]
    signed = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    if abs(signed - P * P) > 1e-3 * P * P:
        hint = "faces are wound clockwise (normals point down)" if abs(signed + P * P) < 1e-3 * P * P else \
            "the surface has holes, overlapping layers or does not span the footprint"
        raise ValueError(f"faces: the tile must cover its footprint [0, {P:g}]^2 exactly once "
                         f"(signed projected area {signed:.6g}, expected {P * P:.6g}): {hint}")
    if check_borders:
        E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        for axis, name in ((0, "x"), (1, "y")):
            d = _border_mismatch(V, E, axis, P, 1e-6 * P)
            if d > 1e-5 * P:
                raise ValueError(f"vertices: opposite borders {name}=0 and {name}={P:g} do not match "
                                 f"(mismatch {d:.3g}); the tile is not tileable")
    return Tile(V, F, M, P)


def is_closed_surface(tile: Tile) -> bool:
    """True if the tile is one connected, consistently oriented closed surface on the torus:
    after welding coincident vertices, every edge not lying on a footprint border line
    (x or y = 0 or P) is shared by exactly two faces that traverse it in opposite
    directions, and the faces form a single connected component.

    Periodic height fields, pyramids, grooves and woven tiles are closed; several
    interpenetrating closed parts (``rods_tile``: rods standing in a floor) or open sheets
    are not.  ``biscale_visibility.visibility_matrix(closed=True)`` relies on this (§3.3)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V, F, P = tile.vertices, tile.faces, tile.period
    q = np.round(V / (1e-9 * P)).astype(np.int64)
    _, weld = np.unique(q, axis=0, return_inverse=True)
    weld = weld.ravel()
    Fw = weld[F]
    a = Fw.ravel()
    b = Fw[:, [1, 2, 0]].ravel()
    if np.any(a == b):
        return False
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    sign = np.where(a < b, 1, -1)
    key = lo * (weld.max() + 1) + hi
    uk, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    net = np.bincount(inv.ravel(), sign, minlength=len(uk))
    ok = (cnt == 2) & (net == 0)
    if not ok.all():
        # edges on a footprint border line may be used once (their partner is on the opposite border)
        Vw = np.zeros((weld.max() + 1, 3))
        Vw[weld] = V
        tol = 1e-6 * P
        e_lo, e_hi = uk // (weld.max() + 1), uk % (weld.max() + 1)
        border = np.zeros(len(uk), bool)
        for ax in (0, 1):
            for side in (0.0, P):
                border |= (np.abs(Vw[e_lo, ax] - side) <= tol) & (np.abs(Vw[e_hi, ax] - side) <= tol)
        if not np.all(ok | (border & (cnt == 1))):
            return False
    n = weld.max() + 1
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    used = np.unique(Fw)
    ncomp, lab = connected_components(g, directed=False)
    return len(np.unique(lab[used])) == 1


# ----------------------------------------------------------------------------- §3.2 facets
def sample_facets(tile: Tile, n_facets: int, rng: np.random.Generator, smooth_normals: bool = False,
                  area_points: int = 8):
    """Random facets of the tile (§3.2): positions (S, 3), normals (S, 3), areas ΔA_s (S,),
    face index (S,), barycentrics (S, 3).

    Faces are picked with probability proportional to area, points uniformly inside them;
    normals are the face normals or (``smooth_normals``) barycentric interpolations of
    area-weighted vertex normals.  ΔA_s is estimated as in the paper by assigning
    ``area_points * S`` further uniform surface points to their nearest facet centre (a
    k-d tree, periodic in x and y; the normal is appended to the position so points do not
    leak across sharp creases) and scaling the counts so that Σ ΔA_s = total area exactly."""
    from scipy.spatial import cKDTree

    V, F, P = tile.vertices, tile.faces, tile.period
    area, fn = face_geometry(V, F)
    cdf = np.cumsum(area)
    total = cdf[-1]

    def draw(n):
        f = np.minimum(np.searchsorted(cdf, rng.random(n) * total, side="right"), len(F) - 1)
        r1, r2 = rng.random(n), rng.random(n)
        s = np.sqrt(r1)
        bary = np.stack([1 - s, s * (1 - r2), s * r2], 1)
        pos = np.einsum("nk,nkd->nd", bary, V[F[f]])
        if smooth_normals:
            vn = np.zeros_like(V)
            np.add.at(vn, F.ravel(), np.repeat(fn * area[:, None], 3, axis=0))
            vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-300)
            nrm = np.einsum("nk,nkd->nd", bary, vn[F[f]])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        else:
            nrm = fn[f]
        return pos, nrm, f, bary

    pos, nrm, face, bary = draw(n_facets)
    q_pos, q_nrm, _, _ = draw(area_points * n_facets)
    lam = 0.1 * P  # weight of the normal in the 6D distance (normals differ by <=2)
    zmin = min(pos[:, 2].min(), q_pos[:, 2].min())
    span = max(np.ptp(np.concatenate([pos[:, 2], q_pos[:, 2]])), P)
    box = np.array([P, P, 4 * span + 1, 8 * lam + 1, 8 * lam + 1, 8 * lam + 1])

    def emb(p, n):
        e = np.concatenate([np.mod(p[:, :2], P), (p[:, 2:] - zmin), lam * (n + 1.0)], 1)
        e[:, :2] = np.where(e[:, :2] >= P, 0.0, e[:, :2])
        return e

    tree = cKDTree(emb(pos, nrm), boxsize=box)
    _, nearest = tree.query(emb(q_pos, q_nrm), k=1)
    counts = np.bincount(nearest, minlength=n_facets).astype(np.float64)
    dA = total * counts / counts.sum()
    return pos, nrm, dA, face, bary


# ----------------------------------------------------------------------------- generators
def _grid_faces(nx: int, ny: int) -> np.ndarray:
    """Two CCW triangles per cell of an (nx+1) x (ny+1) vertex grid indexed i*(ny+1)+j (x-major)."""
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a = (i * (ny + 1) + j).ravel()
    b = a + (ny + 1)  # +x
    c = b + 1         # +x +y
    d = a + 1         # +y
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _check(name, value, lo, hi, integer=False):
    ok = np.isfinite(value) and lo <= value <= hi and (not integer or float(value).is_integer())
    if not ok:
        raise ValueError(f"{name}: expected {'an integer' if integer else 'a number'} in [{lo}, {hi}], got {value!r}")
    return int(value) if integer else float(value)


def flat_tile(period: float = 1.0, n: int = 1, material: int = 0) -> Tile:
    """A flat square tile split into 2 n^2 triangles."""
    P = _check("period", period, 1e-9, 1e9)
    n = _check("n", n, 1, 1000, integer=True)
    c = np.linspace(0, P, n + 1)
    x, y = np.meshgrid(c, c, indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    F = _grid_faces(n, n)
    return Tile(V, F, np.full(len(F), material, np.int64), P)


def groove_tile(period: float = 1.0, depth: float = 0.5, floor: float = 0.3, top: float = 0.2,
                n_y: int = 1) -> Tile:
    """Symmetric trapezoidal groove along y (§4, Fig. 4): flat top (material 0, fraction ``top``
    of the period, split between both borders), two walls (material 1) and a flat floor
    (material 2, fraction ``floor``) at depth ``depth`` (in units of the period)."""
    P = _check("period", period, 1e-9, 1e9)
    depth = _check("depth", depth, 0.0, 10.0)
    floor = _check("floor", floor, 0.0, 1.0)
    top = _check("top", top, 0.0, 1.0)
    if floor + top > 1.0:
        raise ValueError(f"floor + top: expected <= 1, got {floor + top}")
    n_y = _check("n_y", n_y, 1, 1000, integer=True)
    x = np.array([0, top / 2, (1 - floor) / 2, (1 + floor) / 2, 1 - top / 2, 1]) * P
    z = np.array([0, 0, -depth, -depth, 0, 0]) * P
    mat_seg = np.array([0, 1, 2, 1, 0])
    seg_ok = np.diff(x) > 0            # drop zero-width segments
    keep = np.concatenate([[True], seg_ok])
    x, z, mat_seg = x[keep], z[keep], mat_seg[seg_ok]
    yc = np.linspace(0, P, n_y + 1)
    X, Y = np.meshgrid(np.arange(len(x)), yc, indexing="ij")
    V = np.stack([x[X.ravel()], Y.ravel(), z[X.ravel()]], 1)
    F = _grid_faces(len(x) - 1, n_y)
    seg = np.concatenate([np.repeat(np.arange(len(x) - 1), n_y)] * 2)
    return Tile(V, F, mat_seg[seg].astype(np.int64), P)


def pyramid_tile(period: float = 1.0, n_sides: int = 4, height: float = 0.5, base: float = 1.0,
                 rotation: float | None = None) -> Tile:
    """A regular n-sided pyramid centred in the tile (§4.2, Fig. 5): sides material 1, the
    flat floor around it material 0.  ``base`` in (0, 1] scales the base polygon relative to
    the largest one that fits in the square; ``height`` is in units of the period;
    ``rotation`` (radians) turns the polygon (default: 4-sided pyramids have their corners
    on the tile diagonals, so ``base=1`` fills the square)."""
    P = _check("period", period, 1e-9, 1e9)
    n = _check("n_sides", n_sides, 3, 64, integer=True)
    h = _check("height", height, 0.0, 10.0) * P
    base = _check("base", base, 1e-3, 1.0)
    phi0 = (np.pi / 4 if n == 4 else np.pi / 2) if rotation is None else _check("rotation", rotation, -10.0, 10.0)
    c = np.array([P / 2, P / 2])
    phis = np.mod(phi0 + 2 * np.pi * np.arange(n) / n, 2 * np.pi)

    def r_in(a, r):  # distance from centre to the polygon boundary at angle a
        k = np.floor(np.mod(a - phi0, 2 * np.pi) / (2 * np.pi / n))
        mid = phi0 + (k + 0.5) * 2 * np.pi / n
        return r * np.cos(np.pi / n) / np.cos(a - mid)

    def r_out(a):
        return (P / 2) / np.maximum(np.abs(np.cos(a)), np.abs(np.sin(a)))

    probe = np.linspace(0, 2 * np.pi, 4097)
    r_max = np.min(r_out(probe) / r_in(probe, 1.0))
    r = base * r_max * (1 - 1e-12)
    ang = np.unique(np.round(np.concatenate([phis, np.pi / 4 + np.pi / 2 * np.arange(4)]), 12) % (2 * np.pi))
    m = len(ang)
    # exact directions of the vertices on the polygon and on the square
    inner = c + np.stack([np.cos(ang), np.sin(ang)], 1) * r_in(ang, r)[:, None]
    on_vertex = np.isin(np.round(ang, 12), np.round(phis, 12))
    inner[on_vertex] = c + r * np.stack([np.cos(ang[on_vertex]), np.sin(ang[on_vertex])], 1)
    outer = c + np.stack([np.cos(ang), np.sin(ang)], 1) * r_out(ang)[:, None]
    outer = np.clip(np.round(outer / P * 1e12) / 1e12 * P, 0, P)
    V = np.concatenate([np.c_[inner, np.zeros(m)], np.c_[outer, np.zeros(m)], [[c[0], c[1], h]]])
    k = np.arange(m)
    k1 = (k + 1) % m
    floor = np.concatenate([np.stack([k, m + k, m + k1], 1), np.stack([k, m + k1, k1], 1)])
    sides = np.stack([np.full(m, 2 * m), k, k1], 1)
    F = np.concatenate([floor, sides])
    mat = np.concatenate([np.zeros(len(floor), np.int64), np.ones(m, np.int64)])
    area, _ = face_geometry(V, F)
    keep = area > 1e-12 * P * P
    return Tile(V, F[keep], mat[keep], P)


def _prism(p0, axis, radius, length, sides):
    """Closed prism (rod) with ``sides`` faces around ``axis`` starting at p0: vertices, faces."""
    axis = axis / np.linalg.norm(axis)
    t = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    t /= np.linalg.norm(t)
    b = np.cross(axis, t)
    a = 2 * np.pi * np.arange(sides) / sides
    ring = radius * (np.cos(a)[:, None] * t + np.sin(a)[:, None] * b)
    bot = p0 + ring
    top = p0 + length * axis + ring
    V = np.concatenate([bot, top, [p0, p0 + length * axis]])
    k = np.arange(sides)
    k1 = (k + 1) % sides
    side = np.concatenate([np.stack([k, k1, sides + k1], 1), np.stack([k, sides + k1, sides + k], 1)])
    cap_t = np.stack([np.full(sides, 2 * sides + 1), sides + k, sides + k1], 1)
    cap_b = np.stack([np.full(sides, 2 * sides), k1, k], 1)
    return V, np.concatenate([side, cap_t, cap_b])


def rods_tile(period: float = 1.0, n_rods: int = 4, radius: float = 0.05, length: float = 0.5,
              tilt: float = 0.3, azimuth: float = 0.0, randomness: float = 0.5, sides: int = 8,
              seed: int = 0) -> Tile:
    """Rods standing on a flat floor (§4.2, Fig. 6 velvet): floor material 0, rods material 1.

    Rods are closed prisms of ``radius`` and ``length`` (units of the period) tilted by
    ``tilt`` radians towards ``azimuth``, with directions and positions perturbed by
    ``randomness`` in [0, 1]; they start slightly below the floor and are kept inside the
    footprint (so the tile stays tileable)."""
    P = _check("period", period, 1e-9, 1e9)
    n_rods = _check("n_rods", n_rods, 1, 1000, integer=True)
    radius = _check("radius", radius, 1e-4, 0.25)
    length = _check("length", length, 1e-3, 5.0)
    tilt = _check("tilt", tilt, 0.0, 1.4)
    azimuth = _check("azimuth", azimuth, -10.0, 10.0)
    randomness = _check("randomness", randomness, 0.0, 1.0)
    sides = _check("sides", sides, 3, 64, integer=True)
    rng = np.random.default_rng(seed)
    floor = flat_tile(P)
    Vs, Fs, Ms = [floor.vertices], [floor.faces], [floor.face_material]
    nv = len(floor.vertices)
    g = int(np.ceil(np.sqrt(n_rods)))
    for i in range(n_rods):  # loop over a few rods (geometry construction, not facets)
        th = tilt + randomness * rng.normal(0, 0.3)
        az = azimuth + randomness * rng.normal(0, 0.8)
        axis = np.array([np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)])
        lx, ly = axis[:2] * length * P
        margin = radius * P * 1.01
        lo = np.array([margin - min(lx, 0), margin - min(ly, 0)])
        hi = np.array([P - margin - max(lx, 0), P - margin - max(ly, 0)])
        if np.any(hi <= lo):
            raise ValueError(f"length/tilt: rod {i} does not fit in the tile (reduce length, tilt or radius)")
        cell = (np.array([i % g, i // g]) + 0.5) / g
        xy = lo + (hi - lo) * np.clip(cell + randomness * rng.uniform(-0.5, 0.5, 2) / g, 0, 1)
        p0 = np.array([xy[0], xy[1], -0.02 * length * P])
        V, F = _prism(p0, axis, radius * P, length * P * 1.02, sides)
        Vs.append(V)
        Fs.append(F + nv)
        Ms.append(np.ones(len(F), np.int64))
        nv += len(V)
    return Tile(np.concatenate(Vs), np.concatenate(Fs), np.concatenate(Ms), P)


def heightfield_tile(heights, period: float = 1.0, height_scale: float = 1.0, materials=None) -> Tile:
    """Periodic height field (§4.2, Fig. 8): ``heights`` (H, W) sampled at x_i = i P / W,
    y_j = j P / H (row j, column i) and wrapped, so opposite borders match exactly; z is
    ``height_scale * heights`` (units of the period times P).  ``materials`` (H, W) int gives
    the material of each cell (both triangles), default 0."""
    Hm = np.asarray(heights, dtype=np.float64)
    if Hm.ndim != 2 or min(Hm.shape) < 2 or max(Hm.shape) > 4096:
        raise ValueError(f"heights: expected a 2D array with sides in [2, 4096], got shape {Hm.shape}")
    if not np.all(np.isfinite(Hm)):
        raise ValueError("heights: contains NaN or inf")
    P = _check("period", period, 1e-9, 1e9)
    s = _check("height_scale", height_scale, -1e3, 1e3)
    ny, nx = Hm.shape
    Zw = np.pad(Hm.T, ((0, 1), (0, 1)), mode="wrap")  # (nx+1, ny+1) indexed [i, j]
    x, y = np.meshgrid(np.linspace(0, P, nx + 1), np.linspace(0, P, ny + 1), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), s * P * Zw.ravel()], 1)
    F = _grid_faces(nx, ny)
    if materials is None:
        M = np.zeros(len(F), np.int64)
    else:
        Mm = np.asarray(materials)
        if Mm.shape != Hm.shape:
            raise ValueError(f"materials: expected shape {Hm.shape}, got {Mm.shape}")
        M = np.tile(Mm.T.ravel().astype(np.int64), 2)
    return Tile(V, F, M, P)


def woven_tile(period: float = 1.0, n_threads: int = 2, width: float = 0.8, height: float = 0.15,
               undulation: float = 0.5, res: int = 64) -> Tile:
    """Plain-weave threads as a periodic height field (§4.2, Fig. 7): warp threads along y
    (material 0) and weft threads along x (material 1) alternate over/under; ``width`` is
    the thread width as a fraction of the spacing P/n, ``height`` the thread thickness (units
    of the period), ``undulation`` the fraction of the thickness by which threads go up and
    down; ``res`` height-field samples per side.  The gaps show a floor at z = 0 (material 0)."""
    P = _check("period", period, 1e-9, 1e9)
    n = _check("n_threads", n_threads, 2, 32, integer=True)
    if n % 2:
        raise ValueError(f"n_threads: expected an even number (plain weave repeats every 2 threads), got {n}")
    width = _check("width", width, 0.05, 1.0)
    height = _check("height", height, 0.0, 2.0)
    undulation = _check("undulation", undulation, 0.0, 1.0)
    res = _check("res", res, 8, 1024, integer=True)
    sp = 1.0 / n
    c = (np.arange(res) + 0.5) / res
    y, x = np.meshgrid(c, c, indexing="ij")  # [row j (y), column i (x)]

    def thread(across, along):
        k = np.floor(across / sp)
        d = (across - (k + 0.5) * sp) / (0.5 * width * sp)
        prof = np.sqrt(np.clip(1 - d ** 2, 0, 1))
        wave = np.cos(np.pi * along / sp + np.pi * k)
        return np.where(np.abs(d) < 1, height * (0.5 * prof + 0.5 + 0.5 * undulation * wave), 0.0), np.abs(d) < 1

    hw, mw = thread(x, y)
    hf, mf = thread(y, x)
    # weft waves in opposite phase: shift by one thread spacing along its length
    hf2, _ = thread(y, x + sp)
    hf_on = np.where(mf, hf2, 0.0)
    Hm = np.maximum(hw, hf_on)
    mats = np.where(hf_on > hw, 1, 0)
    return heightfield_tile(Hm, P, 1.0, materials=mats)
