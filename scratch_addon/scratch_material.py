"""Build the scratch SV-BRDF material (Raymond et al. 2016) in a Cycles node tree.

Pipeline: ``precompute.scratch.material.validate`` (parameters) -> ``tables`` (ρ0, ρm, γ from
``precompute.scratch.brdf.simulate``; lobe data from ``precompute.scratch.lobes``; all cached by
content hash) -> ``osl.scratch_svbrdf`` (specialised OSL source, tables compiled in) -> INTERNAL
script node with UV Map and Tangent nodes and the base closure linked to its ``Base`` input, plus
its node-group twin (``node_groups.scratch_svm``) for Cycles SVM, GPU and EEVEE (``render_paths``).
"""
from __future__ import annotations

import dataclasses
import json

import bpy
import numpy as np

from ..node_groups import scratch_svm
from ..osl import scratch_svbrdf
from ..precompute.scratch import layers as scratch_layers
from ..precompute.scratch.material import (BACKENDS, BASE_TYPES, LOBE_SHAPES, MODES, ScratchParams,  # noqa: F401
                                           fit_error, tables, validate)
from ..precompute.validation import check_range
from . import osl_compile, render_paths

#: EEVEE compiles every layer into one GLSL shader, and its compile time explodes with the shader's size
#: (software GL here, 48x32 px: 16 layers 1.8 s, 18 layers 198 s, 24 layers > 15 min; fig12d's 32 layers as 16
#: with its wood texture 73 s, as 8: 5.2 s).  Above this count EEVEE renders ``merged_layers``.
EEVEE_MAX_LAYERS = 8

def _check_uvs_for(obj_meshes) -> None:
    for mesh in obj_meshes:
        if not mesh.uv_layers:
            raise ValueError(f"mesh {mesh.name!r} has no UV map: scratch layers and directions follow the UVs "
                             "(add one with UV > Unwrap or Smart UV Project)")


def check_uvs(material: bpy.types.Material) -> None:
    """Raise ValueError if an object using ``material`` has a mesh without UVs."""
    users = [o.data for o in bpy.data.objects if o.type == "MESH" and material.name in [m.name for m in o.data.materials if m]]
    _check_uvs_for(users)


def _principled_conductor(nodes, fresnel):
    """A mirror conductor for Blender < 4.3: Principled metallic, F82-tint model (Cycles' principled
    metal: Base Color = F(0 deg), Specular Tint = F(82 deg) / Schlick(82 deg)), the closest built-in
    match to ``fresnel`` there; exact at normal incidence and at 82 deg."""
    f0 = np.broadcast_to(np.asarray(fresnel(np.array([1.0])), float).reshape(-1), (3,))
    f82 = np.broadcast_to(np.asarray(fresnel(np.array([1.0 / 7.0])), float).reshape(-1), (3,))
    schlick82 = f0 + (1.0 - f0) * (1.0 - 1.0 / 7.0) ** 5
    node = nodes.new("ShaderNodeBsdfPrincipled")
    node.inputs["Base Color"].default_value = (*np.clip(f0, 0.0, 1.0), 1.0)
    node.inputs["Metallic"].default_value = 1.0
    node.inputs["Roughness"].default_value = 0.0
    node.inputs["Specular Tint"].default_value = (*np.clip(f82 / np.maximum(schlick82, 1e-6), 0.0, 1.0), 1.0)
    return node


def _base_node(tree, params: ScratchParams):
    """The base material closure node (eq. 4's ρ_b), or None."""
    b = params.base
    kind = b["type"]
    n = tree.nodes
    if kind == "none":
        return None
    if kind == "mirror":
        f = params.fresnel
        if f is None:
            node = n.new("ShaderNodeBsdfGlossy")
            node.distribution = "GGX"
            node.inputs["Roughness"].default_value = 0.0
            node.inputs["Color"].default_value = (1, 1, 1, 1)
            return node
        if hasattr(f, "k") and not hasattr(bpy.types, "ShaderNodeBsdfMetallic"):
            return _principled_conductor(n, f)  # Blender < 4.3 has no Metallic BSDF node
        if hasattr(f, "k"):  # conductor (exact or Lazanyi): Cycles' own physical conductor
            node = n.new("ShaderNodeBsdfMetallic")
            node.fresnel_type = "PHYSICAL_CONDUCTOR"
            node.inputs["Roughness"].default_value = 0.0
            nn = [float(x) for x in (list(f.n) * 3)[:3]] if f.n.size == 1 else [float(x) for x in f.n]
            kk = [float(x) for x in (list(f.k) * 3)[:3]] if f.k.size == 1 else [float(x) for x in f.k]
            node.inputs["IOR"].default_value = nn
            node.inputs["Extinction"].default_value = kk
            return node
        node = n.new("ShaderNodeBsdfPrincipled")  # dielectric mirror: specular only
        node.inputs["Base Color"].default_value = (0, 0, 0, 1)
        node.inputs["Roughness"].default_value = 0.0
        f0 = float(f.f0.mean())
        node.inputs["IOR"].default_value = (1 + f0 ** 0.5) / max(1 - f0 ** 0.5, 1e-3)
        return node
    if kind == "diffuse":
        node = n.new("ShaderNodeBsdfDiffuse")
        node.inputs["Color"].default_value = b.get("color", (0.5, 0.5, 0.5, 1.0))
        return node
    if kind == "glossy":
        node = n.new("ShaderNodeBsdfGlossy")
        node.distribution = "MULTI_GGX"
        node.inputs["Color"].default_value = b.get("color", (0.9, 0.9, 0.9, 1.0))
        node.inputs["Roughness"].default_value = b.get("roughness", 0.1)
        return node
    node = n.new("ShaderNodeBsdfPrincipled")
    node.inputs["Base Color"].default_value = b.get("color", (0.8, 0.1, 0.1, 1.0))
    node.inputs["Roughness"].default_value = b.get("roughness", 0.3)
    if "metallic" in b:
        node.inputs["Metallic"].default_value = check_range("base metallic", b["metallic"], 0.0, 1.0)
    return node


def _wood_texture(tree, socket) -> None:
    """Procedural wood rings (Wave texture through a brown colour ramp) into ``socket``."""
    wave = tree.nodes.new("ShaderNodeTexWave")
    wave.wave_type, wave.bands_direction = "RINGS", "Z"
    wave.inputs["Scale"].default_value = 2.0
    wave.inputs["Distortion"].default_value = 6.0
    wave.inputs["Detail"].default_value = 3.0
    wave.location = (-400, -450)
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.location = (-150, -450)
    ramp.color_ramp.elements[0].color = (0.20, 0.08, 0.03, 1)
    ramp.color_ramp.elements[1].color = (0.45, 0.22, 0.08, 1)
    tree.links.new(wave.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], socket)


def _jsonable(v):
    return v.tolist() if hasattr(v, "tolist") else float(v)


def build(material: bpy.types.Material, params: ScratchParams, progress=None, **spec_options) -> bpy.types.Material:
    """(Re)build ``material``'s node tree for ``params``; ``progress(fraction)`` is called along the way.

    Backend "svm": node groups only.  Backend "osl": the OSL script for Cycles with OSL on the CPU
    plus its SVM twin for Cycles SVM (the default, GPU) and EEVEE, chosen by ``render_paths``.  EEVEE
    gets a lighter twin above ``EEVEE_MAX_LAYERS`` layers (``precompute.scratch.layers.merged_layers``:
    the same scratched fraction in fewer layers), because it compiles every layer into one shader."""
    step = progress or (lambda _f: None)
    step(0.05)
    tab = tables(params)
    brdf, lobe_data, svm_lobes = tab["brdf"], tab["lobes"], tab["svm_lobes"]
    step(0.7)
    src = None
    if params.backend != "svm":
        src = scratch_svbrdf.source(params, brdf, lobe_data, voronoi_int2=bpy.app.version >= (5, 0, 0), **spec_options)
    step(0.8)
    tree = material.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (900, 0)
    base = _base_node(tree, params)
    if base is not None:
        base.location = (-200, -250)
    surfaces = {"svm": _build_svm(tree, material, params, svm_lobes, base), "osl": None, "eevee": None}
    if params.layers is not None and params.layers.n_layers > EEVEE_MAX_LAYERS:
        preview = dataclasses.replace(params, layers=scratch_layers.merged_layers(params.layers, EEVEE_MAX_LAYERS))
        surfaces["eevee"] = _build_svm(tree, material, preview, svm_lobes, base,
                                       f"EEVEE preview ({EEVEE_MAX_LAYERS} merged layers)", offset=(-1400, -2600))
    if src is not None:
        script = osl_compile.script_node_from_source(tree, f"{material.name}.scratch.osl", src)
        script.location = (200, 300)
        uv = tree.nodes.new("ShaderNodeUVMap")
        uv.location = (-200, 400)
        tangent = tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tangent.location = (-200, 250)
        if "UV" in script.inputs:
            tree.links.new(uv.outputs["UV"], script.inputs["UV"])
        tree.links.new(tangent.outputs["Tangent"], script.inputs["Tangent"])
        tint = script.inputs["Tint"]
        tint.default_value = (*params.tint, 1.0) if len(tint.default_value) == 4 else params.tint
        if base is not None and "Base" in script.inputs:
            tree.links.new(base.outputs[0], script.inputs["Base"])
        surfaces["osl"] = script.outputs["BSDF"]
    return _finish(material, tree, out, surfaces, params, lobe_data, step)


def _build_svm(tree, material, params: ScratchParams, lobe_data, base, label="SVM path (Cycles SVM / GPU, EEVEE)",
               offset=(-1400, -600)) -> bpy.types.NodeSocket:
    """A node-group (SVM) path, framed: see ``node_groups/scratch_svm.py`` for how it differs from OSL."""
    layers = params.layers
    theta_k, xi_k = scratch_layers.layer_transforms(layers) if layers is not None else (None, None)
    before = set(tree.nodes)
    surface = scratch_svm.build(tree, lobe_data, layers, theta_k, xi_k, tint=params.tint,
                                base_socket=None if base is None else base.outputs[0], name=material.name)
    frame = tree.nodes.new("NodeFrame")
    frame.label = label
    for node in set(tree.nodes) - before - {frame}:
        node.location = (node.location[0] + offset[0], node.location[1] + offset[1])
        node.parent = frame
    return surface


def _finish(material, tree, out, surfaces: dict, params: ScratchParams, lobe_data, step) -> bpy.types.Material:
    """Diffuse term, output links (render paths), material flags and the stored parameters."""
    if params.diffuse is not None:  # a Lambertian term common to scratches and base (Fig. 12c, d)
        diff = tree.nodes.new("ShaderNodeBsdfDiffuse")
        diff.location = (400, -300)
        if params.diffuse == "wood":
            _wood_texture(tree, diff.inputs["Color"])
        else:
            diff.inputs["Color"].default_value = (*params.diffuse, 1.0)

        def with_diffuse(surface, y):
            add = tree.nodes.new("ShaderNodeAddShader")
            add.location = (600, y)
            tree.links.new(surface, add.inputs[0])
            tree.links.new(diff.outputs["BSDF"], add.inputs[1])
            return add.outputs["Shader"]

        surfaces = {k: None if s is None else with_diffuse(s, y)
                    for (k, s), y in zip(surfaces.items(), (-150, 150, -450))}
    render_paths.link_surface(tree, surfaces["svm"], surfaces["osl"], out, eevee_socket=surfaces["eevee"])
    material.cycles.use_bump_map_correction = False  # it rotates tilted lobe normals back toward Ng
    material["scratch_addon_kind"] = "scratch_svbrdf"
    if lobe_data is not None:
        material["scratch_addon_fit_error"] = fit_error(lobe_data)
    material["scratch_addon_params"] = json.dumps({
        "profile": params.profile.cache_key(), "fresnel": None if params.fresnel is None else params.fresnel.cache_key(),
        "layers": None if params.layers is None else params.layers.cache_key(), "lobes": params.lobes,
        "base": {k: list(v) if isinstance(v, tuple) else v for k, v in params.base.items()}, "mode": params.mode,
        "resolution": params.resolution, "slices": params.slices, "tint": list(params.tint),
        "diffuse": params.diffuse, "backend": params.backend, "lobe_shape": params.lobe_shape}, default=_jsonable)
    step(1.0)
    return material
