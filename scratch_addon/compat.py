"""Differences between the Blender versions and hosts the add-on supports (4.2 LTS, 4.5 LTS, 5.0; the
application and bpy as a Python module)."""
from __future__ import annotations

#: The bpy 4.2 *Python module* (not the Blender 4.2 application) segfaults at interpreter exit once any Python
#: class was registered into a space type: an Operator or a Panel alone does it (add-on-free reproducers in
#: tests/stock/test_stock_blender.py; a PropertyGroup with an update callback too, after unregistering).  An
#: earlier version registered our PropertyGroups without update callbacks there, hoping to avoid it; measured
#: (stock bpy 4.2.23, the built zip installed and enabled, every callback removed): the process still exits 139,
#: because every add-on registers operators.  So the callbacks stay everywhere: live edits work in the 4.2
#: module too, and the exit crash is upstream's (fixed in 4.3+).
PROPERTY_GROUP_CALLBACKS = True


def update(callback):
    """``callback`` as a PropertyGroup ``update=`` (kept as the one place to change if a host needs it)."""
    return callback if PROPERTY_GROUP_CALLBACKS else None
