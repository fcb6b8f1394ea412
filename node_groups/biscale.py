"""Bi-scale fitted lobe (SVM, GPU-safe): one Cycles GGX Glossy BSDF with a tilted normal and a
rotated tangent in the surface frame of the active UV map (Wu et al. 2011, large-scale material
approximated as in ``precompute.biscale.fit``).

Frame: u = UV tangent made orthogonal to the shading normal n, v = n x u.
Closure normal N = cos(Tilt) n + sin(Tilt) (cos(Tilt Azimuth) u + sin(Tilt Azimuth) v),
tangent T = cos(Tangent Azimuth) u + sin(Tangent Azimuth) v (angles in radians).
Roughness / Anisotropy follow the Glossy node's own mapping (see
``precompute.biscale.fit.glossy_node_params``).  Materials using tilted lobes must have
``use_bump_map_correction`` off (it rotates tilted normals back toward Ng).
"""
from __future__ import annotations

import bpy

from . import add_socket, ensure_group

GROUP_NAME = "Scratch: Bi-scale Lobe"
VERSION = 1


def _build(ng: bpy.types.ShaderNodeTree) -> None:
    add_socket(ng, "Color", "INPUT", "NodeSocketColor", (0.8, 0.8, 0.8, 1.0))
    add_socket(ng, "Roughness", "INPUT", "NodeSocketFloat", 0.3, 0.0, 1.0)
    add_socket(ng, "Anisotropy", "INPUT", "NodeSocketFloat", 0.0, -1.0, 1.0)
    add_socket(ng, "Tilt", "INPUT", "NodeSocketFloat", 0.0, 0.0, 1.5708)
    add_socket(ng, "Tilt Azimuth", "INPUT", "NodeSocketFloat", 0.0, -100.0, 100.0)
    add_socket(ng, "Tangent Azimuth", "INPUT", "NodeSocketFloat", 0.0, -100.0, 100.0)
    add_socket(ng, "BSDF", "OUTPUT", "NodeSocketShader")
    n, link = ng.nodes, ng.links.new
    gin, gout = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    geo = n.new("ShaderNodeNewGeometry")
    tan = n.new("ShaderNodeTangent")
    tan.direction_type = "UV_MAP"

    def vmath(op, a, b=None, scale=None):
        m = n.new("ShaderNodeVectorMath")
        m.operation = op
        link(a, m.inputs[0])
        if b is not None:
            link(b, m.inputs[1])
        if scale is not None:
            link(scale, m.inputs["Scale"])
        return m.outputs["Value"] if op in ("DOT_PRODUCT", "LENGTH") else m.outputs["Vector"]

    def smath(op, a):
        m = n.new("ShaderNodeMath")
        m.operation = op
        link(a, m.inputs[0])
        return m.outputs["Value"]

    nrm = geo.outputs["Normal"]
    # u = normalize(t - (t.n) n), v = n x u
    tn = vmath("DOT_PRODUCT", tan.outputs["Tangent"], nrm)
    proj = vmath("SCALE", nrm, scale=tn)
    u = vmath("NORMALIZE", vmath("SUBTRACT", tan.outputs["Tangent"], proj))
    v = vmath("CROSS_PRODUCT", nrm, u)

    def rotate(angle):  # cos(a) u + sin(a) v
        return vmath("ADD", vmath("SCALE", u, scale=smath("COSINE", angle)),
                     vmath("SCALE", v, scale=smath("SINE", angle)))

    horiz = rotate(gin.outputs["Tilt Azimuth"])
    N = vmath("NORMALIZE", vmath("ADD", vmath("SCALE", nrm, scale=smath("COSINE", gin.outputs["Tilt"])),
                                  vmath("SCALE", horiz, scale=smath("SINE", gin.outputs["Tilt"]))))
    T = rotate(gin.outputs["Tangent Azimuth"])
    glossy = n.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    link(gin.outputs["Color"], glossy.inputs["Color"])
    link(gin.outputs["Roughness"], glossy.inputs["Roughness"])
    link(gin.outputs["Anisotropy"], glossy.inputs["Anisotropy"])
    link(N, glossy.inputs["Normal"])
    link(T, glossy.inputs["Tangent"])
    link(glossy.outputs["BSDF"], gout.inputs["BSDF"])
    gin.location, gout.location, glossy.location = (-900, 0), (400, 0), (150, 0)


def ensure() -> bpy.types.ShaderNodeTree:
    """The (up-to-date) node group."""
    return ensure_group(GROUP_NAME, VERSION, _build)
