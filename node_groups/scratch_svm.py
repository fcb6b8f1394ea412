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
          name: str = "scratch") -> bpy.types.NodeSocket:
    """Add the scratch SV-BRDF to ``tree``; returns the output closure socket (eq. 4)."""
    g = _G(tree)
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
        for k in range(layers.n_layers):
            c, s_ = math.cos(theta_k[k]), math.sin(theta_k[k])
            yx = g.math("ADD", g.math("MULTIPLY", g.math("ADD", g.math("MULTIPLY", uvs[0], c), g.math("MULTIPLY", uvs[1], s_)),
                                        1.0 / layers.length), float(xi_k[k][0]))
            yy = g.math("ADD", g.math("MULTIPLY", g.math("ADD", g.math("MULTIPLY", uvs[0], -s_), g.math("MULTIPLY", uvs[1], c)),
                                        1.0 / layers.width), float(xi_k[k][1]))
            vor = g.node("ShaderNodeTexVoronoi", voronoi_dimensions="2D", feature="F1", distance="EUCLIDEAN")
            vor.inputs["Scale"].default_value = 1.0
            vor.inputs["Randomness"].default_value = 1.0
            g._set(vor.inputs["Vector"], g.combine(yx, yy))
            a = g.math("LESS_THAN", vor.outputs["Distance"], float(layers.density) + 1e-7)  # [F1]_d, eq. 7
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
            term = g.math("MULTIPLY", sel, float(theta_k[k]))
            theta_sel = term if theta_sel is None else g.math("ADD", theta_sel, term)
    # scratch frame of the picked layer
    u = g.vmath("ADD", g.vmath("SCALE", t, scale=g.math("COSINE", theta_sel)), g.vmath("SCALE", b, scale=g.math("SINE", theta_sel)))
    v = g.vmath("CROSS_PRODUCT", N, u)
    theta_o = g.math("ARCSINE", g.math("MINIMUM", g.math("MAXIMUM", g.vmath("DOT_PRODUCT", wo, u), -1.0), 1.0))
    phi_o = g.math("ARCTAN2", g.vmath("DOT_PRODUCT", wo, v), g.vmath("DOT_PRODUCT", wo, N))
    table = "cdf" in lobe_data
    if table:
        scratch = _table_lobe(g, lobe_data, name, phi_o, wo, h_slice, N, u, v, noise((39.346, 11.135, 83.155)), tint)
    else:
        x = g.math("MULTIPLY", g.math("ABSOLUTE", theta_o), 2.0 / _PI)
        S = lobe_data["m"]["weights"].shape[0]
        xs = g.math("SUBTRACT", g.math("MULTIPLY", g.math("ADD", phi_o, _PI / 2), S / _PI), 0.5)
        s0 = g.math("FLOOR", xs)
        s = g.math("ADD", s0, g.math("LESS_THAN", h_slice, g.math("SUBTRACT", xs, s0)))
        s = g.math("MINIMUM", g.math("MAXIMUM", s, 0.0), S - 1.0)
        row = g.math("DIVIDE", g.math("ADD", s, 0.5), float(S))
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
            if tuple(tint) != (1.0, 1.0, 1.0):
                colour = g.vmath("MULTIPLY", colour, tuple(float(c) for c in tint))
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


def table_images(name: str, lobe_data: dict) -> dict:
    """Packed Non-Color float images of tabulated-tilt lobes (``precompute.scratch.lobes.table_lobes``):

    - ``N`` [1, G]: per uniform φo cell, R = its node interval k, G = φ_k, B = φ_k+1 (radians);
    - ``C`` [S, M+1] (rows = φo nodes): R = the bin-picking CDF, G = its total P, B = the aim code of the bin
      (exit centroid + 2 for even bounces; first M columns), A = the node's φ;
    - lossy only: ``Y`` [S, K M / y_group] RGB = the θo coefficients (column g K + k for bin group g,
      function k) and ``B`` [K, NT] RGB = the θo basis (read with Linear interpolation along v).
    """
    cdf = np.asarray(lobe_data["cdf"], np.float64)
    S, M1 = cdf.shape
    M = M1 - 1
    phi = np.asarray(lobe_data["phi"], np.float64)
    cell = np.asarray(lobe_data["cell"], np.int64)
    n = np.zeros((1, cell.size, 4))
    n[0, :, 0], n[0, :, 1], n[0, :, 2] = cell, phi[cell], phi[cell + 1]
    c = np.zeros((S, M1, 4))
    c[..., 0] = cdf
    c[..., 1] = np.asarray(lobe_data["total"], np.float64)[:, None]
    c[:, :M, 2] = lobe_data["cen"]
    c[..., 3] = phi[:, None]
    out = {"N": _data_image(f"{name}.N", n), "C": _data_image(f"{name}.C", c)}
    if lobe_data.get("basis") is not None:
        coef = np.asarray(lobe_data["coef"], np.float64)                      # [S, Mg, K, 3]
        y = np.zeros((S, coef.shape[1] * coef.shape[2], 4))
        y[..., :3] = coef.reshape(S, -1, 3)
        basis = np.asarray(lobe_data["basis"], np.float64)                    # [K, NT, 3]
        b = np.zeros(basis.shape[:2] + (4,))
        b[..., :3] = basis
        out.update(Y=_data_image(f"{name}.Y", y), B=_data_image(f"{name}.Btheta", b))
    return out


def _table_lobe(g, lobe_data, name, phi_o, wo, h_slice, N, u, v, h, tint):
    """One tabulated-tilt lobe, as the OSL ``table_lobes`` with TK = 1 (``precompute.scratch.lobes.table_lobes``):
    the φo node picked between the two around φo (a cell image gives the interval), a binary search of h in
    the node's CDF (log2 M image lookups), the aim at the bin's exit centroid moved to the actual view
    (odd bounces mirror-like, even retro-like), a narrow GGX Glossy tilted halfway between φo and the
    exit, colour P Y_b(θo) (Y = 1 lossless, else Σ_k coef B_k(v), v = 1 - sqrt(cos θo))."""
    imgs = table_images(name, lobe_data)
    cdf = lobe_data["cdf"]
    S, M = cdf.shape[0], cdf.shape[1] - 1
    if M & (M - 1):
        raise ValueError(f"table lobes need a power-of-two table size M; got {M}")
    G = int(np.asarray(lobe_data["cell"]).size)
    lossless = lobe_data.get("basis") is None

    def fetch(img, col, n_cols, row, interpolation="Closest"):
        tex = g.node("ShaderNodeTexImage", image=img, interpolation=interpolation, extension="EXTEND")
        g._set(tex.inputs["Vector"], g.combine(g.math("DIVIDE", g.math("ADD", col, 0.5), float(n_cols)), row))
        return tex

    # node interval of phi_o, then one of its two nodes with the linear weight
    cell = g.math("MINIMUM", g.math("MAXIMUM", g.math("FLOOR", g.math("MULTIPLY", g.math("ADD", phi_o, _PI / 2), G / _PI)),
                                     0.0), G - 1.0)
    k, pa, pb = g.separate(fetch(imgs["N"], cell, G, 0.5).outputs["Color"])
    up = g.math("LESS_THAN", g.math("MULTIPLY", h_slice, g.math("SUBTRACT", pb, pa)), g.math("SUBTRACT", phi_o, pa))
    s = g.math("ADD", k, up)
    row = g.math("DIVIDE", g.math("ADD", s, 0.5), float(S))
    lo, hi = 0.0, float(M)
    for _ in range(int(math.log2(M))):  # hi - lo halves every step: M = 2^L
        mid = g.math("FLOOR", g.math("MULTIPLY", g.math("ADD", lo, hi), 0.5))
        # cdf[mid] <= h (the R channel: a Color socket into a Math node would be converted to grey)
        go = g.math("LESS_THAN", g.separate(fetch(imgs["C"], mid, M + 1, row).outputs["Color"])[0], g.math("ADD", h, 1e-12))
        lo = g.math("ADD", lo, g.math("MULTIPLY", go, g.math("SUBTRACT", mid, lo)))
        hi = g.math("ADD", hi, g.math("MULTIPLY", g.math("SUBTRACT", 1.0, go), g.math("SUBTRACT", mid, hi)))
    c0 = fetch(imgs["C"], lo, M + 1, row)
    c1 = fetch(imgs["C"], g.math("ADD", lo, 1.0), M + 1, row)
    c0r, P, code = g.separate(c0.outputs["Color"])
    phi_s = c0.outputs["Alpha"]
    c1r = g.separate(c1.outputs["Color"])[0]
    fr = g.math("MINIMUM", g.math("MAXIMUM", g.math("DIVIDE", g.math("SUBTRACT", h, c0r),
                                                    g.math("MAXIMUM", g.math("SUBTRACT", c1r, c0r), 1e-12)), 0.0), 1.0)
    even = g.math("GREATER_THAN", code, 1.5)
    ce = g.math("SUBTRACT", code, g.math("MULTIPLY", even, 2.0))
    hw = g.math("MINIMUM", ce, g.math("SUBTRACT", 1.0, ce))
    aim = g.math("ADD", g.math("MULTIPLY", g.math("ADD", g.math("ADD", lo, ce),
                                                  g.math("MULTIPLY", g.math("SUBTRACT", g.math("MULTIPLY", fr, 2.0), 1.0), hw)),
                               _PI / M), -_PI / 2)
    # exit: aim + (phi_s - phi_o) for odd bounces, aim - (phi_s - phi_o) for even ones
    d = g.math("MULTIPLY", g.math("SUBTRACT", phi_s, phi_o), g.math("SUBTRACT", 1.0, g.math("MULTIPLY", even, 2.0)))
    tilt = g.math("MULTIPLY", g.math("ADD", g.math("ADD", aim, d), phi_o), 0.5)
    n_l = g.vmath("NORMALIZE", g.vmath("ADD", g.vmath("SCALE", N, scale=g.math("COSINE", tilt)),
                                      g.vmath("SCALE", v, scale=g.math("SINE", tilt))))
    if lossless:
        colour = g.combine(P, P, P)
    else:
        K, NT = lobe_data["basis"].shape[:2]
        yg = int(lobe_data.get("y_group", 1))
        n_cols = lobe_data["coef"].shape[1] * K
        cu = g.vmath("DOT_PRODUCT", wo, u)
        cos_t = g.math("SQRT", g.math("MAXIMUM", g.math("SUBTRACT", 1.0, g.math("MULTIPLY", cu, cu)), 0.0))
        vt = g.math("SUBTRACT", 1.0, g.math("SQRT", cos_t))
        bcol = g.math("MULTIPLY", vt, NT - 1.0)   # linear interpolation between the NT basis samples
        grp = g.math("MULTIPLY", g.math("FLOOR", g.math("DIVIDE", g.math("ADD", lo, 0.5), float(yg))), float(K))
        Y = None
        for j in range(K):
            coef = fetch(imgs["Y"], g.math("ADD", grp, float(j)), n_cols, row).outputs["Color"]
            basis = fetch(imgs["B"], bcol, NT, (j + 0.5) / K, "Linear").outputs["Color"]
            term = g.vmath("MULTIPLY", coef, basis)
            Y = term if Y is None else g.vmath("ADD", Y, term)
        Y = g.vmath("MAXIMUM", Y, (0.0, 0.0, 0.0))
        colour = g.vmath("SCALE", Y, scale=P)
    if tuple(tint) != (1.0, 1.0, 1.0):
        colour = g.vmath("MULTIPLY", colour, tuple(float(c) for c in tint))
    # Glossy roughness mapping (see lobe_images): alpha_y below alpha_x -> an isotropic lobe of alpha_x
    ax = float(lobe_data["alpha_x"])
    ay = max(float(lobe_data["alpha_y"]), ax)
    glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
    g._set(glossy.inputs["Color"], colour)
    rough, aniso = glossy_node_params(ax, min(ay, 1.0))
    g._set(glossy.inputs["Roughness"], rough)
    g._set(glossy.inputs["Anisotropy"], aniso)
    g._set(glossy.inputs["Normal"], n_l)
    g._set(glossy.inputs["Tangent"], u)
    return glossy.outputs[0]
