"""Generator of the specialised OSL iridescent scratch layer (Velinov, Werner & Hullin 2018; Werner et al. 2017).

The shader itself is ``osl/iridescent_layer.osl`` (its file header documents sockets, flags and
tables); ``generate`` writes one scratch set's flags and tables into it (``osl.specialise``).
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
  eqs. 36-41; a port of ``precompute.iridescence.lights``) for the lights compiled into the
  shader (``SphereLightSpec``/``PolygonLightSpec`` in world space, radiance in W/m²/sr).  The
  result is radiance, returned as ``emission()``: Cycles' NEE never sees it (no BSDF, no double
  counting with the lights it also samples for the base), BSDF rays cannot bounce off it, and
  the material must use ``emission_sampling = 'NONE'`` so the object is not sampled as a light.
  Shadows (``shadows``, default on): one ``trace()`` per light and sample toward a uniformly
  chosen point of the light (sphere: its disk facing P; polygon: area-weighted fan triangle), an
  unbiased soft-shadow visibility estimate.  No world light, no indirect light in the scratches;
  light edits need a rebuild.

Segment selection (``candidates``, both routes): 0 = every segment listed in the shading point's
reach-grid cell (exact; cost ∝ scratch density).  N > 0 (default 4) = N stratified draws from the
cell's point-independent bound distribution (``candidate_weights``: upper bounds of |η_s|² and ρ_m
over the cell, quantised to exact integer probabilities packed with the segment index), each
evaluated exactly and weighted 1/(N p): route A resamples the lobes among them by their proxy mass
(RIS, Rtot = Σ r_i replaces ΣH), route B sums their closed forms, ρ̂ = Σ ρ_i/(N p_i).  All three
are unbiased (tests/test_iridescent_layer_osl.py replays the stage in numpy); cost is O(N log n), and a
segment drawn by consecutive strata is evaluated once (route A).  Route A estimates the energy the
scratches take (the base weight, ``precompute.iridescence.energy``) from its lobe's segment: one
propagating fraction per lobe, not per candidate.

Shading points whose reach-grid cell is empty (no segment within 3σ of any point of the cell)
do one table lookup and return ``Base`` unchanged.
"""
from __future__ import annotations

import numpy as np

from ..precompute.iridescence import energy
from ..precompute.iridescence.layer import (LOBE_ALPHA, NS, REACH_SIGMA, LayerSpec, PolygonLightSpec, SphereLightSpec,
                                           shader_tables)
from . import const_array, specialise


def generate(spec: LayerSpec) -> str:
    """OSL source of the specialised layer shader for ``spec`` (validated first):
    ``iridescent_layer.osl`` with the scratch set's flags and tables (see ``osl.specialise``)."""
    spec.validate()
    tab = shader_tables(spec)
    grid = tab["grid"]
    maxc = max(grid.max_per_cell, 1)
    nstore = int(spec.candidates) if spec.candidates > 0 else maxc
    lights = spec.lights if spec.route == "lights" else []
    spheres = [L for L in lights if isinstance(L, SphereLightSpec)]
    polys = [L for L in lights if isinstance(L, PolygonLightSpec)]
    lam = [float(x) for x in spec.wavelengths_um]
    flags = dict(SHADER_NAME=spec.name, SIGMA=float(spec.sigma_um), UV_SCALE=float(spec.scratches.uv_scale_um),
                 REACH=REACH_SIGMA * spec.sigma_um, NS=NS, QBITS=int(tab["qbits"]), QMASK=(1 << tab["qbits"]) - 1,
                 NCAND=int(spec.candidates), NSTORE=nstore, KS=int(spec.samples), LOBE_ALPHA=LOBE_ALPHA,
                 GO_U=float(grid.origin[0]), GO_V=float(grid.origin[1]), CELL=float(grid.cell), NX=int(grid.nx),
                 NY=int(grid.ny), NSPH=len(spheres), NPOLY=len(polys), NLIGHT=len(spheres) + len(polys),
                 ROUTE_LIGHTS=spec.route == "lights", BASE_BLEND=bool(spec.base_blend),
                 BASE_PAPER=bool(spec.base_blend) and spec.base_weight == "paper",
                 SHADOWS=spec.route == "lights" and bool(spec.shadows) and bool(lights), KNEE=energy.KNEE)
    tables = [const_array("SEG", tab["segments"]),
              const_array("CSTART", grid.start, "int", per_line=16),
              const_array("CITEMS", tab["packed"], "int", per_line=16),
              f"    float LAM[3] = {{{lam[0]:.9g}, {lam[1]:.9g}, {lam[2]:.9g}}};\n",
              "    float KL[3] = {" + ", ".join(f"{2 * np.pi / x:.9g}" for x in lam) + "};   // 2π/λ (1/µm)\n"]
    if spheres:
        tables.append(const_array("SPH", [v for L in spheres for v in (*L.center, L.radius, *L.radiance)]))
    if polys:
        nv = [len(L.vertices) for L in polys]
        tables.append(const_array("PSTART", np.concatenate([[0], np.cumsum(nv)]), "int"))
        tables.append(const_array("PVERT", np.asarray([v for L in polys for v in L.vertices], float).ravel()))
        tables.append(const_array("PRAD", [v for L in polys for v in L.radiance]))
        tables.append(const_array("PTWO", [int(L.two_sided) for L in polys], "int"))
    return specialise("iridescent_layer.osl", flags, {"iridescent_layer_tables.h": "".join(tables)},
                      f"osl/iridescent_layer.py (route {spec.route!r}, {len(spec.scratches.width_um)} segments)")
