"""Generator of the specialised OSL scratch SV-BRDF shader (Raymond et al. 2016, §4.2-§5, eqs. 2, 3, 4, 7).

The shader itself is ``osl/scratch_svbrdf.osl`` (reference mode: ``osl/scratch_reference.osl``); its
file header documents the model, the sockets, the compile-time flags and the tables.  This module
computes one material's numbers and writes them in front of / into that file (``osl.specialise``):
the feature flags as ``#define``s and the lobe tables, layer rotations/offsets and the noise coverage
table as constant arrays, so an INTERNAL script node renders on a machine without the add-on.  OSL's
preprocessor compiles only the features a material uses:

- no ``node_voronoi.h`` and no α code for a dense layer (``LAYERS 0``: scratches everywhere, Fig. 1a);
- no γ / ρ0 code for a lossless profile (``LOSSLESS 1``: ρ0 = ρm, eq. 2 reduces to ρm);
- no ``Base`` input when the scratches cover everything or no base is wanted (``USE_BASE 0``);
- no layer-selection code when all layers are summed (``PICK_LAYER 0``, at most ``MAX_SUMMED_LAYERS``).

Per shading point (world space; n = shading normal, t = UV tangent, b = n x t):
  layer k: scratch direction u_k = cos Θ_k t + sin Θ_k b, v_k = n x u_k;
  (θo, φo) = (asin(ωo.u_k), atan2(ωo.v_k, ωo.n))                                 (§4.1)
  α_k = footprint-filtered indicator [F1(y_k)]_d, y_k = diag(l, w)^-1 R(Θ_k)(u, v) + ξ_k   (eqs. 3, 7)
  ρ = Σ α_k ρ_k / max(ᾱ, 1) + max(1 - ᾱ, 0) ρ_b                                    (eq. 4)
  ρ_k(φo, ·) = Σ_j [R_γj(θo) w^m_j lobe^m_j + (1 - R_γj(θo)) w^0_j lobe^0_j]       (eq. 2 per lobe)
where a lobe is a GGX (or Beckmann) microfacet lobe with normal N'_j = cos t_j n + sin t_j v_k and
tangent u_k (see ``precompute.scratch.lobe_fit``), R_γ(θo) = (2|θo|/π)^γ and γ_j is γ at the lobe's centre.

With ``ShaderSpec.table`` (tabulated-tilt lobes, ``precompute.scratch.lobes.table_lobes``) the fitted lobes
are replaced by one narrow lobe per sample from exact view slices at adaptive φo nodes
(``precompute.scratch.slices``): the node around φo picked with its linear weight, aim bin b of its slice by a
binary search in its CDF (probability p_b / P), the aim at the bin's exit centroid, moved to the actual φo
(odd bounces mirror-like, even bounces retro-like), weight P Y_b(θo) with Y_b = Σ_k coef_bk B_k(v) (eq. 2
generalised to a per-material θo basis, v = 1 − sqrt(cos θo)); its expectation is the exact slice.

Layer rotation note: eq. 7 is printed as R(Θ_k) diag(l, w)^-1; rotating *after* the stretch would
leave the scratches axis-aligned (a circle's image under the stretch does not rotate), so the UV
coordinates are rotated first, as the paper's Fig. 9 shows ("stretched and rotated").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..precompute.scratch import layers as layers_mod, material
from ..precompute.scratch.material import ScratchParams
from . import const_array, specialise

def _const(name: str, values, ctype: str = "float") -> str:
    """``const_array`` of the values rounded to float32 first (what OSL compiles them to): the text depends only
    on the float32 values, so the same tables give the same text whether they were computed (float64) or read
    back from the table cache (float32), and materials share one Text / shader group (issue 15 item 5)."""
    if ctype == "float":
        values = np.asarray(values, np.float32).ravel()
    return const_array(name, values, ctype)


def _f32(x) -> float:
    """``x`` rounded to float32 (a ``#define`` value; see ``_const``)."""
    return float(np.float32(x))


#: Above this many layers, one layer is picked per shading point (probability α_k / ᾱ) so the
#: closure count stays constant; at or below it every layer is summed.
MAX_SUMMED_LAYERS = 2
#: Layers whose α_k is below this are culled (the paper's threshold, §6.1; the numpy twins' constant).
ALPHA_CULL = layers_mod.ALPHA_CULL


@dataclass
class LobeTable:
    """Lobes of one table channel: per φo slice s, lobes ``start[s]:start[s+1]`` of the flat arrays."""

    start: np.ndarray   # [MS + 1] int
    tilt: np.ndarray    # [L] radians
    width: np.ndarray   # [L] GGX alpha_y
    weight: np.ndarray  # [L, 3] RGB closure weights
    gamma: np.ndarray   # [L] γ at the lobe centre (eq. 2)
    dist: np.ndarray = None  # [L] 0 = GGX, 1 = Beckmann (None: all GGX)
    jitter: np.ndarray = None  # [L] tilt jitter j (radians): tilt drawn in [t - j, t + j] per sample (None: 0)

    @classmethod
    def from_fit(cls, fit: dict) -> "LobeTable":
        """From ``precompute.scratch.lobes.lobe_tables`` entries (``weights`` [S, K] or [S, K, 3], ``tilts``,
        ``widths``, optional ``dist``, ``gamma`` and ``jitters`` [S, K]); zero-weight slots are dropped."""
        w = np.asarray(fit["weights"], float)
        rgb = np.repeat(w[..., None], 3, -1) if w.ndim == 2 else w
        keep = rgb.max(-1) > 0
        start = np.concatenate([[0], np.cumsum(keep.sum(1))]).astype(np.int64)
        n = int(start[-1])
        take = lambda key, default: np.asarray(fit[key])[keep] if key in fit else default  # noqa: E731
        return cls(start, np.asarray(fit["tilts"], float)[keep], np.asarray(fit["widths"], float)[keep], rgb[keep],
                   take("gamma", np.ones(n)).astype(float), take("dist", np.zeros(n, int)).astype(int),
                   take("jitters", np.zeros(n)).astype(float))

    @property
    def jittered(self) -> bool:
        return self.jitter is not None and bool(np.any(np.asarray(self.jitter) > 0))

    @property
    def n_slices(self) -> int:
        return len(self.start) - 1


@dataclass
class ShaderSpec:
    """Everything the generated shader needs; see the module docstring for the model."""

    lobes_m: LobeTable | None
    lobes_0: LobeTable | None = None        # None: lossless profile, ρ0 = ρm
    alpha_x: float = 1e-4
    layers: object | None = None            # precompute.scratch.layers.LayerParams, None = dense
    theta_k: np.ndarray = field(default_factory=lambda: np.zeros(0))
    xi_k: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    coverage: np.ndarray = field(default_factory=lambda: np.zeros(0))  # c̄ on precompute.scratch.layers.COVERAGE_D
    coverage_dmax: float = 1.5
    use_base: bool = True
    lobe_mode: str = "pick"                 # "pick": one hash-picked lobe (weight / probability); "all": sum
    alpha_mode: str = "footprint"           # "footprint": eq. 3 over the ray footprint; "mean": α_k = c̄(d) (tests)
    base_pick: bool = True                  # eq. 4 by picking scratches (prob. min(ᾱ,1)) or base: one closure
    name: str = "scratch_svbrdf"
    table: "TableLobes | None" = None       # tabulated-tilt lobes instead of lobes_m / lobes_0
    voronoi_int2: bool = True               # Cycles' Voronoi hash API: int2 cells (Blender >= 5.0) or floats (4.x)
    cost_off: int = 0                       # bench/scratch_cost.py only: COST_OFF stage bits (1 Voronoi, 2 footprint
                                            # α, 4 CDF search, 8 closure set-up; table lobes; 16 no culled
                                            # early-out), 0 in every material


@dataclass
class TableLobes:
    """Tabulated-tilt lobes from exact view slices (``precompute.scratch.lobes.table_lobes``): node angles
    ``phi [S]`` and the node interval of each uniform φo cell ``cell [G]``; per node s and aim bin b the
    bin-picking ``cdf [S, M+1]`` / ``total [S]`` and the aim code ``cen [S, M]`` (exit centroid + 2 for even
    bounces); the θo dependence ``coef [S, M / y_group, K, 3]`` on the basis ``basis [K, NT, 3]`` (None:
    lossless); ``alpha_y`` the lobes' GGX width; ``strata`` the closures summed in ``lobe_mode="all"``."""

    phi: np.ndarray
    cell: np.ndarray
    cdf: np.ndarray
    total: np.ndarray
    cen: np.ndarray
    coef: np.ndarray | None
    basis: np.ndarray | None
    alpha_y: float
    y_group: int = 1
    strata: int = 1
    alias_prob: np.ndarray | None = None    # [S, M] alias table of the bins (lobe_table.alias_table); None: from cdf
    alias_idx: np.ndarray | None = None

    @classmethod
    def from_tables(cls, t: dict, strata: int = 1) -> "TableLobes":
        """From ``precompute.scratch.lobes.table_lobes``."""
        opt = lambda k: None if t.get(k) is None else np.asarray(t[k], float)  # noqa: E731
        ap, ai = t.get("alias_prob"), t.get("alias_idx")
        return cls(np.asarray(t["phi"], float), np.asarray(t["cell"], np.int64), np.asarray(t["cdf"], float),
                   np.asarray(t["total"], float), np.asarray(t["cen"], float), opt("coef"), opt("basis"),
                   float(t["alpha_y"]), int(t.get("y_group", 1)), int(strata),
                   None if ap is None else np.asarray(ap, float), None if ai is None else np.asarray(ai, int))

    @property
    def lossless(self) -> bool:
        return self.basis is None

    def alias(self) -> tuple[np.ndarray, np.ndarray]:
        """(prob [S, M], alias [S, M]): the alias table the shader samples bins with
        (``precompute.scratch.lobe_table.alias_table`` of ``cdf``)."""
        if self.alias_prob is None or self.alias_idx is None:
            from ..precompute.scratch.lobe_table import alias_table
            return alias_table(self.cdf)
        return self.alias_prob, self.alias_idx

    @property
    def n_slices(self) -> int:
        return self.cdf.shape[0]

    @property
    def n_bins(self) -> int:
        return self.cdf.shape[1] - 1


def _table_arrays(t: TableLobes) -> str:
    prob, alias = t.alias()
    out = (_const("TB_PHI", t.phi) + _const("TB_CELL", t.cell, "int")
           + _const("TB_AP", prob.ravel()) + _const("TB_AI", alias.ravel(), "int")
           + _const("TB_TOT", t.total) + _const("TB_CEN", t.cen.ravel()))
    if not t.lossless:
        out += _const("TB_Y", t.coef.ravel()) + _const("TB_B", t.basis.ravel())
    return out


def _lobe_arrays(prefix: str, t: LobeTable, jittered: bool = False) -> str:
    dist = np.zeros(len(t.tilt), int) if t.dist is None else np.asarray(t.dist, int)
    jit = np.zeros(len(t.tilt)) if t.jitter is None else np.asarray(t.jitter, float)
    return (_const(f"{prefix}_START", t.start, "int")
            + _const(f"{prefix}_DIST", dist, "int")
            + _const(f"{prefix}_TILT", t.tilt)
            + _const(f"{prefix}_AY", t.width)
            + _const(f"{prefix}_W", t.weight.ravel())
            + _const(f"{prefix}_GAMMA", t.gamma)
            + (_const(f"{prefix}_JIT", jit) if jittered else ""))


def generate(spec: ShaderSpec) -> str:
    """OSL source of the specialised scratch shader for ``spec``: ``scratch_svbrdf.osl`` with the
    material's feature flags and tables (see ``osl.specialise``)."""
    layered = spec.layers is not None
    tab = spec.table
    if tab is None and spec.lobes_m is None:
        raise ValueError("ShaderSpec needs lobes_m (fitted lobes) or table (tabulated-tilt lobes)")
    lossless = tab.lossless if tab is not None else spec.lobes_0 is None
    use_base = spec.use_base and layered
    ms = tab.n_slices if tab is not None else spec.lobes_m.n_slices
    if tab is None and not lossless and spec.lobes_0.n_slices != ms:
        raise ValueError("lobes_0 and lobes_m must have the same number of phi_o slices")
    n_layers = spec.layers.n_layers if layered else 1
    if spec.lobe_mode not in ("pick", "all"):
        raise ValueError(f"lobe_mode must be 'pick' or 'all', got {spec.lobe_mode!r}")
    if layered and spec.alpha_mode not in ("footprint", "mean"):
        raise ValueError(f"alpha_mode must be 'footprint' or 'mean', got {spec.alpha_mode!r}")

    flags = dict(SHADER_NAME=spec.name, LAYERS=layered, NL=n_layers, PICK_LAYER=n_layers > MAX_SUMMED_LAYERS,
                 ALPHA_MEAN=layered and spec.alpha_mode == "mean", USE_BASE=use_base,
                 BASE_PICK=spec.base_pick and use_base, LOSSLESS=lossless, LOBE_TABLE=tab is not None)
    if tab is not None:
        # tabulated-tilt lobes (precompute.scratch.lobe_table): one sampled closure, or `strata` stratified ones
        strata = tab.strata if spec.lobe_mode == "all" else 1
        if not (isinstance(strata, (int, np.integer)) and 1 <= strata <= 64):
            raise ValueError(f"table strata must be an integer in [1, 64]; got {strata!r}")
        flags.update(LOBE_SUM=False, JITTERED=False, MS=ms, AX=_f32(spec.alpha_x), MB=tab.n_bins, AY_TB=_f32(tab.alpha_y),
                     TK=int(strata), NS=tab.n_slices, NG=int(tab.cell.size),
                     KY=0 if tab.lossless else int(tab.basis.shape[0]),
                     NT=2 if tab.lossless else int(tab.basis.shape[1]), YG=int(tab.y_group))
        tables = [_table_arrays(tab)]
    else:
        per_slice = int(np.diff(spec.lobes_m.start).max(initial=0))
        if not lossless:
            per_slice += int(np.diff(spec.lobes_0.start).max(initial=0))
        # tilt jitter (stochastic box lobes, precompute.scratch.lobe_fit): only compiled when a lobe has one
        jittered = spec.lobes_m.jittered or (not lossless and spec.lobes_0.jittered)
        flags.update(LOBE_SUM=spec.lobe_mode == "all", JITTERED=jittered, MS=ms, AX=_f32(spec.alpha_x),
                     KMAX2=max(per_slice, 1))
        tables = [_lobe_arrays("LM", spec.lobes_m, jittered)]
        if not lossless:
            tables.append(_lobe_arrays("L0", spec.lobes_0, jittered))
    if layered:
        lp = spec.layers
        flags.update(LAYER_LENGTH=float(lp.length), LAYER_WIDTH=float(lp.width), LAYER_DENSITY=float(lp.density))
        tables.append(_layer_arrays(spec))
    flags.update(ALPHA_CULL=ALPHA_CULL, VORONOI_INT2=bool(spec.voronoi_int2))
    if spec.cost_off:
        flags["COST_OFF"] = int(spec.cost_off)
    return specialise("scratch_svbrdf.osl", flags, {"scratch_svbrdf_tables.h": "\n".join(tables)},
                      "osl/scratch_svbrdf.py")


def _layer_arrays(spec) -> str:
    """CS_K (cos Θ_k, sin Θ_k per layer), XI_K, COV and COV_DMAX of a layered ``ShaderSpec`` / ``ReferenceSpec``.  COV holds c̄(d) / d² on the
    uniform grid of [0, COV_DMAX] (π at d = 0): the shaders' ``mean_coverage`` is exact near 0
    (``precompute.scratch.layers.coverage_lookup`` is its twin)."""
    cov = np.asarray(spec.coverage, np.float64)
    d = np.linspace(0.0, float(spec.coverage_dmax), len(cov))
    ratio = np.concatenate([[np.pi], cov[1:] / d[1:] ** 2])
    theta = np.asarray(spec.theta_k, np.float64)
    cs = np.stack([np.cos(theta), np.sin(theta)], -1).ravel()   # the shaders read them per sample: no trig
    return (_const("CS_K", cs) + _const("XI_K", np.asarray(spec.xi_k).ravel())
            + _const("COV", ratio) + f"    float COV_DMAX = {_f32(spec.coverage_dmax):.9g};\n")


# --- reference mode ------------------------------------------------------------------------------
@dataclass
class ReferenceSpec:
    """Exact-table reference (validation only): φi importance-sampled from the ρm slice (§5.1) and
    traced with ``ray_portal_bsdf`` (no light sampling).  Tables are [M, M] / [M, M, 3] float arrays
    (``precompute.scratch_brdf.ScratchBRDF``); layers as in ``ShaderSpec``."""

    rho_m: np.ndarray
    rho0: np.ndarray
    gamma: np.ndarray
    layers: object | None = None
    theta_k: np.ndarray = field(default_factory=lambda: np.zeros(0))
    xi_k: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    coverage: np.ndarray = field(default_factory=lambda: np.zeros(0))
    coverage_dmax: float = 1.5
    use_base: bool = True
    name: str = "scratch_reference"
    voronoi_int2: bool = True               # as ShaderSpec.voronoi_int2

    #: Largest table compiled into the source (5 M² floats; larger tables make OSL compile slowly).
    MAX_M = material.REFERENCE_MAX_M


def generate_reference(spec: ReferenceSpec) -> str:
    """OSL source of the exact-table reference shader (eq. 2 and eq. 5 by importance sampling):
    ``scratch_reference.osl`` with the material's flags and tables."""
    rho_m = np.asarray(spec.rho_m, np.float64)
    rho_m = rho_m.mean(-1) if rho_m.ndim == 3 else rho_m
    M = rho_m.shape[0]
    if M > ReferenceSpec.MAX_M:
        raise ValueError(f"reference mode: resolution must be <= {ReferenceSpec.MAX_M}, got {M}")
    rho0 = np.asarray(spec.rho0, np.float64)
    rho0 = np.repeat(rho0[..., None], 3, -1) if rho0.ndim == 2 else rho0
    gamma = np.asarray(spec.gamma, np.float64)
    gamma = gamma.mean(-1) if gamma.ndim == 3 else gamma
    edges = -np.pi / 2 + np.arange(M + 1) * np.pi / M
    C = np.diff(np.sin(edges))                          # ∫cos over each φi bin
    mass = rho_m * C[None, :]
    total = mass.sum(1)                                 # albedo of each φo slice (white furnace)
    cdf = np.concatenate([np.zeros((M, 1)), np.cumsum(mass, 1)], 1) / np.where(total > 0, total, 1.0)[:, None]
    layered = spec.layers is not None
    flags = dict(SHADER_NAME=spec.name, LAYERS=layered, NL=spec.layers.n_layers if layered else 1,
                 USE_BASE=spec.use_base and layered, MT=M)
    tables = [_const("RHO_M", rho_m.ravel()) + _const("RHO_0", rho0.ravel())
              + _const("GAM", gamma.ravel()) + _const("CDF", cdf.ravel()) + _const("TOTAL", total)
              + _const("EDGE_SIN", np.sin(edges))]
    if layered:
        lp = spec.layers
        flags.update(LAYER_LENGTH=float(lp.length), LAYER_WIDTH=float(lp.width), LAYER_DENSITY=float(lp.density))
        tables.append(_layer_arrays(spec))
    flags.update(ALPHA_CULL=ALPHA_CULL, VORONOI_INT2=bool(spec.voronoi_int2))
    return specialise("scratch_reference.osl", flags, {"scratch_reference_tables.h": "\n".join(tables)},
                      "osl/scratch_svbrdf.py (reference mode)")


def source(params: ScratchParams, brdf=None, lobe_data=None, voronoi_int2: bool = True, **spec_options) -> str:
    """The specialised OSL source of a scratch material (``precompute.scratch.material.validate``d
    ``params``; tables computed or taken from the cache unless given).  ``voronoi_int2``: the running
    Blender's Voronoi hash API (>= 5.0: True)."""
    layers = params.layers
    theta_k, xi_k = layers_mod.layer_transforms(layers) if layers is not None else (None, None)
    layer_kw = {} if layers is None else dict(theta_k=theta_k, xi_k=xi_k, coverage=layers_mod.coverage_table()[1])
    if brdf is None and (params.mode == "reference" or (lobe_data is None and params.lobe_shape != "table")):
        brdf = material.brdf_table(params)   # table lobes render from view slices, not from this table
    if params.mode == "reference":
        return generate_reference(ReferenceSpec(
            rho_m=brdf.rho_m, rho0=brdf.rho0, gamma=brdf.gamma, layers=layers,
            use_base=params.base["type"] != "none", voronoi_int2=voronoi_int2, **layer_kw))
    if lobe_data is None:
        lobe_data = material.lobe_data(params, brdf)
    if params.lobe_shape == "table":
        lobes = dict(lobes_m=None, table=TableLobes.from_tables(lobe_data, strata=params.lobes))
    else:
        def table(entry):
            return None if entry is None else LobeTable.from_fit(entry)
        lobes = dict(lobes_m=table(lobe_data["m"]), lobes_0=table(lobe_data["0"]))
    spec = ShaderSpec(**lobes, alpha_x=lobe_data["alpha_x"], layers=layers, use_base=params.base["type"] != "none",
                      voronoi_int2=voronoi_int2, **layer_kw, **spec_options)
    return generate(spec)
