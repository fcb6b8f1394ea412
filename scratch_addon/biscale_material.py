"""Bi-scale materials in Blender (Wu et al. 2011): tile mesh -> effective BRDF -> Cycles material.

* ``tile_from_object``: the evaluated mesh of an object as a periodic tile (object space; the
  footprint is the x/y bounding square of the mesh, moved to [0, P]^2).
* ``small_scale_material``: a material slot -> small-scale BRDF dict (``precompute.biscale.brdfs``):

  - a *Diffuse BSDF* feeding the output -> ``lambert`` with albedo = its Color;
  - a *Principled BSDF* -> ``principled`` (Cycles' own closures: F82-tint metal, dielectric specular with the real
    Fresnel curve, Lambert base under the specular's albedo, Multiscatter GGX as the node's distribution says) when
    its coat, sheen, transmission, subsurface, thin film, diffuse roughness and anisotropy are 0, alpha 1 and the
    inputs it reads unlinked; otherwise the approximate ``cook_torrance`` (GGX, alpha = Roughness², Schlick F0 =
    Base Color for Metallic = 1 and 0.08·Specular IOR Level for dielectrics, mixed by Metallic, kd = Base
    Color·(1 - Metallic)) — the old mapping, 4-17 % off at a default node;
  - a *Glossy BSDF* -> ``cook_torrance`` (alpha = Roughness², no diffuse) with Cycles' colour and distribution:
    the Glossy BSDF has no Fresnel, its Color c scales the lobe at every angle (``fresnel="none"``, ks = max(c),
    F0 = c / max(c)); Multiscatter GGX (the node's default) -> ``multiscatter=True`` (Cycles' energy
    preservation: up to +15 % at Roughness 0.5, +68 % at 0.8 over single-scatter GGX), GGX -> ``ggx``, Beckmann ->
    ``beckmann_smith`` (Cycles' own G), Ashikhmin-Shirley -> GGX of the same alpha (no twin);
  - Diffuse and Glossy BSDFs summed by *Add Shader* / blended by *Mix Shader* nodes (constant Fac; one Glossy
    roughness and distribution) -> ``cook_torrance`` with kd = the weighted Diffuse colours, the Glossy colours
    summed as above (with several Glossy colours and Multiscatter GGX, Fms is taken of the summed colour);
  - anything else (or no node tree) -> ``lambert`` with the viewport diffuse colour.
* ``make_biscale_material``: ``mode="table"`` (what ``bake`` makes by default): the table itself as
  a tabulated-BRDF closure (``osl/tabulated_brdf.osl``, one narrow GGX closure per sample, light
  sampling kept; ``scratch_addon.tabulated_material``), the fitted closures as its SVM/EEVEE twin;
  ``mode="fit"``: the fitted closure mixture (``precompute.biscale.fit``)
  as SVM nodes (Diffuse BSDF + "Scratch: Bi-scale Lobe" groups, tangent from the UV map): works on
  GPU; ``mode="reference"``: the exact table importance-sampled through ``ray_portal_bsdf`` in an
  OSL script node (``osl.biscale_reference``; OSL backend, validation renders).
* ``bake``: the whole pipeline with an in-memory cache of ``BiscaleTile`` keyed by the mesh's
  content hash, so colour-only / material-only edits reuse visibility and N (fast path).
"""
from __future__ import annotations

import bpy
import numpy as np

from ..node_groups import biscale as biscale_groups
from ..osl import biscale_reference
from ..precompute.biscale import fit as fitmod
from ..precompute.cycles import principled as cycles_principled
from ..precompute.biscale import table as biscale_table
from ..precompute.biscale.bake import bake_tables, check_inputs, get_tile, mesh_hash, table_dir  # noqa: F401 - re-exports
from . import osl_compile, render_paths, tabulated_material, transaction
from .keywords import checked
from .materials import new_material


def tile_from_object(obj, depsgraph=None):
    """(vertices (V, 3), faces (F, 3), face_material (F,), period) of ``obj``'s evaluated mesh.

    Raises ValueError for non-mesh objects, empty meshes and non-square footprints."""
    if obj is None or obj.type != "MESH":
        raise ValueError(f"tile object: expected a mesh object, got {getattr(obj, 'type', None)!r}")
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        mesh.calc_loop_triangles()
        nv, nt = len(mesh.vertices), len(mesh.loop_triangles)
        if nv < 3 or nt == 0:
            raise ValueError(f"tile object {obj.name!r}: the mesh has no faces")
        V = np.empty(nv * 3, np.float64)
        mesh.vertices.foreach_get("co", V)
        F = np.empty(nt * 3, np.int64)
        mesh.loop_triangles.foreach_get("vertices", F)
        M = np.empty(nt, np.int64)
        mesh.loop_triangles.foreach_get("material_index", M)
    finally:
        ev.to_mesh_clear()
    V, F = V.reshape(-1, 3), F.reshape(-1, 3)
    lo, hi = V[:, :2].min(0), V[:, :2].max(0)
    ext = hi - lo
    P = float(ext.max())
    if P <= 0 or abs(ext[0] - ext[1]) > 1e-4 * P:
        raise ValueError(f"tile object {obj.name!r}: the x/y footprint must be a square (got {ext[0]:.6g} x "
                         f"{ext[1]:.6g}); the tile is not tileable")
    V = V - np.array([lo[0], lo[1], 0.0])
    return V, F, M, P


def _output_shader_node(mat):
    tree = getattr(mat, "node_tree", None)
    if tree is None:
        return None
    out = next((nd for nd in tree.nodes if nd.bl_idname == "ShaderNodeOutputMaterial" and nd.is_active_output), None)
    out = out or next((nd for nd in tree.nodes if nd.bl_idname == "ShaderNodeOutputMaterial"), None)
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    return out.inputs["Surface"].links[0].from_node


def _val(node, name, default):
    s = node.inputs.get(name)
    return default if s is None else s.default_value


def small_scale_material(mat) -> dict:
    """Small-scale BRDF dict of a Blender material (see the module docstring for the mapping)."""
    if mat is None:
        return {"model": "lambert", "albedo": 0.8}
    node = _output_shader_node(mat)
    clamp = lambda c: tuple(float(np.clip(x, 0.0, 1.0)) for x in list(c)[:3])  # noqa: E731
    if node is not None and node.bl_idname == "ShaderNodeBsdfDiffuse":
        return {"model": "lambert", "albedo": clamp(_val(node, "Color", (0.8, 0.8, 0.8, 1)))}
    if node is not None and node.bl_idname == "ShaderNodeBsdfPrincipled":
        exact = _principled_dict(node)
        if exact is not None:
            return exact
        base = np.array(clamp(_principled_input(node, "base_color")))
        metal = float(np.clip(_principled_input(node, "metallic"), 0, 1))
        rough = float(np.clip(_principled_input(node, "roughness"), 0, 1))
        spec = float(np.clip(_principled_input(node, "specular_ior_level"), 0, 1))
        f0 = (1 - metal) * min(0.08 * spec, 1.0) + metal * base
        return {"model": "cook_torrance", "distribution": "ggx", "alpha": max(rough * rough, 1e-3),
                "F0": tuple(float(x) for x in np.clip(f0, 0, 1)), "kd": tuple(float(x) for x in base * (1 - metal)),
                "ks": 1.0}
    terms = _shader_terms(node, 1.0)
    if terms and all(n.bl_idname in _DIFFUSE + _GLOSSY for n, _ in terms):
        lobe = {(round(float(np.clip(_val(n, "Roughness", 0.5), 0, 1)), 6), _GLOSSY_DIST.get(n.distribution, "ggx"))
                for n, _ in terms if n.bl_idname in _GLOSSY}
        if len(lobe) == 1:     # Cycles: Σ w (Diffuse colour / π) + Σ w Glossy colour · D G / (4 cos cos)
            kd = sum((w * np.asarray(_val(n, "Color", (0.8, 0.8, 0.8, 1))[:3], float) for n, w in terms
                      if n.bl_idname in _DIFFUSE), np.zeros(3))
            ks = sum(w * np.asarray(_val(n, "Color", (0.8, 0.8, 0.8, 1))[:3], float) for n, w in terms
                     if n.bl_idname in _GLOSSY)
            ks = np.clip(ks, 0.0, 1.0)
            top = float(ks.max())
            r, dist = lobe.pop()
            return {"model": "cook_torrance", "distribution": "ggx" if dist == "multi_ggx" else dist,
                    "alpha": max(r * r, 1e-3), "fresnel": "none", "multiscatter": dist == "multi_ggx",
                    "F0": tuple(float(x) for x in (ks / top if top > 0 else np.ones(3))), "ks": top,
                    "kd": clamp(kd)}
        if not lobe:
            kd = sum(w * np.asarray(_val(n, "Color", (0.8, 0.8, 0.8, 1))[:3], float) for n, w in terms)
            return {"model": "lambert", "albedo": clamp(kd)}
    return {"model": "lambert", "albedo": clamp(mat.diffuse_color)}


def _principled_input(node, key: str):
    """The Principled BSDF node's input of ``principled.PRINCIPLED_DEFAULTS[key]`` (that default when it has no such
    socket)."""
    return _val(node, cycles_principled.PRINCIPLED_SOCKETS[key], cycles_principled.PRINCIPLED_DEFAULTS[key])


def _principled_dict(node):
    """``principled`` dict of a Principled BSDF node whose inputs the exact twin covers (no coat, sheen,
    transmission, subsurface, thin film, diffuse roughness, anisotropy; the inputs it reads unlinked; GGX or
    Multiscatter GGX), else None."""
    pr = cycles_principled
    others = ("Coat Weight", "Sheen Weight", "Transmission Weight", "Subsurface Weight", "Thin Film Thickness",
              "Diffuse Roughness", "Anisotropic", "Alpha")
    if node.distribution not in ("GGX", "MULTI_GGX") or any(
            node.inputs.get(k) is not None and node.inputs[k].is_linked
            for k in (*pr.PRINCIPLED_SOCKETS.values(), *others)):
        return None
    if not pr.principled_supported({k: _val(node, k, 0.0 if k != "Alpha" else 1.0) for k in others}):
        return None
    rgb = lambda c, hi=1.0: tuple(float(np.clip(x, 0.0, hi)) for x in list(c)[:3])  # noqa: E731
    pin = lambda key: _principled_input(node, key)  # noqa: E731
    return {"model": "principled", "base_color": rgb(pin("base_color")),
            "metallic": float(np.clip(pin("metallic"), 0, 1)),
            "roughness": float(np.clip(pin("roughness"), 0, 1)),
            "ior": float(np.clip(pin("ior"), 1e-3, 1e3)),
            "specular_ior_level": float(np.clip(pin("specular_ior_level"), 0, 1e3)),
            "specular_tint": rgb(pin("specular_tint"), 1e3),
            "multiscatter": node.distribution == "MULTI_GGX"}


_DIFFUSE = ("ShaderNodeBsdfDiffuse",)
_GLOSSY = ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic")
#: the Glossy node's distribution -> ``brdfs`` cook_torrance (Ashikhmin-Shirley has no twin: GGX of the same α)
_GLOSSY_DIST = {"GGX": "ggx", "MULTI_GGX": "multi_ggx", "BECKMANN": "beckmann_smith", "ASHIKHMIN_SHIRLEY": "ggx"}


def _shader_terms(node, weight: float, depth: int = 0):
    """[(BSDF node, weight)] that ``node`` sums: Add Shader adds its inputs, Mix Shader with an unlinked Fac f
    weights them (1 - f, f); None when a linked Fac, a node group or a loop (depth > 16) is in the way."""
    if node is None or depth > 16:
        return None
    if node.bl_idname == "NodeReroute":
        return _shader_terms(node.inputs[0].links[0].from_node if node.inputs[0].is_linked else None, weight, depth + 1)
    if node.bl_idname == "ShaderNodeAddShader":
        pairs = [(s, weight) for s in list(node.inputs)[:2]]
    elif node.bl_idname == "ShaderNodeMixShader":
        if node.inputs[0].is_linked:
            return None
        f = float(np.clip(node.inputs[0].default_value, 0.0, 1.0))
        pairs = [(node.inputs[1], weight * (1.0 - f)), (node.inputs[2], weight * f)]
    else:
        return [(node, weight)]
    out = []
    for sock, w in pairs:
        if sock.is_linked and w > 0:
            t = _shader_terms(sock.links[0].from_node, w, depth + 1)
            if t is None:
                return None
            out += t
    return out


MODES = ("table", "fit", "reference")


@checked
def make_biscale_material(fit=None, name: str = "Bi-scale", use_tilted: bool = True, mode: str = "fit",
                          brdf=None, table=None) -> bpy.types.Material:
    """Cycles material of a bi-scale effective BRDF.

    ``mode="fit"``: the fitted closure mixture ``fit`` (``precompute.biscale.fit.ClosureFit``) as SVM
    nodes (Diffuse BSDF + "Scratch: Bi-scale Lobe" groups; works on GPU and in EEVEE).
    ``mode="reference"``: the exact table of ``brdf`` (``precompute.biscale.EffectiveBRDF``)
    importance-sampled by an INTERNAL OSL script node (``osl.biscale_reference``; no light sampling:
    validation renders) where Cycles runs OSL on the CPU, and the fitted closures ``fit`` (fitted
    here when None) everywhere else (Cycles SVM, GPU, EEVEE; see ``render_paths``).  Tangent node (UV map) and UV Map
    node wired in as for the scratch reference shader.
    ``mode="table"``: the tabulated-BRDF closure of ``table`` (a ``TabulatedBRDF``, best the finer table made
    from the facets by ``precompute.biscale.table.tabulate_tile``; default ``brdf`` itself on its grid)."""
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    if mode in ("reference", "table") and brdf is None:
        raise ValueError(f"brdf: the {mode} mode needs the EffectiveBRDF table")
    if fit is None and mode == "fit":
        raise ValueError("fit: the fit mode needs a ClosureFit (precompute.biscale.fit.fit_closures)")
    if fit is None:  # the reference mode's twin where OSL cannot run
        fit = fitmod.fit_closures(brdf)
    if mode == "table":   # the exact table as a closure; the fitted closures are its SVM / EEVEE twin
        with transaction.new_datablocks():
            mat = tabulated_material.make_tabulated_material(
                biscale_table.to_tabulated(brdf) if table is None else table, name, svm_twin=lambda tree: _fit_closures(tree, fit, use_tilted),
                kind="biscale")
            mat["biscale_mode"], mat["biscale_fit_rel_l1"], mat["biscale_fit_psnr"] = mode, float(fit.rel_l1), float(fit.psnr)
        return mat
    src = biscale_reference.generate(brdf) if mode == "reference" else None  # ValueError first
    with transaction.new_datablocks():  # a failure leaves no half material (nor its script text) behind
        mat = new_material(name)
        svm_surface = _fit_closures(mat.node_tree, fit, use_tilted)
        osl_surface = None if src is None else _reference_script(mat, src)
        render_paths.link_surface(mat.node_tree, svm_surface, osl_surface, mat.node_tree.nodes["Material Output"])
        mat.cycles.use_bump_map_correction = False  # keeps tilted lobe normals (see shared notes)
        mat["scratch_addon_kind"] = "biscale"
        mat["biscale_mode"] = mode
        mat["biscale_fit_rel_l1"] = float(fit.rel_l1)
        mat["biscale_fit_psnr"] = float(fit.psnr)
    return mat


def _fit_closures(tree, fit, use_tilted: bool):
    """Diffuse BSDF + one "Scratch: Bi-scale Lobe" group per fitted lobe, summed; returns the closure socket."""
    group = biscale_groups.ensure()
    diff = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Color"].default_value = (*[float(c) for c in np.clip(fit.diffuse, 0, 1)], 1.0)
    diff.inputs["Roughness"].default_value = 0.0
    diff.location = (-300, 200)
    shader = diff.outputs["BSDF"]
    for k, lb in enumerate(fit.lobes):
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        node.location = (-300, -180 * (k + 1))
        r, an = fitmod.glossy_node_params(lb.alpha_x, lb.alpha_y)
        node.inputs["Color"].default_value = (*[float(c) for c in np.clip(lb.colour, 0, 1)], 1.0)
        node.inputs["Roughness"].default_value = r
        node.inputs["Anisotropy"].default_value = an
        node.inputs["Tilt"].default_value = lb.tilt if use_tilted else 0.0
        node.inputs["Tilt Azimuth"].default_value = lb.tilt_azimuth
        node.inputs["Tangent Azimuth"].default_value = lb.tangent_azimuth
        add = tree.nodes.new("ShaderNodeAddShader")
        add.location = (0, -180 * k)
        tree.links.new(shader, add.inputs[0])
        tree.links.new(node.outputs["BSDF"], add.inputs[1])
        shader = add.outputs["Shader"]
    return shader


def _reference_script(mat, src):
    """The exact-table OSL script node (UV Map and Tangent wired in); returns its closure socket."""
    script = osl_compile.uv_script_node(mat.node_tree, f"{mat.name}.biscale.osl", src)
    return script.outputs["BSDF"]


@checked
def bake(tile_obj, target=None, n_lobes: int = 4, progress=None, depsgraph=None, exr_dir: str | None = None,
         mode: str = "table", **opts):
    """Effective BRDF of ``tile_obj`` (its material slots are the small-scale materials) as a material
    applied to ``target`` (if given): ``mode="table"`` (default) the table as a tabulated-BRDF closure
    (OSL; the fitted closures elsewhere), ``dir_res`` by default from the sharpest small-scale material
    (``precompute.biscale.table.table_dir_res``); ``mode="fit"`` the fitted closure mixture, ``mode="reference"``
    the exact table importance-sampled in OSL where Cycles runs OSL on the CPU, the fitted closures elsewhere.
    ``interreflections`` ("auto" default, True, False; in ``opts``): light bouncing between the tile's
    facets added to the table and the fit (``precompute.biscale.interreflect``; "auto": when the
    first-bounce estimate exceeds 1 %).  Returns (material, EffectiveBRDF, ClosureFit, info dict).  ``progress(fraction)`` is
    called between steps.  The table's folder (``exr_dir``, default the cache's ``biscale`` folder) is
    checked before the bake; a failure leaves ``target``'s material slot as it was and no new material."""
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    check_inputs([{"model": "lambert"}], n_lobes, **opts)  # every option before any work (the slots come later)
    if mode == "reference":
        max_res = biscale_reference.MAX_DIR_RES
        dr = opts.get("dir_res", 10)
        if dr > max_res:
            raise ValueError(f"dir_res: the reference mode (Exact Reference) compiles the table into OSL and needs "
                             f"dir_res <= {max_res}, got {dr}")
    if mode == "table" and opts.get("dir_res", 0) > biscale_table.MAX_SHADER_DIR_RES:
        raise ValueError(f"dir_res: the table mode holds at most {biscale_table.MAX_SHADER_DIR_RES}, got {opts['dir_res']}")
    if target is not None and (not isinstance(target, bpy.types.Object) or target.type != "MESH"):
        raise ValueError(f"target: expected a mesh object, got {getattr(target, 'type', type(target).__name__)!r}")
    step = progress or (lambda f: None)
    step(0.0)
    exr_dir = table_dir(exr_dir)  # before the bake, not after it
    V, F, M, P = tile_from_object(tile_obj, depsgraph)
    slots = [s.material for s in tile_obj.material_slots] or [None]
    materials = [small_scale_material(m) for m in slots]
    if mode == "table" and not opts.get("dir_res"):
        opts["dir_res"] = biscale_table.table_dir_res(materials)   # follows the sharpest small-scale material
    step(0.1)
    brdf, fit, info = bake_tables(V, F, M, P, materials, n_lobes=n_lobes, exr_dir=exr_dir,
                                  progress=lambda f: step(0.1 + 0.8 * f), closure_table=mode == "table", **opts)
    table = info.pop("table", None)     # the closure's finer table, tabulated from the facets
    with transaction.new_datablocks():
        mat = make_biscale_material(fit, name=f"Bi-scale {tile_obj.name}", mode=mode, brdf=brdf, table=table)
        mat["biscale_table"] = info["exr"] or ""
        mat["biscale_interreflections"] = bool(info["interreflections"])
        mat["biscale_indirect_estimate"] = float(info["indirect_estimate"])
        if target is not None:
            if target.data.materials:
                target.data.materials[target.active_material_index] = mat
            else:
                target.data.materials.append(mat)
    step(1.0)
    info["mode"] = mode
    return mat, brdf, fit, info
