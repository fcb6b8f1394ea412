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


def test_coverage_table_quadrature_matches_monte_carlo():
    """The tabulated c̄(d) (quadrature of 1 − E_p[Π_j (1 − A_j)]) against the independent Monte Carlo of F1
    (400k points, i.i.d. feature jitter): within 4 standard errors at every grid density."""
    d, c = sl.coverage_table()
    mc = sl.mean_coverage(d)
    se = np.sqrt(np.maximum(c * (1 - c), 1e-12) / 400_000)
    assert np.all(np.abs(c - mc) <= 4 * se + 1e-9), np.max(np.abs(c - mc) / (se + 1e-12))
    assert c[0] == 0 and np.all(np.diff(c) >= 0) and c[-1] == pytest.approx(1.0, abs=1e-6)


def test_coverage_lookup_is_exact_near_zero_and_culls_where_svm_does():
    """The shaders' c̄(d) lookup (COV = c̄ / d², ``coverage_lookup``) is π d² as d -> 0 (issue 15: the linear c̄ table
    read c̄(1e-4) as 8e-6 instead of 3.1e-8 and culled only below d = 1.25e-5), so α_k < ALPHA_CULL exactly below
    d = sqrt(1e-6 / π) = 5.6e-4, the SVM path's CULL_DENSITY."""
    d = np.geomspace(1e-6, 0.02, 50)
    np.testing.assert_allclose(sl.coverage_lookup(d), math.pi * d ** 2, rtol=2e-4)
    d_cull = math.sqrt(sl.ALPHA_CULL / math.pi)
    assert sl.coverage_lookup(d_cull * 0.999) < sl.ALPHA_CULL < sl.coverage_lookup(d_cull * 1.001)
    # and it still follows the table between the nodes (linear in g = c̄ / d², not in c̄)
    grid, c = sl.coverage_table()
    np.testing.assert_allclose(sl.coverage_lookup(grid[:41]), c[:41], rtol=1e-12, atol=1e-15)
    mid = 0.5 * (grid[1:41] + grid[:40])
    np.testing.assert_allclose(sl.coverage_lookup(mid), sl._exact_coverage(mid), atol=2e-3)


def test_union_alpha_keeps_binary_picks_and_sums_to_the_union():
    rng = np.random.default_rng(4)
    a = rng.random((200, 6)) * (rng.random((200, 6)) < 0.5)
    b, s = sl.union_alpha(a)
    np.testing.assert_allclose(s, 1 - np.prod(1 - a, -1), atol=1e-12)
    np.testing.assert_allclose(b.sum(-1), s, atol=1e-12)
    ratio = np.where(a > 0, b / np.where(a > 0, a, 1), 0)   # one scale per point: the pick proportions stay
    for r, m in zip(ratio, a > 0):
        if m.any():
            np.testing.assert_allclose(r[m], r[m][0], rtol=1e-12)
    binary = (rng.random((50, 4)) < 0.4).astype(float)
    bb, sb = sl.union_alpha(binary)
    np.testing.assert_array_equal(sb, binary.max(-1))   # min(Σ α, 1) of eq. 4 where α is 0/1


@pytest.mark.parametrize("n_layers, density", [(4, 0.3), (16, 0.05), (1, 0.4)])
def test_footprint_alpha_is_continuous_into_the_far_field(n_layers, density):
    """issue 15 (OSL far field): the twin of osl/scratch_layer_alpha.h averaged over the surface gives the same
    scratched fraction Σ α_k = 1 − (1 − c̄)^N at every footprint, sharp (binary α, as the SVM twin), in the
    transition, just below and just above the far-field switch.  The old far field (α_k = c̄, eq. 4's min(Σ α, 1))
    read min(N c̄, 1): 100 % instead of 72 % at N = 4, d = 0.3."""
    lp = sl.LayerParams(n_layers, 360.0, 0.02, 0.005, density, seed=2)
    c = float(sl.coverage_lookup(density))
    union = 1 - (1 - c) ** n_layers
    r_far = sl.FAR_SPREAD * math.sqrt(2) * lp.width   # r_uv max(1/l, 1/w) = 0.8 √2
    uv = np.random.default_rng(1).random((20_000, 2)) * 3.0
    means = {}
    for name, r in (("sharp", 1e-3 * lp.width), ("transition", 0.5 * lp.width), ("below", r_far * 0.999),
                    ("above", r_far * 1.001), ("far", 10 * r_far)):
        a, s = sl.footprint_alpha(uv, r, lp)
        assert np.all(s <= 1 + 1e-12) and np.allclose(a.sum(-1), s)
        means[name] = float(s.mean())
    # Σ α over 20k points: std <= 0.5, standard error <= 0.0035 (layers over 3 x 3 UV: ~18k noise cells)
    for name, m in means.items():
        assert abs(m - union) < 0.015, (name, means, union)
    assert abs(means["below"] - means["above"]) < 0.015, means
    assert means["above"] == pytest.approx(union, rel=1e-12)
