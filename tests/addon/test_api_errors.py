"""Clear errors from the glue (issue #14 items 4 and 5): unknown keywords to the scripting API are a
ValueError naming the keyword and listing the accepted ones; operators report file-system errors in
one line (no traceback); an unusable cache folder falls back to a temp folder with a warning the
operator reports; *Bake Bi-scale* checks its table folder before the bake."""
from __future__ import annotations

import importlib
import time

import numpy as np
import pytest

from scratch_materials.precompute.tables import cache

pytestmark = [pytest.mark.bpy]

FAST = dict(profile=("v_groove", 45.0), resolution=64, slices=16, layers=None, backend="svm")


# ----------------------------------------------------------------------------- unknown keywords

@pytest.mark.parametrize("call, bad, hint", [
    (lambda api: api.make_scratched_material(profil=("quartic", 0.2)), "profil", "profile"),
    (lambda api: api.make_scratched_material("demo", lobe_shapes="table"), "lobe_shapes", "lobe_shape"),
    (lambda api: api.make_material("brushed", colour=(1, 0, 0)), "colour", "color"),
    (lambda api: api.make_material("demo", sample=4), "sample", None),
    (lambda api: api.demo_scene("demo", resolutoin=64), "resolutoin", "resolution"),
    (lambda api: api.render("x.png", sample=4), "sample", "samples"),
    (lambda api: api.preset_names(kind="scratch"), "kind", None),
])
def test_unknown_keywords_are_value_errors_listing_the_accepted_ones(addon, scene, call, bad, hint):
    import bpy

    n_materials, n_objects = len(bpy.data.materials), len(bpy.data.objects)
    with pytest.raises(ValueError) as err:
        call(addon.api)
    msg = str(err.value)
    assert not isinstance(err.value, TypeError)
    assert f"unknown keyword {bad!r}" in msg and "accepted:" in msg
    if hint:
        assert f"did you mean {hint!r}" in msg and hint in msg.split("accepted:")[1]
    assert (len(bpy.data.materials), len(bpy.data.objects)) == (n_materials, n_objects)  # nothing made or wiped


def test_glue_entry_points_check_keywords_too(addon, scene):
    irid = importlib.import_module(addon.__name__ + ".iridescence_material")
    mg = importlib.import_module(addon.__name__ + ".microgeometry_ops")
    bmat = importlib.import_module(addon.__name__ + ".biscale_material")
    mat = addon.materials.new_material("M")
    with pytest.raises(ValueError, match="unknown keyword 'sigma'.*did you mean 'sigma_um'"):
        irid.insert_layer(mat, sigma=10.0)
    with pytest.raises(ValueError, match="unknown keyword 'pixel_size'.*accepted: filepath, pixel_um"):
        mg.material_from_heightfield("x.npy", pixel_size=1.0)
    with pytest.raises(ValueError, match="unknown keyword 'mdoe'.*did you mean 'mode'"):
        bmat.make_biscale_material(mdoe="fit")
    with pytest.raises(ValueError, match="render: .*positional"):
        addon.api.render("a.png", 4, (8, 8), 0, False, "extra")


# ----------------------------------------------------------------------------- operators: one line, no traceback

def _plane(addon, scene):
    import bpy

    obj = addon.render.add_plane(scene)
    bpy.context.view_layer.objects.active = obj
    return obj


def test_operators_report_os_errors_in_one_line(addon, scene, monkeypatch):
    import bpy

    obj = _plane(addon, scene)
    mat = addon.api.make_scratched_material(name="S", **FAST)
    obj.data.materials.append(mat)
    mat.scratch.from_params(FAST)

    def denied(*_a, **_k):
        raise PermissionError(13, "Permission denied", "/studio/cache/scratch_brdf-0123.exr")

    monkeypatch.setattr(addon.scratch_material, "tables", denied)
    for op, kwargs in ((bpy.ops.scratch.update_material, {}), (bpy.ops.scratch.add_preset_material,
                                                                {"preset": "fig14a_shallow"})):
        with bpy.context.temp_override(material=mat), pytest.raises(RuntimeError) as err:
            op(**kwargs)
        msg = str(err.value).strip()
        assert msg == "Error: Permission denied: '/studio/cache/scratch_brdf-0123.exr'", msg
    monkeypatch.undo()
    monkeypatch.setattr(cache, "clear", denied)
    clear = importlib.import_module(addon.__name__ + ".preferences").cache
    monkeypatch.setattr(clear, "clear", denied)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.scratch.clear_cache()
    assert str(err.value).strip() == "Error: Permission denied: '/studio/cache/scratch_brdf-0123.exr'"


def test_an_unusable_cache_folder_falls_back_and_the_operator_warns(addon, scene, tmp_path):
    import bpy

    tables = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.tables.cache")
    _plane(addon, scene)
    not_a_folder = tmp_path / "cache_is_a_file"
    not_a_folder.write_text("x")
    previous = tables._cache_dir  # the extension's folder, set by its preferences: restored below
    tables.set_cache_dir(not_a_folder)
    try:
        assert bpy.ops.scratch.add_preset_material(preset="fig14a_shallow") == {"FINISHED"}
        assert tables.cache_dir_problem() and "directory" in tables.cache_dir_problem().lower()
        used = tables.get_cache_dir()
        # the preset's tables were written to the fallback (table lobes trace no M x M BRDF any more)
        written = ("scratch_brdf-", "scratch_table_lobes-", "scratch_view_slices-")
        assert used != str(not_a_folder) and any(f.startswith(written) for f in __import__("os").listdir(used))
        assert bpy.ops.scratch.clear_cache() == {"FINISHED"}
        prefs = importlib.import_module(addon.__name__ + ".preferences")
        lines = []

        class Layout:  # the preferences panel draws without raising and says why
            def prop(self, *a, **k):
                pass

            def operator(self, *a, **k):
                pass

            def label(self, text="", **k):
                lines.append(text)

        prefs.ScratchAddonPreferences.draw(type("P", (), {"layout": Layout()})(), bpy.context)
        assert any("unusable" in ln for ln in lines)
    finally:
        tables.set_cache_dir(previous)


# ----------------------------------------------------------------------------- bi-scale: folder checked first

@pytest.fixture
def biscale(addon):
    import bpy

    ops = importlib.import_module(addon.__name__ + ".biscale_ops")
    geo = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.geometry")
    tile = ops.add_tile_object(bpy.context, geo.groove_tile(depth=0.4))
    return importlib.import_module(addon.__name__ + ".biscale_material"), tile


def test_bake_fails_before_baking_when_its_table_cannot_be_written(addon, scene, biscale, tmp_path):
    bmat, tile = biscale
    f = tmp_path / "file"
    f.write_text("x")
    target = addon.render.add_plane(scene, size=2.0)
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match="exr_dir: cannot write .*Not a directory"):
        bmat.bake(tile, target, n_lobes=1, exr_dir=str(f / "tables"), n_facets=20000, dir_res=16)
    assert time.perf_counter() - t0 < 2.0  # a 20k-facet bake at dir_res 16 takes far longer
    assert not target.data.materials


def test_bake_operator_with_an_unusable_table_folder_still_bakes(addon, scene, biscale, tmp_path):
    import bpy

    bmat, tile = biscale
    tables = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.tables.cache")
    folder = tmp_path / "cache"
    folder.mkdir()
    (folder / "biscale").write_text("a file where the table folder should be")
    previous = tables._cache_dir
    tables.set_cache_dir(folder)
    target = addon.render.add_plane(scene, size=2.0)
    for o in bpy.context.view_layer.objects:
        o.select_set(o in (tile, target))
    bpy.context.view_layer.objects.active = tile
    try:
        assert bpy.ops.scratch.bake_biscale(target=target.name, n_facets=200, dir_res=4, n_lobes=1,
                                            interreflections="OFF") == {"FINISHED"}
    finally:
        tables.set_cache_dir(previous)
    mat = target.data.materials[0]
    assert mat["scratch_addon_kind"] == "biscale" and mat["biscale_table"].startswith(str(folder))
    assert np.isfinite(mat["biscale_fit_psnr"])


# ----------------------------------------------------------------------------- bi-scale: user-facing option names

def test_biscale_operator_errors_name_the_panel_fields_not_internal_names(addon, scene, biscale):
    import bpy

    _bmat, tile = biscale
    with pytest.raises(RuntimeError) as err:  # a rods tile's Height field feeds geometry.rods_tile(length=...)
        bpy.ops.scratch.add_biscale_tile(kind="RODS", height=7.0)
    msg = str(err.value).strip()
    assert msg.startswith("Error: Height: expected a number in") and "length" not in msg, msg
    target = addon.render.add_plane(scene, size=2.0)
    bpy.context.view_layer.objects.active = tile
    t0 = time.perf_counter()
    with pytest.raises(RuntimeError) as err:  # the reference mode compiles the table into OSL: bounded size
        bpy.ops.scratch.bake_biscale(target=target.name, mode="REFERENCE", dir_res=24, n_facets=100000)
    msg = str(err.value).strip()
    assert time.perf_counter() - t0 < 2.0 and len(msg.splitlines()) == 1
    assert "Direction Resolution" in msg and "dir_res" not in msg, msg
    assert not target.data.materials


def test_biscale_api_unknown_option_is_named_before_the_bake(addon, scene, biscale):
    bmat, tile = biscale
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"unknown bi-scale option 'facets' \(did you mean 'n_facets'\?\)"):
        bmat.bake(tile, None, facets=100000, dir_res=16)
    with pytest.raises(ValueError, match=r"^l_M: expected an integer in \[1, 1024\], got 0$"):
        bmat.bake(tile, None, l_M=0, n_facets=100000)
    assert time.perf_counter() - t0 < 2.0
