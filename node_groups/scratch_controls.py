"""Live controls of a scratch material: the one table of panel values that are node sockets.

``SOCKETS`` maps each socket-valued ``material.scratch`` property to where its value lives on each
render path.  Values marked ``controls`` are inputs of one "Scratch Controls" group node (a
pass-through group, free at render time: Cycles removes group proxies and folds unlinked values into
constants) whose outputs feed the OSL script node's input of the same name *and* the SVM / EEVEE
twins' node math, so one socket drives every path; an artist can keyframe it, drive it or link a
texture into it.  Values marked ``base`` / ``diffuse`` are inputs of the base closure node (shared by
both twins) or of the Lambertian term node.

To make another parameter live (e.g. after moving it from a compiled constant into a shader
parameter): add a row here, read the socket in ``scratch_svm.build(controls=...)`` and link the OSL
input in ``scratch_addon.scratch_material``; ``scratch_addon.live`` does the rest.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy

from . import add_socket, ensure_group

GROUP_NAME = "Scratch: Live Controls"
NODE_NAME = "Scratch Controls"
BASE_NODE_NAME = "Scratch Base"
DIFFUSE_NODE_NAME = "Scratch Diffuse"


@dataclass(frozen=True)
class Socket:
    """``prop`` (a ``material.scratch`` property) lives in ``node``'s input ``inputs`` (first that exists);
    ``osl``: the OSL script input it feeds (None: not an OSL parameter); ``svm``: how the SVM twin reads it."""

    prop: str
    node: str                    # "controls", "base" or "diffuse"
    inputs: tuple
    osl: str | None = None
    svm: str = ""
    socket_type: str = "NodeSocketFloat"
    default: object = None
    min_value: float | None = None
    max_value: float | None = None
    when: str = ""               # a condition on the settings, "" = always


#: property -> socket on each path (``scratch_addon.live`` writes them; ``scratch_svm.build(controls=)`` reads them)
SOCKETS = (
    Socket("length", "controls", ("Length",), osl="Length", svm="1 / l in y_k (eq. 7): the layer Voronoi's texture mapping, written on change", default=0.2, min_value=1e-6),
    Socket("width", "controls", ("Width",), osl="Width", svm="1 / w in y_k (eq. 7): the layer Voronoi's texture mapping, written on change", default=2e-4, min_value=1e-7),
    Socket("density", "controls", ("Density",), osl="Density", svm="threshold d of [F1]_d (eq. 7)", default=0.6,
           min_value=0.0, max_value=1.0),
    Socket("tint", "controls", ("Tint",), osl="Tint", svm="lobe colour x tint", socket_type="NodeSocketColor",
           default=(1.0, 1.0, 1.0, 1.0)),
    Socket("base_color", "base", ("Color", "Base Color"), svm="base closure (shared)",
           when="base_type in ('diffuse', 'glossy', 'principled')"),
    Socket("base_roughness", "base", ("Roughness",), svm="base closure (shared)",
           when="base_type in ('glossy', 'principled')"),
    Socket("diffuse_color", "diffuse", ("Color",), svm="Lambertian term (shared)", when="diffuse_type == 'color'"),
)
CONTROLS = tuple(s for s in SOCKETS if s.node == "controls")
VERSION = 1000 + len(CONTROLS)   # the interface follows the table: a new row rebuilds the group


def _build(ng: bpy.types.ShaderNodeTree) -> None:
    for s in CONTROLS:
        add_socket(ng, s.inputs[0], "INPUT", s.socket_type, s.default, s.min_value, s.max_value)
    for s in CONTROLS:
        add_socket(ng, s.inputs[0], "OUTPUT", s.socket_type)
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    gin.location, gout.location = (-200, 0), (200, 0)
    for s in CONTROLS:
        ng.links.new(gin.outputs[s.inputs[0]], gout.inputs[s.inputs[0]])


def ensure() -> bpy.types.ShaderNodeTree:
    """The pass-through group of the ``controls`` sockets."""
    return ensure_group(GROUP_NAME, VERSION, _build)


def add_node(tree, values: dict, location=(-700, 700)):
    """A "Scratch Controls" group node in ``tree`` with inputs set from ``values`` (prop -> value)."""
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = ensure()
    node.name = node.label = NODE_NAME
    node.location = location
    for s in CONTROLS:
        if s.prop in values:
            set_value(node.inputs[s.inputs[0]], values[s.prop])
    return node


def set_value(socket, value) -> bool:
    """Write ``value`` into ``socket`` (RGB gets alpha 1); True if it changed."""
    if isinstance(value, (int, float)):
        value = float(value)
        changed = abs(socket.default_value - value) > 0.0
    else:
        value = tuple(float(v) for v in value)
        n = len(socket.default_value)
        value = (value + (1.0,) * n)[:n]
        changed = tuple(socket.default_value) != value
    if changed:
        socket.default_value = value
    return changed
