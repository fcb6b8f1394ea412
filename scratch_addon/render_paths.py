"""Materials that render wherever the user renders: Cycles SVM (the default, GPU), Cycles OSL, EEVEE.

An OSL-backed material holds two surfaces: the OSL script's closure and an SVM twin built from
ordinary nodes.  The Cycles output takes a Mix Shader between them whose factor is the
``Scratch: Render Path`` group (1 exactly when Cycles runs OSL on the CPU; drivers on the active
scene, see ``node_groups/render_path.py``), and a second Material Output with target EEVEE takes
the SVM twin (tabulated BRDFs: the table graph's EEVEE variant, ``tabulated_material``; a fitted twin
where the table does not fit the images or ``eevee_table=False``).  Materials without OSL keep one
output (target All).  ``describe`` says which path renders a material in a scene.
"""
from __future__ import annotations

import bpy

from ..node_groups import render_path

SWITCH_NAME = "Scratch Render Path"      # the Mix Shader
SWITCH_GROUP_NAME = "Scratch Render Path Value"
EEVEE_OUTPUT_NAME = "Material Output (EEVEE)"


def _outputs(tree):
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]


def cycles_output(tree):
    """The Material Output Cycles uses (target Cycles or All; the active one first)."""
    outs = [n for n in _outputs(tree) if n.target in ("CYCLES", "ALL")]
    if not outs:
        raise ValueError("material has no Material Output node for Cycles")
    return next((n for n in outs if n.is_active_output), outs[0])


def switch_shader(tree, svm_socket, osl_socket, location=(0.0, 0.0)):
    """A Mix Shader: ``svm_socket`` unless Cycles runs OSL, then ``osl_socket``; returns the Mix node
    (its factor comes from a ``Scratch: Render Path`` group node)."""
    value = tree.nodes.new("ShaderNodeGroup")
    value.node_tree = render_path.ensure()
    value.name = value.label = SWITCH_GROUP_NAME
    value.location = (location[0] - 200, location[1] + 120)
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.name = mix.label = SWITCH_NAME
    mix.location = location
    tree.links.new(value.outputs["OSL"], mix.inputs["Fac"])
    if svm_socket is not None:
        tree.links.new(svm_socket, mix.inputs[1])
    tree.links.new(osl_socket, mix.inputs[2])
    return mix


def switch_nodes(mix) -> list:
    """The Mix node of a switch and the group node feeding its factor."""
    fac = mix.inputs["Fac"]
    return [mix] + ([fac.links[0].from_node] if fac.is_linked else [])


def link_surface(tree, svm_socket, osl_socket=None, out=None, eevee: bool = True, eevee_socket=None):
    """Wire a material's surface: one output (target All) for a node-group surface; otherwise the
    Cycles output gets the render-path switch between ``svm_socket`` and ``osl_socket`` (or
    ``svm_socket`` alone) and, with ``eevee``, an EEVEE output gets ``eevee_socket`` (a lighter
    preview) or the SVM twin.  Returns the switch's Mix node or None."""
    out = out or cycles_output(tree)
    if osl_socket is None and eevee_socket is None:
        out.target = "ALL"
        tree.links.new(svm_socket, out.inputs["Surface"])
        return None
    out.target = "CYCLES"
    x, y = out.location
    mix = None if osl_socket is None else switch_shader(tree, svm_socket, osl_socket, (x - 200, y))
    tree.links.new(svm_socket if mix is None else mix.outputs["Shader"], out.inputs["Surface"])
    if eevee:
        node = tree.nodes.get(EEVEE_OUTPUT_NAME) or tree.nodes.new("ShaderNodeOutputMaterial")
        node.name = node.label = EEVEE_OUTPUT_NAME
        node.target = "EEVEE"
        node.location = (x, y - 200)
        if (eevee_socket or svm_socket) is not None:
            tree.links.new(eevee_socket or svm_socket, node.inputs["Surface"])
    return mix


def has_osl(material) -> bool:
    """True if the material holds an OSL script node (or a node group holding one: the scratch shader's)."""
    tree = material.node_tree
    return tree is not None and any(n.bl_idname == "ShaderNodeScript" or (
        n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None
        and any(m.bl_idname == "ShaderNodeScript" for m in n.node_tree.nodes)) for n in tree.nodes)


def describe(material, scene) -> tuple[str, str]:
    """(icon, one line) saying which path renders ``material`` in ``scene`` and why."""
    engine = scene.render.engine
    if not has_osl(material):
        return "CHECKMARK", "Node groups: renders in Cycles (CPU, GPU, OSL or SVM) and EEVEE"
    iridescent = material.get("scratch_addon_iridescent_layer") is not None
    table = material.get("tabulated_svm")            # tabulated BRDFs: "table" (node graph) or "fit"
    what = "iridescent glints" if iridescent else "tabulated BRDF" if table else "OSL shader"
    if engine != "CYCLES":
        if material.get("tabulated_eevee") == "table":
            return "CHECKMARK", (f"{engine.title().replace('_', ' ')} renders the tabulated BRDF as node groups (one "
                                 "sampled closure per pixel sample: grain falls with Render Samples)")
        twin = ("the base material without glints" if iridescent else "its fitted node twin (an approximation)"
                if table else "its SVM twin (node groups)")
        need = "Cycles" if table == "table" else "Cycles OSL on the CPU"
        return "INFO", f"{engine.title().replace('_', ' ')} renders {twin}; the {what} needs {need}"
    if render_path.osl_renders(scene):
        return "CHECKMARK", f"Cycles renders the {what} (Shading System OSL, CPU)"
    if table == "table":
        return "CHECKMARK", "Cycles renders the tabulated BRDF as node groups (SVM, CPU or GPU)"
    why = "Shading System is SVM" if not scene.cycles.shading_system else "OSL runs on the CPU only"
    if table:
        return "INFO", f"Cycles renders the fitted node twin (an approximation; the table is too large): {why}"
    twin = "the base material without glints" if iridescent else "the SVM twin (binary scratch coverage)"
    return "INFO", f"Cycles renders {twin}: {why}"
