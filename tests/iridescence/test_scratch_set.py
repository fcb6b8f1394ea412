"""Scratch sets (random, from polylines), the uniform-grid index and the shader export."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.iridescence.scratch_set import (ScratchSet, brute_force_query, build_grid, point_segment_distance,
                                                random_scratches, scratches_from_polylines, to_shader_arrays)


def _same(a, b):
    (oa, ia), (ob, ib) = a, b
    if not np.array_equal(oa, ob):
        return False
    return all(np.array_equal(np.sort(ia[oa[i]:oa[i + 1]]), np.sort(ib[ob[i]:ob[i + 1]])) for i in range(len(oa) - 1))


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 60), seed=st.integers(0, 10_000), cell=st.floats(0.005, 0.6),
       lmax=st.floats(0.0, 0.8), radius=st.floats(0.0, 0.3), orient=st.sampled_from(["uniform", "fixed", "von_mises"]),
       angle=st.floats(-4.0, 4.0))
def test_grid_query_equals_brute_force(n, seed, cell, lmax, radius, orient, angle):
    S = random_scratches(n, length_range=(0.0, lmax), orientation=orient, angle=angle, seed=seed)
    g = build_grid(S, cell_size=cell)
    rng = np.random.default_rng(seed + 1)
    q = rng.random((50, 2)) * 1.4 - 0.2                      # also outside the grid's bounding box
    r = rng.random(50) * radius                               # per-query radius (footprint + 3σ)
    assert _same(g.query(S, q, r), brute_force_query(S, q, r))


def test_grid_query_exact_3sigma_set():
    """The lookup returns exactly the scratches within footprint radius + 3σ (UV), no more, no fewer."""
    S = random_scratches(500, length_range=(0.01, 0.2), uv_scale_um=1e4, seed=7)
    g = build_grid(S)
    q = np.random.default_rng(0).random((300, 2))
    R = 0.002 + 3 * 60.0 / S.uv_scale_um
    off, ids = g.query(S, q, R)
    d = point_segment_distance(q[:, None], S.p0[None], S.p1[None])
    assert off[-1] == np.count_nonzero(d <= R)
    qi = np.repeat(np.arange(300), np.diff(off))
    assert np.all(d[qi, ids] <= R)


def test_random_scratches_ranges_and_determinism():
    a = random_scratches(2000, length_range=(0.1, 0.2), width_range_um=(1, 2), depth_range_um=(3, 4), seed=5)
    b = random_scratches(2000, length_range=(0.1, 0.2), width_range_um=(1, 2), depth_range_um=(3, 4), seed=5)
    assert np.array_equal(a.p0, b.p0)
    L = a.length_uv
    assert L.min() >= 0.1 - 1e-12 and L.max() <= 0.2 + 1e-12
    assert a.width_um.min() >= 1 and a.width_um.max() <= 2 and a.depth_um.min() >= 3 and a.depth_um.max() <= 4
    # uniform orientation: axial mean resultant length ≈ 0 (|R| ~ 1/√n); von Mises with κ=8: ≈ I1(8)/I0(8) ≈ 0.94
    R = lambda phi: abs(np.mean(np.exp(2j * phi)))  # noqa: E731
    assert R(a.phi) < 0.06
    v = random_scratches(2000, orientation="von_mises", angle=0.7, kappa=8.0, seed=1)
    assert abs(R(v.phi) - 0.9352) < 0.02
    assert abs(np.angle(np.mean(np.exp(2j * v.phi))) / 2 - 0.7) < 0.02


def test_polylines_to_segments():
    pl = [np.array([[0, 0], [1, 0], [1, 1.0]]), np.array([[2, 2], [2, 2], [3, 2.0]])]
    S = scratches_from_polylines(pl, [1.0, 2.0], 0.5, uv_scale_um=100.0)
    assert len(S) == 3                                        # zero-length segment dropped
    assert np.array_equal(S.curve_id, [0, 0, 1]) and np.array_equal(S.width_um, [1, 1, 2])
    assert np.allclose(S.p1[0], S.p0[1])                      # consecutive within a curve
    with pytest.raises(ValueError, match="polylines"):
        scratches_from_polylines([np.zeros((1, 2))], 1.0, 1.0, 1.0)


def test_shader_arrays_layout_roundtrip():
    S = random_scratches(30, seed=2)
    g = build_grid(S)
    a = to_shader_arrays(S, g)
    seg = a["segments"].reshape(-1, 6)
    assert np.allclose(seg[:, :2], S.p0, atol=1e-6) and np.allclose(seg[:, 4], S.width_um, rtol=1e-6)
    ox, oy, h, nx, ny, s = a["grid_params"]
    assert int(nx) * int(ny) + 1 == a["cell_start"].size and a["cell_start"][-1] == a["cell_items"].size
    # a scratch's midpoint cell lists it
    mid = 0.5 * (S.p0 + S.p1)
    cid = (np.floor((mid[:, 1] - oy) / h) * nx + np.floor((mid[:, 0] - ox) / h)).astype(int)
    for m in range(0, 30, 7):                                  # a few spot checks
        assert m in a["cell_items"][a["cell_start"][cid[m]]:a["cell_start"][cid[m] + 1]]


def test_invalid():
    with pytest.raises(ValueError, match="width_um"):
        ScratchSet(np.zeros((1, 2)), np.ones((1, 2)), -1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="uv_scale_um"):
        ScratchSet(np.zeros((1, 2)), np.ones((1, 2)), 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="count"):
        random_scratches(-1)
    with pytest.raises(ValueError, match="length_range"):
        random_scratches(3, length_range=(0.3, 0.1))
    with pytest.raises(ValueError, match="orientation"):
        random_scratches(3, orientation="radial")
    with pytest.raises(ValueError, match="radius"):
        build_grid(random_scratches(3)).query(random_scratches(3), np.zeros((1, 2)), -1.0)


def test_grid_build_in_chunks_is_identical(monkeypatch):
    """Chunked candidate tests (GRID_CHUNK candidates, GRID_BLOCK segments at a time) give the same index as one pass."""
    from scratch_materials.precompute.iridescence import scratch_set
    S = random_scratches(400, length_range=(0.0, 0.6), seed=3)
    one = build_grid(S, cell_size=0.02)
    monkeypatch.setattr(scratch_set, "GRID_CHUNK", 37)
    monkeypatch.setattr(scratch_set, "GRID_BLOCK", 29)
    many = build_grid(S, cell_size=0.02)
    assert np.array_equal(one.cell_start, many.cell_start) and np.array_equal(one.cell_items, many.cell_items)


def test_grid_size_bounded(monkeypatch):
    """Issue #14 (memory bounded for every accepted input): an automatic cell size coarsens until the index fits
    MAX_GRID_ITEMS (queries stay exact); an explicit one that cannot fit is refused up front naming cell_size."""
    from scratch_materials.precompute.iridescence import scratch_set
    S = random_scratches(2000, length_range=(0.2, 0.6), seed=5)
    free = build_grid(S)
    monkeypatch.setattr(scratch_set, "MAX_GRID_ITEMS", free.cell_items.size // 4)
    g = build_grid(S)
    assert g.cell_size > free.cell_size and g.cell_items.size <= scratch_set.MAX_GRID_ITEMS
    q = np.random.default_rng(1).random((200, 2))
    assert _same(g.query(S, q, 0.01), brute_force_query(S, q, 0.01))
    with pytest.raises(ValueError, match="cell_size"):
        build_grid(S, cell_size=free.cell_size)
    monkeypatch.setattr(scratch_set, "MAX_GRID_ITEMS", 1000)
    with pytest.raises(ValueError, match="scratches"):
        build_grid(S)


def test_grid_memory_many_long_scratches():
    """100,000 scratches 0.1-0.3 UV long: the old build made every (segment, bounding-box cell) candidate at once
    (~1e8 pairs, several GB); now the candidates stream in chunks: peak Python allocations < 300 MiB."""
    import tracemalloc
    S = random_scratches(100_000, length_range=(0.1, 0.3), seed=11)
    tracemalloc.start()
    try:
        g = build_grid(S)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 300 * 2**20, f"peak {peak / 2**20:.0f} MiB"
    q = np.random.default_rng(2).random((100, 2))
    assert _same(g.query(S, q, 0.002), brute_force_query(S, q, 0.002))


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 80), seed=st.integers(0, 10_000), cell=st.floats(0.003, 0.5), lmax=st.floats(0.0, 1.0),
       orient=st.sampled_from(["uniform", "fixed", "von_mises"]), angle=st.floats(-4.0, 4.0))
def test_grid_corridor_equals_whole_box(n, seed, cell, lmax, orient, angle):
    """The build tests only a corridor of cells along each segment; the index equals the one that tests every cell
    of the segment's bounding box (the previous build) exactly."""
    from scratch_materials.precompute.iridescence import scratch_set
    S = random_scratches(n, length_range=(0.0, lmax), orientation=orient, angle=angle, seed=seed)
    g = build_grid(S, cell_size=cell)
    blo, bhi, _ = g._cell_range(np.minimum(S.p0, S.p1), np.maximum(S.p0, S.p1))
    si, cx, cy = scratch_set.cell_pairs(blo, bhi)
    centre = g.origin + (np.stack([cx, cy], axis=1) + 0.5) * g.cell_size
    keep = point_segment_distance(centre, S.p0[si], S.p1[si]) <= 0.5 * np.sqrt(2.0) * g.cell_size * (1.0 + 1e-9)
    start, items = scratch_set.csr_from_pairs((cy * g.nx + cx)[keep], si[keep], g.nx * g.ny)
    assert np.array_equal(start, g.cell_start) and np.array_equal(items, g.cell_items)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 10_000), reach=st.floats(0.001, 0.2), frac=st.floats(0.3, 3.0),
       lmax=st.floats(0.0, 1.0), orient=st.sampled_from(["uniform", "fixed"]), angle=st.floats(-4.0, 4.0))
def test_reach_grid_corridor_equals_whole_box(n, seed, reach, frac, lmax, orient, angle):
    """The iridescent layer's reach grid tests a corridor of cells along each segment; it equals the grid that
    tests every cell of the reach-expanded bounding box (the previous build) exactly."""
    from scratch_materials.precompute.iridescence import layer, scratch_set
    S = random_scratches(n, length_range=(0.0, lmax), orientation=orient, angle=angle, seed=seed)
    g = layer.reach_grid(S.p0, S.p1, reach, cell_frac=frac)
    blo = np.clip(np.floor((np.minimum(S.p0, S.p1) - reach - g.origin) / g.cell).astype(np.int64), 0, [g.nx - 1, g.ny - 1])
    bhi = np.clip(np.floor((np.maximum(S.p0, S.p1) + reach - g.origin) / g.cell).astype(np.int64), 0, [g.nx - 1, g.ny - 1])
    si, cx, cy = scratch_set.cell_pairs(blo, bhi)
    corner = g.origin + np.stack([cx, cy], 1) * g.cell
    keep = layer.segment_box_distance(S.p0[si], S.p1[si], corner, corner + g.cell) <= reach * (1 + 1e-9) + 1e-12
    start, items = scratch_set.csr_from_pairs((cy * g.nx + cx)[keep], si[keep], g.nx * g.ny)
    assert np.array_equal(start, g.start) and np.array_equal(items, g.items)


def test_reach_grid_in_chunks_is_identical(monkeypatch):
    from scratch_materials.precompute.iridescence import layer
    S = random_scratches(300, length_range=(0.0, 0.6), seed=4)
    one = layer.reach_grid(S.p0, S.p1, 0.01)
    monkeypatch.setattr(layer, "GRID_CHUNK", 41)
    monkeypatch.setattr(layer, "GRID_BLOCK", 23)
    many = layer.reach_grid(S.p0, S.p1, 0.01)
    assert np.array_equal(one.start, many.start) and np.array_equal(one.items, many.items)


def test_overfull_reach_cell_refused_before_the_per_item_weights(monkeypatch):
    """Issue #14 (memory): 200,000 scratches (the panel's maximum count) built every per-(cell, segment) weight
    (1.1 GB) before refusing an over-full cell; the check now runs on the grid's cell counts first."""
    from scratch_materials.precompute.iridescence import layer

    def boom(*a, **k):
        raise AssertionError("candidate_weights ran before the cell-load check")
    monkeypatch.setattr(layer, "candidate_weights", boom)
    S = random_scratches(40_000, length_range=(0.3, 0.6), seed=2)
    with pytest.raises(ValueError, match="^scratches: .* within reach of one grid cell"):
        layer.shader_tables(layer.LayerSpec(scratches=S, sigma_um=1000.0))
