"""Tests of the tilted-GGX lobe fitting of scratch BRDF slices (precompute.lobe_fit).

Tables come from the real ``precompute.scratch_brdf.simulate`` (exact beam tracing); the error
metric is the relative L1 between the lobes' cone-collapsed Cycles response and the slice.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from precompute import lobe_fit as lf
from precompute import profiles, scratch_brdf

M = 64


@pytest.fixture(scope="module")
def vgroove_tables():
    return {h: scratch_brdf.simulate(profiles.v_groove(h), resolution=M).rho_m for h in (45.0, 30.0)}


@pytest.fixture(scope="module")
def quartic_table():
    # 1024 segments: facets finer than a bin (a 256-segment polyline gives a facet comb at M = 256)
    return scratch_brdf.simulate(profiles.quartic(0.2, segments=1024), resolution=M).rho_m


def test_known_lobes_are_recovered():
    # A slice made of 3 known lobes (what Cycles would return for them) is fitted to < 1 % with
    # <= 4 lobes, and the fitted lobes reproduce it; an independent check of model/fitter consistency.
    edges = lf.phi_bin_edges(M)
    phi_o = 0.3
    w = np.array([0.6, 0.3, 0.5])
    c = np.array([-0.9, -0.2, 0.7])                 # lobe centres on the cone
    t = 0.5 * (c + phi_o)
    a = np.array([0.08, 0.2, 0.01])
    f = lf.lobe_model(phi_o, w, t, a, edges, alpha_x=1e-4)
    res = lf.fit_lobes(f, phi_o, K=8, error_target=0.01)
    assert res.error <= 0.01
    assert res.n_lobes <= 4
    fit = lf.lobe_model(phi_o, res.weights, res.tilts, res.widths, edges, alpha_x=res.alpha_x)
    assert lf.relative_l1(fit, f) == pytest.approx(res.error, rel=1e-6)
    # the narrow lobe's centre is found to within a bin
    k = np.argmin(np.abs(res.widths - 0.01) + (res.weights == 0))
    assert abs((2 * res.tilts[k] - phi_o) - 0.7) < np.pi / M


def test_vgroove_tables_meet_target_with_few_lobes(vgroove_tables):
    # V-grooves reflect into a few discrete directions per slice: <= 3 % everywhere, few lobes.
    for h, rho in vgroove_tables.items():
        r = lf.fit_table(rho, K=8)
        assert np.all(r["error"] <= 0.03), (h, r["error"].max())
        assert r["n_lobes"].max() <= 4
        assert np.all(r["weights"] >= 0)


def test_fit_table_shapes_bounds_and_consistency(quartic_table):
    K = 5
    r = lf.fit_table(quartic_table, K=K)
    for key in ("weights", "tilts", "widths"):
        assert r[key].shape == (M, K) and np.all(np.isfinite(r[key]))
    assert np.all(r["weights"] >= 0) and np.all(r["n_lobes"] <= K)
    used = r["weights"] > 0
    phi = lf.phi_bin_centres(M)[:, None]
    centre = 2 * r["tilts"] - phi
    assert np.all(np.abs(centre[used]) <= 0.5 * np.pi + 1e-9)           # centres above the horizon
    assert np.all(r["widths"][used] * r["alpha_x"] > 2e-10)              # never singular in Cycles
    # the reported error is the error of the returned lobes against rho cos(phi_i) bin averages
    edges = lf.phi_bin_edges(M)
    f = quartic_table * (np.diff(np.sin(edges)) / np.diff(edges))[None, :]
    fit = lf.lobe_model(phi[:, 0], r["weights"], r["tilts"], r["widths"], edges, alpha_x=r["alpha_x"])
    np.testing.assert_allclose(lf.relative_l1(fit, f), r["error"], rtol=1e-6, atol=1e-12)
    # more lobes never make it worse on the median
    r8 = lf.fit_table(quartic_table, K=8)
    assert np.median(r8["error"]) <= np.median(r["error"]) + 1e-3


def test_quartic_error_regression(quartic_table):
    # Guards the current quality on the shallow quartic (see report: ~10-15 % median at K = 8,
    # limited by the hard cut-offs of the slices vs GGX's heavy tails); must not regress.
    r = lf.fit_table(quartic_table, K=8)
    assert np.median(r["error"]) < 0.2


@pytest.mark.xfail(strict=True, reason="issue #4 target (<= 3 % rel. L1 per slice at K <= 8) not met on quartic")
def test_quartic_meets_issue_target(quartic_table):
    r = lf.fit_table(quartic_table, K=8)
    assert np.percentile(r["error"], 95) <= 0.03


def test_bad_input_raises():
    with pytest.raises(ValueError, match="rho"):
        lf.fit_table(np.ones((4, 5)))
    with pytest.raises(ValueError, match="rho"):
        lf.fit_table(-np.ones((8, 8)))
    with pytest.raises(ValueError, match="K"):
        lf.fit_table(np.ones((8, 8)), K=0)
    with pytest.raises(ValueError, match="phi_o"):
        lf.fit_lobes(np.ones(16), 2.0)
    with pytest.raises(ValueError, match="slice_values"):
        lf.fit_lobes(np.array([1.0, np.nan, 1.0, 1.0]), 0.0)
    with pytest.raises(ValueError, match="min_width"):
        lf.fit_lobes(np.ones(16), 0.0, min_width=1e-7)


@settings(max_examples=25, deadline=None)
@given(phi_o=st.floats(-1.5707, 1.5707), K=st.integers(1, 8), seed=st.integers(0, 2**16),
       n_bumps=st.integers(0, 4))
def test_fuzz_random_smooth_slices(phi_o, K, seed, n_bumps):
    rng = np.random.default_rng(seed)
    x = lf.phi_bin_centres(32)
    f = np.zeros(32)
    for _ in range(n_bumps):
        f += rng.uniform(0, 3) * np.exp(-0.5 * ((x - rng.uniform(-1.6, 1.6)) / rng.uniform(0.01, 1.0)) ** 2)
    r = lf.fit_lobes(f, phi_o, K=K, max_iter=4)
    assert r.weights.shape == (K,) and r.n_lobes <= K
    assert np.all(np.isfinite(r.weights)) and np.all(r.weights >= 0)
    assert np.all(np.isfinite(r.tilts)) and np.all((r.widths > 0) & (r.widths <= 1))
    assert np.isfinite(r.error) and r.error >= 0
    if n_bumps == 0:
        assert r.n_lobes == 0 and r.error == 0
