"""Scratch layer distributions (Raymond et al. 2016, §4.3 and §5.3, eq. 7).

A layer k places parallel scratches with the indicator function

    1_{S_k}(u, v) = [ N( R(Θ_k) diag(l, w)^-1 (u, v)ᵀ + ξ_k ) ]_d          (eq. 7)

where N is Worley's cellular noise F1 (here: Cycles' own 2D Voronoi F1, Euclidean,
randomness 1, unit cells), [x]_d = 1 if x <= d, l and w are the mean scratch length and
width in UV units, Θ_k is drawn in [-Θ/2, Θ/2] and ξ_k in [-1, 1]².

The relative area α_k (eq. 3) tends, for footprints spanning many noise cells, to the mean
coverage c̄(d) = P(F1 <= d) of the noise, which this module tabulates (``mean_coverage``)
so the shader can converge to the area-weighted BRDF at a distance.  The per-layer
rotations and offsets are generated here once (seeded) and compiled into the shader, so
numpy and OSL use the very same numbers.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..validation import check_seed

__all__ = ["LayerParams", "layer_transforms", "mean_coverage", "COVERAGE_D", "coverage_table", "PAPER_TABLE1",
           "merged_layers", "voronoi_f1", "layer_indicator", "coverage_ratio", "coverage_lookup", "union_alpha",
           "far_alpha", "footprint_alpha", "FAR_SPREAD", "ALPHA_CULL"]

#: Allowed scratch length / width in UV units: far inside float32 (the shaders' constants and the panel's
#: settings hold every accepted value exactly enough to rebuild the same material).
SIZE_RANGE = (1e-9, 1e9)

#: Density grid of the tabulated mean coverage (F1 of a 3x3-searched unit jittered grid is < 1.5).
COVERAGE_D = np.linspace(0.0, 1.5, 61)


@dataclass(frozen=True)
class LayerParams:
    """Distribution parameters of one material's scratch layers (the paper's Table 1 columns).

    n_layers: N >= 1; theta_deg: orientation spread Θ in degrees [0, 360];
    length l and width w: mean scratch length/width in UV units, in [1e-9, 1e9] (``SIZE_RANGE``: what a
    float32 shader constant and the panel hold), w <= l;
    density d in [0, 1]; seed: any integer.
    """

    n_layers: int = 4
    theta_deg: float = 7.0
    length: float = 0.2
    width: float = 2e-4
    density: float = 0.6
    seed: int = 0

    def __post_init__(self):
        def bad(name, rng, value):
            raise ValueError(f"{name} must be {rng}, got {value!r}")

        if isinstance(self.n_layers, bool) or not isinstance(self.n_layers, (int, np.integer)) or not 1 <= self.n_layers <= 64:
            bad("layers (n_layers)", "an integer in [1, 64]", self.n_layers)
        for name, lo, hi in (("theta_deg", 0.0, 360.0), ("density", 0.0, 1.0)):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not (lo <= float(v) <= hi):
                bad(name, f"in [{lo:g}, {hi:g}]", v)
        lo, hi = SIZE_RANGE
        for name in ("length", "width"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not (lo <= float(v) <= hi):
                bad(name, f"in [{lo:g}, {hi:g}] (UV units)", v)
        if self.width > self.length:
            bad("width", f"<= length ({self.length:g}): scratches are stretched along u", self.width)
        if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool):
            bad("seed", "an integer", self.seed)

    def cache_key(self) -> dict:
        return {k: getattr(self, k) for k in ("n_layers", "theta_deg", "length", "width", "density", "seed")}


#: The paper's Table 1 (Raymond et al. 2016): figure -> (N, Θ deg, l, w, d).
PAPER_TABLE1 = {
    "fig1b": (4, 7.0, 0.2, 2e-4, 0.6),
    "fig1c": (16, 360.0, 0.1, 1e-5, 0.3),
    "fig1d": (32, 360.0, 0.3, 3e-4, 0.05),
    "fig10bde": (6, 5.0, 0.1, 5e-4, 0.16),
    "fig10f": (32, 360.0, 0.1, 2e-4, 0.05),
    "fig12a": (4, 4.0, 0.1, 5e-5, 0.5),
    "fig12b": (16, 360.0, 0.1, 2e-4, 0.1),
    "fig12c": (16, 360.0, 0.02, 2e-5, 0.1),
    "fig12d": (32, 360.0, 0.1, 1e-5, 0.2),
    "fig14a": (4, 7.0, 0.02, 7e-4, 0.5),
    "fig14b": (16, 360.0, 0.02, 1e-5, 0.2),
}


def layer_transforms(params: LayerParams) -> tuple[np.ndarray, np.ndarray]:
    """Per-layer rotation Θ_k (radians, uniform in [-Θ/2, Θ/2]) and offset ξ_k ∈ [-1, 1]² (§5.3, eq. 7)."""
    rng = np.random.default_rng(np.random.SeedSequence([0x5C7A7C4, int(params.seed) & 0xFFFFFFFF]))
    half = math.radians(params.theta_deg) / 2.0
    theta_k = rng.uniform(-half, half, params.n_layers)
    xi_k = rng.uniform(-1.0, 1.0, (params.n_layers, 2))
    return theta_k, xi_k


def _f1_unit_jittered_grid(points: np.ndarray, jitter: np.ndarray) -> np.ndarray:
    """F1 distance of ``points`` (in [0,1)² of a centre cell) to feature points of the 3x3 cells around it.

    ``jitter[..., 9, 2]`` are the neighbours' feature positions inside their cells, i.i.d. uniform:
    this is the distribution of Cycles' ``voronoi_f1`` (2D, Euclidean, randomness 1, 3x3 search).
    """
    off = np.stack(np.meshgrid([-1, 0, 1], [-1, 0, 1], indexing="xy"), -1).reshape(9, 2)
    feature = off[None] + jitter  # [n, 9, 2]
    return np.sqrt(((feature - points[:, None, :]) ** 2).sum(-1)).min(-1)


def mean_coverage(d, samples: int = 400_000, seed: int = 1) -> np.ndarray:
    """c̄(d) = P(F1 <= d): the area fraction the thresholded noise [N]_d covers (§5.3, eq. 7).

    Monte Carlo over uniform points and uniform feature jitter (standard error <= 0.0008 at the
    default sample count).  Vectorised over ``d``.
    """
    d = np.asarray(d, dtype=np.float64)
    if np.any(~np.isfinite(d)) or np.any(d < 0):
        raise ValueError("density d must be finite and >= 0")
    rng = np.random.default_rng(check_seed("seed", seed))
    f1 = _f1_unit_jittered_grid(rng.random((samples, 2)), rng.random((samples, 9, 2)))
    f1.sort()
    return np.searchsorted(f1, d, side="right") / samples


def coverage_table() -> tuple[np.ndarray, np.ndarray]:
    """(d grid, c̄(d)) on ``COVERAGE_D``: linear interpolation error < 0.003 (61 points on [0, 1.5]).

    Computed by quadrature, not Monte Carlo (``_exact_coverage``): the feature points of the 9 cells
    around a point p are independent and uniform in their cells, so P(F1(p) > d) = Π_j (1 − A_j(p, d)) with
    A_j the area of the disk (p, d) inside cell j, and c̄(d) = 1 − E_p[Π_j (1 − A_j)] (§5.3, eq. 7)."""
    return COVERAGE_D.copy(), _coverage().copy()


@functools.lru_cache(maxsize=1)
def _coverage() -> np.ndarray:
    return _exact_coverage(COVERAGE_D)


def _quadrant_area(x, y, r):
    """Area of the disk of radius r at the origin inside [0, x] × [0, y], odd in x and in y (x, y signed)."""
    sx, sy = np.sign(x), np.sign(y)
    x, y = np.minimum(np.abs(x), r), np.minimum(np.abs(y), r)

    def h(t):  # ∫_0^t sqrt(r² - s²) ds, t in [0, r]
        return 0.5 * (t * np.sqrt(np.maximum(r * r - t * t, 0.0)) + r * r * np.arcsin(np.clip(t / np.maximum(r, 1e-300), 0, 1)))

    t_star = np.minimum(x, np.sqrt(np.maximum(r * r - y * y, 0.0)))   # below t*, the chord reaches past y
    return sx * sy * (y * t_star + h(x) - h(t_star))


def _exact_coverage(d, n: int = 64) -> np.ndarray:
    """c̄(d) = 1 − E_p[Π_j (1 − A_j(p, d))] over the 3x3 cells (midpoint rule, n² points of the cell, |error| < 2e-6 at n = 64 against n = 400; exact
    where the disk lies inside one cell, so the error lives in a strip of width d along the cell edges)."""
    d = np.atleast_1d(np.asarray(d, np.float64))
    g = (np.arange(n) + 0.5) / n
    px, py = (a.ravel() for a in np.meshgrid(g, g, indexing="xy"))
    out = np.empty(d.shape)
    for m, r in enumerate(d):
        if r <= 0.0:
            out[m] = 0.0
            continue
        keep = np.ones_like(px)
        for j in (-1, 0, 1):
            for i in (-1, 0, 1):
                x0, x1, y0, y1 = i - px, i + 1 - px, j - py, j + 1 - py
                a = (_quadrant_area(x1, y1, r) - _quadrant_area(x0, y1, r)
                     - _quadrant_area(x1, y0, r) + _quadrant_area(x0, y0, r))
                keep *= 1.0 - np.clip(a, 0.0, 1.0)
        out[m] = 1.0 - keep.mean()
    return out


def coverage_ratio() -> tuple[np.ndarray, np.ndarray]:
    """(d grid, g(d) = c̄(d) / d²) on ``COVERAGE_D``, g(0) = π: the table the shaders interpolate (``COV``).

    c̄(d) = π d² (1 + O(d³)) near 0, so interpolating g instead of c̄ makes the lookup exact as d -> 0: the
    layer culling c̄(d) < ALPHA_CULL then holds below d = sqrt(ALPHA_CULL / π) = 5.6e-4, as on the SVM path."""
    d, c = coverage_table()
    g = np.empty_like(c)
    g[0] = math.pi
    g[1:] = c[1:] / d[1:] ** 2
    return d, g


def coverage_lookup(d, ratio: np.ndarray | None = None, dmax: float = float(COVERAGE_D[-1])) -> np.ndarray:
    """The shaders' c̄(d) (``mean_coverage`` in osl/scratch_layers.h): d² times g linearly interpolated on the
    uniform grid of ``ratio`` (default ``coverage_ratio()``); d in [0, 1] (clamped like the shader)."""
    g = coverage_ratio()[1] if ratio is None else np.asarray(ratio, np.float64)
    d = np.clip(np.asarray(d, np.float64), 0.0, 1.0)
    x = d / dmax * (len(g) - 1)
    i0 = np.minimum(np.floor(x).astype(int), len(g) - 2)
    return d * d * (g[i0] + (g[i0 + 1] - g[i0]) * (x - i0))


#: α_k below it are 0 (§6.1): the one value of the shaders' ALPHA_CULL (``osl.scratch_svbrdf``) and the SVM
#: path's cull density (``node_groups.scratch_svm.CULL_DENSITY``)
ALPHA_CULL = 1e-6
#: footprint spread (noise cells) from which a layer's α_k is its mean c̄(d) (osl/scratch_layer_alpha.h)
FAR_SPREAD = 0.8


def union_alpha(alpha) -> tuple[np.ndarray, np.ndarray]:
    """Layer coverages α_k [..., N] -> (α'_k, Σ α'_k) with Σ α'_k = 1 − Π_k (1 − α_k) (eq. 4 for independent layers).

    Eq. 4 takes min(Σ α_k, 1) as the scratched fraction: right where the layers' scratches do not overlap
    (a sharp footprint: α_k binary), but N c̄ instead of 1 − (1 − c̄)^N once α_k -> c̄(d) in the far field,
    a step where the footprint grows and a disagreement with the binary-α SVM twin.  Independent layers
    cover 1 − Π (1 − α_k) of the footprint; α'_k keeps the layer-pick proportions α_k / Σ α_k.  Binary α_k
    are unchanged in effect (one covering layer picked uniformly), and E[1 − Π (1 − α_k)] = 1 − (1 − c̄)^N
    at every footprint size (each α_k has mean c̄ and the layers are independent)."""
    a = np.asarray(alpha, np.float64)
    s = a.sum(-1)
    union = 1.0 - np.prod(1.0 - a, axis=-1)
    scale = np.where(s > 0.0, union / np.where(s > 0.0, s, 1.0), 0.0)
    return a * scale[..., None], union


def far_alpha(cbar, n_layers: int) -> np.ndarray:
    """α_k of every layer in the far field (footprint >> a noise cell): (1 − (1 − c̄)^N) / N (``union_alpha``
    of N equal α_k = c̄(d); 0 where c̄ < ALPHA_CULL)."""
    c = np.asarray(cbar, np.float64)
    return np.where(c < ALPHA_CULL, 0.0, (1.0 - (1.0 - c) ** n_layers) / n_layers)


def _disk_overlap(a, R, r):
    """Twin of ``disk_overlap`` (osl/scratch_layers.h): lens area of circles (a, R) at distance r / (π R²)."""
    a, R, r = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (a, R, r)))
    with np.errstate(invalid="ignore", divide="ignore"):
        c1 = np.clip((r * r + a * a - R * R) / (2 * r * a), -1, 1)
        c2 = np.clip((r * r + R * R - a * a) / (2 * r * R), -1, 1)
        k = (-r + a + R) * (r + a - R) * (r - a + R) * (r + a + R)
        lens = a * a * np.arccos(c1) + R * R * np.arccos(c2) - 0.5 * np.sqrt(np.maximum(k, 0.0))
        out = np.clip(lens / (math.pi * R * R), 0.0, 1.0)
    out = np.where(r <= np.abs(a - R), np.where(a < R, a * a / (R * R), 1.0), out)
    return np.where(r >= a + R, 0.0, out)


def footprint_alpha(uv, r_uv: float, params: LayerParams) -> tuple[np.ndarray, np.ndarray]:
    """Twin of osl/scratch_layer_alpha.h for a view along the normal (round footprint of radius ``r_uv`` in UV):
    (α'_k [..., N], Σ α'_k [...]) at UV points ``uv [..., 2]`` (eq. 3 over the footprint, eq. 7, §6.1).

    Per layer: the footprint's spread R = r_uv max(|R(Θ_k)ᵀ-rows / (l, w)|) in noise cells; α_k = the union of
    the 3x3 cells' scratch disks (radius d) over the footprint disk, faded to c̄(d) by smoothstep(0.2, 0.8, R);
    culled below ALPHA_CULL; combined by ``union_alpha``.  Past r_uv max(1/l, 1/w) >= 0.8 √2 every layer is
    far: ``far_alpha``."""
    uv = np.asarray(uv, np.float64)
    d = float(np.clip(params.density, 0.0, 1.0))
    cbar = float(coverage_lookup(d))
    inv_l, inv_w = 1.0 / params.length, 1.0 / params.width
    n = params.n_layers
    shape = uv.shape[:-1]
    if r_uv * max(inv_l, inv_w) >= FAR_SPREAD * math.sqrt(2.0):
        a = np.broadcast_to(far_alpha(cbar, n), shape + (n,)).copy()
        return a, a.sum(-1)
    theta_k, xi_k = layer_transforms(params)
    raw = np.empty(shape + (n,))
    for k in range(n):
        ck, sk = math.cos(theta_k[k]), math.sin(theta_k[k])
        y = np.stack([(ck * uv[..., 0] + sk * uv[..., 1]) * inv_l + xi_k[k, 0],
                      (-sk * uv[..., 0] + ck * uv[..., 1]) * inv_w + xi_k[k, 1]], -1)
        # semi-axes (view along the normal: a1 = (0, r), a2 = (r, 0) in UV, as the shader's pv = (1, 0))
        e1 = np.hypot(sk * r_uv * inv_l, ck * r_uv * inv_w)
        e2 = np.hypot(ck * r_uv * inv_l, -sk * r_uv * inv_w)
        spread = max(e1, e2)
        t = min(max((spread - 0.2) / 0.6, 0.0), 1.0)
        fade = t * t * (3 - 2 * t)
        a = np.full(shape, cbar)
        if fade < 1.0:
            R = max(spread, 1e-6)
            cell = np.floor(y)
            ci = cell.astype(np.int64)
            miss = np.ones(shape)
            for j in (-1, 0, 1):
                for i in (-1, 0, 1):
                    hx, hy = _hash_int2_to_vector2(ci[..., 0] + i, ci[..., 1] + j)
                    dist = np.hypot(cell[..., 0] + i + hx - y[..., 0], cell[..., 1] + j + hy - y[..., 1])
                    miss *= 1.0 - _disk_overlap(d, R, dist)
            a = (1.0 - miss) + (cbar - (1.0 - miss)) * fade
        raw[..., k] = np.where(a < ALPHA_CULL, 0.0, a)
    return union_alpha(raw)


def merged_layers(params: LayerParams, n_max: int) -> LayerParams:
    """At most ``n_max`` layers scratching the same fraction of the surface as ``params``.

    Independent layers of coverage c̄(d) leave 1 − (1 − c̄(d))^N of the surface unscratched, so
    ``n_max`` layers need c̄(d') = 1 − (1 − c̄(d))^(N / n_max); d' follows from the coverage table.
    For previews whose shader cost grows with the layer count (EEVEE compiles every layer); the
    orientations come from the same seed (the first ``n_max`` of its draw)."""
    if isinstance(n_max, bool) or not isinstance(n_max, (int, np.integer)) or n_max < 1:
        raise ValueError(f"n_max must be an integer >= 1, got {n_max!r}")
    if params.n_layers <= n_max:
        return params
    d, cbar = coverage_table()
    target = 1.0 - (1.0 - float(np.interp(params.density, d, cbar))) ** (params.n_layers / n_max)
    density = float(np.interp(target, cbar, d)) if target < cbar[-1] else float(d[-1])
    return LayerParams(int(n_max), params.theta_deg, params.length, params.width, min(density, 1.0), params.seed)



def _hash_int2_to_vector2(kx: np.ndarray, ky: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cycles' ``hash_int2_to_vector2`` (node_hash.h, Blender >= 5.0: PCG 2D on signed 32-bit ints)."""
    with np.errstate(over="ignore"):
        a = np.int32(1664525)
        vx = kx.astype(np.int32) * a + np.int32(1013904223)
        vy = ky.astype(np.int32) * a + np.int32(1013904223)
        vx = vx + vy * a
        vy = vy + vx * a
        vx = vx ^ (vx >> 16)
        vy = vy ^ (vy >> 16)
        vx = vx + vy * a
        vy = vy + vx * a
    scale = np.float32(1.0) / np.float32(0x7FFFFFFF)
    return ((vx & np.int32(0x7FFFFFFF)).astype(np.float32) * scale,
            (vy & np.int32(0x7FFFFFFF)).astype(np.float32) * scale)


def voronoi_f1(y) -> np.ndarray:
    """F1 distance of Cycles' 2D Voronoi texture (Euclidean, randomness 1, scale 1) at points ``y [..., 2]``.

    The numpy twin of ``voronoi_f1`` in Cycles' ``node_voronoi.h`` (integer cells, Blender >= 5.0): the
    nearest of the feature points ``cell + hash(cell)`` of the 3x3 cells around ``y``.  Used to place
    explicit grooves where the shader puts scratches (eq. 7).
    """
    y = np.asarray(y, np.float64)
    if y.shape[-1:] != (2,):
        raise ValueError(f"y: expected points of shape [..., 2], got {y.shape}")
    cell = np.floor(y)
    local = y - cell
    ci = cell.astype(np.int64)
    best = np.full(y.shape[:-1], np.inf)
    for j in (-1, 0, 1):
        for i in (-1, 0, 1):
            hx, hy = _hash_int2_to_vector2(ci[..., 0] + i, ci[..., 1] + j)
            best = np.minimum(best, np.hypot(i + hx - local[..., 0], j + hy - local[..., 1]))
    return best


def layer_indicator(uv, params: LayerParams, k: int) -> np.ndarray:
    """The scratch indicator 1_{S_k}(u, v) of layer ``k`` (eq. 7) at UV points ``uv [..., 2]``: boolean.

    y = diag(l, w)^-1 R(Θ_k) (u, v) + ξ_k (rotation first, as the shader: see osl/scratch_svbrdf.osl) and
    1 where Cycles' Voronoi F1(y) <= d.
    """
    if not isinstance(params, LayerParams):
        raise ValueError(f"params: expected a LayerParams, got {type(params).__name__}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k < params.n_layers:
        raise ValueError(f"k: expected a layer index in [0, {params.n_layers - 1}], got {k!r}")
    uv = np.asarray(uv, np.float64)
    theta_k, xi_k = layer_transforms(params)
    c, s = math.cos(theta_k[k]), math.sin(theta_k[k])
    y = np.stack([(c * uv[..., 0] + s * uv[..., 1]) / params.length + xi_k[k, 0],
                  (-s * uv[..., 0] + c * uv[..., 1]) / params.width + xi_k[k, 1]], -1)
    return voronoi_f1(y) <= params.density
