"""The fast method of the scratch BRDF tracer (``simulate(method="fast")``, issue #14): fewer traced incident
directions, chosen by the table error they add, against the exact method (the oracle)."""
import numpy as np
import pytest

from scratch_materials.precompute.scratch import brdf, fresnel, profiles

M = 64
FR = fresnel.conductor([0.2, 0.9, 1.1], [3.0, 2.5, 2.0])


def _noisy(seed: int, amp: float = 2e-4, corr: int = 16, depth: float = 0.3, n: int = 700) -> profiles.Profile:
    """A sin^2 groove plus instrument-like noise (``corr``-sample box-filtered white noise): its segment
    slopes are random (rms ~0.03-0.07 rad), so every segment scatters light and simplification keeps them."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0.0, 1.0, n)
    h = -depth * np.sin(np.pi * x) ** 2 + np.convolve(rng.standard_normal(n + corr - 1), np.ones(corr) / corr,
                                                      "valid") * amp * (4096 / n)
    return profiles.tabulated(x, h)


def _err(a: brdf.ScratchBRDF, b: brdf.ScratchBRDF) -> float:
    """Largest relative L1 difference of rho_m and of each rho0 channel (``b`` the reference)."""
    pairs = [(a.rho_m[..., 0], b.rho_m[..., 0])] + [(a.rho0[..., c], b.rho0[..., c]) for c in range(3)]
    return max(float(np.abs(x.astype(float) - y).sum() / np.abs(y.astype(float)).sum()) for x, y in pairs)


_CASES = [(1, 2e-4, 16, 0.3), (2, 1e-4, 8, 0.3), (3, 3e-4, 24, 0.2)]
_EXACT = {}


def _exact(case):
    if case not in _EXACT:
        _EXACT[case] = brdf.simulate(_noisy(*case), M, FR, max_seconds=np.inf)
    return _EXACT[case]


@pytest.mark.parametrize("case", _CASES)
@pytest.mark.parametrize("tol", [0.05, 0.03])
def test_fast_table_within_its_bound_of_the_exact_one(case, tol):
    prof = _noisy(*case)
    assert prof.segments > brdf.FAST_MIN_SEGMENTS
    fast = brdf.simulate(prof, M, FR, method="fast", max_table_error=tol, max_seconds=np.inf)
    info = fast.meta["fast"]
    assert info["stride"] >= 1, "the fast path was not used: the test would compare exact with exact"
    assert info["table_error_estimate"] <= tol
    err = _err(fast, _exact(case))
    assert err <= tol, (err, info)
    assert abs(fast.lost - _exact(case).lost) < 1e-6


def test_fast_table_within_its_bound_at_128(monkeypatch):
    """M = 128 (strides 4, 2 and 1 tried; at M = 256 the fast method also takes rows 2-3 at each horizon from
    reciprocity, ``_FAST_RECIPROCITY``: forced here at 128)."""
    monkeypatch.setattr(brdf, "_FAST_RECIPROCITY", 32)
    case = _CASES[0]
    prof = _noisy(*case)
    fast = brdf.simulate(prof, 128, FR, method="fast", max_seconds=np.inf)
    assert fast.meta["fast"]["stride"] >= 1
    exact = brdf.simulate(prof, 128, FR, max_seconds=np.inf)
    assert _err(fast, exact) <= 0.05


def test_a_broken_error_estimate_violates_the_bound(monkeypatch):
    """With the estimate forced to 0 the coarsest stride is always taken: on these profiles its error exceeds
    a 2 % bound that the real estimate keeps (it refines instead)."""
    tol = 0.02
    case = _CASES[0]
    ok = brdf.simulate(_noisy(*case), M, FR, method="fast", max_table_error=tol, max_seconds=np.inf)
    assert _err(ok, _exact(case)) <= tol
    monkeypatch.setattr(brdf, "_table_diff", lambda a, b: 0.0)
    bad = brdf.simulate(_noisy(*case), M, FR, method="fast", max_table_error=tol, max_seconds=np.inf)
    assert bad.meta["fast"]["stride"] == brdf._fast_strides(M)[0]
    assert _err(bad, _exact(case)) > tol


def test_wide_sub_bins_cut_at_bin_edges(monkeypatch):
    """Integrating a path across a sub-bin that spans several phi_i bins as if it were one bin (no cuts at
    the phi_i / phi_o bin edges inside it) is far outside the bound."""
    case = _CASES[0]
    monkeypatch.setattr(brdf, "_table_diff", lambda a, b: 0.0)  # stride 4, whatever its error
    good = brdf.simulate(_noisy(*case), M, FR, method="fast", max_seconds=np.inf)
    assert good.meta["fast"]["stride"] == 4
    assert _err(good, _exact(case)) < 0.08
    monkeypatch.setattr(brdf, "_span", lambda edges, M: 1)
    bad = brdf.simulate(_noisy(*case), M, FR, method="fast", max_seconds=np.inf)
    assert bad.meta["fast"]["stride"] == 4
    assert _err(bad, _exact(case)) > 0.2


def test_fast_keeps_energy():
    """Lossless profile, rho_m: every phi_i column's furnace albedo is 1 - lost, as in the exact method
    (each traced sub-bin keeps exactly its incident energy; a sub-bin of several phi_i bins shares it)."""
    prof = _noisy(4)
    fast = brdf.simulate(prof, M, None, method="fast", max_seconds=np.inf)
    assert fast.meta["fast"]["stride"] >= 1
    a = fast.albedo()
    exact = brdf.simulate(prof, M, None, max_seconds=np.inf).albedo()
    assert np.max(np.abs(a - 1.0)) < 0.02
    assert np.max(np.abs(a - exact)) < 0.02


@pytest.mark.parametrize("prof", [profiles.v_groove(45.0), profiles.v_groove(70.0), profiles.quartic(0.3)])
def test_small_profiles_stay_exact(prof):
    """V-grooves and the analytic families (<= FAST_MIN_SEGMENTS segments): the fast method is the exact one."""
    fast = brdf.simulate(prof, 32, FR, method="fast")
    exact = brdf.simulate(prof, 32, FR)
    assert fast.meta["fast"]["stride"] == 0
    for k in ("rho0", "rho_m", "gamma"):
        np.testing.assert_array_equal(getattr(fast, k), getattr(exact, k))


def test_fast_estimate_is_cheaper_and_bounded():
    prof = _noisy(1, n=2000)
    e = brdf.estimate_cost(prof, 256, FR)
    f = brdf.estimate_cost(prof, 256, FR, method="fast")
    assert f.nodes < e.nodes / 5
    assert f.seconds < e.seconds / 2
    assert f.peak_bytes < brdf.budget.MEMORY_BUDGET


@pytest.mark.parametrize("bad", [0.0, -0.1, 2.0, float("nan"), "x", None])
def test_bad_max_table_error(bad):
    with pytest.raises(ValueError, match="max_table_error"):
        brdf.simulate(profiles.v_groove(45.0), 8, method="fast", max_table_error=bad)


def test_fast_tables_do_not_depend_on_the_parts():
    """Parts of a few traced directions (a large profile's memory budget) give the same fast tables as two
    parts: every part's accumulator covers exactly its own phi_i columns, also when its sub-bins are wide."""
    prof = brdf._simplified(_noisy(5), M, "auto")
    a, la, a2 = brdf._exact_tables(prof, M, 1, None, (), False, 64, 1, part_nodes=4, stride=4, coarse=True)
    b, lb, b2 = brdf._exact_tables(prof, M, 1, None, (), False, 64, 1, part_nodes=64, stride=4, coarse=True)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(a2, b2, rtol=1e-9, atol=1e-12)
    assert la == lb


def test_a_refinement_beyond_max_seconds_is_refused():
    """A tolerance no stride reaches needs further passes: one whose estimate exceeds what is left of
    max_seconds raises ValueError (before it starts) instead of running past the limit."""
    prof = _noisy(1)
    first = brdf.estimate_cost(prof, M, None, method="fast").seconds
    with pytest.raises(ValueError, match="max_seconds"):
        brdf.simulate(prof, M, None, method="fast", max_table_error=1e-4, max_seconds=1.5 * first)


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=12, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**32 - 1), amp=st.floats(0.0, 1e-3), corr=st.integers(1, 32),
       M=st.integers(2, 24), tol=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just(0.05)))
def test_fast_fuzz_finite_or_named_error(seed, amp, corr, M, tol):
    """Any noisy profile, resolution and max_table_error: finite tables that keep the furnace bound, or a
    ValueError naming max_table_error."""
    prof = _noisy(seed, amp=amp, corr=corr, n=600)
    try:
        b = brdf.simulate(prof, M, None, method="fast", max_table_error=tol, max_seconds=60.0)
    except ValueError as e:
        assert "max_table_error" in str(e)
        return
    assert np.all(np.isfinite(b.rho_m)) and np.all(b.rho_m >= 0)
    assert np.all(b.albedo() <= 1.0 + 0.02)


# ---- the wide-sub-bin integration (``brdf._integrate_wide``) against the exact method's integration ----
def _wide_vs_narrow(prof, M, stride):
    """rho_m of the same paths integrated across wide sub-bins (one traced node per ``stride`` bins) and across
    one-bin sub-bins (a traced node at every bin edge: ``_integrate``'s per-bin pieces)."""
    wide, _ = brdf._exact_tables(prof, M, 1, None, (), False, 64, 1, stride=stride)
    narrow, _ = brdf._exact_tables(prof, M, 1, None, (), False, 64, 1)
    return float(np.abs(wide - narrow).max() / np.abs(narrow).max())


@pytest.mark.parametrize("stride", [4, 2])
def test_wide_sub_bins_integrate_like_narrow_ones(stride):
    """70-degree V-groove, no Fresnel: every exit path keeps its bounding vertices or changes them once per wide
    sub-bin, so the flux model is the same whether a path is followed across 1 or ``stride`` bins: the wide
    integration (regular cuts, antiderivative differences) equals the per-bin one to rounding."""
    assert _wide_vs_narrow(profiles.v_groove(70.0), 64, stride) < 1e-10


def test_wide_sub_bins_need_the_phi_o_cuts(monkeypatch):
    """Without the cuts where phi_o crosses its bin edges (a piece's whole flux lands in one phi_o bin) the
    same comparison fails by far."""
    def no_phi_o_cuts(pa, lo, hi, sgn, c, M, span):  # the phi_i bin edges only (each twice: same shape)
        h = np.pi / M
        u = -0.5 * np.pi + (np.floor((pa + 0.5 * np.pi) / h) + 1.0) * h
        x = np.concatenate([lo[:, None], u[:, None] + (np.arange(2 * span) // 2) * h, hi[:, None]], 1)
        return np.clip(x, lo[:, None], hi[:, None])

    monkeypatch.setattr(brdf, "_wide_breakpoints", no_phi_o_cuts)
    assert _wide_vs_narrow(profiles.v_groove(70.0), 64, 4) > 1e-2


def test_wide_breakpoints_are_every_bin_edge_crossing():
    """``_wide_breakpoints`` (no sort: two interleaved regular grids) against a brute-force sorted list of the
    phi_i bin edges and the phi_o bin-edge crossings inside each sub-bin (``[lo, hi]``; horizon clipping aside)."""
    rng = np.random.default_rng(3)
    M, span, n = 64, 4, 400
    h = np.pi / M
    pa = -0.5 * np.pi + rng.integers(0, M - span, n) * h + rng.uniform(0, 1, n) * h * (rng.uniform(size=n) < 0.3)
    width = rng.uniform(0.05, 1.0, n) * span * h
    pb = pa + width
    sgn = np.where(rng.uniform(size=n) < 0.5, 1.0, -1.0)
    c = rng.uniform(-1.0, 1.0, n)
    lo = pa + rng.uniform(0, 0.3, n) * width
    hi = pb - rng.uniform(0, 0.3, n) * width
    x = brdf._wide_breakpoints(pa, lo, hi, sgn, c, M, span)
    assert x.shape == (n, 2 * span + 2)
    assert np.all(np.diff(x, axis=1) >= 0.0)
    E = -0.5 * np.pi + np.arange(-M, 2 * M + 1) * h  # the grid continued past the horizon: cuts there are harmless
    for r in range(n):
        want = [lo[r], hi[r]] + [e for e in E if lo[r] < e < hi[r]]
        want += [p for p in sgn[r] * (E - c[r]) if lo[r] < p < hi[r]]
        got = np.unique(np.round(x[r], 12))
        np.testing.assert_allclose(got, np.unique(np.round(want, 12)), atol=1e-12)
