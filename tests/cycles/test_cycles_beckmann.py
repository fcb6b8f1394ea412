"""Tests of the Beckmann twin of Cycles' microfacet closure and of its tilted-lobe cone collapse.

References are independent of the code under test: sphere quadrature (D normalisation), the exact
Smith Lambda of the Beckmann distribution (Cycles' rational approximation must stay close to it),
a hand-written Cycles formula, brute-force 2D integration of the 3D eval over the theta band, and
the slope-space albedo quadrature.
"""
import numpy as np
import pytest
from scipy.special import erf

from scratch_materials.precompute.cycles import beckmann as bk
from scratch_materials.precompute.cycles import ggx as cg

from test_cycles_ggx import U, Z, _sphere_grid  # noqa: F401  (shared quadrature and frame)


@pytest.mark.parametrize("ax,ay", [(0.3, 0.3), (0.2, 0.5), (0.6, 0.15)])
def test_D_is_normalised(ax, ay):
    # int D(m) (m.n) dm = 1; 1500x1500 midpoint cells on a smooth integrand: error << 1e-3.
    m, w = _sphere_grid(1500, 1500)
    assert np.sum(bk.beckmann_aniso_D(ax, ay, m) * m[..., 2] * w) == pytest.approx(1.0, abs=2e-3)


def test_lambda_approximation_close_to_exact_smith():
    # Walter's approximation is within ~1e-2 absolute of the exact Beckmann Lambda
    # (Lambda = (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi))) and exactly 0 for a >= 1.6 (s < 0.39).
    a = np.linspace(0.05, 3.0, 500)
    exact = 0.5 * (erf(a) - 1) + np.exp(-a * a) / (2 * a * np.sqrt(np.pi))
    approx = bk.beckmann_lambda_from_sqr_alpha_tan_n(1.0 / a**2)
    assert np.max(np.abs(approx - exact)) < 0.015
    assert np.all(approx[a >= 1.6 + 1e-9] == 0)
    assert bk.beckmann_lambda_from_sqr_alpha_tan_n(0.0) == 0
    assert np.isinf(bk.beckmann_lambda_from_sqr_alpha_tan_n(np.inf))


def test_eval_matches_hand_written_cycles_formula():
    t = np.radians(25.0)
    N = np.array([0.0, np.sin(t), np.cos(t)])
    wi, wo = cg.direction(0.2, 0.5), cg.direction(-0.2, -0.9)
    ax, ay = 0.05, 0.6
    Y = np.cross(N, U) / np.linalg.norm(np.cross(N, U))
    X = np.cross(Y, N)
    H = (wi + wo) / np.linalg.norm(wi + wo)
    h = np.array([H @ X / ax, H @ Y / ay, H @ N])
    D = np.exp(-(h[0] ** 2 + h[1] ** 2) / h[2] ** 2) / (np.pi * ax * ay * h[2] ** 4)

    def lam(V):
        s = ((ax * (V @ X)) ** 2 + (ay * (V @ Y)) ** 2) / (V @ N) ** 2
        if s < 0.39:
            return 0.0
        a = 1 / np.sqrt(s)
        return ((0.396 * a - 1.259) * a + 1) / ((2.181 * a + 3.535) * a)

    ev, pdf = cg.bsdf_eval(N, U, ax, ay, wi, wo, dist="beckmann")
    assert lam(wo) > 0                                   # the configuration exercises the rational branch
    assert ev == pytest.approx(D / (4 * (N @ wi)) / (1 + lam(wi) + lam(wo)), rel=1e-12)
    assert pdf == pytest.approx(D / (4 * (N @ wi)) / (1 + lam(wi)), rel=1e-12)


def test_albedo_quadrature_matches_sphere_integration():
    # slope-space quadrature of the Beckmann albedo vs a direct sphere integral of bsdf_eval
    N = cg.tilted_normal(0.4)
    wi = cg.direction(0.1, 0.3)
    d, w = _sphere_grid(1200, 1200)
    ev, _ = cg.bsdf_eval(N, U, 0.25, 0.35, wi, d, dist="beckmann")
    direct = np.sum(ev * w)
    quad = float(cg.albedo(0.4, 0.25, 0.35, 0.1, 0.3, n=1024, dist="beckmann"))
    assert quad == pytest.approx(direct, abs=3e-3)


def _brute_force_band(theta_o, phi_o, tilt, ay, ax, phi_lo, phi_hi, n_th=3000, n_ph=400):
    half = 8 * ax                       # Gaussian x-slope tails: mass beyond 8 ax is ~1e-29
    th = -theta_o + np.linspace(-half, half, n_th)
    ph = np.linspace(phi_lo, phi_hi, n_ph + 1)
    ph = 0.5 * (ph[1:] + ph[:-1])
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    ev, _ = cg.tilted_lobe_eval(theta_o, phi_o, TH, PH, tilt, ay, ax, dist="beckmann")
    return np.trapz(ev * np.cos(TH), th, axis=0).mean()


@pytest.mark.parametrize("theta_o,phi_o,tilt,ay", [(0.0, 0.3, 0.2, 0.2), (0.6, -0.4, 0.5, 0.1), (1.1, 0.8, 0.3, 0.6)])
def test_cone_collapse_matches_brute_force_2d_integration(theta_o, phi_o, tilt, ay):
    # Same protocol as the GGX test (ax = 2e-3, 8 bins, 3000 x 400 points per bin): 1.5 % relative,
    # 1 % of the peak absolute next to the tilted normal's horizon.
    ax = 2e-3
    edges = np.linspace(-1.2, 1.2, 9)
    closed = cg.cone_collapse_binned(phi_o, edges, tilt, ay, ax, theta_o, dist="beckmann")
    brute = np.array([_brute_force_band(theta_o, phi_o, tilt, ay, ax, a, b) for a, b in zip(edges[:-1], edges[1:])])
    np.testing.assert_allclose(closed, brute, rtol=0.015, atol=1e-2 * brute.max())
    fine = np.linspace(-1.2, 1.2, 8 * 2000 + 1)
    gp = cg.cone_collapse(phi_o, 0.5 * (fine[1:] + fine[:-1]), tilt, ay, ax, theta_o,
                          dist="beckmann").reshape(8, -1).mean(1)
    np.testing.assert_allclose(closed, gp, rtol=0.01, atol=1e-2 * gp.max())


def test_cone_collapse_integral_equals_3d_albedo_and_edges_are_sharper_than_ggx():
    phi = np.linspace(-np.pi / 2, np.pi / 2, 40001)
    for tilt, phi_o, ay in [(0.0, 0.0, 0.3), (0.6, 0.2, 0.2), (1.0, -0.3, 0.5)]:
        g = cg.cone_collapse(phi_o, phi, tilt, ay, 1e-3, dist="beckmann")
        ref = float(cg.albedo(tilt, 1e-3, ay, 0.0, phi_o, n=1024, dist="beckmann"))
        assert np.trapz(g, phi) == pytest.approx(ref, abs=2e-3)
    # Gaussian slope tails: 4 widths away from the centre a Beckmann lobe has far less mass than GGX
    far = np.abs(np.tan(0.5 * phi)) > 4 * 0.05
    gb = cg.cone_collapse(0.0, phi, 0.0, 0.05, 1e-3, dist="beckmann")
    gg = cg.cone_collapse(0.0, phi, 0.0, 0.05, 1e-3, dist="ggx")
    assert np.trapz(gb * far, phi) < 1e-6 < 0.01 < np.trapz(gg * far, phi)


def test_mixed_codes_match_single_distribution_calls():
    edges = np.linspace(-np.pi / 2, np.pi / 2, 65)
    t = np.array([0.1, -0.3, 0.4])
    a = np.array([0.05, 0.2, 0.01])
    d = np.array([0, 1, 1])
    mixed = cg.cone_collapse_binned(0.2, edges, t, a, 1e-4, dist=d)
    for k in range(3):
        single = cg.cone_collapse_binned(0.2, edges, t[k], a[k], 1e-4, dist=["ggx", "beckmann"][d[k]])
        np.testing.assert_allclose(mixed[k], single, rtol=1e-12, atol=0)


def test_bad_dist_raises():
    with pytest.raises(ValueError, match="dist"):
        cg.cone_collapse(0.0, 0.0, 0.0, 0.1, dist="phong")
    with pytest.raises(ValueError, match="dist"):
        cg.cone_collapse_binned(0.0, [0.0, 0.1], 0.0, 0.1, dist=np.array([2]))
    with pytest.raises(ValueError, match="dist"):
        cg.albedo(0.0, 0.1, 0.1, dist=0.5)
