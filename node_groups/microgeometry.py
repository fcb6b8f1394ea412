"""Ellipsoid-NDF lobes (Dong et al. 2015, §8-9) as Glossy BSDF node groups (SVM: GPU-safe, no OSL).

Both groups build the closure frame of :func:`precompute.microgeometry.glossy.closure_frame`:

* surface frame from the active UV map: ``T0`` (Tangent node, UV_MAP), ``N`` (Geometry normal),
  ``B0 = normalize(N x T0)``, ``T0 = B0 x N`` (re-orthogonalised);
* lobe axis rotated by ``Rotation`` turns about ``N``: ``T_r = cos T0 + sin B0``, ``B_r = N x T_r``;
* closure normal ``N' = normalize(Tilt.x T0 + Tilt.y B0 + Tilt.z N)`` (the ellipsoid's ``R^T z``);
* tangent ``X' = B_r x N'`` (the ellipsoid's ``R^T x``, exact for ``R = Rx Ry Rz``); the Glossy
  node's own Rotation stays 0 (it would rotate about ``N'``, which is not the ellipsoid's ``theta_z``).

Distribution: single-scattering GGX.  Eq. 13-14 of the paper are a single-scattering microfacet
model too; Cycles' multiscatter GGX is energy conserving only for isotropic lobes (measured 0.57
albedo at roughness 0.5 / anisotropy 0.8, tests/test_render_baseline.py) and is not modelled by
the numpy twin (precompute/cycles_ggx.py) that the render tests compare against; for the narrow
lobes of polished/brushed metals (alpha <~ 0.1) the missing multiple scattering is < 1 %.

Groups
------
* ``GROUP_AVERAGE`` "Microgeometry: Average NDF": Color, Roughness, Anisotropy, Rotation (turns),
  Tilt (vector in the UV tangent frame) -> BSDF.  One lobe for the whole surface (Fig. 13, left).
* ``GROUP_TEXTURE`` "Microgeometry: Texture Lobe": Color, Params (RGBA from the packed params
  image: roughness, anisotropy, rotation), Tilt (RGB from the tilt image) -> BSDF.  Use
  :func:`add_texture_nodes` to wire the two Non-Color float images tiled over the UVs with a scale.
"""
from __future__ import annotations

import math

import bpy

from . import add_socket, ensure_group

GROUP_AVERAGE = "Microgeometry: Average NDF"
GROUP_TEXTURE = "Microgeometry: Texture Lobe"
VERSION = 1


def _vmath(n, op, a=None, b=None, link=None, loc=(0, 0)):
    node = n.new("ShaderNodeVectorMath")
    node.operation = op
    node.location = loc
    if a is not None:
        link(a, node.inputs[0])
    if b is not None:
        link(b, node.inputs[1])
    return node


def _math(n, op, a=None, b=None, link=None, loc=(0, 0)):
    node = n.new("ShaderNodeMath")
    node.operation = op
    node.location = loc
    if a is not None:
        if isinstance(a, (int, float)):
            node.inputs[0].default_value = a
        else:
            link(a, node.inputs[0])
    if b is not None:
        if isinstance(b, (int, float)):
            node.inputs[1].default_value = b
        else:
            link(b, node.inputs[1])
    return node


def _scaled_sum(n, link, vecs_and_scalars, loc):
    """sum_k s_k v_k with Vector Math SCALE / ADD nodes (scalars are float sockets)."""
    acc = None
    for k, (v, s) in enumerate(vecs_and_scalars):
        sc = n.new("ShaderNodeVectorMath")
        sc.operation = "SCALE"
        sc.location = (loc[0], loc[1] - 120 * k)
        link(v, sc.inputs[0])
        link(s, sc.inputs["Scale"])
        if acc is None:
            acc = sc.outputs[0]
        else:
            add = _vmath(n, "ADD", acc, sc.outputs[0], link, (loc[0] + 160, loc[1] - 120 * k))
            acc = add.outputs[0]
    return acc


def _glossy_with_frame(ng, color, roughness, anisotropy, rotation, tilt, x0=0):
    """Nodes of the tilted/rotated closure frame + GGX Glossy; returns the Glossy node."""
    n, link = ng.nodes, ng.links.new
    tangent = n.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (x0, 200)
    geom = n.new("ShaderNodeNewGeometry")
    geom.location = (x0, 0)
    N = geom.outputs["Normal"]
    b0 = _vmath(n, "CROSS_PRODUCT", N, tangent.outputs["Tangent"], link, (x0 + 200, 200))
    b0n = _vmath(n, "NORMALIZE", b0.outputs[0], None, link, (x0 + 360, 200))
    B0 = b0n.outputs[0]
    t0 = _vmath(n, "CROSS_PRODUCT", B0, N, link, (x0 + 520, 200))
    T0 = t0.outputs[0]
    ang = _math(n, "MULTIPLY", rotation, 2.0 * math.pi, link, (x0, -250))
    c = _math(n, "COSINE", ang.outputs[0], None, link, (x0 + 160, -250))
    s = _math(n, "SINE", ang.outputs[0], None, link, (x0 + 160, -400))
    T_r = _scaled_sum(n, link, [(T0, c.outputs[0]), (B0, s.outputs[0])], (x0 + 700, 200))
    B_r = _vmath(n, "CROSS_PRODUCT", N, T_r, link, (x0 + 1050, 200)).outputs[0]
    sep = n.new("ShaderNodeSeparateXYZ")
    sep.location = (x0 + 160, -600)
    link(tilt, sep.inputs[0])
    Np = _scaled_sum(n, link, [(T0, sep.outputs["X"]), (B0, sep.outputs["Y"]), (N, sep.outputs["Z"])],
                     (x0 + 700, -400))
    Np = _vmath(n, "NORMALIZE", Np, None, link, (x0 + 1050, -400)).outputs[0]
    Xp = _vmath(n, "CROSS_PRODUCT", B_r, Np, link, (x0 + 1250, 100)).outputs[0]
    Xp = _vmath(n, "NORMALIZE", Xp, None, link, (x0 + 1400, 100)).outputs[0]
    glossy = n.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    glossy.location = (x0 + 1600, 0)
    link(color, glossy.inputs["Color"])
    link(roughness, glossy.inputs["Roughness"])
    link(anisotropy, glossy.inputs["Anisotropy"])
    glossy.inputs["Rotation"].default_value = 0.0
    link(Np, glossy.inputs["Normal"])
    link(Xp, glossy.inputs["Tangent"])
    return glossy


def _build_average(ng: bpy.types.ShaderNodeTree) -> None:
    add_socket(ng, "Color", "INPUT", "NodeSocketColor", (0.8, 0.8, 0.8, 1.0))
    add_socket(ng, "Roughness", "INPUT", "NodeSocketFloat", 0.3, 0.0, 1.0)
    add_socket(ng, "Anisotropy", "INPUT", "NodeSocketFloat", 0.0, -1.0, 1.0)
    add_socket(ng, "Rotation", "INPUT", "NodeSocketFloat", 0.0, -10.0, 10.0)
    add_socket(ng, "Tilt", "INPUT", "NodeSocketVector", (0.0, 0.0, 1.0))
    add_socket(ng, "BSDF", "OUTPUT", "NodeSocketShader")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    gin.location = (-300, 0)
    o = gin.outputs
    glossy = _glossy_with_frame(ng, o["Color"], o["Roughness"], o["Anisotropy"], o["Rotation"], o["Tilt"])
    gout.location = (glossy.location.x + 250, 0)
    ng.links.new(glossy.outputs["BSDF"], gout.inputs["BSDF"])


def _build_texture(ng: bpy.types.ShaderNodeTree) -> None:
    add_socket(ng, "Color", "INPUT", "NodeSocketColor", (0.8, 0.8, 0.8, 1.0))
    add_socket(ng, "Params", "INPUT", "NodeSocketColor", (0.3, 0.0, 0.0, 1.0))
    add_socket(ng, "Tilt", "INPUT", "NodeSocketColor", (0.0, 0.0, 1.0, 1.0))
    add_socket(ng, "BSDF", "OUTPUT", "NodeSocketShader")
    n, link = ng.nodes, ng.links.new
    gin, gout = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    gin.location = (-500, 0)
    sep = n.new("ShaderNodeSeparateColor")  # RGB mode: (roughness, anisotropy, rotation)
    sep.location = (-300, -100)
    link(gin.outputs["Params"], sep.inputs["Color"])
    glossy = _glossy_with_frame(ng, gin.outputs["Color"], sep.outputs["Red"], sep.outputs["Green"],
                                sep.outputs["Blue"], gin.outputs["Tilt"])
    gout.location = (glossy.location.x + 250, 0)
    link(glossy.outputs["BSDF"], gout.inputs["BSDF"])


def ensure_average() -> bpy.types.ShaderNodeTree:
    """The (up-to-date) average-NDF group."""
    return ensure_group(GROUP_AVERAGE, VERSION, _build_average)


def ensure_texture() -> bpy.types.ShaderNodeTree:
    """The (up-to-date) per-texel lobe group."""
    return ensure_group(GROUP_TEXTURE, VERSION, _build_texture)


def add_texture_nodes(tree, params_image, tilt_image, scale: float = 1.0, interpolation: str = "Linear",
                      location=(-900, 0)):
    """Add UV x Scale -> two Image Texture nodes (REPEAT) -> a ``GROUP_TEXTURE`` node into ``tree``.

    ``params_image``/``tilt_image``: Non-Color float images (see module doc).  ``scale``: texture
    repeats per UV unit (Mapping node Scale, editable afterwards).  Returns the group node.
    """
    n, link = tree.nodes, tree.links.new
    x, y = location
    uv = n.new("ShaderNodeTexCoord")
    uv.location = (x, y)
    mapping = n.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.location = (x + 200, y)
    mapping.label = "Texture Scale"
    mapping.inputs["Scale"].default_value = (scale, scale, 1.0)
    link(uv.outputs["UV"], mapping.inputs["Vector"])
    group = n.new("ShaderNodeGroup")
    group.node_tree = ensure_texture()
    group.location = (x + 700, y)
    for k, (img, sock) in enumerate(((params_image, "Params"), (tilt_image, "Tilt"))):
        tex = n.new("ShaderNodeTexImage")
        tex.image = img
        tex.interpolation = interpolation
        tex.extension = "REPEAT"
        tex.location = (x + 420, y - 300 * k)
        tex.label = sock
        link(mapping.outputs["Vector"], tex.inputs["Vector"])
        link(tex.outputs["Color"], group.inputs[sock])
    return group
