"""Which shading path renders: a node group whose output "OSL" is 1 exactly when Cycles runs OSL.

Cycles renders an OSL script node only with *Render › Shading System* set to OSL on a device
that runs OSL (the CPU; OptiX too, but we cannot tell OptiX from CUDA inside a scene); with
SVM (the default, and the only path on CUDA/HIP/Metal) the script node is dropped and its
closure is black.  EEVEE ignores script nodes too.  Our OSL materials therefore carry an SVM
twin of themselves and choose between the two with a Mix Shader whose factor is this group's
output:

    OSL = shading_system * (device == CPU)

computed from two drivers that read the *active scene* (driver variables of type Context
Property: no Python expression, so they run in a .blend opened without the add-on and without
auto-run scripts).  The factor is a constant when Cycles syncs the shader, so its constant
folding removes the unused branch: measured, a Mix of a 40-noise-node SVM branch and an OSL
branch costs what the OSL branch alone costs (0.200 s vs 0.196 s; the SVM branch alone 11.9 s).
OptiX with OSL gets the SVM twin: correct, just not the OSL path.
"""
from __future__ import annotations

import bpy

from . import add_socket, ensure_group

GROUP_NAME = "Scratch: Render Path"
VERSION = 1


def _drive(socket, data_path: str) -> None:
    """Drive ``socket.default_value`` by ``active_scene.<data_path>`` (no Python expression)."""
    socket.driver_remove("default_value")
    driver = socket.driver_add("default_value").driver
    driver.type = "SUM"
    var = driver.variables.new()
    var.name = data_path.rpartition(".")[2]
    var.type = "CONTEXT_PROP"
    var.targets[0].context_property = "ACTIVE_SCENE"
    var.targets[0].data_path = data_path


def _build(ng: bpy.types.ShaderNodeTree) -> None:
    add_socket(ng, "OSL", "OUTPUT", "NodeSocketFloat")
    n = ng.nodes
    is_cpu = n.new("ShaderNodeMath")
    is_cpu.operation = "LESS_THAN"           # cycles.device: CPU = 0, GPU = 1
    is_cpu.label = "Device is CPU"
    is_cpu.inputs[1].default_value = 0.5
    osl = n.new("ShaderNodeMath")
    osl.operation = "MULTIPLY"
    osl.label = "OSL renders"
    gout = n.new("NodeGroupOutput")
    is_cpu.location, osl.location, gout.location = (-200, 0), (0, 0), (200, 0)
    ng.links.new(is_cpu.outputs[0], osl.inputs[1])
    ng.links.new(osl.outputs[0], gout.inputs["OSL"])
    _drive(is_cpu.inputs[0], "cycles.device")
    _drive(osl.inputs[0], "cycles.shading_system")


def ensure() -> bpy.types.ShaderNodeTree:
    """The (up-to-date) node group."""
    return ensure_group(GROUP_NAME, VERSION, _build)


def osl_renders(scene) -> bool:
    """The group's value for ``scene``: True when Cycles would run our OSL script nodes."""
    c = scene.cycles
    return scene.render.engine == "CYCLES" and bool(c.shading_system) and c.device == "CPU"
