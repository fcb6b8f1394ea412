"""Issue 16 item 3 (bi-scale with inter-reflections within 3 % of the explicit tiles): the closure table's
view grid with the tile's visibility events on nodes (``table.view_events``), and the indirect table's
MIS between the camera-side and light-side estimators (``interreflect.indirect_table``), also at
arbitrary view nodes (``mis="pair"``), each against an independent reference: the groove's analytic
events, the plain (unweighted) estimator, and one-sided path tracing at the exact view."""
from __future__ import annotations

import math

import numpy as np
import pytest

from scratch_materials.precompute.biscale import geometry, interreflect
from scratch_materials.precompute.biscale import table as btable
from scratch_materials.precompute.biscale.directions import direction_grid
from scratch_materials.precompute.biscale.effective import BiscaleTile
from scratch_materials.precompute.tables import tabulated_brdf as tb

MATS = [{"model": "lambert", "albedo": 0.7},
        {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.2, "F0": 1.0, "ks": 0.8},
        {"model": "lambert", "albedo": (0.2, 0.5, 0.8)}]


@pytest.fixture(scope="module")
def groove():
    t = geometry.groove_tile(depth=0.4)          # walls 0.25 wide x 0.4 deep, floor 0.3, top 0.2
    return BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=3000, dir_res=6)


def test_view_events_are_the_grooves_visibility_events(groove):
    """The groove along y: a wall turns away from a view past tan a = 0.25 / 0.4 (32.0°, it starts hiding
    the floor), the floor is hidden past tan a = (0.25 + 0.3) / 0.4 (54.0°), on both sides; a does not
    kink along b.  Found from the facets' visibility within 0.6° (the 1° sweep's centroid), and on nodes
    of ``tile_view_grid``."""
    ev = btable.view_events(groove, 0)
    want = np.degrees(np.arctan([-1.375, -0.625, 0.625, 1.375]))
    assert len(ev) == 4, np.degrees(ev)
    np.testing.assert_allclose(np.degrees(ev), want, atol=0.6)
    assert len(btable.view_events(groove, 1)) == 0
    va, vb = btable.tile_view_grid(groove, 19, 15)
    assert len(va) == 19 and len(vb) == 15 and all(np.min(np.abs(va - e)) < 1e-12 for e in ev)


def test_mis_cuts_the_noise_and_keeps_the_mean(groove):
    """Symmetric indirect table (res 6 x 100 paths, 6 seeds): the MIS-weighted pair of estimators has a
    median per-entry relative spread < 0.75x the plain mean of the two (measured 0.11 vs 0.19: the
    lamp -> glossy wall -> diffuse floor caustics are sampled from the light's side), and the same
    expectation: the table totals agree within 4 standard errors of their difference."""
    out = {}
    for mis in (True, False):
        T = np.array([interreflect.indirect_table(groove, MATS, res=6, n_paths=100, seed=s, mis=mis)[0]
                      for s in range(6)])
        m, sd = T.mean(0), T.std(0, ddof=1)
        rel = (sd / np.maximum(m, 1e-12))[m > 0.05 * m.max()]
        tot = T.sum((1, 2, 3))
        out[mis] = (np.median(rel), tot.mean(), tot.std(ddof=1) / np.sqrt(len(tot)))
    assert out[True][0] < 0.75 * out[False][0], out
    assert abs(out[True][1] - out[False][1]) < 4 * math.hypot(out[True][2], out[False][2]), out


def test_paired_runs_at_view_nodes_match_path_tracing_at_the_view():
    """``tile_indirect(view=...)``: the indirect table at arbitrary ωo nodes (the camera-side run from the
    nodes and the light-side run from the ωi grid, MIS-weighted and added) is unbiased: at a node placed
    on θo 60° / φo 20° its env-weighted (0.5 + 0.5 ωi) integral matches one-sided path tracing from that
    exact view (16,384 paths, no MIS) within 4 standard errors of both (seeds) + 1 %.  Dropping the light
    side (the camera-side run alone, still MIS-weighted) misses it by > 10 % (the test can fail)."""
    t = geometry.groove_tile(depth=0.4)
    tile = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=3000, dir_res=6, seed=1)
    v = np.array([math.sin(math.radians(60)) * math.cos(math.radians(20)),
                  math.sin(math.radians(60)) * math.sin(math.radians(20)), math.cos(math.radians(60))])
    a, b = tb.view_angles(v)
    nodes = tb.view_directions([-0.4, a, 1.3], [-0.6, b, 1.0])
    k = 4                                                       # (a, b) is node 1 x 3 + 1
    res = 6
    dirs = direction_grid(res)
    _, omc = tb._cell_integrals(res)
    w = (0.5 + 0.5 * dirs) * omc[:, None]
    pair, one = [], []
    for seed in range(3):
        tile.opts["seed"] = seed
        tile.__dict__.pop("_indirect_memo", None)
        ind, info = interreflect.tile_indirect(tile, MATS, True, res=res, n_paths=400, view=nodes)
        pair.append((ind[:, k] * w).sum(0))
        ta, _ = interreflect.indirect_table(tile, MATS, res=res, n_paths=400, seed=seed, wo=nodes, wi=dirs, mis="pair")
        one.append((ta[:, k] * w).sum(0))
    ref = [(interreflect.indirect_table(tile, MATS, res=res, n_paths=16384, seed=10 + s, wo=v[None], wi=dirs)[0][:, 0]
            * w).sum(0) for s in range(2)]
    pair, ref, one = np.array(pair), np.array(ref), np.array(one)
    se = np.sqrt(pair.var(0, ddof=1) / len(pair) + ref.var(0, ddof=1) / len(ref))
    assert np.all(np.abs(pair.mean(0) - ref.mean(0)) < 4 * se + 0.01 * ref.mean(0)), (pair.mean(0), ref.mean(0), se)
    assert np.all(np.abs(one.mean(0) / ref.mean(0) - 1) > 0.10), (one.mean(0), ref.mean(0))
