"""Build the scratch SV-BRDF material (Raymond et al. 2016) in a Cycles node tree.

Pipeline: ``precompute.scratch.material.validate`` (parameters) -> ``tables`` (ρ0, ρm, γ from
``precompute.scratch.brdf.simulate``; lobe data from ``precompute.scratch.lobes``; all cached by
content hash) -> ``osl.scratch_svbrdf`` (specialised OSL source, tables compiled in) -> INTERNAL
script node with UV Map and Tangent nodes, inside a node group shared by every material with the same source
(``shader_group``: its bytecode is stored once), the base closure linked to its ``Base`` input, plus
its node-group twin (``node_groups.scratch_svm``) for Cycles SVM, GPU and EEVEE (``render_paths``).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json

import bpy
import numpy as np

from ..node_groups import scratch_controls, scratch_svm
from ..precompute.cycles.glossy import glossy_node_params
from ..osl import scratch_svbrdf
from ..precompute.scratch import layers as scratch_layers
from ..precompute.scratch.material import (BACKENDS, BASE_TYPES, LOBE_SHAPES, MODES, ScratchParams,  # noqa: F401
                                           fit_error, has_preview, tables, tables_cached, validate)
from ..precompute.validation import check_range
from . import osl_compile, render_paths, transaction

#: EEVEE compiles every layer into one GLSL shader, and its compile time explodes with the shader's size
#: (software GL here, 48x32 px: 16 layers 1.8 s, 18 layers 198 s, 24 layers > 15 min; fig12d's 32 layers as 16
#: with its wood texture 73 s, as 8: 5.2 s).  Above this count EEVEE renders ``merged_layers``.
EEVEE_MAX_LAYERS = 8
#: Build the "Scratch Controls" node (live, animatable sockets; ``live``).  False: the values are compiled in
#: as constants, as before issue 18 (bench/live_update.py --cost compares the two).
LIVE_CONTROLS = True

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
    """The base material closure node (eq. 4's ρ_b, named ``scratch_controls.BASE_NODE_NAME``), or None."""
    node = _base_node_unnamed(tree, params)
    if node is not None:
        node.name = node.label = scratch_controls.BASE_NODE_NAME
    return node


def _base_node_unnamed(tree, params: ScratchParams):
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


def shader_source(params: ScratchParams, brdf, lobe_data, **spec_options) -> str:
    """The specialised OSL source of the scratch SV-BRDF (``osl.scratch_svbrdf.source``) for this Blender."""
    return scratch_svbrdf.source(params, brdf, lobe_data, voronoi_int2=bpy.app.version >= (5, 0, 0), **spec_options)


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
        src = shader_source(params, brdf, lobe_data, **spec_options)
    step(0.8)
    with transaction.rebuild(material):  # the old nodes stay until the new tree is complete (compiled)
        _build_tree(material, material.node_tree, params, src, lobe_data, svm_lobes, step,
                    cost_off=int(spec_options.get("cost_off", 0)))
    if spec_options:  # a non-default specialisation: live edits rebuild it rather than update it in place
        material[STRUCTURE_KEY] = "specialised " + repr(sorted(spec_options))
    return material


def _build_tree(material, tree, params: ScratchParams, src, lobe_data, svm_lobes, step,
                cost_off: int = 0) -> bpy.types.Material:
    """The node tree of ``build`` (added to ``tree``; ``transaction.rebuild`` removes the old nodes)."""
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (900, 0)
    base = _base_node(tree, params)
    if base is not None:
        base.location = (-200, -250)
    live = {}
    if LIVE_CONTROLS:
        controls = scratch_controls.add_node(tree, _control_values(params))
        live = {s.prop: controls.outputs[s.inputs[0]] for s in scratch_controls.CONTROLS}
    surfaces = {"svm": _build_svm(tree, material, params, svm_lobes, base, cost_off=cost_off, controls=live),
                "osl": None, "eevee": None}
    if params.layers is not None and params.layers.n_layers > EEVEE_MAX_LAYERS:
        preview = dataclasses.replace(params, layers=scratch_layers.merged_layers(params.layers, EEVEE_MAX_LAYERS))
        preview_live = dict(live, density=_merged_density(tree, live["density"], params.layers)) if live else {}
        surfaces["eevee"] = _build_svm(tree, material, preview, svm_lobes, base,
                                       f"EEVEE preview ({EEVEE_MAX_LAYERS} merged layers)", offset=(-1400, -2600),
                                       controls=preview_live, twin="eevee")
    elif scratch_svm.races(svm_lobes, params.layers):   # the Cycles twin is a layer race: EEVEE gets its own
        surfaces["eevee"] = _build_svm(tree, material, params, svm_lobes, base, "EEVEE (all layers at once)",
                                       offset=(-1400, -2600), controls=live, twin="eevee")
    if src is not None:
        # one Text per distinct shader: materials that differ only by socket values (tint, base, layer size
        # and density) share it
        # and its compiled script node (bytecode): one shared node group per text (shader_group)
        script = tree.nodes.new("ShaderNodeGroup")
        script.node_tree = shader_group(src)
        script.name = script.label = SCRIPT_NODE_NAME
        script.location = (200, 300)
        values = _control_values(params)
        for sock in scratch_controls.CONTROLS:  # one socket drives the OSL input and the twins' math
            if sock.osl and sock.osl in script.inputs and sock.prop in values:
                scratch_controls.set_value(script.inputs[sock.osl], values[sock.prop])
                if live:
                    tree.links.new(live[sock.prop], script.inputs[sock.osl])
        if base is not None and "Base" in script.inputs:
            tree.links.new(base.outputs[0], script.inputs["Base"])
        surfaces["osl"] = script.outputs["BSDF"]
    return _finish(material, tree, out, surfaces, params, lobe_data, step)


def _control_values(params: ScratchParams) -> dict:
    """Values of the "Scratch Controls" inputs (``node_groups.scratch_controls.CONTROLS``) for ``params``."""
    lp = params.layers
    values = {"tint": tuple(params.tint)}
    if lp is not None:
        values.update(length=lp.length, width=lp.width, density=lp.density)
    return values


def _merged_density(tree, density, layers):
    """``density`` mapped to the EEVEE preview's merged-layer density (``merged_layers``: the same scratched
    fraction in ``EEVEE_MAX_LAYERS`` layers) by a Float Curve sampled from that function, so the preview
    follows the live, animatable density too (curve error < 0.01 in d)."""
    node = tree.nodes.new("ShaderNodeFloatCurve")
    node.label = f"Density for {EEVEE_MAX_LAYERS} merged layers"
    node.location = (-500, 500)
    curve = node.mapping.curves[0]
    xs = np.linspace(0.0, 1.0, 21)
    ys = [scratch_layers.merged_layers(dataclasses.replace(layers, density=float(x)), EEVEE_MAX_LAYERS).density
          for x in xs]
    pts = curve.points
    pts[0].location, pts[-1].location = (0.0, ys[0]), (1.0, ys[-1])
    for x, y in zip(xs[1:-1], ys[1:-1]):
        pts.new(float(x), float(y))
    node.mapping.clip_min_y, node.mapping.clip_max_y = 0.0, 1.0
    node.mapping.update()
    tree.links.new(density, node.inputs["Value"])
    return node.outputs["Value"]


def _build_svm(tree, material, params: ScratchParams, lobe_data, base, label="SVM path (Cycles SVM / GPU, EEVEE)",
               offset=(-1400, -600), cost_off: int = 0, controls=None, twin="svm") -> bpy.types.NodeSocket:
    """A node-group (SVM) path, framed: see ``node_groups/scratch_svm.py`` for how it differs from OSL."""
    layers = params.layers
    theta_k, xi_k = scratch_layers.layer_transforms(layers) if layers is not None else (None, None)
    before = set(tree.nodes)
    surface = scratch_svm.build(tree, lobe_data, layers, theta_k, xi_k, tint=params.tint,
                                base_socket=None if base is None else base.outputs[0], name=material.name,
                                cost_off=cost_off, controls=controls, twin=twin)
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
        diff.name = diff.label = scratch_controls.DIFFUSE_NODE_NAME
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
    _store_params(material, params, lobe_data)
    step(1.0)
    return material


def _store_params(material, params: ScratchParams, lobe_data) -> None:
    """The material's record of what it was built from (custom properties)."""
    material["scratch_addon_kind"] = "scratch_svbrdf"
    material.pop(PREVIEW_KEY, None)
    if lobe_data is not None:
        material["scratch_addon_fit_error"] = fit_error(lobe_data)
    material[TABLE_KEY], material[STRUCTURE_KEY] = live_keys(params, material.name)
    material["scratch_addon_params"] = json.dumps({
        "profile": params.profile.cache_key(), "fresnel": None if params.fresnel is None else params.fresnel.cache_key(),
        "layers": None if params.layers is None else params.layers.cache_key(), "lobes": params.lobes,
        "base": {k: list(v) if isinstance(v, tuple) else v for k, v in params.base.items()}, "mode": params.mode,
        "resolution": params.resolution, "slices": params.slices, "tint": list(params.tint),
        "diffuse": params.diffuse, "backend": params.backend, "lobe_shape": params.lobe_shape}, default=_jsonable)


# --- live updates (scratch_addon.live) ----------------------------------------------------------------
#: Material custom properties: what the tables / the node-tree structure were built from.
TABLE_KEY = "scratch_live_table_key"
#: set while the material shows a live edit's preview tables (the full ones are on their way)
PREVIEW_KEY = "scratch_live_preview"
STRUCTURE_KEY = "scratch_live_structure_key"


def live_keys(params: ScratchParams, name: str) -> tuple[str, str]:
    """(table key, structure key) of ``params``: the table key changes with every setting that is not a live
    socket (``node_groups.scratch_controls.SOCKETS``), the structure key only with those that change the node
    graph (a change of the table key alone is applied in place by ``apply_tables``)."""
    base = {k: v for k, v in params.base.items() if k not in ("color", "roughness")}
    f = params.fresnel
    lp = params.layers
    layers = None if lp is None else [lp.n_layers, float(lp.theta_deg), int(lp.seed)]
    diffuse = None if params.diffuse is None else ("wood" if params.diffuse == "wood" else "color")
    common = dict(layers=layers, base=base, mode=params.mode, resolution=params.resolution, slices=params.slices,
                  diffuse=diffuse, backend=params.backend, lobe_shape=params.lobe_shape)
    table = json.dumps(dict(common, profile=params.profile.cache_key(), lobes=params.lobes,
                            fresnel=None if f is None else f.cache_key()), sort_keys=True, default=_jsonable)
    kind = None if f is None else ("conductor" if hasattr(f, "k") else "dielectric")
    in_place = params.mode == "lobes" and params.lobe_shape == "table"
    if in_place and lp is not None:
        common["layers"] = [lp.n_layers]   # rotations / offsets: constants rewritten in place (set_layer_constants)
    structure = json.dumps(dict(common, fresnel=kind, name=name, lobes=None if in_place else params.lobes,
                                profile=None if in_place else params.profile.cache_key()),
                           sort_keys=True, default=_jsonable)
    return table, structure


SCRIPT_NODE_NAME = "Scratch Shader"
#: compiled OSL bytecode by source hash (a table edit undone or dragged back compiles no second time)
_BYTECODE: dict = {}


def _source_key(src: str) -> str:
    import hashlib

    return hashlib.sha1(src.encode()).hexdigest()


def _remember_bytecode(src: str, node) -> None:
    if len(_BYTECODE) > 64:
        _BYTECODE.pop(next(iter(_BYTECODE)))
    _BYTECODE[_source_key(src)] = (node.bytecode, node.bytecode_hash)


def shader_text_name(src: str) -> str:
    """Name of the Text holding ``src``: by content hash, so materials with the same shader share one Text."""
    return f"scratch_svbrdf.{hashlib.sha1(src.encode()).hexdigest()[:12]}.osl"


#: name prefix of the shared node groups holding one compiled scratch shader (``shader_group``)
SHADER_GROUP_PREFIX = "Scratch OSL "


def shader_group_name(src: str) -> str:
    """Name of the node group holding ``src``'s script node (the content hash of ``shader_text_name``)."""
    return SHADER_GROUP_PREFIX + hashlib.sha1(src.encode()).hexdigest()[:12]


#: names of the shader groups built or found in this session (``prepare`` compiles no shader it knows in the background)
_GROUPS_SEEN: set = set()


def shader_group(src: str) -> bpy.types.ShaderNodeTree:
    """The node group of the OSL source ``src``, shared by every material with this shader (issue 15 item 5).

    A script node stores its compiled bytecode (~1 MB for a scratch shader: the tables are constants in it) and a
    .blend held one copy per material; inside one group per distinct source it is stored once.  The group holds
    the UV Map and UV Tangent nodes (they make Cycles export the attributes) and the script node; its inputs are
    the script's other inputs (Base, Length, Width, Density, Tint: the per-material values), its outputs BSDF and
    Alpha.  Cycles flattens groups when it syncs: each material still compiles its own OSL shader group.
    Compiled on creation (``osl_compile.OSLCompileError`` on failure, nothing left behind)."""
    from ..node_groups import add_socket

    name = shader_group_name(src)
    group = bpy.data.node_groups.get(name)
    if group is not None and any(n.bl_idname == "ShaderNodeScript" and n.bytecode for n in group.nodes):
        _GROUPS_SEEN.add(name)
        return group
    if group is not None:   # an incomplete group of that name: build it again
        bpy.data.node_groups.remove(group)
    text_name = shader_text_name(src)
    text_existed = bpy.data.texts.get(text_name) is not None
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    try:
        script = osl_compile.uv_script_node(group, text_name, src)   # + UV Map and UV Tangent -> Tangent
    except BaseException:
        bpy.data.node_groups.remove(group)
        text = bpy.data.texts.get(text_name)
        if text is not None and not text_existed and text.users == 0:
            bpy.data.texts.remove(text)
        raise
    script.name = script.label = SCRIPT_NODE_NAME
    if "UV" in script.inputs:
        uv = next(n for n in group.nodes if n.bl_idname == "ShaderNodeUVMap")
        group.links.new(uv.outputs["UV"], script.inputs["UV"])
    gin = group.nodes.new("NodeGroupInput")
    gin.location = (-600, -200)
    gout = group.nodes.new("NodeGroupOutput")
    gout.location = (450, 0)
    kinds = {"SHADER": "NodeSocketShader", "RGBA": "NodeSocketColor", "VALUE": "NodeSocketFloat",
             "VECTOR": "NodeSocketVector", "INT": "NodeSocketInt"}
    for sock in script.inputs:
        if sock.name in ("UV", "Tangent"):
            continue
        item = add_socket(group, sock.name, "INPUT", kinds.get(sock.type, "NodeSocketFloat"))
        if hasattr(sock, "default_value") and hasattr(item, "default_value"):
            value = sock.default_value
            item.default_value = value if isinstance(value, (int, float)) else tuple(value)
        group.links.new(gin.outputs[sock.name], sock)
    for sock in script.outputs:
        add_socket(group, sock.name, "OUTPUT", kinds.get(sock.type, "NodeSocketFloat"))
        group.links.new(sock, gout.inputs[sock.name])
    _GROUPS_SEEN.add(name)
    return group


def script_node(material):
    """The compiled ``ShaderNodeScript`` of a scratch material (inside its shared ``shader_group``; a material
    built before the shared groups holds it directly), or None."""
    node = scratch_script(material)
    if node is None or node.bl_idname == "ShaderNodeScript":
        return node
    return next((n for n in node.node_tree.nodes if n.bl_idname == "ShaderNodeScript"), None)


def _set_source(node, src: str) -> None:
    """Point the INTERNAL script of ``node`` at the (shared) Text of ``src`` and compile it (bytecode reused for
    a source seen before); a Text other materials use is never rewritten.  On a compile error the node keeps
    its text and bytecode.  A group node (``shader_group``) is repointed at the group of ``src`` instead."""
    if node.bl_idname == "ShaderNodeGroup":
        node.node_tree = shader_group(src)
        return
    key = _source_key(src)
    old = (node.script, node.bytecode, node.bytecode_hash)
    name = shader_text_name(src)
    text = bpy.data.texts.get(name)
    created = text is None
    if created:
        text = bpy.data.texts.new(name)
        text.write(src)
    node.script = text
    hit = _BYTECODE.get(key)
    if hit is not None:
        node.bytecode, node.bytecode_hash = hit
        return
    try:
        osl_compile.compile_script_node(node)
    except BaseException:
        node.script = old[0]
        node.bytecode, node.bytecode_hash = old[1], old[2]
        if created:
            bpy.data.texts.remove(text)
        raise
    _remember_bytecode(src, node)


#: table images with one row per φo node (their row count follows the adaptive node count S in place)
_ROW_IMAGES = tuple(scratch_svm.TABLE_IMAGE_PREFIX + k for k in ("A", "C", "Y"))


def _layer_transforms_change(material, lp) -> bool:
    """True unless ``material`` was built / updated with the same layer rotations and offsets as ``lp`` (they
    depend on the layer count, the spread Θ and the seed only: ``layers.layer_transforms``)."""
    try:
        old = json.loads(material["scratch_addon_params"])["layers"]
        return any(old[k] != v for k, v in lp.cache_key().items() if k in ("n_layers", "theta_deg", "seed"))
    except (KeyError, TypeError, ValueError):
        return True


def _prefix(img) -> str:
    return img.name.rsplit(" ", 1)[0]


class NeedsRebuild(Exception):
    """``apply_tables`` cannot update this material in place (its node tree has another structure)."""


def scratch_script(material):
    """The scratch shader's node in ``material`` (the group node of its ``shader_group``; the script node itself
    in a material built before the shared groups) or None."""
    def ours(n):
        if n is not None and n.bl_idname == "ShaderNodeGroup":
            return n.node_tree is not None and n.node_tree.name.startswith(SHADER_GROUP_PREFIX)
        return (n is not None and n.bl_idname == "ShaderNodeScript" and n.script is not None
                and n.script.name.startswith("scratch_svbrdf."))
    node = material.node_tree.nodes.get(SCRIPT_NODE_NAME)
    if ours(node):
        return node
    return next((n for n in material.node_tree.nodes if ours(n)), None)


def prepare(params: ScratchParams, quality: str = "full") -> dict:
    """Everything ``build`` / ``apply_tables`` compute before touching a material (no bpy datablocks: runs in a
    worker thread): the tables (cached) and the OSL source.  ``quality`` "preview": the quick tables a live
    edit shows first (``precompute.scratch.lobes.table_lobes``); ``apply_tables`` marks the material
    (``PREVIEW_KEY``) until the full ones replace them."""
    tab = tables(params, quality)
    src = None
    if params.backend != "svm":
        lp = params.layers
        lobes = tab["lobes"]
        ident = [np.ascontiguousarray(lobes[k]).tobytes() for k in ("cdf", "w_m", "w_0") if lobes.get(k) is not None] \
            if isinstance(lobes, dict) and "cdf" in lobes else None
        import hashlib

        key = None if ident is None else (live_keys(params, "")[0], None if lp is None else (lp.length, lp.width,
                                          lp.density), hashlib.sha1(b"".join(ident)).hexdigest())
        src = _SOURCES.get(key) if key is not None else None
        if src is None:
            src = shader_source(params, tab["brdf"], tab["lobes"])
            if key is not None:   # the same tables (a cache miss gives float64, a hit float32: other text)
                if len(_SOURCES) > 32:
                    _SOURCES.pop(next(iter(_SOURCES)))
                _SOURCES[key] = src
        if shader_group_name(src) not in _GROUPS_SEEN:   # a new shader: compile it in the background now, beside
            osl_compile.precompile(src)                  # the table images' update (issue 18)
    return dict(tab, src=src, quality=quality)


def _own_race_groups(tree) -> list:
    """Point ``tree``'s race positions (``scratch_svm.race_group``) at a fresh copy of their group before an
    in-place update edits it: a copied material shares the group, and a failed update must leave the old
    group as it was (``transaction`` restores the group nodes' pointers and removes the copy; on success it
    drops the old group when nothing uses it).  Returns [(copy, the old group's name)]."""
    copies = {}
    for node in tree.nodes:
        grp = node.node_tree if node.bl_idname == "ShaderNodeGroup" else None
        if grp is not None and grp.get(scratch_svm.RACE_GROUP):
            if grp.as_pointer() not in copies:
                copies[grp.as_pointer()] = (grp.copy(), grp.name)
            node.node_tree = copies[grp.as_pointer()][0]
    return list(copies.values())


#: generated OSL sources by settings (a value dragged back generates no second time)
_SOURCES: dict = {}


def _set_default(socket, value) -> None:
    """``socket.default_value = value`` unless it holds that value already (as float32): every RNA write
    updates the whole node tree (about 7 ms on a 32-layer material of 1800 nodes)."""
    old = socket.default_value
    if isinstance(old, float):
        same = old == float(np.float32(value))
    elif hasattr(old, "__len__") and not isinstance(old, str):
        same = len(old) == len(value) and all(a == float(np.float32(b)) for a, b in zip(old, value))
    else:
        same = old == value
    if not same:
        socket.default_value = value


def _repoint_images(tree, table_nodes, new: dict) -> None:
    """Point ``table_nodes`` at the ``new`` table images (by kind, the name without its content hash).  An old
    image only these nodes use is swapped by one ID remap (``Image.user_remap``) and one tree update: assigning
    ``node.image`` updates the whole tree per node (132 table nodes of a 32-layer material: 0.9 s CPU, 0.03 s
    remapped).  An image another datablock also uses (tables another material shares) keeps its other users:
    these nodes are repointed one by one."""
    by_old: dict = {}
    for node in table_nodes:
        by_old.setdefault(node.image.as_pointer(), (node.image, []))[1].append(node)
    remapped = False
    for old, nodes in by_old.values():
        img = new[old.name.rsplit(" ", 1)[0]]
        if img == old:
            continue
        if old.users == len(nodes) and not old.use_fake_user:
            old.user_remap(img)
            remapped = True
        else:
            for node in nodes:
                node.image = img
    if remapped:
        tree.update_tag()


def apply_tables(material, params: ScratchParams, prepared: dict | None = None) -> bpy.types.Material:
    """Update ``material`` in place to ``params`` whose node-graph structure equals the built one
    (``live_keys``): new tables into its table images, the new OSL source compiled into its script node,
    the table lobe's roughness and the base closure's Fresnel inputs; no node is created.  Raises
    ``NeedsRebuild`` (material untouched) when the structure differs; any failure leaves it as it was."""
    if material.get(STRUCTURE_KEY) != live_keys(params, material.name)[1]:
        raise NeedsRebuild("the node-graph structure changes")
    prepared = prepared or prepare(params)
    svm_lobes = prepared["svm_lobes"]
    if "cdf" not in svm_lobes:
        raise NeedsRebuild("fitted lobes")
    tree = material.node_tree
    script = scratch_script(material)
    if (prepared["src"] is None) != (script is None):
        raise NeedsRebuild("the OSL script node is missing")
    table_nodes = [n for n in scratch_svm.tree_nodes(tree) if n.bl_idname == "ShaderNodeTexImage"
                   and n.image is not None and n.image.name.startswith(scratch_svm.TABLE_IMAGE_PREFIX)]
    if not table_nodes:
        raise NeedsRebuild("no table images")
    with transaction.rebuild(material, replace=False):
        race_groups = _own_race_groups(tree)
        table_nodes = [n for n in scratch_svm.tree_nodes(tree) if n.bl_idname == "ShaderNodeTexImage"
                       and n.image is not None and n.image.name.startswith(scratch_svm.TABLE_IMAGE_PREFIX)]
        base_old = tree.nodes.get(scratch_controls.BASE_NODE_NAME)
        base_new = _base_node_unnamed(tree, params)
        try:
            if (base_old is None) != (base_new is None) or (base_new is not None and
                                                            base_new.bl_idname != base_old.bl_idname):
                raise NeedsRebuild("the base closure changes type")
            if base_new is not None:
                live = ("Color", "Base Color", "Roughness") if params.base["type"] != "mirror" else ()
                for new_in, old_in in zip(base_new.inputs, base_old.inputs):
                    if hasattr(new_in, "default_value") and new_in.name not in live:
                        _set_default(old_in, new_in.default_value)   # a base's colour, roughness: live sockets
        finally:
            if base_new is not None:
                tree.nodes.remove(base_new)
        # new (content-hashed, shared) images; the nodes are repointed, no image another material uses is rewritten
        preview = prepared.get("quality") == "preview"
        new = {img.name.rsplit(" ", 1)[0]: img for img in scratch_svm.table_images(material.name, svm_lobes).values()}
        rows = [n for n in scratch_svm.tree_nodes(tree) if n.get(scratch_svm.TABLE_ROWS)]
        for node in table_nodes:
            img = new.get(node.image.name.rsplit(" ", 1)[0])
            if img is None or img.size[0] != node.image.size[0]:
                raise NeedsRebuild("the table images change width")
            if img.size[1] != node.image.size[1] and (not rows or _prefix(img) not in _ROW_IMAGES):
                raise NeedsRebuild("the table images change height")
        _repoint_images(tree, table_nodes, new)
        S = int(np.asarray(svm_lobes["cdf"]).shape[0])   # adaptive φo nodes: rows of the A, C, Y images
        for node in rows:   # row = up / S + row_k: row_k ((k + 0.5) / S) comes from the N image
            _set_default(node.inputs[1], 1.0 / S)
        ax = float(svm_lobes["alpha_x"])
        rough, aniso = glossy_node_params(ax, min(max(float(svm_lobes["alpha_y"]), ax), 1.0))
        for node in scratch_svm.tree_nodes(tree):
            if node.get(scratch_svm.TABLE_GLOSSY):
                _set_default(node.inputs["Roughness"], float(rough))
                _set_default(node.inputs["Anisotropy"], float(aniso))
        lp = params.layers
        if lp is not None and _layer_transforms_change(material, lp):
            theta_k, xi_k = scratch_layers.layer_transforms(lp)
            scratch_svm.set_layer_constants(tree, theta_k, xi_k, "svm")
            if lp.n_layers > EEVEE_MAX_LAYERS:
                merged = scratch_layers.merged_layers(lp, EEVEE_MAX_LAYERS)
                scratch_svm.set_layer_constants(tree, *scratch_layers.layer_transforms(merged), "eevee")
            else:   # the EEVEE twin of a layer race (a no-op without one)
                scratch_svm.set_layer_constants(tree, theta_k, xi_k, "eevee")
        if script is not None:   # last: its compile (``prepare`` started it) ran beside the image updates
            _set_source(script, prepared["src"])
        _store_params(material, params, prepared["lobes"])
        if preview:
            material[PREVIEW_KEY] = 1
    for copy, name in race_groups:   # the old group is gone unless another material uses it: take its name back
        if name not in bpy.data.node_groups:
            copy.name = name
    return material
