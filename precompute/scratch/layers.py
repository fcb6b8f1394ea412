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
           "merged_layers", "voronoi_f1", "layer_indicator"]

#: Density grid of the tabulated mean coverage (F1 of a 3x3-searched unit jittered grid is < 1.5).
COVERAGE_D = np.linspace(0.0, 1.5, 61)


@dataclass(frozen=True)
class LayerParams:
    """Distribution parameters of one material's scratch layers (the paper's Table 1 columns).

    n_layers: N >= 1; theta_deg: orientation spread Θ in degrees [0, 360];
    length l and width w: mean scratch length/width in UV units (> 0, w <= l);
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
        for name in ("length", "width"):
            v = getattr(self, name)
            if not isinstance(v, (int, float, np.floating, np.integer)) or not (0.0 < float(v) < math.inf):
                bad(name, "a positive finite number (UV units)", v)
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
    """(d grid, c̄(d)) on ``COVERAGE_D``: linear interpolation error < 0.003 (61 points on [0, 1.5])."""
    return COVERAGE_D.copy(), _coverage().copy()


@functools.lru_cache(maxsize=1)
def _coverage() -> np.ndarray:
    return mean_coverage(COVERAGE_D)  # 0.35 s of Monte Carlo, the same every time (fixed seed)


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
