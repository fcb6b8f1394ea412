"""Tables above ``tabulated_brdf.MAX_FLOATS`` (what an OSL array literal compiles; the bi-scale bake's default
table, ωi 31² x 31 x 31 view nodes, is one): they render through the node graph on every path, Cycles SVM and
Cycles OSL (Cycles compiles the graph's builtin nodes for OSL; no script node), and EEVEE's output takes the
graph's EEVEE variant.  Checked: the wiring, a white furnace on SVM and on OSL against the table's directional
albedo, SVM = OSL, and the errors (OSL source refused by name, no half material when the graph cannot hold it)."""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

from scratch_materials.precompute.tables import tabulated_brdf as tb

from test_tabulated_cycles import aniso_brdf                # noqa: E402


@pytest.fixture(scope="module")
def large():
    """ωi 23² x a 25 x 25 view grid (denser beyond 65°, as the bi-scale bake's): 991,875 floats."""
    g = (math.radians(65.0), 2.5)
    B = tb.TabulatedBRDF.from_function(aniso_brdf, 23, view_a=tb.view_grid_nodes(25, [0.4], grazing=g),
                                       view_b=tb.view_grid_nodes(25, grazing=g))
    assert B.table.size > tb.MAX_FLOATS
    return B


def test_view_grid_atlas_is_2d_and_its_linear_lookup_is_each_tiles_bilinear(large):
    """View grids: the F atlas is a 2D grid of padded tiles (node o = ia NB + ib in column ia, row ib), so its
    sides grow as √n_o (25 x 25 nodes at ωi 23²: 625 x 625 texels instead of 15,625 x 25).  Cycles' Linear rule
    at the graph's coordinate ((ia (res+2) + 1 + t-index) / W, (ib (res+2) + 1 + s-index) / H) equals the clamped
    bilinear interpolation of node o's table for targets anywhere in a cell, edges included; reading the
    transposed tile (ib, ia) instead misses (the table is not symmetric in a, b)."""
    T = tb.closure_tables(large)
    res, n_o = T.res, T.n_o
    img = tb.svm_images(T)["F"]
    assert img.shape[:2] == tb.svm_atlas_shape(T) == (25 * (res + 2), 25 * (res + 2))
    rng = np.random.default_rng(6)
    n = 20000
    o, k = rng.integers(0, n_o, n), rng.integers(0, res * res, n)
    ht, hs = rng.random(n), rng.random(n)
    ht[:200], hs[:200] = 0.0, 1.0 - 1e-7
    rk, ck = k // res, k % res
    tx, ty = tb.svm_atlas_tile(T, o)
    np.testing.assert_array_equal(tx * 25 + ty, o)
    r0, r1, fr = tb._lin_taps(rk + hs - 0.5, res)
    c0, c1, fc = tb._lin_taps(ck + ht - 0.5, res)
    F = T.F.astype(np.float64)
    want = (((1 - fr) * (1 - fc))[:, None] * F[r0 * res + c0, o] + ((1 - fr) * fc)[:, None] * F[r0 * res + c1, o]
            + (fr * (1 - fc))[:, None] * F[r1 * res + c0, o] + (fr * fc)[:, None] * F[r1 * res + c1, o])
    R = res + 2
    got = tb.texture_linear(img, (tx * R + 1 + ck + ht) / img.shape[1], (ty * R + 1 + rk + hs) / img.shape[0])[:, :3]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * F.max())
    bad = tb.texture_linear(img, (ty * R + 1 + ck + ht) / img.shape[1], (tx * R + 1 + rk + hs) / img.shape[0])[:, :3]
    assert np.abs(bad - want).max() > 0.05 * F.max()


@pytest.fixture
def tm(addon):
    return importlib.import_module(addon.__name__ + ".tabulated_material")


def test_osl_source_refuses_a_table_above_max_floats(large):
    from scratch_materials.osl import tabulated_brdf as gen

    with pytest.raises(ValueError, match="table: .* floats"):
        gen.generate(large)
    assert tb.closure_tables(large).F.size == large.table.size        # the closure itself holds it
    with pytest.raises(ValueError, match="table: .* floats"):
        tb.closure_tables(tb.TabulatedBRDF(np.zeros((48 * 48, 48 * 48, 3)), 48, False))


@pytest.mark.bpy
def test_large_table_material_is_the_graph_on_every_path(addon, scene, tm, large):
    """No OSL script and no render-path switch: the Cycles output takes the SVM graph (also under OSL), the EEVEE
    output its EEVEE variant; ``svm_table=False`` (no path could render it) is a ValueError that creates nothing."""
    import bpy

    rp = importlib.import_module(addon.__name__ + ".render_paths")
    m = tm.make_tabulated_material(large, "large table")
    tree = m.node_tree
    assert m["tabulated_svm"] == "table" and m["tabulated_eevee"] == "table" and m["tabulated_osl"] == "graph"
    assert not any(n.bl_idname == "ShaderNodeScript" for n in tree.nodes) and rp.SWITCH_NAME not in tree.nodes
    cyc = rp.cycles_output(tree).inputs["Surface"].links[0].from_node
    assert cyc.node_tree.name.startswith("Scratch: Tabulated BRDF ") and not cyc.node_tree.name.endswith("EEVEE")
    ee = tree.nodes[rp.EEVEE_OUTPUT_NAME].inputs["Surface"].links[0].from_node
    assert ee.node_tree.name.endswith(" EEVEE")
    n_mats, n_groups = len(bpy.data.materials), len(bpy.data.node_groups)
    with pytest.raises(ValueError, match="svm_table"):
        tm.make_tabulated_material(large, "large no graph", svm_table=False)
    assert len(bpy.data.materials) == n_mats and len(bpy.data.node_groups) == n_groups
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.shading_system = True
    assert rp.describe(m, sc)[0] == "CHECKMARK"


@pytest.mark.render
@pytest.mark.bpy
def test_large_table_renders_its_albedo_on_svm_and_osl(addon, scene, tm, render_dir, large, capsys):
    """White furnace, orthographic view at θo 72° along -x (between grazing nodes) and 50° along +y: Cycles SVM
    and Cycles OSL (the graph compiled for OSL) both render the table's directional albedo.  32x32 px x 32 spp =
    32k samples, per-sample relative std < 0.6 (``test_tabulated_svm``'s furnace) -> standard error < 0.35 %;
    tolerance 1.5 % each, SVM vs OSL 2 % (two independent estimates).  A black or wrongly wired render (the
    fitted twin, a wrong view node) misses by far more: the two views' albedos differ by > 8 %."""
    import bpy

    views = [np.array([-math.sin(math.radians(72)), 0, math.cos(math.radians(72))]),
             np.array([0, math.sin(math.radians(50)), math.cos(math.radians(50))])]
    alb = large.albedo(np.array(views), 96, 192)
    assert np.abs(alb[0] - alb[1]).max() > 0.08 * alb.max()
    m = tm.make_tabulated_material(large, "large furnace")
    sc = bpy.context.scene
    addon.render.uniform_world(sc, 1.0)
    addon.render.add_plane(sc, size=12.0, material=m)
    for wo, a in zip(views, alb):
        got = {}
        for osl in (False, True):
            for o in [o for o in sc.objects if o.type == "CAMERA"]:
                bpy.data.objects.remove(o)
            addon.render.add_camera(sc, location=tuple(5 * wo), target=(0, 0, 0), ortho_scale=0.5)
            addon.render.configure_cycles(sc, samples=32, res=(32, 32), seed=1, osl=osl, max_bounces=1)
            img, _ = addon.render.render_array(sc, str(render_dir), name=f"large{osl}")
            got[osl] = img.reshape(-1, 3).mean(0)
        with capsys.disabled():
            print(f"\n[large table] view {wo.round(2)}: SVM {got[False]} OSL {got[True]} albedo {a}")
        np.testing.assert_allclose(got[False], a, rtol=0.015)
        np.testing.assert_allclose(got[True], a, rtol=0.015)
        np.testing.assert_allclose(got[True], got[False], rtol=0.02)
