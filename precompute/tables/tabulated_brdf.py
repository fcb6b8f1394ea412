"""A tabulated BRDF rendered exactly by one narrow microfacet closure per sample, with light sampling.

Shared by every model that ends as a 4D table (bi-scale effective BRDFs of Wu et al. 2011, measured
MERL BRDFs of Matusik et al. 2003, measured NDFs of Dong et al. 2015).  Cycles has no tabulated
closure; the scratch material's *table lobes* (``precompute.scratch.lobe_table``) showed the way for
2D slices, this module does it for a full BRDF f(ωi, ωo):

**Table.**  ``TabulatedBRDF.table[i, o, c]`` is the standard (reciprocal) BRDF f in 1/sr.  ωi runs
over the cell-centred ``res x res`` hemi-octahedral grid (p = (x, y)/(|x|+|y|+z), s = px+py,
t = px-py; index = row*res + col, row along s; the same map as ``precompute.biscale.directions``).
ωo runs over

* ``iso=False`` (anisotropic, 4D): the same hemi-octahedral grid, in the surface frame (x = tangent);
* ``iso=True`` (isotropic, 3D): ``n_theta`` polar angles θo_k = (k + 1/2) π / (2 n_theta) at φo = 0;
  ωi is then expressed in the frame turned about n so that ωo has azimuth 0.

``eval`` is bilinear in ωi's (s, t) and bilinear (anisotropic) or linear in θo (isotropic), clamped
to the outermost nodes.

**View grids** (``view_a``, ``view_b``: anisotropic, not half).  The ωo axis is then its own tensor grid
in the *projected view angles* a = atan2(ox, oz), b = atan2(oy, oz) ∈ (-π/2, π/2) (every upper-hemisphere
direction once), with nodes at arbitrary increasing angles ``view_a`` (NA) x ``view_b`` (NB), node
o = ia·NB + ib, ωo(a, b) = normalize(tan a, tan b, 1); ``eval`` is bilinear in (a, b) between them.
The closure picks one ωi row per ωo node, so the view axis can be denser or warped without growing
the ωi axis: a shadowing / masking event of a tile extruded along y (every edge along y: grooves,
V-cavities) is a line a = const, so its view kinks sit exactly on nodes (``view_grid_nodes``) instead
of between them.  The shader finds the interval by a guide over the angle (``view_guide``) and a short
walk, once per shading point.

**Lobe-following view interpolation** (``view_shift``, view grids; the bi-scale bake's default).  A highlight moves
with the view (the mirror direction of a tile's wall turns as fast as the view does), so blending the rows of the
four bracketing nodes spreads it over four places and its peak sags between them (groove tile, θo/φo 78/200, the lamp
on a GGX α 0.2 wall: the lamp term -3.7 % of eq. 8 with nodes 3° x 7.7° apart, -1.5 % with a node at the view).
Instead each tap's row is moved, as a mass per unit (s, t) area, by Δ_o = c(ωo) - c_o: the bilinear interpolation
of the rows' anchors c_o (``view_centroids``: the mean (s, t) weighted by (f cos θ J)^p, p = ``view_anchor``: 1, the
mass centroid, by default; 2 in bi-scale bakes, leaning to the row's peak; a broad part that stays put is moved by shifts that sum to zero, a second-order error)
at the view, minus node o's own (``view_shifts``): f(ωi, ωo) = Σ_o w_o g_o(st - Δ_o) / (cos θi J(st)), g_o = f_o cos θ J, zero where st - Δ_o leaves
the square.  At the nodes it is the table; between them a lobe that moves rigidly is carried along instead of
blended (displacement interpolation to first order).  The closure only moves its drawn target by Δ_o: the weight
f_o cos θ / p_o of the drawn point is unchanged (a translation in (s, t) keeps the mass and the density per unit
area), so sampling, NEE and MIS stay exact for the shifted BRDF (``sample``, ``pdf``, ``sample_alias``; the graph
reads Δ_o from a centroid image "C" with one Linear and one Closest lookup; OSL: ``CEN``).  With a floor
(``floor_parts``) the closure moves the residual only (its own centroids); the floors stay where they are.
Measured (numpy, lamp term vs eq. 8, the bake grid's bracketing nodes): groove at 78/200 -3.7 -> -1.6 % (mass
centroid, p = 1); a pyramid of Principled BSDFs at 55/300 (a metal floor's highlight under broad walls) +5.0 % blended,
+4.9 % with the mass centroid, +1.8 % with p = 2 (a node at the view: +1.2 %).

**Half-vector tables** (``half=True``, for sharp microfacet BRDFs such as measured NDFs).  The "ωi"
axis is then the half vector h = normalize(ωi + ωo) on the same hemi-octahedral grid zoomed to
(s, t) ∈ [-Z, Z]² (Z = ``extent`` <= 1: the diamond |px| + |py| <= Z around the normal), and
ωi = 2 (ωo·h) h - ωo.  A microfacet lobe sits on the same h cells at every view, so the cells can be
made as fine as the NDF needs (the zoom) and interpolating between ωo nodes does not smear it; f is
0 for h outside the diamond.  Densities convert by dωi = 4 |ωo·h| dωh.  A half table stores
ρ = f cos θi cos θo J(h) (for a microfacet BRDF F D G2 J / 4: smooth in ωo, where f itself carries the
fast 1/cos θo; J = dωh/(ds dt) makes it a density per unit (s, t) area) and f = ρ / (cos θi cos θo J)
with the actual cosines and J.  Interpolating f instead would gain ~8 % energy between ωo nodes 7°
apart at 40°, and interpolating per steradian would gain 3 % on a lobe narrower than a cell at the
normal, where J has its cusp (J ≈ (1 + 3 (|px| + |py|)) / 2); per (s, t) area, the bilinear interpolant
keeps each cell's mass exactly.

**Sampling (the closure).**  For a view ωo (towards the viewer, z > 0):

1. one ωo node o is picked with probability equal to its interpolation weight (an unbiased estimate
   of the interpolation in ωo);
2. a ωi cell k is drawn from row o's CDF (probability P_k; the inverse CDF found from a guide table,
   ``guide_table`` / ``guide_pick``: O(1) expected reads), and a target point is jittered uniformly
   in (s, t) inside the cell: ωi = v/|v|, v = (px, py, 1-|px|-|py|) (``hemi_oct_decode``);
3. the solid-angle density of the target is  p(ωi) = P_k / (h² J(s, t)),  h = 2/res the cell side,
   J = dω/(ds dt) = 1 / (2 |v|³) (``jacobian``);
4. the shader emits ONE closure  W · microfacet("ggx", m, T, α, α)  with m = normalize(ωo + ωi) (the
   micro-normal that mirrors ωo into the target) and  W = f(ωi, ωo_o) cos θi / (p(ωi) A),  A the
   closure's albedo (``lobe_albedo``: Smith G of the narrow lobe, ≈ 1).

As α → 0 the closure is a mirror into ωi, so the expectation of the rendered radiance is
∫ eval(ωi, ωo) L(ωi) cos θi dωi, blurred only by the narrow lobe (α defaults to 1/16 of a cell).
The closure is an ordinary Cycles microfacet lobe: next-event estimation and MIS evaluate it at light
directions, which keeps that estimate consistent (Cycles' own eval/pdf), so lamps and environment
light are sampled as for any glossy material.  Per-sample weights are f cos / p: the proposal P_k is
∝ (cell average of the bilinear interpolant of row o's channel mean) x (∫_cell cos θ dω), mixed with
a defensive fraction ``DEFENSIVE`` ∝ solid angle, so weights stay near the directional albedo.

**The smooth floor** (``floor_split``, on by default).  One narrow lobe per sample sees a small lamp only when
the drawn bin's lobe covers it: for the smooth part of a BRDF (a MERL material's diffuse term) a point lamp
then turns into fireflies (a Lambertian MERL file under the startup scene's point lamp: 93-112 % relative noise
of the frame mean at 8 spp).  So f = kd/π + r with the largest constant kd (RGB) that keeps r >= 0 at every node
(bilinear interpolation then keeps r >= 0 everywhere): kd renders as a Diffuse closure (next-event estimation
sees the lamp at every sample), and the closure above samples and weights r only (``F``, ``cdf`` and the
weights W are r's; what renders is kd/π + r).  Measured (``tests/tables/test_tabulated_floor``): the Lambertian
file's noise drops to 0.2 %, that of a Diffuse BSDF; the floor takes 100 % of a Lambertian, 18-19 % of a
GGX (α 0.2) + Lambert MERL file (its GGX tails included), 0 of a bi-scale pyramid of diffuse facets (f = 0
where ωi and ωo see disjoint facets).

**The glossy floor** (``glossy_floor_split``, ``floor_parts``; ``floor=True`` = "auto").  A MERL metal, plastic or
paint has a glossy lobe, and under a point lamp the residual of the Diffuse floor (the whole lobe) was fireflies
(GGX 0.2 + Lambert MERL file, 8 spp: 467 % pixel error on SVM).  So f = kd/π + ks g + r, g Cycles' own GGX or
Beckmann closure (``glossy_eval``: F = 1, height-correlated Smith G2, single scattering, the twin of
``precompute.cycles.ggx.bsdf_eval``) of α_g, rendered as a Glossy closure that light sampling evaluates at every
sample; r >= 0 at every node (``glossy_nodes``: g in the table's layout).  (kd, ks) per channel maximise the floors'
albedo (a 2-variable linear programme per (dist, α)), (dist, α_g) by a log grid and a golden-section search
(both tails are needed: a GGX floor cannot sit under a Beckmann lobe); isotropic tables take ks per θo node
(``ks_view``, linear in θo), because one bad row (a MERL file's grazing bins) would cap a shared ks (0.43 vs 0.8).
"auto" uses it when it takes >= ``GLOSSY_SHARE_MIN`` (10 %) of the table's hemispherical albedo.  **Floor points**
(``floor_points``, a MERL import's ``info["floor_points"]``): r >= 0 is also required at the file's own θh bins near
the peak (0.01-0.1° apart, far finer than a cell), so the floor may be narrower than a cell (``glossy_floor_alpha_min``
then 0.0019): a GGX α 0.02 file at 48² (1.9° cells) gets a GGX α 0.02 floor that takes 96 % of it, and the table only
a small residual (Session 10; the floor no narrower than a cell left it 27 % off under a striped world); the horizon
cells then do not bind ks (``_horizon_cells``, their clamp bounded by ``_bound_clamp``).  Measured
(``bench/out/tabulated_floor.md``): GGX + Lambert MERL 8 spp pixel error 467 % -> 8.6 % on SVM (analytic
material 3.8 %), 210 % -> 46 % on OSL; a Beckmann + Lambert file 1234 % -> 7.8 % (SVM), 834 % -> 17 % (OSL).

``closure_tables`` makes the arrays compiled into ``osl/tabulated_brdf.osl``; ``sample`` is the
numpy twin of the shader (same arrays, same arithmetic); ``pdf`` the density of step 3 marginalised
over the ωo node (the chi-square oracle).  Units: directions are unit vectors in the surface frame
(z = normal), solid angles in steradians, BRDF values in 1/sr.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .. import validation
from ..cycles import beckmann as _bk
from .alias import alias_pmf, alias_tables
from .prefilter import deconvolve_cells

__all__ = ["TabulatedBRDF", "ClosureTables", "closure_tables", "sample", "pdf", "hemi_oct_encode",
           "hemi_oct_decode", "direction_grid", "jacobian", "lobe_albedo", "default_alpha", "theta_nodes",
           "MAX_RES", "MAX_FLOATS", "MAX_TABLE_FLOATS", "DEFENSIVE", "reflect", "cell_points", "guide_table", "guide_pick",
           "view_angles", "view_directions", "view_taps", "view_guide", "view_centroids", "MAX_VIEW_ANCHOR", "view_shifts", "view_grid_nodes", "VIEW_GUIDE_BINS",
           "lambert_nodes", "floor_split", "closure_albedo",
           "floor_parts", "glossy_floor_split", "FloorParts", "floor_eval", "floor_mode", "glossy_albedo", "glossy_nodes",
           "glossy_eval", "FLOOR_DISTS", "floor_ks",
           "GLOSSY_SHARE_MIN", "FLOOR_MODES", "glossy_floor_alpha_min", "floor_albedo", "floor_points", "CLAMP_MAX"]

#: Largest ωi grid side.
MAX_RES = 48
#: Largest table compiled into a shader (floats in F): keeps the generated source below ~10 MB.  Larger tables
#: render through the node graph on every path (``node_groups.tabulated_svm``: images; Cycles compiles its
#: builtin nodes for OSL too), up to ``MAX_TABLE_FLOATS``.
MAX_FLOATS = 400_000
#: Largest table of any closure (floats in F; 16 MB as float32): the node graph's images bound it too
#: (``tabulated_svm.fits``).
MAX_TABLE_FLOATS = 4_000_000
#: Fraction of the proposal spread over all cells ∝ solid angle (bounds the weights).
DEFENSIVE = 0.02
#: Bins of the view-grid guide over (-π/2, π/2) (``view_guide``).
VIEW_GUIDE_BINS = 64
#: Largest anchor power of the lobe-following view interpolation (``TabulatedBRDF.view_anchor``, ``view_centroids``).
MAX_VIEW_ANCHOR = 16.0


# ----------------------------------------------------------------------------- the hemi-octahedral map
def hemi_oct_encode(w) -> np.ndarray:
    """(s, t) in [-1, 1]² of unit directions w (..., 3), z >= 0 (z clamped to 0 below)."""
    w = np.asarray(w, np.float64)
    z = np.maximum(w[..., 2], 0.0)
    d = np.abs(w[..., 0]) + np.abs(w[..., 1]) + z
    d = np.where(d > 0, d, 1.0)
    px, py = w[..., 0] / d, w[..., 1] / d
    return np.stack([px + py, px - py], -1)


def hemi_oct_decode(st) -> np.ndarray:
    """Unit directions (..., 3) of (s, t) in [-1, 1]²."""
    st = np.asarray(st, np.float64)
    px, py = 0.5 * (st[..., 0] + st[..., 1]), 0.5 * (st[..., 0] - st[..., 1])
    v = np.stack([px, py, 1.0 - np.abs(px) - np.abs(py)], -1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def direction_grid(res: int) -> np.ndarray:
    """Cell-centred res x res hemi-octahedral grid (res², 3), index = row*res + col (row along s)."""
    c = -1.0 + (2.0 * np.arange(res) + 1.0) / res
    S, T = np.meshgrid(c, c, indexing="ij")
    return hemi_oct_decode(np.stack([S.ravel(), T.ravel()], -1))


def jacobian(st) -> np.ndarray:
    """dω/(ds dt) of the hemi-octahedral map at (s, t): 1 / (2 |v|³), v = (px, py, 1-|px|-|py|)
    (a face element dA = √3 dpx dpy subtends (n̂·v̂) dA/|v|² = dpx dpy/|v|³; |∂p/∂(s,t)| = 1/2)."""
    st = np.asarray(st, np.float64)
    px, py = 0.5 * (st[..., 0] + st[..., 1]), 0.5 * (st[..., 0] - st[..., 1])
    z = 1.0 - np.abs(px) - np.abs(py)
    return 0.5 / np.sqrt(px * px + py * py + z * z) ** 3


def theta_nodes(n_theta: int) -> np.ndarray:
    """Polar angles (radians) of the isotropic table's ωo nodes: (k + 1/2) π / (2 n_theta)."""
    return (np.arange(n_theta) + 0.5) * (0.5 * np.pi / n_theta)


def _lin_taps(x, n):
    """Two clamped linear taps (i0, i0+1) and the weight of i0+1 of continuous index x on n nodes."""
    x = np.clip(x, 0.0, n - 1.0)
    i0 = np.minimum(np.floor(x).astype(int), max(n - 2, 0))
    return i0, np.minimum(i0 + 1, n - 1), x - i0


def _bilinear(st, res):
    """(indices (N, 4), weights (N, 4)) of the bilinear interpolation at (s, t) on the cell centres."""
    xr = (st[:, 0] + 1.0) * 0.5 * res - 0.5
    xc = (st[:, 1] + 1.0) * 0.5 * res - 0.5
    r0, r1, fr = _lin_taps(xr, res)
    c0, c1, fc = _lin_taps(xc, res)
    idx = np.stack([r0 * res + c0, r0 * res + c1, r1 * res + c0, r1 * res + c1], 1)
    w = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], 1)
    return idx, w


def view_angles(wo) -> np.ndarray:
    """Projected view angles (a, b) = (atan2(ox, oz), atan2(oy, oz)) (..., 2), radians, of directions (..., 3)
    with z >= 0 (the coordinates of a view grid, module docstring)."""
    wo = np.asarray(wo, np.float64)
    z = np.maximum(wo[..., 2], 0.0)
    return np.stack([np.arctan2(wo[..., 0], z), np.arctan2(wo[..., 1], z)], -1)


def view_directions(view_a, view_b) -> np.ndarray:
    """Unit ωo (NA NB, 3) of the view grid nodes, o = ia NB + ib: normalize(tan a, tan b, 1)."""
    A, Bb = np.meshgrid(np.asarray(view_a, np.float64), np.asarray(view_b, np.float64), indexing="ij")
    v = np.stack([np.tan(A), np.tan(Bb), np.ones_like(A)], -1).reshape(-1, 3)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _node_taps(x, nodes):
    """Clamped linear taps on increasing ``nodes``: (i0 in [0, n-2], weight of i0+1 in [0, 1])."""
    nodes = np.asarray(nodes, np.float64)
    i0 = np.clip(np.searchsorted(nodes, x, side="right") - 1, 0, len(nodes) - 2)
    f = np.clip((x - nodes[i0]) / (nodes[i0 + 1] - nodes[i0]), 0.0, 1.0)
    return i0, f


def view_taps(wo, view_a, view_b):
    """Bilinear taps of views ``wo`` (N, 3) on the view grid: (node indices (N, 4), weights (N, 4)) in the
    shader's order (ia, ib), (ia, ib+1), (ia+1, ib), (ia+1, ib+1); clamped to the outermost nodes."""
    ab = view_angles(wo)
    ia, fa = _node_taps(ab[:, 0], view_a)
    ib, fb = _node_taps(ab[:, 1], view_b)
    nb = len(view_b)
    o = ia * nb + ib
    idx = np.stack([o, o + 1, o + nb, o + nb + 1], 1)
    w = np.stack([(1 - fa) * (1 - fb), (1 - fa) * fb, fa * (1 - fb), fa * fb], 1)
    return idx, w


def view_centroids(table, res: int, power: float = 1.0) -> np.ndarray:
    """Anchor (s, t) (n_o, 2) of each ωo node's row of ``table`` (res², n_o, 3 or 1) for the lobe-following view
    interpolation (``TabulatedBRDF.view_shift``, module docstring): the mean of the cell centres weighted by g_k^p,
    g_k = f̄_k cos θ_k J(s_k, t_k) the row's mass per unit (s, t) area (f̄ the channel mean; J ``jacobian``),
    p = ``power`` in [1, ``MAX_VIEW_ANCHOR``] (``TabulatedBRDF.view_anchor``; 1: the mass centroid); (0, 0) for an
    empty row.

    Why a power: the taps' shifts sum to zero, Σ_o w_o Δ_o = 0, so a part of the rows that stays put (a tile's diffuse
    facets, shaped by visibility) is moved by ±Δ_o symmetrically and its error is second order in Δ, whereas a sharp
    highlight that moves with the view needs Δ_o equal to its own motion.  The mass centroid (p = 1) mixes both and
    moves the highlight by the wrong amount.  Measured (numpy, the bench lamp over the view's footprint, table on the
    bake grid's bracketing nodes vs eq. 8 from the same 10,000 facets; p = 1 / 2 / 4, a node at the view):
    Principled pyramid (metal floor α 0.16, dielectric walls) 55/300 +4.9 / +1.8 / +1.1 %, node +1.2 %; 45/90 +0.8 /
    +0.4 / +0.2 %; 60/250 +0.4 / -0.5 / -0.8 %; groove 78/200 -1.6 / -1.5 / -1.6 %, node -1.5 %; the audit's bump (many
    sharp facet lobes of an 8 x 8 faceted cap) 55/300 +3.4 / +3.6 / +4.7 %, node +2.0 % (a peak anchor jumps between
    lobes there).  p = 2 (the bi-scale bake's ``table.VIEW_ANCHOR``) takes most of the pyramid's gain and costs the
    bump 0.2 %.  The cost of a larger p: a broad part moved by a larger Δ loses what crosses the square's edge (the
    closure drops such targets; eval and pdf agree): on the coarse synthetic table of ``tests/tables/test_tabulated_brdf``
    (res 10, a constant part up to the horizon) the sampled mass at one view falls 0.7 % -> 1.5 % with p = 2, so p = 1
    stays the default of other tables."""
    p = validation.check_range("power", power, 1.0, MAX_VIEW_ANCHOR)
    st = hemi_oct_encode(direction_grid(int(res)))
    g = np.asarray(table, np.float64).mean(-1) * (hemi_oct_decode(st)[:, 2] * jacobian(st))[:, None]   # (D, n_o)
    g = np.maximum(g, 0.0)
    gmax = g.max(0, keepdims=True)
    g = (g / np.where(gmax > 0, gmax, 1.0)) ** float(p)             # normalised per row: no under- / overflow
    tot = g.sum(0)
    return np.where(tot[:, None] > 0, (g.T @ st) / np.where(tot > 0, tot, 1.0)[:, None], 0.0)


def view_shifts(centroids, io, wto) -> np.ndarray:
    """(s, t) offsets (N, k, 2) of the taps ``io`` (N, k) with weights ``wto`` (N, k) of the lobe-following view
    interpolation: Δ_o = Σ_o' w_o' c_o' - c_o, the interpolated centroid minus node o's (``view_centroids``)."""
    C = np.asarray(centroids, np.float64)
    c = np.einsum("nk,nkd->nd", wto, C[io])
    return c[:, None, :] - C[io]


def _shifted_eval(table, res: int, centroids, wi, io, wto) -> np.ndarray:
    """f(ωi, ωo) (N, 3) of the lobe-following view interpolation: Σ_o w_o g_o(st - Δ_o) / (cos θi J(st)), g_o = f_o cos J
    the row's bilinear mass per (s, t) area at the point shifted back, 0 where that point leaves the square."""
    st = hemi_oct_encode(wi)
    d = view_shifts(centroids, io, wto)
    den = np.maximum(wi[:, 2], 1e-12) * jacobian(st)
    out = np.zeros((len(wi), table.shape[2]))
    for k in range(io.shape[1]):
        s2 = st - d[:, k]
        inside = np.all(np.abs(s2) <= 1.0, axis=1)
        s2 = np.clip(s2, -1.0, 1.0)
        ii, wti = _bilinear(s2, res)
        fo = np.einsum("na,nac->nc", wti, table[ii, io[:, k:k + 1]])
        g = fo * (hemi_oct_decode(s2)[:, 2] * jacobian(s2) / den)[:, None]
        out += np.where(inside[:, None], wto[:, k:k + 1] * g, 0.0)
    return out


def view_guide(nodes, bins: int = VIEW_GUIDE_BINS) -> np.ndarray:
    """Guide of the shader's interval search on ``nodes`` (increasing, radians): for bin j of (-π/2, π/2)
    the interval i in [0, n-2] holding the bin's lower edge (n-2 / 0 beyond the nodes).  The shader starts
    there and steps up while x >= nodes[i+1] (i < n-2): the interval ``view_taps`` finds."""
    edges = -0.5 * np.pi + np.arange(bins) * (np.pi / bins) - 1e-6   # float32 rounding cannot skip an interval
    nodes = np.asarray(nodes, np.float64)
    return np.clip(np.searchsorted(nodes, edges, side="right") - 1, 0, len(nodes) - 2).astype(np.int32)


def _grazing_mass(x, grazing):
    """Cumulative node density M(x) = ∫_0^x ρ (odd in x) of ``view_grid_nodes``: ρ = 1 for |a| < a_g, ``ratio``
    beyond (``grazing`` = (a_g radians, ratio); None: ρ = 1)."""
    x = np.asarray(x, np.float64)
    if grazing is None:
        return x
    ag, r = float(grazing[0]), float(grazing[1])
    ax = np.abs(x)
    return np.sign(x) * np.where(ax < ag, ax, ag + r * (ax - ag))


def _grazing_mass_inv(m, grazing):
    m = np.asarray(m, np.float64)
    if grazing is None:
        return m
    ag, r = float(grazing[0]), float(grazing[1])
    am = np.abs(m)
    return np.sign(m) * np.where(am < ag, am, ag + (am - ag) / r)


def _symmetric_largest_remainder(share, mids, free: int) -> np.ndarray:
    """Integer node counts per gap summing to ``free`` (largest remainder of ``share``); ties (remainders within
    1e-7) go first to the gap nearest the middle (|mid|), and mirror-image gaps (equal remainder and |mid|) are
    served together or not at all, so a symmetric set of gaps gets a symmetric allocation whenever one exists
    (an odd leftover with no middle gap has none: then the nearer-to-middle, lower-index gap takes it)."""
    k = np.floor(share + 1e-9).astype(int)
    rem = share - k
    am = np.abs(np.asarray(mids, np.float64))
    tie = 1e-7 * max(1.0, float(np.max(share)) if len(share) else 1.0)
    rem = np.where(np.abs(rem - np.round(rem, 6)) < tie, np.round(rem, 6), rem)   # equal shares compare equal
    am = np.round(am, 6)
    left0 = int(free - k.sum())
    order = np.lexsort((np.arange(len(share)), am, -rem))
    groups, seen = [], np.zeros(len(share), bool)
    for i in order:                      # tie groups (mirror-image gaps) in order of remainder, middle first
        if not seen[i]:
            grp = np.flatnonzero((np.abs(rem - rem[i]) < tie) & (am == am[i]) & ~seen)
            seen[grp] = True
            groups.append(grp)

    def greedy(parity: bool):
        kk, left = k.copy(), left0
        if parity:                       # symmetric gaps: the odd node goes to the one unpaired (middle) gap
            singles = [g for g in groups if len(g) == 1]
            if left % 2 == 1 and singles:
                kk[singles[0]] += 1
                left -= 1
        for g in groups:
            if parity and len(g) == 1:
                continue
            if 0 < len(g) <= left:
                kk[g] += 1
                left -= len(g)
        return kk, left

    kk, left = greedy(False)
    if left:
        kk, left = greedy(True)
    for i in order:                      # no symmetric completion exists: the first in order takes the rest
        if left <= 0:
            break
        if kk[i] == k[i]:
            kk[i] += 1
            left -= 1
    return kk


def view_grid_nodes(n: int, events=(), limit: float = np.radians(85.0), grazing=None) -> np.ndarray:
    """``n`` increasing view angles (radians) over [-limit, limit] with every event angle in ``events``
    (|e| < limit) on a node: the events and the two ends are fixed, the remaining nodes go to the gaps in
    proportion to their node mass (largest remainder; ties to the gaps nearest a = 0, mirror-image gaps
    together: symmetric events give symmetric nodes), spaced evenly in that mass inside each gap.  The mass is
    the angle itself (even spacing), or with ``grazing`` = (a_g, ratio) (radians, >= 1) ``ratio`` x denser
    beyond |a| = a_g (``GRAZING``: the bright grazing side of a glossy tile's wall needs nodes ~4° apart over
    65-85°, ``bench/out/biscale_truth_svm_views.md``).  ``n`` must hold the ends and the events (ValueError
    otherwise); events closer than 1e-3 rad merge."""
    validation.check_range("n", n, 2, 256)
    if grazing is not None:
        validation.check_range("grazing angle", grazing[0], 0.0, float(limit))
        validation.check_range("grazing ratio", grazing[1], 1.0, 16.0)
    ev = np.sort(np.asarray(events, np.float64).ravel()) if len(events) else np.zeros(0)
    ev = ev[np.abs(ev) < limit - 1e-3]
    fixed = [-limit]
    for e in ev:
        if e - fixed[-1] > 1e-3:
            fixed.append(float(e))
    if limit - fixed[-1] <= 1e-3:
        fixed.pop()
    fixed.append(limit)
    fixed = np.array(fixed)
    if len(fixed) > n:
        raise ValueError(f"n: {len(fixed)} view nodes are fixed (ends and events), got n = {n}")
    mfix = _grazing_mass(fixed, grazing)
    gaps = np.diff(mfix)
    free = int(n) - len(fixed)
    k = _symmetric_largest_remainder(gaps / gaps.sum() * free, 0.5 * (fixed[:-1] + fixed[1:]), free)
    out = [fixed[:1]]
    for g0, g1, m, a1 in zip(mfix[:-1], mfix[1:], k, fixed[1:]):
        inner = _grazing_mass_inv(g0 + (g1 - g0) * np.arange(1, m + 1) / (m + 1), grazing)
        out.append(np.concatenate([inner, [a1]]))
    return np.concatenate(out)


def _check_view_nodes(name, v):
    v = np.asarray(validation.finite(name, v), np.float64).ravel()
    if len(v) < 2 or len(v) > 256 or np.any(np.diff(v) <= 1e-6) or np.abs(v).max() >= 0.5 * np.pi:
        raise ValueError(f"{name}: expected 2..256 increasing angles in (-π/2, π/2) (radians), got {len(v)} values "
                         f"in [{v.min() if len(v) else 0:.4g}, {v.max() if len(v) else 0:.4g}]")
    return v


def _unit_rows(name, w):
    w = np.atleast_2d(validation.finite(name, w))
    if w.ndim != 2 or w.shape[1] != 3:
        raise ValueError(f"{name}: expected unit vectors of shape (N, 3), got {w.shape}")
    n = np.linalg.norm(w, axis=1, keepdims=True)
    return w / np.where(n > 0, n, 1.0)


# ----------------------------------------------------------------------------- the table

def hemisphere_midpoints(n_theta: int = 64, n_phi: int = 128):
    """Directions (n_theta * n_phi, 3) and their solid angle dω (sr) of the midpoint rule in (cos θ, φ) over
    the upper hemisphere: ∫ g(ω) cos θ dω ≈ Σ g(ω_j) cos θ_j dω (the white-furnace quadrature)."""
    mu = (np.arange(n_theta) + 0.5) / n_theta
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    M, PH = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    wi = np.stack([s * np.cos(PH), s * np.sin(PH), M], -1).reshape(-1, 3)
    return wi, (1.0 / n_theta) * (2 * np.pi / n_phi)


def cell_points(res: int, sub: int, extent: float = 1.0):
    """(s, t) midpoints (res² sub², 2) of the sub x sub sub-cells of each res x res cell of [-extent, extent]²,
    cell-major (cell k = row*res + col, then its sub-cells), and a sub-cell's (s, t) area."""
    h = 2.0 * extent / res
    c = -extent + (np.arange(res * sub) + 0.5) * (h / sub)
    S, T = np.meshgrid(c, c, indexing="ij")
    st = np.stack([S, T], -1).reshape(res, sub, res, sub, 2).transpose(0, 2, 1, 3, 4).reshape(-1, 2)
    return st, (h / sub) ** 2


def reflect(wo, h):
    """ωi = 2 (ωo·h) h - ωo (N, 3) and a mask of ωi above the horizon (z > 0)."""
    wi = 2.0 * np.sum(wo * h, -1, keepdims=True) * h - wo
    return wi, wi[..., 2] > 0


@dataclass
class TabulatedBRDF:
    """A tabulated standard BRDF f(ωi, ωo) (1/sr, RGB); see the module docstring for the grids.

    ``table`` (res², n_o, 3): n_o = res² (anisotropic) or ``n_theta`` (isotropic).  ``half``: the first
    axis is the half vector on the grid zoomed to (s, t) ∈ [-extent, extent]² (module docstring).
    ``view_a`` / ``view_b`` (radians): a view grid in the projected view angles (anisotropic, not half;
    n_o = NA NB, module docstring); ``view_shift`` (view grids only): interpolate between its nodes by following the
    lobe (each tap's row moved by the interpolated centroid minus its own, module docstring) instead of blending;
    ``view_anchor`` (p in [1, ``MAX_VIEW_ANCHOR``]): that centroid weights the row's mass by g^p (``view_centroids``)."""
    table: np.ndarray
    res: int
    iso: bool = False
    info: dict = field(default_factory=dict)
    half: bool = False
    extent: float = 1.0
    view_a: np.ndarray | None = None
    view_b: np.ndarray | None = None
    view_shift: bool = False
    view_anchor: float = 1.0

    def __post_init__(self):
        validation.check_range("res", self.res, 2, MAX_RES)
        self.res = int(self.res)
        self.half = bool(self.half)
        self.extent = float(validation.check_range("extent", self.extent, 1e-3, 1.0)) if self.half else 1.0
        t = np.asarray(self.table, np.float64)
        n_i = self.res * self.res
        if (self.view_a is None) != (self.view_b is None):
            raise ValueError("view_a, view_b: give both angle arrays of a view grid, or neither")
        n_o = n_i
        if self.view_a is not None:
            if self.iso or self.half:
                raise ValueError("view_a: a view grid needs an anisotropic, non-half table (iso=False, half=False)")
            self.view_a = _check_view_nodes("view_a", self.view_a)
            self.view_b = _check_view_nodes("view_b", self.view_b)
            n_o = len(self.view_a) * len(self.view_b)
        if not isinstance(self.view_shift, (bool, np.bool_)):
            raise ValueError(f"view_shift: must be True or False, got {self.view_shift!r}")
        self.view_shift = bool(self.view_shift)
        if self.view_shift and self.view_a is None:
            raise ValueError("view_shift: the lobe-following view interpolation needs a view grid (view_a, view_b)")
        self.view_anchor = float(validation.check_range("view_anchor", self.view_anchor, 1.0, MAX_VIEW_ANCHOR))
        if t.ndim != 3 or t.shape[0] != n_i or t.shape[2] != 3 or (not self.iso and t.shape[1] != n_o) \
                or (self.iso and not 2 <= t.shape[1] <= 256):
            want = "(res², n_theta in [2, 256], 3)" if self.iso else \
                ("(res², len(view_a) len(view_b), 3)" if self.view_a is not None else "(res², res², 3)")
            raise ValueError(f"table: expected shape {want} with res = {self.res}, got {t.shape}")
        if not np.all(np.isfinite(t)) or t.min() < 0:
            raise ValueError("table: BRDF values must be finite and >= 0")
        self.table = t

    @property
    def n_o(self) -> int:
        return self.table.shape[1]

    def cache_key(self):
        key = {"table": self.table.astype(np.float32), "res": self.res, "iso": bool(self.iso),
               "half": self.half, "extent": self.extent}
        if self.view_a is not None:
            key.update(view_a=self.view_a, view_b=self.view_b)
        if self.view_shift:
            key.update(view_shift=True)
            if self.view_anchor != 1.0:
                key.update(view_anchor=self.view_anchor)
        return key

    # -- frames
    def _local(self, wi, wo):
        """ωi in the table's frame and the ωo interpolation taps (N, k) with weights (N, k)."""
        if not self.iso:
            if self.view_a is not None:
                io, wto = view_taps(wo, self.view_a, self.view_b)
            else:
                io, wto = _bilinear(hemi_oct_encode(wo), self.res)
            return wi, io, wto
        phi = np.arctan2(wo[:, 1], wo[:, 0])
        c, s = np.cos(phi), np.sin(phi)
        wl = np.stack([c * wi[:, 0] + s * wi[:, 1], -s * wi[:, 0] + c * wi[:, 1], wi[:, 2]], -1)
        th = np.arccos(np.clip(wo[:, 2], -1, 1))
        x = th / (0.5 * np.pi / self.n_o) - 0.5
        i0, i1, f = _lin_taps(x, self.n_o)
        return wl, np.stack([i0, i1], 1), np.stack([1 - f, f], 1)

    def grid_coords(self, wi, wo):
        """(s, t) of the table's first axis normalised to [-1, 1]² (N, 2), and a mask of the pairs inside
        the grid: ωi's own coordinates, or (half tables) those of h = normalize(ωi + ωo) over ``extent``.
        Frame-invariant about n, so it can be called in the surface or the table's frame."""
        if not self.half:
            return hemi_oct_encode(wi), np.ones(len(wi), bool)
        h = wi + wo
        n = np.linalg.norm(h, axis=1, keepdims=True)
        st = hemi_oct_encode(h / np.where(n > 0, n, 1.0)) / self.extent
        return st, np.all(np.abs(st) <= 1.0, axis=1) & (n[:, 0] > 0)

    def eval(self, wi, wo) -> np.ndarray:
        """f(ωi, ωo) (N, 3) in 1/sr at unit directions (N, 3) in the surface frame; 0 below the horizon."""
        wi, wo = _unit_rows("wi", wi), _unit_rows("wo", wo)
        if wi.shape != wo.shape:
            raise ValueError(f"wi, wo: expected equal shapes, got {wi.shape} and {wo.shape}")
        wl, io, wto = self._local(wi, wo)
        if self.view_shift:
            out = _shifted_eval(self.table, self.res, view_centroids(self.table, self.res, self.view_anchor), wi, io, wto)
            return np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None], out, 0.0)
        st, inside = self.grid_coords(wl, self._local(wo, wo)[0])
        ii, wti = _bilinear(st, self.res)
        vals = self.table[ii[:, :, None], io[:, None, :]]
        out = np.einsum("na,nb,nabc->nc", wti, wto, vals)
        if self.half:                                   # ρ = f cos θi cos θo J(h)
            out = out / (np.maximum(wi[:, 2], 1e-6) * np.maximum(wo[:, 2], 1e-6) * jacobian(st * self.extent))[:, None]
        return np.where(((wi[:, 2] > 0) & (wo[:, 2] > 0) & inside)[:, None], out, 0.0)

    def albedo(self, wo, n_theta: int = 64, n_phi: int = 128) -> np.ndarray:
        """Directional albedo ∫ f cos θi dωi (N, 3) for views wo (N, 3), midpoint rule in (cos θi, φi)."""
        wo = _unit_rows("wo", wo)
        if self.half:     # quadrature over the h grid: sharp lobes are resolved where they are
            sub = max(2, int(np.ceil(n_theta / self.res)))
            st, dst = cell_points(self.res, sub, self.extent)
            h = hemi_oct_decode(st)
            dwh = jacobian(st) * dst
            out = []
            for w in wo:
                wi, ok = reflect(np.broadcast_to(w, h.shape), h)
                v = self.eval(np.where(ok[:, None], wi, [0, 0, 1.0]), np.broadcast_to(w, h.shape))
                out.append((v * (ok * wi[:, 2] * 4 * np.abs(h @ w) * dwh)[:, None]).sum(0))
            return np.array(out)
        wi, dw = hemisphere_midpoints(n_theta, n_phi)
        return np.array([(self.eval(wi, np.broadcast_to(w, wi.shape)) * wi[:, 2:3]).sum(0) * dw for w in wo])

    def view_nodes(self) -> np.ndarray:
        """Unit ωo of the table's ωo nodes (n_o, 3)."""
        if self.view_a is not None:
            return view_directions(self.view_a, self.view_b)
        if not self.iso:
            return direction_grid(self.res)
        th = theta_nodes(self.n_o)
        return np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)

    @classmethod
    def from_function(cls, f, res: int, iso: bool = False, n_theta: int = 32, sub: int = 1, info=None,
                      half: bool = False, extent: float = 1.0, view_a=None, view_b=None):
        """Tabulate ``f(wi, wo) -> (N, 3)`` (1/sr, surface frame) at the grid nodes; with ``sub`` > 1
        each ωi value is the average over sub x sub points of its cell in (s, t) (box prefilter, for
        BRDFs sharper than a cell).  ``half``: a half-vector table over (s, t) ∈ [-extent, extent]²
        (module docstring); the cell average is over h, ωi = reflect(ωo, h), 0 below the horizon.
        ``view_a`` / ``view_b``: ωo on that view grid (radians, module docstring)."""
        validation.check_range("res", res, 2, MAX_RES)
        validation.check_range("sub", sub, 1, 16)
        res, sub = int(res), int(sub)
        if iso:
            validation.check_range("n_theta", n_theta, 2, 256)
        extent = validation.check_range("extent", extent, 1e-3, 1.0) if half else 1.0
        st, _ = cell_points(res, sub, extent)
        x_all = hemi_oct_decode(st)                  # ωi, or h for half tables: (res² * sub², 3), cell-major
        vg = {} if view_a is None and view_b is None else {"view_a": view_a, "view_b": view_b}
        n_o = int(n_theta) if iso else (len(np.ravel(view_a)) * len(np.ravel(view_b)) if vg else res * res)
        wo_nodes = cls(np.zeros((res * res, n_o, 3)), res, bool(iso), half=bool(half), **vg).view_nodes()
        out = np.empty((res * res, len(wo_nodes), 3))
        for o, wo in enumerate(wo_nodes):
            WO = np.broadcast_to(wo, x_all.shape)
            if half:
                wi, ok = reflect(WO, x_all)
                v = np.zeros((len(wi), 3))
                if ok.any():                            # ρ = f cos θi cos θo J(h)
                    v[ok] = _call_f(f, wi[ok], WO[ok]) * (wi[ok, 2] * wo[2] * jacobian(st[ok]))[:, None]
                # mean over the sub-points whose ωi is above the horizon: eval masks the rest, so a cell
                # the horizon cuts keeps its mass (a mean over all would lose it twice)
                n_ok = ok.reshape(res * res, sub * sub).sum(1)
                out[:, o] = v.reshape(res * res, sub * sub, 3).sum(1) / np.maximum(n_ok, 1)[:, None]
                continue
            v = _call_f(f, x_all, WO)
            out[:, o] = np.broadcast_to(v.reshape(res * res, sub * sub, -1).mean(1), (res * res, 3))
        if not np.all(np.isfinite(out)):
            raise ValueError("f: returned NaN or inf on the table grid")
        info = dict(info or {})
        info.setdefault("sub", sub)                     # the cell average's rule (``lambert_nodes``, ``glossy_nodes``)
        return cls(np.maximum(out, 0.0), res, bool(iso), info, bool(half), float(extent), **vg)


# ----------------------------------------------------------------------------- the closure
def _call_f(f, wi, wo) -> np.ndarray:
    """``f(wi, wo)`` as (N, 3) or (N, 1) floats; a result of another shape is a ValueError naming ``f``."""
    v = np.asarray(f(wi, wo), np.float64)
    n = len(wi)
    if v.shape in ((n,), (n, 1), (n, 3)):
        return v.reshape(n, -1)
    raise ValueError(f"f: must return (N, 3) RGB (or (N,) grey) values for N = {n} direction pairs, got shape {v.shape}")


def default_alpha(res: int, extent: float = 1.0) -> float:
    """GGX alpha of the closure: 1/16 of a cell's angular size (≈ π extent/(2 res) rad per cell; extent < 1:
    a zoomed half-vector grid), so that the lobe blur stays well inside a cell; floored at 2e-5 (Cycles needs
    alpha_x alpha_y > 2e-10)."""
    return float(max(np.tan(0.5 * np.pi * extent / res / 16.0), 2e-5))


def lobe_albedo(cos_d, alpha) -> np.ndarray:
    """Albedo of Cycles' GGX closure (F = 1) about micro-normal m for a view at cos θd = ωo·m, when the
    lobe is narrow (α ≪ 1): the sampled weight G2/G1 with the height-correlated Smith G,
    (1 + Λ)/(1 + 2Λ), Λ = (√(1 + α² tan² θd) - 1)/2 (Heitz 2014, eqs. 72, 99); ωi·m = ωo·m."""
    c = np.clip(np.asarray(cos_d, np.float64), 1e-6, 1.0)
    t2 = (1.0 - c * c) / (c * c)
    lam = 0.5 * (np.sqrt(1.0 + alpha * alpha * t2) - 1.0)
    return (1.0 + lam) / (1.0 + 2.0 * lam)


def _cell_integrals(res: int, sub: int = 16):
    """(∫_cell dω, ∫_cell cos θ dω) per cell, midpoint rule on sub x sub sub-cells."""
    h = 2.0 / res
    c = -1.0 + (np.arange(res * sub) + 0.5) * (h / sub)
    S, T = np.meshgrid(c, c, indexing="ij")
    J = jacobian(np.stack([S, T], -1)) * (h / sub) ** 2
    cos = hemi_oct_decode(np.stack([S, T], -1))[..., 2]
    om = J.reshape(res, sub, res, sub).sum((1, 3)).ravel()
    omc = (J * cos).reshape(res, sub, res, sub).sum((1, 3)).ravel()
    return om, omc


@dataclass
class ClosureTables:
    """Arrays of the shader: ``F`` (res², n_o, 3) float32, ``cdf`` (n_o, res²+1) float32, ``res``,
    ``iso``, ``alpha`` (closure GGX alpha), ``half`` / ``extent`` (half-vector grid, module docstring);
    ``guide`` (n_o, res²) int32: the guide table of each CDF (``guide_table``); ``kd`` (3,) the smooth
    floor's albedo (``floor_split``): the shader adds a Diffuse closure of weight kd, and ``F`` / ``cdf`` are
    those of the residual r = f - kd/π (- ks g); ``ks`` (3,), ``alpha_g``, ``dist_g``: the glossy floor
    (``glossy_floor_split``: a ``dist_g`` ("ggx" / "beckmann") closure of α ``alpha_g`` and colour ks, none when ks = 0;
    ``ks_view`` (n_o, 3) or None: the colour per θo node of an isotropic table, ``floor_ks``); ``centroid`` (n_o, 2) or
    None: the (s, t) centroids of F's rows (``view_centroids``) when the table interpolates its view grid by following
    the lobe (``TabulatedBRDF.view_shift``: the drawn target moves by the interpolated centroid minus its node's)."""
    F: np.ndarray
    cdf: np.ndarray
    res: int
    iso: bool
    alpha: float
    half: bool = False
    extent: float = 1.0
    guide: np.ndarray | None = None
    view_a: np.ndarray | None = None
    view_b: np.ndarray | None = None
    kd: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ks: np.ndarray = field(default_factory=lambda: np.zeros(3))
    alpha_g: float = 0.0
    dist_g: str = "ggx"
    ks_view: np.ndarray | None = None
    centroid: np.ndarray | None = None

    def __post_init__(self):
        if self.guide is None:
            self.guide = guide_table(self.cdf)
        self.kd = np.asarray(self.kd, np.float64).reshape(3)
        self.ks = np.asarray(self.ks, np.float64).reshape(3)
        self.alpha_g = float(self.alpha_g)

    @property
    def n_o(self) -> int:
        return self.F.shape[1]


def guide_table(cdf) -> np.ndarray:
    """Guide table (Chen & Asau 1974, "cutpoint method") of each row of ``cdf`` (n, M+1), nondecreasing from 0
    to 1: ``G[r, j]`` (n, M) int32 is a lower bound of the bin k(u) = #{b >= 1: cdf[r, b] <= u} (clipped to
    M - 1) of every u in [j/M, (j+1)/M).  The shader starts at G[r, floor(u M)] and steps up while
    u >= cdf[r, k+1]: the same bin as a binary search (so ``sample`` is its exact twin) in O(1) expected
    steps (at most 1 + (bins whose upper edge falls in the bucket): < 2 on average) instead of log2 M.
    The bounds are taken at j/M (1 - 1e-6) so that float32 rounding of u M in the shader cannot skip a bin."""
    cdf = np.asarray(cdf, np.float64)
    n, M = cdf.shape[0], cdf.shape[1] - 1
    u = np.arange(M) / M * (1.0 - 1e-6)
    G = np.empty((n, M), np.int32)
    for r in range(n):
        G[r] = np.minimum(np.searchsorted(cdf[r, 1:], u, side="right"), M - 1)
    return G


def _half_cell_integrals(brdf: TabulatedBRDF, sub: int = 4):
    """Half tables: (∫_cell dωh (D,), ∫_cell [ωi above] 4 |ωo·h| ds dt (n_o, D)) per h cell and ωo node
    (ρ = f cos θi cos θo J carries the cosines and dωh/(ds dt)), midpoint rule on sub x sub sub-cells."""
    res, D = brdf.res, brdf.res * brdf.res
    st, dst = cell_points(res, sub, brdf.extent)
    h = hemi_oct_decode(st)
    dwh = jacobian(st) * dst
    om = dwh.reshape(D, sub * sub).sum(1)
    wo = brdf.view_nodes()
    c = h @ wo.T                                               # (P, n_o) ωo·h
    cos_i = 2.0 * c * h[:, 2:3] - wo[None, :, 2]               # ωi·n of the reflected directions
    omc = ((cos_i > 0) * 4.0 * np.abs(c) * dst).reshape(D, sub * sub, -1).sum(1)
    return om, omc.T


def lambert_nodes(brdf: TabulatedBRDF) -> np.ndarray:
    """Table values (res², n_o) of the white Lambertian f = 1/π in ``brdf``'s layout: 1/π (ωi tables), or
    (half tables) ρ = cos θi cos θo J(h) / π averaged, as ``TabulatedBRDF.from_function`` does, over the
    sub x sub points of each h cell whose ωi is above the horizon (``info["sub"]``, default 4; 0 for cells
    wholly below it)."""
    D = brdf.res * brdf.res
    if not getattr(brdf, "half", False):
        return np.full((D, brdf.n_o), 1.0 / np.pi)
    sub = int(brdf.info.get("sub", 4)) if isinstance(getattr(brdf, "info", None), dict) else 4
    st, _ = cell_points(brdf.res, sub, brdf.extent)
    h = hemi_oct_decode(st)
    wo = brdf.view_nodes()
    c = h @ wo.T                                               # (P, n_o) ωo·h
    cos_i = 2.0 * c * h[:, 2:3] - wo[None, :, 2]               # ωi·n of ωi = reflect(ωo, h)
    ok = cos_i > 0
    v = np.where(ok, cos_i * wo[None, :, 2] * jacobian(st)[:, None], 0.0) / np.pi
    n_ok = ok.reshape(D, sub * sub, -1).sum(1)
    return v.reshape(D, sub * sub, -1).sum(1) / np.maximum(n_ok, 1)


def floor_split(brdf: TabulatedBRDF, floor: bool = True):
    """The smooth floor of ``brdf``: f = kd/π + r with the largest constant kd (RGB, per channel) that keeps
    the residual r >= 0 at every table node, kd = min over nodes of table / ``lambert_nodes`` (nodes where the
    Lambertian is 0 impose nothing).  Bilinear interpolation then keeps r >= 0 between nodes, and kd/π + r is
    the table (ωi tables: exactly; half tables: r interpolates ρ - kd ρ_Lambert, so the sum is the table with
    its Lambertian part made exact instead of interpolated).  The floor renders as a Diffuse closure (light
    sampling sees a small lamp at every sample); only r goes through the one-lobe closure.  kd = 0 for half
    tables zoomed to a lobe (``extent`` < 1: f = 0 outside the zoom) and with ``floor=False``.
    A floor per ωo node (kd_o interpolated in ωo, tried in OSL) was measured and dropped: under the startup point
    lamp it left a GGX + Lambert MERL file as noisy as no floor (8 spp pixel error 4.64 vs 4.64; the constant
    floor: 2.06) and made a bi-scale pyramid of diffuse facets noisier (2.49 vs 1.82): a residual that touches 0
    at many nodes varies up to 4x inside a cell, where the proposal is uniform, and its weights with it.
    Returns (kd (3,), the residual as a ``TabulatedBRDF`` of the same layout)."""
    half = bool(getattr(brdf, "half", False))
    kd = np.zeros(3)
    table = np.asarray(brdf.table, np.float64)
    if floor and not (half and brdf.extent < 1.0):
        lam = lambert_nodes(brdf)
        pos = lam > 0
        if pos.any():
            kd = np.maximum((table[pos] / lam[pos][:, None]).min(0), 0.0)
        if kd.max() <= 1e-6:                            # nothing to gain: no Diffuse closure
            kd = np.zeros(3)
        table = np.maximum(table - kd * lam[..., None], 0.0)   # >= 0 up to rounding at the argmin nodes
    va, vb = getattr(brdf, "view_a", None), getattr(brdf, "view_b", None)
    vg = {} if va is None else {"view_a": va, "view_b": vb, "view_shift": bool(getattr(brdf, "view_shift", False))}
    if vg:
        vg["view_anchor"] = float(getattr(brdf, "view_anchor", 1.0))
    res_brdf = TabulatedBRDF(table, brdf.res, bool(brdf.iso), dict(getattr(brdf, "info", {}) or {}), half,
                             float(getattr(brdf, "extent", 1.0)) if half else 1.0, **vg)
    return kd, res_brdf


# ----------------------------------------------------------------------------- the glossy floor
#: ``floor="auto"`` (the default, ``floor=True``) adds the glossy floor when it takes at least this share of the
#: table's hemispherical albedo (else the Diffuse floor alone): the extra Glossy closure costs 6 % more instructions
#: per sample on SVM (``bench/out/tabulated_floor_callgrind.md``), and a floor worth less saves little noise.
GLOSSY_SHARE_MIN = 0.1
#: the floor modes of ``floor_parts`` / ``closure_tables`` (True = "auto", False = "none")
FLOOR_MODES = ("auto", "glossy", "diffuse", "none")
#: views (polar angles, radians) and their weights cos θ sin θ dθ of the hemispherical albedo averages
_AVG_THETA = (np.arange(12) + 0.5) * (0.5 * np.pi / 12)
_AVG_W = np.cos(_AVG_THETA) * np.sin(_AVG_THETA) / np.sum(np.cos(_AVG_THETA) * np.sin(_AVG_THETA))


def floor_mode(floor) -> str:
    """The floor mode of a ``floor`` argument: True -> "auto", False / None -> "none", or one of ``FLOOR_MODES``
    (ValueError naming ``floor`` otherwise)."""
    if floor is True:
        return "auto"
    if floor is False or floor is None:
        return "none"
    if isinstance(floor, str) and floor in FLOOR_MODES:
        return floor
    raise ValueError(f"floor: expected True, False or one of {FLOOR_MODES}, got {floor!r}")


#: the glossy floor's distributions: Cycles' GGX and Beckmann closures (heavy / light tails)
FLOOR_DISTS = ("ggx", "beckmann")


def _lambda(z, alpha, dist: str):
    """Cycles' isotropic Smith Λ at cos θ = z: GGX (Heitz 2014 eq. 72) or Cycles' Beckmann approximation
    (``precompute.cycles.beckmann``)."""
    z2 = np.clip(z * z, 1e-12, 1.0)
    s = alpha * alpha * (1.0 - z2) / z2
    if dist == "beckmann":
        return _bk.beckmann_lambda_from_sqr_alpha_tan_n(s)
    return 0.5 * (np.sqrt(1.0 + s) - 1.0)


def glossy_eval(wi, wo, alpha, dist: str = "ggx") -> np.ndarray:
    """The glossy floor's lobe g (N,) in 1/sr: Cycles' isotropic microfacet reflection closure ``dist`` ("ggx":
    the Glossy node's GGX / OSL ``microfacet("ggx")``; "beckmann"), F = 1, height-correlated Smith G2, single
    scattering: D G2 / (4 cos θi cos θo) (``precompute.cycles.ggx.bsdf_eval`` / cos θi) for ωi, ωo above the horizon
    (callers mask the rest: Cycles evaluates 0 there)."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return _glossy_cosines(h[..., 2] ** 2, wi[..., 2], wo[..., 2], alpha, dist)


def _glossy_cosines(c2, zi, zo, alpha, dist: str = "ggx") -> np.ndarray:
    """``glossy_eval`` from the cosines it depends on: c2 = cos² θh, zi = cos θi, zo = cos θo (isotropic: D of θh
    alone, GGX or Cycles' Beckmann ``beckmann_aniso_D``), D G2 / (4 cos θi cos θo) in 1/sr; shared by the floor
    search's cached pair geometry (``_geometry_nodes``)."""
    a2 = alpha * alpha
    if dist == "ggx":
        D = a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)
    else:
        c2 = np.asarray(c2, np.float64)
        D = _bk.beckmann_aniso_D(alpha, alpha, np.stack([np.sqrt(np.maximum(1.0 - c2, 0.0)), np.zeros_like(c2),
                                                         np.sqrt(c2)], -1))
    G = 1.0 / (1.0 + _lambda(zi, alpha, dist) + _lambda(zo, alpha, dist))
    return D * G / (4.0 * np.maximum(zi, 1e-6) * np.maximum(zo, 1e-6))


def glossy_albedo(cos_o, alpha, dist: str = "ggx", n: int = 768) -> np.ndarray:
    """Directional albedo ∫ g cos θi dωi of the glossy floor's lobe (``glossy_eval``) at views of cos θo ``cos_o``
    (N,), dimensionless.  With g cos θi dωi = D G2 (ωo·h) / cos θo dωh and h drawn from D(h) cos θh dωh =
    du dφ / 2π (GGX: tan² θh = α² u / (1 - u); Beckmann: -α² ln(1 - u)): E = E_h[G2 (ωo·h) / (cos θo cos θh)],
    ωi above the horizon; midpoint rule on n x n in (u, φ)."""
    mu = np.clip(np.atleast_1d(np.asarray(cos_o, np.float64)), 1e-4, 1.0)
    u = (np.arange(n) + 0.5) / n
    ph = (np.arange(n) + 0.5) / n * 2 * np.pi
    t2 = -alpha * alpha * np.log1p(-u) if dist == "beckmann" else alpha * alpha * u / (1.0 - u)
    th = np.arctan(np.sqrt(t2))
    ch, sh = np.cos(th)[:, None], np.sin(th)[:, None]
    h = np.stack(np.broadcast_arrays(sh * np.cos(ph), sh * np.sin(ph), ch), -1).reshape(-1, 3)
    out = np.empty(len(mu))
    for i, m in enumerate(mu):
        wo = np.array([np.sqrt(1.0 - m * m), 0.0, m])
        oh = h @ wo
        wi = 2.0 * oh[:, None] * h - wo
        ok = (oh > 0) & (wi[:, 2] > 0)
        G2 = 1.0 / (1.0 + _lambda(wi[:, 2], alpha, dist) + _lambda(np.full(1, m), alpha, dist))
        out[i] = np.sum(np.where(ok, G2 * oh / (m * h[:, 2]), 0.0)) / len(h)
    return out


def _hemi_average(E) -> float:
    """Hemispherical average ∫ E(θo) cos θo dωo / π of a directional albedo sampled at ``_AVG_THETA``."""
    return float(np.sum(np.asarray(E) * _AVG_W))


_HEMI_ALBEDO: dict = {}


def _hemi_albedo(brdf: TabulatedBRDF) -> float:
    """The table's hemispherical albedo (grey: mean of RGB), ``_hemi_average`` of ``TabulatedBRDF.albedo`` at
    ``_AVG_THETA``; remembered per table content (``_table_key``: ``floor_parts`` and the search both need it)."""
    key = _table_key(brdf)
    if key not in _HEMI_ALBEDO:
        if len(_HEMI_ALBEDO) >= 64:
            _HEMI_ALBEDO.clear()
        mu = np.cos(_AVG_THETA)
        _HEMI_ALBEDO[key] = _hemi_average(np.mean(brdf.albedo(np.stack([np.sin(_AVG_THETA), 0 * mu, mu], -1),
                                                              48, 96), 1))
    return _HEMI_ALBEDO[key]


def _node_pairs(brdf: TabulatedBRDF):
    """The (ωi, ωo) pairs ``from_function`` evaluates to build ``brdf``'s nodes, for evaluating other BRDFs in its
    layout at once: (wi (n_o, P, 3), wo (n_o, 1, 3), weight (n_o, P) (half tables: ok cos θi cos θo J, else 1),
    sub²) with P = res² sub² cell-major points; a node is the sum over its cell's sub² points x weight / count
    (half tables: the count of points above the horizon, as ``from_function``)."""
    info = brdf.info if isinstance(getattr(brdf, "info", None), dict) else {}
    half = bool(getattr(brdf, "half", False))
    sub = int(info.get("sub", 4 if half else 1))
    st, _ = cell_points(brdf.res, sub, float(getattr(brdf, "extent", 1.0)) if half else 1.0)
    x = hemi_oct_decode(st)
    wo = brdf.view_nodes()[:, None, :]
    if not half:
        return np.broadcast_to(x, (len(wo), *x.shape)), wo, np.ones((len(wo), len(x))) / (sub * sub), sub
    wi, ok = reflect(np.broadcast_to(wo, (len(wo), len(x), 3)), np.broadcast_to(x, (len(wo), len(x), 3)))
    w = np.where(ok, wi[..., 2] * wo[..., 2] * jacobian(st)[None, :], 0.0)
    n_ok = ok.reshape(len(wo), brdf.res ** 2, sub * sub).sum(-1)
    w = w / np.repeat(np.maximum(n_ok, 1), sub * sub, axis=1)
    return np.where(ok[..., None], wi, [0.0, 0.0, 1.0]), wo, w, sub


def glossy_nodes(brdf: TabulatedBRDF, alpha: float, dist: str = "ggx", pairs=None) -> np.ndarray:
    """The glossy floor's lobe (``glossy_eval``, α ``alpha``, ``dist``) in ``brdf``'s layout (res², n_o): its values
    at the table's nodes, cell-averaged over ``info["sub"]``² points as ``from_function`` built the table (half
    tables: ρ = g cos θi cos θo J, as ``lambert_nodes``), vectorised over all pairs (``_node_pairs``, reusable
    via ``pairs``).  The g subtracted where the residual is stored."""
    wi, wo, w, sub = _node_pairs(brdf) if pairs is None else pairs
    v = glossy_eval(wi, wo, float(alpha), dist) * w                         # (n_o, P)
    return np.maximum(v.reshape(v.shape[0], -1, sub * sub).sum(-1).T, 0.0)


def _best_split(t, lam, g, Eg, levels: int = 3, K: int = 33):
    """Per channel, kd >= 0 and ks_o >= 0 per view node o (rows of the table: t (D, n_o, 3), lam, g (D, n_o))
    maximising the floor's albedo kd + Σ_o Eg_o ks_o subject to kd lam + ks_o g <= t at every node (``Eg`` (n_o,):
    the view weights times the lobe's albedo at each node; one column (n_o = 1) for a ks shared by all views).
    ks_o(kd) = min over row o of (t - kd lam) / g is concave in kd, so the objective is too: a grid of K values of
    kd in [0, kd_max], refined ``levels`` times around the best.  The search runs on the ``keep`` nodes of each row
    with the smallest ratios at kd = 0, kd_max / 2 and kd_max (the lines that bound the envelope, up to lines
    crossing the whole set), and ks is then computed over every node for the kd found, so every returned pair
    satisfies the constraints exactly.  Returns kd (3,), ks (n_o, 3)."""
    pos_l = lam > 0
    pos_g = g > 1e-12 * max(float(g.max()), 1e-300)
    gs = np.where(pos_g, g, 1.0)
    Eg = np.asarray(Eg, np.float64)
    kd_out, ks_out = np.zeros(3), np.zeros((g.shape[1], 3))
    keep = 48
    for c in range(3):
        tc = t[..., c]
        kd_max = max(float((tc[pos_l] / lam[pos_l]).min()), 0.0) if pos_l.any() else 0.0

        def ratios(kd, tt, ll, gg, pp):                  # (K, D', n_o)
            return np.where(pp[None], (tt[None] - kd[:, None, None] * ll[None]) / gg[None], np.inf)
        sel = (tc, lam, gs, pos_g)
        if tc.shape[0] > keep:                           # prune each row to its few binding candidates
            q = ratios(np.array([0.0, 0.5 * kd_max, kd_max]), *sel)
            idx = np.concatenate([np.argpartition(qk, keep, axis=0)[:keep] for qk in q], 0)     # (3 keep, n_o)
            sel = tuple(np.take_along_axis(a, idx, 0) for a in sel)

        def ks_of(kd, sel=sel):                          # (K, n_o)
            return np.maximum(ratios(kd, *sel).min(1), 0.0)
        lo, hi = 0.0, kd_max
        best_v, best = -1.0, (0.0, np.zeros(g.shape[1]))
        for _ in range(levels):
            kds = np.linspace(lo, hi, K)
            kss = np.where(np.isfinite(ks := ks_of(kds)), ks, 0.0)
            v = kds + kss @ Eg
            i = int(np.argmax(v))
            if v[i] >= best_v:
                best_v, best = float(v[i]), (float(kds[i]), kss[i])
            step = (hi - lo) / (K - 1)
            lo, hi = max(kds[i] - step, 0.0), min(kds[i] + step, kd_max)
        kd = np.array([best[0]])
        full = np.maximum(ratios(kd, tc, lam, gs, pos_g).min(1)[0], 0.0)         # every node: exact for kd
        kd_out[c], ks_out[:, c] = best[0], np.where(np.isfinite(full), full, 0.0)
    return kd_out, ks_out


@dataclass
class FloorParts:
    """The floors of a table (``floor_parts``): f = kd/π + ks g + r at every node.  ``kd`` (3,) Diffuse albedo;
    the glossy floor g: Cycles' ``dist_g`` closure ("ggx" or "beckmann", ``glossy_eval``) of α ``alpha_g``, F = 1,
    colour ``ks`` (3,) (ks = 0: none; with ``ks_view`` (n_o, 3), isotropic tables: the colour per θo node,
    interpolated linearly in θo, ``ks`` its maximum); ``residual`` r (a ``TabulatedBRDF``, >= 0); ``mode`` the mode
    used; ``share`` the glossy floor's share of the table's hemispherical albedo (ks Ē_g / Ē_f, channel mean)."""
    kd: np.ndarray
    ks: np.ndarray
    alpha_g: float
    residual: TabulatedBRDF
    mode: str
    share: float = 0.0
    dist_g: str = "ggx"
    ks_view: np.ndarray | None = None

    @property
    def iso(self) -> bool:
        return bool(self.residual.iso)

    @property
    def n_o(self) -> int:
        return self.residual.n_o


_FLOOR_CACHE: dict = {}


#: the glossy floor search's lobes in one table layout (``_layout_lobes``): an edit of a table (a bi-scale colour,
#: a re-import) keeps its layout, so the search's 16 grid lobes are evaluated once per layout, not per table
_LOBES: dict = {"layout": None, "geom": None, "g": {}}
_ALBEDO_MEMO: dict = {}


def _layout_key(brdf) -> tuple:
    """What ``_node_pairs`` depends on: the table's layout, not its values."""
    import hashlib
    h = hashlib.sha1()
    for a in (getattr(brdf, "view_a", None), getattr(brdf, "view_b", None)):
        if a is not None:
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
    info = brdf.info if isinstance(getattr(brdf, "info", None), dict) else {}
    half = bool(getattr(brdf, "half", False))
    return (h.hexdigest(), brdf.res, bool(brdf.iso), half, float(getattr(brdf, "extent", 1.0)) if half else 1.0,
            int(info.get("sub", 4 if half else 1)), len(brdf.view_nodes()))


def _layout_lobes(brdf):
    """``lobe(α, dist)`` -> ``glossy_nodes`` of ``brdf``'s layout, remembered for the last layout only (memory: at
    most 48 lobes of one layout, 1 MB each for a bi-scale 19² x 19x19 table)."""
    key = _layout_key(brdf)
    if _LOBES["layout"] != key:
        _LOBES.update(layout=key, geom=_node_geometry(_node_pairs(brdf)), g={})

    def lobe(a: float, dg: str) -> np.ndarray:
        if (a, dg) not in _LOBES["g"]:
            if len(_LOBES["g"]) >= 48:
                _LOBES["g"].clear()
            _LOBES["g"][(a, dg)] = _geometry_nodes(_LOBES["geom"], a, dg)
        return _LOBES["g"][(a, dg)]
    return lobe


def _node_geometry(pairs) -> dict:
    """What ``glossy_eval`` needs of the node pairs (``_node_pairs``), once per layout: cos² θh, cos θi, cos θo of the
    pairs with weight > 0, their weights and node index (a node sums its cell's pairs)."""
    wi, wo, w, sub = pairs
    n_o, P = w.shape
    keep = np.flatnonzero(w.ravel() != 0)
    WI = wi.reshape(-1, 3)[keep]
    WO = np.broadcast_to(wo, wi.shape).reshape(-1, 3)[keep]
    h = WI + WO
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    o, p = np.divmod(keep, P)
    return {"c2": h[:, 2] ** 2, "zi": WI[:, 2], "zo": WO[:, 2], "w": w.ravel()[keep],
            "node": (p // (sub * sub)) * n_o + o, "shape": (P // (sub * sub), n_o), "sub": sub}


def _geometry_nodes(geom: dict, alpha: float, dist: str) -> np.ndarray:
    """``glossy_nodes`` from the cached pair geometry (``_node_geometry``): ``glossy_eval``'s lobe from the cosines
    (``_glossy_cosines``), without re-deriving the half vectors per α (the floor search evaluates ~30 α on 10⁶
    pairs)."""
    v = _glossy_cosines(geom["c2"], geom["zi"], geom["zo"], alpha, dist) * geom["w"]
    D_, n_o = geom["shape"]
    return np.maximum(np.bincount(geom["node"], v, D_ * n_o).reshape(D_, n_o), 0.0)


def _glossy_albedo_memo(cos_o, a: float, dg: str) -> np.ndarray:
    """``glossy_albedo(cos_o, a, dg, 128)``, remembered (the search repeats its α grid for every table)."""
    cos_o = np.ascontiguousarray(cos_o, np.float64)
    k = (cos_o.tobytes(), a, dg)
    if k not in _ALBEDO_MEMO:
        if len(_ALBEDO_MEMO) >= 256:
            _ALBEDO_MEMO.clear()
        _ALBEDO_MEMO[k] = glossy_albedo(cos_o, a, dg, 128)
    return _ALBEDO_MEMO[k]


def _table_key(brdf) -> tuple:
    import hashlib
    h = hashlib.sha1(np.ascontiguousarray(brdf.table, np.float64).tobytes())
    for a in (getattr(brdf, "view_a", None), getattr(brdf, "view_b", None)):
        if a is not None:
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
    info = brdf.info if isinstance(getattr(brdf, "info", None), dict) else {}
    pts = info.get("floor_points")
    if isinstance(pts, dict):                              # the floors depend on the floor points too
        for k in ("wi", "f", "ok", "alpha_min"):
            h.update(np.ascontiguousarray(pts.get(k), np.float64).tobytes())
    return (h.hexdigest(), brdf.res, bool(brdf.iso), bool(getattr(brdf, "half", False)),
            float(getattr(brdf, "extent", 1.0)), int(info.get("sub", 0)))


def glossy_floor_alpha_min(brdf: TabulatedBRDF) -> float:
    """The smallest α of the glossy floor's search: one cell's angular size tan(π Z / (2 res)) (Z the half table's
    zoom): a lobe narrower than a cell could sit between the nodes, where the constraint r >= 0 does not see it,
    and add energy the table does not hold.  A table with floor points (``floor_points``: f sampled finer than the
    cells where a narrow lobe sits, checked as constraints too) takes their own limit, ``alpha_min``."""
    pts = floor_points(brdf)
    if pts is not None:
        return float(pts["alpha_min"])
    Z = float(getattr(brdf, "extent", 1.0)) if getattr(brdf, "half", False) else 1.0
    return float(np.tan(0.5 * np.pi * Z / brdf.res))


def floor_points(brdf) -> dict | None:
    """The floor points of ``brdf`` (``info["floor_points"]``), or None: extra constraints r >= 0 of the floors,
    finer than the table's cells where a sharp lobe sits (a MERL file's own θh bins near the specular peak,
    ``merl.floor_points``), so that a glossy floor narrower than a cell can be fitted without slipping between the
    nodes.  A dict: ``wi`` (n_o, P, 3) unit directions for the table's view nodes (``TabulatedBRDF.view_nodes``),
    ``f`` (n_o, P, 3) the BRDF there (1/sr), ``ok`` (n_o, P) the points that constrain (ωi above the horizon, a
    measured bin), ``alpha_min`` the smallest floor α the points resolve."""
    info = brdf.info if isinstance(getattr(brdf, "info", None), dict) else {}
    pts = info.get("floor_points")
    if pts is None:
        return None
    n_o = brdf.table.shape[1]
    shape = np.shape(pts.get("wi")) if isinstance(pts, dict) else ()
    if not (len(shape) == 3 and shape[0] == n_o and shape[2] == 3 and np.shape(pts.get("f")) == shape
            and np.shape(pts.get("ok")) == shape[:2] and "alpha_min" in pts):
        raise ValueError(f"info: floor_points must hold wi, f (n_o = {n_o}, P, 3), ok (n_o, P) and alpha_min")
    return pts


#: largest share of a view row's albedo that clamping r >= 0 in the horizon cells may add (``_bound_clamp``)
CLAMP_MAX = 1e-3


def _horizon_cells(brdf) -> np.ndarray:
    """(res², n_o) bool: the half table's cells the horizon cuts (some, not all, of a cell's sub-points have ωi
    above it).  With floor points (a MERL import) they do not constrain the glossy floor's ks: their nodes average
    only grazing ωi, where a MERL file's 1° θd bins are coarser than the Smith shadowing's change (the table's node
    / the true BRDF 0.5-0.9 there, GGX α 0.02 file at 48²), so they capped ks at 0.56-0.68 of the lobe's 0.94.
    r < 0 there is clamped (``residual``) and bounded by ``_bound_clamp``."""
    _layout_lobes(brdf)                                           # the layout's pair geometry
    geom = _LOBES["geom"]
    n_ok = np.bincount(geom["node"], minlength=int(np.prod(geom["shape"]))).reshape(geom["shape"])
    return (n_ok > 0) & (n_ok < geom["sub"] ** 2)


def _bound_clamp(brdf, t, lam, g, kd, ks, cut) -> np.ndarray:
    """ks (n_o, 3) lowered where needed so that the energy the residual's clamp adds in the horizon cells ``cut``,
    Σ_cut max(0, kd lam + ks g - t) w (w the cell's albedo weight ∫ 4 |ωo·h| ds dt, ``_half_cell_integrals``), stays
    at most ``CLAMP_MAX`` of the row's Σ t w: bisection (40 steps) between the value that keeps r >= 0 in those cells
    and ks.  Returns ks when it already does (measured: GGX α 0.02 gold file at 48², 1.2e-4 at the most grazing
    view, 0 below 70°)."""
    _, omc = _half_cell_integrals(brdf)
    w = omc.T[..., None]                                          # (D, n_o, 1)
    E_row = (t * w).sum(0)                                        # (n_o, 3)
    c = cut.any(1)
    tc, lc, gc, wc = t[c], lam[c][..., None], g[c][..., None], w[c]
    mc = cut[c][..., None] & (gc > 0)

    def excess(k):
        return (np.where(mc, np.maximum(kd * lc + k[None] * gc - tc, 0.0), 0.0) * wc).sum(0) - CLAMP_MAX * E_row
    if np.all(excess(ks) <= 0):
        return ks
    lo = np.maximum(np.where(mc, (tc - kd * lc) / np.where(mc, gc, 1.0), np.inf).min(0), 0.0)
    lo = np.minimum(np.where(np.isfinite(lo), lo, ks), ks)
    hi = ks.copy()
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        ok = excess(mid) <= 0
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    return np.where(excess(ks) <= 0, ks, lo)


def _point_rows(brdf, pts, a: float, dg: str):
    """Rows (P, n_o) of the floor points for ``_best_split``: (f (P, n_o, 3), 1/π, the glossy lobe g of α ``a``),
    all three 0 where a point does not constrain.  The units are f's (1/sr), not ρ's: the split compares ratios
    (t - kd lam) / g row by row, so rows of other units mix freely."""
    ok = np.asarray(pts["ok"], bool)
    wo = brdf.view_nodes()[:, None, :]
    wi = np.asarray(pts["wi"], np.float64)
    g = np.where(ok, glossy_eval(np.where(ok[..., None], wi, wo), np.broadcast_to(wo, wi.shape), a, dg), 0.0)
    f = np.where(ok[..., None], np.asarray(pts["f"], np.float64), 0.0)
    return f.transpose(1, 0, 2), np.where(ok, 1.0 / np.pi, 0.0).T, g.T


def glossy_floor_split(brdf: TabulatedBRDF, alpha: float | None = None, dist: str | None = None,
                       n_grid: int = 8, per_view: bool = True, min_share: float = 0.0) -> FloorParts:
    """The glossy floor of ``brdf``: f = kd/π + ks g + r, g a Cycles microfacet closure (``glossy_eval``: GGX or
    Beckmann of α, F = 1, height-correlated Smith G2, single scattering: what the Glossy BSDF node and OSL
    ``microfacet`` render), with r >= 0 at every table node (``glossy_nodes``: g in the table's layout; bilinear
    interpolation then keeps r >= 0 everywhere).  For a given (dist, α), (kd, ks) per channel maximise the
    floor's albedo kd + ks Ē_g (Ē the hemispherical average of ``glossy_albedo``) under those constraints
    (``_best_split``, a 2-variable linear programme).  The rule for (dist, α) (``dist`` / ``alpha`` if given):
    the largest floor albedo summed over channels: a log grid of ``n_grid`` α in [``glossy_floor_alpha_min``, 1]
    per dist, then a golden-section search in log α between the best grid value's neighbours (its dist).
    Both tails are tried because r >= 0 must hold in the far tails too: a GGX floor (heavy tails) fits under a
    GGX lobe but not under a Beckmann one (its tails fall below GGX's: ks = 0), a Beckmann floor fits under both.
    What renders: kd/π + ks g (exact, Cycles evaluates it) + the interpolated r, so the floor's parts are not
    interpolated (a lobe that is the floor's renders as the analytic lobe).  Half tables zoomed to a lobe
    (``extent`` < 1: f = 0 outside the zoom) get no floor.  ``per_view`` (isotropic tables): ks is chosen per θo
    node (ks_o, the largest for each row; rendered linearly interpolated in θo like the table, ``floor_ks``), so
    that one bad row (a MERL file's grazing bins, which bind a shared ks to 0.43 of the lobe's 0.8) does not cap
    every view.  ``min_share``: skip the α refinement when the best grid value's share of the albedo is below it
    ("auto" passes half of ``GLOSSY_SHARE_MIN``: a floor too small to be used costs one grid pass).
    Returns ``FloorParts`` (mode "glossy")."""
    half = bool(getattr(brdf, "half", False))
    table = np.asarray(brdf.table, np.float64)
    D, n_o = table.shape[:2]
    va, vb = getattr(brdf, "view_a", None), getattr(brdf, "view_b", None)
    vg = {} if va is None else {"view_a": va, "view_b": vb, "view_shift": bool(getattr(brdf, "view_shift", False))}
    if dist is not None and dist not in FLOOR_DISTS:
        raise ValueError(f"dist: expected one of {FLOOR_DISTS}, got {dist!r}")
    n_grid = validation.check_int("n_grid", n_grid, 1, 64)
    min_share = validation.check_range("min_share", min_share, 0.0, 1.0)

    def residual(t):
        return TabulatedBRDF(np.maximum(t, 0.0), brdf.res, bool(brdf.iso), dict(getattr(brdf, "info", {}) or {}),
                             half, float(getattr(brdf, "extent", 1.0)) if half else 1.0, **vg)
    if half and brdf.extent < 1.0:
        return FloorParts(np.zeros(3), np.zeros(3), 0.0, residual(table), "glossy", 0.0)
    key = ("glossy", alpha, dist, n_grid, per_view, min_share) + _table_key(brdf)
    if key in _FLOOR_CACHE:
        return _FLOOR_CACHE[key]
    lam = lambert_nodes(brdf)
    t = table
    mu = np.cos(_AVG_THETA)
    per_view = bool(per_view) and bool(brdf.iso)
    lobes = _layout_lobes(brdf)
    th_o = theta_nodes(n_o)
    w_o = np.cos(th_o) * np.sin(th_o)
    w_o /= w_o.sum()
    memo = {}

    pts = floor_points(brdf)
    cut = _horizon_cells(brdf) if pts is not None else None

    def rows(a, dg):                                      # the nodes' constraints, and the floor points' if any
        g = lobes(a, dg)
        if pts is None:
            return t, lam, g
        tp, lp, gp = _point_rows(brdf, pts, a, dg)        # horizon cells: no ks constraint (``_horizon_cells``)
        return np.concatenate([t, tp]), np.concatenate([lam, lp]), np.concatenate([np.where(cut, 0.0, g), gp])

    def solve(a, dg):
        k = (float(a), dg)
        if k not in memo:
            t, lam, g = rows(float(a), dg)
            if per_view:                                  # ks per θo node: weights cos θ sin θ of the nodes
                Eg = _glossy_albedo_memo(np.cos(th_o), float(a), dg) * w_o
                kd, ks = _best_split(t, lam, g, Eg)
            else:
                Eg = np.array([_hemi_average(_glossy_albedo_memo(mu, float(a), dg))])
                kd, ks = _best_split(t.reshape(-1, 1, 3), lam.reshape(-1, 1), g.reshape(-1, 1), Eg)
                ks = np.repeat(ks, n_o, 0)
            memo[k] = (float(np.sum(kd) + np.sum(Eg[:, None] * ks[: len(Eg)])), kd, ks, lobes(float(a), dg), Eg)
        return memo[k]
    E_f = _hemi_albedo(brdf)
    dists = FLOOR_DISTS if dist is None else (dist,)
    if alpha is not None:
        for dg in dists:
            solve(validation.check_range("alpha_g", alpha, 1e-3, 1.0), dg)
    else:
        grid = np.geomspace(glossy_floor_alpha_min(brdf), 1.0, n_grid)
        for dg in dists:
            for a in grid:
                solve(a, dg)
        a0, dg = max(memo, key=lambda k: memo[k][0] - 1e-9 * (k[1] != "ggx"))      # ties: GGX
        best_share = (memo[(a0, dg)][0] - np.sum(memo[(a0, dg)][1])) / 3.0 / max(E_f, 1e-30)
        if best_share >= min_share:                        # refine the best distribution's α
            # with floor points, also the other distribution's own best when its grid value is at least half the
            # best: a GGX floor under a sharp GGX file peaks within a few % of the file's α (GGX α 0.02 gold: floor
            # share 0.96 there, 0.83 at α 0.018), so the grid can rank a flatter Beckmann floor first
            best = memo[(a0, dg)][0]
            for d in dists if pts is not None else (dg,):
                k0 = max((k for k in memo if k[1] == d), key=lambda k: memo[k][0])
                if d == dg or memo[k0][0] >= 0.5 * best:
                    _golden(lambda x: solve(np.exp(x), d)[0], grid, k0[0], 8 if pts is None else 12)
    a_best, d_best = max(memo, key=lambda k: memo[k][0] - 1e-9 * (k[1] != "ggx"))    # ties: GGX
    total, kd, ks, g, Eg = memo[(a_best, d_best)]
    if kd.max() <= 1e-6:
        kd = np.zeros(3)
    if cut is not None and ks.any():                       # the horizon cells' clamp: at most CLAMP_MAX
        ks = _bound_clamp(brdf, t, lam, g, kd, ks, cut)
        if not per_view:
            ks = np.broadcast_to(ks.min(0), ks.shape).copy()
    if ks.max() <= 1e-6:
        ks = np.zeros_like(ks)
    r = t - kd * lam[..., None] - ks[None, :, :] * g[..., None]       # >= 0 up to rounding (horizon cells: clamped)
    share = float(np.sum(Eg[:, None] * ks[: len(Eg)]) / 3.0 / E_f) if E_f > 0 and ks.any() else 0.0
    ks_view = ks if per_view and ks.any() else None
    out = FloorParts(kd, ks.max(0), float(a_best) if ks.any() else 0.0, residual(r), "glossy", share,
                     d_best if ks.any() else "ggx", ks_view)
    if len(_FLOOR_CACHE) > 16:
        _FLOOR_CACHE.clear()
    _FLOOR_CACHE[key] = out
    return out


def _golden(value, grid, a0, steps: int = 8) -> None:
    """Golden-section search for the maximum of ``value(log α)`` between the neighbours of ``a0`` in ``grid`` (unimodal
    near the best grid value); ``value`` remembers what it evaluates (the caller keeps the best)."""
    n = len(grid)
    i = int(np.argmin(np.abs(grid - a0)))
    lo, hi = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, n - 1)])
    gr = 0.5 * (np.sqrt(5.0) - 1.0)
    x1, x2 = hi - gr * (hi - lo), lo + gr * (hi - lo)
    for _ in range(steps):
        if value(x1) >= value(x2):
            hi, x2 = x2, x1
            x1 = hi - gr * (hi - lo)
        else:
            lo, x1 = x1, x2
            x2 = lo + gr * (hi - lo)


def floor_ks(parts, wo) -> np.ndarray:
    """The glossy floor's colour (N, 3) at views wo (N, 3) of ``parts`` (``FloorParts`` or ``ClosureTables``): ks,
    or with ``ks_view`` its linear interpolation in θo between the isotropic table's nodes (clamped: the taps of
    ``TabulatedBRDF.eval``)."""
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    kv = getattr(parts, "ks_view", None)
    if kv is None:
        return np.broadcast_to(np.asarray(parts.ks, np.float64), (len(wo), 3)).copy()
    n_o = len(kv)
    i0, i1, f = _lin_taps(np.arccos(np.clip(wo[:, 2], -1, 1)) / (0.5 * np.pi / n_o) - 0.5, n_o)
    return (1.0 - f)[:, None] * kv[i0] + f[:, None] * kv[i1]


def floor_albedo(tb: ClosureTables, wo) -> np.ndarray:
    """Directional albedo (N, 3) of the floors of ``tb`` at views wo (N, 3) (z > 0): kd + ks ``glossy_albedo``
    (ks at the view, ``floor_ks``).  A white furnace renders this plus the table closure's mean W A."""
    wo = _unit_rows("wo", wo)
    out = np.broadcast_to(tb.kd, (len(wo), 3)).copy()
    if np.any(tb.ks):
        out += floor_ks(tb, wo) * glossy_albedo(wo[:, 2], tb.alpha_g, tb.dist_g)[:, None]
    return out


def floor_parts(brdf: TabulatedBRDF, floor=True) -> FloorParts:
    """The floors the shader renders for ``floor`` (``floor_mode``): "none" (False): none; "diffuse": the Diffuse
    floor alone (``floor_split``); "glossy": Diffuse + glossy floor (``glossy_floor_split``); "auto" (True, the
    default): the glossy floor when it takes at least ``GLOSSY_SHARE_MIN`` of the table's hemispherical albedo,
    else the Diffuse floor alone; no search when the Diffuse floor leaves less than that in the residual (the glossy
    floor takes its energy off the residual: a Lambertian table, 1.5 s -> 0.1 s for a bi-scale-size one)."""
    mode = floor_mode(floor)
    if mode in ("diffuse", "none"):
        kd, r = floor_split(brdf, mode == "diffuse")
        return _deconvolved(brdf, FloorParts(kd, np.zeros(3), 0.0, r, mode, 0.0))
    if mode == "auto":      # the glossy floor takes energy off the residual: none to take, no search
        kd, r = floor_split(brdf, True)
        diffuse = FloorParts(kd, np.zeros(3), 0.0, r, "diffuse", 0.0)
        E_f = _hemi_albedo(brdf)
        if E_f <= 0.0 or 1.0 - float(np.mean(kd)) / E_f < GLOSSY_SHARE_MIN:
            return _deconvolved(brdf, diffuse)
    parts = glossy_floor_split(brdf, min_share=0.5 * GLOSSY_SHARE_MIN if mode == "auto" else 0.0)
    return _deconvolved(brdf, parts if mode == "glossy" or parts.share >= GLOSSY_SHARE_MIN else diffuse)


def _deconvolved(brdf: TabulatedBRDF, parts: FloorParts) -> FloorParts:
    """``parts`` with its residual's node values deconvolved (``prefilter.deconvolve_cells``) when ``brdf`` holds
    cell averages that ask for it (``info["deconvolve_residual"]``: MERL imports, ``merl.to_tabulated``): the floors
    are split from the cell averages (they match them exactly), and the residual's bilinear reconstruction then
    has its cell averages instead of a blur by about a cell (a gold GGX α 0.05 file at 48² x 32 in the merl_audit
    scenes, numpy: worst view 1.8 -> 1.1 %).  Anything else: ``parts`` unchanged."""
    info = brdf.info if isinstance(getattr(brdf, "info", None), dict) else {}
    if not info.get("deconvolve_residual"):
        return parts
    r = parts.residual
    va, vb = getattr(r, "view_a", None), getattr(r, "view_b", None)
    vg = {} if va is None else {"view_a": va, "view_b": vb}
    x = TabulatedBRDF(deconvolve_cells(r.table, r.res), r.res, r.iso, dict(r.info), r.half, r.extent, **vg)
    return replace(parts, residual=x)


def floor_eval(parts: FloorParts, wi, wo) -> np.ndarray:
    """f (N, 3) in 1/sr of what the shader renders with floors ``parts``: kd/π + ks g (exact) + r (interpolated)."""
    wi, wo = _unit_rows("wi", wi), _unit_rows("wo", wo)
    out = parts.residual.eval(wi, wo)
    ok = ((wi[:, 2] > 0) & (wo[:, 2] > 0))[:, None]
    out = out + np.where(ok, parts.kd / np.pi, 0.0)
    if parts.ks.any():
        out = out + np.where(ok, floor_ks(parts, wo) * glossy_eval(wi, wo, parts.alpha_g, parts.dist_g)[:, None], 0.0)
    return out


def closure_albedo(brdf: TabulatedBRDF, wo, floor=True, n_theta: int = 64, n_phi: int = 128) -> np.ndarray:
    """Directional albedo (N, 3) of what the shader renders for views wo (N, 3): kd (the Diffuse floor, whose
    cosine-weighted integral is kd) plus ks x the glossy floor's ``glossy_albedo`` plus the residual's ``albedo``
    (``floor_parts``)."""
    parts = floor_parts(brdf, floor)
    wo = _unit_rows("wo", wo)
    out = parts.kd[None, :] + parts.residual.albedo(wo, n_theta, n_phi)
    if parts.ks.any():
        out = out + floor_ks(parts, wo) * glossy_albedo(wo[:, 2], parts.alpha_g, parts.dist_g)[:, None]
    return out


def closure_tables(brdf: TabulatedBRDF, alpha: float | None = None, floor=True) -> ClosureTables:
    """The proposal CDFs (module docstring) and the float32 table of ``brdf`` for the shader; with ``floor``
    (default True = "auto") those of the residual r after the smooth Diffuse floor kd/π and the glossy floor
    ks g_α (``floor_parts``; "glossy", "diffuse", "none" / False)."""
    res = brdf.res
    D = res * res
    half = bool(getattr(brdf, "half", False))
    extent = float(getattr(brdf, "extent", 1.0)) if half else 1.0
    alpha = default_alpha(res, extent) if alpha is None else validation.check_range("alpha", alpha, 2e-5, 0.5)
    if brdf.table.size > MAX_TABLE_FLOATS:
        raise ValueError(f"table: {brdf.table.size} floats; a closure holds at most {MAX_TABLE_FLOATS} "
                         f"(lower res or n_theta)")
    parts = floor_parts(brdf, floor)
    kd, brdf = parts.kd, parts.residual
    if half:
        om, omc = _half_cell_integrals(brdf)
    else:
        om, omc = _cell_integrals(res)
        omc = omc[None, :]
    g = brdf.table.mean(-1).reshape(res, res, brdf.n_o)
    k = np.array([0.125, 0.75, 0.125])   # cell average of the clamped bilinear interpolant, per axis
    gp = np.pad(g, ((1, 1), (0, 0), (0, 0)), mode="edge")
    g = k[0] * gp[:-2] + k[1] * gp[1:-1] + k[2] * gp[2:]
    gp = np.pad(g, ((0, 0), (1, 1), (0, 0)), mode="edge")
    g = k[0] * gp[:, :-2] + k[1] * gp[:, 1:-1] + k[2] * gp[:, 2:]
    q = g.reshape(D, brdf.n_o).T * omc
    tot = q.sum(1, keepdims=True)
    q = np.where(tot > 0, q / np.where(tot > 0, tot, 1.0), om[None, :] / om.sum())
    q = (1.0 - DEFENSIVE) * q + DEFENSIVE * om[None, :] / om.sum()
    cdf = np.concatenate([np.zeros((brdf.n_o, 1)), np.cumsum(q, 1)], 1)
    cdf /= cdf[:, -1:]
    cdf[:, -1] = 1.0
    va, vb = getattr(brdf, "view_a", None), getattr(brdf, "view_b", None)
    cen = view_centroids(brdf.table, res, getattr(brdf, "view_anchor", 1.0)) if getattr(brdf, "view_shift", False) \
        else None
    return ClosureTables(brdf.table.astype(np.float32), cdf.astype(np.float32), res, bool(brdf.iso), float(alpha),
                         half, extent, view_a=va, view_b=vb, kd=kd, ks=parts.ks, alpha_g=parts.alpha_g,
                         dist_g=parts.dist_g, ks_view=parts.ks_view, centroid=cen)


def guide_pick(cdf, guide, o, u) -> np.ndarray:
    """The shader's bin pick: k = guide[o, floor(u M)] (u M in float32, as OSL), then k += 1 while
    u >= cdf[o, k+1] and k < M - 1.  Rows ``o`` (N,) of ``cdf`` (n, M+1) float32, uniforms ``u`` (N,);
    returns k (N,), equal to #{b >= 1: cdf[o, b] <= u} clipped to M - 1 (the inverse CDF)."""
    cdf = np.asarray(cdf, np.float32)
    M = cdf.shape[1] - 1
    u = np.asarray(u, np.float32)
    j = np.minimum((u * np.float32(M)).astype(np.int64), M - 1)
    k = np.asarray(guide)[o, j].astype(np.int64)
    while True:
        step = (u >= cdf[o, k + 1]) & (k < M - 1)
        if not step.any():
            return k
        k = k + step


def _view_taps(tb: ClosureTables, wo):
    """ωo node taps (N, k), their weights (N, k), and the frame rotation (cos φo, sin φo) (iso) or (1, 0)."""
    n = len(wo)
    if getattr(tb, "view_a", None) is not None:
        idx, w = view_taps(wo, tb.view_a, tb.view_b)
        return idx, w, np.ones(n), np.zeros(n)
    if not tb.iso:
        idx, w = _bilinear(hemi_oct_encode(wo), tb.res)
        return idx, w, np.ones(n), np.zeros(n)
    phi = np.arctan2(wo[:, 1], wo[:, 0])
    th = np.arccos(np.clip(wo[:, 2], -1, 1))
    i0, i1, f = _lin_taps(th / (0.5 * np.pi / tb.n_o) - 0.5, tb.n_o)
    return np.stack([i0, i1], 1), np.stack([1 - f, f], 1), np.cos(phi), np.sin(phi)


def _uniforms(u, n: int) -> np.ndarray:
    """``u`` as (n, 4) finite numbers in [0, 1] (one row per view, or one row for all), else ValueError."""
    try:
        u = np.atleast_2d(np.asarray(u, np.float64))
    except (TypeError, ValueError):
        raise ValueError(f"u: expected (N, 4) uniform numbers in [0, 1], got {u!r}") from None
    if u.ndim != 2 or u.shape[1] != 4 or u.shape[0] not in (1, n):
        raise ValueError(f"u: expected shape ({n}, 4) (one row per view), got {u.shape}")
    if not np.all(np.isfinite(u)) or u.min(initial=0.0) < 0.0 or u.max(initial=0.0) > 1.0:
        raise ValueError("u: uniform numbers must be finite and in [0, 1]")
    return np.broadcast_to(np.minimum(u, np.nextafter(1.0, 0.0)), (n, 4))


def sample(tb: ClosureTables, wo, u):
    """Numpy twin of the shader: views ``wo`` (N, 3) (surface frame, z > 0), uniform numbers ``u``
    (N, 4) = (h_o, h_k, h_s, h_t).  Returns (ωi target (N, 3), micro-normal m (N, 3),
    closure weight W (N, 3) = f cos θi / (p A), p (N,) the density of step 3 per steradian)."""
    wo = _unit_rows("wo", wo)
    u = _uniforms(u, len(wo))
    res, F, cdf = tb.res, tb.F.astype(np.float64), tb.cdf.astype(np.float64)
    D, cell, N = res * res, 2.0 / res, len(wo)
    # 1. ωo node, picked with probability = its interpolation weight (cumulative weights vs h_o)
    taps, wts, cph, sph = _view_taps(tb, wo)
    cw = np.cumsum(wts, 1)
    j = np.minimum((u[:, 0:1] >= cw).sum(1), taps.shape[1] - 1)
    o = taps[np.arange(N), j]
    # 2. ωi cell from row o's CDF, uniform jitter in (s, t)
    k = guide_pick(tb.cdf, tb.guide, o, u[:, 1])
    pk = cdf[o, k + 1] - cdf[o, k]
    s = -1.0 + (k // res + u[:, 2]) * cell
    t = -1.0 + (k % res + u[:, 3]) * cell
    Z = tb.extent if tb.half else 1.0
    qx, qy = 0.5 * Z * (s + t), 0.5 * Z * (s - t)
    v = np.stack([qx, qy, 1 - np.abs(qx) - np.abs(qy)], -1)
    ln = np.linalg.norm(v, axis=1)
    wl = v / ln[:, None]
    p = pk / ((Z * cell) ** 2 * 0.5 / ln ** 3)                 # 3. p = P_k / (h² J)  (half: of h)
    # f bilinear in ωi at node o
    r0, r1, fr = _lin_taps((s + 1) * 0.5 * res - 0.5, res)
    c0, c1, fc = _lin_taps((t + 1) * 0.5 * res - 0.5, res)
    f = (((1 - fr) * (1 - fc))[:, None] * F[r0 * res + c0, o] + ((1 - fr) * fc)[:, None] * F[r0 * res + c1, o]
         + (fr * (1 - fc))[:, None] * F[r1 * res + c0, o] + (fr * fc)[:, None] * F[r1 * res + c1, o])
    with np.errstate(divide="ignore", invalid="ignore"):
        wfac = np.where(pk > 0, wl[:, 2] / np.where(pk > 0, p, 1.0), 0.0)   # cos θi / p at the drawn point (ωi tables)
    if getattr(tb, "centroid", None) is not None:               # lobe-following view interpolation: move the target
        d = view_shifts(tb.centroid, taps, wts)[np.arange(N), j]
        s2, t2 = s + d[:, 0], t + d[:, 1]
        pk = np.where((np.abs(s2) <= 1.0) & (np.abs(t2) <= 1.0), pk, 0.0)
        qx, qy = 0.5 * (s2 + t2), 0.5 * (s2 - t2)
        v = np.stack([qx, qy, 1 - np.abs(qx) - np.abs(qy)], -1)
        ln = np.linalg.norm(v, axis=1)
        wl = v / ln[:, None]
        p = np.where(pk > 0, pk / (cell ** 2 * 0.5 / ln ** 3), 0.0)   # the target's density (per steradian)
    # back to the surface frame (iso: the frame turned by φo)
    x = np.stack([cph * wl[:, 0] - sph * wl[:, 1], sph * wl[:, 0] + cph * wl[:, 1], wl[:, 2]], -1)
    if tb.half:                                                 # x is h: ωi = reflect(ωo, h), dωi = 4 |ωo·h| dωh
        wi, ok = reflect(wo, x)
        m = x
        p = p / (4.0 * np.abs(np.sum(wo * x, 1)))
        pk = np.where(ok, pk, 0.0)
        f = f / (np.maximum(wi[:, 2], 1e-6) * np.maximum(wo[:, 2], 1e-6) * 0.5 / ln ** 3)[:, None]   # ρ -> f
    else:
        wi = x
        m = wi + wo
        m /= np.linalg.norm(m, axis=1, keepdims=True)
    A = lobe_albedo(np.sum(wo * m, 1), tb.alpha)
    with np.errstate(divide="ignore", invalid="ignore"):
        W = np.where(pk[:, None] > 0, f * (wi[:, 2] / p if tb.half else wfac)[:, None] / A[:, None], 0.0)
    return wi, m, W, p


def pdf(tb: ClosureTables, wi, wo) -> np.ndarray:
    """Density (1/sr) of the target ωi of ``sample`` for views wo (step 3 marginalised over the ωo node)."""
    wi, wo = _unit_rows("wi", wi), _unit_rows("wo", wo)
    res, cdf, N = tb.res, tb.cdf.astype(np.float64), len(wo)
    taps, wts, cph, sph = _view_taps(tb, wo)
    x = wi
    ok = np.ones(N, bool)
    Z = tb.extent if tb.half else 1.0
    if tb.half:                                                 # the density of h = normalize(ωi + ωo), then dωi
        x = wi + wo
        n = np.linalg.norm(x, axis=1, keepdims=True)
        ok = n[:, 0] > 1e-12
        x = x / np.where(ok[:, None], n, 1.0)
    wl = np.stack([cph * x[:, 0] + sph * x[:, 1], -sph * x[:, 0] + cph * x[:, 1], x[:, 2]], -1)
    st = hemi_oct_encode(wl)
    if getattr(tb, "centroid", None) is not None:               # the targets moved by Δ_o: the cell each came from
        st_k = st[:, None, :] - view_shifts(tb.centroid, taps, wts)
        ok_k = np.all(np.abs(st_k) <= 1.0, axis=2)
        c_k = np.clip(((st_k + 1.0) * 0.5 * res).astype(int), 0, res - 1)
        kk = c_k[..., 0] * res + c_k[..., 1]
        P = (cdf[taps, kk + 1] - cdf[taps, kk]) * wts * ok_k
        out = P.sum(1) / (4.0 / res ** 2 * jacobian(st))
        return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0), out, 0.0)
    ok &= np.all(np.abs(st) <= Z, axis=1)
    cell = np.clip(((st / Z + 1.0) * 0.5 * res).astype(int), 0, res - 1)
    k = cell[:, 0] * res + cell[:, 1]
    P = (cdf[taps, k[:, None] + 1] - cdf[taps, k[:, None]]) * wts
    out = P.sum(1) / (4.0 * Z * Z / res ** 2 * jacobian(st))
    if tb.half:
        out = out / (4.0 * np.maximum(np.abs(np.sum(wo * x, 1)), 1e-12))
    return np.where((wi[:, 2] > 0) & (wo[:, 2] > 0) & ok, out, 0.0)


# ----------------------------------------------------------------------------- the SVM / EEVEE twin
def _ggx_unit(wi, wo, alpha):
    """Cycles' GGX reflection (F = 1, height-correlated Smith G), standard BRDF in 1/sr."""
    return glossy_eval(wi, wo, alpha, "ggx")


def glossy_twin(brdf: TabulatedBRDF) -> dict:
    """A Diffuse + isotropic GGX Glossy approximation of ``brdf`` for render paths without OSL
    (Cycles SVM, GPU, EEVEE): ``{"diffuse": RGB, "specular": RGB, "alpha": GGX alpha, "rel_l1": fit
    error}``.  Least squares of f ≈ kd/π + ks·GGX_α over the ωo nodes with θo <= 60° and all ωi
    (weighted by cos θi), kd, ks >= 0 per channel, α from a log grid.  Not exact: the table closure is."""
    wo_nodes = brdf.view_nodes()
    keep = np.nonzero(wo_nodes[:, 2] >= 0.5)[0]
    if len(keep) == 0:
        keep = np.array([int(np.argmax(wo_nodes[:, 2]))])
    if getattr(brdf, "half", False):        # the table's own (ωi = reflect(ωo, h), ωo) pairs, ρ -> f
        h = direction_grid(brdf.res) * 1.0
        st = hemi_oct_encode(h) * brdf.extent
        h = hemi_oct_decode(st)
        Wo = np.repeat(wo_nodes[keep][None, :, :], len(h), 0)
        Wi, ok = reflect(Wo, np.repeat(h[:, None, :], len(keep), 1))
        Wi = np.where(ok[..., None], Wi, [0.0, 0.0, 1.0])
        om_h, omc_h = _half_cell_integrals(brdf, 2)
        omc = (omc_h[keep].T * np.maximum(Wi[..., 2], 0)) * ok     # cos θi dωi per pair
        y = brdf.table[:, keep, :] / (np.maximum(Wi[..., 2], 1e-6) * Wo[..., 2] * jacobian(st)[:, None])[..., None] \
            * ok[..., None]
        omc = omc * jacobian(st)[:, None]                     # ∫ ... ds dt -> ∫ ... dωh
        w = np.sqrt(omc)
    else:
        wi = direction_grid(brdf.res)
        _, omc = _cell_integrals(brdf.res, 4)
        Wi = np.repeat(wi[:, None, :], len(keep), 1)
        Wo = np.repeat(wo_nodes[keep][None, :, :], len(wi), 0)
        y = brdf.table[:, keep, :]                               # (Ni, K, 3)
        w = np.sqrt(omc)[:, None]                                # cos-weighted least squares
        omc = np.broadcast_to(omc[:, None], y.shape[:2])
    best = None
    for alpha in np.geomspace(0.01, 1.0, 25):
        g = _ggx_unit(Wi, Wo, alpha)
        Amat = np.stack([np.full_like(g, 1.0 / np.pi), g], -1) * w[..., None]
        coef = np.zeros((2, 3))
        for c in range(3):
            sol, *_ = np.linalg.lstsq(Amat.reshape(-1, 2), (y[..., c] * w).ravel(), rcond=None)
            if sol.min() < 0:   # clamp one term to zero and refit the other
                cands = []
                for j in (0, 1):
                    a = Amat.reshape(-1, 2)[:, j]
                    x = max(float(a @ (y[..., c] * w).ravel() / max(a @ a, 1e-30)), 0.0)
                    s2 = np.zeros(2)
                    s2[j] = x
                    cands.append((np.sum((Amat.reshape(-1, 2) @ s2 - (y[..., c] * w).ravel()) ** 2), s2))
                sol = min(cands, key=lambda t: t[0])[1]
            coef[:, c] = sol
        model = (np.stack([np.full_like(g, 1.0 / np.pi), g], -1)[..., None] * coef[None, None]).sum(-2)
        err = float(np.sum(np.abs(model - y) * omc[..., None]) / max(np.sum(y * omc[..., None]), 1e-30))
        if best is None or err < best[0]:
            best = (err, alpha, coef.copy())
    err, alpha, coef = best
    return {"diffuse": np.clip(coef[0], 0, 1), "specular": np.clip(coef[1], 0, 1), "alpha": float(alpha),
            "rel_l1": err}


# ----------------------------------------------------------------------------- the SVM node-graph twin
# ``node_groups/tabulated_svm.py`` renders the same closure with ordinary nodes (Cycles SVM, GPU, EEVEE):
# per-sample uniforms from White Noise, the ωi bin from an alias table (one Closest image lookup instead
# of the CDF walk), f from a padded image atlas (one Linear lookup), one narrow GGX Glossy node.  The
# functions below are its numpy twin: ``svm_images`` makes the images, ``sample_alias`` reads them the way
# Cycles does (``texture_closest`` / ``texture_linear``) with the graph's arithmetic.

def svm_constant(tb: ClosureTables) -> float:
    """c in the alias image's c / P_k: W = f qz c / (P_k len⁴) / A (c = cell² / 2 for ωi tables) or
    W = ρ (ωo·h) c / (ωo_z P_k) / A (c = 4 Z² cell² for half tables); ``sample_alias``."""
    cell = 2.0 / tb.res
    return 4.0 * tb.extent ** 2 * cell ** 2 if tb.half else 0.5 * cell ** 2


#: the graph drops the narrow lobe's albedo A when 1/A - 1 stays below this for θd <= 80° (ωi, ωo less than
#: 160° apart): 1/A - 1 = (r - 1)/(r + 1) ≈ α² tan² θd / 4, so below α ≈ 0.011 (tables of res >= 9 by default)
SVM_ALBEDO_TOL = 1e-3


def svm_uses_albedo(tb: ClosureTables) -> bool:
    """True if the node graph divides by the lobe albedo A (``lobe_albedo``); for the narrow default lobes A = 1
    to within ``SVM_ALBEDO_TOL`` wherever it matters, and the graph saves its eight nodes."""
    return bool(1.0 / lobe_albedo(np.cos(np.radians(80.0)), tb.alpha) - 1.0 > SVM_ALBEDO_TOL)


#: texels per axis of the SVM graph's view guide (``svm_view_guide``): x(a) is sampled every (a_{n-1} - a_0) / 4095
#: (0.042° for ±85°), exact at every sample and at both ends; between samples its linear interpolation misses
#: x(a) only in the sample interval around a node (a kink), by at most Δ/4 x the jump of the slope there
#: (``svm_view_guide_error``).
SVM_VIEW_GUIDE = 4096


def svm_view_guide(nodes, texels: int = SVM_VIEW_GUIDE):
    """The graph's guide of the view-grid pick on one axis: (x (texels,), scale, offset).  ``x[i]`` is the
    continuous node index of the angle a_i = a_0 + i (a_{n-1} - a_0) / (texels - 1) (piecewise linear between
    the increasing ``nodes``, radians: x(a_k) = k); the graph looks it up Linear / EXTEND at u = a scale +
    offset, which puts a_0 and a_{n-1} on the first and last texel centres: the clamp beyond the outermost
    nodes is the image's EXTEND, exactly ``view_taps``' clamp."""
    nodes = np.asarray(nodes, np.float64)
    G = int(texels)
    a = nodes[0] + np.arange(G) * ((nodes[-1] - nodes[0]) / (G - 1))
    x = np.interp(a, nodes, np.arange(len(nodes), dtype=np.float64))
    scale = (G - 1.0) / (G * (nodes[-1] - nodes[0]))
    return x, scale, 0.5 / G - nodes[0] * scale


def svm_view_guide_error(nodes, texels: int = SVM_VIEW_GUIDE) -> float:
    """Bound of |x_guide(a) - x(a)| (node-index units = interpolation weight) over all a: in the sample
    interval around node k, Δ/4 x |slope jump| (slopes 1 / (a_{k+1} - a_k)); when several nodes share a
    sample interval, the interval's own error (Δ x the largest slope, a crude bound)."""
    nodes = np.asarray(nodes, np.float64)
    d = (nodes[-1] - nodes[0]) / (texels - 1)
    slope = 1.0 / np.diff(nodes)
    jump = np.abs(np.diff(slope))
    if len(nodes) > 2 and np.min(np.diff(nodes)) < d:
        return float(d * slope.max())
    return float(0.25 * d * jump.max()) if len(jump) else 0.0


def svm_images(tb: ClosureTables) -> dict:
    """Float32 RGBA arrays (rows, cols, 4), row 0 at the bottom (Blender's pixel order), of the node graph:

    - ``"A"`` (n_o, D): row o = ωo node o's alias table (``alias_tables`` of ``tb.cdf``), texel (o, j):
      R = prob_j, G = alias_j - j, B = c / P_j, A = c / P_alias_j - c / P_j (c = ``svm_constant``; 0 for
      P = 0): one Closest lookup at ((j + 1/2) / D, (o + 1/2) / n_o), j = floor(h D), gives the bin and its 1/P_k;
    - ``"F"`` (n_o (res+2), res+2): tile o = rows [o (res+2), (o+1)(res+2)), texel (o (res+2) + 1 + a, 1 + b)
      = RGB F[a res + b, o] (ωi cell a along s, b along t), bordered by a copy of its edge texels so that
      a Linear lookup at ((1 + ck + h_t) / (res+2), (o (res+2) + 1 + rk + h_s) / H) is the clamped bilinear
      interpolation of ``sample`` inside node o's tile and never reads a neighbour tile.  View grids: a 2D atlas
      (NB (res+2), NA (res+2)), node o = ia NB + ib in tile column ia, row ib (``svm_atlas_tile``): texel
      (ib (res+2) + 1 + a, ia (res+2) + 1 + b), so the image side grows as √n_o and dense view grids fit;
    - ``"V"`` (view grids only; 2, ``SVM_VIEW_GUIDE``): row 0 R = the guide x(a) of ``view_a``, row 1 G = that of
      ``view_b`` (``svm_view_guide``; read Linear at heights 1/4 and 3/4, the rows' centres, the sum of the two
      colours is (xa, xb, 0)); other channels 0;
    - ``"K"`` (glossy floor per view, ``ks_view``; 1, n_o): RGB the glossy floor's colour at θo node o (read Linear
      at ((x + 1/2) / n_o, 1/2), x the continuous θo index: ``floor_ks``);
    - ``"C"`` (lobe-following view grids, ``centroid``; NB, NA): texel (ib, ia) RG = node (ia, ib)'s centroid (t, s) / cell
      in the graph's bin coordinates (g0 along t, g1 along s): a Linear read at ((xa + 1/2) / NA, (xb + 1/2) / NB) minus a
      Closest read at the drawn node's texel is the target's shift Δ_o (``view_shifts``)."""
    res, n_o, D = tb.res, tb.n_o, tb.res * tb.res
    cdf = tb.cdf.astype(np.float64)
    P = np.diff(cdf, axis=1)
    prob, alias = alias_tables(cdf)
    c = svm_constant(tb)
    inv = np.where(P > 0, c / np.where(P > 0, P, 1.0), 0.0)
    a = np.zeros((n_o, D, 4))
    a[..., 0], a[..., 1], a[..., 2] = prob, alias - np.arange(D), inv
    a[..., 3] = np.take_along_axis(inv, alias, 1) - inv
    F = tb.F.astype(np.float64).reshape(res, res, n_o, 3).transpose(2, 0, 1, 3)        # (o, a, b, rgb)
    F = np.pad(F, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
    R = res + 2
    f = np.zeros(svm_atlas_shape(tb) + (4,))
    if getattr(tb, "view_a", None) is not None:     # tile (ia, ib) at column ia, row ib
        NA, NB = len(tb.view_a), len(tb.view_b)
        f[..., :3] = F.reshape(NA, NB, R, R, 3).transpose(1, 2, 0, 3, 4).reshape(NB * R, NA * R, 3)
    else:
        f[..., :3] = F.reshape(n_o * R, R, 3)
    out = {"A": a.astype(np.float32), "F": f.astype(np.float32)}
    if getattr(tb, "view_a", None) is not None:
        v = np.zeros((2, SVM_VIEW_GUIDE, 4), np.float32)
        v[0, :, 0], v[1, :, 1] = svm_view_guide(tb.view_a)[0], svm_view_guide(tb.view_b)[0]
        out["V"] = v
    if getattr(tb, "ks_view", None) is not None:
        k = np.zeros((1, len(tb.ks_view), 4), np.float32)
        k[0, :, :3] = tb.ks_view
        out["K"] = k
    if getattr(tb, "centroid", None) is not None:
        NA, NB = len(tb.view_a), len(tb.view_b)
        c = np.zeros((NB, NA, 4), np.float32)
        cen = np.asarray(tb.centroid, np.float64).reshape(NA, NB, 2).transpose(1, 0, 2) / (2.0 / res)
        c[..., 0], c[..., 1] = cen[..., 1], cen[..., 0]
        out["C"] = c
    return out


def svm_atlas_shape(tb: ClosureTables) -> tuple:
    """(rows, cols) of the "F" atlas (``svm_images``): view grids (NB (res+2), NA (res+2)), else (n_o (res+2), res+2)."""
    R = tb.res + 2
    if getattr(tb, "view_a", None) is not None:
        return (len(tb.view_b) * R, len(tb.view_a) * R)
    return (tb.n_o * R, R)


def svm_atlas_tile(tb: ClosureTables, o) -> tuple:
    """Tile (column, row) of ωo node(s) ``o`` in the "F" atlas: view grids (o // NB, o % NB), else (0, o)."""
    o = np.asarray(o)
    if getattr(tb, "view_a", None) is not None:
        nb = len(tb.view_b)
        return o // nb, o % nb
    return np.zeros_like(o), o


def texture_closest(img, x, y) -> np.ndarray:
    """Cycles' Closest image lookup with extension EXTEND: texel (clamp(floor(y H)), clamp(floor(x W))) of
    ``img`` (H, W, C), x, y in [0, 1] (float32 products, as the kernel)."""
    H, W = img.shape[:2]
    ix = np.clip(np.floor(np.float32(x) * np.float32(W)).astype(np.int64), 0, W - 1)
    iy = np.clip(np.floor(np.float32(y) * np.float32(H)).astype(np.int64), 0, H - 1)
    return img[iy, ix]


def texture_linear(img, x, y) -> np.ndarray:
    """Cycles' Linear image lookup with extension EXTEND: bilinear between texel centres (i + 1/2) / W."""
    H, W = img.shape[:2]
    fx = np.asarray(x, np.float64) * W - 0.5
    fy = np.asarray(y, np.float64) * H - 0.5
    ix, iy = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    tx, ty = (fx - ix)[:, None], (fy - iy)[:, None]
    x0, x1 = np.clip(ix, 0, W - 1), np.clip(ix + 1, 0, W - 1)
    y0, y1 = np.clip(iy, 0, H - 1), np.clip(iy + 1, 0, H - 1)
    img = img.astype(np.float64)
    return ((1 - ty) * ((1 - tx) * img[y0, x0] + tx * img[y0, x1]) + ty * ((1 - tx) * img[y1, x0] + tx * img[y1, x1]))


def svm_view_index(tb: ClosureTables, wo, images: dict | None = None) -> np.ndarray:
    """View grids: the graph's continuous node indices (xa, xb) (N, 2) of views ``wo`` (N, 3): the projected
    angles a = atan2(ωx, ωz), b = atan2(ωy, ωz) mapped to the guide coordinate (``svm_view_guide``) and read
    by Cycles' Linear rule from the ``"V"`` image (row 0 R, row 1 G)."""
    V = (svm_images(tb) if images is None else images)["V"]
    ab = np.stack([np.arctan2(wo[:, 0], wo[:, 2]), np.arctan2(wo[:, 1], wo[:, 2])], -1).astype(np.float32)
    out = []
    for k, nodes in enumerate((tb.view_a, tb.view_b)):
        _, scale, offset = svm_view_guide(nodes)
        u = ab[:, k] * np.float32(scale) + np.float32(offset)
        out.append(texture_linear(V, u, np.full(len(wo), 0.25 + 0.5 * k))[:, k])
    return np.stack(out, -1)


def svm_view_node(tb: ClosureTables, wo, u0, u1, images: dict | None = None) -> np.ndarray:
    """The graph's ωo node (N,) for views ``wo`` (N, 3) (surface frame) and uniforms u0, u1: a node with
    probability equal to its interpolation weight (``_view_taps``), drawn as floor(x + u) per axis.
    Isotropic: x = clamp(θo / (π / 2 n_o) - 1/2, 0, n_o - 1), o = floor(x + u0).  Anisotropic: the
    hemi-octahedral (s, t) of ωo (|ωx| + |ωy| = max(|ωx + ωy|, |ωx - ωy|)), (xr, xc) = clamp((s, t) + 1) res / 2
    - 1/2, 0, res - 1), o = floor(xr + u0) res + floor(xc + u1): row and column drawn independently, so
    each of the four bilinear taps has its bilinear weight.  View grids: (xa, xb) from the guide image
    (``svm_view_index``), o = floor(xa + u0) NB + floor(xb + u1)."""
    if getattr(tb, "view_a", None) is not None:
        x = svm_view_index(tb, wo, images)
        return np.floor(x[:, 0] + u0).astype(np.int64) * len(tb.view_b) + np.floor(x[:, 1] + u1).astype(np.int64)
    if tb.iso:
        th = np.arccos(np.clip(wo[:, 2], -1.0, 1.0))
        x = np.clip((th / (0.5 * np.pi / tb.n_o) - 0.5) / (tb.n_o - 1.0), 0.0, 1.0)
        return np.floor(x * (tb.n_o - 1.0) + u0).astype(np.int64)
    A, B = wo[:, 0] + wo[:, 1], wo[:, 0] - wo[:, 1]
    d = np.maximum(np.abs(A), np.abs(B)) + wo[:, 2]
    xr = np.clip((A / d + 1.0) * 0.5 * tb.res - 0.5, 0.0, tb.res - 1.0)
    xc = np.clip((B / d + 1.0) * 0.5 * tb.res - 0.5, 0.0, tb.res - 1.0)
    return np.floor(xr + u0).astype(np.int64) * tb.res + np.floor(xc + u1).astype(np.int64)


def svm_alias_pick(images: dict, o, h):
    """The graph's bin pick: j = floor(h M), texel A[o, j] (Closest lookup at its centre), f = h M - j, the alias bin when
    prob_j < f.  Returns (bin k (N,), c / P_k (N,)); ``images`` from ``svm_images``."""
    A = images["A"]
    n_o, M = A.shape[:2]
    h = np.asarray(h, np.float32)
    uh = h * np.float32(M)
    j = np.floor(uh)
    t = texture_closest(A, (j + 0.5) / M, (np.asarray(o) + 0.5) / n_o)      # at the texel centre
    take = (t[:, 0] < uh - j).astype(np.float64)
    return (j + take * t[:, 1]).astype(np.int64), t[:, 2] + take * t[:, 3]


def sample_alias(tb: ClosureTables, wo, u, images: dict | None = None):
    """Numpy twin of the SVM node graph (``node_groups/tabulated_svm``): views ``wo`` (N, 3) (surface frame,
    z > 0), uniforms ``u`` (N, 5) = (h_o, h_o2, h_k, h_t, h_s) (two White Noise colours).  Same closure as
    ``sample``: the ωo node with its interpolation weight (``svm_view_node``), the ωi bin k with probability
    P_k (``svm_alias_pick``), the target jittered uniformly in bin k, m the micro-normal mirroring ωo into
    the target, W = f cos θi / (p A).  The graph's arithmetic: with g = (ck + h_t, rk + h_s),
    q = Z ((g0 + g1) cell / 2 - 1, (g1 - g0) cell / 2), v = (q, 1 - |qx| - |qy|), x the target (|v| = len),
    1/A = 2 r / (1 + r), r = √(1 - α² + α² / (ωo·m)²) (taken as 1 when ``svm_uses_albedo`` is False);
    ωi tables W = f qz cell² / (2 P_k len⁴ A), half tables W = ρ (ωo·h) 4 Z² cell² / (ωo_z P_k A) [ωi above the
    horizon]; f (ρ) from the Linear lookup of the ``"F"`` atlas.  Returns (ωi (N, 3), m (N, 3), W (N, 3), p (N,)) as ``sample``."""
    wo = _unit_rows("wo", wo)
    u = np.atleast_2d(np.asarray(u, np.float64))
    if u.shape != (len(wo), 5):
        raise ValueError(f"u: expected shape ({len(wo)}, 5), got {u.shape}")
    images = svm_images(tb) if images is None else images
    res, n_o, cell = tb.res, tb.n_o, 2.0 / tb.res
    Z = tb.extent if tb.half else 1.0
    o = svm_view_node(tb, wo, u[:, 0], u[:, 1], images)
    k, invP = svm_alias_pick(images, o, u[:, 2])
    shift = getattr(tb, "centroid", None) is not None
    rk = np.floor((k + 0.5) / res)
    ck = k - res * rk
    g0, g1 = ck + u[:, 3], rk + u[:, 4]
    Fimg = images["F"]
    tx, ty = svm_atlas_tile(tb, o)
    f = texture_linear(Fimg, (tx * (res + 2) + 1.0 + g0) / Fimg.shape[1],
                       (ty * (res + 2) + 1.0 + g1) / Fimg.shape[0])[:, :3]
    qx, qy = Z * ((g0 + g1) * cell / 2 - 1.0), Z * (g1 - g0) * cell / 2
    qz = 1.0 - np.abs(qx) - np.abs(qy)
    if shift:                                       # the target moved by Δ_o = C Linear at (xa, xb) - C Closest at the node
        C = images["C"]
        xab = svm_view_index(tb, wo, images)
        ia, ib = np.floor(xab[:, 0] + u[:, 0]), np.floor(xab[:, 1] + u[:, 1])
        dg = (texture_linear(C, (xab[:, 0] + 0.5) / C.shape[1], (xab[:, 1] + 0.5) / C.shape[0])
              - texture_closest(C, (ia + 0.5) / C.shape[1], (ib + 0.5) / C.shape[0]))
        g0s, g1s = g0 + dg[:, 0], g1 + dg[:, 1]
        qx2, qy2 = (g0s + g1s) * cell / 2 - 1.0, (g1s - g0s) * cell / 2
        qz2 = 1.0 - np.abs(qx2) - np.abs(qy2)
    if tb.iso:                                      # the frame turned about n so that ωo has azimuth 0
        fy = np.stack([-wo[:, 1], wo[:, 0] + 1e-6, np.zeros(len(wo))], -1)     # n x (ωo + 1e-6 t)
        fy /= np.linalg.norm(fy, axis=1, keepdims=True)
        fx = np.stack([fy[:, 1], -fy[:, 0], np.zeros(len(wo))], -1)             # fy x n
    else:
        fx, fy = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])
    x = qx[:, None] * fx + qy[:, None] * fy + qz[:, None] * np.array([0, 0, 1.0])
    L2 = np.sum(x * x, 1)
    ln = np.sqrt(L2)
    P = tb.cdf.astype(np.float64)[o, k + 1] - tb.cdf.astype(np.float64)[o, k]
    p = P / (Z * Z * cell * cell * 0.5 / ln ** 3)
    a2 = tb.alpha ** 2
    if tb.half:
        h = x / ln[:, None]
        oh = np.sum(wo * h, 1)
        iz = 2.0 * oh * qz / ln - wo[:, 2]
        wi, m, cd = 2.0 * oh[:, None] * h - wo, h, oh
        s = oh * (iz > 0) / wo[:, 2] * invP
        p = p / (4.0 * np.abs(oh))
    else:
        wi = x / ln[:, None]
        s = qz / (L2 * L2) * invP
        if shift:                                   # weight of the drawn point, direction of the moved one (above the horizon)
            x = qx2[:, None] * fx + qy2[:, None] * fy + qz2[:, None] * np.array([0, 0, 1.0])
            ln = np.linalg.norm(x, axis=1)
            wi = x / ln[:, None]
            s = s * (qz2 > 0)
            p = P / (cell * cell * 0.5 / ln ** 3)
        m = x + ln[:, None] * wo
        m /= np.linalg.norm(m, axis=1, keepdims=True)
        cd = np.sum(wo * m, 1)
    if svm_uses_albedo(tb):                         # 1/A = 2 r / (1 + r), r = √(1 - α² + α² / cd²)
        r = np.sqrt(1.0 - a2 + a2 / np.where(cd != 0, cd * cd, np.inf))
        s = s * 2.0 * r / (1.0 + r)
    return wi, m, f * s[:, None], p


__all__ += ["alias_tables", "alias_pmf", "svm_constant", "svm_uses_albedo", "SVM_ALBEDO_TOL", "svm_images", "texture_closest", "texture_linear",
            "svm_view_node", "svm_alias_pick", "sample_alias", "SVM_VIEW_GUIDE", "svm_view_guide",
            "svm_view_guide_error", "svm_view_index"]
