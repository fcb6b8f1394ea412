"""The extension builds with Blender's own tool, validates, installs and enables; the
TD route (repo root on sys.path + scratch_addon.register()) works too."""
from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import ROOT, blender_ext_cli

pytestmark = pytest.mark.bpy


def test_zip_validates_with_blenders_validator(extension_zip):
    proc = subprocess.run([sys.executable, str(blender_ext_cli()), "validate", str(extension_zip)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    names = set(zipfile.ZipFile(extension_zip).namelist())
    assert {"blender_manifest.toml", "__init__.py", "scratch_addon/__init__.py", "precompute/tables/cache.py",
            "osl/aniso_ggx.osl", "node_groups/brushed.py"} <= names
    assert not [n for n in names if n.startswith(("tests/", "bench/", ".")) or "__pycache__" in n or n == "scratch_materials.py"]


def test_validator_rejects_a_broken_manifest(tmp_path):
    # The validation test above must be able to fail: a manifest without an id is refused.
    src = tmp_path / "src"
    src.mkdir()
    (src / "__init__.py").write_text("def register(): pass\ndef unregister(): pass\n")
    text = (ROOT / "blender_manifest.toml").read_text().replace('id = "scratch_addon"', "")
    (src / "blender_manifest.toml").write_text(text)
    proc = subprocess.run([sys.executable, str(blender_ext_cli()), "validate", str(src)], capture_output=True, text=True)
    assert proc.returncode != 0


def test_extension_is_enabled_with_preferences_and_cache(extension, addon):
    import bpy

    prefs = bpy.context.preferences.addons[extension.__name__].preferences
    assert prefs.cache_dir == ""
    cache = sys.modules[extension.__name__ + ".precompute.tables.cache"]
    folder = Path(cache.get_cache_dir())
    assert folder.is_dir() and "scratch_addon" in str(folder) and "extensions" in str(folder)
    prefs.cache_dir = str(folder.parent / "custom_cache")
    try:
        assert Path(cache.get_cache_dir()) == folder.parent / "custom_cache"
    finally:
        prefs.cache_dir = ""
    assert Path(cache.get_cache_dir()) == folder
    assert hasattr(bpy.types, "SCRATCH_OT_add_preset_material")


def test_operator_assigns_preset_material(scene, addon):
    import bpy

    addon.render.add_plane(scene)
    obj = scene.objects["Plane"]
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.scratch.add_preset_material(preset="brushed") == {"FINISHED"}
    assert obj.active_material is not None and obj.active_material["scratch_addon_kind"] == "brushed"


def test_operator_poll_refuses_without_mesh(scene):
    import bpy

    with pytest.raises(RuntimeError, match="Select a mesh object"):
        bpy.ops.scratch.add_preset_material(preset="brushed")


def test_td_route_register_from_repo_root(tmp_path):
    # the documented TD entry point: the repository on sys.path, the extension root as scratch_materials;
    # one name per module (no top-level precompute / scratch_addon imported)
    code = (
        "import os, sys, tempfile\n"
        "os.environ['BLENDER_USER_RESOURCES'] = tempfile.mkdtemp()\n"
        f"sys.path.insert(0, {str(ROOT)!r})\n"
        "import bpy, scratch_materials as sm\n"
        "sm.register()\n"
        "from scratch_materials.scratch_addon import api\n"
        "from scratch_materials.precompute.scratch import profiles\n"
        "m = api.make_material('brushed')\n"
        "assert hasattr(bpy.types, 'SCRATCH_OT_add_preset_material')\n"
        "assert isinstance(api.scratch_material.validate(profile=profiles.quartic(0.2)).profile, profiles.Profile)\n"
        "sm.unregister()\n"
        "assert not hasattr(bpy.types, 'SCRATCH_OT_add_preset_material')\n"
        "assert not {'precompute', 'scratch_addon', 'osl', 'node_groups'} & set(sys.modules)\n"
        "print('OK', m.name)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0 and "OK Scratch brushed" in proc.stdout, proc.stderr[-2000:]
