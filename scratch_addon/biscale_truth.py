"""Explicit-geometry ground truth for bi-scale materials (Wu et al. 2011 validated the way Cycles can):
the tile repeated n x n times on a plane with its small-scale materials as ordinary Cycles BSDFs, and
direction-coded environments.  Rendered with ``max_bounces = 0`` it is the direct-light truth that
Wu's model stands for (shadowing and masking by neighbouring tiles included, no inter-reflections);
with bounces, the full global-illumination truth.  Used by ``tests/biscale`` and ``bench/biscale_truth``.
"""
from __future__ import annotations

import bpy
import numpy as np

from ..precompute.cycles import principled as cycles_principled
from . import render
from .materials import ensure_nodes, new_material

__all__ = ["small_scale_blender_material", "explicit_tile_plane", "direction_world"]


def small_scale_blender_material(mat: dict, name: str = "small scale") -> bpy.types.Material:
    """A Cycles material rendering the small-scale BRDF dict ``mat`` (``precompute.biscale.brdfs``)
    exactly: ``lambert`` -> Diffuse BSDF; ``cook_torrance`` with the GGX (or ``beckmann_smith``) distribution and
    no Fresnel (F0 = 1, or ``fresnel="none"``) -> Glossy BSDF GGX / Multiscatter GGX (``multiscatter``) / Beckmann,
    colour ks·F0, Roughness √α (Blender's α = Roughness²), plus a Diffuse BSDF of colour kd.  Other models have no
    exact Cycles twin: ValueError."""
    model = mat.get("model") if isinstance(mat, dict) else None
    if model == "principled":
        return _principled_material(mat, name)
    if model not in ("lambert", "cook_torrance"):
        raise ValueError(f"materials: the explicit truth renders 'lambert' and GGX 'cook_torrance', got {model!r}")
    if model == "cook_torrance" and (mat.get("distribution", "beckmann") not in ("ggx", "beckmann_smith")
                                     or (mat.get("fresnel", "schlick") != "none"
                                         and not np.allclose(mat.get("F0", 0.95), 1.0))):
        raise ValueError("materials: cook_torrance needs distribution 'ggx' or 'beckmann_smith' and no Fresnel "
                         "(F0 = 1 or fresnel 'none') for an exact Cycles twin")
    m = new_material(name)
    tree = m.node_tree
    for nd in [nd for nd in tree.nodes if nd.bl_idname != "ShaderNodeOutputMaterial"]:
        tree.nodes.remove(nd)
    out = next(nd for nd in tree.nodes if nd.bl_idname == "ShaderNodeOutputMaterial")
    rgb = lambda v: (*[float(x) for x in np.broadcast_to(np.asarray(v, float), 3)], 1.0)  # noqa: E731
    if model == "lambert":
        d = tree.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Color"].default_value = rgb(mat.get("albedo", 0.8))
        d.inputs["Roughness"].default_value = 0.0
        tree.links.new(d.outputs["BSDF"], out.inputs["Surface"])
        return m
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = ("BECKMANN" if mat["distribution"] == "beckmann_smith"
                      else "MULTI_GGX" if mat.get("multiscatter", False) else "GGX")
    g.inputs["Roughness"].default_value = float(np.sqrt(mat.get("alpha", 0.2)))
    colour = np.asarray(mat.get("ks", 1.0), float) * np.asarray(mat.get("F0", 1.0), float)
    g.inputs["Color"].default_value = rgb(colour if mat.get("fresnel", "schlick") == "none" else mat.get("ks", 1.0))
    shader = g.outputs["BSDF"]
    kd = np.broadcast_to(np.asarray(mat.get("kd", 0.0), float), 3)
    if kd.max() > 0:
        d = tree.nodes.new("ShaderNodeBsdfDiffuse")
        d.inputs["Color"].default_value = rgb(kd)
        add = tree.nodes.new("ShaderNodeAddShader")
        tree.links.new(d.outputs["BSDF"], add.inputs[0])
        tree.links.new(shader, add.inputs[1])
        shader = add.outputs["Shader"]
    tree.links.new(shader, out.inputs["Surface"])
    return m


def _principled_material(mat: dict, name: str) -> bpy.types.Material:
    """A Principled BSDF node with the ``principled`` dict's inputs (the rest at the node's defaults)."""
    m = new_material(name)
    tree = m.node_tree
    for nd in [nd for nd in tree.nodes if nd.bl_idname != "ShaderNodeOutputMaterial"]:
        tree.nodes.remove(nd)
    out = next(nd for nd in tree.nodes if nd.bl_idname == "ShaderNodeOutputMaterial")
    p = tree.nodes.new("ShaderNodeBsdfPrincipled")
    d = {**cycles_principled.PRINCIPLED_DEFAULTS, **mat}     # the twin's defaults (the node's), one copy
    p.distribution = "MULTI_GGX" if d["multiscatter"] else "GGX"
    for key, socket in cycles_principled.PRINCIPLED_SOCKETS.items():
        v = np.asarray(d[key], float)
        p.inputs[socket].default_value = ((*np.broadcast_to(v, 3).tolist(), 1.0) if key in ("base_color", "specular_tint")
                                          else float(v))
    tree.links.new(p.outputs["BSDF"], out.inputs["Surface"])
    return m


def explicit_tile_plane(scene, tile, materials, n: int = 300, size: float = 4.0, name: str = "Explicit tiles"):
    """The tile (``precompute.biscale.geometry.Tile``) repeated n x n times over a ``size`` square
    centred at the origin (tile x along world x, like the bi-scale material's UV tangent on
    ``render.add_plane``), flat shaded, one material slot per small-scale material dict."""
    if not (isinstance(n, int) and 1 <= n <= 1000):
        raise ValueError(f"n: expected an integer in [1, 1000], got {n!r}")
    V, F, M, P = (np.asarray(tile.vertices, float), np.asarray(tile.faces, np.int64),
                  np.asarray(tile.face_material, np.int64), float(tile.period))
    s = size / (n * P)
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"), -1).reshape(-1, 2)
    offs = np.concatenate([ij * P, np.zeros((len(ij), 1))], 1)
    Vall = ((V[None] + offs[:, None]) * s - np.array([size / 2, size / 2, 0])).reshape(-1, 3)
    Fall = (F[None] + (np.arange(len(ij)) * len(V))[:, None, None]).reshape(-1, 3)
    mesh = render.flat_triangle_mesh(name, Vall, Fall, np.tile(np.minimum(M, len(materials) - 1), len(ij)))
    mesh.validate()
    for k, md in enumerate(materials):
        mesh.materials.append(small_scale_blender_material(md, f"{name} m{k}"))
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    return obj


def direction_world(scene, kind: str = "first", strength: float = 1.0) -> None:
    """A direction-coded environment: world colour 0.5 + 0.5 d (``"first"``: the image mean is a first
    moment of where light leaves) or d² per channel (``"second"``), d the ray direction (Texture
    Coordinate "Generated" in a world shader)."""
    if kind not in ("first", "second"):
        raise ValueError(f"kind: expected 'first' or 'second', got {kind!r}")
    world = scene.world or bpy.data.worlds.new("Direction coded")
    scene.world = world
    tree = ensure_nodes(world)
    tree.nodes.clear()
    tc = tree.nodes.new("ShaderNodeTexCoord")
    vm = tree.nodes.new("ShaderNodeVectorMath")
    if kind == "first":
        vm.operation = "MULTIPLY_ADD"
        vm.inputs[1].default_value = (0.5, 0.5, 0.5)
        vm.inputs[2].default_value = (0.5, 0.5, 0.5)
        tree.links.new(tc.outputs["Generated"], vm.inputs[0])
    else:
        vm.operation = "MULTIPLY"
        tree.links.new(tc.outputs["Generated"], vm.inputs[0])
        tree.links.new(tc.outputs["Generated"], vm.inputs[1])
    bg = tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = strength
    tree.links.new(vm.outputs["Vector"], bg.inputs["Color"])
    out = tree.nodes.new("ShaderNodeOutputWorld")
    tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
