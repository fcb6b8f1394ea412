"""Material builders: thin wrappers that put node groups into a material's node tree."""
from __future__ import annotations

import bpy

from ..node_groups import brushed
from ..precompute.validation import check_color, check_range  # noqa: F401 - the glue's validators


def ensure_nodes(idblock):
    """The node tree of a material or world, switching its nodes on where Blender < 5.0 has them off."""
    if idblock.node_tree is None or (bpy.app.version < (5, 0, 0) and not idblock.use_nodes):
        idblock.use_nodes = True  # 5.0 always has a node tree (use_nodes is deprecated there)
    return idblock.node_tree


def new_material(name: str) -> bpy.types.Material:
    """A material with an empty node tree plus a Material Output node."""
    mat = bpy.data.materials.new(name)
    ensure_nodes(mat).nodes.clear()
    out = mat.node_tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    return mat


def make_brushed_material(
    name: str = "Brushed Baseline",
    color=(0.91, 0.92, 0.92),
    roughness: float = 0.3,
    anisotropy: float = 0.8,
    rotation: float = 0.0,
) -> bpy.types.Material:
    """Anisotropic GGX brushed metal (SVM), the baseline the scratch materials are compared with."""
    rgba = check_color("color", color)
    roughness = check_range("roughness", roughness, 0.0, 1.0)
    anisotropy = check_range("anisotropy", anisotropy, -1.0, 1.0)
    rotation = check_range("rotation", rotation, 0.0, 1.0)
    group = brushed.ensure()
    mat = new_material(name)
    tree = mat.node_tree
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Color"].default_value = rgba
    node.inputs["Roughness"].default_value = roughness
    node.inputs["Anisotropy"].default_value = anisotropy
    node.inputs["Rotation"].default_value = rotation
    tree.links.new(node.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    mat["scratch_addon_kind"] = "brushed"
    return mat
