"""Inter-reflections inside the bi-scale tile (issue 16 item 3, ``precompute.biscale.interreflect``):
the periodic ray cast against the exact visibility of eq. 8, the path tracer's single-bounce term
against ``tabulate_tile`` (the normalisation), a white furnace (nothing absorbs, so the total
effective albedo is 1), a flat tile (nothing to bounce off), the automatic decision and the bake
wiring.  The Cycles comparison with full global illumination is in test_biscale_truth_gi.py."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.biscale import bake
from scratch_materials.precompute.biscale import interreflect as ir
from scratch_materials.precompute.biscale import table as btable
from scratch_materials.precompute.biscale.directions import direction_grid, direction_solid_angles
from scratch_materials.precompute.biscale.effective import BiscaleTile
from scratch_materials.precompute.biscale.geometry import flat_tile, groove_tile, pyramid_tile, rods_tile
from scratch_materials.precompute.biscale.visibility import visibility_matrix

WHITE = [{"model": "lambert", "albedo": 1.0}] * 3
GREY = [{"model": "lambert", "albedo": 0.5}, {"model": "lambert", "albedo": (0.8, 0.6, 0.4)}]


def _albedo(table, res):
    """Σ_i f(ωi, ωo) cos θi Δω_i per ωo (channel 0), the grid's own quadrature."""
    d, dw = direction_grid(res), direction_solid_angles(res)
    return (table[..., 0] * (d[:, 2] * dw)[:, None]).sum(0)


@pytest.mark.parametrize("tile", [pyramid_tile(height=0.5), rods_tile(n_rods=3, length=0.6, tilt=0.6, randomness=0.2),
                                  groove_tile(depth=0.4)], ids=["pyramid", "rods", "groove"])
def test_periodic_ray_cast_agrees_with_the_visibility_of_eq8(tile):
    """``periodic_ray_cast`` (lattice walk + Möller-Trumbore) finds a hit exactly where the sheared-grid
    visibility (``visibility_matrix``, an independent algorithm) says occluded; directions lying in a
    facet's own plane are excluded (both answers are right there).  Includes grazing directions that
    cross many tile copies."""
    b = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=400, dir_res=4)
    tri = tile.vertices[tile.faces]
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(24, 3))
    dirs[:, 2] = np.abs(dirs[:, 2]) * np.linspace(0.05, 1.0, 24)          # down to ~2° above the horizon
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    V = visibility_matrix(tri, tile.period, b.pos, dirs, point_normals=b.n)
    for k, w in enumerate(dirs):
        front = b.n @ w > 1e-6
        _, tid, _ = ir.periodic_ray_cast(tri, tile.period, b.pos[front] + 1e-7 * b.n[front], np.tile(w, (front.sum(), 1)))
        mism = (tid >= 0) == V[front, k]
        assert mism.mean() <= 0.002, (k, w, mism.sum())


def test_single_bounce_of_the_path_tracer_is_eq8():
    """With only the first vertex's next-event estimate (``first_bounce=1, max_bounces=1``) the path
    tracer computes Wu's eq. 8 by Monte Carlo over the projected footprint; the facet sum
    ``tabulate_tile`` on the same grid is the independent reference.  Measured: mean albedo -0.2 %,
    per ωo within 2.8 % (256 paths, 2000 facets); bounds 1 % / 5 %.  Fails if the a_v(ωo)
    normalisation or the 1/cos θi of f were wrong (>= 10 % off at 45°)."""
    t = pyramid_tile(height=0.5)
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=2000, dir_res=8)
    mc, info = ir.indirect_table(b, GREY, res=8, n_paths=256, max_bounces=1, first_bounce=1)
    ref = btable.tabulate_tile(b, GREY, res=8).table
    a_mc, a_ref = _albedo(mc, 8), _albedo(ref, 8)
    assert abs(a_mc.mean() / a_ref.mean() - 1) <= 0.01
    assert np.abs(a_mc / a_ref - 1).max() <= 0.05
    assert info["max_depth"] == 1


@pytest.mark.parametrize("tile", [pyramid_tile(height=0.5), groove_tile(depth=0.4)], ids=["pyramid", "groove"])
def test_white_furnace_all_light_leaves(tile):
    """Albedo-1 Lambertian facets absorb nothing, and a closed tile lets no light through: every ωo's
    effective albedo (single bounce + inter-reflections) is 1 — the grid quadrature's own value
    Σ cos θ Δω / π = 1.0087 at res 8.  Wu's single bounce alone is 10-25 % short.  Noise: per-ωo std
    1.8 % (256 paths), mean of 64 ωo 0.25 %; bounds 1 % on the mean, 8 % per ωo.  Fails without the
    periodic neighbours (light leaving through a tile side lost: next test)."""
    b = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=2000, dir_res=8)
    q = _albedo(np.full((64, 64, 3), 1 / np.pi), 8)
    direct = _albedo(btable.tabulate_tile(b, WHITE, res=8).table, 8)
    ind, info = ir.indirect_table(b, WHITE, res=8, n_paths=256)
    tot = direct + _albedo(ind, 8)
    assert abs(tot.mean() / q.mean() - 1) <= 0.01, tot.mean() / q.mean()
    assert np.abs(tot / q - 1).max() <= 0.08
    assert direct.mean() / q.mean() < 0.92                     # inter-reflections matter here
    assert info["max_depth"] >= 4


def test_white_furnace_needs_the_neighbours(monkeypatch):
    """A deliberately broken tracer that ignores the periodic neighbours (rays only tested against the
    tile they start in) fails the furnace: the light crossing tile sides is lost."""
    walk = ir._walk

    def home_only(grid, o, d, max_tiles):
        r, cx, cy, t_max = walk(grid, o, d, max_tiles)
        keep = (cx // grid.G == 0) & (cy // grid.G == 0)
        return r[keep], cx[keep], cy[keep], t_max

    monkeypatch.setattr(ir, "_walk", home_only)
    t = groove_tile(depth=0.4)
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=2000, dir_res=8)
    q = _albedo(np.full((64, 64, 3), 1 / np.pi), 8)
    direct = _albedo(btable.tabulate_tile(b, WHITE, res=8).table, 8)
    ind, _ = ir.indirect_table(b, WHITE, res=8, n_paths=256)
    assert (direct + _albedo(ind, 8)).mean() / q.mean() < 0.97


def test_flat_tile_has_nothing_to_bounce_off():
    t = flat_tile(n=2)
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=200, dir_res=6)
    ind, info = ir.indirect_table(b, WHITE, res=6, n_paths=16)
    assert np.all(ind == 0) and info["max_depth"] == 1
    assert ir.indirect_estimate(b, WHITE) == 0.0
    table, info = ir.tile_indirect(b, WHITE, "auto")
    assert table is None and info["interreflections"] is False


def test_auto_decision_follows_the_estimate():
    """"auto": on for the pyramid (first-bounce estimate 14 %, measured change of the albedo 14 %),
    off for a 2 % deep groove; True / False force it; the estimate tracks the measured change."""
    t = pyramid_tile(height=0.5)
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=1000, dir_res=8)
    est = ir.indirect_estimate(b, GREY)
    ind, info = ir.tile_indirect(b, GREY, "auto", res=6, n_paths=64)
    assert info["interreflections"] and ind is not None and info["estimate"] == est
    direct = btable.tabulate_tile(b, GREY, res=6).table
    change = _albedo(ind, 6).mean() / _albedo(direct, 6).mean()
    assert 0.5 * est < change < 2 * est and est > ir.AUTO_THRESHOLD
    s = groove_tile(depth=0.02)
    bs = BiscaleTile(s.vertices, s.faces, s.face_material, n_facets=500, dir_res=8)
    assert ir.indirect_estimate(bs, WHITE) < ir.AUTO_THRESHOLD
    assert ir.tile_indirect(bs, WHITE, "auto")[0] is None
    assert ir.tile_indirect(bs, WHITE, True, res=4, n_paths=4)[0] is not None
    assert ir.tile_indirect(b, GREY, "off")[0] is None


@pytest.mark.parametrize("bad", ["sometimes", 2, None, 0.5])
def test_bad_mode_names_the_parameter(bad):
    with pytest.raises(ValueError, match="interreflections"):
        ir.check_mode(bad)
    t = pyramid_tile()
    with pytest.raises(ValueError, match="interreflections"):
        bake.check_inputs(GREY, 1, interreflections=bad)


def test_bad_sizes_are_value_errors():
    t = pyramid_tile()
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=100, dir_res=4)
    for kw, name in ((dict(res=1), "res"), (dict(n_paths=0), "n_paths"), (dict(max_bounces=0), "max_bounces")):
        with pytest.raises(ValueError, match=name):
            ir.indirect_table(b, GREY, **kw)


def test_bake_adds_the_indirect_table(tmp_path):
    """``bake_tables(interreflections=...)``: on adds the resampled indirect table to both the
    effective BRDF (what the closures are fitted to) and the closure's table; off is Wu's table; the
    info says what was decided; the indirect table is memoised on the tile (a second bake is free)."""
    t = pyramid_tile(height=0.5)
    kw = dict(n_lobes=1, exr_dir=str(tmp_path), closure_table=True, n_facets=600, dir_res=6, normal_res=21, l_M=40)
    off, _, i_off = bake.bake_tables(t.vertices, t.faces, t.face_material, 1.0, GREY, interreflections=False, **kw)
    on, _, i_on = bake.bake_tables(t.vertices, t.faces, t.face_material, 1.0, GREY, interreflections="auto", **kw)
    assert not i_off["interreflections"] and i_on["interreflections"] and i_on["indirect_estimate"] > 0.05
    tile, _ = bake.get_tile(t.vertices, t.faces, np.minimum(t.face_material, 1), 1.0, n_facets=600, dir_res=6,
                            normal_res=21, l_M=40)
    T = i_on["table"]                     # the closure's table has a view grid (the tile's events on nodes)
    assert T.view_a is not None and np.array_equal(T.view_a, i_off["table"].view_a)
    # traced on the coarser view grid of the same layout (bake.INDIRECT_VIEW_NODES), interpolated to the table's nodes
    from scratch_materials.precompute.biscale import table as btable
    from scratch_materials.precompute.tables.tabulated_brdf import view_directions

    ca, cb = btable.tile_view_grid(tile, bake.INDIRECT_VIEW_NODES, bake.INDIRECT_VIEW_NODES)
    assert len(ca) < len(T.view_a)
    ind, info = ir.tile_indirect(tile, GREY, True, view=view_directions(ca, cb))
    assert info["seconds"] < 0.5 * i_on["seconds_indirect"] + 0.05      # memoised
    ind = ir.resample_view_nodes(ind, ca, cb, T.view_nodes())
    np.testing.assert_allclose(on.table - off.table, ir.resample_views(ind, info["res"], T.view_a, T.view_b, 6),
                               atol=1e-12)
    np.testing.assert_allclose(T.table - i_off["table"].table, ir.resample_wi(ind, info["res"], T.res), atol=1e-12)


def test_resample_view_nodes_is_identity_on_its_own_nodes_and_linear_between():
    """``resample_view_nodes``: onto the grid's own nodes it is the identity; a table linear in the view angles is
    reproduced exactly at other views (bilinear in (a, b)); views beyond the outermost nodes take the edge."""
    from scratch_materials.precompute.tables.tabulated_brdf import view_angles, view_directions

    va, vb = np.radians([-80.0, -30.0, 0.0, 45.0, 80.0]), np.radians([-70.0, 0.0, 20.0, 70.0])
    rng = np.random.default_rng(2)
    T = rng.random((9, len(va) * len(vb), 3))
    np.testing.assert_allclose(ir.resample_view_nodes(T, va, vb, view_directions(va, vb)), T, atol=1e-12)
    A, B = np.meshgrid(va, vb, indexing="ij")
    lin = (0.3 + 0.2 * A - 0.1 * B).ravel()
    wo = view_directions(np.radians([-60.0, 10.0, 33.0]), np.radians([-5.0, 50.0]))
    ab = view_angles(wo)
    got = ir.resample_view_nodes(np.broadcast_to(lin[None, :, None], (1, len(lin), 1)), va, vb, wo)[0, :, 0]
    np.testing.assert_allclose(got, 0.3 + 0.2 * ab[:, 0] - 0.1 * ab[:, 1], atol=1e-12)


def test_resample_is_identity_on_its_own_grid_and_keeps_constants():
    rng = np.random.default_rng(1)
    T = rng.random((36, 36, 3))
    np.testing.assert_allclose(ir.resample(T, 6, 6), T, atol=1e-12)
    np.testing.assert_allclose(ir.resample(np.full((36, 36, 3), 0.3), 6, 11), 0.3, atol=1e-12)


@pytest.mark.parametrize("theta", [10.0, 50.0, 85.0])
def test_direction_sampler_is_unbiased(theta):
    """The bounce sampler (cosine + GGX half-vector mixture, weight f cos / pdf_mix) integrates a GGX
    α = 0.2 lobe to its directional albedo (midpoint rule, 256 x 512): measured within 0.15 % at
    400k samples; bound 1.5 % at 100k (per-sample std / mean < 1.5, so the standard error is < 0.5 %).
    A pdf missing its cosine part (pure GGX weight) or with the wrong Jacobian 1/(4 ωo·h) fails."""
    from scratch_materials.precompute.biscale.brdfs import eval_material, material_lobes
    from scratch_materials.precompute.tables.tabulated_brdf import hemisphere_midpoints

    lob = material_lobes({"model": "cook_torrance", "distribution": "ggx", "alpha": 0.2, "F0": 1.0, "ks": 0.8})
    n = np.array([[0.0, 0.0, 1.0]])
    wo = np.array([[np.sin(np.radians(theta)), 0.0, np.cos(np.radians(theta))]])
    N = 100_000
    w, pdf = ir._sample_dirs(np.random.default_rng(0), np.repeat(n, N, 0), np.repeat(wo, N, 0), np.full(N, 0.8),
                             np.full(N, 0.2))
    f = eval_material(lob, n, w, wo)[:, 0]
    est = np.where(pdf > 0, f * np.clip(w[:, 2], 0, None) / np.where(pdf > 0, pdf, 1.0), 0.0).mean()
    wi, dw = hemisphere_midpoints(256, 512)
    ref = (eval_material(lob, n, wi, wo)[:, 0] * wi[:, 2]).sum() * dw
    assert est == pytest.approx(ref, rel=0.015)


def test_path_count_is_bounded():
    """All paths are traced at once: more than MAX_TOTAL_PATHS is refused (memory), not swapped."""
    t = pyramid_tile()
    b = BiscaleTile(t.vertices, t.faces, t.face_material, n_facets=100, dir_res=4)
    with pytest.raises(ValueError, match="n_paths"):
        ir.indirect_table(b, GREY, res=19, n_paths=1_000_000)
