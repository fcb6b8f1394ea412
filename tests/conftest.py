"""Test harness.

- Hermetic Blender: ``BLENDER_USER_RESOURCES`` and the table cache point into a temp dir
  *before* anything imports bpy (numpy-only tests never import it).
- ``extension`` (session): builds the extension zip with Blender's own ``blender_ext.py
  build`` and installs + enables it the way a user's Blender does
  (``bpy.ops.extensions.package_install_files``).  Yields the installed add-on package.
- ``scene`` (per test): an empty file before and after the test.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
_TMP = Path(tempfile.mkdtemp(prefix="scratch_tests_"))
os.environ["BLENDER_USER_RESOURCES"] = str(_TMP / "blender_user")
os.environ["SCRATCH_ADDON_CACHE"] = str(_TMP / "cache")
EXTENSION_MODULE = "bl_ext.user_default.scratch_addon"


def blender_ext_cli() -> Path:
    """Blender's extension build/validate CLI shipped inside the bpy wheel."""
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    base = Path(spec.origin).parent
    hits = sorted(base.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not hits:
        raise FileNotFoundError(f"blender_ext.py not found under {base}")
    return hits[-1]


def build_extension_zip(out_dir: Path) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, str(blender_ext_cli()), "build", "--source-dir", str(ROOT),
                           "--output-dir", str(out_dir)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    zips = sorted(out_dir.glob("scratch_addon-*.zip"))
    assert len(zips) == 1, proc.stdout
    return zips[0]


@pytest.fixture(scope="session")
def extension_zip() -> Path:
    return build_extension_zip(_TMP / "dist")


@pytest.fixture(scope="session")
def extension(extension_zip):
    """The installed, enabled extension package (``bl_ext.user_default.scratch_addon``)."""
    import bpy  # noqa: I001 - first: Blender's own modules (addon_utils) are importable only after bpy
    import addon_utils

    result = bpy.ops.extensions.package_install_files(filepath=str(extension_zip), repo="user_default",
                                                      enable_on_install=True)
    assert result == {"FINISHED"}
    loaded, enabled = addon_utils.check(EXTENSION_MODULE)
    assert loaded and enabled, "extension did not enable"
    yield sys.modules[EXTENSION_MODULE]
    addon_utils.disable(EXTENSION_MODULE)


@pytest.fixture
def addon(extension):
    """The installed ``scratch_addon`` glue package (``...scratch_addon.scratch_addon``)."""
    import importlib

    return importlib.import_module(EXTENSION_MODULE + ".scratch_addon")


@pytest.fixture
def scene(extension):
    """An empty scene before and after the test (add-ons stay enabled)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def render_dir(tmp_path) -> Path:
    return tmp_path
