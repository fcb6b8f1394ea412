"""Layer distributions (eq. 7), the noise's mean coverage, and the lobe-table helpers (numpy only)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import nnls

from scratch_materials.osl import const_array
from scratch_materials.precompute.scratch import layers as sl
from scratch_materials.precompute.scratch.lobes import nnls_batched


@pytest.mark.parametrize("kwargs, needle", [
    (dict(n_layers=0), "n_layers"), (dict(n_layers=65), "n_layers"), (dict(n_layers=2.0), "n_layers"),
    (dict(theta_deg=-1), "theta_deg"), (dict(theta_deg=400), "theta_deg"),
    (dict(density=1.5), "density"), (dict(density=float("nan")), "density"),
    (dict(width=-1e-3), "width"), (dict(length=0.0), "length"), (dict(width=float("inf")), "width"),
    (dict(length=0.1, width=0.2), "width"), (dict(seed=1.5), "seed"),
])
def test_layer_params_reject_bad_values(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        sl.LayerParams(**kwargs)


@given(n=st.integers(1, 64), theta=st.floats(0, 360), seed=st.integers(-2**40, 2**40))
@settings(max_examples=40, deadline=None)
def test_layer_transforms_ranges_and_determinism(n, theta, seed):
    p = sl.LayerParams(n_layers=n, theta_deg=theta, seed=seed)
    th, xi = sl.layer_transforms(p)
    assert th.shape == (n,) and xi.shape == (n, 2)
    assert np.all(np.abs(th) <= math.radians(theta) / 2 + 1e-12) and np.all(np.abs(xi) <= 1)
    th2, xi2 = sl.layer_transforms(p)
    assert np.array_equal(th, th2) and np.array_equal(xi, xi2)


def test_mean_coverage_limits():
    # small d: one feature point per unit cell, disks rarely overlap -> c(d) ~ pi d^2
    d = np.array([0.02, 0.05])
    np.testing.assert_allclose(sl.mean_coverage(d, samples=2_000_000), math.pi * d ** 2, rtol=0.05)
    c = sl.mean_coverage(sl.COVERAGE_D)
    assert c[0] == 0 and np.all(np.diff(c) >= 0) and c[-1] == pytest.approx(1.0, abs=1e-3)
    # a jittered grid overlaps less than a Poisson process of equal density, so it covers more
    assert sl.mean_coverage(0.6) > 1 - math.exp(-math.pi * 0.36)
    with pytest.raises(ValueError, match="density"):
        sl.mean_coverage(-0.1)


@given(seed=st.integers(0, 10_000), K=st.integers(1, 8), m=st.integers(8, 40))
@settings(max_examples=30, deadline=None)
def test_nnls_batched_matches_scipy(seed, K, m):
    rng = np.random.default_rng(seed)
    A = rng.random((3, m, K))
    b = rng.random((3, m)) - 0.2
    x = nnls_batched(A, b, iters=2000)
    for i in range(3):
        ref, _ = nnls(A[i], b[i])
        r_ours = np.linalg.norm(A[i] @ x[i] - b[i])
        r_ref = np.linalg.norm(A[i] @ ref - b[i])
        assert np.all(x[i] >= 0) and r_ours <= r_ref * (1 + 1e-4) + 1e-9


@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=32), min_size=1, max_size=20))
@settings(max_examples=50, deadline=None)
def test_const_array_literals_round_trip_float32(values):
    text = const_array("X", values)
    body = text[text.index("{") + 1:text.rindex("}")]
    parsed = np.array([float(v) for v in body.replace("\n", " ").split(",")], np.float32)
    assert np.array_equal(parsed, np.array(values, np.float32))


def test_merged_layers_keep_the_scratched_fraction():
    from scratch_materials.precompute.scratch.layers import LayerParams, coverage_table, layer_transforms, merged_layers

    d, cbar = coverage_table()
    for n, dens in ((32, 0.05), (32, 0.2), (16, 0.3), (64, 0.1)):
        p = LayerParams(n, 360.0, 0.1, 1e-4, dens, seed=3)
        q = merged_layers(p, 8)
        assert q.n_layers == 8 and q.density > p.density
        union = lambda k, dd: 1.0 - (1.0 - np.interp(dd, d, cbar)) ** k  # noqa: E731 - independent layers
        # interpolation in the 61-point table: < 0.003 in c̄, so the unions agree to ~0.01
        assert abs(union(8, q.density) - union(n, p.density)) < 0.01, (n, dens, q.density)
        t_p, _ = layer_transforms(p)
        t_q, _ = layer_transforms(q)
        np.testing.assert_array_equal(t_q, t_p[:8])  # the same orientations, fewer layers
    small = LayerParams(4, 7.0, 0.2, 2e-4, 0.6)
    assert merged_layers(small, 8) is small
    with pytest.raises(ValueError, match="n_max"):
        merged_layers(small, 0)
