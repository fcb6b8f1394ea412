"""Tests of the tilted-GGX lobe fitting of scratch BRDF slices (precompute.scratch.lobe_fit).

Tables come from the real ``precompute.scratch.brdf.simulate`` (exact beam tracing); the error
metric is the relative L1 between the lobes' cone-collapsed Cycles response and the slice.
"""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.scratch import lobe_fit as lf
from scratch_materials.precompute.scratch import profiles, brdf as scratch_brdf

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
    f = lf.lobe_model(phi_o, w, t, a, edges, alpha_x=1e-4, dist=np.array([0, 1, 1]))   # GGX + 2 Beckmann
    res = lf.fit_lobes(f, phi_o, K=8, error_target=0.01, dists="mixed")  # each lobe picks its distribution
    assert res.error <= 0.01
    assert res.n_lobes <= 4
    fit = lf.lobe_model(phi_o, res.weights, res.tilts, res.widths, edges, alpha_x=res.alpha_x, dist=res.dist)
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
    assert r["dist"].shape == (M, K) and set(np.unique(r["dist"])) <= {0, 1}
    fit = lf.lobe_model(phi[:, 0], r["weights"], r["tilts"], r["widths"], edges, alpha_x=r["alpha_x"], dist=r["dist"])
    np.testing.assert_allclose(lf.relative_l1(fit, f), r["error"], rtol=1e-6, atol=1e-12)
    # more lobes never make it worse on the median
    r8 = lf.fit_table(quartic_table, K=8)
    assert np.median(r8["error"]) <= np.median(r["error"]) + 1e-3


def test_quartic_error_regression(quartic_table):
    # Guards the quality on the shallow quartic at M = 64 (measured: median 2.9 %, p95 5.3 % at
    # K = 8 with Beckmann/GGX + quantile restarts; it was 14 % with GGX-only greedy).  GGX-only must
    # be clearly worse: the Beckmann lobes are what makes the box edges.
    r = lf.fit_table(quartic_table, K=8)
    assert np.median(r["error"]) < 0.04
    g = lf.fit_table(quartic_table, K=8, dists="ggx", max_iter=4)
    assert np.median(g["error"]) > np.median(r["error"]) + 0.01


def test_quartic_meets_issue_target_with_12_lobes(quartic_table):
    # The 3 % target is reached on every slice's median and (to 0.5 %) p95 with K = 12 (measured
    # p95 3.0 %, max 3.4 %); Cycles allows 64 closures per shading point.
    r = lf.fit_table(quartic_table, K=12)
    assert np.median(r["error"]) <= 0.03
    assert np.percentile(r["error"], 95) <= 0.035


@pytest.mark.xfail(strict=True, reason="<= 8 *fitted* lobes do not reach issue #4's 3 % (p95 rel. L1) on quartics "
                   "(box lobes: p95 4.9 % here; they meet it on the circular profile); the tabulated-tilt lobes, "
                   "the default, do (tests/test_lobe_table.py)")
@pytest.mark.parametrize("jitter", [False, True], ids=["plain", "jitter"])
def test_quartic_meets_issue_target(quartic_table, jitter):
    r = lf.fit_table(quartic_table, K=8, jitter=jitter)
    assert np.percentile(r["error"], 95) <= 0.03


# ----------------------------------------------------------------------------- jittered (box) lobes
@pytest.fixture(scope="module")
def circular_table():
    return scratch_brdf.simulate(profiles.circular(0.5, segments=1024), resolution=M).rho_m


@pytest.mark.parametrize("d,dists", [([1, 1, 1], "auto"), ([0, 1, 0], "mixed")], ids=["beckmann", "mixed"])
def test_known_jittered_lobes_are_recovered(d, dists):
    # Two boxes (narrow lobes jittered by j: phi_i width 4 j) and a bell, as Cycles renders them on
    # average: refitted to < 1 % with 3 lobes; the boxes' centres and extents are found to ~a bin.
    # (A bell overlapping a box is reproduced too, but with more lobes: the greedy step takes the
    # joint plateau for one box first.)
    edges = lf.phi_bin_edges(M)
    phi_o = -0.2
    w = np.array([0.5, 0.3, 0.4])
    c = np.array([-0.8, 0.6, 0.0])
    j = np.array([0.15, 0.1, 0.0])
    t = 0.5 * (c + phi_o)
    a = np.array([2e-3, 5e-3, 0.05])
    f = lf.lobe_model(phi_o, w, t, a, edges, alpha_x=1e-4, dist=np.array(d), jitters=j)
    res = lf.fit_lobes(f, phi_o, K=8, error_target=0.01, jitter=True, dists=dists)
    assert res.error <= 0.01
    assert res.n_lobes == 3
    assert res.jitters.shape == (8,) and np.all(res.jitters >= 0)
    fit = lf.lobe_model(phi_o, res.weights, res.tilts, res.widths, edges, alpha_x=res.alpha_x, dist=res.dist,
                        jitters=res.jitters)
    assert lf.relative_l1(fit, f) == pytest.approx(res.error, rel=1e-6)
    used = res.weights > 0
    centres = (2 * res.tilts - phi_o)[used]
    for ck, jk in zip(c[:2], j[:2]):
        k = np.argmin(np.abs(centres - ck))
        assert abs(centres[k] - ck) < np.pi / M
        assert abs(4 * res.jitters[used][k] - 4 * jk) < 2 * np.pi / M


def test_jitter_meets_issue_target_on_the_circular_profile(circular_table):
    # A circular groove spreads each bounce order evenly over an interval: its slices are sums of
    # boxes.  Measured at K = 8 (M = 64): plain lobes p95 6.5 %, jittered boxes p95 2.9 %.
    plain = lf.fit_table(circular_table, K=8)
    boxes = lf.fit_table(circular_table, K=8, jitter=True)
    assert np.percentile(boxes["error"], 95) <= 0.03
    assert np.percentile(plain["error"], 95) > 0.04
    assert np.mean(boxes["jitters"][boxes["weights"] > 0] > 0) > 0.5      # it is the boxes that do it


def test_jittered_fit_bounds_consistency_and_regression(quartic_table):
    K = 8
    r = lf.fit_table(quartic_table, K=K, jitter=True)
    phi = lf.phi_bin_centres(M)
    for key in ("weights", "tilts", "widths", "jitters"):
        assert r[key].shape == (M, K) and np.all(np.isfinite(r[key]))
    used = r["weights"] > 0
    assert np.all(r["jitters"] >= 0) and np.all(r["jitters"][~used] == 0)
    # each box stays above the horizon: |centre| + 2 j <= pi/2
    centre = 2 * r["tilts"] - phi[:, None]
    assert np.all((np.abs(centre) + 2 * r["jitters"])[used] <= 0.5 * np.pi + 1e-9)
    # the reported errors are those of the exact jittered model (not the one-panel fitting model)
    edges = lf.phi_bin_edges(M)
    f = quartic_table * (np.diff(np.sin(edges)) / np.diff(edges))[None, :]
    fit = lf.lobe_model(phi, r["weights"], r["tilts"], r["widths"], edges, alpha_x=r["alpha_x"], dist=r["dist"],
                        jitters=r["jitters"])
    np.testing.assert_allclose(lf.relative_l1(fit, f), r["error"], rtol=1e-6, atol=1e-12)
    # measured median 2.9 %, p95 4.9 % (plain lobes: 3.05 %, 6.6 %)
    assert np.median(r["error"]) < 0.034
    assert np.percentile(r["error"], 95) < 0.056
    # without jitter the jitters are all zero (the default model is unchanged)
    assert np.all(lf.fit_table(quartic_table[::8], K=2, phi_o=phi[::8])["jitters"] == 0)


def test_lobe_tables_with_jitter_conserve_energy():
    from scratch_materials.precompute.scratch import fresnel, lobes as scratch_lobes
    from scratch_materials.precompute.cycles.ggx import cone_collapse_binned_jittered

    Mt, S, K = 32, 8, 4
    brdf = scratch_brdf.simulate(profiles.circular(0.5, segments=512), resolution=Mt,
                                 fresnel=fresnel.conductor_preset("iron"))
    out = scratch_lobes.lobe_tables(brdf, K=K, slices=S, use_cache=False, jitter=True)
    edges = lf.phi_bin_edges(Mt)
    C_i = np.diff(np.sin(edges))
    for key, table in (("m", np.asarray(brdf.rho_m)), ("0", np.asarray(brdf.rho0))):
        e = out[key]
        assert e["jitters"].shape == (S, K) and np.all(e["jitters"] >= 0) and np.any(e["jitters"] > 0)
        atoms = cone_collapse_binned_jittered(out["phi_o"][:, None], edges, e["tilts"], e["widths"], e["jitters"],
                                              out["alpha_x"], dist=e["dist"])
        albedo = (atoms * np.diff(edges)).sum(-1)                                     # [S, K]
        rows = lf.rows_at(table if table.ndim == 3 else table[..., None], out["phi_o"])  # [S, M, C]
        want = np.einsum("smc,m->sc", rows, C_i)
        got = np.einsum("skc,sk->sc", e["weights"][..., :want.shape[1]], albedo)
        np.testing.assert_allclose(got, want, rtol=1e-9)
    with pytest.raises(ValueError, match="jitter"):
        scratch_lobes.lobe_tables(brdf, K=K, slices=S, use_cache=False, jitter="yes")


def test_rows_at_interpolates_linearly_between_bin_centres():
    rng = np.random.default_rng(0)
    rho = rng.random((16, 16))
    c = lf.phi_bin_centres(16)
    np.testing.assert_allclose(lf.rows_at(rho, c), rho, rtol=0, atol=1e-12)        # at the centres: the rows
    mid = 0.5 * (c[3] + c[4])
    np.testing.assert_allclose(lf.rows_at(rho, [mid])[0], 0.5 * (rho[3] + rho[4]), atol=1e-12)
    np.testing.assert_allclose(lf.rows_at(rho, [-np.pi / 2])[0], rho[0], atol=1e-12)   # clamped at the ends
    assert lf.rows_at(rho[..., None].repeat(3, -1), c[:2]).shape == (2, 16, 3)
    # the shader's slices: S = 8 slices of a 16-bin table sit on bin edges -> mean of two rows
    np.testing.assert_allclose(lf.rows_at(rho, lf.slice_centres(8)), 0.5 * (rho[0::2] + rho[1::2]), atol=1e-12)


def test_fit_table_at_given_phi_o_fits_those_rows(quartic_table):
    S = 16
    po = lf.slice_centres(S)
    rows = lf.rows_at(quartic_table, po)
    r = lf.fit_table(rows, K=8, phi_o=po)
    np.testing.assert_array_equal(r["phi_o"], po)
    edges = lf.phi_bin_edges(M)
    f = rows * (np.diff(np.sin(edges)) / np.diff(edges))[None, :]
    fit = lf.lobe_model(po, r["weights"], r["tilts"], r["widths"], edges, alpha_x=r["alpha_x"], dist=r["dist"])
    np.testing.assert_allclose(lf.relative_l1(fit, f), r["error"], rtol=1e-6, atol=1e-12)
    # fitting the rows at other angles gives a different (worse) model for these rows
    wrong = lf.lobe_model(po + np.pi / M, r["weights"], r["tilts"], r["widths"], edges, alpha_x=r["alpha_x"],
                          dist=r["dist"])
    assert np.median(lf.relative_l1(wrong, f)) > np.median(r["error"])


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
    with pytest.raises(ValueError, match="dists"):
        lf.fit_lobes(np.ones(16), 0.0, dists="phong")
    with pytest.raises(ValueError, match="phi_o"):
        lf.fit_table(np.ones((3, 8)), phi_o=[0.0, 0.1])
    with pytest.raises(ValueError, match="phi_o"):
        lf.fit_table(np.ones((2, 8)), phi_o=[0.0, 1.6])
    with pytest.raises(ValueError, match="phi_o"):
        lf.rows_at(np.ones((8, 8)), [2.0])


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
    assert set(np.unique(r.dist)) <= {0, 1}
    if n_bumps == 0:
        assert r.n_lobes == 0 and r.error == 0


@settings(max_examples=15, deadline=None)
@given(phi_o=st.floats(-1.5707, 1.5707), K=st.integers(1, 6), seed=st.integers(0, 2**16),
       n_boxes=st.integers(0, 3), margin=st.sampled_from([0.0, 0.1]))
def test_fuzz_random_box_slices_with_jitter(phi_o, K, seed, n_boxes, margin):
    rng = np.random.default_rng(seed)
    x = lf.phi_bin_centres(32)
    f = np.zeros(32)
    for _ in range(n_boxes):
        lo, hi = np.sort(rng.uniform(-1.6, 1.6, 2))
        f += rng.uniform(0, 3) * ((x > lo) & (x < hi + 0.1))
    r = lf.fit_lobes(f, phi_o, K=K, max_iter=4, margin=margin, jitter=True)
    assert r.weights.shape == r.jitters.shape == (K,) and r.n_lobes <= K
    for a in (r.weights, r.tilts, r.widths, r.jitters):
        assert np.all(np.isfinite(a))
    assert np.all(r.weights >= 0) and np.all(r.jitters >= 0) and np.all((r.widths > 0) & (r.widths <= 1))
    used = r.weights > 0
    assert np.all(np.abs(2 * r.tilts - phi_o)[used] + 2 * r.jitters[used] <= 0.5 * np.pi - margin + 1e-9)
    assert np.isfinite(r.error) and r.error >= 0
    if n_boxes == 0:
        assert r.n_lobes == 0 and r.error == 0
