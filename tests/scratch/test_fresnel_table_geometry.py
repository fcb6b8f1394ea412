"""Fresnel after the trace (issue 18: a metal edit without tracing again).  ``beam.trace_exact(cos_path=True)``
records every exit's bounce cosines; ``beam.path_fresnel`` weights them by any Fresnel model and θo.
``slices._trace`` keeps that geometry per profile (``slices.GEOMETRY_BYTES``) and traces each view direction once.

Oracle: ``beam.trace_exact`` with the Fresnel model inside the trace (the product per bounce as the beam
travels), record for record and bit for bit; the view slices / table lobes with the store off."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.scratch import beam, fresnel, lobes, material, profiles, slices


def _model(name):
    return material.trace_fresnel(material.validate(fresnel=name))


def _cos(T):
    return np.cos(slices.theta_of_coordinate(np.linspace(0.0, 1.0, T)))


@pytest.mark.parametrize("prof, metal", [(profiles.quartic(0.08), "iron"), (profiles.v_groove(30), "gold"),
                                         (profiles.circular(0.5), "aluminium"), (profiles.quartic(0.3), "copper")])
def test_path_fresnel_is_the_traced_fresnel_bit_for_bit(prof, metal):
    F, cs = _model(metal), _cos(9)
    phi = np.linspace(-1.5707, 1.5707, 23)
    v = prof.periodic_vertices()
    traced = beam.trace_exact(v, phi, F, tuple(cs))
    geo = beam.trace_exact(v, phi, None, (), cos_path=True)
    for k in ("sample", "pid", "bounces", "phi_o", "weight", "flux_ab", "lost", "bounds"):
        np.testing.assert_array_equal(getattr(geo, k), getattr(traced, k), err_msg=k)
    assert geo.cos_path.shape == (geo.sample.size, geo.bounces.max())
    assert np.all((geo.cos_path > 0) == (np.arange(geo.cos_path.shape[1])[None] < geo.bounces[:, None]))
    np.testing.assert_array_equal(beam.path_fresnel(geo.cos_path, geo.bounces, geo.weight, F, cs), traced.fresnel)
    # the test can fail: dropping each path's last bounce changes multi-bounce exits
    cut = geo.cos_path.copy()
    cut[np.arange(cut.shape[0]), geo.bounces - 1] = 1.0
    assert not np.array_equal(beam.path_fresnel(cut, geo.bounces, geo.weight, F, cs), traced.fresnel)


def test_stored_geometry_gives_each_directions_trace(monkeypatch):
    """Directions asked again (alone, mixed with new ones, in another order, repeated) come back with the records
    of a direct trace of them, grouped by direction, bit for bit; a stored direction is not traced again."""
    monkeypatch.setattr(slices, "_GEOMETRY", {})
    prof, F, cs = profiles.quartic(0.11), _model("gold"), _cos(5)
    v = prof.periodic_vertices()
    calls = []
    real = slices.trace_exact
    monkeypatch.setattr(slices, "trace_exact", lambda verts, p, *a, **k: calls.append(np.size(p)) or real(verts, p, *a, **k))
    first = np.linspace(-1.5, 1.5, 13)
    slices._trace(prof, first, F, cs)
    assert calls == [13]
    ask = np.concatenate([first[::-3], [0.123, -0.777], first[2:4], first[2:3]])   # stored, new, repeated
    got = slices._trace(prof, ask, F, cs)
    assert calls == [13, 2]                                  # only the two new directions traced
    for j, p in enumerate(ask):
        ref = real(v, np.array([p]), F, tuple(cs))
        sel = got.sample == j
        for k in ("pid", "bounces", "phi_o", "weight", "fresnel"):
            np.testing.assert_array_equal(getattr(got, k)[sel], getattr(ref, k), err_msg=f"{k} of direction {j}")
        assert got.flux_ab is None and got.bounds is None                  # beam edges: not traced for slices
        assert got.lost[j] == ref.lost[0]
    # another metal and θo set on the same geometry: no trace, the traced weights of that model
    gold_free = slices._trace(prof, first, _model("iron"), _cos(3))
    assert calls == [13, 2]
    ref = real(v, first, _model("iron"), tuple(_cos(3)))
    a, b = np.lexsort((ref.pid, ref.bounces, ref.sample)), np.lexsort((gold_free.pid, gold_free.bounces, gold_free.sample))
    np.testing.assert_array_equal(gold_free.fresnel[b], ref.fresnel[a])


def test_metal_edit_reuses_the_geometry_and_equals_a_fresh_computation(monkeypatch):
    """A metal change traces (almost) nothing again and gives the table lobes of the store turned off, bit for bit."""
    prof = profiles.quartic(0.095)
    monkeypatch.setattr(slices, "_GEOMETRY", {})
    traced = []
    real = slices.trace_exact
    monkeypatch.setattr(slices, "trace_exact", lambda verts, p, *a, **k: traced.append(np.size(p)) or real(verts, p, *a, **k))
    lobes.table_lobes(prof, _model("iron"), 64, 16, use_cache=False)
    first = sum(traced)
    traced.clear()
    gold = lobes.table_lobes(prof, _model("gold"), 64, 16, use_cache=False)
    assert sum(traced) < 0.25 * first, (sum(traced), first)
    monkeypatch.setattr(slices, "GEOMETRY_BYTES", 0)
    fresh = lobes.table_lobes(prof, _model("gold"), 64, 16, use_cache=False)
    for k, v in fresh.items():
        if isinstance(v, np.ndarray):
            np.testing.assert_array_equal(gold[k], v, err_msg=k)
        else:
            assert gold[k] == v or (gold[k] is None and v is None), k


def test_geometry_store_is_bounded(monkeypatch):
    monkeypatch.setattr(slices, "_GEOMETRY", {})
    monkeypatch.setattr(slices, "GEOMETRY_BYTES", 2_000_000)          # about 2.4 profiles of 31 directions
    for a in (0.07, 0.08, 0.09, 0.1):
        slices._trace(profiles.quartic(a), np.linspace(-1.5, 1.5, 31))
        total = sum(slices._store_bytes(s) for s in slices._GEOMETRY.values())
        assert total <= slices.GEOMETRY_BYTES
    assert 1 <= len(slices._GEOMETRY) < 4                 # older profiles dropped first
    assert slices._geometry_key(profiles.quartic(0.1).periodic_vertices()) in slices._GEOMETRY


def test_tabulated_lookup_is_the_clipped_linear_interpolation_bit_for_bit():
    """``fresnel.Tabulated.__call__`` (fmin/fmax clip, np.take gathers) equals the plain formula
    value[i] + t slope[i] of x = clip(nan_to_num(c), 0, 1) N, NaN and out-of-range cosines included."""
    tab = _model("iron")
    rng = np.random.default_rng(3)
    c = np.concatenate([rng.random(5000), [0.0, -0.0, 1.0, 1.5, -2.0, np.nan, 1e-300, 1.0 - 1e-16]]).reshape(-1, 4)
    n = tab.slope.shape[0]
    x = np.clip(np.nan_to_num(c, nan=0.0), 0.0, 1.0) * n
    i = np.minimum(x.astype(np.intp), n - 1)
    ref = tab.value[i] + (x - i)[..., None] * tab.slope[i]
    np.testing.assert_array_equal(tab(c), ref)
    assert tab(c).shape == c.shape + (3,)


def test_trace_helper_process_gives_the_same_tables(monkeypatch):
    """Half of each batch traced by the helper process (``slices.TRACE_HELPER``): the table lobes equal those
    traced in one process, bit for bit; a dead helper is noticed and the trace falls back to this process."""
    if slices._python() is None:
        pytest.skip("no Python interpreter to run the helper with")
    prof, F = profiles.quartic(0.085), _model("copper")
    monkeypatch.setattr(slices, "_GEOMETRY", {})
    monkeypatch.setattr(slices, "TRACE_HELPER", True)
    assert slices.start_trace_helper()
    try:
        calls = []
        real = slices._helper_trace
        monkeypatch.setattr(slices, "_helper_trace", lambda *a: calls.append(a[1].size) or real(*a))
        split = lobes.table_lobes(prof, F, 64, 16, use_cache=False)
        assert calls and slices._HELPER["proc"] is not None          # the helper was used
        monkeypatch.setattr(slices, "_GEOMETRY", {})
        monkeypatch.setattr(slices, "TRACE_HELPER", False)
        one = lobes.table_lobes(prof, F, 64, 16, use_cache=False)
        for k, v in one.items():
            if isinstance(v, np.ndarray):
                np.testing.assert_array_equal(split[k], v, err_msg=k)
        # the helper dies: the next trace falls back (same records) and forgets it
        slices._HELPER["proc"].kill()
        slices._HELPER["proc"].wait()
        monkeypatch.setattr(slices, "TRACE_HELPER", True)
        phi = np.linspace(-1.4, 1.4, 40)
        got = slices._trace_directions(prof.periodic_vertices(), phi, F, np.cos([0.0, 0.7]), True)
        ref = beam.trace_exact(prof.periodic_vertices(), phi, F, tuple(np.cos([0.0, 0.7])), cos_path=True)
        np.testing.assert_array_equal(got.fresnel, ref.fresnel)
        assert slices._HELPER["proc"] is None
    finally:
        slices.stop_trace_helper()
