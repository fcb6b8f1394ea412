"""Ellipsoid NDF -> Cycles Glossy parameters (precompute/microgeometry_material.py).

References: the ellipsoid NDF of eq. 10 (precompute.microgeometry.ellipsoid, independent of the converter),
the numpy twin of Cycles' GGX closure (precompute.cycles.ggx.bsdf_eval / ggx_aniso_D), Smith's
Lambda written out from the ellipsoid matrix A (not from the converter's frame), and round trips.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.cycles import ggx as cg
from scratch_materials.precompute.microgeometry import glossy as mm
from scratch_materials.precompute.microgeometry.ellipsoid import ellipsoid_matrix, ellipsoid_ndf, rotation_matrix
from scratch_materials.precompute.microgeometry.heightfield import gaussian_surface
from scratch_materials.precompute.microgeometry.ndf import filtered_ndf
from scratch_materials.precompute.microgeometry.synthesis import synthesize_parameter_texture

alphas = st.floats(0.01, 0.9)
small_angle = st.floats(-0.5, 0.5)
any_tz = st.floats(-3.0, 3.0)


def _upper_dirs(rng, n, params):
    """Random unit vectors above both n and the lobe axis N' (where both closures are defined)."""
    Np = rotation_matrix(*params[2:])[2]
    v = rng.normal(size=(4 * n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v = v[(v[:, 2] > 0.05) & (v @ Np > 0.05)]
    return v[:n]


@settings(max_examples=40, deadline=None)
@given(alphas, alphas, any_tz)
def test_untilted_ggx_equals_ellipsoid_exactly(ax, ay, tz):
    # theta_x = theta_y = 0: eq. 10 is GTR2aniso; the converted closure's D must be identical.
    p = np.array([ax, ay, 0.0, 0.0, tz])
    maps, loss = mm.glossy_from_ellipsoid(p)
    assert np.allclose(maps["tilt"], [0, 0, 1])
    N, X, au, av = mm.closure_frame(maps["roughness"], maps["anisotropy"], maps["rotation"], maps["tilt"])
    Xc, Yc = cg.make_orthonormals_tangent(N, X)  # Cycles' frame from (N, T)
    m = _upper_dirs(np.random.default_rng(0), 500, p)
    local = np.stack([m @ Xc, m @ Yc, m @ N], -1)
    np.testing.assert_allclose(cg.ggx_aniso_D(au, av, local), ellipsoid_ndf(m, maps["ellipsoid"]), rtol=1e-9)
    np.testing.assert_allclose(maps["ellipsoid"], p, rtol=1e-4)  # only near-isotropic pairs are snapped


def _smith_lambda_from_A(params, v):
    """GGX Smith Lambda in the ellipsoid's own frame: 0.5 (||A v|| / |(R v)_z| - 1) (Heitz 2014 eq. 72)."""
    A = ellipsoid_matrix(params)
    R = rotation_matrix(*params[2:])
    return 0.5 * (np.linalg.norm(v @ A.T, axis=-1) / np.abs(v @ R[2]) - 1.0)


@settings(max_examples=30, deadline=None)
@given(alphas, alphas, small_angle, small_angle, any_tz)
def test_tilted_closure_in_cycles_twin_reproduces_ellipsoid(ax, ay, tx, ty, tz):
    # Cycles' eval = D_cyc(h) G2 / (4 N'.wi).  The ellipsoid lobe in its own frame: D_cyc = ||A n|| D_ell
    # (normalisation about N' instead of n), G2 = 1/(1 + L(wi) + L(wo)) with L from the matrix A.
    p = np.array([ax, ay, tx, ty, tz])
    maps, _ = mm.glossy_from_ellipsoid(p)
    p = maps["ellipsoid"]  # the represented lobe (= p up to the near-isotropic snap, see the fuzz test)
    N, X, au, av = mm.closure_frame(maps["roughness"], maps["anisotropy"], maps["rotation"], maps["tilt"])
    rng = np.random.default_rng(1)
    wi = _upper_dirs(rng, 300, p)
    wo = _upper_dirs(rng, 300, p)
    n = min(len(wi), len(wo))
    wi, wo = wi[:n], wo[:n]
    ev, _ = cg.bsdf_eval(N, X, au, av, wi, wo)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    keep = h[:, 2] > 0
    An = np.linalg.norm(ellipsoid_matrix(p)[:, 2])
    G2 = 1.0 / (1.0 + _smith_lambda_from_A(p, wi) + _smith_lambda_from_A(p, wo))
    expect = An * ellipsoid_ndf(h, p) * G2 / (4.0 * (wi @ N))
    assert keep.sum() > 50
    np.testing.assert_allclose(ev[keep], expect[keep], rtol=1e-8)


@settings(max_examples=60, deadline=None)
@given(st.floats(1e-4, 10.0), st.floats(1e-4, 10.0), st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), any_tz)
def test_round_trip_and_clamping_fuzz(ax, ay, tx, ty, tz):
    p = np.array([ax, ay, tx, ty, tz])
    maps, loss = mm.glossy_from_ellipsoid(p)
    rep = maps["ellipsoid"]
    # node parameters are in the Glossy node's range, and Cycles' mapping gives back the represented alphas
    assert 0 <= maps["roughness"] <= 1 and abs(maps["anisotropy"]) <= mm.ANISO_MAX + 1e-12
    au, av = mm.cycles_glossy_alphas(maps["roughness"], maps["anisotropy"])
    np.testing.assert_allclose([au, av], rep[:2], rtol=1e-9)
    assert rep[0] <= 1 and rep[1] <= 1 and min(rep[0], rep[1]) / max(rep[0], rep[1]) >= 1e-4 * (1 - 1e-9)
    # the angles survive unchanged; alphas only change when out of range, and the report says so
    back = mm.ellipsoid_from_glossy(maps["roughness"], maps["anisotropy"], maps["rotation"], maps["tilt"])
    np.testing.assert_allclose(back[2:], p[2:], atol=1e-9)
    np.testing.assert_allclose(back[:2], rep[:2], rtol=1e-9)
    ratio = min(ax, ay) / max(ax, ay)
    in_range = max(ax, ay) <= 1 and ratio >= 1e-4 and not (1 - 1e-12 > ratio >= (1 - 1e-4) ** 2)  # near-iso: isotropic
    assert loss.lossless == in_range
    if in_range:
        np.testing.assert_allclose(rep, p, rtol=1e-11)
    else:
        assert loss.max_alpha_rel_change > 0
    assert loss.max_tilt_deg == pytest.approx(np.degrees(np.arccos(np.cos(tx) * np.cos(ty))), abs=1e-6)


def test_anisotropy_is_continuous_where_alphas_cross():
    # texels whose alpha_x and alpha_y swap order must not jump (filtered textures interpolate it)
    ax = np.linspace(0.09, 0.11, 201)
    r, an = mm.glossy_from_alphas(ax, np.full_like(ax, 0.1))
    assert np.all(np.abs(np.diff(an)) < 2e-3) and an[0] > 0 > an[-1]
    au, av = mm.cycles_glossy_alphas(r, an)
    np.testing.assert_allclose(au[np.abs(an) > 1e-4], ax[np.abs(an) > 1e-4], rtol=1e-12)


def test_cycles_mapping_matches_documented_formula():
    # alpha = r^2; an > 0: (alpha (1 - an), alpha / (1 - an)); clamps: an to 0.99, alphas to 1
    au, av = mm.cycles_glossy_alphas(0.5, 0.6)
    assert (au, av) == pytest.approx((0.25 * 0.4, 0.25 / 0.4))
    au, av = mm.cycles_glossy_alphas(0.5, -0.6)
    assert (au, av) == pytest.approx((0.25 / 0.4, 0.25 * 0.4))
    au, av = mm.cycles_glossy_alphas(0.9, 0.5)
    assert av == 1.0 and au == pytest.approx(0.81 * 0.5)
    assert mm.cycles_glossy_alphas(0.3, 1.5)[0] == pytest.approx(0.09 * 0.01)


def test_projection_factor_is_one_untilted_and_second_order_in_tilt():
    assert mm.projection_factor([0.2, 0.05, 0, 0, 0.4]) == pytest.approx(1.0)
    f1 = mm.projection_factor([0.05, 0.05, 0.05, 0, 0]) - 1
    f2 = mm.projection_factor([0.05, 0.05, 0.1, 0, 0]) - 1
    assert abs(f1) < 1e-5 and f2 / f1 == pytest.approx(4.0, rel=0.02)


def test_from_filtered_ndf_of_brushed_surface():
    hf = gaussian_surface((192, 256), 0.11, 0.08, (15.0, 1.5), seed=3)  # scratches along x
    nd = filtered_ndf(hf, resolution=513)
    gp = mm.glossy_from_ndf(nd, "ellipsoid", n_nodes=64)
    assert gp.loss.lossless and gp.loss.hellinger == 0.0
    # brushed along x: slopes vary across (y), so the lobe is narrow in x: alpha_u < alpha_v -> an > 0
    assert gp.anisotropy > 0.5 and abs(np.sin(2 * np.pi * gp.rotation)) < 0.1
    # the fitted GGX (untilted) agrees with the ellipsoid conversion in roughness within 10 %
    gg = mm.glossy_from_ndf(nd, "ggx", n_nodes=64)
    assert gg.tilt == (0.0, 0.0, 1.0) and gg.roughness == pytest.approx(gp.roughness, rel=0.1)
    assert set(gp.as_inputs()) == {"Roughness", "Anisotropy", "Rotation", "Tilt"}
    with pytest.raises(ValueError, match="model"):
        mm.glossy_from_ndf(nd, "beckmann")


def test_node_textures_decode_back_to_the_synthesised_texture():
    rng = np.random.default_rng(4)
    seq_x = np.column_stack([0.05 + 0.01 * rng.random(32), 0.3 + 0.05 * rng.random(32), 0.05 * rng.normal(size=32),
                             0.05 * rng.normal(size=32), 0.1 * rng.normal(size=32)])
    seq_y = seq_x[rng.permutation(32)]
    tex = synthesize_parameter_texture(seq_x, seq_y, (16, 24), seed=1)
    imgs, loss = mm.node_textures(tex)
    assert imgs["params"].shape == (16, 24, 4) and imgs["tilt"].dtype == np.float32 and loss.n_total == 16 * 24
    back = mm.ellipsoid_from_glossy(imgs["params"][..., 0], imgs["params"][..., 1], imgs["params"][..., 2],
                                    imgs["tilt"][..., :3])
    # float32 storage: ~1e-7 relative on the stored values, amplified by 1/sqrt(alpha ratio) in the alphas
    np.testing.assert_allclose(back[..., :2], tex[..., :2], rtol=2e-5)
    np.testing.assert_allclose(back[..., 2:], tex[..., 2:], atol=2e-5)


@pytest.mark.parametrize("call, match", [
    (lambda: mm.glossy_from_ellipsoid([0.1, 0.1, 0, 0]), "params"),
    (lambda: mm.glossy_from_ellipsoid([np.nan, 0.1, 0, 0, 0]), "params"),
    (lambda: mm.glossy_from_ellipsoid([0.1, 0.1, 2.0, 0, 0]), "theta_x"),
    (lambda: mm.glossy_from_alphas(1.5, 0.1), "alpha_u"),
    (lambda: mm.glossy_from_alphas(1e-6, 0.5), "ratio"),
    (lambda: mm.representable_alphas(-1.0, 0.1), "alpha_x"),
    (lambda: mm.ellipsoid_from_glossy(0.3, 0.2, 0.0, [0.1, 0.0, -1.0]), "tilt"),
    (lambda: mm.ellipsoid_from_glossy(0.3, 0.2, 0.0, [0.0, 0.0, 0.0]), "tilt"),
    (lambda: mm.cycles_glossy_alphas(np.nan, 0.2), "roughness"),
    (lambda: mm.node_textures(np.ones((4, 4, 3))), "texture"),
])
def test_bad_input_raises_clear_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()
