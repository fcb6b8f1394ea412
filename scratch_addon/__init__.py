"""Scratched & microgeometry materials for Cycles (Blender add-on glue).

The extension root package (``bl_ext.<repo>.scratch_addon`` installed, ``scratch_materials`` for TD
scripts) calls ``register()``; this package builds node trees, reads properties and reports, and
reaches the science (``..precompute``), the shaders (``..osl``) and the node groups
(``..node_groups``) by relative imports only.
"""
from __future__ import annotations

import bpy

from . import api, materials, operators, osl_compile, panels, preferences, presets, properties, render  # noqa: F401
from . import biscale_material, biscale_ops, iridescence_material, iridescence_ops, live, microgeometry_ops  # noqa: F401
from . import biscale_truth, merl_ops, tabulated_material  # noqa: F401

_classes = (*preferences.classes, *properties.classes, *iridescence_material.classes, *operators.classes,
            *panels.classes, *biscale_ops.classes, *microgeometry_ops.classes, *iridescence_ops.classes,
            *merl_ops.classes)


def register() -> None:
    for cls in _classes:
        bpy.utils.register_class(cls)
    properties.register_pointer()
    preferences.apply_cache_dir()
    live.register()


def unregister() -> None:
    live.unregister()
    properties.unregister_pointer()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
