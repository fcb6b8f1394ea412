"""Generator of the iridescent-layer OSL shader (osl/iridescent_layer.py), without Blender.

References: scipy's sine integral, brute-force segment/point distances for the reach grid,
and the route-A sampling maths checked against quadrature of the model's sinc² term."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import integrate, special

from osl import iridescent_layer as il
from precompute.iridescence import RGB_WAVELENGTHS_UM, SIGMA_UM
from precompute.scratch_set import point_segment_distance, random_scratches


def test_constants_match_numpy_model():
    assert np.allclose(il.RGB_WAVELENGTHS_UM, RGB_WAVELENGTHS_UM) and il.SIGMA_UM == SIGMA_UM


def test_si_float32_twin_matches_scipy():
    # The shader's Si (float32 Taylor + fitted auxiliary functions) against double-precision sici:
    # float32 rounding of the ~π/2 result is 1e-7, fit error 1.4e-6 → 5e-6 is tight.
    x = np.concatenate([np.linspace(-60, 60, 40001), np.geomspace(60, 1e5, 2000), -np.geomspace(60, 1e5, 50)])
    err = np.abs(il.si_float32(x) - special.sici(x)[0])
    assert err.max() < 5e-6, err.max()
    # Eq. 29's approximation is 100x worse; make sure the test could tell them apart
    from precompute.iridescence import si_approx
    assert np.abs(si_approx(x[:40001]) - special.sici(x[:40001])[0]).max() > 1e-3


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 60), st.floats(0.002, 0.05), st.integers(0, 10_000))
def test_reach_grid_cell_holds_every_segment_in_reach(count, reach, seed):
    S = random_scratches(count, length_range=(0.0, 0.2), seed=seed)
    g = il.reach_grid(S.p0, S.p1, reach)
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
    assert g.nx * g.ny <= il.MAX_CELLS


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
    a = il.generate(il.LayerSpec(S))
    assert "#define ROUTE_LIGHTS 0" in a and "#define BASE_BLEND 1" in a and "#define NSPH 0" in a
    assert "closure color Base" in a and "point UV" in a and "vector Tangent" in a and "output closure color BSDF" in a
    lights = [il.SphereLightSpec((0, 0, 2), 0.1, (1, 1, 1)),
              il.PolygonLightSpec(((0, 0, 2), (0, 1, 2), (1, 1, 2)), (2, 2, 2))]
    b = il.generate(il.LayerSpec(S, route="lights", lights=lights, base_blend=False))
    assert "#define ROUTE_LIGHTS 1" in b and "#define NSPH 1" in b and "#define NPOLY 1" in b and "#define BASE_BLEND 0" in b
    empty = il.generate(il.LayerSpec(random_scratches(0)))
    assert "#define MAXC 1" in empty


@pytest.mark.parametrize("kw, match", [
    (dict(sigma_um=0.0), "sigma_um"), (dict(sigma_um=np.nan), "sigma_um"), (dict(route="magic"), "route"),
    (dict(samples=0), "samples"), (dict(samples=2.5), "samples"), (dict(name="bad name"), "name"),
    (dict(wavelengths_um=(0.5, 0.6)), "wavelengths_um"),
    (dict(lights=[il.SphereLightSpec((0, 0, 1), 0.0, (1, 1, 1))]), "radius"),
    (dict(lights=[il.SphereLightSpec((0, 0, 1), 0.1, (1, -1, 1))]), "radiance"),
    (dict(lights=[il.PolygonLightSpec(((0, 0, 1), (1, 0, 1)), (1, 1, 1))]), "vertices"),
    (dict(lights=["sun"]), "SphereLightSpec"),
])
def test_bad_parameters_raise_clear_errors(kw, match):
    S = random_scratches(5, seed=0)
    with pytest.raises(ValueError, match=match):
        il.generate(il.LayerSpec(S, **kw))
    with pytest.raises(ValueError, match="ScratchSet"):
        il.generate(il.LayerSpec(object()))
