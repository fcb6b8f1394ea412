"""Add-on preferences: where precomputed tables are cached."""
from __future__ import annotations

import bpy

from ..precompute.tables import cache
from .ui_utils import USER_ERRORS, report_error, reported_warnings

#: The add-on's module name as Blender knows it: the extension root package
#: (``bl_ext.<repo>.scratch_addon`` installed, ``scratch_materials`` for TD scripts).
ADDON_PACKAGE = __package__.rpartition(".")[0]


def default_cache_dir() -> str:
    """The extension's per-user cache folder, or the library default outside an extension."""
    if ADDON_PACKAGE.startswith("bl_ext."):
        try:
            return bpy.utils.extension_path_user(ADDON_PACKAGE, path="cache", create=True)
        except (ValueError, RuntimeError, OSError):
            pass
    cache.set_cache_dir(None)
    return cache.get_cache_dir()


def _update_cache_dir(self, _context) -> None:
    apply_cache_dir(self)


def apply_cache_dir(prefs=None) -> str:
    """Point ``precompute.tables.cache`` at the preference's folder (or the default); returns it."""
    prefs = prefs if prefs is not None else get_prefs()
    folder = bpy.path.abspath(prefs.cache_dir) if prefs is not None and prefs.cache_dir else default_cache_dir()
    cache.set_cache_dir(folder)
    return folder


def get_prefs():
    """This add-on's preferences, or None when it was registered without addon_utils (TD scripts)."""
    addon = bpy.context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon is not None else None


class ScratchAddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    cache_dir: bpy.props.StringProperty(
        name="Cache Folder",
        description="Folder for precomputed scratch tables (empty: the extension's user cache folder)",
        subtype="DIR_PATH",
        default="",
        update=_update_cache_dir,
    )

    def draw(self, _context):
        layout = self.layout
        layout.prop(self, "cache_dir")
        layout.label(text=f"In use: {cache.get_cache_dir()}", icon="FILE_FOLDER")
        problem = cache.cache_dir_problem()
        if problem:
            layout.label(text=f"Cache folder unusable ({problem}): using a temp folder", icon="ERROR")
        layout.operator("scratch.clear_cache", icon="TRASH")


class SCRATCH_OT_clear_cache(bpy.types.Operator):
    """Delete all cached scratch tables (they are recomputed on demand)"""

    bl_idname = "scratch.clear_cache"
    bl_label = "Clear Table Cache"

    def execute(self, _context):
        try:
            with reported_warnings(self):
                n = cache.clear()
        except USER_ERRORS as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"Removed {n} cached table(s) from {cache.get_cache_dir()}")
        return {"FINISHED"}


classes = (ScratchAddonPreferences, SCRATCH_OT_clear_cache)
