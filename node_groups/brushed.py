"""Anisotropic GGX "brushed metal" baseline (SVM): the reference every scratch material is timed against.

Inputs: Color, Roughness (GGX alpha = roughness^2 as in Cycles), Anisotropy in [-1, 1],
Rotation (0..1 of a turn). The tangent follows the active UV map's U direction so
brushing follows the UV layout.
"""
from __future__ import annotations

import bpy

from . import add_socket, ensure_group

GROUP_NAME = "Scratch: Brushed Baseline"
VERSION = 1


def _build(ng: bpy.types.ShaderNodeTree) -> None:
    add_socket(ng, "Color", "INPUT", "NodeSocketColor", (0.9, 0.9, 0.9, 1.0))
    add_socket(ng, "Roughness", "INPUT", "NodeSocketFloat", 0.3, 0.0, 1.0)
    add_socket(ng, "Anisotropy", "INPUT", "NodeSocketFloat", 0.8, -1.0, 1.0)
    add_socket(ng, "Rotation", "INPUT", "NodeSocketFloat", 0.0, 0.0, 1.0)
    add_socket(ng, "BSDF", "OUTPUT", "NodeSocketShader")
    n = ng.nodes
    gin, gout = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    tangent = n.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    glossy = n.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "MULTI_GGX"
    gin.location, tangent.location, glossy.location, gout.location = (-400, 0), (-200, -250), (0, 0), (250, 0)
    link = ng.links.new
    link(gin.outputs["Color"], glossy.inputs["Color"])
    link(gin.outputs["Roughness"], glossy.inputs["Roughness"])
    link(gin.outputs["Anisotropy"], glossy.inputs["Anisotropy"])
    link(gin.outputs["Rotation"], glossy.inputs["Rotation"])
    link(tangent.outputs["Tangent"], glossy.inputs["Tangent"])
    link(glossy.outputs["BSDF"], gout.inputs["BSDF"])


def ensure() -> bpy.types.ShaderNodeTree:
    """The (up-to-date) node group."""
    return ensure_group(GROUP_NAME, VERSION, _build)
