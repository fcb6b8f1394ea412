"""SVM node-group path of the scratch SV-BRDF (GPU / EEVEE-safe, no OSL): Raymond et al. 2016 eqs. 2, 4, 7.

Same model as ``osl/scratch_svbrdf.py`` with these differences (measured in
``bench/scratch_svm_vs_osl.py`` and ``tests/test_scratch_svm.py``):

- α_k is the *binary* indicator [F1]_d at the shading point (SVM has no ray differentials);
  pixel sampling averages it, so images converge to the same footprint average, with more
  noise at a distance where the OSL path filters α over the footprint;
- every lobe of a slice is summed (SVM cannot hash-pick a closure without a mix tree), so the
  cost grows with K; layers are still hash-picked (probability α_k / ᾱ), so cost does not grow
  with N beyond one Voronoi node per layer;
- lobe parameters come from packed Non-Color float images (one row per φo slice, one column
  per lobe) read with Closest interpolation; the φo slice is picked stochastically between the
  two nearest rows, as in OSL; jittered (box) lobes share one tilt offset per sample (the OSL
  path jitters only the picked lobe: the same expectation);
- tabulated-tilt lobes (``precompute.scratch.lobe_table``, the default) are one Glossy node: the bin is
  found by a binary search of log2 M Closest lookups in a packed CDF image (M a power of two), the
  aim inside the bin with the same random number, weights from a second image; dense scratches:
  image means equal to the OSL table lobes within noise (0.2-0.4 %).
"""
from __future__ import annotations

import math

import bpy
import numpy as np

from ..precompute.cycles.glossy import glossy_node_params

_PI = math.pi
#: custom property marking the table lobe's Glossy node
TABLE_GLOSSY = "scratch_table_glossy"
#: custom property "<twin>/<kind>/<k>" on the Math node holding layer k's rotation / offset constant (input 1)
LAYER_CONST = "scratch_layer_const"


def set_layer_constants(tree, theta_k, xi_k, twin: str = "svm") -> int:
    """Write new layer rotations Θ_k and offsets ξ_k (eq. 7) into the Math nodes ``build`` tagged for ``twin``
    (same layer count); returns how many constants were written."""
    values = {}
    for k in range(len(theta_k)):
        c, s_ = math.cos(theta_k[k]), math.sin(theta_k[k])
        values.update({f"{twin}/c/{k}": c, f"{twin}/s/{k}": s_, f"{twin}/ms/{k}": -s_,
                       f"{twin}/xi0/{k}": float(xi_k[k][0]), f"{twin}/xi1/{k}": float(xi_k[k][1]),
                       f"{twin}/theta/{k}": float(theta_k[k])})
    n = 0
    for node in tree.nodes:
        tag = node.get(LAYER_CONST)
        if tag is not None and tag in values:
            node.inputs[1].default_value = values[tag]
            n += 1
    return n


class _G:
    """Tiny node-building helper: math on sockets or constants, auto-laid-out left to right."""

    def __init__(self, tree):
        self.tree = tree
        self.n = 0

    def node(self, kind, **props):
        node = self.tree.nodes.new(kind)
        for k, v in props.items():
            setattr(node, k, v)
        node.location = (200 * (self.n // 40), -60 * (self.n % 40))
        self.n += 1
        return node

    def _set(self, socket, value):
        if isinstance(value, bpy.types.NodeSocket):
            self.tree.links.new(value, socket)
        else:
            socket.default_value = value

    def math(self, op, a, b=0.0, c=None):
        m = self.node("ShaderNodeMath", operation=op)
        self._set(m.inputs[0], a)
        self._set(m.inputs[1], b)
        if c is not None:
            self._set(m.inputs[2], c)
        return m.outputs[0]

    def vmath(self, op, a, b=None, scale=None):
        m = self.node("ShaderNodeVectorMath", operation=op)
        self._set(m.inputs[0], a)
        if b is not None:
            self._set(m.inputs[1], b)
        if scale is not None:
            self._set(m.inputs["Scale"], scale)
        return m.outputs["Value"] if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE") else m.outputs["Vector"]

    def combine(self, x, y, z=0.0):
        c = self.node("ShaderNodeCombineXYZ")
        for s, v in zip(c.inputs, (x, y, z)):
            self._set(s, v)
        return c.outputs[0]

    def separate(self, v):
        s = self.node("ShaderNodeSeparateXYZ")
        self._set(s.inputs[0], v)
        return s.outputs

    def add_shader(self, a, b):
        if a is None:
            return b
        m = self.node("ShaderNodeAddShader")
        self.tree.links.new(a, m.inputs[0])
        self.tree.links.new(b, m.inputs[1])
        return m.outputs[0]


def lobe_images(name: str, entry: dict, alpha_x: float) -> tuple[bpy.types.Image, bpy.types.Image]:
    """Packed Non-Color float images of a lobe table: W (RGB weights, tilt jitter) and P (tilt, roughness,
    anisotropy, γ); alpha is "channel packed" (a data channel, never multiplied into the colour).

    Rows = φo slices (row 0 at the bottom = slice 0), columns = lobes.  Glossy parameters from
    ``precompute.cycles.glossy.glossy_node_params``: α_u = alpha_x along the scratch, α_v = the lobe width.
    """
    w = np.asarray(entry["weights"], np.float32)             # [S, K, 3]
    S, K = w.shape[:2]
    ay = np.maximum(np.asarray(entry["widths"], np.float64), alpha_x)
    rough, aniso = glossy_node_params(np.full_like(ay, alpha_x), np.minimum(ay, 1.0))  # Cycles clamps alpha to 1
    p = np.stack([np.asarray(entry["tilts"]), rough, aniso, np.asarray(entry["gamma"])], -1).astype(np.float32)
    jit = np.asarray(entry.get("jitters", np.zeros((S, K))), np.float32)[..., None]
    return _data_image(f"{name}.W", np.concatenate([w, jit], -1)), _data_image(f"{name}.P", p)


def build(tree: bpy.types.NodeTree, lobe_data: dict, layers, theta_k, xi_k, tint=(1, 1, 1), base_socket=None,
          name: str = "scratch", controls: dict | None = None, twin: str = "svm") -> bpy.types.NodeSocket:
    """Add the scratch SV-BRDF to ``tree``; returns the output closure socket (eq. 4).

    ``controls``: optional output sockets {"length", "width", "density", "tint"} that replace the
    compiled-in constants ``layers.length`` (l), ``layers.width`` (w), ``layers.density`` (d, eq. 7) and
    ``tint`` (the live-editable, animatable values of ``scratch_addon.live``).  Unlinked, Cycles folds
    them back into constants (measured: bench/live_update.py --cost)."""
    g = _G(tree)
    controls = controls or {}
    length = controls.get("length", None)
    width = controls.get("width", None)
    tint = controls.get("tint", tint)
    geo = g.node("ShaderNodeNewGeometry")
    tan = g.node("ShaderNodeTangent", direction_type="UV_MAP")
    uvn = g.node("ShaderNodeUVMap")
    N = geo.outputs["Normal"]
    wo = geo.outputs["Incoming"]  # towards the viewer
    # t = normalize(T - (T.N) N), b = N x t
    T = tan.outputs["Tangent"]
    t = g.vmath("NORMALIZE", g.vmath("SUBTRACT", T, g.vmath("SCALE", N, scale=g.vmath("DOT_PRODUCT", T, N))))
    b = g.vmath("CROSS_PRODUCT", N, t)
    # per-sample random numbers (P jitters per sample, as in the OSL path)
    def noise(k):
        wn = g.node("ShaderNodeTexWhiteNoise", noise_dimensions="4D")
        g._set(wn.inputs["Vector"], geo.outputs["Position"])
        g._set(wn.inputs["W"], g.math("ADD", g.vmath("DOT_PRODUCT", wo, k), 17.0 * k[0]))
        return wn.outputs["Value"]

    h_slice, h_layer = noise((12.9898, 78.233, 37.719)), noise((93.989, 67.345, 24.113))
    # tilt jitter (stochastic box lobes): one offset in [-1, 1) per sample, scaled per lobe
    jittered = "cdf" not in lobe_data and any(e is not None and np.any(np.asarray(e.get("jitters", 0.0)) > 0)
                                              for e in (lobe_data["m"], lobe_data["0"]))
    h_jit = g.math("SUBTRACT", g.math("MULTIPLY", noise((57.193, 29.917, 64.433)), 2.0), 1.0) if jittered else None

    if layers is None:
        theta_sel = 0.0
        alpha_sum = 1.0
    else:
        uv = uvn.outputs["UV"]
        uvs = g.separate(uv)
        alphas, acc, accs = [], None, []
        inv_l = 1.0 / layers.length if length is None else g.math("DIVIDE", 1.0, length)
        inv_w = 1.0 / layers.width if width is None else g.math("DIVIDE", 1.0, width)
        dens = controls.get("density", None)
        threshold = float(layers.density) + 1e-7 if dens is None else g.math("ADD", dens, 1e-7)
        def tagged(kind, k, socket):   # a per-layer constant (input 1 of the node): set_layer_constants
            socket.node[LAYER_CONST] = f"{twin}/{kind}/{k}"
            return socket

        for k in range(layers.n_layers):
            c, s_ = math.cos(theta_k[k]), math.sin(theta_k[k])
            ru = g.math("ADD", tagged("c", k, g.math("MULTIPLY", uvs[0], c)), tagged("s", k, g.math("MULTIPLY", uvs[1], s_)))
            rv = g.math("ADD", tagged("ms", k, g.math("MULTIPLY", uvs[0], -s_)), tagged("c", k, g.math("MULTIPLY", uvs[1], c)))
            yx = tagged("xi0", k, g.math("ADD", g.math("MULTIPLY", ru, inv_l), float(xi_k[k][0])))
            yy = tagged("xi1", k, g.math("ADD", g.math("MULTIPLY", rv, inv_w), float(xi_k[k][1])))
            vor = g.node("ShaderNodeTexVoronoi", voronoi_dimensions="2D", feature="F1", distance="EUCLIDEAN")
            vor.inputs["Scale"].default_value = 1.0
            vor.inputs["Randomness"].default_value = 1.0
            g._set(vor.inputs["Vector"], g.combine(yx, yy))
            a = g.math("LESS_THAN", vor.outputs["Distance"], threshold)  # [F1]_d, eq. 7
            alphas.append(a)
            acc = a if acc is None else g.math("ADD", acc, a)
            accs.append(acc)
        alpha_sum = acc
        target = g.math("MULTIPLY", h_layer, alpha_sum)
        theta_sel, prev = None, None
        for k, acc_k in enumerate(accs):  # layer k is picked when acc_{k-1} <= target < acc_k
            below = g.math("LESS_THAN", target, acc_k)
            sel = below if prev is None else g.math("SUBTRACT", below, prev)
            prev = below
            term = tagged("theta", k, g.math("MULTIPLY", sel, float(theta_k[k])))
            theta_sel = term if theta_sel is None else g.math("ADD", theta_sel, term)
    # scratch frame of the picked layer
    u = g.vmath("ADD", g.vmath("SCALE", t, scale=g.math("COSINE", theta_sel)), g.vmath("SCALE", b, scale=g.math("SINE", theta_sel)))
    v = g.vmath("CROSS_PRODUCT", N, u)
    theta_o = g.math("ARCSINE", g.math("MINIMUM", g.math("MAXIMUM", g.vmath("DOT_PRODUCT", wo, u), -1.0), 1.0))
    phi_o = g.math("ARCTAN2", g.vmath("DOT_PRODUCT", wo, v), g.vmath("DOT_PRODUCT", wo, N))
    x = g.math("MULTIPLY", g.math("ABSOLUTE", theta_o), 2.0 / _PI)
    table = "cdf" in lobe_data
    S = lobe_data["cdf"].shape[0] if table else lobe_data["m"]["weights"].shape[0]
    xs = g.math("SUBTRACT", g.math("MULTIPLY", g.math("ADD", phi_o, _PI / 2), S / _PI), 0.5)
    s0 = g.math("FLOOR", xs)
    s = g.math("ADD", s0, g.math("LESS_THAN", h_slice, g.math("SUBTRACT", xs, s0)))
    s = g.math("MINIMUM", g.math("MAXIMUM", s, 0.0), S - 1.0)
    row = g.math("DIVIDE", g.math("ADD", s, 0.5), float(S))

    if table:
        scratch = _table_lobe(g, lobe_data, name, row, s, S, x, N, u, v, noise((39.346, 11.135, 83.155)), tint)
    else:
        scratch = _fitted_lobes(g, lobe_data, name, row, x, N, u, v, h_jit, jittered, tint)
    if layers is None:
        return scratch
    # eq. 4 with one picked layer: min(ᾱ, 1) * ρ_k + max(1 - ᾱ, 0) * ρ_b  ==  Mix(fac = min(ᾱ, 1), base, ρ_k)
    mixs = g.node("ShaderNodeMixShader")
    g._set(mixs.inputs["Fac"], g.math("MINIMUM", alpha_sum, 1.0))
    if base_socket is not None:
        tree.links.new(base_socket, mixs.inputs[1])
    tree.links.new(scratch, mixs.inputs[2])
    return mixs.outputs[0]


def _tinted(g, colour, tint):
    """``colour`` times the scratch tint (a constant RGB, skipped when white, or a Color socket)."""
    if isinstance(tint, bpy.types.NodeSocket):
        return g.vmath("MULTIPLY", colour, tint)
    if tuple(tint)[:3] != (1.0, 1.0, 1.0):
        return g.vmath("MULTIPLY", colour, tuple(float(c) for c in tuple(tint)[:3]))
    return colour


def _fitted_lobes(g, lobe_data, name, row, x, N, u, v, h_jit, jittered, tint):
    """Every fitted lobe of the slice in ``row`` as a Glossy node (eq. 2 per lobe); returns their sum."""
    scratch = None
    for key, use_r_m in (("m", True), ("0", False)):
        entry = lobe_data[key]
        if entry is None:
            continue
        lossless = lobe_data["0"] is None
        img_w, img_p = lobe_images(f"{name}.{key}", entry, lobe_data["alpha_x"])
        K = entry["weights"].shape[1]
        for j in range(K):
            if not np.any(entry["weights"][:, j] > 0):
                continue
            coord = g.combine((j + 0.5) / K, row)
            tw = g.node("ShaderNodeTexImage", image=img_w, interpolation="Closest", extension="EXTEND")
            tp = g.node("ShaderNodeTexImage", image=img_p, interpolation="Closest", extension="EXTEND")
            g._set(tw.inputs["Vector"], coord)
            g._set(tp.inputs["Vector"], coord)
            tilt, rough, aniso = g.separate(tp.outputs["Color"])
            gamma = tp.outputs["Alpha"]
            if jittered:
                tilt = g.math("ADD", tilt, g.math("MULTIPLY", tw.outputs["Alpha"], h_jit))
            n_l = g.vmath("NORMALIZE", g.vmath("ADD", g.vmath("SCALE", N, scale=g.math("COSINE", tilt)),
                                              g.vmath("SCALE", v, scale=g.math("SINE", tilt))))
            colour = tw.outputs["Color"]
            if not lossless:  # eq. 2 per lobe: R_γ(θo) for ρm lobes, 1 - R_γ for ρ0 lobes
                r = g.math("POWER", x, gamma)
                f = r if use_r_m else g.math("SUBTRACT", 1.0, r)
                colour = g.vmath("SCALE", colour, scale=f)
            colour = _tinted(g, colour, tint)
            glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
            g._set(glossy.inputs["Color"], colour)
            g._set(glossy.inputs["Roughness"], rough)
            g._set(glossy.inputs["Anisotropy"], aniso)
            g._set(glossy.inputs["Normal"], n_l)
            g._set(glossy.inputs["Tangent"], u)
            scratch = g.add_shader(scratch, glossy.outputs[0])
    return scratch


def _data_image(img_name: str, arr: np.ndarray) -> bpy.types.Image:
    """A packed Non-Color float RGBA image holding ``arr`` [rows, cols, 4] (row 0 at the bottom)."""
    rows, cols = arr.shape[:2]
    img = bpy.data.images.get(img_name)
    if img is not None and tuple(img.size) != (cols, rows):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(img_name, width=cols, height=rows, alpha=True, float_buffer=True, is_data=True)
    img.colorspace_settings.is_data = True
    img.alpha_mode = "CHANNEL_PACKED"
    img.pixels.foreach_set(np.ascontiguousarray(arr, np.float32).reshape(-1))
    img.file_format = "OPEN_EXR"
    img.pack()
    return img


def table_images(name: str, lobe_data: dict) -> tuple[bpy.types.Image, bpy.types.Image]:
    """Packed images of tabulated-tilt lobes (``precompute.scratch.lobes.table_lobes``), rows = φo slices:
    C [S, M+1] (R = the bin-picking CDF, G = its total P) and B [S, M] (RGB = w^0_b, A = w^m_b; lossless:
    RGB = 0) plus, in C's B channel of the first M columns, γ of each bin."""
    cdf = np.asarray(lobe_data["cdf"], np.float64)
    S, M1 = cdf.shape
    M = M1 - 1
    c = np.zeros((S, M1, 4))
    c[..., 0] = cdf
    c[..., 1] = np.asarray(lobe_data["total"], np.float64)[:, None]
    c[:, :M, 2] = lobe_data["gamma"]
    b = np.zeros((S, M, 4))
    b[..., 3] = lobe_data["w_m"]
    if lobe_data.get("w_0") is not None:
        b[..., :3] = lobe_data["w_0"]
    return _data_image(f"{name}.C", c), _data_image(f"{name}.B", b)


def _table_lobe(g, lobe_data, name, row, s, S, x, N, u, v, h, tint):
    """One tabulated-tilt lobe (``precompute.scratch.lobe_table``), as the OSL ``table_lobes`` with TK = 1:
    binary search of h in the slice's CDF (log2 M image lookups), aim φi inside the picked bin, a
    narrow GGX Glossy tilted to mirror the slice's φo into φi, colour W_b(θo) P / p_b (eq. 2)."""
    img_c, img_b = table_images(name, lobe_data)
    M = lobe_data["cdf"].shape[1] - 1
    if M & (M - 1):
        raise ValueError(f"table lobes need a power-of-two table size M; got {M}")
    lossless = lobe_data.get("w_0") is None

    def fetch(img, col, n_cols):
        tex = g.node("ShaderNodeTexImage", image=img, interpolation="Closest", extension="EXTEND")
        g._set(tex.inputs["Vector"], g.combine(g.math("DIVIDE", g.math("ADD", col, 0.5), float(n_cols)), row))
        return tex

    lo, hi = 0.0, float(M)
    for _ in range(int(math.log2(M))):  # hi - lo halves every step: M = 2^L
        mid = g.math("FLOOR", g.math("MULTIPLY", g.math("ADD", lo, hi), 0.5))
        # cdf[mid] <= h (the R channel: a Color socket into a Math node would be converted to grey)
        go = g.math("LESS_THAN", g.separate(fetch(img_c, mid, M + 1).outputs["Color"])[0], g.math("ADD", h, 1e-12))
        lo = g.math("ADD", lo, g.math("MULTIPLY", go, g.math("SUBTRACT", mid, lo)))
        hi = g.math("ADD", hi, g.math("MULTIPLY", g.math("SUBTRACT", 1.0, go), g.math("SUBTRACT", mid, hi)))
    c0 = fetch(img_c, lo, M + 1)
    c1 = fetch(img_c, g.math("ADD", lo, 1.0), M + 1)
    c0r, P, gamma = g.separate(c0.outputs["Color"])
    c1r = g.separate(c1.outputs["Color"])[0]
    fr = g.math("MINIMUM", g.math("MAXIMUM", g.math("DIVIDE", g.math("SUBTRACT", h, c0r),
                                                    g.math("MAXIMUM", g.math("SUBTRACT", c1r, c0r), 1e-12)), 0.0), 1.0)
    phi_i = g.math("ADD", g.math("MULTIPLY", g.math("ADD", lo, fr), _PI / M), -_PI / 2)
    phi_s = g.math("ADD", g.math("MULTIPLY", s, _PI / S), -_PI / 2 + 0.5 * _PI / S)
    tilt = g.math("MULTIPLY", g.math("ADD", phi_i, phi_s), 0.5)
    n_l = g.vmath("NORMALIZE", g.vmath("ADD", g.vmath("SCALE", N, scale=g.math("COSINE", tilt)),
                                      g.vmath("SCALE", v, scale=g.math("SINE", tilt))))
    bin_ = fetch(img_b, lo, M)
    wm = bin_.outputs["Alpha"]
    if lossless:
        colour = g.combine(P, P, P)            # W_b P / p_b with W_b = p_b = w^m_b
    else:
        w0 = bin_.outputs["Color"]
        r = g.math("POWER", x, gamma)
        W = g.vmath("ADD", g.vmath("SCALE", w0, scale=g.math("SUBTRACT", 1.0, r)),
                    g.combine(*(g.math("MULTIPLY", r, wm),) * 3))
        w0s = g.separate(w0)
        p = g.math("ADD", wm, g.math("MULTIPLY", g.math("ADD", g.math("ADD", w0s[0], w0s[1]), w0s[2]), 1.0 / 3.0))
        colour = g.vmath("SCALE", W, scale=g.math("DIVIDE", P, g.math("MAXIMUM", p, 1e-30)))
    colour = _tinted(g, colour, tint)
    # Glossy roughness mapping (see lobe_images): alpha_y below alpha_x -> an isotropic lobe of alpha_x
    ax = float(lobe_data["alpha_x"])
    ay = max(float(lobe_data["alpha_y"]), ax)
    glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
    glossy[TABLE_GLOSSY] = True   # its roughness follows the table (scratch_addon.scratch_material.apply_tables)
    g._set(glossy.inputs["Color"], colour)
    rough, aniso = glossy_node_params(ax, min(ay, 1.0))
    g._set(glossy.inputs["Roughness"], rough)
    g._set(glossy.inputs["Anisotropy"], aniso)
    g._set(glossy.inputs["Normal"], n_l)
    g._set(glossy.inputs["Tangent"], u)
    return glossy.outputs[0]
