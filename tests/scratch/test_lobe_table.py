"""Tabulated-tilt lobes (precompute.scratch.lobe_table): a scratch BRDF slice rendered bin by bin by one
sampled narrow lobe, against independent references.

- the error target of issue #4 (<= 3 % rel. L1 per slice) on quartic, circular and V-groove tables
  from the real beam tracer, where <= 8 fitted lobes stay at 5-11 % (tests/test_lobe_fit.py);
- the model (sum_b w_b A_b) against a Monte Carlo average of what the shader samples (bin by the
  CDF, tilt inside the bin, weight W P / p), with plain ``cone_collapse_binned`` lobes;
- the shader's binary search (``sample_bins``) against ``np.searchsorted``;
- energy: every slice reflects exactly the table's albedo; bad input raises.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.cycles import ggx as cycles_ggx
from scratch_materials.precompute.scratch import (fresnel, lobe_fit as lf, lobe_table as lt, profiles, brdf as scratch_brdf, lobes as
                                scratch_lobes)

M = 64


@pytest.fixture(scope="module")
def tables():
    return {name: scratch_brdf.simulate(p, resolution=M).rho_m for name, p in [
        ("quartic_0.2", profiles.quartic(0.2, segments=1024)), ("quartic_1.0", profiles.quartic(1.0, segments=1024)),
        ("circular_0.5", profiles.circular(0.5, segments=1024)), ("v_groove_45", profiles.v_groove(45.0))]}


@pytest.mark.parametrize("name", ["quartic_0.2", "quartic_1.0", "circular_0.5", "v_groove_45"])
def test_table_lobes_meet_issue_target(tables, name):
    phi = lf.slice_centres(32)
    rows = lf.rows_at(tables[name], phi)
    w, err, A = lt.fit_bins(rows, phi)
    # measured max 0.05-0.8 % (V-groove: one-bin mirror peaks, the GGX tail spill); target 3 %
    assert err.max() <= 0.03, (name, err.max())
    # the error is really that of the model: recompute it independently
    e = lf.phi_bin_edges(M)
    f = rows * (np.diff(np.sin(e)) / np.diff(e))
    assert np.allclose(lf.relative_l1(lt.model(w, A), f), err)


def test_energy_is_the_tables_albedo(tables):
    phi = lf.slice_centres(16)
    rows = lf.rows_at(tables["quartic_1.0"], phi)
    w, _, A = lt.fit_bins(rows, phi)
    e = lf.phi_bin_edges(M)
    albedo = rows @ np.diff(np.sin(e))
    rendered = (lt.model(w, A) * np.diff(e)).sum(1)
    np.testing.assert_allclose(rendered, albedo, rtol=1e-9)


def test_model_equals_monte_carlo_of_the_shader_sampling():
    """Average of what the shader draws (plain narrow lobes at sampled tilts, weight P / p_b) = the model."""
    rng = np.random.default_rng(1)
    Mb, S = 32, 3
    phi = np.array([-0.9, 0.1, 0.7])
    rows = rng.random((S, Mb)) * (rng.random((S, Mb)) > 0.4)
    w, _, A = lt.fit_bins(rows, phi)
    cdf, total = lt.proposal(w)
    n = 20000
    h = (np.arange(n) + rng.random(n)) / n                  # stratified uniforms
    e = lf.phi_bin_edges(Mb)
    ay = lt.default_width(Mb)
    for s in range(S):
        b, fr = lt.sample_bins(cdf, np.full(n, s), h)
        tilt = 0.5 * (e[b] + fr * np.pi / Mb + phi[s])
        atoms = cycles_ggx.cone_collapse_binned(phi[s], e, tilt, ay, 1e-4)          # [n, Mb]
        mc = (total[s] * atoms).mean(0)                                               # weight P/p * p-weight w: P
        ref = lt.model(w[s:s + 1], A[s:s + 1])[0]
        assert lf.relative_l1(mc, ref) < 0.01, (s, lf.relative_l1(mc, ref))


@settings(max_examples=60, deadline=None)
@given(st.integers(4, 300), st.lists(st.floats(0.0, 1.0, exclude_max=True), min_size=1, max_size=20),
       st.integers(0, 2**31 - 1))
def test_binary_search_is_searchsorted(Mb, hs, seed):
    rng = np.random.default_rng(seed)
    p = rng.random((2, Mb)) * (rng.random((2, Mb)) > 0.5)
    p[:, 0] += 1e-3
    cdf, _ = lt.proposal(p)
    h = np.array(hs)
    for s in range(2):
        b, fr = lt.sample_bins(cdf, np.full(h.size, s), h)
        expect = np.searchsorted(cdf[s], h, side="right") - 1
        np.testing.assert_array_equal(b, np.clip(expect, 0, Mb - 1))
        assert np.all(p[s, b] > 0)                            # empty bins are never picked
        assert np.all((fr >= 0) & (fr <= 1))


def test_lossy_tables_and_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SCRATCH_ADDON_CACHE", str(tmp_path))
    prof, gold = profiles.quartic(0.3, segments=512), fresnel.conductor_preset("gold")
    t = scratch_lobes.table_lobes(prof, gold, resolution=M, slices=16, use_cache=False)
    S = t["phi"].size
    assert t["cdf"].shape == (S, M + 1) and t["cen"].shape == (S, M) and t["total"].shape == (S,)
    K, NT = t["basis"].shape[:2]
    assert t["coef"].shape == (S, M // t["y_group"], K, 3) and t["basis"].shape == (K, NT, 3)
    # adaptive nodes: a dyadic refinement of 16 uniform intervals, every uniform cell mapped to its interval
    assert S >= 17 and np.all(np.diff(t["phi"]) > 0) and t["phi"][0] == -0.5 * np.pi and t["phi"][-1] == 0.5 * np.pi
    cells = -0.5 * np.pi + (np.arange(t["cell"].size) + 0.5) * np.pi / t["cell"].size
    assert np.all((t["phi"][t["cell"]] <= cells) & (cells <= t["phi"][t["cell"] + 1]))
    assert t["error_m"] < 0.01 and t["error_0"] < 0.01
    np.testing.assert_allclose(t["cdf"][:, -1][t["total"] > 0], 1.0)
    assert np.all(np.diff(t["cdf"], axis=1) >= 0)
    t2 = scratch_lobes.table_lobes(prof, gold, resolution=M, slices=16)
    t3 = scratch_lobes.table_lobes(prof, gold, resolution=M, slices=16)       # from the cache
    np.testing.assert_allclose(t2["coef"], t3["coef"], rtol=1e-6)
    np.testing.assert_allclose(t2["cdf"], t["cdf"], rtol=1e-6)  # the cache returns its float32 form from the first call
    with pytest.raises(ValueError, match="slices"):
        scratch_lobes.table_lobes(prof, gold, resolution=M, slices=15)


@pytest.mark.parametrize("call, needle", [
    (lambda: lt.bin_atoms([0.1], 3), r"M \(phi_i bins\) must be an integer in \[4, 4096\]"),
    (lambda: lt.bin_atoms([2.0], 16), "phi_o must be"),
    (lambda: lt.fit_bins(-np.ones((2, 8)), np.zeros(2)), "rows must be finite and >= 0"),
    (lambda: lt.fit_bins(np.ones((2, 8)), np.zeros(2), sweeps=-1), "sweeps"),
    (lambda: lt.fit_bins(np.ones((2, 8)), np.zeros(3)), "one view angle per row"),
    (lambda: lt.sample_bins(np.array([[0.0, 1.0]]), [0], [1.0]), "h must be"),
    (lambda: lt.sample_bins(np.array([[0.0, 1.0]]), [1], [0.5]), "s must be slice indices"),
    (lambda: lt.fit_bins(np.ones((2, 8)), np.zeros(2), atoms=np.ones((2, 8, 4))), "atoms must have shape"),
    (lambda: cycles_ggx.cone_collapse_binned_jittered_windows(0.0, np.array([[0.1, 0.0]]), 0.0, 1e-3, 0.01),
     "window_edges"),
    (lambda: cycles_ggx.cone_collapse_binned_jittered_windows(0.0, np.array([[0.0, 0.1]]), 0.0, 1e-3, -0.01),
     "jitter"),
])
def test_bad_input(call, needle):
    with pytest.raises(ValueError, match=needle):
        call()


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([4, 8, 16, 64]),
       st.lists(st.sampled_from([-1.5707963, -1.5707, -1.3, -0.2, 0.0, 0.9, 1.5707, 1.5707963]), min_size=1, max_size=4),
       st.floats(-12, 6), st.floats(0.0, 0.99), st.integers(0, 2**31 - 1))
def test_fit_bins_fuzz_grazing_views_sparse_and_extreme_rows(Mb, phis, log_scale, sparsity, seed):
    """Grazing views (|phi_o| -> pi/2), rows that are empty, one-bin or span 18 orders of magnitude:
    finite non-negative weights, a finite error in [0, 1], and never more energy than the table."""
    rng = np.random.default_rng(seed)
    phi = np.array(phis)
    rows = rng.random((phi.size, Mb)) * (rng.random((phi.size, Mb)) > sparsity) * 10.0 ** log_scale
    rows[0, :] = 0.0 if seed % 3 == 0 else rows[0, :]           # an all-zero slice now and then
    w, err, A = lt.fit_bins(rows, phi)
    assert np.all(np.isfinite(w)) and np.all(w >= 0)
    assert np.all(np.isfinite(err)) and np.all(err >= 0) and np.all(err <= 1.0 + 1e-9)
    e = lf.phi_bin_edges(Mb)
    albedo = rows @ np.diff(np.sin(e))
    rendered = (lt.model(w, A) * np.diff(e)).sum(1)
    assert np.all(rendered <= albedo * (1 + 1e-9) + 1e-300)
    cdf, total = lt.proposal(w)
    assert np.all(np.isfinite(cdf)) and np.all(np.diff(cdf, axis=1) >= 0)
    assert np.all((cdf[:, -1] == 1.0) | (total == 0))


@pytest.mark.parametrize("Mb, phis", [(16, [-1.5, 0.0, 1.2]), (64, [-0.3, 1.5707])])
def test_banded_atoms_equal_the_full_range_evaluation(Mb, phis):
    full = lt.bin_atoms(phis, Mb, band=None)
    banded = lt.bin_atoms(phis, Mb)
    inside = banded != 0
    np.testing.assert_allclose(banded[inside], full[inside], rtol=1e-12, atol=0)
    assert np.abs(banded - full).sum() <= 1e-4 * full.sum()        # the dropped GGX tails
    with pytest.raises(ValueError, match="band"):
        lt.bin_atoms(phis, Mb, band=0)


def test_alias_table_samples_the_bin_distribution_exactly():
    """The alias table (one lookup, both render paths) picks bin b with probability exactly p_b of the CDF
    (``alias_pmf``, exact), the sampler's histogram agrees (chi-square) and the fraction inside the bin is
    uniform; a table built from another distribution fails."""
    from scipy import stats

    rng = np.random.default_rng(3)
    w = rng.random((6, 32)) ** 6
    w[1] = 0.0            # an empty slice
    w[4, 5:] = 0.0        # trailing empty bins
    cdf, total = lt.proposal(w)
    prob, alias = lt.alias_table(cdf)
    p = np.diff(cdf, axis=1)
    live = total > 0
    np.testing.assert_allclose(lt.alias_pmf(prob, alias)[live], p[live], atol=1e-12)
    assert np.all((prob >= 0) & (prob <= 1)) and np.all((alias >= 0) & (alias < 32))
    n = 200_000
    for s in (0, 4):
        b, frac = lt.sample_alias(prob, alias, np.full(n, s), rng.random(n))
        counts = np.bincount(b, minlength=32)
        keep = p[s] > 0
        assert counts[~keep].sum() == 0
        assert stats.chisquare(counts[keep], n * p[s][keep]).pvalue > 1e-3
        assert stats.kstest(frac[b == np.argmax(p[s])], "uniform").pvalue > 1e-3
    other_prob, other_alias = lt.alias_table(lt.proposal(np.roll(w, 3, axis=1))[0])  # broken: wrong table
    assert np.abs(lt.alias_pmf(other_prob, other_alias)[0] - p[0]).max() > 1e-3
