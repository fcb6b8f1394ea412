"""Differences between the Blender versions and hosts the add-on supports (4.2 LTS, 4.5 LTS, 5.0; the
application and bpy as a Python module)."""
from __future__ import annotations

import bpy

#: The bpy 4.2 *Python module* (not the Blender 4.2 application) segfaults at interpreter exit once a
#: PropertyGroup with a Python callback (update, get/set, enum items, poll) was registered — even after it
#: was unregistered (a static SpaceType destructor calls bpy_class_free on a finalised interpreter; an
#: add-on-free reproducer does the same, see tests/stock/test_stock_blender.py).  There, and only there,
#: our PropertyGroups register without update callbacks: edits apply on *Update*.
PROPERTY_GROUP_CALLBACKS = not (bpy.app.version < (4, 3, 0) and not bpy.app.binary_path)


def update(callback):
    """``callback`` as a PropertyGroup ``update=`` where Blender can hold it safely, else None."""
    return callback if PROPERTY_GROUP_CALLBACKS else None
