"""The tabulated-BRDF closure (``precompute.tables.tabulated_brdf``), as Mitsuba 3 tests its BSDFs:
chi-square of the sampler against its density, sample / eval / pdf consistency, white furnace,
reciprocity, the Diffuse+Glossy twin fit, and input errors.  Pure numpy (the shader's numpy twin)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from scratch_materials.precompute.tables import tabulated_brdf as tb
from scratch_materials.osl import tabulated_brdf as gen


def ggx_plus_diffuse(alpha=0.25, ks=0.9, kd=(0.05, 0.1, 0.2)):
    """A reciprocal analytic BRDF (Cycles' GGX with F = 1 plus Lambert), 1/sr."""
    def f(wi, wo):
        return ks * tb._ggx_unit(wi, wo, alpha)[:, None] * np.ones(3) + np.asarray(kd) / np.pi
    return f


def aniso_brdf(wi, wo):
    """A reciprocal anisotropic BRDF: brighter towards +x, a stretched lobe around the mirror direction."""
    r = np.stack([-wo[:, 0], -wo[:, 1], wo[:, 2]], -1)
    d = wi - r
    lobe = np.exp(-(d[:, 0] / 0.35) ** 2 - (d[:, 1] / 0.12) ** 2)
    v = 0.08 + 0.15 * (np.maximum(wi[:, 0], 0) + np.maximum(wo[:, 0], 0)) + 1.5 * lobe
    return v[:, None] * np.array([1.0, 0.8, 0.6])


@pytest.fixture(scope="module")
def tables():
    out = {"aniso": tb.TabulatedBRDF.from_function(aniso_brdf, 10),
            "iso": tb.TabulatedBRDF.from_function(ggx_plus_diffuse(), 12, iso=True, n_theta=12),
            # half-vector tables (h grid zoomed to the lobe): a sharp anisotropic lobe, and an isotropic GGX
            "half": tb.TabulatedBRDF.from_function(aniso_brdf, 10, sub=2, half=True, extent=0.8),
            "iso_half": tb.TabulatedBRDF.from_function(ggx_plus_diffuse(alpha=0.08, kd=(0, 0, 0)), 12, iso=True,
                                                       n_theta=12, sub=3, half=True, extent=0.5),
            # a view grid in the projected view angles, warped (an event at a = 0.4 rad), denser in a than b
            "view": tb.TabulatedBRDF.from_function(aniso_brdf, 10, view_a=tb.view_grid_nodes(13, [0.4]),
                                                   view_b=tb.view_grid_nodes(9))}
    # the same view grid interpolated by following the lobe (``view_shift``: targets moved by the centroid shift)
    v = out["view"]
    out["view_shift"] = tb.TabulatedBRDF(v.table, v.res, view_a=v.view_a, view_b=v.view_b, view_shift=True)
    return out


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def chi2_directions(T, wi, wo, n, nt=10, npf=20, total=True):
    """p-value of the chi-square test of sampled directions ``wi`` (of ``n`` draws) against ``pdf`` (at ``wo``)
    on nt x npf bins in (cos θ, φ); bins with expected count < 5 merged into one.  ``total``: also check that
    the density integrates to one over the upper hemisphere (not for half-vector tables, whose reflections
    can leave it)."""
    mu = np.clip(wi[:, 2], 0, 1 - 1e-12)
    ph = np.mod(np.arctan2(wi[:, 1], wi[:, 0]), 2 * np.pi)
    obs = np.histogram2d(mu, ph, [np.linspace(0, 1, nt + 1), np.linspace(0, 2 * np.pi, npf + 1)])[0].ravel()
    sub = 12                                                  # midpoint rule inside each bin
    m = (np.arange(nt * sub) + 0.5) / (nt * sub)
    p = (np.arange(npf * sub) + 0.5) / (npf * sub) * 2 * np.pi
    M, PH = np.meshgrid(m, p, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    w = np.stack([s * np.cos(PH), s * np.sin(PH), M], -1).reshape(-1, 3)
    dens = tb.pdf(T, w, np.repeat(wo[None], len(w), 0)).reshape(nt, sub, npf, sub)
    exp = dens.sum((1, 3)).ravel() * (1.0 / (nt * sub)) * (2 * np.pi / (npf * sub)) * n
    if total:
        assert abs(exp.sum() / n - 1) < 0.01                  # the density integrates to one
    big = exp >= 5
    o = np.append(obs[big], obs[~big].sum())
    e = np.append(exp[big], exp[~big].sum())
    e *= o.sum() / e.sum()
    chi2 = ((o - e) ** 2 / np.maximum(e, 1e-12)).sum()
    return stats.chi2.sf(chi2, len(o) - 1)


def _chi2_pvalue(brdf, wo, wo_sampled=None, n=40000, seed=0, nt=10, npf=20):
    """``chi2_directions`` of ``sample`` (at ``wo_sampled``) against ``pdf`` (at ``wo``)."""
    T = tb.closure_tables(brdf)
    wo_s = wo if wo_sampled is None else wo_sampled
    wi, _, _, _ = tb.sample(T, np.repeat(wo_s[None], n, 0), np.random.default_rng(seed).random((n, 4)))
    return chi2_directions(T, wi, wo, n, nt, npf)


@pytest.mark.parametrize("kind, wo", [("aniso", (0.45, 0.2, 0.8)), ("aniso", (-0.9, 0.1, 0.3)),
                                      ("iso", (0.3, -0.5, 0.7)), ("iso", (0.95, 0.05, 0.1)),
                                      ("view", (0.45, 0.2, 0.8)), ("view", (-0.9, 0.1, 0.3)),
                                      ("view_shift", (0.45, 0.2, 0.8)), ("view_shift", (-0.9, 0.1, 0.3))])
def test_sampler_chi_square(tables, kind, wo):
    """Off-node views (the ωo node is itself sampled): the sampled targets follow ``pdf`` (p > 1e-3,
    200 bins, 40k samples); the same statistic rejects the sampler of the mirrored view (p < 1e-6),
    so the test can fail."""
    wo = _unit(wo)
    assert _chi2_pvalue(tables[kind], wo) > 1e-3
    wrong = wo * np.array([-1, 1, 1]) if kind in ("aniso", "view", "view_shift") else _unit(wo * np.array([1, 1, 3]))
    assert _chi2_pvalue(tables[kind], wo, wrong) < 1e-6


@pytest.mark.parametrize("kind", ["aniso", "iso", "half", "iso_half", "view", "view_shift"])
def test_weight_is_eval_cos_over_pdf(tables, kind):
    """At a ωo node (one interpolation tap) every sample's weight equals eval · cos θi / (pdf · A) and
    its density equals ``pdf``: the shader's weight and the closure's target density agree."""
    B = tables[kind]
    T = tb.closure_tables(B)
    wo = B.view_nodes()[[len(B.view_nodes()) // 2 + 3]]
    if kind == "iso":                                       # any azimuth: the table turns with φo
        c, s = np.cos(2.1), np.sin(2.1)
        wo = wo @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    n = 3000
    WO = np.repeat(wo, n, 0)
    wi, m, W, p = tb.sample(T, WO, np.random.default_rng(1).random((n, 4)))
    if B.half:                                              # targets below the horizon carry no weight
        keep = wi[:, 2] > 0
        assert keep.mean() > 0.5 and np.all(W[~keep] == 0)
        wi, m, W, p, WO = wi[keep], m[keep], W[keep], p[keep], WO[keep]
    np.testing.assert_allclose(tb.pdf(T, wi, WO), p, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1, rtol=1e-12)
    np.testing.assert_allclose(np.sum(m * wi, 1), np.sum(m * WO, 1), atol=1e-12)   # m mirrors ωo into ωi
    A = tb.lobe_albedo(np.sum(WO * m, 1), T.alpha)
    P = tb.floor_parts(B)                   # the closure renders the residual r = f - kd/π - ks g (the floors)
    kd, R = P.kd, P.residual
    np.testing.assert_allclose(T.kd, kd)
    np.testing.assert_allclose(T.ks, P.ks)
    np.testing.assert_allclose(W, R.eval(wi, WO) * wi[:, 2:3] / (p * A)[:, None], rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("kind", ["aniso", "iso", "half", "iso_half", "view", "view_shift"])
def test_furnace_mean_weight_is_albedo(tables, kind):
    """The floors' albedo (kd + ks E_g, ``floor_albedo``) plus the mean of W · A over samples (what a white furnace
    renders, A the closure albedo) equals the directional albedo of floors + residual (``closure_albedo``: the
    residual's ∫ eval cos dωi by quadrature; without a glossy floor, ωi tables: the table's own) at off-node views.
    100k samples; the relative standard error is printed by the estimate itself (< 0.3 %); tolerance
    4 standard errors + 0.3 % for the albedo's midpoint rule."""
    B = tables[kind]
    T = tb.closure_tables(B)
    for wo in _unit(np.array([[0.3, 0.1, 0.9], [-0.7, 0.4, 0.4], [0.05, -0.9, 0.3]])):
        n = 100000
        WO = np.repeat(wo[None], n, 0)
        wi, m, W, p = tb.sample(T, WO, np.random.default_rng(3).random((n, 4)))
        est = W * tb.lobe_albedo(np.sum(WO * m, 1), T.alpha)[:, None]
        se = est.std(0) / np.sqrt(n)
        ref = tb.closure_albedo(B, wo[None], True, 128, 256)[0]     # floors + the residual's quadrature
        got = tb.floor_albedo(T, wo[None])[0] + est.mean(0)
        assert np.all(np.abs(got - ref) < 4 * se + 0.003 * ref), (wo, T.kd, T.ks, est.mean(0), ref, se)
        if not T.ks.any():          # ωi tables: kd/π + r is the table, so its albedo (half tables: closer to f)
            assert B.half or np.all(np.abs(got - B.albedo(wo[None], 128, 256)[0]) < 4 * se + 0.003 * ref)


@pytest.mark.parametrize("kind", ["aniso", "iso", "half", "iso_half", "view"])
def test_guide_table_pick_is_the_inverse_cdf(tables, kind):
    """The shader's bin pick (guide table + walk up, ``guide_pick``) returns the bin of the inverse CDF
    (#{b: cdf_b <= u}, what a binary search returns) for random u, for u exactly at every CDF value and
    at every bucket edge j/M (in float32, as the shader), also for rows with empty bins (half tables);
    and the walk is short: < 2.5 steps on average.  A guide one bin too high (a broken bound) fails."""
    T = tb.closure_tables(tables[kind])
    cdf = T.cdf
    n, M = cdf.shape[0], cdf.shape[1] - 1
    rng = np.random.default_rng(7)
    o = np.concatenate([rng.integers(0, n, 20000), np.repeat(np.arange(n), M + 1), np.repeat(np.arange(n), M)])
    u = np.concatenate([rng.random(20000), cdf.ravel(), np.tile(np.arange(M) / M, n)]).astype(np.float32)
    u = np.minimum(u, np.float32(1.0) - np.float32(2 ** -24))             # hashnoise is in [0, 1)
    k = tb.guide_pick(cdf, T.guide, o, u)
    ref = np.minimum((cdf[o, 1:] <= u[:, None]).sum(1), M - 1)
    np.testing.assert_array_equal(k, ref)
    j = np.minimum((u[:20000] * np.float32(M)).astype(int), M - 1)
    assert np.mean(k[:20000] - T.guide[o[:20000], j]) + 1 < 2.5
    broken = np.minimum(T.guide + 1, M - 1)
    assert np.any(tb.guide_pick(cdf, broken, o, u) != ref)


def test_lambert_table_is_exact():
    """A Lambertian table: eval = ρ/π everywhere, albedo ρ; the floor takes all of it (kd = ρ, the residual
    closure carries nothing); without the floor, per-sample weights W/ρ have a relative std below 0.5
    (measured 0.40 at res 6: the proposal is the cell-averaged cos, so W/ρ varies only inside a cell) and
    stay below 5."""
    rho = np.array([0.8, 0.5, 0.2])
    B = tb.TabulatedBRDF.from_function(lambda wi, wo: np.broadcast_to(rho / np.pi, (len(wi), 3)), 6, iso=True, n_theta=4)
    wo = _unit([[0.2, 0.3, 0.9]])
    np.testing.assert_allclose(B.albedo(wo, 256, 64)[0], rho, rtol=1e-3)
    T = tb.closure_tables(B)
    np.testing.assert_allclose(T.kd, rho, rtol=1e-12)
    _, m, W, _ = tb.sample(T, np.repeat(wo, 5000, 0), np.random.default_rng(0).random((5000, 4)))
    assert np.abs(W).max() < 1e-6 * rho.max()
    T = tb.closure_tables(B, floor=False)
    assert not T.kd.any()
    _, m, W, _ = tb.sample(T, np.repeat(wo, 5000, 0), np.random.default_rng(0).random((5000, 4)))
    r = W / rho
    assert r.std() / r.mean() < 0.5 and r.max() < 5


def test_reciprocity(tables):
    """The anisotropic table of a reciprocal BRDF evaluates reciprocally at any pair (same grid for ωi
    and ωo, bilinear in both): exact to rounding; the isotropic one up to its θo interpolation (< 10 %
    of the value where it is > 0.2/sr); a non-reciprocal BRDF's table is not reciprocal."""
    rng = np.random.default_rng(5)
    a = _unit(rng.normal(size=(500, 3)) * [1, 1, 0.5] + [0, 0, 0.8])
    b = _unit(rng.normal(size=(500, 3)) * [1, 1, 0.5] + [0, 0, 0.8])
    a[:, 2], b[:, 2] = np.abs(a[:, 2]) + 0.05, np.abs(b[:, 2]) + 0.05
    a, b = _unit(a), _unit(b)
    A = tables["aniso"]
    np.testing.assert_allclose(A.eval(a, b), A.eval(b, a), rtol=1e-12)
    Bi = tables["iso"]
    fab, fba = Bi.eval(a, b), Bi.eval(b, a)
    big = (fab > 0.2) & (fba > 0.2)
    assert np.median(np.abs(fab - fba)[big] / fab[big]) < 0.1
    nonrec = tb.TabulatedBRDF.from_function(lambda wi, wo: np.repeat((0.1 + wo[:, 0:1] ** 2), 3, 1), 8)
    assert np.abs(nonrec.eval(a, b) - nonrec.eval(b, a)).max() > 0.1


def test_glossy_twin_recovers_a_ggx_diffuse_table():
    """The SVM twin fit of a table made from its own model recovers α (±25 %, the table's point
    sampling of a sharp lobe and the 20 % steps of the α grid) and the diffuse colour (±0.06: the
    GGX tails absorb ~0.04 of it at the grid's α, measured)."""
    B = tb.TabulatedBRDF.from_function(ggx_plus_diffuse(alpha=0.3, ks=0.7, kd=(0.3, 0.2, 0.1)), 16, iso=True, n_theta=16)
    twin = tb.glossy_twin(B)
    assert abs(twin["alpha"] / 0.3 - 1) < 0.25, twin
    np.testing.assert_allclose(twin["diffuse"], [0.3, 0.2, 0.1], atol=0.06)
    assert twin["rel_l1"] < 0.1


def test_errors():
    with pytest.raises(ValueError, match="res"):
        tb.TabulatedBRDF(np.zeros((4, 4, 3)), 1)
    with pytest.raises(ValueError, match="table"):
        tb.TabulatedBRDF(np.zeros((4, 3, 3)), 2)
    with pytest.raises(ValueError, match="table"):
        tb.TabulatedBRDF(np.full((4, 4, 3), np.nan), 2)
    with pytest.raises(ValueError, match="table"):
        tb.TabulatedBRDF(-np.ones((4, 4, 3)), 2)
    B = tb.TabulatedBRDF(np.ones((16, 16, 3)), 4)
    with pytest.raises(ValueError, match="alpha"):
        tb.closure_tables(B, alpha=0.0)
    with pytest.raises(ValueError, match="table"):      # above MAX_FLOATS: no OSL source (the graph renders it)
        gen.generate(tb.TabulatedBRDF(np.ones((48 * 48, 256, 3)), 48, iso=True))
    with pytest.raises(ValueError, match="table"):      # above MAX_TABLE_FLOATS: no closure at all
        tb.closure_tables(tb.TabulatedBRDF(np.ones((48 * 48, 600, 3)), 48, iso=True))
    with pytest.raises(ValueError, match="wo"):
        B.eval(np.ones((2, 3)), np.full((2, 3), np.inf))
    with pytest.raises(ValueError, match="f"):
        tb.TabulatedBRDF.from_function(lambda wi, wo: np.full((len(wi), 3), np.nan), 4)


@pytest.mark.parametrize("u", [[[0.5, 0.5, np.nan, 0.5]], [[0.5, 2.0, 0.5, 0.5]], [[-0.1, 0.5, 0.5, 0.5]], [0.5],
                               np.full((3, 4), 0.5), "x"])
def test_sample_rejects_bad_uniforms(u):
    """Issue #14: ``sample`` with NaN, out-of-range or misshapen uniforms raised IndexError deep in the bin pick;
    now a ValueError naming ``u``."""
    brdf = tb.TabulatedBRDF.from_function(lambda wi, wo: np.ones(wi.shape[:-1] + (3,)) / np.pi, 6)
    with pytest.raises(ValueError, match="^u: "):
        tb.sample(tb.closure_tables(brdf), np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 0.95]]), u)


@pytest.mark.parametrize("half", [False, True])
def test_from_function_wrong_shape_names_f(half):
    """Issue #14: a BRDF function returning the wrong shape failed with numpy's reshape message."""
    with pytest.raises(ValueError, match="^f: "):
        tb.TabulatedBRDF.from_function(lambda wi, wo: np.ones(5), 6, half=half, extent=0.5 if half else None)
