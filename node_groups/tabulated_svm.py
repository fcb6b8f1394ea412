"""The tabulated-BRDF closure as SVM nodes (Cycles SVM, GPU, EEVEE): the node twin of ``osl/tabulated_brdf.osl``.

Same closure as the OSL shader (``precompute.tables.tabulated_brdf``, module docstring): per sample one ωo
node picked with its interpolation weight, one ωi bin k drawn with probability P_k, a target jittered
uniformly in the bin, ONE narrow GGX Glossy node whose normal m mirrors ωo into the target and whose colour
is W = f cos θi / (p A).  Light sampling and MIS stay intact (Cycles evaluates the Glossy closure at light
directions).  What differs from the OSL shader (numpy twin: ``tabulated_brdf.sample_alias``):

- random numbers: two 4D White Noise colours of (P, ωo·k) (P jitters per sample, as OSL's hashnoise);
- the ωo node: floor(x + h) per axis (isotropic: x the continuous θo index; anisotropic: the hemi-octahedral
  row and column drawn independently; view grids: x(a), x(b) of the projected view angles a = atan2(ωx, ωz),
  b = atan2(ωy, ωz) from one Linear lookup each of a 4096-texel guide of the piecewise-linear node index
  (``tabulated_brdf.svm_view_guide``: exact at the texels and the end nodes, off by <= Δ/4 x the slope jump in
  the texel interval around an interior node, 2.7e-3 of a weight for nodes 0.05 rad apart, measured 1.6e-4 on
  the test grid), which gives each tap its interpolation weight (``view_taps``);
- the ωi bin: Walker's alias table of node o (``tabulated_brdf.svm_images`` "A": one Closest lookup at
  the centre of texel (floor(h M), o) returns prob_j, alias_j - j and c / P of both), instead of the CDF walk;
- the smooth floor (``tabulated_brdf.floor_split``): a Diffuse BSDF of colour kd x Tint added to the Glossy
  (``_floor``), the images holding the residual, as the OSL shader's FLOOR; the glossy floor
  (``tabulated_brdf.glossy_floor_split``): a second Glossy BSDF (GGX or Beckmann, roughness √α_g, colour ks x Tint),
  GFLOOR;
- f: one Linear lookup of the "F" atlas (node o's tile bordered by a copy of its edges: the clamped bilinear
  interpolation of the OSL shader, never bleeding into a neighbour tile); in the EEVEE variant (``ensure(eevee=True)``)
  four Closest lookups weighted by Mix nodes, because EEVEE's Linear lookup picks a mip level from the per-pixel
  jumps of the coordinate.  (White Noise's Value output equals its Colour's x in Cycles: one node gives three
  independent uniforms, not four.)

The group is built per table (images and constants are the table's) and shared by content hash.

Cost (``bench/tabulated_cost``, whole frame, per sample): 1.55-1.57x the SVM anisotropic Glossy (goal 1.3x, not
met; the OSL closure measures 1.29-1.35x in the same run); callgrind of that scene (``tabulated_cost --callgrind``,
load-free, ``bench/out/tabulated_callgrind.md``): aniso 1.72x, isotropic 1.65x, a bi-scale-size view-grid table 1.75x.  Per sample the graph runs 2 White Noise, 2 image
lookups and ~45 Math / Vector Math nodes (isotropic: 50 nodes in the group); callgrind of a 32² x 4 spp frame
(load-free instruction counts, render threads only): 1.65x the baseline's instructions (1.63x before the vector
rewrite of VERSION 3), the extra being SVM node interpretation (svm_eval_nodes 23 % of the frame, White Noise
3 %, Math / Vector Math 4.5 %) and image lookups only 2 %: hence one Linear lookup of the padded atlas rather
than 4 Closest lookups and their weights.  The smooth floor's Diffuse BSDF (``_floor``) adds 3.0 % instructions per
sample (``bench/tabulated_floor_callgrind``: 1.700x vs 1.650x the baseline, a GGX + Lambert table); the glossy floor's
Glossy BSDF and its per-view colour lookup 6.0 % more (1.802x).  Cycles compiles every unlinked constant input to its own value
node, so the count of nodes, not their kind, sets the price.
"""
from __future__ import annotations

import hashlib
import math

import bpy
import numpy as np

from ..precompute.cycles.glossy import glossy_node_params
from ..precompute.tables import tabulated_brdf as tbm
from . import add_socket, ensure_group
from .scratch_svm import _data_image, _G

GROUP_PREFIX = "Scratch: Tabulated BRDF "
IMAGE_PREFIX = "Scratch tabulated "
VERSION = 4
#: largest image side the graph uses (GPU textures and EEVEE: 16384 on common hardware)
MAX_IMAGE_SIDE = 16384


def fits(tb: tbm.ClosureTables) -> bool:
    """True if the graph can render the table: its images stay within ``MAX_IMAGE_SIDE`` (the alias rows are
    res² wide and n_o tall, the F atlas n_o (res + 2) tall; view grids: NB (res + 2) x NA (res + 2), a 2D atlas).  Every ωo grid is drawn: uniform θo, the hemi-octahedral grid,
    and view grids (``view_a`` / ``view_b``, the bi-scale bake's default) through the guide image "V"."""
    return tb.res * tb.res <= MAX_IMAGE_SIDE and tb.n_o <= MAX_IMAGE_SIDE and max(tbm.svm_atlas_shape(tb)) <= MAX_IMAGE_SIDE


def table_hash(tb: tbm.ClosureTables) -> str:
    h = hashlib.sha1()
    for a in (tb.F, tb.cdf):
        h.update(np.ascontiguousarray(a, np.float32).tobytes())
    h.update(repr((tb.res, tb.iso, tb.n_o, float(tb.alpha), tb.half, float(tb.extent), VERSION)).encode())
    h.update(np.asarray(getattr(tb, "kd", np.zeros(3)), np.float32).tobytes())       # the Diffuse floor
    if np.any(getattr(tb, "ks", 0.0)):                # the glossy floor (other tables' hashes unchanged)
        h.update(np.asarray(tb.ks, np.float32).tobytes() + np.float32(tb.alpha_g).tobytes() + tb.dist_g.encode())
        if getattr(tb, "ks_view", None) is not None:
            h.update(np.asarray(tb.ks_view, np.float32).tobytes())
    if getattr(tb, "view_a", None) is not None:      # view grids only: the hash of other tables is unchanged
        for a in (tb.view_a, tb.view_b):
            h.update(np.ascontiguousarray(a, np.float64).tobytes())
    if getattr(tb, "centroid", None) is not None:    # lobe-following view interpolation (other hashes unchanged)
        h.update(b"centroid" + np.ascontiguousarray(tb.centroid, np.float32).tobytes())
    return h.hexdigest()[:12]


def images(tb: tbm.ClosureTables) -> dict:
    """Packed Non-Color float images of ``tabulated_brdf.svm_images`` ("A" RGBA, "F" RGB), shared by content."""
    arr = tbm.svm_images(tb)
    out = {"A": _data_image(IMAGE_PREFIX + "A", arr["A"], alpha=True),
           "F": _data_image(IMAGE_PREFIX + "F", arr["F"], alpha=False)}
    if "V" in arr:
        out["V"] = _data_image(IMAGE_PREFIX + "V", arr["V"], alpha=False)
    if "K" in arr:
        out["K"] = _data_image(IMAGE_PREFIX + "K", arr["K"], alpha=False)
    if "C" in arr:
        out["C"] = _data_image(IMAGE_PREFIX + "C", arr["C"], alpha=False)
    for img in out.values():    # EEVEE uploads float images as half floats by default (Cycles reads float32):
        img.use_half_precision = False     # the guide's node index up to 18 would round by up to 0.008
    return out


def ensure(tb: tbm.ClosureTables, _break: str | None = None, eevee: bool = False) -> bpy.types.ShaderNodeTree:
    """The node group of table ``tb`` (input "Tint", output "BSDF"), built once per table content.
    ``eevee``: the EEVEE variant, whose F lookup is four Closest reads weighted bilinearly by nodes: EEVEE's
    Linear image lookup is ``textureGrad`` with the screen-space derivatives of the coordinate, and the atlas
    coordinate jumps from pixel to pixel (a random bin per sample), so it reads a coarse mip level (the atlas
    blurred across bins and tiles: the aniso test table rendered 6 % dark in a white furnace, measured).
    ``_break`` (tests only): "view" picks the ωo node of the opposite view, "alias" skips the alias step
    (bin j straight from h), "floor" counts the Diffuse floor twice: each must fail the render tests."""
    if not fits(tb):
        raise ValueError(f"table: res {tb.res}, {tb.n_o} view nodes exceed the {MAX_IMAGE_SIDE}-texel image limit")
    name = GROUP_PREFIX + table_hash(tb) + (" EEVEE" if eevee else "") + (f" broken {_break}" if _break else "")
    return ensure_group(name, VERSION, lambda ng: _build(ng, tb, images(tb), _break, eevee))


class _T(_G):
    def madd(self, a, b, c):
        """Vector Math Multiply Add a * b + c (a float socket or constant is broadcast to a vector)."""
        node = self.node("ShaderNodeVectorMath", operation="MULTIPLY_ADD")
        for s, v in zip(node.inputs[:3], (a, b, c)):   # a float socket is converted to (v, v, v) by Blender
            self._set(s, (v, v, v) if isinstance(v, float) else v)
        return node.outputs["Vector"]


def _closest_bilinear(g, img, xy, W: int, H: int):
    """Bilinear interpolation of ``img`` (W x H texels) at texel-space point ``xy`` (a vector socket; texel
    (i, j) centred at (i + 1/2, j + 1/2)) from four Closest / EXTEND reads: Cycles' Linear rule without
    EEVEE's mip selection."""
    p = g.vmath("SUBTRACT", xy, (0.5, 0.5, 0.0))
    i = g.vmath("FLOOR", p)
    fx, fy, _ = g.separate(g.vmath("SUBTRACT", p, i))
    taps = []
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        t = g.node("ShaderNodeTexImage", image=img, interpolation="Closest", extension="EXTEND")
        g._set(t.inputs["Vector"], g.madd(i, (1.0 / W, 1.0 / H, 0.0), ((dx + 0.5) / W, (dy + 0.5) / H, 0.0)))
        taps.append(t.outputs["Color"])

    def mix(f, a, b):
        m = g.node("ShaderNodeMix", data_type="RGBA", blend_type="MIX", clamp_factor=False)
        for sock, v in zip([s for s in m.inputs if s.enabled], (f, a, b)):     # Factor, A, B (colour)
            g._set(sock, v)
        return next(s for s in m.outputs if s.enabled)
    return mix(fy, mix(fx, taps[0], taps[1]), mix(fx, taps[2], taps[3]))


def _build(ng, tb: tbm.ClosureTables, imgs: dict, _break: str | None, eevee: bool = False) -> None:
    add_socket(ng, "Tint", "INPUT", "NodeSocketColor", (1.0, 1.0, 1.0, 1.0))
    add_socket(ng, "BSDF", "OUTPUT", "NodeSocketShader")
    g = _T(ng)
    gin, gout = g.node("NodeGroupInput"), g.node("NodeGroupOutput")
    res, n_o, D = tb.res, tb.n_o, tb.res * tb.res
    cell = 2.0 / res
    Z = tb.extent if tb.half else 1.0
    geo = g.node("ShaderNodeNewGeometry")
    tan = g.node("ShaderNodeTangent", direction_type="UV_MAP")
    N, wo, P = geo.outputs["Normal"], geo.outputs["Incoming"], geo.outputs["Position"]
    t = tan.outputs["Tangent"]              # orthonormal to N (Cycles' Tangent node)

    # per-sample uniforms: (h_o, h_o2, h_k) and the jitter (h_t, h_s, -)
    w_hash = g.vmath("DOT_PRODUCT", wo, (12.9898, 78.233, 37.719))

    def noise(w):
        wn = g.node("ShaderNodeTexWhiteNoise", noise_dimensions="4D")
        g._set(wn.inputs["Vector"], P)
        g._set(wn.inputs["W"], w)
        return wn.outputs["Color"]
    oz = g.vmath("DOT_PRODUCT", wo, N)
    h1 = noise(w_hash)
    jit = noise(oz)                          # another 4D point (P, ωo·n): an independent hash, no extra node
    u0, _, hk = g.separate(h1)

    def map_range(x, lo, hi, a, b, vector=False):
        m = g.node("ShaderNodeMapRange", data_type="FLOAT_VECTOR" if vector else "FLOAT", clamp=True)
        ins = [s for s in m.inputs if s.enabled]
        for s, v in zip(ins, (x, lo, hi, a, b)):
            g._set(s, (v, v, v) if vector and not isinstance(v, bpy.types.NodeSocket) else v)
        return next(s for s in m.outputs if s.enabled)

    flip = _break == "view"
    # 1. the ωo node o, drawn with its interpolation weight: floor(x + h) per axis
    if tb.iso:
        # x / (n_o - 1) = clamp(θo / (π / 2 n_o) - 1/2) / (n_o - 1) in [0, 1] (the Math node's clamp)
        a, b = 2.0 * n_o / math.pi / (n_o - 1.0), -0.5 / (n_o - 1.0)
        if flip:
            a, b = -a, 1.0 - b
        xn = g.math("MULTIPLY_ADD", g.math("ARCCOSINE", oz), a, b)
        xn.node.use_clamp = True
        o = g.math("FLOOR", g.math("MULTIPLY_ADD", xn, n_o - 1.0, u0))
        # the table frame (ωo at azimuth 0): fy = normalize(n x ωo'), fx = fy x n, ωo' = ωo + 1e-6 t (defined at ωo = n)
        fy = g.vmath("NORMALIZE", g.vmath("CROSS_PRODUCT", N, g.madd(t, 1e-6, wo)))
        fx = g.vmath("CROSS_PRODUCT", fy, N)
    elif getattr(tb, "view_a", None) is not None:
        # view grid: per axis the projected angle a = atan2(ωx, ωz) (b: ωy), its continuous node index x from
        # the guide row (Linear lookup at (a scale + offset, 1/4 or 3/4); EXTEND clamps beyond the end nodes)
        ey = g.vmath("CROSS_PRODUCT", N, t)
        xs = []
        for k, (axis, nodes) in enumerate(((t, tb.view_a), (ey, tb.view_b))):
            _, scale, offset = tbm.svm_view_guide(nodes)
            if flip:
                scale = -scale
            ang = g.math("ARCTAN2", g.vmath("DOT_PRODUCT", wo, axis), oz)
            tv = g.node("ShaderNodeTexImage", image=imgs["V"], interpolation="Linear", extension="EXTEND")
            g._set(tv.inputs["Vector"], g.madd(ang, (scale, 0.0, 0.0), (offset, 0.25 + 0.5 * k, 0.0)))
            xs.append(tv.outputs["Color"])                              # (xa, 0, 0) and (0, xb, 0)
        xab = g.vmath("ADD", xs[0], xs[1])                              # (xa, xb, 0)
        rc = g.vmath("FLOOR", g.vmath("ADD", xab, h1))
        o = g.vmath("DOT_PRODUCT", rc, (float(len(tb.view_b)), 1.0, 0.0))
        fx, fy = t, ey
    else:
        ey = g.vmath("CROSS_PRODUCT", N, t)
        A = g.vmath("DOT_PRODUCT", wo, g.vmath("ADD", t, ey))          # ωx + ωy
        B = g.vmath("DOT_PRODUCT", wo, g.vmath("SUBTRACT", t, ey))     # ωx - ωy
        d = g.math("ADD", g.math("MAXIMUM", g.math("ABSOLUTE", A), g.math("ABSOLUTE", B)), oz)
        st = g.vmath("DIVIDE", g.combine(A, B, 0.0), d)                 # hemi-octahedral (s, t) of ωo
        lo_, hi_ = -1.0 + 1.0 / res, 1.0 - 1.0 / res
        xrc = map_range(st, lo_, hi_, *((res - 1.0, 0.0) if flip else (0.0, res - 1.0)), vector=True)
        rc = g.vmath("FLOOR", g.vmath("ADD", xrc, h1))
        o = g.vmath("DOT_PRODUCT", rc, (float(res), 1.0, 0.0))
        fx, fy = t, ey
    # 2. the ωi bin: node o's alias table at texel (j, o), j = floor(h M)
    uh = g.math("MULTIPLY", hk, float(D))
    j = g.math("FLOOR", uh)
    ta = g.node("ShaderNodeTexImage", image=imgs["A"], interpolation="Closest", extension="EXTEND")
    # at the texel centres ((j + 1/2) / M, (o + 1/2) / n_o): GPU texture units round coordinates to 1/256 texel
    g._set(ta.inputs["Vector"], g.madd(j, (1.0 / D, 0.0, 0.0), g.madd(o, (0.0, 1.0 / n_o, 0.0), (0.5 / D, 0.5 / n_o, 0.0))))
    prob, d_alias, inv_pj = g.separate(ta.outputs["Color"])
    if _break == "alias":
        lo, inv_p = j, inv_pj
    else:
        take = g.math("LESS_THAN", prob, g.math("SUBTRACT", uh, j))    # f = hM - j > prob_j: the alias bin
        lo = g.math("MULTIPLY_ADD", take, d_alias, j)
        inv_p = g.math("MULTIPLY_ADD", take, ta.outputs["Alpha"], inv_pj)
    rk = g.math("FLOOR", g.math("MULTIPLY_ADD", lo, 1.0 / res, 0.5 / res))
    # (ck + h_t, rk + h_s, -) = (lo, 0, 0) + rk (-res, 1, 0) + jitter, ck = lo - res rk
    gv = g.madd(rk, (-float(res), 1.0, 0.0), g.madd(lo, (1.0, 0.0, 0.0), jit))
    # f: Linear lookup in node o's padded tile
    H, W = tbm.svm_atlas_shape(tb)
    grid2d = getattr(tb, "view_a", None) is not None and not tb.iso
    tile, step = (rc, (res + 2.0, res + 2.0, 0.0)) if grid2d else (o, (0.0, res + 2.0, 0.0))   # view grids: tile (ia, ib)
    if eevee:       # texel space (1 + g0, o (res + 2) + 1 + g1); view grids (ia (res + 2) + 1 + g0, ib (res + 2) + 1 + g1)
        f_rgb = _closest_bilinear(g, imgs["F"], g.madd(tile, step, g.vmath("ADD", gv, (1.0, 1.0, 0.0))), W, H)
    else:
        off = g.madd(tile, (step[0] / W, step[1] / H, 0.0), (1.0 / W, 1.0 / H, 0.0))
        tf = g.node("ShaderNodeTexImage", image=imgs["F"], interpolation="Linear", extension="EXTEND")
        g._set(tf.inputs["Vector"], g.madd(gv, (1.0 / W, 1.0 / H, 0.0), off))
        f_rgb = tf.outputs["Color"]
    # 3. the target: q = Z ((g0 + g1) cell/2 - 1, (g1 - g0) cell/2) (one Mapping node: -45° and scale), v = (q, 1 - |q|₁)
    mp = g.node("ShaderNodeMapping", vector_type="POINT")
    g._set(mp.inputs["Vector"], gv)
    mp.inputs["Location"].default_value = (-Z, 0.0, 0.0)
    mp.inputs["Rotation"].default_value = (0.0, 0.0, -0.25 * math.pi)
    sc = Z * cell / math.sqrt(2.0)
    mp.inputs["Scale"].default_value = (sc, sc, 0.0)
    q = mp.outputs["Vector"]
    qz = g.math("SUBTRACT", 1.0, g.vmath("DOT_PRODUCT", g.vmath("ABSOLUTE", q), (1.0, 1.0, 0.0)))
    qx, qy, _ = g.separate(q)
    x = g.madd(N, qz, g.madd(fy, qy, g.vmath("SCALE", fx, scale=qx)))
    L2 = g.vmath("DOT_PRODUCT", x, x)
    shift = getattr(tb, "centroid", None) is not None and "C" in imgs
    if shift:
        # lobe-following view interpolation: the target moves by Δ_o = C(xa, xb) (Linear) - C(ia, ib) (Closest), in bin
        # units (``tabulated_brdf.svm_images`` "C"); the weight stays the drawn point's
        NA, NB = len(tb.view_a), len(tb.view_b)
        if eevee:
            c_lin = _closest_bilinear(g, imgs["C"], g.vmath("ADD", xab, (0.5, 0.5, 0.0)), NA, NB)
        else:
            tl = g.node("ShaderNodeTexImage", image=imgs["C"], interpolation="Linear", extension="EXTEND")
            g._set(tl.inputs["Vector"], g.madd(xab, (1.0 / NA, 1.0 / NB, 0.0), (0.5 / NA, 0.5 / NB, 0.0)))
            c_lin = tl.outputs["Color"]
        tc = g.node("ShaderNodeTexImage", image=imgs["C"], interpolation="Closest", extension="EXTEND")
        g._set(tc.inputs["Vector"], g.madd(rc, (1.0 / NA, 1.0 / NB, 0.0), (0.5 / NA, 0.5 / NB, 0.0)))
        mp2 = g.node("ShaderNodeMapping", vector_type="POINT")
        g._set(mp2.inputs["Vector"], g.vmath("ADD", gv, g.vmath("SUBTRACT", c_lin, tc.outputs["Color"])))
        for name in ("Location", "Rotation", "Scale"):
            mp2.inputs[name].default_value = mp.inputs[name].default_value
        q2 = mp2.outputs["Vector"]
        qz2 = g.math("SUBTRACT", 1.0, g.vmath("DOT_PRODUCT", g.vmath("ABSOLUTE", q2), (1.0, 1.0, 0.0)))
        qx2, qy2, _ = g.separate(q2)
        x_t = g.madd(N, qz2, g.madd(fy, qy2, g.vmath("SCALE", fx, scale=qx2)))
        L2_t = g.vmath("DOT_PRODUCT", x_t, x_t)
    else:
        x_t, L2_t = x, L2
    a2 = float(tb.alpha) ** 2

    def inv_albedo(cd):     # 2 r / (1 + r), r = sqrt(1 - α² + α² / cd²): 1/A
        r = g.math("SQRT", g.math("ADD", g.math("DIVIDE", a2, g.math("MULTIPLY", cd, cd)), 1.0 - a2))
        return g.math("DIVIDE", g.math("MULTIPLY", r, 2.0), g.math("ADD", r, 1.0))
    if tb.half:
        m = g.vmath("NORMALIZE", x)                                     # h
        oh = g.vmath("DOT_PRODUCT", wo, m)
        above = g.math("LESS_THAN", g.math("MULTIPLY", oz, 0.5), g.math("MULTIPLY", oh, g.vmath("DOT_PRODUCT", m, N)))
        s = g.math("DIVIDE", g.math("MULTIPLY", oh, above), oz)        # ωi = reflect(ωo, h) above the horizon
        cd = oh
    else:
        m = g.vmath("NORMALIZE", g.madd(wo, g.math("SQRT", L2_t), x_t))
        cd = g.vmath("DOT_PRODUCT", wo, m) if tbm.svm_uses_albedo(tb) else None
        s = g.math("DIVIDE", qz, g.math("MULTIPLY", L2, L2))
        if shift:                                                       # no light from a target below the horizon
            s = g.math("MULTIPLY", s, g.math("GREATER_THAN", qz2, 0.0))
    s = g.math("MULTIPLY", s, inv_p)
    if tbm.svm_uses_albedo(tb):
        s = g.math("MULTIPLY", s, inv_albedo(cd))
    colour = g.vmath("MULTIPLY", g.vmath("SCALE", f_rgb, scale=s), gin.outputs["Tint"])
    glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
    g._set(glossy.inputs["Color"], colour)
    g._set(glossy.inputs["Roughness"], float(glossy_node_params(tb.alpha, tb.alpha)[0]))
    g._set(glossy.inputs["Normal"], m)
    ng.links.new(_floor(g, tb, gin.outputs["Tint"], glossy.outputs["BSDF"], 2.0 if _break == "floor" else 1.0,
                        xn if tb.iso else None, imgs.get("K")), gout.inputs["BSDF"])


def _floor(g, tb: tbm.ClosureTables, tint, bsdf, scale: float = 1.0, view_x=None, k_img=None):
    """The floors (``tabulated_brdf.floor_parts``): a Diffuse BSDF of colour kd x Tint and (glossy floor) a Glossy
    BSDF (GGX or Beckmann: ``dist_g``, roughness √α_g, colour ks x Tint, the shading normal) added to the table's Glossy ``bsdf`` (light
    sampling sees the lamp at every sample); ``bsdf`` itself when kd = ks = 0.  ``scale`` multiplies both (tests:
    a floor counted twice).  Per-view colours (``ks_view``, isotropic tables): ks(θo) from a Linear lookup of the
    1 x n_o image "K" at u = (x (n_o - 1) + 1/2) / n_o, ``view_x`` = x the graph's clamped θo index / (n_o - 1):
    the linear interpolation between the θo nodes of ``tabulated_brdf.floor_ks``."""
    kd = np.asarray(getattr(tb, "kd", np.zeros(3)), np.float64) * scale
    ks = np.asarray(getattr(tb, "ks", np.zeros(3)), np.float64) * scale
    if ks.any():
        gl = g.node("ShaderNodeBsdfGlossy", distribution="BECKMANN" if tb.dist_g == "beckmann" else "GGX")
        if getattr(tb, "ks_view", None) is not None and view_x is not None and k_img is not None:
            n_o = len(tb.ks_view)
            tk = g.node("ShaderNodeTexImage", image=k_img, interpolation="Linear", extension="EXTEND")
            g._set(tk.inputs["Vector"], g.madd(view_x, ((n_o - 1.0) / n_o, 0.0, 0.0), (0.5 / n_o, 0.5, 0.0)))
            col = g.vmath("MULTIPLY", tint, tk.outputs["Color"])
            if scale != 1.0:
                col = g.vmath("SCALE", col, scale=scale)
        else:
            col = g.vmath("MULTIPLY", tint, tuple(float(c) for c in ks))
        g._set(gl.inputs["Color"], col)
        g._set(gl.inputs["Roughness"], float(glossy_node_params(tb.alpha_g, tb.alpha_g)[0]))
        bsdf = g.add_shader(gl.outputs["BSDF"], bsdf)
    if not kd.any():
        return bsdf
    diff = g.node("ShaderNodeBsdfDiffuse")
    g._set(diff.inputs["Color"], g.vmath("MULTIPLY", tint, tuple(float(c) for c in kd)))
    return g.add_shader(diff.outputs["BSDF"], bsdf)


