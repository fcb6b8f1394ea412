"""Generator of the specialised OSL scratch SV-BRDF shader (Raymond et al. 2016, §4.2-§5, eqs. 2, 3, 4, 7).

The generated shader is self-contained: lobe tables, layer rotations/offsets and the noise
coverage table are compiled in as constant arrays, so an INTERNAL script node renders on a
machine without the add-on.  Only the features a material uses are emitted:

- no ``node_voronoi.h`` and no α code for a dense layer (scratches everywhere, Fig. 1a);
- no γ / ρ0 code for a lossless profile (ρ0 = ρm, eq. 2 reduces to ρm);
- no ``Base`` input when the scratches cover everything or no base is wanted;
- no layer-selection code when all layers are summed.

Per shading point (world space; n = shading normal, t = UV tangent, b = n x t):
  layer k: scratch direction u_k = cos Θ_k t + sin Θ_k b, v_k = n x u_k;
  (θo, φo) = (asin(ωo.u_k), atan2(ωo.v_k, ωo.n))                                 (§4.1)
  α_k = footprint-filtered indicator [F1(y_k)]_d, y_k = diag(l, w)^-1 R(Θ_k)(u, v) + ξ_k   (eqs. 3, 7)
  ρ = Σ α_k ρ_k / max(ᾱ, 1) + max(1 - ᾱ, 0) ρ_b                                    (eq. 4)
  ρ_k(φo, ·) = Σ_j [R_γj(θo) w^m_j lobe^m_j + (1 - R_γj(θo)) w^0_j lobe^0_j]       (eq. 2 per lobe)
where a lobe is ``microfacet("ggx", N'_j, u_k, alpha_x, width_j)`` with N'_j = cos t_j n + sin t_j v_k
(see ``precompute.lobe_fit``), R_γ(θo) = (2|θo|/π)^γ and γ_j is γ at the lobe's centre.

With ``ShaderSpec.table`` (tabulated-tilt lobes, ``precompute.lobe_table``) the fitted lobes are
replaced by one narrow lobe per sample: aim bin b of the slice picked by a binary search in its CDF
(probability p_b / P), tilt drawn inside the bin with the same hash, weight W_b(θo) P / p_b with
W_b = R_γb w^m_b + (1 − R_γb) w^0_b (eq. 2 per bin); its expectation is the table slice.

Layer rotation note: eq. 7 is printed as R(Θ_k) diag(l, w)^-1; rotating *after* the stretch would
leave the scratches axis-aligned (a circle's image under the stretch does not rotate), so the UV
coordinates are rotated first, as the paper's Fig. 9 shows ("stretched and rotated").
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import const_array

#: Above this many layers, one layer is picked per shading point (probability α_k / ᾱ) so the
#: closure count stays constant; at or below it every layer is summed.
MAX_SUMMED_LAYERS = 2
#: Layers whose α_k is below this are culled (the paper's threshold, §6.1).
ALPHA_CULL = 1e-6


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
        """From ``precompute.scratch_lobes.lobe_tables`` entries (``weights`` [S, K] or [S, K, 3], ``tilts``,
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
    layers: object | None = None            # precompute.scratch_layers.LayerParams, None = dense
    theta_k: np.ndarray = field(default_factory=lambda: np.zeros(0))
    xi_k: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    coverage: np.ndarray = field(default_factory=lambda: np.zeros(0))  # c̄ on precompute.scratch_layers.COVERAGE_D
    coverage_dmax: float = 1.5
    use_base: bool = True
    lobe_mode: str = "pick"                 # "pick": one hash-picked lobe (weight / probability); "all": sum
    alpha_mode: str = "footprint"           # "footprint": eq. 3 over the ray footprint; "mean": α_k = c̄(d) (tests)
    base_pick: bool = True                  # eq. 4 by picking scratches (prob. min(ᾱ,1)) or base: one closure
    name: str = "scratch_svbrdf"
    table: "TableLobes | None" = None       # tabulated-tilt lobes instead of lobes_m / lobes_0


@dataclass
class TableLobes:
    """Tabulated-tilt lobes (``precompute.lobe_table``): per slice s and aim bin b the ρm weight
    ``w_m [S, M]``, the ρ0 weights ``w_0 [S, M, 3]`` (None: lossless), ``gamma [S, M]``, the
    bin-picking ``cdf [S, M+1]`` and ``total [S]``; ``alpha_y`` the lobes' GGX width; ``strata``
    the closures summed in ``lobe_mode="all"`` (h_k = (k + h) / strata)."""

    w_m: np.ndarray
    w_0: np.ndarray | None
    gamma: np.ndarray
    cdf: np.ndarray
    total: np.ndarray
    alpha_y: float
    strata: int = 1

    @classmethod
    def from_tables(cls, t: dict, strata: int = 1) -> "TableLobes":
        """From ``precompute.scratch_lobes.table_lobes``."""
        return cls(np.asarray(t["w_m"], float), None if t.get("w_0") is None else np.asarray(t["w_0"], float),
                   np.asarray(t["gamma"], float), np.asarray(t["cdf"], float), np.asarray(t["total"], float),
                   float(t["alpha_y"]), int(strata))

    @property
    def n_slices(self) -> int:
        return self.cdf.shape[0]

    @property
    def n_bins(self) -> int:
        return self.cdf.shape[1] - 1


def _table_arrays(t: TableLobes) -> str:
    out = const_array("TB_CDF", t.cdf.ravel()) + const_array("TB_TOT", t.total) + const_array("TB_WM", t.w_m.ravel())
    if t.w_0 is not None:
        out += const_array("TB_W0", t.w_0.ravel()) + const_array("TB_GAM", t.gamma.ravel())
    return out


def _lobe_arrays(prefix: str, t: LobeTable, jittered: bool = False) -> str:
    dist = np.zeros(len(t.tilt), int) if t.dist is None else np.asarray(t.dist, int)
    jit = np.zeros(len(t.tilt)) if t.jitter is None else np.asarray(t.jitter, float)
    return (const_array(f"{prefix}_START", t.start, "int")
            + const_array(f"{prefix}_DIST", dist, "int")
            + const_array(f"{prefix}_TILT", t.tilt)
            + const_array(f"{prefix}_AY", t.width)
            + const_array(f"{prefix}_W", t.weight.ravel())
            + const_array(f"{prefix}_GAMMA", t.gamma)
            + (const_array(f"{prefix}_JIT", jit) if jittered else ""))


def generate(spec: ShaderSpec) -> str:
    """OSL source of the specialised scratch shader for ``spec``."""
    layered = spec.layers is not None
    tab = spec.table
    if tab is None and spec.lobes_m is None:
        raise ValueError("ShaderSpec needs lobes_m (fitted lobes) or table (tabulated-tilt lobes)")
    lossless = (tab.w_0 is None) if tab is not None else spec.lobes_0 is None
    use_base = spec.use_base and layered
    ms = tab.n_slices if tab is not None else spec.lobes_m.n_slices
    if tab is None and not lossless and spec.lobes_0.n_slices != ms:
        raise ValueError("lobes_0 and lobes_m must have the same number of phi_o slices")
    n_layers = spec.layers.n_layers if layered else 1
    summed = n_layers <= MAX_SUMMED_LAYERS

    src = ['// Generated by osl/scratch_svbrdf.py -- do not edit (Raymond et al. 2016 scratch SV-BRDF).',
           '#include "stdcycles.h"']
    if layered:
        src.append('#include "node_voronoi.h"')
    if spec.lobe_mode not in ("pick", "all"):
        raise ValueError(f"lobe_mode must be 'pick' or 'all', got {spec.lobe_mode!r}")
    if tab is not None:
        # tabulated-tilt lobes (precompute.lobe_table): one sampled closure, or `strata` stratified ones
        strata = tab.strata if spec.lobe_mode == "all" else 1
        if not (isinstance(strata, (int, np.integer)) and 1 <= strata <= 64):
            raise ValueError(f"table strata must be an integer in [1, 64]; got {strata!r}")
        src.append(f"#define MS {ms}\n#define NL {n_layers}\n#define AX {spec.alpha_x:.9g}\n"
                   f"#define MB {tab.n_bins}\n#define AY_TB {tab.alpha_y:.9g}\n#define TK {strata}")
        jittered = False
        layer_lobes = _LAYER_HEAD + _RHO_TABLE[lossless]
        src.append(_TABLE_FUNC)
    else:
        per_slice = int(np.diff(spec.lobes_m.start).max(initial=0))
        if not lossless:
            per_slice += int(np.diff(spec.lobes_0.start).max(initial=0))
        src.append(f"#define MS {ms}\n#define NL {n_layers}\n#define AX {spec.alpha_x:.9g}\n"
                   f"#define KMAX2 {max(per_slice, 1)}")
        # tilt jitter (stochastic box lobes, precompute.lobe_fit): only generated when a lobe has one
        jittered = spec.lobes_m.jittered or (not lossless and spec.lobes_0.jittered)
        layer_lobes = _jitter_subst(_LAYER_HEAD + _RHO[(spec.lobe_mode, lossless)], jittered)
        funcs = _LOBE_FUNC_ALL if spec.lobe_mode == "all" else _LOBE_FUNC_PICK
        src.append(_jitter_subst(_LOBE_COMMON + funcs, jittered))
    if layered:
        src.append(_DISK_OVERLAP)
    params = []
    if use_base:
        params.append("    closure color Base = 0,")
    if layered:
        lp = spec.layers
        params += [f"    float Length = {lp.length:.9g},", f"    float Width = {lp.width:.9g},",
                   f"    float Density = {lp.density:.9g},"]
    params += ["    vector Tangent = 0,  // connect a Tangent node (UV map): the scratch direction u",
               "    color Tint = color(1.0),", "    output closure color BSDF = 0,", "    output float Alpha = 0)"]
    if layered:
        params.insert(0, "    point UV = 0,  // connect a UV Map node: scratch layers live in UV space (eq. 7)")
    src.append(f"shader {spec.name}(\n" + "\n".join(params) + "\n{")
    if tab is not None:
        body = [_table_arrays(tab)]
    else:
        body = [_lobe_arrays("LM", spec.lobes_m, jittered)]
        if not lossless:
            body.append(_lobe_arrays("L0", spec.lobes_0, jittered))
    if layered:
        body.append(const_array("THETA_K", spec.theta_k) + const_array("XI_K", np.asarray(spec.xi_k).ravel())
                    + const_array("COV", spec.coverage))
        body.append(f"    float COV_DMAX = {spec.coverage_dmax:.9g};")
    body.append(_jitter_subst(_FRAME, jittered))
    if layered:
        if spec.alpha_mode not in ("footprint", "mean"):
            raise ValueError(f"alpha_mode must be 'footprint' or 'mean', got {spec.alpha_mode!r}")
        alpha = _ALPHA if spec.alpha_mode == "footprint" else _ALPHA_MEAN
        body.append(alpha.replace("@CULL@", f"{ALPHA_CULL:.9g}"))
        scratch = (_SCRATCH_SUMMED if summed else _SCRATCH_PICKED).replace("@LAYER_LOBES@", layer_lobes)
        body.append(_EQ4[(use_base, spec.base_pick and use_base)].replace("@SCRATCH@", scratch))
    else:
        body.append("    // dense layer: scratches everywhere (Fig. 1a)\n    Alpha = 1.0;\n    float THETA_K[1] = {0.0};\n    {\n    int k = 0;"
                    + layer_lobes + "    BSDF = Tint * rho;\n    }")
    src.append("\n".join(body))
    src.append("}")
    return "\n".join(src) + "\n"


def _jitter_subst(code: str, jittered: bool) -> str:
    """Fill the @JIT...@ placeholders: the jitter arrays/arguments and the per-sample tilt offset
    ``j (2 h - 1)`` (uniform in [-j, j]; its expectation is the lobe the fit modelled), or nothing."""
    rep = {
        "@JIT_DECL_M@": ", float jm[]" if jittered else "",
        "@JIT_DECL_0@": ", float j0[]" if jittered else "",
        "@JIT_DECL_H@": ", float hj" if jittered else "",
        "@JIT_DECL@": ", float jit[], float hj" if jittered else "",
        "@JIT_M@": " + jm[q] * hj" if jittered else "",
        "@JIT_0@": " + j0[q] * hj" if jittered else "",
        "@JIT_J@": " + jit[j] * hj" if jittered else "",
        "@JIT_ARG_M@": ", LM_JIT" if jittered else "",
        "@JIT_ARG_0@": ", L0_JIT" if jittered else "",
        "@JIT_ARG_H@": ", h_jit" if jittered else "",
        "@JIT_HASH@": ("    // per-sample tilt offset in [-1, 1) of the jittered lobes\n"
                       "    float h_jit = 2.0 * hashnoise(P, dot(wo, vector(57.193, 29.917, 64.433)) + 43.0) - 1.0;\n")
        if jittered else "",
    }
    for k, v in rep.items():
        code = code.replace(k, v)
    return code


# --- OSL snippets -------------------------------------------------------------------------------
# The lobe sum lives in a macro-like function taking the lobe arrays by name (OSL passes arrays by
# reference).  R_γ(θo) = (2|θo|/π)^γ (eq. 2).
_LOBE_COMMON = r'''

// eq. 2 per lobe: rho_m lobes get R_gamma(theta_o), rho_0 lobes 1 - R_gamma, R = (2|theta_o|/pi)^gamma
float lobe_factor(float gam, float x, int use_r, int r_is_m)
{
    if (!use_r)
        return 1.0;
    float r = (x > 0.0) ? pow(x, gam) : 0.0;
    return r_is_m ? r : 1.0 - r;
}

// A lobe: GGX with its normal tilted inside the n-v plane, tangent u (precompute.lobe_fit).
// No horizon culling: the fit already accounts for what Cycles loses below the horizon, and
// lobes centred near grazing carry real energy.
closure color lobe(int beckmann, float tilt, float ay, vector u, vector v, normal n)
{
    normal Nl = normalize(cos(tilt) * n + sin(tilt) * v);
    closure color c = 0;
    if (beckmann)
        c = microfacet("beckmann", Nl, u, AX, ay, 0.0, 0);
    else
        c = microfacet("ggx", Nl, u, AX, ay, 0.0, 0);
    return c;
}

'''

_LOBE_FUNC_ALL = r'''
closure color lobe_set(int start[], int dist[], float tilt[], float ay[], float w[], float gam[]@JIT_DECL@, int s,
                       float x, vector u, vector v, normal n, int use_r, int r_is_m)
{
    closure color c = 0;
    for (int j = start[s]; j < start[s + 1]; j++)
        c += lobe_factor(gam[j], x, use_r, r_is_m) * color(w[3 * j], w[3 * j + 1], w[3 * j + 2])
             * lobe(dist[j], tilt[j]@JIT_J@, ay[j], u, v, n);
    return c;
}

'''

_LOBE_FUNC_PICK = r'''
// Pick one lobe of slice s among the rho_m lobes (weight R_gamma, or 1 when lossless) and the rho_0
// lobes (weight 1 - R_gamma), with probability proportional to the channel-mean weight, and return
// it weighted by 1 / probability. Weights are computed once (x^gamma = exp(gamma ln x)).
closure color pick_lobe(int sm[], int dm[], float tm[], float am[], float wm[], float gm[]@JIT_DECL_M@,
                        int s0[], int d0[], float t0[], float a0[], float w0[], float g0[]@JIT_DECL_0@,
                        int use0, int s, float x, float h@JIT_DECL_H@, vector u, vector v, normal n)
{
    float lw[KMAX2];
    float lx = (x > 0.0) ? log(x) : 0.0;
    int nm = sm[s + 1] - sm[s];
    int n0 = use0 ? s0[s + 1] - s0[s] : 0;
    float total = 0.0;
    for (int j = 0; j < nm; j++) {
        int q = sm[s] + j;
        float r = use0 ? ((x > 0.0) ? exp(gm[q] * lx) : 0.0) : 1.0;
        lw[j] = r * (wm[3 * q] + wm[3 * q + 1] + wm[3 * q + 2]);
        total += lw[j];
    }
    for (int j = 0; j < n0; j++) {
        int q = s0[s] + j;
        float r = (x > 0.0) ? exp(g0[q] * lx) : 0.0;
        lw[nm + j] = (1.0 - r) * (w0[3 * q] + w0[3 * q + 1] + w0[3 * q + 2]);
        total += lw[nm + j];
    }
    closure color c = 0;
    if (total <= 0.0)
        return c;
    float target = h * total, acc = 0.0;
    int pick = -1;
    for (int j = 0; j < nm + n0; j++) {
        if (lw[j] <= 0.0)
            continue;
        pick = j;
        acc += lw[j];
        if (target < acc)
            break;
    }
    if (pick < 0)
        return c;
    // weight / probability = (factor * rgb) / (factor * sum(rgb) / total) = total * rgb / sum(rgb)
    if (pick < nm) {
        int q = sm[s] + pick;
        color w = color(wm[3 * q], wm[3 * q + 1], wm[3 * q + 2]);
        c = (total / (w[0] + w[1] + w[2])) * w * lobe(dm[q], tm[q]@JIT_M@, am[q], u, v, n);
    } else {
        int q = s0[s] + pick - nm;
        color w = color(w0[3 * q], w0[3 * q + 1], w0[3 * q + 2]);
        c = (total / (w[0] + w[1] + w[2])) * w * lobe(d0[q], t0[q]@JIT_0@, a0[q], u, v, n);
    }
    return c;
}
'''

_TABLE_FUNC = r'''
// Tabulated-tilt lobes (precompute.lobe_table): pick aim bin b of slice s with probability p_b / P
// (binary search in the CDF), draw the aim phi_i uniformly inside the bin with the same number,
// tilt the narrow GGX normal to mirror the slice's phi_o into phi_i, weight W_b(theta_o) P / p_b with
// W_b = R_gamma_b w^m_b + (1 - R_gamma_b) w^0_b (eq. 2).  TK stratified closures: h_k = (k + h) / TK.
closure color table_lobes(float cdf[], float tot[], float wm[], float w0[], float gam[], int use0, int s,
                          float x, float h, vector u, vector v, normal n)
{
    closure color c = 0;
    float P = tot[s];
    if (P <= 0.0)
        return c;
    float phi_s = -M_PI_2 + (s + 0.5) * M_PI / MS;
    int base = s * (MB + 1);
    for (int k = 0; k < TK; k++) {
        float hk = (k + h) / TK;
        int lo = 0, hi = MB;
        while (hi - lo > 1) {
            int mid = (lo + hi) / 2;
            if (cdf[base + mid] <= hk) lo = mid; else hi = mid;
        }
        float c0 = cdf[base + lo], c1 = cdf[base + lo + 1];
        float fr = (c1 > c0) ? clamp((hk - c0) / (c1 - c0), 0.0, 1.0) : 0.5;
        float tilt = 0.5 * (-M_PI_2 + (lo + fr) * M_PI / MB + phi_s);
        int q = s * MB + lo;
        color W = color(wm[q]);
        float p = wm[q];
        if (use0) {
            float r = (x > 0.0) ? pow(x, gam[q]) : 0.0;
            color w_0 = color(w0[3 * q], w0[3 * q + 1], w0[3 * q + 2]);
            W = r * W + (1.0 - r) * w_0;
            p += (w_0[0] + w_0[1] + w_0[2]) / 3.0;
        }
        if (p > 0.0)
            c += (P / (p * TK)) * W * microfacet("ggx", normalize(cos(tilt) * n + sin(tilt) * v), u, AX, AY_TB, 0.0, 0);
    }
    return c;
}
'''

_RHO_TABLE = {  # lossless -> the slice's closure rho (eq. 2) from the tabulated-tilt lobes
    True: r'''
        closure color rho = table_lobes(TB_CDF, TB_TOT, TB_WM, TB_WM, TB_WM, 0, s, x, h_lobe, u, v, n);
''',
    False: r'''
        closure color rho = table_lobes(TB_CDF, TB_TOT, TB_WM, TB_W0, TB_GAM, 1, s, x, h_lobe, u, v, n);
''',
}

_DISK_OVERLAP = r'''
// Fraction of a disk footprint (radius R) covered by a scratch disk (radius a) at centre distance r:
// lens area of two circles / (pi R^2).
float disk_overlap(float a, float R, float r)
{
    if (r >= a + R) return 0.0;
    if (r <= abs(a - R)) return (a < R) ? (a * a) / (R * R) : 1.0;
    float c1 = clamp((r * r + a * a - R * R) / (2.0 * r * a), -1.0, 1.0);
    float c2 = clamp((r * r + R * R - a * a) / (2.0 * r * R), -1.0, 1.0);
    float k = (-r + a + R) * (r + a - R) * (r - a + R) * (r + a + R);
    float lens = a * a * acos(c1) + R * R * acos(c2) - 0.5 * sqrt(max(k, 0.0));
    return clamp(lens / (M_PI * R * R), 0.0, 1.0);
}
'''

_FRAME = r'''
    // Frame: n = shading normal, t = UV tangent (Tangent input, world space), b = n x t.
    // (getattribute("geom:uv"/"geom:tangent") alone does not make Cycles export the attributes:
    // the material builder links UV Map and Tangent nodes, which request them.)
    normal n = N;
    vector T = (length(Tangent) > 0.0) ? Tangent : dPdu;
    vector t = T - dot(T, n) * n;
    t = (length(t) > 1e-8) ? normalize(t) : normalize(cross(n, abs(n[0]) < 0.9 ? vector(1, 0, 0) : vector(0, 1, 0)));
    vector b = cross(n, t);
    vector wo = I;  // towards the viewer
    // Two decorrelated per-sample random numbers (OSL has no sample index; P jitters per sample).
    float h_slice = hashnoise(P, dot(wo, vector(12.9898, 78.233, 37.719)));
    float h_layer = hashnoise(P, dot(wo, vector(93.989, 67.345, 24.113)) + 17.0);
    float h_lobe = hashnoise(P, dot(wo, vector(39.346, 11.135, 83.155)) + 31.0);
@JIT_HASH@'''

_ALPHA = r'''
    // UV and its footprint. Cycles' ray differentials are isotropic (no foreshortening), so the
    // footprint is stretched by 1/cos(view) along the view direction projected into the surface.
    point uvw = UV;
    float r_uv = max(max(length(Dx(uvw)), length(Dy(uvw))), 1e-9);
    float cos_v = max(abs(dot(wo, n)), 0.05);
    float pv_t = dot(wo, t), pv_b = dot(wo, b);
    float pv_len = hypot(pv_t, pv_b);
    if (pv_len < 1e-6) { pv_t = 1.0; pv_b = 0.0; pv_len = 1.0; }
    pv_t /= pv_len; pv_b /= pv_len;
    // Ellipse semi-axes in UV: a1 across the view (r_uv), a2 along it (r_uv / cos).
    float a1u = -pv_b * r_uv, a1v = pv_t * r_uv;
    float a2u = pv_t * r_uv / cos_v, a2v = pv_b * r_uv / cos_v;

    float d = clamp(Density, 0.0, 1.0);
    float cbar;  // mean coverage c̄(d) (precompute.scratch_layers.mean_coverage), linear interpolation
    {
        float x = d / COV_DMAX * (arraylength(COV) - 1);
        int i0 = min((int)floor(x), arraylength(COV) - 2);
        cbar = mix(COV[i0], COV[i0 + 1], x - i0);
    }
    float inv_l = 1.0 / max(Length, 1e-9), inv_w = 1.0 / max(Width, 1e-9);
    float alpha[NL];
    float alpha_sum = 0.0;
    for (int k = 0; k < NL; k++) {
        float ck = cos(THETA_K[k]), sk = sin(THETA_K[k]);
        // y = diag(l, w)^-1 R(Θk) (u, v) + ξk  (eq. 7, rotation first: see the generator docstring)
        vector2 y = vector2((ck * uvw[0] + sk * uvw[1]) * inv_l + XI_K[2 * k],
                            (-sk * uvw[0] + ck * uvw[1]) * inv_w + XI_K[2 * k + 1]);
        // footprint semi-axes in noise space
        float e1x = (ck * a1u + sk * a1v) * inv_l, e1y = (-sk * a1u + ck * a1v) * inv_w;
        float e2x = (ck * a2u + sk * a2v) * inv_l, e2y = (-sk * a2u + ck * a2v) * inv_w;
        float spread = max(hypot(e1x, e1y), hypot(e2x, e2y));
        float fade = smoothstep(0.2, 0.8, spread);  // footprint spans cells: converge to c̄(d)
        float a = cbar;
        if (fade < 1.0) {
            // α over a disk footprint of radius R = spread: the disk-disk overlap with each
            // scratch disk [F1 <= d] of the 3x3 Voronoi cells (Cycles' node_voronoi.h feature
            // points), combined as a union. Exact in the sharp limit and mean-preserving.
            float R = max(spread, 1e-6);
            vector2 cell_f = vector2(floor(y.x), floor(y.y));
            int2 cell = vec2_to_int2(cell_f);
            float miss = 1.0;
            float fx = y.x - cell_f.x, fy = y.y - cell_f.y;  // position inside the cell
            float reach = d + R;
            for (int j = -1; j <= 1; j++) {
                // distance from y to the neighbour cell's box: a cell farther than d + R cannot hold
                // a feature point whose disk meets the footprint, so it is skipped before hashing
                float by = (j < 0) ? fy : ((j > 0) ? 1.0 - fy : 0.0);
                if (by >= reach) continue;
                for (int i = -1; i <= 1; i++) {
                    float bx = (i < 0) ? fx : ((i > 0) ? 1.0 - fx : 0.0);
                    if (bx * bx + by * by >= reach * reach) continue;
                    int2 off = {i, j};
                    vector2 fp = cell_f + int2_to_vec2(off) + hash_int2_to_vector2(cell + off);
                    miss *= 1.0 - disk_overlap(d, R, distance(fp, y));
                }
            }
            a = mix(1.0 - miss, cbar, fade);
        }
        alpha[k] = (a < @CULL@) ? 0.0 : a;  // layer culling (§6.1)
        alpha_sum += alpha[k];
    }
    Alpha = alpha_sum;
'''

_EQ4 = {  # (use_base, base_pick) -> eq. 4: rho = min(alpha_sum, 1) S + max(1 - alpha_sum, 0) rho_b
    (False, False): r'''
    if (alpha_sum > 0.0) {
        float h_pick = h_layer;
@SCRATCH@
        BSDF = min(alpha_sum, 1.0) * Tint * S;
    }
''',
    (True, False): r'''
    if (alpha_sum > 0.0) {
        float h_pick = h_layer;
@SCRATCH@
        BSDF = min(alpha_sum, 1.0) * Tint * S;
    }
    BSDF += max(1.0 - alpha_sum, 0.0) * Base;
''',
    (True, True): r'''
    // one closure per shading point: scratches with probability P = min(alpha_sum, 1), else the base;
    // weights min(alpha_sum, 1) / P = 1 and max(1 - alpha_sum, 0) / (1 - P) = 1
    float P_s = min(alpha_sum, 1.0);
    if (h_layer < P_s) {
        float h_pick = h_layer / P_s;
@SCRATCH@
        BSDF = Tint * S;
    } else {
        BSDF = Base;
    }
''',
}

_ALPHA_MEAN = r'''
    // alpha_mode "mean": every layer at its mean coverage c̄(d) (the far-field limit of eq. 3)
    float d = clamp(Density, 0.0, 1.0);
    float x_d = d / COV_DMAX * (arraylength(COV) - 1);
    int i_d = min((int)floor(x_d), arraylength(COV) - 2);
    float cbar = mix(COV[i_d], COV[i_d + 1], x_d - i_d);
    float alpha[NL];
    float alpha_sum = 0.0;
    for (int k = 0; k < NL; k++) {
        alpha[k] = cbar;
        alpha_sum += cbar;
    }
    Alpha = alpha_sum;
'''

_LAYER_HEAD = r'''
        float ck = cos(THETA_K[k]), sk = sin(THETA_K[k]);
        vector u = ck * t + sk * b;
        vector v = cross(n, u);
        float theta_o = asin(clamp(dot(wo, u), -1.0, 1.0));
        float phi_o = atan2(dot(wo, v), dot(wo, n));
        float x = 2.0 * abs(theta_o) / M_PI;
        // stochastic linear interpolation between the two nearest phi_o slices
        float xs = (phi_o + M_PI_2) / M_PI * MS - 0.5;
        int s = (int)floor(xs);
        if (h_slice < xs - s) s += 1;
        s = clamp(s, 0, MS - 1);
'''

_RHO = {  # (lobe_mode, lossless) -> the slice's closure rho (eq. 2)
    ("pick", True): r'''
        closure color rho = pick_lobe(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA@JIT_ARG_M@,
                                      LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA@JIT_ARG_M@, 0, s, x,
                                      h_lobe@JIT_ARG_H@, u, v, n);
''',
    ("pick", False): r'''
        closure color rho = pick_lobe(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA@JIT_ARG_M@,
                                      L0_START, L0_DIST, L0_TILT, L0_AY, L0_W, L0_GAMMA@JIT_ARG_0@, 1, s, x,
                                      h_lobe@JIT_ARG_H@, u, v, n);
''',
    ("all", True): r'''
        closure color rho = lobe_set(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA@JIT_ARG_M@@JIT_ARG_H@, s, x,
                                     u, v, n, 0, 1);
''',
    ("all", False): r'''
        closure color rho = lobe_set(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA@JIT_ARG_M@@JIT_ARG_H@, s, x,
                                     u, v, n, 1, 1)
                          + lobe_set(L0_START, L0_DIST, L0_TILT, L0_AY, L0_W, L0_GAMMA@JIT_ARG_0@@JIT_ARG_H@, s, x,
                                     u, v, n, 1, 0);
''',
}


_SCRATCH_SUMMED = r'''
    // every layer: S = sum_k (alpha_k / alpha_sum) rho_k
    closure color S = 0;
    for (int k = 0; k < NL; k++) {
        if (alpha[k] <= 0.0) continue;
@LAYER_LOBES@
        S += (alpha[k] / alpha_sum) * rho;
    }
'''

_SCRATCH_PICKED = r'''
    // one layer, picked with probability alpha_k / alpha_sum (weight / probability = 1)
    closure color S = 0;
    {
        int k = NL - 1;
        float acc = 0.0;
        for (int j = 0; j < NL; j++) {
            acc += alpha[j];
            if (h_pick * alpha_sum < acc) { k = j; break; }
        }
@LAYER_LOBES@
        S = rho;
    }
'''



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

    #: Largest table compiled into the source (5 M² floats; larger tables make OSL compile slowly).
    MAX_M = 128


def generate_reference(spec: ReferenceSpec) -> str:
    """OSL source of the exact-table reference shader (eq. 2 and eq. 5 by importance sampling)."""
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
    use_base = spec.use_base and layered
    src = ["// Generated by osl/scratch_svbrdf.py (reference mode) -- validation only.", '#include "stdcycles.h"']
    if layered:
        src.append('#include "node_voronoi.h"')
        src.append(_DISK_OVERLAP)
    src.append(f"#define M {M}\n#define NL {spec.layers.n_layers if layered else 1}")
    params = []
    if layered:
        lp = spec.layers
        params += ["    point UV = 0,", f"    float Length = {lp.length:.9g},", f"    float Width = {lp.width:.9g},",
                   f"    float Density = {lp.density:.9g},"]
    if use_base:
        params.append("    closure color Base = 0,")
    params += ["    vector Tangent = 0,", "    color Tint = color(1.0),", "    output closure color BSDF = 0,",
               "    output float Alpha = 0)"]
    src.append(f"shader {spec.name}(\n" + "\n".join(params) + "\n{")
    body = [const_array("RHO_M", rho_m.ravel()), const_array("RHO_0", rho0.ravel()), const_array("GAM", gamma.ravel()),
            const_array("CDF", cdf.ravel()), const_array("TOTAL", total), const_array("EDGE_SIN", np.sin(edges))]
    if layered:
        body.append(const_array("THETA_K", spec.theta_k) + const_array("XI_K", np.asarray(spec.xi_k).ravel())
                    + const_array("COV", spec.coverage))
        body.append(f"    float COV_DMAX = {spec.coverage_dmax:.9g};")
    body.append(_jitter_subst(_FRAME, False))
    body.append("    float h_phi = hashnoise(P, dot(wo, vector(71.17, 5.31, 47.77)) + 47.0);")
    if layered:
        body.append(_ALPHA.replace("@CULL@", f"{ALPHA_CULL:.9g}"))
        body.append(_REF_PICK_LAYER)
    else:
        body.append("    Alpha = 1.0;\n    float THETA_K[1] = {0.0};\n    int k = 0;\n    float scale = 1.0;")
    body.append(_REF_SAMPLE)
    if use_base:
        body.append("    BSDF += max(1.0 - alpha_sum, 0.0) * Base;")
    src.append("\n".join(body))
    src.append("}")
    return "\n".join(src) + "\n"


_REF_PICK_LAYER = r'''
    int k = NL - 1;
    float scale = min(alpha_sum, 1.0);
    {
        float acc = 0.0;
        for (int j = 0; j < NL; j++) {
            acc += alpha[j];
            if (h_layer * alpha_sum < acc) { k = j; break; }
        }
    }
    if (alpha_sum <= 0.0) scale = 0.0;
'''

_REF_SAMPLE = r'''
    if (scale > 0.0) {
        float ck = cos(THETA_K[k]), sk = sin(THETA_K[k]);
        vector u = ck * t + sk * b;
        vector v = cross(n, u);
        float theta_o = asin(clamp(dot(wo, u), -1.0, 1.0));
        float phi_o = atan2(dot(wo, v), dot(wo, n));
        int o = clamp((int)floor((phi_o + M_PI_2) / M_PI * M), 0, M - 1);
        if (TOTAL[o] > 0.0) {
            // inverse CDF over phi_i bins (rho_m cos, Raymond et al. 2016 §5.1), cos-distributed inside the bin
            int i = 0;
            for (int j = 0; j < M; j++) {
                if (h_phi < CDF[o * (M + 1) + j + 1]) { i = j; break; }
                i = j;
            }
            float lo = CDF[o * (M + 1) + i], hi = CDF[o * (M + 1) + i + 1];
            float f = (hi > lo) ? (h_phi - lo) / (hi - lo) : 0.5;
            float s_phi = mix(EDGE_SIN[i], EDGE_SIN[i + 1], clamp(f, 0.0, 1.0));
            float phi_i = asin(clamp(s_phi, -1.0, 1.0));
            float rm = RHO_M[o * M + i];
            // eq. 2 with gamma of this bin; weight = rho_s cos / pdf = (rho_s / rho_m) * TOTAL[o]
            float x = 2.0 * abs(theta_o) / M_PI;
            float r = (x > 0.0) ? pow(x, GAM[o * M + i]) : 0.0;
            color r0 = color(RHO_0[3 * (o * M + i)], RHO_0[3 * (o * M + i) + 1], RHO_0[3 * (o * M + i) + 2]);
            color rho_s = r * rm + (1.0 - r) * r0;
            color weight = (rm > 0.0) ? rho_s / rm * TOTAL[o] : color(0.0);
            vector wi = -sin(theta_o) * u + cos(theta_o) * (sin(phi_i) * v + cos(phi_i) * n);
            BSDF = scale * Tint * weight * ray_portal_bsdf(P, normalize(wi));
        }
    }
'''
