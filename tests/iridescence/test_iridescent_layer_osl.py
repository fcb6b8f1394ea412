"""Generator of the iridescent-layer OSL shader (osl/iridescent_layer.py), without Blender.

References: scipy's sine integral, brute-force segment/point distances for the reach grid,
the route-A sampling maths checked against quadrature of the model's sinc² term, and the
candidate (RIS) stage replayed in numpy from the generated tables against the brute-force
sums of ``precompute.iridescence`` (|η_s|², ρ) over every segment within 3σ."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import integrate, special

from scratch_materials.osl import iridescent_layer as il
from scratch_materials.precompute.iridescence import energy as en
from scratch_materials.precompute.iridescence import layer as ly
from scratch_materials.precompute.iridescence import model as ir
from scratch_materials.precompute.iridescence.model import RGB_WAVELENGTHS_UM, SIGMA_UM
from scratch_materials.precompute.iridescence.scratch_set import ScratchSet, point_segment_distance, random_scratches


def test_constants_match_numpy_model():
    assert np.allclose(ly.RGB_WAVELENGTHS_UM, RGB_WAVELENGTHS_UM) and ly.SIGMA_UM == SIGMA_UM


def test_si_float32_twin_matches_scipy():
    # The shader's Si (float32 Taylor + fitted auxiliary functions) against double-precision sici:
    # float32 rounding of the ~π/2 result is 1e-7, fit error 1.4e-6 → 5e-6 is tight.
    x = np.concatenate([np.linspace(-60, 60, 40001), np.geomspace(60, 1e5, 2000), -np.geomspace(60, 1e5, 50)])
    err = np.abs(ly.si_float32(x) - special.sici(x)[0])
    assert err.max() < 5e-6, err.max()
    # Eq. 29's approximation is 100x worse; make sure the test could tell them apart
    from scratch_materials.precompute.iridescence.model import si_approx
    assert np.abs(si_approx(x[:40001]) - special.sici(x[:40001])[0]).max() > 1e-3


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 60), st.floats(0.002, 0.05), st.integers(0, 10_000))
def test_reach_grid_cell_holds_every_segment_in_reach(count, reach, seed):
    S = random_scratches(count, length_range=(0.0, 0.2), seed=seed)
    g = ly.reach_grid(S.p0, S.p1, reach)
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.1, 1.1, (400, 2))
    d = point_segment_distance(q[:, None], S.p0[None], S.p1[None])          # brute force (400, M)
    ix = np.floor((q - g.origin) / g.cell).astype(int)
    inside = (ix[:, 0] >= 0) & (ix[:, 1] >= 0) & (ix[:, 0] < g.nx) & (ix[:, 1] < g.ny)
    for i in range(q.shape[0]):
        near = set(np.nonzero(d[i] <= reach)[0])
        if not inside[i]:
            assert not near          # outside the grid nothing is in reach
            continue
        cell = ix[i, 1] * g.nx + ix[i, 0]
        assert near <= set(g.items[g.start[cell]:g.start[cell + 1]].tolist())
    assert g.nx * g.ny <= ly.MAX_CELLS


def test_route_a_proxy_has_the_model_mass_and_bounded_weight():
    # h = 1/(1 + (ξ/s)²), s = λ/(πW) has the same integral over ℝ as sinc²(πWξ/λ) (= λ/W) and
    # sinc²/h ≤ 1.5: the one-sample weights stay bounded (low variance, never infinite).
    for W, lam in [(0.8, 0.465), (6.0, 0.63), (2.5, 0.532)]:
        s = lam / (np.pi * W)
        # ∫ sinc²(πu) du over |u| ≤ X is 1 − 1/(π²X) + O(X⁻²) (tail: ⟨sin²⟩ = ½ times the 1/(πu)² envelope)
        X = 1000.0
        u = np.linspace(-X, X, 4_000_001)
        sinc2 = integrate.trapezoid(np.sinc(u) ** 2, u) * lam / W
        assert abs(sinc2 - (1 - 1 / (np.pi ** 2 * X)) * lam / W) < 1e-5 * lam / W
        assert np.isclose(np.pi * s, lam / W)
        x = np.linspace(-3, 3, 200001)
        ratio = np.sinc(W * x / lam) ** 2 * (1 + (x / s) ** 2)
        assert ratio.max() < 1.5


def test_generated_source_features():
    S = random_scratches(20, seed=3, uv_scale_um=1e4)
    a = il.generate(ly.LayerSpec(S))
    assert "#define ROUTE_LIGHTS 0" in a and "#define BASE_BLEND 1" in a and "#define NSPH 0" in a
    assert "closure color Base" in a and "point UV" in a and "vector Tangent" in a and "output closure color BSDF" in a
    lights = [ly.SphereLightSpec((0, 0, 2), 0.1, (1, 1, 1)),
              ly.PolygonLightSpec(((0, 0, 2), (0, 1, 2), (1, 1, 2)), (2, 2, 2))]
    b = il.generate(ly.LayerSpec(S, route="lights", lights=lights, base_blend=False))
    assert "#define ROUTE_LIGHTS 1" in b and "#define NSPH 1" in b and "#define NPOLY 1" in b and "#define BASE_BLEND 0" in b
    empty = il.generate(ly.LayerSpec(random_scratches(0)))
    assert "#define NCAND 4" in empty and "#define NSTORE 4" in empty
    assert "#define NCAND 0" in il.generate(ly.LayerSpec(S, candidates=0))


@pytest.mark.parametrize("kw, match", [
    (dict(sigma_um=0.0), "sigma_um"), (dict(sigma_um=np.nan), "sigma_um"), (dict(route="magic"), "route"),
    (dict(samples=0), "samples"), (dict(samples=2.5), "samples"), (dict(name="bad name"), "name"),
    (dict(candidates=-1), "candidates"), (dict(candidates=ly.MAX_CANDIDATES + 1), "candidates"),
    (dict(candidates=True), "candidates"),
    (dict(wavelengths_um=(0.5, 0.6)), "wavelengths_um"),
    (dict(lights=[ly.SphereLightSpec((0, 0, 1), 0.0, (1, 1, 1))]), "radius"),
    (dict(lights=[ly.SphereLightSpec((0, 0, 1), 0.1, (1, -1, 1))]), "radiance"),
    (dict(lights=[ly.PolygonLightSpec(((0, 0, 1), (1, 0, 1)), (1, 1, 1))]), "vertices"),
    (dict(lights=["sun"]), "SphereLightSpec"),
])
def test_bad_parameters_raise_clear_errors(kw, match):
    S = random_scratches(5, seed=0)
    with pytest.raises(ValueError, match=match):
        il.generate(ly.LayerSpec(S, **kw))
    with pytest.raises(ValueError, match="ScratchSet"):
        il.generate(ly.LayerSpec(object()))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.3, 3.0))
def test_segment_box_distance_matches_brute_force(seed, size):
    rng = np.random.default_rng(seed)
    p0, p1 = rng.uniform(-2, 2, (50, 2)), rng.uniform(-2, 2, (50, 2))
    p1[:5] = p0[:5]                                          # degenerate segments (points)
    p1[5:10, 0] = p0[5:10, 0]                                # axis-parallel
    lo = rng.uniform(-1, 1, (50, 2))
    hi = lo + size
    d = ly.segment_box_distance(p0, p1, lo, hi)
    # brute force: dense samples on the segment, distance to the box
    t = np.linspace(0, 1, 4001)[:, None, None]
    q = p0 + t * (p1 - p0)
    ref = np.linalg.norm(q - np.clip(q, lo, hi), axis=2).min(0)
    assert np.all(d <= ref + 1e-9)                           # never more than the true distance (reach kept)
    assert np.allclose(d, ref, atol=4.0 * 4.0 / 4000)        # sampling step of the brute force


def _replay_candidates(spec, uv, trials, rng, wo=None):
    """numpy replay of the shader's RIS candidate stage (cell lookup, stratified quanta, binary
    search, weights 1/(NCAND p)) from the generated tables: per point and trial
    R = Σ_i w_i |η_s|²_i Hbar_sum_i, ρ̂ = Σ_i w_i ρ_i and (with views ``wo`` (P, 3) in the UV frame)
    Ê = R Hbar_i F_i / Hbar_sum_i of the candidate i picked ∝ r_i for the lobe (the energy estimate, the shader's
    ``energy_share`` of route A), (P, trials, 3)."""
    tab = ly.shader_tables(spec)
    g, packed, qb = tab["grid"], tab["packed"], tab["qbits"]
    seg = tab["segments"].reshape(-1, ly.NS).astype(np.float64)
    Q, K, sig = 1 << qb, spec.candidates, spec.sigma_um
    ix = np.floor((uv - g.origin) / g.cell).astype(int)
    inside = (ix >= 0).all(1) & (ix[:, 0] < g.nx) & (ix[:, 1] < g.ny)
    cell = np.where(inside, ix[:, 1] * g.nx + ix[:, 0], 0)
    c0, c1 = g.start[cell], np.where(inside, g.start[cell + 1], g.start[cell])
    x = uv * spec.scratches.uv_scale_um
    R = np.zeros((uv.shape[0], trials))
    rho = np.zeros_like(R)
    E = np.zeros(R.shape + (3,))
    r_i, e_i = np.zeros((K,) + R.shape), np.zeros((K,) + R.shape + (3,))   # per candidate: r, Hbar F / Hbar_sum
    lam = np.asarray(spec.wavelengths_um, np.float32)
    ends = packed & (Q - 1)
    for i in range(uv.shape[0]):
        e = ends[c0[i]:c1[i]]
        uc = rng.random(trials)
        if e.size == 0:                  # no segment within reach of the cell: the shader returns Base
            continue
        for ci in range(K):
            k = np.minimum(((ci + uc) / K * Q).astype(np.int64), Q - 1)
            j = np.searchsorted(e, k, side="left")                       # first end >= k
            q = e[j] - np.where(j > 0, e[np.maximum(j - 1, 0)], -1)
            w = Q / (K * q)
            m = packed[c0[i] + j] >> qb
            tu, tv, ct, cb, L = seg[m, 0], seg[m, 1], seg[m, 2], seg[m, 3], seg[m, 4]
            sb = tv * x[i, 0] - tu * x[i, 1] + cb
            st1 = ct - (tu * x[i, 0] + tv * x[i, 1])
            st2 = st1 + L
            gap = np.maximum(0.0, np.maximum(st1, -st2))
            inr = sb ** 2 + gap ** 2 <= (ly.REACH_SIGMA * sig) ** 2
            e2 = np.exp(-sb ** 2 / (2 * sig ** 2))
            eta = np.pi * sig ** 2 * e2 ** 2 * (special.erf(st2 / sig) - special.erf(st1 / sig))
            r_i[ci, i] = np.where(inr, w * eta * seg[m, 9], 0.0)
            R[i] += r_i[ci, i]
            rho[i] += np.where(inr, w * seg[m, 10] * e2 * (special.erf(st2 / (np.sqrt(2) * sig))
                                                         - special.erf(st1 / (np.sqrt(2) * sig))), 0.0)
            if wo is not None:
                ot, ob = tu * wo[i, 0] + tv * wo[i, 1], tu * wo[i, 1] - tv * wo[i, 0]
                rr = np.sqrt(np.maximum(0.0, 1.0 - ot * ot))[:, None]
                kW = 2 * np.pi * seg[m, 5][:, None] / lam
                F = np.clip(1 - en.tail_fraction(kW * (rr + ob[:, None])) - en.tail_fraction(kW * (rr - ob[:, None])), 0, 1)
                e_i[ci, i] = seg[m, 6:9] * F / seg[m, 9][:, None]
        if wo is not None:
            # the lobe's segment: candidate i with probability r_i / R (the shader's stratified pick, KS = 1);
            # Ê = R Hbar_i F_i / Hbar_sum_i (its expected albedo given the candidates and the segment)
            y = rng.random(trials) * R[i]
            pick = np.minimum((np.cumsum(r_i[:, i], 0) <= y[None]).sum(0), K - 1)
            E[i] = R[i][:, None] * e_i[pick, i, np.arange(trials)]
    return (R, rho, E) if wo is not None else (R, rho)


@pytest.mark.parametrize("count, domain", [(1200, (0.4, 0.4, 0.6, 0.6)), (150, (0.0, 0.0, 1.0, 1.0))])
def test_ris_candidate_stage_is_unbiased(count, domain):
    # The closure weight of route A is R·g(ξ₂)/(KS·h(ξ₂)) and the base blend 1 − ρ̂: both unbiased iff
    # E[R] = Σ_m |η_s|²_m Σ_c Hbar_c,m and E[ρ̂] = Σ_m ρ_m over every segment within 3σ (the numpy
    # model's reach).  Reference: precompute.iridescence's eta_s_sq / area_density_point / depth_term,
    # brute force over all segments (independent of the grid, the bound and the packing).
    S = random_scratches(count, length_range=(0.05, 0.15), domain=domain, uv_scale_um=2e4, seed=count)
    spec = ly.LayerSpec(S, candidates=4).validate()
    rng = np.random.default_rng(1)
    lo, hi = np.asarray(domain[:2]), np.asarray(domain[2:])
    uv = lo + (hi - lo) * rng.random((60, 2))
    R, rho = _replay_candidates(spec, uv, 1500, rng)
    sc, sig = S.uv_scale_um, spec.sigma_um
    x = uv * sc
    s_b, s1, s2 = ir.scratch_coords(x[:, None], S.p0[None] * sc, S.p1[None] * sc)
    d = point_segment_distance(uv[:, None], S.p0[None], S.p1[None]) * sc
    inr = d <= ly.REACH_SIGMA * sig
    eta = np.where(inr, ir.eta_s_sq(s_b, sig, s1, s2), 0.0)
    lam = np.asarray(RGB_WAVELENGTHS_UM)
    Hs = (S.width_um[:, None] * ir.depth_term(S.depth_um[:, None], lam[None])).sum(1) \
        / (2 * np.sqrt(np.pi) * sig * np.pi * sig ** 2)        # Σ_c H_c / |η_s|² = Σ_c W|𝒟|²/(2√π σ A_C)
    R_ref = (eta * Hs[None]).sum(1)
    rho_ref = np.where(inr, ir.area_density_point(S.width_um[None], s_b, s1, s2, sig), 0.0).sum(1)
    for est, ref in ((R, R_ref), (rho, rho_ref)):
        mean, se = est.mean(1), est.std(1) / np.sqrt(est.shape[1])
        assert np.all(np.isfinite(est)) and np.all(est >= 0)
        # per point: within 5 standard errors (+ float32 tables); overall: within 1 %
        assert np.all(np.abs(mean - ref) <= 5 * se + 1e-4 * ref + 1e-12), np.max(np.abs(mean - ref) / (se + 1e-30))
        assert abs(mean.sum() / ref.sum() - 1) < 0.01
    assert R_ref.max() > 0 and rho_ref.max() > 0


def test_candidate_distribution_is_exact_and_covers_every_listed_segment():
    S0 = random_scratches(400, length_range=(0.0, 0.3), seed=5, uv_scale_um=1e4)
    p1 = S0.p1.copy()
    p1[:3] = S0.p0[:3]                                       # zero-length: dropped, contribute nothing
    S = ScratchSet(S0.p0, p1, S0.width_um, S0.depth_um, S0.uv_scale_um)
    tab = ly.shader_tables(ly.LayerSpec(S))
    g, q = tab["grid"], tab["quanta"]
    cid = np.repeat(np.arange(g.nx * g.ny), np.diff(g.start))
    tot = np.bincount(cid, weights=q, minlength=g.nx * g.ny)
    assert q.min() >= 1                                      # every listed segment can be drawn
    assert np.all(tot[np.diff(g.start) > 0] == 1 << tab["qbits"])
    assert not set(range(3)) & set(g.items.tolist())


@pytest.mark.parametrize("count, domain, th", [(1200, (0.4, 0.4, 0.6, 0.6), 60.0), (150, (0.0, 0.0, 1.0, 1.0), 10.0)])
def test_energy_estimate_is_unbiased(count, domain, th):
    # The shader weights the base by 1 − N(Ê) and its lobes by N(Ê)/Ê with Ê = R Hbar_i F_i / Hbar_sum_i of the
    # lobe's segment i (picked ∝ r_i among the RIS candidates): E[Ê] must be the numpy model's E (``evaluate(...).energy``: every segment in
    # reach, exact erf, float64, the same rational tail).
    S = random_scratches(count, length_range=(0.05, 0.15), domain=domain, uv_scale_um=2e4, seed=count + 1)
    spec = ly.LayerSpec(S, candidates=4).validate()
    rng = np.random.default_rng(2)
    lo, hi = np.asarray(domain[:2]), np.asarray(domain[2:])
    uv = lo + (hi - lo) * rng.random((40, 2))
    a = rng.uniform(0, 2 * np.pi, 40)
    t = np.radians(th)
    wo = np.stack([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), np.full(40, np.cos(t))], 1)
    _, _, E = _replay_candidates(spec, uv, 1500, rng, wo)
    ref = ir.evaluate(S, uv, wo, ir.SphereLight(np.array([0.5, 0.5, 5.0]), 0.1)).energy
    mean, se = E.mean(1), E.std(1) / np.sqrt(E.shape[1])
    assert np.all(np.abs(mean - ref) <= 5 * se + 1e-4 * ref + 1e-12), np.max(np.abs(mean - ref) / (se + 1e-30))
    assert abs(mean.sum() / ref.sum() - 1) < 0.01 and ref.max() > 0.05


def test_shader_energy_constants_are_the_numpy_twins():
    import re

    from scratch_materials import osl
    src = osl.read_source("iridescent_layer.osl")
    body = re.search(r"void tail_nd\(color x, output color nu, output color de\)\s*\{(.*?)\n\}", src, re.S).group(1)
    nums = [float(v) for v in re.findall(r"-?\d+\.\d+", body)]
    a1, a2, b1, b2 = en.TAIL_COEF
    assert nums == [0.0, 1.0, a1, a2, 2.0, b1, b2, a2]             # max(x, 0.0), then the rational
    assert f"#define KNEE {en.KNEE}" in src
    gen = il.generate(ly.LayerSpec(random_scratches(5, seed=1)))
    assert f"#define KNEE {en.KNEE}" in gen and "#define BASE_PAPER 0" in gen
    assert "#define BASE_PAPER 1" in il.generate(ly.LayerSpec(random_scratches(5, seed=1), base_weight="paper"))
    with pytest.raises(ValueError, match="base_weight"):
        il.generate(ly.LayerSpec(random_scratches(5, seed=1), base_weight="alpha"))
