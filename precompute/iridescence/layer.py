"""The iridescent layer's shader tables (Velinov, Werner & Hullin 2018, §3-4; numpy, no Blender).

For a scratch set (``scratch_set.ScratchSet``) this computes what ``osl/iridescent_layer.osl``
evaluates per shading point: per-segment terms of eqs. 10-17 (``segment_terms``), a *reach grid*
over UV listing per cell the segments within ``REACH_SIGMA`` σ (``reach_grid``), the cell's
point-independent candidate distribution (``candidate_weights``: upper bounds of |η_s|² and ρ_m,
quantised to exact integer probabilities, ``quantize_cells``) and the float32 Si approximation the
shader uses (``si_float32``).  ``osl.iridescent_layer.generate`` writes these into the shader; the
model, routes and estimators are documented there and in ``model``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .model import RGB_WAVELENGTHS_UM as _RGB
from .scratch_set import GRID_BLOCK, GRID_CHUNK, corridor_bound, corridor_cells, csr_from_pairs

SIGMA_UM = 60.0
RGB_WAVELENGTHS_UM = tuple(float(x) for x in _RGB)
ROUTES = ("lobes", "lights")
#: Base weights: energy-consistent (``precompute.iridescence.energy``) or eq. 6's (1 − ρ).
BASE_WEIGHTS = ("energy", "paper")
#: GGX α of the per-sample lobes (both axes): ≪ any light's angular size, ax·ay > 2e-10 (NEE works).
LOBE_ALPHA = 1e-3
#: Reach of a segment around the shading point, in σ (exp(−9) ≈ 1e-4 truncation, as the numpy model).
REACH_SIGMA = 3.0
MAX_CELLS = 1 << 16
MAX_SEGMENTS = 200_000

# Si(x) for |x| > 4: π/2 − f(x) cos x − g(x) sin x, x·f and x²·g as degree-8 polynomials in
# y = 16/x² (least-squares Chebyshev fit to scipy's sici on [4, 1e6]; max |error| 1.4e-6).
SI_F = (0.999999996, -0.124975163, 0.092212424, -0.144500071, 0.263070324, -0.381662002, 0.364743176,
        -0.197777004, 0.045661117)
SI_G = (0.999999965, -0.374774073, 0.454449374, -0.928665073, 1.915608844, -2.945925628, 2.901227397,
        -1.60069362, 0.3736449)


def si_float32(x) -> np.ndarray:
    """NumPy float32 twin of the shader's ``si_f`` (Taylor series for |x| ≤ 4, auxiliary f, g above)."""
    x = np.asarray(x, dtype=np.float32)
    ax = np.abs(x)
    t = np.minimum(ax, np.float32(4.0))
    s = np.zeros_like(t)
    term = t.copy()
    t2 = t * t
    for n in range(14):
        s += term / np.float32(2 * n + 1)
        term = term * (-t2) / np.float32((2 * n + 2) * (2 * n + 3))
    big = np.maximum(ax, np.float32(4.0))
    y = np.float32(16.0) / (big * big)
    pf = np.polynomial.polynomial.polyval(y, np.array(SI_F, np.float32)).astype(np.float32)
    pg = np.polynomial.polynomial.polyval(y, np.array(SI_G, np.float32)).astype(np.float32)
    r_big = np.float32(np.pi / 2) - pf / big * np.cos(big) - pg / (big * big) * np.sin(big)
    return np.sign(x) * np.where(ax <= 4.0, s, r_big)


# ----------------------------------------------------------------------------- light specs
@dataclass(frozen=True)
class SphereLightSpec:
    """Sphere light (a Cycles point light with radius): world ``center`` (3,), ``radius`` (m),
    RGB ``radiance`` (W/m²/sr; Blender: color·energy/(4π²r²), soft falloff off)."""

    center: tuple
    radius: float
    radiance: tuple


@dataclass(frozen=True)
class PolygonLightSpec:
    """Convex planar polygon light: world ``vertices`` (N ≤ 16, 3) counter-clockwise seen from the
    emitting side, RGB ``radiance`` (W/m²/sr; Blender area light: color·energy/(π·area))."""

    vertices: tuple
    radiance: tuple
    two_sided: bool = False


def _check_lights(lights):
    out = []
    for i, L in enumerate(lights):
        if isinstance(L, SphereLightSpec):
            c = np.asarray(L.center, float)
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise ValueError(f"lights[{i}].center must be 3 finite numbers")
            if not (np.isfinite(L.radius) and L.radius > 0):
                raise ValueError(f"lights[{i}].radius must be > 0 (a point light needs a radius for route 'lights')")
        elif isinstance(L, PolygonLightSpec):
            v = np.asarray(L.vertices, float)
            if v.ndim != 2 or v.shape[1] != 3 or not 3 <= v.shape[0] <= 16 or not np.all(np.isfinite(v)):
                raise ValueError(f"lights[{i}].vertices must be (N, 3) finite with 3 <= N <= 16")
        else:
            raise ValueError(f"lights[{i}] must be a SphereLightSpec or PolygonLightSpec")
        r = np.asarray(L.radiance, float)
        if r.shape != (3,) or not np.all(np.isfinite(r)) or np.any(r < 0):
            raise ValueError(f"lights[{i}].radiance must be 3 finite numbers >= 0")
        out.append(L)
    return out


# ----------------------------------------------------------------------------- reach grid
@dataclass
class ReachGrid:
    """Uniform UV grid; cell ``iy*nx + ix`` lists every segment within ``reach_uv`` of *some* point
    of the cell (exact segment-box distance), so the shader needs exactly one cell per shading point."""

    origin: np.ndarray
    cell: float
    nx: int
    ny: int
    start: np.ndarray   # (nx*ny + 1,) int
    items: np.ndarray   # (K,) int

    @property
    def max_per_cell(self) -> int:
        return int(np.diff(self.start).max()) if self.start.size > 1 else 0


def segment_box_distance(p0, p1, lo, hi) -> np.ndarray:
    """Euclidean distance between segments p0 → p1 and axis-aligned boxes [lo, hi] (all (K, 2)); 0 if they meet."""
    d = p1 - p0
    # slab test: does the segment meet the box?
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta, tb = (lo - p0) * inv, (hi - p0) * inv
    par = d == 0
    inside_par = (p0 >= lo) & (p0 <= hi)
    t_enter = np.where(par, np.where(inside_par, -np.inf, np.inf), np.minimum(ta, tb)).max(1)
    t_exit = np.where(par, np.where(inside_par, np.inf, -np.inf), np.maximum(ta, tb)).min(1)
    meets = (t_enter <= t_exit) & (t_exit >= 0.0) & (t_enter <= 1.0)

    def pt_box(q):
        return np.linalg.norm(q - np.clip(q, lo, hi), axis=1)

    def pt_seg(q):
        L2 = np.sum(d * d, 1)
        t = np.clip(np.sum((q - p0) * d, 1) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
        return np.linalg.norm(q - (p0 + t[:, None] * d), axis=1)

    corners = [lo, hi, np.stack([lo[:, 0], hi[:, 1]], 1), np.stack([hi[:, 0], lo[:, 1]], 1)]
    dist = np.minimum(pt_box(p0), pt_box(p1))
    for c in corners:
        dist = np.minimum(dist, pt_seg(c))
    return np.where(meets, 0.0, dist)


def reach_grid(p0, p1, reach_uv: float, max_cells: int = MAX_CELLS, cell_frac: float = 1.0) -> ReachGrid:
    """Build the reach grid for segments ``p0 → p1`` (M, 2) UV; cells about ``cell_frac·reach_uv`` wide."""
    p0, p1 = np.asarray(p0, float).reshape(-1, 2), np.asarray(p1, float).reshape(-1, 2)
    M = p0.shape[0]
    if M == 0:
        return ReachGrid(np.zeros(2), 1.0, 1, 1, np.zeros(2, np.int64), np.zeros(0, np.int64))
    lo = np.minimum(p0, p1).min(0) - reach_uv
    hi = np.maximum(p0, p1).max(0) + reach_uv
    ext = hi - lo
    cell = max(cell_frac * reach_uv, float(np.sqrt(ext[0] * ext[1] / max_cells)) * 1.001, 1e-12)
    nx, ny = (np.floor(ext / cell).astype(np.int64) + 1).tolist()
    while nx * ny > max_cells:
        cell *= 1.1
        nx, ny = (np.floor(ext / cell).astype(np.int64) + 1).tolist()
    R = reach_uv / cell * (1 + 1e-6) + 1e-9                     # the reach in cells, for the candidate corridor
    cells, items = [], []
    for s0 in range(0, M, GRID_BLOCK):        # bounded memory: blocks of segments, chunks of ~GRID_CHUNK candidates
        q0, q1 = p0[s0:s0 + GRID_BLOCK], p1[s0:s0 + GRID_BLOCK]
        blo = np.clip(np.floor((np.minimum(q0, q1) - reach_uv - lo) / cell).astype(np.int64), 0, [nx - 1, ny - 1])
        bhi = np.clip(np.floor((np.maximum(q0, q1) + reach_uv - lo) / cell).astype(np.int64), 0, [nx - 1, ny - 1])
        cum = np.cumsum(corridor_bound(q0, q1, blo, bhi, 1.0 + 2.0 * R))
        a = 0
        while a < len(q0):
            b = max(int(np.searchsorted(cum, (cum[a - 1] if a else 0) + GRID_CHUNK, side="right")), a + 1)
            sid, cx, cy = corridor_cells((q0[a:b] - lo) / cell, (q1[a:b] - lo) / cell, blo[a:b], bhi[a:b], -R, 1.0 + R)
            sid = sid + a
            corner = lo + np.stack([cx, cy], 1) * cell
            keep = segment_box_distance(q0[sid], q1[sid], corner, corner + cell) <= reach_uv * (1 + 1e-9) + 1e-12
            cells.append((cy * nx + cx)[keep])
            items.append(sid[keep] + s0)
            a = b
    start, items = csr_from_pairs(np.concatenate(cells), np.concatenate(items), nx * ny)
    return ReachGrid(lo, cell, nx, ny, start, items)


# ----------------------------------------------------------------------------- spec + generator
@dataclass
class LayerSpec:
    """Inputs of ``generate``.  ``scratches``: a ``precompute.iridescence.scratch_set.ScratchSet`` (or any
    object with p0, p1 (M, 2) UV, width_um, depth_um (M,), uv_scale_um).

    ``candidates``: segments visited per shading sample.  0 = every segment of the reach-grid cell
    (exhaustive; cost grows with the scratch density); N > 0 = N segments drawn from the cell's
    bound distribution (``shader_tables``) and resampled by their exact weight (RIS), an unbiased
    estimator whose cost does not depend on the density.  ``samples``: route A lobes per sample."""

    scratches: object
    sigma_um: float = SIGMA_UM
    route: str = "lobes"
    lights: list = field(default_factory=list)
    samples: int = 1                 # route A: (segment, ξ₂) lobes per shading sample
    base_blend: bool = True          # weight the base (``base_weight``) instead of keeping it
    wavelengths_um: tuple = RGB_WAVELENGTHS_UM
    name: str = "iridescent_layer"
    candidates: int = 4              # 0 = exhaustive, else RIS candidates per shading sample
    base_weight: str = "energy"      # "energy": 1 − N(E) per channel (energy.py); "paper": 1 − ρ (eq. 6)
    shadows: bool = True             # route B: trace() visibility toward each light

    def validate(self) -> "LayerSpec":
        s = self.scratches
        for attr in ("p0", "p1", "width_um", "depth_um", "uv_scale_um"):
            if not hasattr(s, attr):
                raise ValueError(f"scratches must be a ScratchSet (missing {attr!r})")
        if len(np.asarray(s.width_um)) > MAX_SEGMENTS:
            raise ValueError(f"scratches: at most {MAX_SEGMENTS} segments (got {len(s.width_um)})")
        if not (np.isfinite(self.sigma_um) and 1.0 <= self.sigma_um <= 1000.0):
            raise ValueError(f"sigma_um must be in [1, 1000] micrometres, got {self.sigma_um!r}")
        if self.route not in ROUTES:
            raise ValueError(f"route must be one of {', '.join(ROUTES)}; got {self.route!r}")
        if isinstance(self.samples, bool) or not isinstance(self.samples, (int, np.integer)) or not 1 <= self.samples <= 32:
            raise ValueError(f"samples must be an integer in [1, 32], got {self.samples!r}")
        if (isinstance(self.candidates, bool) or not isinstance(self.candidates, (int, np.integer))
                or not 0 <= self.candidates <= MAX_CANDIDATES):
            raise ValueError(f"candidates must be an integer in [0, {MAX_CANDIDATES}] (0 = all), got {self.candidates!r}")
        if self.base_weight not in BASE_WEIGHTS:
            raise ValueError(f"base_weight must be one of {', '.join(BASE_WEIGHTS)}; got {self.base_weight!r}")
        lam = np.asarray(self.wavelengths_um, float)
        if lam.shape != (3,) or np.any(lam < 0.2) or np.any(lam > 2.0):
            raise ValueError("wavelengths_um must be 3 wavelengths in [0.2, 2.0] micrometres")
        if not self.name.isidentifier():
            raise ValueError(f"name must be an identifier, got {self.name!r}")
        self.lights = _check_lights(self.lights)
        return self


#: Columns of the shader's per-segment table (everything that does not depend on the shading point).
SEG_COLUMNS = ("t_u", "t_v", "c_t", "c_b", "L_um", "W_um", "Hbar_r", "Hbar_g", "Hbar_b", "Hbar_sum", "rho_coef",
               "pref_r", "pref_g", "pref_b")
NS = len(SEG_COLUMNS)
MAX_CANDIDATES = 64
#: Defensive share of the uniform distribution in each cell's candidate distribution (bounds 1/p).
UNIFORM_MIX = 0.02
#: Reach-grid cell size in units of the reach (3σ): smaller = tighter candidate bounds, larger tables.
CELL_FRAC = 1.5


def segment_terms(spec: LayerSpec) -> dict:
    """Point-independent per-segment terms (µm; eqs. 3, 10, 11, 17), float64, each (M,) or (M, 3).

    ``pref`` = W²|𝒟|²/(A_C λ²) (f_m per unit |η_s|² before the angular factor); route A's Cauchy
    proxy of channel c has amplitude ``amp_c = η·pref_c λ_c/(2√π σ)`` (ξ₁ integrated out) and mass
    ``H_c = amp_c λ_c / W`` = η·``Hbar_c``; ρ_m = ``rho_coef``·e^{−s_b²/2σ²}[erf(s_t2/√2σ) − erf(s_t1/√2σ)]."""
    s = spec.scratches
    sc = float(s.uv_scale_um)
    p0, p1 = np.asarray(s.p0, float).reshape(-1, 2) * sc, np.asarray(s.p1, float).reshape(-1, 2) * sc
    d = p1 - p0
    L = np.linalg.norm(d, axis=1)
    t = d / np.where(L > 0, L, 1.0)[:, None]
    W = np.asarray(s.width_um, float)
    D = np.asarray(s.depth_um, float)
    lam = np.asarray(spec.wavelengths_um, float)
    sig = float(spec.sigma_um)
    A_C = np.pi * sig ** 2
    pref = W[:, None] ** 2 * (2.0 - 2.0 * np.cos(4 * np.pi * D[:, None] / lam)) / (A_C * lam ** 2)
    amp_bar = pref * lam / (2.0 * np.sqrt(np.pi) * sig)
    Hbar = amp_bar * lam / np.where(W > 0, W, 1.0)[:, None]
    return dict(t=t, c_t=np.sum(p0 * t, 1), c_b=p0[:, 1] * t[:, 0] - p0[:, 0] * t[:, 1], L=L, W=W, Hbar=Hbar,
                rho_coef=W / A_C * np.sqrt(np.pi / 2.0) * sig, pref=pref)


def candidate_weights(spec: LayerSpec, terms: dict, grid: "ReachGrid") -> np.ndarray:
    """Per grid item (cell, segment): the cell's candidate probability p (sums to 1 per cell).

    Bound of the segment's weight over the cell: with d = distance cell (box) ↔ segment,
    |η_s|² ≤ A_C min(2, 2L/(√π σ)) e^{−d²/σ²} (erf slope ≤ 2/√π; erfc(x) ≤ e^{−x²} off the ends) and
    ρ_m ≤ rho_coef·min(2, 2L/(√(2π) σ)) e^{−d²/2σ²}.  p = (1 − ε)·½(η-bound share + ρ-bound share)
    + ε/n (ρ term only for the "paper" base weight; the energy E_m ≤ |η_s|²·Hbar_sum follows the η share),
    so 1/p ≤ n/ε."""
    if grid.items.size == 0:
        return np.zeros(0)
    sc = float(spec.scratches.uv_scale_um)
    sig = float(spec.sigma_um)
    cid = np.repeat(np.arange(grid.nx * grid.ny), np.diff(grid.start))
    m = grid.items
    corner = (grid.origin + np.stack([cid % grid.nx, cid // grid.nx], 1) * grid.cell) * sc
    p0 = np.asarray(spec.scratches.p0, float).reshape(-1, 2)[m] * sc
    p1 = np.asarray(spec.scratches.p1, float).reshape(-1, 2)[m] * sc
    d = segment_box_distance(p0, p1, corner, corner + grid.cell * sc)
    L = terms["L"][m]
    b_eta = np.pi * sig ** 2 * np.minimum(2.0, 2.0 * L / (np.sqrt(np.pi) * sig)) * np.exp(-(d / sig) ** 2) \
        * terms["Hbar"][m].sum(1)
    b_rho = terms["rho_coef"][m] * np.minimum(2.0, 2.0 * L / (np.sqrt(2 * np.pi) * sig)) * np.exp(-0.5 * (d / sig) ** 2)
    n = np.diff(grid.start)[cid].astype(float)

    def share(b):
        tot = np.bincount(cid, weights=b, minlength=grid.nx * grid.ny)[cid]
        return np.where(tot > 0, b / np.where(tot > 0, tot, 1.0), 1.0 / n)

    paper = spec.base_blend and spec.base_weight == "paper"      # ρ estimated too (the energy is ∝ η Hbar)
    p = 0.5 * (share(b_eta) + share(b_rho)) if paper else share(b_eta)
    return (1.0 - UNIFORM_MIX) * p + UNIFORM_MIX / n


def _check_cell_load(n_cell, qbits: int) -> None:
    """Every cell's segments must get >= 1 of its 2**qbits quanta with room to spare (<= 2**qbits / 4)."""
    Q = 1 << qbits
    if n_cell.size and n_cell.max() > Q // 4:
        raise ValueError(f"scratches: {n_cell.max()} segments within reach of one grid cell (at most {Q // 4} "
                         "with this many segments); use fewer segments or a smaller sigma_um")


def quantize_cells(p, start, qbits: int) -> np.ndarray:
    """Integer quanta per item (≥ 1 each, exactly 2**qbits per non-empty cell, ∝ ``p`` otherwise), so the
    shader's probabilities are exact integers / 2**qbits (largest-remainder rounding per cell)."""
    Q = 1 << qbits
    n_cell = np.diff(start)
    if p.size == 0:
        return np.zeros(0, np.int64)
    _check_cell_load(n_cell, qbits)
    cid = np.repeat(np.arange(n_cell.size), n_cell)
    x = p * (Q - n_cell[cid])
    c = 1 + np.floor(x).astype(np.int64)
    rem = Q - np.bincount(cid, weights=c, minlength=n_cell.size).astype(np.int64)      # < n per cell
    order = np.lexsort((-(x - np.floor(x)), cid))                                       # by cell, then frac desc
    rank = np.arange(p.size) - start[cid[order]]
    c[order] += (rank < rem[cid[order]]).astype(np.int64)
    return c


def shader_tables(spec: LayerSpec, cell_frac: float = CELL_FRAC) -> dict:
    """The constant arrays of the generated shader: the flat segment table (``SEG_COLUMNS``, float32)
    and the reach grid (segments with L = 0 dropped: they contribute nothing) whose items are packed
    ints ``segment << QBITS | e`` where e is the inclusive end of the item's range of quanta in its
    cell's candidate distribution (``candidate_weights``, quantised by ``quantize_cells``)."""
    s = spec.scratches
    terms = segment_terms(spec)
    keep = terms["L"] > 0
    p0, p1 = np.asarray(s.p0, float).reshape(-1, 2), np.asarray(s.p1, float).reshape(-1, 2)
    reach_uv = REACH_SIGMA * spec.sigma_um / float(s.uv_scale_um)
    idx = np.nonzero(keep)[0]
    grid = reach_grid(p0[idx], p1[idx], reach_uv, cell_frac=cell_frac)
    grid.items = idx[grid.items]
    qbits = 31 - max(1, int(np.ceil(np.log2(max(len(terms["L"]), 2)))))
    _check_cell_load(np.diff(grid.start), qbits)          # before the per-item weights (memory ∝ items)
    q = quantize_cells(candidate_weights(spec, terms, grid), grid.start, qbits)
    cid = np.repeat(np.arange(grid.nx * grid.ny), np.diff(grid.start))
    end = np.cumsum(q) - np.concatenate([[0], np.cumsum(q)])[grid.start[cid]] - 1
    packed = (grid.items.astype(np.int64) << qbits) | end
    seg = np.concatenate([terms["t"], terms["c_t"][:, None], terms["c_b"][:, None], terms["L"][:, None],
                          terms["W"][:, None], terms["Hbar"], terms["Hbar"].sum(1)[:, None],
                          terms["rho_coef"][:, None], terms["pref"]], 1)
    assert seg.shape[1] == NS
    return {"segments": seg.astype(np.float32).ravel(), "grid": grid, "packed": packed, "qbits": qbits,
            "quanta": q, "grid_params": np.array([grid.origin[0], grid.origin[1], grid.cell, grid.nx, grid.ny])}
