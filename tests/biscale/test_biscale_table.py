"""Bi-scale materials baked to the tabulated-BRDF closure (the default product path): the table is
handed over unchanged, its resolution follows the sharpest small-scale material, the bake operator
makes it by default, and Cycles renders it within 3 % of the explicit tiled geometry (direct light,
direction-coded environment, an area lamp with NEE on)."""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from scratch_materials.precompute.biscale import table as btable
from scratch_materials.precompute.biscale.effective import BiscaleTile
from scratch_materials.precompute.biscale.geometry import pyramid_tile, rods_tile

MATS = [{"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": 1.0, "ks": 0.8},
        {"model": "lambert", "albedo": (0.8, 0.5, 0.2)}]


@pytest.fixture(scope="module")
def brdf():
    g = rods_tile(n_rods=4, length=0.6, tilt=0.6, randomness=0.2)
    return BiscaleTile(g.vertices, g.faces, g.face_material, n_facets=1500, dir_res=8, normal_res=41,
                       l_M=120).effective_brdf(MATS)


def test_table_is_the_effective_brdf(brdf):
    """``to_tabulated`` keeps the grid and the values: its eval equals ``EffectiveBRDF.eval`` at random
    direction pairs (both bilinear on the same hemi-octahedral grid)."""
    tab = btable.to_tabulated(brdf)
    rng = np.random.default_rng(0)
    a = rng.normal(size=(400, 3)); a[:, 2] = np.abs(a[:, 2]) + 0.05
    b = rng.normal(size=(400, 3)); b[:, 2] = np.abs(b[:, 2]) + 0.05
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(tab.eval(a, b), brdf.eval(a, b), rtol=1e-12, atol=1e-15)
    assert not tab.iso and tab.res == brdf.dir_res


def test_resolution_follows_the_sharpest_material():
    lam = {"model": "lambert"}
    assert btable.table_dir_res([lam]) == btable.MIN_DIR_RES
    ct = lambda a: {"model": "cook_torrance", "alpha": a}  # noqa: E731
    r = [btable.table_dir_res([lam, ct(a)]) for a in (0.6, 0.3, 0.25, 0.2, 0.05)]
    assert r == sorted(r) and r[-1] == btable.MAX_DIR_RES and r[1] == math.ceil(math.pi / 0.3)
    assert btable.table_dir_res([ct(0.25), ct(0.6)]) == btable.table_dir_res([ct(0.25)])
    assert btable.sharpest_alpha([{"model": "blinn_phong", "exponent": 98.0}]) == pytest.approx(math.sqrt(0.02))


def test_fine_table_is_the_facet_sum_at_its_nodes(brdf):
    """``tabulate_tile`` at its own grid nodes is eq. 8 evaluated directly (``brute_force_fr_at``, its own
    ray-cast visibility), made reciprocal as the bake: (f(i, o) + f(o, i)) / 2, to float32 rounding."""
    from scratch_materials.precompute.biscale.effective import brute_force_fr_at
    from scratch_materials.precompute.tables.tabulated_brdf import direction_grid

    g = rods_tile(n_rods=4, length=0.6, tilt=0.6, randomness=0.2)
    tile = BiscaleTile(g.vertices, g.faces, g.face_material, n_facets=1500, dir_res=8, normal_res=41, l_M=120)
    tab = btable.tabulate_tile(tile, MATS, res=12)
    assert tab.res == 12 and not tab.iso and btable.closure_res(8) == btable.CLOSURE_RES
    d = direction_grid(12)
    rng = np.random.default_rng(3)
    i, o = rng.integers(0, len(d), 60), rng.integers(0, len(d), 60)
    fwd = brute_force_fr_at(tile, MATS, d[i], d[o]) / d[i, 2:3]
    bwd = brute_force_fr_at(tile, MATS, d[o], d[i]) / d[o, 2:3]
    np.testing.assert_allclose(tab.table[i, o], 0.5 * (fwd + bwd), rtol=1e-4, atol=1e-6)
    with pytest.raises(ValueError, match="res"):
        btable.tabulate_tile(tile, MATS, res=btable.MAX_CLOSURE_RES + 1)


def test_fine_table_removes_the_interpolation_error():
    """Between the bake's directions, bilinear interpolation misses the pyramid's shadowing: at the
    render test's lamp (directions over the 1.5 m lamp) and the 35° view the coarse table (dir_res 10)
    is 4.1 % below the Monte Carlo ray-traced tile (``render_reference_fr``, 40k rays per view, noise
    < 0.3 %), the facet sum at exactly those directions 0.7 % below, the fine table 1.1 % (measured).
    Bound 2 % for the fine table (the coarse one fails it)."""
    from scratch_materials.precompute.biscale.effective import render_reference_fr
    from scratch_materials.precompute.biscale.geometry import pyramid_tile

    tile = pyramid_tile(height=0.5)
    mats = [{"model": "lambert", "albedo": 0.5}, {"model": "lambert", "albedo": (0.8, 0.6, 0.4)}]
    bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=2000, dir_res=10)
    fine = btable.tabulate_tile(bt, mats)
    rng = np.random.default_rng(1)
    wi = np.array([-1.5, 1.0, 2.5]) + rng.uniform(-0.75, 0.75, (40, 3)) * [1, 1, 0]
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = np.repeat([[math.sin(math.radians(35)), 0.0, math.cos(math.radians(35))]], len(wi), 0)
    ref = (render_reference_fr(tile, mats, wi, wo, n_rays=40000) / wi[:, 2:3]).mean(0)
    err_fine = np.abs(fine.eval(wi, wo).mean(0) / ref - 1).max()
    assert err_fine <= 0.02, err_fine
    assert fine.res > bt.opts["dir_res"]


# ----------------------------------------------------------------------------- Blender
@pytest.mark.bpy
def test_bake_operator_makes_the_table_by_default(addon, scene):
    import bpy

    ops = importlib.import_module(addon.__name__ + ".biscale_ops")
    registered = [c for c in ops.classes if not hasattr(bpy.types, c.__name__)]
    for c in registered:
        bpy.utils.register_class(c)
    try:
        geo = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.geometry")
        tile = ops.add_tile_object(bpy.context, geo.groove_tile(depth=0.4))
        target = addon.render.add_plane(bpy.context.scene, size=2.0)
        bpy.context.view_layer.objects.active = tile
        assert bpy.ops.scratch.bake_biscale(target=target.name, n_facets=600, dir_res=6,   # mode: the default
                                            interreflections="OFF") == {"FINISHED"}   # (pass: test_biscale_truth_gi)
        m = target.data.materials[0]
        assert m["biscale_mode"] == "table" and m["tabulated_res"] == btable.closure_res(6)   # the finer table
        assert not m.cycles.use_bump_map_correction
        # the default table (ωi 31², 31 x 31 view nodes: 2,770,563 floats) is above what OSL compiles: the graph
        # renders it on every path, Cycles SVM and OSL (no script, no switch), reading the view grid's guide image
        assert m["tabulated_svm"] == "table" and m["tabulated_osl"] == "graph"
        assert "Scratch Render Path" not in m.node_tree.nodes
        assert not any(n.bl_idname == "ShaderNodeScript" for n in m.node_tree.nodes)
        out = next(n for n in m.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and n.target == "CYCLES")
        svm_src = out.inputs["Surface"].links[0].from_node
        assert svm_src.bl_idname == "ShaderNodeGroup" and svm_src.node_tree.name.startswith("Scratch: Tabulated BRDF ")
        eevee = m.node_tree.nodes["Material Output (EEVEE)"].inputs["Surface"].links[0].from_node
        assert eevee.node_tree.name.endswith(" EEVEE") and m["tabulated_eevee"] == "table"   # EEVEE: the table graph
        n_mat = len(bpy.data.materials)
        with pytest.raises(RuntimeError, match="Direction Resolution.*at most 19"):   # the panel's name
            bpy.ops.scratch.bake_biscale(target=target.name, n_facets=600, dir_res=24)
        assert len(bpy.data.materials) == n_mat and target.data.materials[0] == m
    finally:
        for c in reversed(registered):
            bpy.utils.unregister_class(c)


@pytest.mark.bpy
@pytest.mark.render
def test_table_matches_explicit_tiles_direct_light(addon, scene, render_dir, capsys):
    """Ground truth (shared notes): a pyramid tile (two Lambert materials) repeated 100 x 100 on a 4 m
    plane, flat shaded, vs the table material on a plane; orthographic views at θo = 0° and 35°,
    direction-coded world (0.5 + 0.5 d) plus an area lamp with NEE on, direct light only
    (max_bounces 0).  32x32 px x 128 spp per image; the lamp (1.5 m, ~0.2 sr) is mostly found by BSDF
    sampling of the narrow closure: seed-to-seed noise of the means ~1.5 % at 64 spp (seeds 7, 1, 2:
    0.6-2.9 %, measured), hence 128 spp.
    The closure renders its table exactly (0.1 % from the ray-portal reference, measured); the table is
    the product path's: tabulated from the facets at ``closure_res`` (19) directions
    (``tabulate_tile``), not the bake's dir_res 10 grid, whose bilinear interpolation is 3.4-4 % low at
    this lamp and view.  Measured (0° / 35°): fine table 0.73 / 1.15 %; the old dir_res-10 table
    1.39 / 3.45 % (fails).  Bound 3 % (issue 16's goal)."""
    bench = importlib.import_module("bench.biscale_truth")
    bmat = importlib.import_module(addon.__name__ + ".biscale_material")
    geo = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.geometry")
    eff = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.effective")
    tile = geo.pyramid_tile(height=0.5)
    mats = [{"model": "lambert", "albedo": 0.5}, {"model": "lambert", "albedo": (0.8, 0.6, 0.4)}]
    tab = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.table")
    bt = eff.BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=2000, dir_res=10)
    brdf = bt.effective_brdf(mats)
    m = bmat.make_biscale_material(None, name="pyr table", mode="table", brdf=brdf,
                                   table=tab.tabulate_tile(bt, mats))
    views = [bench._view(0, 0), bench._view(35, 0)]
    ex, bk, _ = bench.render_pair(tile, mats, m, views, n=100, spp=128, tmp=str(render_dir))
    err = np.abs(bk - ex).max(1) / ex.mean(1)
    with capsys.disabled():
        print(f"\n[biscale table vs explicit, direct + lamp] rel. err per view {np.round(100 * err, 2)} %")
    assert np.all(err <= 0.03), (ex, bk)
