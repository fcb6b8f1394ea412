"""Generator of the specialised OSL iridescent scratch layer (Velinov, Werner & Hullin 2018; Werner et al. 2017).

The generated shader takes any closure as ``Base`` and returns ``BSDF``: the base (optionally
blended by ``1 - ρ``, eqs. 6/17) plus the wave-optical response of the scratches in reach.  The
scratch segments (UV, width W and depth D in µm) and a *reach grid* over UV are compiled in as
constant arrays, so an INTERNAL script node renders without the add-on (and on OptiX).

Model per segment m at the shading point (RGB mode: one wavelength λ_c per channel, as
``precompute.iridescence.evaluate(mode='rgb')``; µm throughout):

  |η_s|² = 2A_C e^{−s_b²/σ²} · ½[erf(s_t2/σ) − erf(s_t1/σ)]          eq. 10 (finite segment)
  ρ_m    = (W/A_C) e^{−s_b²/2σ²} √(π/2) σ [erf(s_t2/√2σ) − erf(s_t1/√2σ)]   eq. 17
  f_m    = W²|𝒟|²|η_s|² sinc²(πWξ₂/λ) e^{−σ²k²ξ₁²} / (A_C λ²)             eqs. 1-11

Point evaluation: the pixel filter's jittered samples do the footprint integral (Monte Carlo
anti-aliasing along *and* across scratches, Fig. 4 right), so eqs. 14-18 are not used here.

Two routes (``route``):

``"lobes"`` (A, default) — the Gaussian in ξ₁ is far narrower than any light (eq. 26), so
  f_m ≈ g_m(ξ₂) δ(ξ₁) with g_m = W²|𝒟|²|η_s|² √π/(σk) sinc²(πWξ₂/λ)/(A_C λ²), and in
  direction-cosine space L = ∫∫ f L_i dξ₁dξ₂ (eq. 24).  Each shading sample draws ``samples`` (default 1)
  (segment, ξ₂) pairs — segment/channel stratified with probability ∝ the mass of a Cauchy
  proxy h_c = amp_c/(1 + (ξ₂/s_c)²), s_c = λ_c/(πW) (same total mass over ℝ as sinc², ratio
  sinc²/h ≤ 1.5), ξ₂ from that Cauchy; a ξ₂ off the chord of the hemisphere (ω_i below the
  horizon) contributes nothing — and returns for each a very
  narrow GGX lobe (α = ``LOBE_ALPHA``, normal ∝ ξ₂ b_m + (ω_i,z + ω_o,z) n, tangent t_m) whose
  reflection direction is the chosen point on the line ξ₁ = 0.  Its RGB weight is the one-sample
  MIS (balance over channels) estimate ``ΣH · g_c(ξ₂) / Σ_c' h_c'(ξ₂) / samples``.  The closure
  sum is therefore an unbiased estimator of the model's BSDF, and Cycles' NEE + MIS light it
  with any light (area, sphere, mesh, world), with shadows.  A narrow GGX lobe reflects
  albedo 1.0 (measured) so no compensation is needed.

``"lights"`` (B) — Velinov's closed forms (eq. 27 with exact Si, sphere eqs. 30-37, polygon
  eqs. 36-41; a port of ``precompute.iridescence_lights``) for the lights compiled into the
  shader (``SphereLightSpec``/``PolygonLightSpec`` in world space, radiance in W/m²/sr).  The
  result is radiance, returned as ``emission()``: Cycles' NEE never sees it (no BSDF, no double
  counting with the lights it also samples for the base), BSDF rays cannot bounce off it, and
  the material must use ``emission_sampling = 'NONE'`` so the object is not sampled as a light.
  No shadows, no world light, no indirect light in the scratches; light edits need a rebuild.

Segment selection (``candidates``, both routes): 0 = every segment listed in the shading point's
reach-grid cell (exact; cost ∝ scratch density).  N > 0 (default 4) = N stratified draws from the
cell's point-independent bound distribution (``candidate_weights``: upper bounds of |η_s|² and ρ_m
over the cell, quantised to exact integer probabilities packed with the segment index), each
evaluated exactly and weighted 1/(N p): route A resamples the lobes among them by their proxy mass
(RIS, Rtot = Σ r_i replaces ΣH), route B sums their closed forms, ρ̂ = Σ ρ_i/(N p_i).  All three
are unbiased (tests/test_iridescent_layer_osl.py replays the stage in numpy); cost is O(N log n).

Shading points whose reach-grid cell is empty (no segment within 3σ of any point of the cell)
do one table lookup and return ``Base`` unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import const_array

from ..precompute.iridescence.scratch_set import cell_pairs, csr_from_pairs

SIGMA_UM = 60.0
RGB_WAVELENGTHS_UM = (0.630, 0.532, 0.465)   # = precompute.iridescence.RGB_WAVELENGTHS_UM
ROUTES = ("lobes", "lights")
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
    blo = np.floor((np.minimum(p0, p1) - reach_uv - lo) / cell).astype(np.int64)
    bhi = np.floor((np.maximum(p0, p1) + reach_uv - lo) / cell).astype(np.int64)
    blo = np.clip(blo, 0, [nx - 1, ny - 1])
    bhi = np.clip(bhi, 0, [nx - 1, ny - 1])
    sid, cx, cy = cell_pairs(blo, bhi)
    corner = lo + np.stack([cx, cy], 1) * cell
    dist = segment_box_distance(p0[sid], p1[sid], corner, corner + cell)
    keep = dist <= reach_uv * (1 + 1e-9) + 1e-12
    start, items = csr_from_pairs((cy * nx + cx)[keep], sid[keep], nx * ny)
    return ReachGrid(lo, cell, nx, ny, start, items)


# ----------------------------------------------------------------------------- spec + generator
@dataclass
class LayerSpec:
    """Inputs of ``generate``.  ``scratches``: a ``precompute.scratch_set.ScratchSet`` (or any
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
    base_blend: bool = True          # (1 − ρ)·Base (eq. 6) instead of Base
    wavelengths_um: tuple = RGB_WAVELENGTHS_UM
    name: str = "iridescent_layer"
    candidates: int = 4              # 0 = exhaustive, else RIS candidates per shading sample

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
    + ε/n (ρ term only with ``base_blend``), so 1/p ≤ n/ε."""
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

    p = 0.5 * (share(b_eta) + share(b_rho)) if spec.base_blend else share(b_eta)
    return (1.0 - UNIFORM_MIX) * p + UNIFORM_MIX / n


def quantize_cells(p, start, qbits: int) -> np.ndarray:
    """Integer quanta per item (≥ 1 each, exactly 2**qbits per non-empty cell, ∝ ``p`` otherwise), so the
    shader's probabilities are exact integers / 2**qbits (largest-remainder rounding per cell)."""
    Q = 1 << qbits
    n_cell = np.diff(start)
    if p.size == 0:
        return np.zeros(0, np.int64)
    if n_cell.max() > Q // 4:
        raise ValueError(f"scratches: {n_cell.max()} segments within reach of one grid cell (at most {Q // 4} "
                         "with this many segments); use fewer segments or a smaller sigma_um")
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


def generate(spec: LayerSpec) -> str:
    """OSL source of the specialised layer shader for ``spec`` (validated first)."""
    spec.validate()
    tab = shader_tables(spec)
    grid = tab["grid"]
    maxc = max(grid.max_per_cell, 1)
    nstore = int(spec.candidates) if spec.candidates > 0 else maxc
    lights = spec.lights if spec.route == "lights" else []
    spheres = [L for L in lights if isinstance(L, SphereLightSpec)]
    polys = [L for L in lights if isinstance(L, PolygonLightSpec)]
    lam = [float(x) for x in spec.wavelengths_um]
    src = [f"// Generated by osl/iridescent_layer.py -- do not edit (Velinov et al. 2018 iridescent scratches, "
           f"route {spec.route!r}, {len(spec.scratches.width_um)} segments).",
           '#include "stdcycles.h"',
           f"#define SIGMA {spec.sigma_um:.9g}",
           f"#define UV_SCALE {float(spec.scratches.uv_scale_um):.9g}",
           f"#define REACH {REACH_SIGMA * spec.sigma_um:.9g}",
           f"#define NS {NS}",
           f"#define QBITS {tab['qbits']}\n#define QMASK {(1 << tab['qbits']) - 1}",
           f"#define NCAND {int(spec.candidates)}",
           f"#define NSTORE {nstore}",
           f"#define KS {int(spec.samples)}",
           f"#define LOBE_ALPHA {LOBE_ALPHA:.9g}",
           f"#define GO_U {grid.origin[0]:.9g}\n#define GO_V {grid.origin[1]:.9g}\n#define CELL {grid.cell:.9g}",
           f"#define NX {grid.nx}\n#define NY {grid.ny}",
           f"#define NSPH {len(spheres)}\n#define NPOLY {len(polys)}",
           f"#define ROUTE_LIGHTS {1 if spec.route == 'lights' else 0}",
           f"#define BASE_BLEND {1 if spec.base_blend else 0}",
           _SI.replace("@SIF@", ", ".join(f"{c:.9g}" for c in SI_F)).replace("@SIG@", ", ".join(f"{c:.9g}" for c in SI_G))]
    if spec.route == "lights":
        src.append(_LIGHT_FUNCS)
    src.append(f"shader {spec.name}(\n"
               "    closure color Base = 0,\n"
               "    point UV = 0,  // connect a UV Map node (scratches live in UV space)\n"
               "    vector Tangent = 0,  // connect a Tangent node (UV map): +U in world space\n"
               "    output closure color BSDF = 0)\n{")
    body = [const_array("SEG", tab["segments"]),
            const_array("CSTART", grid.start, "int", per_line=16),
            const_array("CITEMS", tab["packed"], "int", per_line=16)]
    body.append(f"    float LAM[3] = {{{lam[0]:.9g}, {lam[1]:.9g}, {lam[2]:.9g}}};")
    if spheres:
        body.append(const_array("SPH", [v for L in spheres for v in (*L.center, L.radius, *L.radiance)]))
    if polys:
        nv = [len(L.vertices) for L in polys]
        body.append(const_array("PSTART", np.concatenate([[0], np.cumsum(nv)]), "int"))
        body.append(const_array("PVERT", np.asarray([v for L in polys for v in L.vertices], float).ravel()))
        body.append(const_array("PRAD", [v for L in polys for v in L.radiance]))
        body.append(const_array("PTWO", [int(L.two_sided) for L in polys], "int"))
    body.append(_BODY)
    src.append("\n".join(body))
    src.append("}")
    return "\n".join(src) + "\n"


# --- OSL snippets -------------------------------------------------------------------------------
_SI = r'''
#define A_C (M_PI * SIGMA * SIGMA)

// Si(x) (eq. 28): Taylor series for |x| <= 4, pi/2 - f cos x - g sin x above (fit, |err| < 2e-6).
float si_f(float x)
{
    float ax = abs(x);
    float r = 0.0;
    if (ax <= 4.0) {
        float term = ax, t2 = ax * ax;
        for (int n = 0; n < 14; n++) {
            r += term / (2 * n + 1);
            term *= -t2 / ((2 * n + 2) * (2 * n + 3));
        }
    } else {
        float SF[9] = {@SIF@};
        float SG[9] = {@SIG@};
        float y = 16.0 / (ax * ax);
        float pf = 0.0, pg = 0.0;
        for (int i = 8; i >= 0; i--) { pf = pf * y + SF[i]; pg = pg * y + SG[i]; }
        r = M_PI_2 - pf / ax * cos(ax) - pg / (ax * ax) * sin(ax);
    }
    return (x < 0.0) ? -r : r;
}

float sinc_f(float x) { return (abs(x) < 1e-4) ? 1.0 - x * x / 6.0 : sin(x) / x; }
'''

_LIGHT_FUNCS = r'''
// N(q) of eq. 27 without the sqrt(pi)/(sigma k) factor: (2 Si(x) - x sinc^2(x/2)) / kW, x = kW q.
float n_sinc2(float q, float kW)
{
    float x = kW * q;
    float s = sinc_f(0.5 * x);
    return (2.0 * si_f(x) - x * s * s) / kW;
}

// Angular factor (per channel) on the psi-interval [lo, hi] of the small circle xi1 = 0
// (xi2 = rho cos psi + o_b decreases with psi).
color interval_A(float lo, float hi, float rho, float o_b, float W, float LAM[])
{
    color A = 0;
    if (hi > lo) {
        float q_hi = rho * cos(lo) + o_b, q_lo = rho * cos(hi) + o_b;
        for (int c = 0; c < 3; c++) {
            float k = M_2PI / LAM[c];
            A[c] = sqrt(M_PI) / (SIGMA * k) * (n_sinc2(q_hi, k * W) - n_sinc2(q_lo, k * W));
        }
    }
    return A;
}
'''

_BODY = r'''
    BSDF = Base;
    float gx = (UV[0] - GO_U) / CELL, gy = (UV[1] - GO_V) / CELL;
    int c0 = 0, c1 = 0;
    if (gx >= 0.0 && gy >= 0.0 && gx < NX && gy < NY) {
        int cell = (int)floor(gy) * NX + (int)floor(gx);
        c0 = CSTART[cell];
        c1 = CSTART[cell + 1];
    }
    vector wo = normalize(I);
    normal n = N;
    float on = dot(wo, n);
    if (c1 > c0 && on > 1e-6 && !backfacing()) {
        // frame: t = UV tangent (Tangent input), b = n x t (= +V for a right-handed UV map)
        vector T = (length(Tangent) > 0.0) ? Tangent : dPdu;
        vector t = T - dot(T, n) * n;
        t = (length(t) > 1e-8) ? normalize(t) : normalize(cross(n, abs(n[0]) < 0.9 ? vector(1, 0, 0) : vector(0, 1, 0)));
        vector b = cross(n, t);
        float xu = UV[0] * UV_SCALE, xv = UV[1] * UV_SCALE;     // shading point in um
        float rho = 0.0;
        float wd = dot(wo, vector(12.9898, 78.233, 37.719));
#if ROUTE_LIGHTS
        color Ls = 0;
#else
        int cs[NSTORE];          // stored (segment, weight r) pairs: r = H_m / p_m (RIS) or H_m (all)
        float cr[NSTORE];
        int nc = 0;
        float Rtot = 0.0;
#endif
#if NCAND > 0
        // RIS candidates: NCAND stratified draws from the cell's quantised bound distribution, weight 1/(NCAND p)
        float uc = hashnoise(P, wd + 7.0);
        for (int ci = 0; ci < NCAND; ci++) {
            int k = (int)((ci + uc) / NCAND * (QMASK + 1));        // quantum index in [0, 2^QBITS)
            k = min(k, QMASK);
            int jl = c0, jh = c1 - 1;
            while (jl < jh) {                                      // first item whose range ends at >= k
                int mid = (jl + jh) / 2;
                if ((CITEMS[mid] & QMASK) >= k) jh = mid; else jl = mid + 1;
            }
            int e0 = (jl > c0) ? (CITEMS[jl - 1] & QMASK) : -1;
            float w = (QMASK + 1.0) / (NCAND * ((CITEMS[jl] & QMASK) - e0));
            int m = NS * (CITEMS[jl] >> QBITS);
#else
        for (int j = c0; j < c1; j++) {
            float w = 1.0;
            int m = NS * (CITEMS[j] >> QBITS);
#endif
            float tu = SEG[m], tv = SEG[m + 1];
            float sb = tv * xu - tu * xv + SEG[m + 3];          // s_b (um)
            float st1 = SEG[m + 2] - (tu * xu + tv * xv);       // s_t1, s_t2 (um): the segment relative to x
            float st2 = st1 + SEG[m + 4];
            float gap = max(0.0, max(st1, -st2));
            if (sb * sb + gap * gap > REACH * REACH) continue;  // beyond 3 sigma (as the numpy model)
            float e2 = exp(sb * sb * (-0.5 / (SIGMA * SIGMA)));
            float eta = A_C * e2 * e2 * (erf(st2 * (1.0 / SIGMA)) - erf(st1 * (1.0 / SIGMA)));               // eq. 10
#if BASE_BLEND
            rho += w * SEG[m + 10] * e2 * (erf(st2 * (M_SQRT1_2 / SIGMA)) - erf(st1 * (M_SQRT1_2 / SIGMA)));  // eq. 17
#endif
            if (eta <= 0.0) continue;
#if ROUTE_LIGHTS
            float W = SEG[m + 5];
            vector tm = tu * t + tv * b;
            vector bm = cross(n, tm);
            float ot = dot(wo, tm), ob = dot(wo, bm);
            color pref = (w * eta) * color(SEG[m + 11], SEG[m + 12], SEG[m + 13]);   // W^2 |D|^2 |eta_s|^2 / (A_C lambda^2)
            float c = -ot, rr = sqrt(max(0.0, 1.0 - c * c));
#if NSPH
            for (int l = 0; l < NSPH; l++) {
                vector p = point(SPH[7 * l], SPH[7 * l + 1], SPH[7 * l + 2]) - P;
                float d = length(p), r = SPH[7 * l + 3];
                if (d <= r) continue;
                p /= d;
                float sa = r / d, ca = sqrt(max(0.0, 1.0 - sa * sa));
                float p_t = dot(p, tm), p_b = dot(p, bm), p_n = dot(p, n);
                if (p_n <= -sa) continue;                    // sphere entirely below the horizon
                float amp = rr * hypot(p_b, p_n), rhs = ca - c * p_t;
                if (amp <= 1e-20 || rhs >= amp) continue;
                float beta = acos(clamp(rhs / amp, -1.0, 1.0));
                float phi0 = atan2(p_n, p_b);
                color Al = 0;
                for (int sh = -1; sh <= 1; sh++) {
                    float lo = max(phi0 - beta + sh * M_2PI, 0.0), hi = min(phi0 + beta + sh * M_2PI, M_PI);
                    Al += interval_A(lo, hi, rr, ob, W, LAM);
                }
                Ls += pref * max(Al, color(0)) * color(SPH[7 * l + 4], SPH[7 * l + 5], SPH[7 * l + 6]);
            }
#endif
#if NPOLY
            for (int l = 0; l < NPOLY; l++) {
                int v0 = PSTART[l], nv = PSTART[l + 1] - PSTART[l];
                vector U[16];
                for (int i = 0; i < nv; i++)
                    U[i] = normalize(point(PVERT[3 * (v0 + i)], PVERT[3 * (v0 + i) + 1], PVERT[3 * (v0 + i) + 2]) - P);
                // emitting side: polygon normal (right-hand rule) must face the shading point
                vector pn = cross(U[1] - U[0], U[2] - U[0]);
                vector V0 = point(PVERT[3 * v0], PVERT[3 * v0 + 1], PVERT[3 * v0 + 2]) - P;
                if (!PTWO[l] && dot(pn, V0) >= 0.0) continue;
                float orient = (dot(cross(U[0], U[1]), U[2]) >= 0.0) ? 1.0 : -1.0;
                float brk[34];
                int nb = 0;
                brk[0] = 0.0;
                nb = 1;
                for (int i = 0; i < nv; i++) {
                    vector Ua = U[i], Ub = U[(i + 1) % nv];
                    float dt = clamp(dot(Ua, Ub), -1.0, 1.0);
                    float gmax = acos(dt);
                    vector G = Ub - Ua * dt;
                    float Gn = length(G);
                    if (Gn <= 0.0) continue;
                    G /= Gn;
                    float a_ = dot(Ua, tm), b_ = dot(G, tm);       // eq. 38: a cos g + b sin g = c
                    float R = hypot(a_, b_);
                    if (R <= 1e-20 || abs(c / R) > 1.0) continue;
                    float g0 = atan2(b_, a_), dg = acos(clamp(c / R, -1.0, 1.0));
                    for (int sg = -1; sg <= 1; sg += 2) {
                        float g = mod(g0 + sg * dg, M_2PI);
                        if (g > M_2PI - 1e-6) g = 0.0;
                        if (g > gmax + 1e-6) continue;
                        vector wv = Ua * cos(g) + G * sin(g);
                        float psi = atan2(dot(wv, n), dot(wv, bm));
                        if (psi >= 0.0) { brk[nb] = psi; nb += 1; }
                    }
                }
                brk[nb] = M_PI;
                nb += 1;
                for (int i = 1; i < nb; i++) {                    // insertion sort (few crossings)
                    float x = brk[i];
                    int k = i - 1;
                    while (k >= 0 && brk[k] > x) { brk[k + 1] = brk[k]; k--; }
                    brk[k + 1] = x;
                }
                color Al = 0;
                for (int i = 0; i + 1 < nb; i++) {
                    float lo = brk[i], hi = brk[i + 1];
                    if (hi <= lo) continue;
                    float mid = 0.5 * (lo + hi);
                    vector wm = c * tm + rr * cos(mid) * bm + rr * sin(mid) * n;
                    int inside = 1;
                    for (int e = 0; e < nv; e++)
                        if (orient * dot(wm, cross(U[e], U[(e + 1) % nv])) < 0.0) inside = 0;
                    if (inside) Al += interval_A(lo, hi, rr, ob, W, LAM);
                }
                Ls += pref * max(Al, color(0)) * color(PRAD[3 * l], PRAD[3 * l + 1], PRAD[3 * l + 2]);
            }
#endif
#else
            // route A: Cauchy proxy h_c = amp_c / (1 + (xi2/s_c)^2), s_c = lambda_c/(pi W), mass H_c = eta Hbar_c
            float r = w * eta * SEG[m + 9];
            if (r > 0.0 && nc < NSTORE) {
                cs[nc] = m; cr[nc] = r;
                Rtot += r;
                nc++;
            }
#endif
        }
        rho = clamp(rho, 0.0, 1.0);
#if BASE_BLEND
        BSDF = (1.0 - rho) * Base;
#endif
#if ROUTE_LIGHTS
        BSDF += Ls * emission();
#else
        if (Rtot > 0.0) {
            // Rtot estimates (RIS) or equals (all) sum_m H_m; each lobe: (segment, channel) with probability
            // r_i Hbar_c / (Rtot Hbar_sum), xi2 from that channel's Cauchy, weight Rtot g(xi2) / (KS h(xi2))
            float u0 = hashnoise(P, dot(wo, vector(93.989, 67.345, 24.113)) + 3.0);
            for (int k = 0; k < KS; k++) {
                float y = (k + u0) / KS * Rtot;
                int ic = nc - 1;
                float acc = 0.0;
                for (int i = 0; i < nc; i++) {
                    if (y < acc + cr[i]) { ic = i; break; }
                    acc += cr[i];
                }
                int m = cs[ic];
                float yy = clamp((y - acc) / cr[ic], 0.0, 1.0) * SEG[m + 9];
                int ch = (yy < SEG[m + 6]) ? 0 : ((yy < SEG[m + 6] + SEG[m + 7]) ? 1 : 2);
                float W = SEG[m + 5];
                vector tm = SEG[m] * t + SEG[m + 1] * b;
                vector bm = cross(n, tm);
                float ot = dot(wo, tm), ob = dot(wo, bm);
                float rr = sqrt(max(0.0, 1.0 - ot * ot));
                // xi2 from the Cauchy proxy of channel ch; off the hemisphere's chord: weight 0
                float s = LAM[ch] / (M_PI * W);
                float u1 = hashnoise(P, dot(wo, vector(41.17, 19.31, 71.53)) + 29.0 * k + 5.0 + u0);
                float xi = s * tan(M_PI * (clamp(u1, 1e-6, 1.0 - 1e-6) - 0.5));
                if (xi <= ob - rr || xi >= ob + rr) continue;
                color g = 0;
                float hs = 0.0;
                for (int c = 0; c < 3; c++) {
                    float amp = SEG[m + 6 + c] * W / LAM[c];       // amp_c / eta
                    float sn = sinc_f(M_PI * W * xi / LAM[c]);
                    float q = xi * M_PI * W / LAM[c];
                    g[c] = amp * sn * sn;
                    hs += amp / (1.0 + q * q);
                }
                if (hs <= 0.0) continue;
                float wb = xi - ob;
                float wn = sqrt(max(0.0, 1.0 - ot * ot - wb * wb));
                vector hv = xi * bm + (wn + on) * n;
                if (length(hv) <= 1e-8) continue;
                BSDF += (Rtot / (KS * hs)) * g * microfacet("ggx", normalize(hv), tm, LOBE_ALPHA, LOBE_ALPHA, 0.0, 0);
            }
        }
#endif
    }
'''
