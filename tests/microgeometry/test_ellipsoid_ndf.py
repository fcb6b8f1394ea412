"""Ellipsoid NDF (Dong et al. 2015 §8): normalisation, GGX reduction, G1, sampler chi^2, fits."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats

from scratch_materials.precompute.microgeometry.ellipsoid import (beckmann_ndf, canonical_params, ellipsoid_g1, ellipsoid_matrix,
                                                ellipsoid_ndf, ellipsoid_pdf, fit_ellipsoid, fit_ggx, ggx_ndf,
                                                sample_ellipsoid)
from scratch_materials.precompute.microgeometry.ndf import NDFTable, splat_table

PARAMS = [
    (0.3, 0.3, 0.0, 0.0, 0.0),
    (0.2, 0.5, 0.3, -0.2, 0.7),
    (0.05, 0.4, 0.5, 0.4, 2.0),
    (1.5, 0.7, -0.6, 0.2, 1.0),
]


def slope_space_integral(f, n=1200):
    """∫ f(m) (m·n) dω via polar slope space: (m·n) dω = d^2s / (1+|s|^2)^2, r = tan(pi u / 2).

    Independent of the disk tables; midpoint rule, converged to ~1e-6 for these lobes.
    """
    u = (np.arange(n) + 0.5) / n
    ph = (np.arange(n) + 0.5) / n * 2 * np.pi
    U, P = np.meshgrid(u, ph)
    r = np.tan(U * np.pi / 2)
    dr = np.pi / 2 / np.cos(U * np.pi / 2) ** 2 / n
    m = np.stack([-r * np.cos(P), -r * np.sin(P), np.ones_like(r)], -1).reshape(-1, 3)
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    return np.sum(f(m).reshape(U.shape) / (1 + r**2) ** 2 * r * dr * (2 * np.pi / n))


@pytest.mark.parametrize("p", PARAMS)
def test_normalisation(p):
    # eq. 10 normalisation ∫ D (m·n) dω = 1, also for rotated (skewed) ellipsoids cut by the hemisphere
    assert abs(slope_space_integral(lambda m: ellipsoid_ndf(m, p)) - 1) < 1e-4


def test_beckmann_ggx_normalised():
    assert abs(slope_space_integral(lambda m: beckmann_ndf(m, 0.2, 0.4, 0.3)) - 1) < 1e-4
    assert abs(slope_space_integral(lambda m: ggx_ndf(m, 0.2, 0.4, 0.3)) - 1) < 1e-4


def test_reduces_to_ggx_and_gtr2aniso():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(2000, 3))
    m[:, 2] = np.abs(m[:, 2])
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    a = 0.35
    cos = m[:, 2]
    tan2 = (1 - cos**2) / cos**2
    ggx_closed = a * a / (np.pi * cos**4 * (a * a + tan2) ** 2)  # Walter et al. 2007 eq. 33
    np.testing.assert_allclose(ellipsoid_ndf(m, (a, a, 0, 0, 0)), ggx_closed, rtol=1e-12)
    # GTR2aniso (Burley 2012 eq. 13) with axes rotated by theta_z
    ax, ay, tz = 0.2, 0.6, 0.4
    c, s = np.cos(tz), np.sin(tz)
    x, y = c * m[:, 0] - s * m[:, 1], s * m[:, 0] + c * m[:, 1]
    gtr2 = 1 / (np.pi * ax * ay * ((x / ax) ** 2 + (y / ay) ** 2 + m[:, 2] ** 2) ** 2)
    np.testing.assert_allclose(ellipsoid_ndf(m, (ax, ay, 0, 0, tz)), gtr2, rtol=1e-12)
    np.testing.assert_allclose(ggx_ndf(m, ax, ay, tz), gtr2, rtol=1e-12)


def test_g1_reduces_to_smith_ggx_and_satisfies_projected_area():
    th = np.linspace(0.01, 1.55, 50)
    u = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], -1)
    a = 0.4
    smith = 2 / (1 + np.sqrt(1 + a * a * np.tan(th) ** 2))
    np.testing.assert_allclose(ellipsoid_g1(u, (a, a, 0, 0, 0)), smith, rtol=1e-12)
    # Smith relation for a skewed ellipsoid: G1(u) ∫ <u,m>+ D(m) dω = u·n (eq. 14, unclamped region)
    p = (0.2, 0.5, 0.3, -0.2, 0.7)
    for t in (0.4, 1.0, 1.4):
        uu = np.array([[np.sin(t) * np.cos(0.4), np.sin(t) * np.sin(0.4), np.cos(t)]])
        proj = slope_space_integral(lambda m: ellipsoid_ndf(m, p) * np.maximum(m @ uu[0], 0) / m[:, 2])
        g = ellipsoid_g1(uu, p)[0]
        if g < 1:
            assert abs(g * proj - uu[0, 2]) < 1e-4
    g = ellipsoid_g1(np.random.default_rng(0).normal(size=(500, 3)), p)
    assert np.all((g >= 0) & (g <= 1))


def chi2_pvalue(p, n=1_000_000, nt=24, nph=48, seed=0, p_pdf=None):
    """Mitsuba-style chi^2: histogram of samples in (theta, phi) vs pdf integrated per bin."""
    rng = np.random.default_rng(seed)
    m = sample_ellipsoid(p, rng.random(n), rng.random(n))
    th = np.arccos(np.clip(m[:, 2], -1, 1))
    ph = np.arctan2(m[:, 1], m[:, 0]) % (2 * np.pi)
    obs, _, _ = np.histogram2d(th, ph, bins=[nt, nph], range=[[0, np.pi / 2], [0, 2 * np.pi]])
    # expected: 6x6 Gauss-Legendre per bin of pdf(m) sin(theta)
    x, w = np.polynomial.legendre.leggauss(6)
    te = np.linspace(0, np.pi / 2, nt + 1)
    pe = np.linspace(0, 2 * np.pi, nph + 1)
    tq = (te[:-1, None] + (x[None] + 1) / 2 * np.diff(te)[:, None]).ravel()
    pq = (pe[:-1, None] + (x[None] + 1) / 2 * np.diff(pe)[:, None]).ravel()
    T, P = np.meshgrid(tq, pq, indexing="ij")
    mm = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    val = (ellipsoid_pdf(mm, p if p_pdf is None else p_pdf).reshape(T.shape) * np.sin(T))
    val = val.reshape(nt, 6, nph, 6) * w[None, :, None, None] * w[None, None, None, :]
    exp = val.sum((1, 3)) * (np.diff(te)[:, None] / 2) * (np.diff(pe)[None, :] / 2) * n
    assert abs(exp.sum() / n - 1) < 1e-3  # pdf normalised on the hemisphere
    # merge low-expectation bins (< 5) into one, as in Mitsuba's chi2 test
    exp, obs = exp.ravel(), obs.ravel()
    low = exp < 5
    e = np.append(exp[~low], exp[low].sum())
    o = np.append(obs[~low], obs[low].sum())
    if e[-1] == 0:
        e, o = e[:-1], o[:-1]
    chi2 = np.sum((o - e) ** 2 / e)
    return stats.chi2.sf(chi2, len(e) - 1)


@pytest.mark.parametrize("p", [(0.3, 0.3, 0.0, 0.0, 0.0), (0.25, 0.6, 0.3, -0.2, 0.7), (0.8, 0.4, -0.5, 0.4, 2.0)])
def test_sampler_chi2(p):
    # 1e6 samples, significance level 0.01 (one test per parameter set)
    assert chi2_pvalue(p) > 0.01


def test_chi2_detects_wrong_pdf():
    # the chi^2 test must be able to fail: a 5 % wider lobe or a 0.05 rad skew is rejected
    assert chi2_pvalue((0.3, 0.3, 0, 0, 0), p_pdf=(0.315, 0.3, 0, 0, 0)) < 1e-6
    assert chi2_pvalue((0.3, 0.3, 0, 0, 0), p_pdf=(0.3, 0.3, 0.05, 0, 0)) < 1e-6


def test_sampler_peak_and_hemisphere():
    p = (0.1, 0.1, 0.2, -0.1, 0.3)
    rng = np.random.default_rng(0)
    m = sample_ellipsoid(p, rng.random(100000), rng.random(100000))
    assert np.all(m[:, 2] > 0) and np.allclose(np.linalg.norm(m, axis=1), 1)
    # peak of the lobe is R^T z (where ||S^{-1} R m|| is minimal)
    A = ellipsoid_matrix(p)
    R = A / np.array([0.1, 0.1, 1.0])[:, None]
    peak = R.T @ np.array([0, 0, 1.0])
    assert np.argmax(ellipsoid_ndf(np.vstack([peak, m[:1000]]), p)) == 0


def test_canonical_params_identity():
    rng = np.random.default_rng(2)
    m = rng.normal(size=(1000, 3))
    m[:, 2] = np.abs(m[:, 2])
    p = np.array([0.2, 0.5, 0.3, -0.2, 2.9])
    c = canonical_params(p, 0.0)
    assert abs(c[4]) <= np.pi / 2 and np.isclose(c[2], -0.3)
    np.testing.assert_allclose(ellipsoid_ndf(m, c), ellipsoid_ndf(m, p), rtol=1e-10)


def sampled_table(p, n=2_000_000, res=513, seed=0):
    """Histogram of sampler output as a disk table (projected-area density == D)."""
    rng = np.random.default_rng(seed)
    m = sample_ellipsoid(p, rng.random(n), rng.random(n))
    h = 2 / (res - 1)
    return NDFTable(splat_table(m[:, 0], m[:, 1], np.ones(n), res)[0] / (n * h * h))


@pytest.mark.parametrize("p", [(0.15, 0.4, 0.1, -0.05, 0.5), (0.3, 0.3, 0.0, 0.0, 0.0)])
def test_fit_recovers_parameters_from_sampled_table(p):
    tab = sampled_table(p)
    assert abs(tab.integral() - 1) < 1e-6
    f = fit_ellipsoid(tab)
    # 2e6 samples: histogram noise gives ~0.3 % scatter in alpha; 2 % is the tolerance
    if p[0] == p[1]:  # isotropic: theta_z undetermined, compare the lobes directly
        assert np.allclose([f.alpha_x, f.alpha_y], p[:2], rtol=0.02)
    else:
        c = canonical_params(np.array(f), p[4])
        np.testing.assert_allclose(c[:2], p[:2], rtol=0.02)
        np.testing.assert_allclose(c[2:], p[2:], atol=0.01)
    g = fit_ggx(tab, isotropic=(p[0] == p[1]))
    if p[0] == p[1]:
        assert abs(g["alpha_x"] - p[0]) < 0.02 * p[0]


@settings(max_examples=40, deadline=None)
@given(ax=st.floats(1e-3, 5), ay=st.floats(1e-3, 5), tx=st.floats(-1.5, 1.5), ty=st.floats(-1.5, 1.5),
       tz=st.floats(-7, 7), graze=st.floats(0, 1e-6))
def test_fuzz_extremes_finite(ax, ay, tx, ty, tz, graze):
    p = (ax, ay, tx, ty, tz)
    m = np.array([[1, 0, graze], [0, 1, graze], [0, 0, 1], [0.6, 0.8, -1e-9], [1e-12, 0, 1]])
    d = ellipsoid_ndf(m, p)
    assert np.all(np.isfinite(d)) and np.all(d >= 0) and d[3] == 0
    g = ellipsoid_g1(m, p)
    assert np.all(np.isfinite(g)) and np.all((g >= 0) & (g <= 1))
    u = np.array([0.0, 0.5, 0.999999])
    s = sample_ellipsoid(p, u, u[::-1])
    assert np.all(np.isfinite(s)) and np.all(s[:, 2] >= 0)


def test_bad_inputs():
    m = np.array([[0, 0, 1.0]])
    with pytest.raises(ValueError, match="alpha"):
        ellipsoid_ndf(m, (0, 0.1, 0, 0, 0))
    with pytest.raises(ValueError, match="theta_x"):
        ellipsoid_ndf(m, (0.1, 0.1, 2.0, 0, 0))
    with pytest.raises(ValueError, match="params"):
        ellipsoid_ndf(m, (0.1, 0.1, 0, 0))
    with pytest.raises(ValueError, match="finite"):
        ellipsoid_ndf(m, (np.nan, 0.1, 0, 0, 0))
    with pytest.raises(ValueError, match="m:"):
        ellipsoid_ndf(np.zeros((2, 3)), (0.1, 0.1, 0, 0, 0))
    with pytest.raises(ValueError, match="u1, u2"):
        sample_ellipsoid((0.1, 0.1, 0, 0, 0), np.array([1.0]), np.array([0.5]))
