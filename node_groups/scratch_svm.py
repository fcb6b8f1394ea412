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
  drawn from a packed alias-table image (one Closest lookup), the aim inside the bin with a second
  random number, the colour from one Linear lookup of the pre-summed θo factor; dense scratches:
  image means equal to the OSL table lobes within noise (0.2-0.4 %).

Cost (``bench/scratch_cost.py``, whole frame, per sample, against the SVM anisotropic Glossy): Cycles' SVM
runs every node that feeds the output, except the nodes that feed only one input of a Mix Shader whose
factor is linked: those are skipped when the factor selects the other input (``SVMCompiler::
generate_multi_closure``: NODE_JUMP_IF_ZERO / NODE_JUMP_IF_ONE, taken when the factor is exactly 0 / 1).  So the
graph keeps the per-sample work behind Mix Shaders: the scratch closure and its lookups behind min(ᾱ, 1) (not run
where no layer covers the point), the whole layer system behind the cull switch [d >= CULL_DENSITY] (a culled
material costs its base).  What a node costs (``bench/scratch_svm_profile.py``, callgrind instructions per shading
point; the baseline's whole sample is ~4,760): every node is one SVM instruction (~47) plus one more (~18) for each
unlinked input it reads, used or not (a Math node reads three: ~65 with both operands linked, ~83 with a constant
operand or a unary op); a 2D Voronoi ~770 (its 9 hashed cells), a Closest image lookup ~170, a Mapping node ~350
(it turns its Euler rotation into a matrix per sample), a 4D White Noise ~290, a Vector Rotate ~260 (~280 Z-axis).
So the layer coordinates of eq. 7 are each layer Voronoi's own texture mapping (``layer_feature_distance``: a
matrix Cycles folds at sync, ~60), and a layer of the picked-layer graph costs its Voronoi plus ~150 for [F1 < d]
and the coverage sum; the layer pick, its hash and the frame rotation add ~680 per sample behind the Mix Shader.  The
floor of any graph that tests each
layer's coverage with a Voronoi node (``bench/scratch_svm_profile`` "floor" rows: base, 4 Voronoi, coverage, one
plain Glossy behind the Mix Shader) is 9,010 instructions per sample at fig1c's 4 layers, 1.89x the baseline (2.04x
with the layer pick and frame rotation): the 1.3x goal at 4 layers is out of reach on SVM; the table lobe adds
~0.6x on top (three 2D lookups with their Combine XYZ, the φo node pick, the alias draw, the tilt rotation).
Constants that depend only on the tables live in the images (the C image holds the tilt's affine terms: two Math
nodes)."""
from __future__ import annotations

import math

import bpy
import numpy as np

from ..precompute.cycles.glossy import glossy_node_params
from ..precompute.scratch.layers import ALPHA_CULL

_PI = math.pi
#: custom property marking the table lobe's Glossy node
TABLE_GLOSSY = "scratch_table_glossy"
#: tag of the Math node mapping a φo node index to its table row ((k + 0.5) / S): an in-place table update with
#: another node count S rewrites its constants (``scratch_addon.scratch_material.apply_tables``)
TABLE_ROWS = "scratch_table_rows"
#: custom property "<twin>/<kind>/<k>" on the node holding layer k's rotation / offset constants
LAYER_CONST = "scratch_layer_const"
#: custom property (Θ_k, ξx, ξy) of eq. 7 on a layer's Voronoi node (``layer_feature_distance``): ``set_layer_size``
#: rebuilds its texture mapping for a new scratch length / width from it
LAYER_XFORM = "scratch_layer_xform"
#: layers are culled (the paper's α_k < ALPHA_CULL = 1e-6, §6.1, ``precompute.scratch.layers.ALPHA_CULL``) below this
#: density: the mean coverage of [F1 <= d] is c̄(d) = π d² for small d (one feature point per unit cell; exact as
#: d -> 0, 0.2 % high at d = 0.1 against the quadrature of ``precompute.scratch.layers.coverage_table``), so c̄(d) < 1e-6 for
#: d < sqrt(1e-6 / π) = 5.6e-4.  The SVM path has no footprint: it culls wherever the OSL path's far field would.
CULL_DENSITY = math.sqrt(ALPHA_CULL / math.pi)
#: name prefix of the table lobe's images (``table_images``: "<prefix><role> <content hash>")
TABLE_IMAGE_PREFIX = "Scratch table "


def set_layer_constants(tree, theta_k, xi_k, twin: str = "svm") -> int:
    """Write new layer rotations Θ_k and offsets ξ_k (eq. 7) into the nodes ``build`` tagged for ``twin``
    (same layer count): each layer's Voronoi texture mapping (``layer_feature_distance``; the Mapping node and
    its offset nodes of materials built before it), the layer-pick constants and a race's parameters image;
    returns how many nodes were written."""
    n = 0
    race = {}
    for node in tree_nodes(tree):
        for tag in (node.get(LAYER_CONST) or "").split(";"):
            parts = tag.split("/")
            if len(parts) != 3 or parts[0] != twin or int(parts[2]) >= len(theta_k):
                continue
            kind, k = parts[1], int(parts[2])
            theta, xi = float(theta_k[k]), (float(xi_k[k][0]), float(xi_k[k][1]))
            if kind == "race_par":
                if "par" not in race:
                    race["par"] = race_params_image(theta_k, xi_k)
                node.image = race["par"]
            elif kind in ("race_rot", "race_off"):   # race positions built before the parameters image
                if "images" not in race:
                    race["images"] = race_images(theta_k, xi_k)
                node.image = race["images"][1 if kind == "race_rot" else 2]
            elif kind == "vor":
                node[LAYER_XFORM] = (theta, xi[0], xi[1])
                set_texture_mapping(node, theta, xi, *tuple(node.texture_mapping.scale)[:2])
            elif kind == "map":   # materials built before layer_feature_distance
                _set_mapping(node, theta, xi)
            elif kind in _LOC_FACTORS:
                node.inputs[1].default_value = _LOC_FACTORS[kind](math.cos(theta), math.sin(theta), xi)
            elif kind == "theta2":
                node.inputs[2].default_value = theta
            elif kind == "theta3":
                node.inputs[3].default_value = theta
            elif kind == "angle":
                node.inputs["Angle"].default_value = theta
            else:
                continue
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
    return _data_image("Scratch lobes W", np.concatenate([w, jit], -1)), _data_image("Scratch lobes P", p)


def build(tree: bpy.types.NodeTree, lobe_data: dict, layers, theta_k, xi_k, tint=(1, 1, 1), base_socket=None,
          name: str = "scratch", cost_off: int = 0, controls: dict | None = None,
          twin: str = "svm") -> bpy.types.NodeSocket:
    """Add the scratch SV-BRDF to ``tree``; returns the output closure socket (eq. 4).

    ``controls``: optional output sockets {"length", "width", "density", "tint"} that replace the
    compiled-in constants ``layers.length`` (l), ``layers.width`` (w), ``layers.density`` (d, eq. 7) and
    ``tint`` (the live-editable, animatable values of ``scratch_addon.live``).  ``twin`` names this copy for
    ``set_layer_constants`` ("svm" or "eevee").

    ``cost_off`` (bench/scratch_cost.py only) switches stages off to time them, as the OSL ``COST_OFF``:
    bit 1 the layer Voronoi (a grid of cell centres instead), 4 the CDF search (bin straight from h),
    8 the closure set-up (untilted white lobe), 16 the layer race (``races``: the picked-layer graph instead)."""
    g = _G(tree)
    controls = controls or {}
    tint = controls.get("tint", tint)
    geo = g.node("ShaderNodeNewGeometry")
    tan = g.node("ShaderNodeTangent", direction_type="UV_MAP")
    uvn = g.node("ShaderNodeUVMap")
    N = geo.outputs["Normal"]
    wo = geo.outputs["Incoming"]  # towards the viewer
    # t: Cycles' Tangent node is already orthonormalised against the shading normal (cross(N, cross(T, N)))
    t = tan.outputs["Tangent"]
    table = "cdf" in lobe_data

    # per-sample random numbers: P jitters per sample (pixel filter, lens, bounce), so a hash of P alone is a new
    # number per sample (the OSL path also hashes the view direction: one Vector Math node more per shading point
    # here, ~70 instructions, bench/scratch_svm_profile); the slice, layer and lobe numbers are the three channels
    # of one 3D hash, a further number (the aim inside a table bin, the box jitter) a 4D hash with a constant W
    def noise(offset, channels=False):
        wn = g.node("ShaderNodeTexWhiteNoise", noise_dimensions="4D" if offset else "3D")
        g._set(wn.inputs["Vector"], geo.outputs["Position"])
        if offset:
            wn.inputs["W"].default_value = float(offset)
        return g.separate(wn.outputs["Color"]) if channels else wn.outputs["Value"]

    h_slice, h_layer, h_lobe = noise(0.0, channels=True)
    # the aim inside a table bin: its own hash for dense scratches; with layers, the residual of the layer
    # pick (fract(h_layer ᾱ): uniform and independent of the picked layer, ᾱ being an integer) saves a node
    h_frac = noise(17.0) if table and layers is None else None
    # tilt jitter (stochastic box lobes): one offset in [-1, 1) per sample, scaled per lobe
    jittered = not table and any(e is not None and np.any(np.asarray(e.get("jitters", 0.0)) > 0)
                                 for e in (lobe_data["m"], lobe_data["0"]))
    h_jit = g.math("MULTIPLY_ADD", noise(43.0), 2.0, -1.0) if jittered else None

    if twin == "svm" and not cost_off & 16 and races(lobe_data, layers):   # the Cycles twin: layers in a nested Mix Shader race (``_layer_race``)
        # the aim inside a table bin: the residual of the race's row pick, fract(h_layer P) (uniform, independent of
        # the row floor(h_layer P) and so of the picked layer; 13 bits at P = 2048) instead of a second hash
        n_orders = float(len(race_orders(layers.n_layers)))
        h_frac = g.math("FRACT", g.math("MULTIPLY", h_layer, n_orders))
        race_args = dict(geo=geo, N=N, wo=wo, t=t, uv=uvn.outputs["UV"], h_slice=h_slice, h_layer=h_layer,
                         h_lobe=h_lobe, h_frac=h_frac)
        return _cull_gate(g, _layer_race(g, lobe_data, name, layers, theta_k, xi_k, tint, base_socket, controls,
                                         cost_off, twin, **race_args), layers, controls, base_socket)
    if layers is None:
        theta_sel = None
        alpha_sum = 1.0
    else:
        uv = uvn.outputs["UV"]
        # l and w are the built values; live edits rewrite the nodes' texture mappings (``set_layer_size``)
        size = (float(layers.length), float(layers.width))
        dens = controls.get("density", None)
        threshold = float(layers.density) + 1e-7 if dens is None else g.math("ADD", dens, 1e-7)
        accs = layer_coverage(g, uv, theta_k, xi_k, size, threshold, twin, cost_off)
        alpha_sum = accs[-1]
        # layer k is picked when acc_{k-1} <= target < acc_k (probability α_k / ᾱ): from the last layer
        # back, Θ = Θ_k wherever target < acc_k (one Less Than and one Mix per layer)
        target = g.math("MULTIPLY", h_layer, alpha_sum)
        if table:
            h_frac = g.math("FRACT", target)
        theta_sel = picked_angle(g, target, accs, theta_k, twin)
    # scratch frame of the picked layer: u = cos Θ t + sin Θ (N x t) = t rotated about N by Θ, v = N x u
    if theta_sel is None:
        u = t
    else:
        rot = g.node("ShaderNodeVectorRotate", rotation_type="AXIS_ANGLE")
        g._set(rot.inputs["Vector"], t)
        g._set(rot.inputs["Axis"], N)
        g._set(rot.inputs["Angle"], theta_sel)
        if layers.n_layers == 1:
            rot[LAYER_CONST] = f"{twin}/angle/0"
        u = rot.outputs["Vector"]
    v = g.vmath("CROSS_PRODUCT", N, u)
    # φo = atan2(wo.v, wo.N)
    phi_o = g.math("ARCTAN2", g.vmath("DOT_PRODUCT", wo, v), g.vmath("DOT_PRODUCT", wo, N))
    if table:
        scratch = _table_lobe(g, lobe_data, name, phi_o, wo, h_slice, N, u, v, h_lobe, h_frac, tint, cost_off)
    else:
        # θo = asin(wo.u) (Cycles' arcsine clamps its argument), x = 2|θo|/π
        x = g.math("MULTIPLY", g.math("ABSOLUTE", g.math("ARCSINE", g.vmath("DOT_PRODUCT", wo, u))), 2.0 / _PI)
        S = lobe_data["m"]["weights"].shape[0]
        # stochastic linear interpolation between the two nearest slices: s = floor(xs + h) is s0 + 1 with
        # probability xs - s0 (xs = (φo + π/2) S / π - 1/2)
        s = g.math("FLOOR", g.math("ADD", g.math("MULTIPLY_ADD", phi_o, S / _PI, S / 2 - 0.5), h_slice))
        s = g.math("MINIMUM", g.math("MAXIMUM", s, 0.0), S - 1.0)
        row = g.math("MULTIPLY_ADD", s, 1.0 / S, 0.5 / S)
        scratch = _fitted_lobes(g, lobe_data, name, row, x, N, u, v, h_jit, jittered, tint)
    if layers is None:
        return scratch
    # eq. 4 with one picked layer: min(ᾱ, 1) * ρ_k + max(1 - ᾱ, 0) * ρ_b  ==  Mix(fac = min(ᾱ, 1), base, ρ_k)
    mixs = g.node("ShaderNodeMixShader")
    g._set(mixs.inputs["Fac"], g.math("MINIMUM", alpha_sum, 1.0))
    if base_socket is not None:
        tree.links.new(base_socket, mixs.inputs[1])
    tree.links.new(scratch, mixs.inputs[2])
    return _cull_gate(g, mixs.outputs[0], layers, controls, base_socket)


def layer_coverage(g, uv, theta_k, xi_k, size, threshold, twin: str | None = None, cost_off: int = 0) -> list:
    """Running sums acc_k = Σ_{j <= k} [F1_j]_d of the layers' coverage indicators (eq. 7; one texture-mapped
    Voronoi per layer, ``layer_feature_distance``); acc_{N-1} = ᾱ.  ``twin``: tag the nodes holding the layer
    constants (``set_layer_constants``)."""
    acc, accs = None, []
    for k in range(len(theta_k)):
        tag = None if twin is None else f"{twin}/%s/{k}"
        f1 = layer_feature_distance(g, uv, theta_k[k], xi_k[k], size, tag=tag, cost_off=cost_off)
        a = g.math("LESS_THAN", f1, threshold)  # [F1]_d, eq. 7
        acc = a if acc is None else g.math("ADD", acc, a)
        accs.append(acc)
    return accs


def picked_angle(g, target, accs, theta_k, twin: str | None = None):
    """Θ of the layer that ``target`` ∈ [0, ᾱ) picks (layer k when acc_{k-1} <= target < acc_k, probability
    α_k / ᾱ): from the last layer back, Θ = Θ_k wherever target < acc_k (one Less Than and one Mix per layer).
    ``twin``: tag the Mix nodes with the Θ_k they hold (``set_layer_constants``)."""
    n = len(theta_k)
    theta_sel = float(theta_k[-1])
    for k in range(n - 2, -1, -1):
        mix = g.node("ShaderNodeMix", data_type="FLOAT", clamp_factor=False)
        g._set(mix.inputs[0], g.math("LESS_THAN", target, accs[k]))
        g._set(mix.inputs[2], theta_sel)
        g._set(mix.inputs[3], float(theta_k[k]))
        if twin is not None:
            tags = [f"{twin}/theta3/{k}"]
            if k == n - 2:   # input 2 holds the last layer's Θ
                tags.append(f"{twin}/theta2/{k + 1}")
            mix[LAYER_CONST] = ";".join(tags)
        theta_sel = mix.outputs[0]
    return theta_sel


def race_visits(n_layers: int, density: float) -> float:
    """Expected number of layers ``_layer_race`` visits (Voronoi evaluations) per sample: with independent
    layers of mean coverage c = c̄(d), |C| ~ Binomial(N, c) and the race visits (N + 1) / (|C| + 1) on average,
    E = (1 - (1 - c)^(N+1)) / c (N when c = 0)."""
    from ..precompute.scratch.layers import coverage_table

    d, cbar = coverage_table()
    c = float(np.interp(min(max(float(density), 0.0), float(d[-1])), d, cbar))
    return float(n_layers) if c <= 1e-9 else (1.0 - (1.0 - c) ** (n_layers + 1)) / c


def races(lobe_data: dict, layers) -> bool:
    """True if ``build`` lays the layers out as a race (``_layer_race``) on the Cycles twin: table lobes, more
    than one layer and a race that visits fewer than half the layers (``race_visits``; fig1c 16 layers at
    d = 0.3: 3.7 visits, race; 4 layers: 2.9, not; 32 sparse layers at d = 0.05: 29, not).  A race position reads its
    layer with one lookup (``race_params_image``) and maps it with a Mapping node (its rotation is per sample), where
    the picked-layer graph's layers are texture-mapped Voronoi nodes: fig1c at 4 layers costs 13,263 instructions per
    sample as a race, 12,438 picked (callgrind, bench/scratch_svm_profile); a race material also syncs a lobe per
    position and an EEVEE twin (scene sync, bench/scratch_scale): hence the half-the-layers rule.
    The EEVEE output then takes its own twin (``build(twin="eevee")``, every layer at once)."""
    if not RACE_LAYERS or "cdf" not in lobe_data or layers is None or layers.n_layers < 2:
        return False
    return race_visits(layers.n_layers, layers.density) < 0.5 * layers.n_layers


def _cull_gate(g, scratched, layers, controls, base_socket):
    """Layer culling (§6.1): every layer's mean coverage c̄(d) < ALPHA_CULL below d = CULL_DENSITY.  A Mix
    Shader with factor [d >= CULL_DENSITY] puts the whole layer system (Voronoi, lookups, closure) behind
    Cycles' jump (SVMCompiler::generate_multi_closure skips the nodes only one branch uses): a culled
    material runs the base alone, and a constant factor folds the switch away at sync."""
    dens = controls.get("density", None)
    if dens is None and float(layers.density) >= CULL_DENSITY:
        return scratched
    gate = g.node("ShaderNodeMixShader")
    g._set(gate.inputs["Fac"], 0.0 if dens is None else g.math("GREATER_THAN", dens, CULL_DENSITY))
    if base_socket is not None:
        g.tree.links.new(base_socket, gate.inputs[1])
    g.tree.links.new(scratched, gate.inputs[2])
    return gate.outputs[0]


#: lay dense layer sets out as a race (``races``).  Trade-off (fig1c, 16 layers, this machine): 3.7x instead of 6.0x
#: the baseline per sample; the race positions are instances of one node group per material (``race_group``), so
#: the material holds one group node per position instead of a copy of the position's graph (981 nodes before)
RACE_LAYERS = True
#: rows of the layer-order image of more than ``_EXACT_ORDERS`` layers (random orders; all N! up to it)
RACE_ORDERS = 2048
_EXACT_ORDERS = 5


def race_orders(n_layers: int) -> np.ndarray:
    """The layer orders of ``_layer_race`` [P, N] (integers): every permutation for N <= 5 (then the first
    covering layer of a uniformly drawn row is uniform over the covering layers, exactly), else RACE_ORDERS
    random permutations (a fixed seed: the same image for every material with N layers; the chance of each
    covering layer to come first is 1/|C| within sampling error sqrt((1/|C|)(1 - 1/|C|) / P), 1.1 % of 1/2
    for two covering layers at P = 2048)."""
    import itertools

    if n_layers <= _EXACT_ORDERS:
        return np.array(list(itertools.permutations(range(n_layers))), np.int64)
    rng = np.random.default_rng(20261124)
    return np.argsort(rng.random((RACE_ORDERS, n_layers)), axis=1)


def race_params_image(theta_k, xi_k) -> bpy.types.Image:
    """The layer parameters of ``_layer_race`` by race row and position: RGB = (ξx, ξy, Θ) of eq. 7 for layer
    ``race_orders(N)[r, i]`` at row r, column i: one lookup per race position (the layers' parameters are per
    material, so is this image: [P, N], 2048 x 16 texels at 16 layers, 0.4 MB before compression)."""
    order = race_orders(len(theta_k))
    xi = np.asarray(xi_k, np.float64)
    p = np.zeros(order.shape + (4,))
    p[..., 0], p[..., 1], p[..., 2] = xi[order, 0], xi[order, 1], np.asarray(theta_k, np.float64)[order]
    return _data_image("Scratch layer race", p, alpha=False)


def race_images(theta_k, xi_k) -> tuple:
    """Images of ``_layer_race``: the orders (``race_orders``; RGB = (k + 1/2) / N, 1/2, 0 of the k-th layer, the
    coordinate of layer k in the constants images), the rotations (RGB = (0, 0, Θ_k), A = Θ_k: the Mapping
    node's rotation and the frame angle) and the offsets (RGB = ξ_k) of eq. 7.  Race positions built before
    ``race_params_image`` read these (``set_layer_constants`` still writes them)."""
    n = len(theta_k)
    order = race_orders(n)
    o = np.zeros(order.shape + (4,))
    o[..., 0], o[..., 1] = (order + 0.5) / n, 0.5
    rot = np.zeros((1, n, 4))
    rot[0, :, 2] = rot[0, :, 3] = np.asarray(theta_k, np.float64)
    off = np.zeros((1, n, 4))
    off[0, :, :2] = np.asarray(xi_k, np.float64)[:, :2]
    return (_data_image("Scratch layer orders", o, alpha=False), _data_image("Scratch layer rotations", rot),
            _data_image("Scratch layer offsets", off, alpha=False))


def _layer_race(g, lobe_data, name, layers, theta_k, xi_k, tint, base_socket, controls, cost_off, twin, *, geo, N,
                wo, t, uv, h_slice, h_layer, h_lobe, h_frac):
    """Eq. 4 with binary α_k, one layer picked uniformly among those covering the point, as a race: the layers
    are visited in a random order (a row of ``race_orders`` drawn with ``h_layer``) by nested Mix Shaders
    Mix(α_π(i), <the rest of the race>, ρ_π(i)) ending on the base; the first covering layer is uniform over
    the covering ones (the OSL path's pick: probability α_k / ᾱ), and Cycles' SVM skips the rest of the race
    as soon as one covers (NODE_JUMP_IF_ONE): with coverage c̄ per layer the expected number of Voronoi
    evaluations is (N + 1) E[1 / (|C| + 1)] instead of N (fig1c at 16 layers: 3.7).  Each position runs its
    own copy of the frame and table lobe (only one runs per sample; EEVEE, which runs every node, keeps the
    single picked-layer graph of ``build``).

    The positions are instances of one node group (``race_group``; Cycles inlines groups at sync, so the
    compiled graph is the one a copy per position gives): Blender's cost of adding a node grows with the
    tree's size, and 32 copies (1,800 nodes) took a minute to build."""
    n = layers.n_layers
    size = (float(layers.length), float(layers.width), 1.0)
    if "length" in controls or "width" in controls:
        size = g.combine(controls.get("length", size[0]), controls.get("width", size[1]), 1.0)
    dens = controls.get("density", None)
    threshold = float(layers.density) + 1e-7 if dens is None else g.math("ADD", dens, 1e-7)
    grp = race_group(lobe_data, name, theta_k, xi_k, n, tint, cost_off, twin)
    shared = {"UV": uv, "Size": size, "Threshold": threshold, "Normal": N, "Incoming": wo, "Tangent": t,
              "h_layer": h_layer, "h_slice": h_slice, "h_lobe": h_lobe, "h_frac": h_frac}
    if isinstance(tint, bpy.types.NodeSocket):
        shared["Tint"] = tint
    race = base_socket
    for i in range(n - 1, -1, -1):
        pos = g.node("ShaderNodeGroup")
        pos.node_tree = grp
        pos.label = f"Race position {i}"
        pos.inputs["Position"].default_value = float(i)
        for key, value in shared.items():
            g._set(pos.inputs[key], value)
        if race is not None:
            g.tree.links.new(race, pos.inputs["Rest"])
        race = pos.outputs["Shader"]
    return race


#: custom property marking the node group of one race position (``race_group``; one per built material, named
#: "<material>.scratch race")
RACE_GROUP = "scratch_race_group"
_RACE_INPUTS = (("Position", "NodeSocketFloat"), ("UV", "NodeSocketVector"), ("Size", "NodeSocketVector"),
                ("Threshold", "NodeSocketFloat"), ("Normal", "NodeSocketVector"), ("Incoming", "NodeSocketVector"),
                ("Tangent", "NodeSocketVector"), ("h_layer", "NodeSocketFloat"), ("h_slice", "NodeSocketFloat"),
                ("h_lobe", "NodeSocketFloat"), ("h_frac", "NodeSocketFloat"), ("Tint", "NodeSocketColor"),
                ("Rest", "NodeSocketShader"))


def race_group(lobe_data, name, theta_k, xi_k, n, tint, cost_off, twin) -> bpy.types.NodeTree:
    """One position of ``_layer_race`` as a node group: Mix(α, Rest, ρ) of the layer the order image names at
    column ``Position`` (the layer's rotation and offset from the constants images, eq. 7; F1 below the
    density threshold; the layer's table lobe).  The layer's rotation and offset come from one lookup in
    ``race_params_image`` (row floor(h_layer P), column Position), whose node carries the ``race_par`` tag of
    ``set_layer_constants``; the table nodes the tags of ``apply_tables``."""
    from . import add_socket

    grp = bpy.data.node_groups.new(f"{name}.scratch race", "ShaderNodeTree")
    grp[RACE_GROUP] = True
    for key, kind in _RACE_INPUTS:
        add_socket(grp, key, "INPUT", kind)
    add_socket(grp, "Shader", "OUTPUT", "NodeSocketShader")
    gg = _G(grp)
    gi = gg.node("NodeGroupInput")
    go = gg.node("NodeGroupOutput")
    inp = gi.outputs

    def tex(img, vector):
        node = gg.node("ShaderNodeTexImage", image=img, interpolation="Closest", extension="EXTEND")
        gg._set(node.inputs["Vector"], vector)
        return node

    # row floor(h_layer P), column Position: (ξx, ξy, Θ) of the layer at this position
    par = tex(race_params_image(theta_k, xi_k), gg.combine(gg.math("MULTIPLY_ADD", inp["Position"], 1.0 / n, 0.5 / n),
                                                          inp["h_layer"]))
    par[LAYER_CONST] = f"{twin}/race_par/0"
    c = par.outputs["Color"]
    theta = gg.separate(c)[2]
    m = gg.node("ShaderNodeMapping", vector_type="TEXTURE")
    gg._set(m.inputs["Vector"], inp["UV"])
    gg._set(m.inputs["Rotation"], gg.vmath("MULTIPLY", c, (0.0, 0.0, 1.0)))   # (0, 0, Θ)
    gg._set(m.inputs["Scale"], inp["Size"])
    # eq. 7: S^-1 R(Θ) (u, v) + ξ; z gets Θ too, which the 2D Voronoi does not read.  (A Z-axis Vector Rotate, a divide
    # by (l, w, 1) and the offset instead: 16,010 instructions per sample at fig1c's 16 layers, 170 more; callgrind)
    y = gg.vmath("ADD", m.outputs["Vector"], c)
    alpha = gg.math("LESS_THAN", _feature_distance(gg, y, cost_off), inp["Threshold"])  # [F1]_d, eq. 7
    tint_in = inp["Tint"] if isinstance(tint, bpy.types.NodeSocket) else tint
    lobe = _frame_lobe(gg, lobe_data, name, theta, inp["Normal"], inp["Incoming"], inp["Tangent"],
                       inp["h_slice"], inp["h_lobe"], inp["h_frac"], tint_in, cost_off)
    mix = gg.node("ShaderNodeMixShader")
    gg._set(mix.inputs["Fac"], alpha)
    grp.links.new(inp["Rest"], mix.inputs[1])
    grp.links.new(lobe, mix.inputs[2])
    grp.links.new(mix.outputs[0], go.inputs["Shader"])
    return grp


def tree_nodes(tree):
    """The nodes of ``tree`` and of the race-position groups (``race_group``) its group nodes use, each once."""
    seen = set()
    for node in tree.nodes:
        yield node
        grp = node.node_tree if node.bl_idname == "ShaderNodeGroup" else None
        if grp is not None and grp.get(RACE_GROUP) and grp.as_pointer() not in seen:
            seen.add(grp.as_pointer())
            yield from grp.nodes


def _frame_lobe(g, lobe_data, name, theta, N, wo, t, h_slice, h_lobe, h_frac, tint, cost_off):
    """The table lobe in the scratch frame of a layer at angle ``theta`` (a socket): u = t rotated about N by Θ,
    v = N x u, φo = atan2(wo.v, wo.N)."""
    rot = g.node("ShaderNodeVectorRotate", rotation_type="AXIS_ANGLE")
    g._set(rot.inputs["Vector"], t)
    g._set(rot.inputs["Axis"], N)
    g._set(rot.inputs["Angle"], theta)
    u = rot.outputs["Vector"]
    v = g.vmath("CROSS_PRODUCT", N, u)
    phi_o = g.math("ARCTAN2", g.vmath("DOT_PRODUCT", wo, v), g.vmath("DOT_PRODUCT", wo, N))
    return _table_lobe(g, lobe_data, name, phi_o, wo, h_slice, N, u, v, h_lobe, h_frac, tint, cost_off)


#: Location of a layer's Mapping node when the size (l, w) is a socket: L = -R_z(Θ) (l ξx, w ξy) =
#: (l a + w b, l c + w d) with these factors of (cos Θ, sin Θ, ξ) (materials built before ``layer_feature_distance``)
_LOC_FACTORS = {"la": lambda c, s_, xi: -c * float(xi[0]), "lb": lambda c, s_, xi: s_ * float(xi[1]),
                "lc": lambda c, s_, xi: -s_ * float(xi[0]), "ld": lambda c, s_, xi: -c * float(xi[1])}


def _feature_distance(g, y, cost_off: int = 0) -> bpy.types.NodeSocket:
    """F1: distance from the layer coordinates ``y`` (eq. 7) to the nearest hashed feature point (Cycles' 2D
    Voronoi, randomness 1: the OSL path's placement); ``cost_off & 1`` (bench only): the cell centre instead."""
    if cost_off & 1:
        return g.vmath("LENGTH", g.vmath("SUBTRACT", g.vmath("FRACTION", y), (0.5, 0.5, 0.0)))
    vor = g.node("ShaderNodeTexVoronoi", voronoi_dimensions="2D", feature="F1", distance="EUCLIDEAN")
    vor.inputs["Scale"].default_value = 1.0
    vor.inputs["Randomness"].default_value = 1.0
    g._set(vor.inputs["Vector"], y)
    return vor.outputs["Distance"]


def layer_feature_distance(g, uv, theta: float, xi, size, tag: str | None = None,
                           cost_off: int = 0) -> bpy.types.NodeSocket:
    """F1 of layer k at the UV point (eq. 7): the distance from y = diag(l, w)^-1 R(Θ) (u, v) + ξ to the nearest
    hashed feature point (Cycles' 2D Voronoi, randomness 1: the OSL path's placement; rotation first, see
    osl/scratch_svbrdf.osl); ``size`` = (l, w) in UV units, Θ in radians.

    y is the Voronoi node's own texture mapping (``set_texture_mapping``): Cycles folds it into one 3x4 matrix at
    sync, a matrix-vector product per shading point, where a Mapping node builds its matrix from the Euler
    rotation every sample (callgrind, bench/scratch_svm_profile: ~350 instructions per layer and shading point
    for the Mapping node, ~60 for the texture mapping).  l and w are therefore compiled values: live edits and
    keyframes of the panel's Length / Width rewrite the mapping (``set_layer_size``, called by
    ``scratch_addon.live``).  ``tag`` ("<twin>/%s/<k>") marks the node for ``set_layer_constants``;
    ``cost_off & 1`` (bench only): the distance to the cell centre (an image, the same mapping) instead."""
    if cost_off & 1:
        node = g.node("ShaderNodeTexImage", image=_cell_distance_image(), interpolation="Closest",
                      extension="REPEAT")
        out = node.outputs["Alpha"]
    else:
        node = g.node("ShaderNodeTexVoronoi", voronoi_dimensions="2D", feature="F1", distance="EUCLIDEAN")
        node.inputs["Scale"].default_value = 1.0
        node.inputs["Randomness"].default_value = 1.0
        out = node.outputs["Distance"]
    g._set(node.inputs["Vector"], uv)
    node[LAYER_XFORM] = (float(theta), float(xi[0]), float(xi[1]))
    if tag:
        node[LAYER_CONST] = tag % "vor"
    set_texture_mapping(node, theta, xi, *size)
    return out


def set_texture_mapping(node, theta: float, xi, length: float, width: float) -> None:
    """The texture mapping of a layer's texture node for eq. 7: y = diag(l, w)^-1 R(Θ) (u, v) + ξ.
    Cycles' Texture-type mapping applies (T R_z(r) S)^-1, i.e. y = S^-1 R_z(r)^T (p - L), so r = Θ
    (R_z(Θ)^T = R(Θ)), S = (l, w, 1) and L = -R_z(Θ) S ξ."""
    tm = node.texture_mapping
    c, s_ = math.cos(theta), math.sin(theta)
    sx, sy = float(length) * float(xi[0]), float(width) * float(xi[1])
    tm.vector_type = "TEXTURE"
    tm.rotation = (0.0, 0.0, float(theta))
    tm.scale = (float(length), float(width), 1.0)
    tm.translation = (-(c * sx - s_ * sy), -(s_ * sx + c * sy), 0.0)


def set_layer_size(tree, length: float, width: float) -> int:
    """Write the scratch length l and width w (UV units, eq. 7) into every layer's texture mapping
    (``layer_feature_distance``) in ``tree`` (both twins); returns how many nodes changed."""
    n = 0
    for node in tree_nodes(tree):
        xform = node.get(LAYER_XFORM)
        if xform is None:
            continue
        old = tuple(node.texture_mapping.scale)[:2]
        if old != (float(np.float32(length)), float(np.float32(width))):
            set_texture_mapping(node, xform[0], xform[1:], length, width)
            n += 1
    return n


def _cell_distance_image() -> bpy.types.Image:
    """Bench only (``cost_off & 1``): |fract(y) - 1/2|, the distance to the cell centre, in the alpha of a tiling
    image (64 x 64 texels): a stand-in for the layer Voronoi with the same mean coverage π d²."""
    x = (np.arange(64) + 0.5) / 64 - 0.5
    arr = np.zeros((64, 64, 4))
    arr[..., 3] = np.hypot(x[None, :], x[:, None])
    return _data_image("Scratch bench cell distance", arr)


def _set_mapping(m, theta: float, xi) -> None:
    """Rotation and Location of a layer's Mapping node (materials built before ``layer_feature_distance``) for
    layer rotation Θ and offset ξ."""
    m.inputs["Rotation"].default_value = (0.0, 0.0, float(theta))
    if m.inputs["Scale"].is_linked:   # ξ is added after the mapping
        m.inputs["Location"].default_value = (0.0, 0.0, 0.0)
        return
    c, s_ = math.cos(theta), math.sin(theta)
    sx, sy = float(m.inputs["Scale"].default_value[0]) * float(xi[0]), float(m.inputs["Scale"].default_value[1]) * float(xi[1])
    m.inputs["Location"].default_value = (-(c * sx - s_ * sy), -(s_ * sx + c * sy), 0.0)


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


def _data_image(img_name: str, arr: np.ndarray, alpha: bool = True) -> bpy.types.Image:
    """A packed Non-Color float RGBA image holding ``arr`` [rows, cols, 4] (row 0 at the bottom); ``alpha``
    False: an RGB image (its packed EXR stores three channels, 3/4 of the bytes) for tables whose shader reads
    only the Color output (``arr``'s fourth channel must then be 0: it is not stored).

    Named ``<img_name> <content hash>`` and shared: materials with the same tables use one image (one packed
    copy in the .blend), and rebuilding a material never rewrites an image another material uses."""
    import hashlib

    data = np.ascontiguousarray(arr, np.float32)
    if not alpha and np.any(data[..., 3] != 0.0):
        raise ValueError(f"{img_name}: an RGB table image cannot hold a fourth channel")
    rows, cols = arr.shape[:2]
    img_name = f"{img_name} {hashlib.sha1(data.tobytes() + repr(data.shape).encode()).hexdigest()[:12]}"
    img = bpy.data.images.get(img_name)
    if img is not None and tuple(img.size) == (cols, rows) and img.packed_file is not None:
        return img
    if img is not None and tuple(img.size) != (cols, rows):
        bpy.data.images.remove(img)
        img = None
    if img is None:
        img = bpy.data.images.new(img_name, width=cols, height=rows, alpha=alpha, float_buffer=True, is_data=True)
    img.colorspace_settings.is_data = True
    img.alpha_mode = "CHANNEL_PACKED"
    if not alpha:   # Blender's pixel buffer stays RGBA (alpha 1); only RGB is packed
        data = data.copy()
        data[..., 3] = 1.0
    img.pixels.foreach_set(data.reshape(-1))
    img.file_format = "OPEN_EXR"
    img.pack()
    return img


def table_images(name: str, lobe_data: dict) -> dict:
    """Packed Non-Color float images of tabulated-tilt lobes (``precompute.scratch.lobes.table_lobes``), laid
    out so that the shader does as little arithmetic per sample as possible (``_table_lobe``):

    - ``N`` [1, G]: per uniform φo cell with node interval k: R = (k + 1/2) / S (the row of node k), G = φ_k,
      B = φ_k+1 - φ_k (radians);
    - ``A`` [S, M] (rows = φo nodes): the bins' alias table (``lobe_table.alias_table``): R = prob_j,
      G = alias_j - j, B = the node's total P;
    - ``C`` [S, M] (rows = φo nodes), bin b of node s with exit centroid c, half spread h = min(c, 1 - c)
      and sign σ = +1 for odd bounces (mirror-like), -1 for even ones (retro-like): R = (b + c - h) π / 2M - π/4
      + σ φ_s / 2, G = 2 h π / 2M, B = (1 - σ) / 2, A = 0 (the tilt is then R + G ξ + B φo: two Math nodes);
    - lossy only: ``Y`` [S, NT M / y_group] RGB = ``theta_factor``.
    Images are shared by content (``_data_image``); all are RGB images (the shader reads their Color only).
    """
    from ..precompute.scratch.lobe_table import alias_table

    cdf = np.asarray(lobe_data["cdf"], np.float64)
    S, M1 = cdf.shape
    M = M1 - 1
    phi = np.asarray(lobe_data["phi"], np.float64)
    cell = np.asarray(lobe_data["cell"], np.int64)
    n = np.zeros((1, cell.size, 4))
    n[0, :, 0], n[0, :, 1], n[0, :, 2] = (cell + 0.5) / S, phi[cell], phi[cell + 1] - phi[cell]
    prob, alias = lobe_data.get("alias_prob"), lobe_data.get("alias_idx")
    if prob is None or alias is None:
        prob, alias = alias_table(cdf)
    total = np.asarray(lobe_data["total"], np.float64)
    a = np.zeros((S, M, 4))
    a[..., 0], a[..., 1], a[..., 2] = prob, np.asarray(alias) - np.arange(M), total[:, None]
    code = np.asarray(lobe_data["cen"], np.float64)
    even = code > 1.5
    ce = code - 2.0 * even
    hw = np.minimum(ce, 1.0 - ce)
    sigma = 1.0 - 2.0 * even
    c = np.zeros((S, M, 4))
    k = np.pi / (2 * M)
    c[..., 0] = (np.arange(M) + ce - hw) * k - np.pi / 4 + 0.5 * sigma * phi[:, None]
    c[..., 1], c[..., 2] = 2.0 * hw * k, 0.5 - 0.5 * sigma
    out = {"N": _data_image(TABLE_IMAGE_PREFIX + "N", n, alpha=False),
           "A": _data_image(TABLE_IMAGE_PREFIX + "A", a, alpha=False),
           "C": _data_image(TABLE_IMAGE_PREFIX + "C", c, alpha=False)}
    if lobe_data.get("basis") is not None:
        out["Y"] = _data_image(TABLE_IMAGE_PREFIX + "Y", theta_factor(lobe_data), alpha=False)
    return out


def theta_factor(lobe_data: dict) -> np.ndarray:
    """The colour of the table lobe, P max(Y_g(v_t), 0) with the θo factor Y_g(v_t) = Σ_k coef[s, g, k] B_k(v_t)
    pre-summed over the K basis functions (``precompute.scratch.lobes.table_lobes``; v = 1 - sqrt(cos θo) on NT
    samples) and P the φo node's total, per RGB channel, as the RGBA rows of the ``Y`` image [S, Mg NT, 4]
    (column g NT + t).  Read with Linear interpolation along v inside a group's NT columns: one lookup where
    coefficients and basis took 2 K, a scale and a clamp.  The clamp is applied to the samples (the shader
    clamped the interpolated value: they differ only between two samples of opposite sign)."""
    coef = np.asarray(lobe_data["coef"], np.float64)                          # [S, Mg, K, 3]
    basis = np.asarray(lobe_data["basis"], np.float64)                        # [K, NT, 3]
    y = np.einsum("sgkc,ktc->sgtc", coef, basis)                              # [S, Mg, NT, 3]
    y = np.maximum(y, 0.0) * np.asarray(lobe_data["total"], np.float64)[:, None, None, None]
    out = np.zeros(y.shape[:2] + (y.shape[2], 4))
    out[..., :3] = y
    return out.reshape(coef.shape[0], -1, 4)


def _table_lobe(g, lobe_data, name, phi_o, wo, h_slice, N, u, v, h, h_frac, tint, cost_off=0):
    """One tabulated-tilt lobe, as the OSL ``table_lobes`` with TK = 1 (``precompute.scratch.lobes.table_lobes``):
    the φo node picked between the two around φo (a cell image gives the interval), the bin from the node's
    alias table (one lookup, probability p_b / P), the aim at the bin's exit centroid moved to the actual view
    (odd bounces mirror-like, even retro-like; the spread inside the bin drawn with ``h_frac``), a narrow GGX
    Glossy tilted halfway between φo and the exit, colour P Y_b(θo) (Y = 1 lossless, else Σ_k coef B_k(v),
    v = 1 - sqrt(cos θo)).  The images (``table_images``) hold what can be precomputed per bin, so a sample
    costs 3 lookups and 12 Math nodes lossless, 4 and 17 lossy (19 when bins share θo coefficients).  ``cost_off`` bits 4 / 8 as in ``build``."""
    imgs = table_images(name, lobe_data)
    cdf = lobe_data["cdf"]
    S, M = cdf.shape[0], cdf.shape[1] - 1
    lossless = lobe_data.get("basis") is None

    def fetch(img, x, y, interpolation="Closest"):
        # lookup at (x, y) in [0, 1]^2: Closest reads texel floor(x width) (Cycles' interp_closest)
        tex = g.node("ShaderNodeTexImage", image=img, interpolation=interpolation, extension="EXTEND")
        g._set(tex.inputs["Vector"], g.combine(x, y))
        return tex

    # node interval of phi_o (EXTEND clamps the cell), then one of its two nodes with the linear weight:
    # the upper one when φ_k + h (φ_k+1 - φ_k) < φo
    # N has one row: the lookup takes the float itself (Cycles converts it to (x, x, x); EXTEND keeps y in row 0),
    # one conversion instead of a Combine XYZ (four SVM nodes more per shading point)
    n_tex = g.node("ShaderNodeTexImage", image=imgs["N"], interpolation="Closest", extension="EXTEND")
    g._set(n_tex.inputs["Vector"], g.math("MULTIPLY_ADD", phi_o, 1.0 / _PI, 0.5))
    row_k, pa, dp = g.separate(n_tex.outputs["Color"])
    up = g.math("LESS_THAN", g.math("MULTIPLY_ADD", h_slice, dp, pa), phi_o)
    row = g.math("MULTIPLY_ADD", up, 1.0 / S, row_k)
    row.node[TABLE_ROWS] = True   # its 1/S is rewritten when an in-place table update changes S
    uh = g.math("MULTIPLY", h, float(M))
    j = g.math("FLOOR", uh)
    a_tex = fetch(imgs["A"], h, row)              # texel floor(h M) = j
    prob, d_alias, P = g.separate(a_tex.outputs["Color"])
    if cost_off & 4:  # bench: no alias table (the bin straight from h)
        lo = j
    else:
        take = g.math("LESS_THAN", prob, g.math("SUBTRACT", uh, j))     # u - j >= prob_j: the alias bin
        lo = g.math("MULTIPLY_ADD", take, d_alias, j)
    c0 = fetch(imgs["C"], g.math("MULTIPLY_ADD", lo, 1.0 / M, 0.5 / M), row)
    a0, a1, b_phi = g.separate(c0.outputs["Color"])
    # exit = aim ± (φ_s - φo) (+ odd, - even bounces), aim = (lo + c + (2 ξ - 1) h) π / M - π/2; the lobe's
    # tilt = (exit + φo) / 2 = a0 + a1 ξ + b_phi φo with the constants folded into the C image (table_images)
    tilt = g.math("MULTIPLY_ADD", b_phi, phi_o, g.math("MULTIPLY_ADD", a1, h_frac, a0))
    # the lobe normal cos(tilt) N + sin(tilt) v is N rotated about u by -tilt (v = N x u)
    rot = g.node("ShaderNodeVectorRotate", rotation_type="AXIS_ANGLE", invert=True)
    g._set(rot.inputs["Vector"], N)
    g._set(rot.inputs["Axis"], u)
    g._set(rot.inputs["Angle"], tilt)
    n_l = rot.outputs["Vector"]
    if lossless:
        colour = P
    else:
        NT = lobe_data["basis"].shape[1]
        yg = int(lobe_data.get("y_group", 1))
        n_cols = lobe_data["coef"].shape[1] * NT
        # v = 1 - sqrt(cos θo) = 1 - q, q = (1 - (wo.u)^2)^(1/4) (Cycles' power is 0 for a negative base), as a
        # continuous column inside the bin group's NT samples: col = g NT + v (NT - 1), linear between samples
        cu = g.vmath("DOT_PRODUCT", wo, u)
        q = g.math("POWER", g.math("SUBTRACT", 1.0, g.math("MULTIPLY", cu, cu)), 0.25)
        grp = lo if yg == 1 else g.math("FLOOR", g.math("MULTIPLY_ADD", lo, 1.0 / yg, 0.5 / yg))
        x = g.math("MULTIPLY_ADD", grp, NT / n_cols, g.math("MULTIPLY_ADD", q, (1.0 - NT) / n_cols, (NT - 0.5) / n_cols))
        colour = fetch(imgs["Y"], x, row, "Linear").outputs["Color"]
    colour = _tinted(g, colour, tint)
    # Glossy roughness mapping (see lobe_images): alpha_y below alpha_x -> an isotropic lobe of alpha_x
    ax = float(lobe_data["alpha_x"])
    ay = max(float(lobe_data["alpha_y"]), ax)
    glossy = g.node("ShaderNodeBsdfGlossy", distribution="GGX")
    glossy[TABLE_GLOSSY] = True   # its roughness follows the table (scratch_addon.scratch_material.apply_tables)
    rough, aniso = glossy_node_params(ax, min(ay, 1.0))
    g._set(glossy.inputs["Anisotropy"], aniso)
    g._set(glossy.inputs["Tangent"], u)
    if cost_off & 8:  # bench: no closure set-up (untilted white lobe; lo and the node kept alive)
        g._set(glossy.inputs["Roughness"], g.math("MULTIPLY", g.math("MULTIPLY_ADD", g.math("ADD", lo, a0), 1e-9, 1.0),
                                                  rough))
        return glossy.outputs[0]
    g._set(glossy.inputs["Color"], colour)
    g._set(glossy.inputs["Roughness"], rough)
    g._set(glossy.inputs["Normal"], n_l)
    return glossy.outputs[0]
