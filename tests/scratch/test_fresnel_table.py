"""Tabulated Fresnel (``fresnel.tabulated``): the conductor formula on a fine cos θ grid, what the tracer
evaluates per bounce.  Oracle: the exact formula (``fresnel.Conductor``, Born & Wolf §14.2)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.scratch import fresnel, lobes, material, profiles

TOL = 1e-5


def _dense():
    rng = np.random.default_rng(1)
    # random points, the grid's own points and points just off them, both ends
    return np.concatenate([rng.random(200_000), np.linspace(0, 1, 4097), np.linspace(0, 1, 4097) + 1e-9,
                           [0.0, 1e-12, 1.0 - 1e-12, 1.0]]).clip(0, 1)


@pytest.mark.parametrize("name", sorted(fresnel.PRESETS))
def test_presets_within_tolerance_of_the_exact_formula(name):
    exact = fresnel.conductor_preset(name)
    tab = fresnel.tabulated(exact, TOL)
    assert isinstance(tab, fresnel.Tabulated) and tab.channels == 3
    c = _dense()
    err = np.abs(tab(c) - exact(c)).max()
    assert err < TOL
    assert err <= tab.error * 1.01 + 1e-12       # the stated error is the measured worst
    np.testing.assert_array_equal(tab(0.0), exact(0.0))   # grid points are the model's own samples
    np.testing.assert_array_equal(tab(1.0), exact(1.0))
    np.testing.assert_allclose(tab(0.0), 1.0, atol=1e-12)  # grazing F = 1, like every model


@settings(max_examples=25, deadline=None)
@given(n=st.floats(0.05, 20.0), k=st.floats(0.0, 20.0))
def test_any_conductor_within_tolerance_or_left_exact(n, k):
    exact = fresnel.conductor(n, k)
    tab = fresnel.tabulated(exact, TOL)
    c = _dense()[::7]
    assert np.abs(tab(c) - exact(c)).max() < TOL   # k = 0, n < 1 has a kink (total reflection): finer grid


def test_shapes_nan_and_out_of_range_like_the_exact_model():
    exact = fresnel.conductor([2.91, 2.89, 2.55], [3.09, 2.93, 2.92])
    tab = fresnel.tabulated(exact)
    c = np.array([[np.nan, -0.5, 1.5], [0.3, 0.7, 1.0]])
    assert tab(c).shape == (2, 3, 3)
    np.testing.assert_allclose(tab(c), exact(c), atol=TOL)
    mono = fresnel.tabulated(fresnel.conductor(2.91, 3.09))
    assert mono(np.zeros((4, 5))).shape == (4, 5, 1)


def test_cache_key_differs_from_the_exact_model_and_schlick_passes_through():
    exact = fresnel.conductor_preset("gold")
    assert fresnel.tabulated(exact).cache_key() != exact.cache_key()
    assert fresnel.tabulated(exact) is fresnel.tabulated(fresnel.conductor_preset("gold"))  # built once
    s = fresnel.schlick(1.5)
    assert fresnel.tabulated(s) is s
    with pytest.raises(ValueError, match="tol"):
        fresnel.tabulated(exact, 0.0)


def test_material_tables_are_traced_with_the_table():
    p = material.validate(profile=("quartic", 0.1), fresnel="iron")
    tf = material.trace_fresnel(p)
    assert isinstance(tf, fresnel.Tabulated) and tf.error < material.FRESNEL_TOL
    assert material.trace_fresnel(material.validate(profile=("quartic", 0.1))) is None


def _y(d):
    """Per node, bin group, θo sample and channel: the θo factor P Σ_k coef B_k the shaders render."""
    return np.einsum("sbkc,ktc->sbtc", d["coef"], d["basis"])


def test_table_lobes_equal_with_exact_and_tabulated_fresnel():
    """The tables traced with the tabulated Fresnel equal those of the exact formula: same adaptive nodes,
    same bin distribution and aims, θo factor within the basis tolerance (2e-3 of the albedo)."""
    prof = profiles.v_groove(30.0)
    exact = fresnel.conductor_preset("gold")
    a = lobes.table_lobes(prof, exact, resolution=64, slices=16, use_cache=False)
    b = lobes.table_lobes(prof, fresnel.tabulated(exact), resolution=64, slices=16, use_cache=False)
    np.testing.assert_array_equal(a["phi"], b["phi"])
    np.testing.assert_allclose(a["cdf"], b["cdf"], atol=1e-9)
    np.testing.assert_allclose(a["cen"], b["cen"], atol=1e-9)
    assert a["coef"].shape == b["coef"].shape
    np.testing.assert_allclose(_y(a), _y(b), atol=2e-4)
