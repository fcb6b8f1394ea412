"""The SVM twin's layer coordinates through each layer Voronoi's own texture mapping (issue 15 item 4).

Eq. 7, y = diag(l, w)^-1 R(Θ_k) (u, v) + ξ_k, is the Voronoi node's texture mapping (a matrix Cycles folds at
sync) instead of a Mapping node per layer (which builds its matrix from the Euler rotation every sample).  Oracle:
the numpy twin of Cycles' Voronoi (``precompute.scratch.layers.voronoi_f1``) at the UV point the render shaded,
read back from the same render (emission (F1, u, v): the comparison needs no camera model).  It holds after a
live Length edit, a seed change (``set_layer_constants``) and on two frames of a keyframed Length; the old
length's oracle is far off the new render (the test sees a mapping that did not follow).
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy]

#: moderate scratch sizes, so that a 40-pixel render resolves the Voronoi cells (a pixel spans < 0.2 cell)
LAYERS = dict(n_layers=3, theta_deg=60.0, length=0.3, width=0.06, density=0.3, seed=1)


def _mods(addon):
    root = addon.__name__.rpartition(".")[0]
    return (importlib.import_module(root + ".node_groups.scratch_svm"),
            importlib.import_module(root + ".precompute.scratch.layers"))


@pytest.fixture
def layered(addon, scene):
    render = addon.render
    scene = render.reset_scene()
    mat = addon.api.make_scratched_material("fig1c_scratched", layers=dict(LAYERS), resolution=64, backend="svm")
    render.add_plane(scene, size=2.0, material=mat)
    render.add_camera(scene, location=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), ortho_scale=1.6)
    render.configure_cycles(scene, samples=1, res=(40, 40), seed=0)
    return scene, mat


def _show_layer(mat, svm, k: int):
    """Emission (F1_k, u, v) as the material's only output: F1 of layer k's Voronoi node as built."""
    tree = mat.node_tree
    vor = next(n for n in tree.nodes if n.get(svm.LAYER_CONST) == f"svm/vor/{k}")
    assert vor.bl_idname == "ShaderNodeTexVoronoi"
    for n in [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]:
        tree.nodes.remove(n)
    uv = tree.nodes.new("ShaderNodeUVMap")
    comb = tree.nodes.new("ShaderNodeCombineXYZ")
    tree.links.new(vor.outputs["Distance"], comb.inputs[0])
    sep = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(uv.outputs["UV"], sep.inputs[0])
    tree.links.new(sep.outputs[0], comb.inputs[1])
    tree.links.new(sep.outputs[1], comb.inputs[2])
    em = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(comb.outputs[0], em.inputs["Color"])
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(em.outputs[0], out.inputs["Surface"])


def _f1_error(addon, scene, tmp, name, layers_mod, params, k):
    """(max |F1 rendered - F1 numpy| at the shaded UV points, F1 spread) for LayerParams ``params``."""
    img, _ = addon.render.render_array(scene, str(tmp), name)
    f1, uv = img[..., 0].astype(np.float64), img[..., 1:3].astype(np.float64)
    theta, xi = layers_mod.layer_transforms(params)
    c, s = np.cos(theta[k]), np.sin(theta[k])
    y = np.stack([(c * uv[..., 0] + s * uv[..., 1]) / params.length + xi[k, 0],
                  (-s * uv[..., 0] + c * uv[..., 1]) / params.width + xi[k, 1]], -1)
    return float(np.abs(f1 - layers_mod.voronoi_f1(y)).max()), float(f1.std())


def test_layer_voronoi_texture_mapping_is_eq7(addon, layered, tmp_path):
    svm, layers_mod = _mods(addon)
    scene, mat = layered
    tree = mat.node_tree
    assert not any(n.bl_idname == "ShaderNodeMapping" for n in tree.nodes), "a Mapping node per layer is back"
    lp = layers_mod.LayerParams(**LAYERS)
    _show_layer(mat, svm, 2)
    err, spread = _f1_error(addon, scene, tmp_path, "built", layers_mod, lp, 2)
    # float32 UVs of the render (|uv| <= 1, ~6e-8) divided by w = 0.06: ~1e-6 in y; 1e-4 leaves room
    assert spread > 0.1 and err < 1e-4, (err, spread)

    nodes = sorted(n.as_pointer() for n in tree.nodes)
    mat.scratch.length = 0.17                        # a live edit: written into the mapping, no rebuild
    assert sorted(n.as_pointer() for n in tree.nodes) == nodes
    new = layers_mod.LayerParams(**dict(LAYERS, length=0.17))
    err, _ = _f1_error(addon, scene, tmp_path, "length", layers_mod, new, 2)
    stale, _ = _f1_error(addon, scene, tmp_path, "length2", layers_mod, lp, 2)
    assert err < 1e-4 and stale > 0.05, (err, stale)

    mat.scratch.seed = 9                             # new Θ_k, ξ_k in place (set_layer_constants)
    assert addon.live.last_update()["kind"] == "tables"
    _show_layer(mat, svm, 2)
    seeded = layers_mod.LayerParams(**dict(LAYERS, length=0.17, seed=9))
    err, _ = _f1_error(addon, scene, tmp_path, "seed", layers_mod, seeded, 2)
    assert err < 1e-4, err


def test_keyframed_length_renders_differently_on_two_frames(addon, layered, tmp_path):
    """A keyframed panel Length reaches the layer mappings on every frame (``scratch_addon.live``'s frame handler
    writes the Length socket and, through ``scratch_svm.set_layer_size``, the mappings)."""
    svm, layers_mod = _mods(addon)
    scene, mat = layered
    _show_layer(mat, svm, 0)
    lengths = {1: 0.12, 2: 0.4}
    for frame, length in lengths.items():
        mat.scratch.length = length
        mat.scratch.keyframe_insert("length", frame=frame)
    renders = {}
    for frame in (2, 1):
        scene.frame_set(frame)
        lp = layers_mod.LayerParams(**dict(LAYERS, length=lengths[frame]))
        err, _ = _f1_error(addon, scene, tmp_path, f"frame{frame}", layers_mod, lp, 0)
        assert err < 1e-4, (frame, err)
        renders[frame] = addon.render.render_array(scene, str(tmp_path), f"again{frame}")[0][..., 0]
    assert np.abs(renders[1] - renders[2]).mean() > 0.05


def test_set_layer_size_writes_both_twins(addon, scene):
    """``set_layer_size`` rewrites every tagged layer node's scale and offset (the EEVEE twin of a race too) and
    nothing when the size is unchanged."""
    svm, layers_mod = _mods(addon)
    mat = addon.api.make_scratched_material("fig1c_scratched", resolution=64, backend="svm",
                                            layers=dict(LAYERS, n_layers=16))
    nodes = [n for n in svm.tree_nodes(mat.node_tree) if n.get(svm.LAYER_XFORM) is not None]
    assert {n[svm.LAYER_CONST].split("/")[0] for n in nodes} == {"eevee"}   # 16 layers: a race on Cycles
    assert svm.set_layer_size(mat.node_tree, LAYERS["length"], LAYERS["width"]) == 0
    assert svm.set_layer_size(mat.node_tree, 0.5, 0.01) == len(nodes) == 8   # the merged EEVEE preview
    for n in nodes:
        theta, xi0, xi1 = n[svm.LAYER_XFORM]
        tm = n.texture_mapping
        assert tuple(tm.scale) == pytest.approx((0.5, 0.01, 1.0))
        c, s = np.cos(theta), np.sin(theta)
        # L = -R_z(Θ) S ξ
        assert tuple(tm.translation)[:2] == pytest.approx((-(c * 0.5 * xi0 - s * 0.01 * xi1),
                                                          -(s * 0.5 * xi0 + c * 0.01 * xi1)), rel=1e-5, abs=1e-7)


def test_race_position_layer_coordinates_are_eq7(addon, scene, tmp_path):
    """A layer race (16 layers) reads the layer of its position from the order row floor(h_layer P): the first
    position's F1 equals the numpy Voronoi twin of that layer (eq. 7, the Z-axis rotate + divide + offset of
    ``race_group``) at the shaded UV point.  Two renders with the same seed shade the same points: (F1, u, v)
    and (h_layer, u, v)."""
    svm, layers_mod = _mods(addon)
    render = addon.render
    scene = render.reset_scene()
    lp = layers_mod.LayerParams(**dict(LAYERS, n_layers=16))
    mat = addon.api.make_scratched_material("fig1c_scratched", layers=dict(LAYERS, n_layers=16), resolution=64,
                                            backend="svm")
    render.add_plane(scene, size=2.0, material=mat)
    render.add_camera(scene, location=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), ortho_scale=1.6)
    render.configure_cycles(scene, samples=1, res=(40, 40), seed=0)
    grp = next(n.node_tree for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeGroup"
               and n.node_tree is not None and n.node_tree.get(svm.RACE_GROUP))
    gin = next(n for n in grp.nodes if n.bl_idname == "NodeGroupInput")
    gout = next(n for n in grp.nodes if n.bl_idname == "NodeGroupOutput")
    vor = next(n for n in grp.nodes if n.bl_idname == "ShaderNodeTexVoronoi")
    sep = grp.nodes.new("ShaderNodeSeparateXYZ")
    grp.links.new(gin.outputs["UV"], sep.inputs[0])
    comb = grp.nodes.new("ShaderNodeCombineXYZ")
    grp.links.new(sep.outputs[0], comb.inputs[1])
    grp.links.new(sep.outputs[1], comb.inputs[2])
    em = grp.nodes.new("ShaderNodeEmission")
    grp.links.new(comb.outputs[0], em.inputs["Color"])
    grp.links.new(em.outputs[0], gout.inputs["Shader"])
    # the outermost position (0) feeds the material output; switch the Cycles path on (no OSL)
    grp.links.new(vor.outputs["Distance"], comb.inputs[0])
    f1_img, _ = render.render_array(scene, str(tmp_path), "f1")
    grp.links.new(gin.outputs["h_layer"], comb.inputs[0])
    h_img, _ = render.render_array(scene, str(tmp_path), "h")
    assert np.array_equal(f1_img[..., 1:], h_img[..., 1:])          # the same shading points
    uv = f1_img[..., 1:3].astype(np.float64)
    order = svm.race_orders(16)
    row = np.clip(np.floor(h_img[..., 0].astype(np.float64) * len(order)), 0, len(order) - 1).astype(int)
    k = order[row, 0]
    theta, xi = layers_mod.layer_transforms(lp)
    c, s = np.cos(theta[k]), np.sin(theta[k])
    y = np.stack([(c * uv[..., 0] + s * uv[..., 1]) / lp.length + xi[k, 0],
                  (-s * uv[..., 0] + c * uv[..., 1]) / lp.width + xi[k, 1]], -1)
    err = np.abs(f1_img[..., 0] - layers_mod.voronoi_f1(y))
    # a row read off by one near a row boundary (float32 h P) is a different layer: allow 1 % of the pixels
    assert len(np.unique(k)) > 8 and np.mean(err < 1e-4) > 0.99, (np.mean(err < 1e-4), err.max())
