"""Shader node groups built in Python (the SVM path: works on GPU, in EEVEE and without OSL).

Each group is built by one function, found by name and rebuilt when its version stamp
is stale, so a .blend never holds the only copy of a design.
"""
from __future__ import annotations

from typing import Callable

import bpy

_STAMP = "scratch_addon_version"


def ensure_group(name: str, version: int, build: Callable[[bpy.types.ShaderNodeTree], None]) -> bpy.types.ShaderNodeTree:
    """Return node group ``name``, (re)building it with ``build(tree)`` if missing or older than ``version``."""
    ng = bpy.data.node_groups.get(name)
    if ng is not None and ng.bl_idname == "ShaderNodeTree" and ng.get(_STAMP) == version:
        return ng
    if ng is None:
        ng = bpy.data.node_groups.new(name, "ShaderNodeTree")
    else:
        ng.nodes.clear()
        ng.interface.clear()
    build(ng)
    ng[_STAMP] = version
    return ng


def add_socket(tree, name: str, in_out: str, socket_type: str, default=None, min_value=None, max_value=None):
    """Add an interface socket to a group (``in_out`` is 'INPUT' or 'OUTPUT')."""
    sock = tree.interface.new_socket(name, in_out=in_out, socket_type=socket_type)
    if default is not None:
        sock.default_value = default
    if min_value is not None:
        sock.min_value = min_value
    if max_value is not None:
        sock.max_value = max_value
    return sock
