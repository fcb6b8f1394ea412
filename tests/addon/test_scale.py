"""Scratch materials at scale (issue 15 item 5): what a material adds to the .blend must not change its render.

Independent references: the same material with every table image as a full RGBA copy (the layout before the
RGB packing), and the saved .blend reopened (the tables read back from their packed EXR files).
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy, pytest.mark.render]


def _svm(addon):
    return importlib.import_module(addon.__name__.rsplit(".", 1)[0] + ".node_groups.scratch_svm")


def _stage(addon, scene, material):
    addon.render.add_plane(scene, size=2.0, material=material, uv_size=0.05)
    addon.render.add_light(scene, "POINT", location=(0.3, -0.5, 1.0), energy=50.0, size=0.05)
    addon.render.uniform_world(scene, 0.2)
    addon.render.add_camera(scene, location=(0.0, -1.5, 1.2), target=(0.0, 0.0, 0.0), lens=35.0)
    addon.render.configure_cycles(scene, samples=4, res=(32, 32), osl=False)


def _table_nodes(addon, material):
    """The table and race image nodes of ``material``, inside its race group (``scratch_svm.race_group``) too."""
    return [n for n in _svm(addon).tree_nodes(material.node_tree) if n.bl_idname == "ShaderNodeTexImage"
            and n.image is not None
            and n.image.name.startswith(("Scratch table ", "Scratch layer "))]


def _pixels(img):
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


def test_rgb_table_images_render_as_rgba_and_survive_a_reload(addon, scene, render_dir, tmp_path):
    """N, A, C, Y and the race's parameters image are RGB (3/4 of the packed bytes): the SVM render equals the
    render with RGBA copies (alpha 0, the old layout) exactly, and the reopened .blend holds the same RGB values
    and renders the same pixels (4-layer race, lossy iron: every table image role)."""
    import bpy

    svm = _svm(addon)
    mat = addon.api.make_scratched_material("fig1b_brushed")
    _stage(addon, scene, mat)
    ref, _ = addon.render.render_array(scene, str(render_dir), "rgb")
    assert ref.mean() > 0.01
    nodes = _table_nodes(addon, mat)
    rgb = {n.image.name: n.image for n in nodes if n.image.depth == 96}
    roles = {name.split(" ")[2] for name in rgb}
    assert {"N", "A", "C", "Y", "race"} <= roles, roles
    before = {name: _pixels(img)[..., :3].copy() for name, img in rgb.items()}
    # RGBA copies (alpha 0): a shader reading an RGB image's alpha (1 in Blender's buffer) would render otherwise
    old = {n.as_pointer(): n.image for n in nodes}
    for n in nodes:
        if n.image.name in rgb:
            px = _pixels(n.image).copy()
            px[..., 3] = 0.0
            n.image = svm._data_image("RGBA copy " + n.image.name, px, alpha=True)
    rgba, _ = addon.render.render_array(scene, str(render_dir), "rgba")
    np.testing.assert_array_equal(rgba, ref)
    for n in nodes:
        n.image = old[n.as_pointer()]
    path = str(tmp_path / "scale.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    for name, px in before.items():
        img = bpy.data.images[name]
        assert img.packed_file is not None
        np.testing.assert_array_equal(_pixels(img)[..., :3], px, err_msg=name)
    again, _ = addon.render.render_array(bpy.context.scene, str(render_dir), "reload")
    np.testing.assert_array_equal(again, ref)


def test_rgb_image_refuses_a_fourth_channel(addon):
    svm = _svm(addon)
    arr = np.zeros((2, 3, 4), np.float32)
    arr[0, 0, 3] = 0.5
    with pytest.raises(ValueError, match="fourth channel"):
        svm._data_image("Scratch test", arr, alpha=False)


def _race_groups(addon, material) -> list:
    key = _svm(addon).RACE_GROUP
    return [n.node_tree.name for n in material.node_tree.nodes
            if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None and n.node_tree.get(key)]


def test_race_positions_share_one_group_and_a_table_edit_renders_like_a_fresh_build(addon, scene, render_dir):
    """A layer race holds one instance of its material's position group per position (not a copy of the
    position's graph per position); a table edit (``apply_tables``) gives the same SVM render as a fresh build
    and leaves the other material's group alone."""
    import bpy

    m1 = addon.api.make_scratched_material("fig1b_brushed")
    m2 = addon.api.make_scratched_material("fig1b_brushed", tint=(1.0, 0.8, 0.6))
    g1, g2 = _race_groups(addon, m1), _race_groups(addon, m2)
    assert len(g1) == 4 and len(set(g1)) == 1 and len(set(g2)) == 1   # 4 layers: 4 positions, one group
    assert len(m1.node_tree.nodes) < 200                              # was 322 with a lobe copy per position
    before = sorted(n.image.name for n in bpy.data.node_groups[g2[0]].nodes if n.bl_idname == "ShaderNodeTexImage")
    m1.scratch.metal = "gold"
    assert addon.live.last_update()["kind"] in ("tables", "rebuild")
    fresh = bpy.data.materials.new("fresh")
    addon.api.make_scratched_material(material=fresh, **m1.scratch.to_params())
    assert _race_groups(addon, m2) == g2
    assert sorted(n.image.name for n in bpy.data.node_groups[g2[0]].nodes
                  if n.bl_idname == "ShaderNodeTexImage") == before
    _stage(addon, scene, m1)
    edited, _ = addon.render.render_array(scene, str(render_dir), "edited")
    scene.objects["Plane"].data.materials[0] = fresh
    built, _ = addon.render.render_array(scene, str(render_dir), "fresh")
    np.testing.assert_array_equal(edited, built)
