"""Bi-scale material generator: effective large-scale BRDF of a small-scale tile
(Wu, Dorsey, Rushmeier 2011, "Physically-based interactive bi-scale material design", §3).

Pipeline (names from the paper):

1. facets (§3.2): ``sample_facets`` — area-proportional samples with normals n_s and
   estimated areas ΔA_s;
2. visibility (§3.3): V[s, d] by exact ray casting against the infinitely repeated tile
   (``biscale_visibility``) for the D = ``dir_res``^2 hemi-octahedral directions;
3. a_v(ωo) = Σ_s V_s(ωo) (n_s·ωo)+ ΔA_s (eq. 10);
4. BVNDF N_kj = Σ_s V_s(ωi,k) V_s(ωo,k) δ̃(n_s, n_j) ΔA_s (eq. 11) per facet group
   (material x colour weight, §3.7), δ̃ a bilinear splat on an octahedral normal grid over
   S^2, k over the reciprocal pairs (i <= o) only, compressed by random-projection SVD
   (Table 2, mean subtracted, ``power_N`` of the power kept);
5. M_kj = f_r(n_j, ωi,k, ωo,k) (n_j·ωi)(n_j·ωo) (eqs. 4, 9) per BRDF lobe, computed once
   in row chunks, compressed by streamed random-projection SVD (``power_M``) and cached
   on disk (``precompute.tables.cache``) and in memory.  The column of the pole n = (0, 0, 1) is
   kept exactly besides the SVD (flat parts of tiles are the most common facets, and a
   flat tile must give back its small-scale BRDF exactly);
6. f̄r(ωi,k, ωo,k) = (1/a_v(ωo,k)) Σ_j N_kj M_kj via the factors (eq. 12); RGB =
   Σ_groups Σ_lobes colour weight x lobe colour x scalar result.

The returned ``EffectiveBRDF`` stores the *standard* BRDF f = f̄r / cos θi (1/sr) on the
D x D direction grid, made exactly reciprocal by averaging the two one-sided
normalisations ((T + T^T)/2, T_io = Σ_j N M / (a_v(ωo) cos θi)); ``.eval`` interpolates it
bilinearly in both hemi-octahedral maps (16 taps), which preserves reciprocity.

Edits: ``BiscaleTile`` keeps facets, visibility and the compressed N; colour-weight edits
redo only step 4 (visibility reused), material edits only step 6 (M comes from the cache).
"""
from __future__ import annotations

import difflib
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..tables.tabulated_brdf import hemisphere_midpoints
from ..tables import cache as _cache
from ..tables import exr_io
from .brdfs import Lobe, eval_material, material_lobes
from .directions import direction_bilinear, direction_grid, normal_grid, normal_splat, pole_index
from .geometry import Tile, face_geometry, is_closed_surface, sample_facets, validate_tile
from .svd import LowRank, random_projection_svd, random_projection_svd_streamed
from .visibility import visibility_matrix

__all__ = ["BiscaleTile", "EffectiveBRDF", "effective_brdf", "precompute_M", "brute_force_fr", "brute_force_fr_at", "psnr",
           "DEFAULTS", "check_options", "render_reference_fr"]

M_VERSION = "1"
DEFAULTS = dict(n_facets=10000, dir_res=10, normal_res=81, smooth_normals=False, seed=0,
                power_N=0.9999, l_N=60, power_M=0.9999, l_M=160, n_power_M=1, use_cache=True)

_M_MEMO: dict = {}


# ----------------------------------------------------------------------------- M (eq. 9)
@dataclass
class MFactors:
    """Compressed pre-rotated cosine-weighted BRDF matrix of one lobe: M ≈ 1 μ^T + U V^T
    (K x J), plus the exact pole column ``Mz`` (K,)."""
    mean: np.ndarray
    U: np.ndarray
    V: np.ndarray
    Mz: np.ndarray
    power: float
    seconds: float = 0.0


def _pairs(D):
    return np.triu_indices(D)


def _M_rows(lobe: Lobe, dirs: np.ndarray, normals: np.ndarray):
    """Row-chunk generator of M (eqs. 4, 9): rows k = reciprocal direction pairs, columns j = normals."""
    ia, ib = _pairs(len(dirs))
    cosND = normals @ dirs.T          # (J, D)  n_j · ω_d
    cio_all = dirs @ dirs.T

    def rows(a, b):
        i, o = ia[a:b], ib[a:b]
        ci = cosND[:, i].T            # (k, J)
        co = cosND[:, o].T
        cio = cio_all[i, o][:, None]
        ok = (ci > 0) & (co > 0)
        a, b_, c = np.where(ok, ci, 1.0), np.where(ok, co, 1.0), np.broadcast_to(cio, ci.shape)
        f = lobe(a, b_, c) if lobe.reciprocal else 0.5 * (lobe(a, b_, c) + lobe(b_, a, c))   # M is reciprocal
        return np.where(ok, f * ci * co, 0.0)
    return rows, len(ia)


def precompute_M(lobe: Lobe, dir_res: int = DEFAULTS["dir_res"], normal_res: int = DEFAULTS["normal_res"],
                 power: float = DEFAULTS["power_M"], l: int = DEFAULTS["l_M"], n_power: int = DEFAULTS["n_power_M"],
                 seed: int = 0, use_cache: bool = True) -> MFactors:
    """Pre-rotated cosine-weighted BRDF matrix M of one lobe (eqs. 4, 9; §3.5), compressed by
    the streamed random-projection SVD (Table 2) keeping ``power`` of its power, and cached
    (disk via ``precompute.tables.cache`` keyed by the lobe and all parameters, plus memory)."""
    key = (lobe.key, dir_res, normal_res, power, l, n_power, seed)
    if key in _M_MEMO:
        return _M_MEMO[key]
    dirs, normals = direction_grid(dir_res), normal_grid(normal_res)
    t0 = time.perf_counter()

    def compute():
        rows, K = _M_rows(lobe, dirs, normals)
        lr = random_projection_svd_streamed(rows, K, len(normals), l=l, power=power, n_power=n_power,
                                            seed=seed, chunk=max(64, 2_000_000 // len(normals)))
        pole, _ = _M_rows(lobe, dirs, normals[[pole_index(normal_res)]])   # the pole column alone
        Mz = np.concatenate([pole(a, min(a + 65536, K))[:, 0] for a in range(0, K, 65536)])
        return {"mean": lr.mean.astype(np.float32), "U": lr.U.astype(np.float32), "V": lr.V.astype(np.float32),
                "Mz": Mz.astype(np.float32), "power": np.array([lr.power], np.float32)}

    inputs = {"lobe": lobe.key, "dir_res": dir_res, "normal_res": normal_res, "power": power, "l": l,
              "n_power": n_power, "seed": seed}
    arr = _cache.cached_arrays("biscale_M", M_VERSION, inputs, compute, enabled=use_cache)
    mf = MFactors(arr["mean"].astype(np.float64), arr["U"].astype(np.float64), arr["V"].astype(np.float64),
                  arr["Mz"].astype(np.float64), float(arr["power"][0]), time.perf_counter() - t0)
    _M_MEMO[key] = mf
    return mf


# ----------------------------------------------------------------------------- result
@dataclass
class EffectiveBRDF:
    """Effective large-scale BRDF on a hemi-octahedral grid (``dir_res``^2 directions).

    ``table[i, o, c]`` is the standard (reciprocal) BRDF f(ωi, ωo) = f̄r / cos θi in 1/sr."""
    table: np.ndarray
    dir_res: int
    info: dict = field(default_factory=dict)

    @property
    def directions(self) -> np.ndarray:
        return direction_grid(self.dir_res)

    def fr_cos(self) -> np.ndarray:
        """Tabulated f̄r of eq. 7 (= f cos θi), shape (D, D, 3)."""
        return self.table * self.directions[:, 2][:, None, None]

    def eval(self, wi, wo) -> np.ndarray:
        """Standard BRDF (N, 3) in 1/sr at unit directions wi, wo (N, 3) (z = large-scale normal);
        bilinear in both hemi-octahedral maps; 0 where either direction is below the horizon."""
        wi = np.atleast_2d(np.asarray(wi, np.float64))
        wo = np.atleast_2d(np.asarray(wo, np.float64))
        if wi.shape[-1] != 3 or wo.shape[-1] != 3 or wi.shape != wo.shape:
            raise ValueError(f"wi, wo: expected two (N, 3) arrays of equal shape, got {wi.shape} and {wo.shape}")
        if not (np.all(np.isfinite(wi)) and np.all(np.isfinite(wo))):
            raise ValueError("wi, wo: contain NaN or inf")
        ii, wti = direction_bilinear(wi, self.dir_res)
        io, wto = direction_bilinear(wo, self.dir_res)
        vals = self.table[ii[:, :, None], io[:, None, :]]            # (N, 4, 4, 3)
        out = np.einsum("na,nb,nabc->nc", wti, wto, vals)
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(above[:, None], out, 0.0)

    def albedo(self, n_theta: int = 64, n_phi: int = 128) -> np.ndarray:
        """Directional albedo ∫ f(ωi, ωo) cos θi dωi (RGB) for every grid direction ωo, by a
        midpoint rule in (cos θi, φi) on ``.eval`` — the white-furnace quantity."""
        wi, dw = hemisphere_midpoints(n_theta, n_phi)
        out = []
        for wo in self.directions:
            f = self.eval(wi, np.broadcast_to(wo, wi.shape))
            out.append((f * wi[:, 2:3]).sum(0) * dw)
        return np.array(out)

    def save_exr(self, path) -> None:
        """Write the table as a float EXR (``precompute.tables.exr_io``): channels R, G, B of shape
        (D, D), row = ωi index, column = ωo index on ``direction_grid(dir_res)``."""
        meta = {"kind": "biscale_effective_brdf", "dir_res": int(self.dir_res),
                "parametrisation": "hemi-octahedral cell-centred; index = row*res+col, s=px+py, t=px-py",
                "value": "standard BRDF f = fr_bar / cos(theta_i), 1/sr, reciprocal",
                **{k: v for k, v in self.info.items() if isinstance(v, (int, float, str))}}
        exr_io.write_exr(path, {c: self.table[..., k].astype(np.float32) for k, c in enumerate("RGB")}, meta,
                         finite=True)

    @classmethod
    def load_exr(cls, path) -> "EffectiveBRDF":
        ch, meta = exr_io.read_exr(path, finite=True)
        if not isinstance(meta, dict) or meta.get("kind") != "biscale_effective_brdf":
            raise exr_io.ExrError(f"{path}: not a bi-scale effective BRDF table")
        return cls(np.stack([ch[c] for c in "RGB"], -1).astype(np.float64), int(meta["dir_res"]), meta)


# ----------------------------------------------------------------------------- options
#: integer options: (lo, hi); ``normal_res`` must also be odd (a cell-centred grid with a pole cell)
_INT_OPTS = {"n_facets": (16, 1_000_000), "dir_res": (2, 64), "normal_res": (5, 201), "seed": (0, 2**63 - 1),
             "l_N": (1, 1024), "l_M": (1, 1024), "n_power_M": (0, 10)}
_FRACTION_OPTS = ("power_N", "power_M")
_BOOL_OPTS = ("smooth_normals", "use_cache")


def check_options(opts: dict, also_accepted: tuple = ()) -> dict:
    """The bi-scale tile options (``DEFAULTS`` completed by ``opts``; keys in ``also_accepted`` are the
    caller's own and skipped), every one checked up front so a
    bake never fails half-way on one: ValueError naming the option as the caller spelt it (the keyword
    of ``bake_tables`` / ``BiscaleTile``, not the name of an inner function's parameter) and what is
    accepted.  ``l_N``, ``l_M``: sketch sizes of the random-projection SVD (Table 2), bounded so that
    memory stays bounded; ``power_*``: fraction of the power kept (§3.5)."""
    accepted = [*also_accepted, *DEFAULTS]
    unknown = [k for k in opts if k not in accepted]
    if unknown:
        close = difflib.get_close_matches(unknown[0], accepted, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        raise ValueError(f"unknown bi-scale option {unknown[0]!r}{hint}; accepted: {', '.join(accepted)}")
    o = {**DEFAULTS, **{k: v for k, v in opts.items() if k in DEFAULTS}}
    for name, (lo, hi) in _INT_OPTS.items():
        v = o[name]
        odd = name == "normal_res"
        if (isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi
                or (odd and v % 2 == 0)):
            what = "a non-negative integer" if name == "seed" else f"an {'odd ' if odd else ''}integer in [{lo}, {hi}]"
            raise ValueError(f"{name}: expected {what}, got {v!r}")
        o[name] = int(v)
    for name in _FRACTION_OPTS:
        v = o[name]
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = math.nan
        if isinstance(v, (bool, np.bool_, str)) or not 0.0 < x <= 1.0:
            raise ValueError(f"{name}: expected a fraction in (0, 1], got {v!r}")
        o[name] = x
    for name in _BOOL_OPTS:
        if not isinstance(o[name], (bool, np.bool_)):
            raise ValueError(f"{name}: expected True or False, got {o[name]!r}")
        o[name] = bool(o[name])
    return o


# ----------------------------------------------------------------------------- tile
class BiscaleTile:
    """A periodic small-scale tile with cached facets, visibility and BVNDF (§3.2-3.4).

    ``color_weights``: per-face (F, 3) or per-vertex (V, 3) RGB weights α (§3.7), default 1.
    See ``DEFAULTS`` for the options.  ``.effective_brdf(materials)`` is the fast path."""

    def __init__(self, vertices, faces, face_material=None, period: float = 1.0, color_weights=None, **opts):
        self.opts = check_options(opts)
        o = self.opts
        self.tile: Tile = validate_tile(vertices, faces, face_material, period)
        self.dirs = direction_grid(o["dir_res"])
        self.normals = normal_grid(o["normal_res"])
        rng = np.random.default_rng(o["seed"])
        t0 = time.perf_counter()
        self.pos, self.n, self.dA, self.face, self.bary = sample_facets(self.tile, int(o["n_facets"]), rng,
                                                                        o["smooth_normals"])
        self.timings = {"facets": time.perf_counter() - t0}
        self.facet_material = self.tile.face_material[self.face]
        self._V = None
        self._N = None
        self.set_color_weights(color_weights)

    # -- colour weights (§3.7)
    def set_color_weights(self, color_weights=None) -> None:
        """Set per-face (F, 3) or per-vertex (V, 3) colour weights; invalidates only N."""
        F, Vn = len(self.tile.faces), len(self.tile.vertices)
        if color_weights is None:
            alpha = np.ones((len(self.pos), 3))
        else:
            w = np.asarray(color_weights, np.float64)
            if w.ndim != 2 or w.shape[1] != 3 or not np.all(np.isfinite(w)) or w.min() < 0 or w.max() > 1e3:
                raise ValueError(f"color_weights: expected (F, 3) per face or (V, 3) per vertex, finite in [0, 1000], "
                                 f"got shape {w.shape}")
            if w.shape[0] == Vn:
                alpha = np.einsum("sk,skc->sc", self.bary, w[self.tile.faces[self.face]])
            elif w.shape[0] == F:
                alpha = w[self.face]
            else:
                raise ValueError(f"color_weights: expected {F} rows (faces) or {Vn} rows (vertices), got {w.shape[0]}")
        self.alpha = alpha
        self._N = None

    # -- visibility (§3.3) and a_v (eq. 10)
    @property
    def visibility(self) -> np.ndarray:
        if self._V is None:
            t0 = time.perf_counter()
            tri = self.tile.vertices[self.tile.faces]
            _, fn = face_geometry(self.tile.vertices, self.tile.faces)
            self.closed = is_closed_surface(self.tile)
            self._V = visibility_matrix(tri, self.tile.period, self.pos, self.dirs,
                                        point_normals=fn[self.face], closed=self.closed)
            self.timings["visibility"] = time.perf_counter() - t0
            cos = np.clip(self.n @ self.dirs.T, 0.0, None)
            self.a_v = (self._V * cos * self.dA[:, None]).sum(0)   # eq. 10
        return self._V

    # -- BVNDF (eq. 11)
    def _groups(self):
        """Facet groups (§3.7): (material, colour) groups when a material has <= 8 distinct colour
        weights, else 3 channel groups with weights ΔA_s α_s,c.  Returns [(material, beta (3,), weight (S,))]."""
        groups = []
        for m in np.unique(self.facet_material):
            sel = self.facet_material == m
            cols, inv = np.unique(self.alpha[sel], axis=0, return_inverse=True)
            inv = inv.ravel()
            if len(cols) <= 8:
                for g, c in enumerate(cols):
                    w = np.zeros(len(self.pos))
                    idx = np.flatnonzero(sel)[inv == g]
                    w[idx] = self.dA[idx]
                    groups.append((int(m), c.copy(), w))
            else:
                for ch in range(3):
                    w = np.where(sel, self.dA * self.alpha[:, ch], 0.0)
                    groups.append((int(m), np.eye(3)[ch], w))
        return groups

    def bvndf(self):
        """Compressed BVNDF per facet group (eq. 11 + Table 2): list of dicts with keys
        material, beta, act (active normal indices), N (LowRank over act).  Cached."""
        if self._N is not None:
            return self._N
        V = self.visibility
        t0 = time.perf_counter()
        o = self.opts
        ia, ib = _pairs(len(self.dirs))
        K = len(ia)
        sidx, swt = normal_splat(self.n, o["normal_res"])
        out = []
        for m, beta, w in self._groups():
            rows_s = np.flatnonzero(w > 0)
            if rows_s.size == 0:
                continue
            J = len(self.normals)
            B = sp.csr_matrix((swt[rows_s].ravel(), (np.repeat(np.arange(rows_s.size), 4), sidx[rows_s].ravel())),
                              shape=(rows_s.size, J))
            act = np.flatnonzero(np.asarray(abs(B).sum(0)).ravel() > 0)
            Bt = sp.csr_matrix(B[:, act].T.multiply(w[rows_s][None, :]), dtype=np.float32)  # (J_act, S_g), ΔA folded in
            Vg = V[rows_s].astype(np.float32)
            N = np.empty((K, act.size), np.float32)
            step = max(1, 8_000_000 // max(rows_s.size, 1))
            for a in range(0, K, step):                             # chunks of direction pairs
                b = min(a + step, K)
                Y = Vg[:, ia[a:b]]
                Y *= Vg[:, ib[a:b]]                                 # V_s(ωi) V_s(ωo), (S_g, k) float32
                N[a:b] = (Bt @ Y).T
            lr = random_projection_svd(N, l=int(o["l_N"]), power=float(o["power_N"]), seed=o["seed"])
            out.append({"material": m, "beta": beta, "act": act, "N": lr})
        self._N = out
        self.timings["bvndf"] = time.perf_counter() - t0
        return out

    # -- eq. 12
    def _lobe_product(self, g, mf: MFactors) -> np.ndarray:
        """Σ_j N_kj M_kj for one group and one lobe from the factors (eq. 12), shape (K,)."""
        lr: LowRank = g["N"]
        act = g["act"]
        pole = pole_index(self.opts["normal_res"])
        m = act != pole
        muN, VN = lr.mean[m], lr.V[m]
        muM, VM = mf.mean[act[m]], mf.V[act[m]]
        s = muN @ muM + lr.U @ (VN.T @ muM) + mf.U @ (VM.T @ muN)
        s += np.einsum("kr,kr->k", lr.U @ (VN.T @ VM), mf.U)
        if not m.all():
            p = np.flatnonzero(~m)[0]
            s += (lr.mean[p] + lr.U @ lr.V[p]) * mf.Mz
        return s

    def effective_brdf(self, materials) -> EffectiveBRDF:
        """Effective BRDF of this tile for ``materials`` (list of dicts, indexed by face_material)."""
        if not isinstance(materials, (list, tuple)) or len(materials) == 0:
            raise ValueError("materials: expected a non-empty list of material dicts")
        if self.tile.face_material.max() >= len(materials):
            raise ValueError(f"face_material: indices must be in [0, {len(materials) - 1}] for {len(materials)} "
                             f"materials, got max {self.tile.face_material.max()}")
        lobes = [material_lobes(mt) for mt in materials]
        o = self.opts
        t_m = time.perf_counter()
        Ms = {lb.key: precompute_M(lb, o["dir_res"], o["normal_res"], o["power_M"], o["l_M"], o["n_power_M"],
                                   0, o["use_cache"]) for ls in lobes for lb in ls}
        t_m = time.perf_counter() - t_m
        groups = self.bvndf()
        t0 = time.perf_counter()
        D = len(self.dirs)
        ia, ib = _pairs(D)
        S = np.zeros((len(ia), 3))
        for g in groups:                                   # few groups x few lobes
            for lb in lobes[g["material"]]:
                S += self._lobe_product(g, Ms[lb.key])[:, None] * (g["beta"] * np.asarray(lb.colour))[None, :]
        full = np.zeros((D, D, 3))
        full[ia, ib] = S
        full[ib, ia] = S
        cos = self.dirs[:, 2]
        a_v = self.a_v
        with np.errstate(divide="ignore", invalid="ignore"):
            T = np.where(a_v[None, :, None] > 1e-12, full / (a_v[None, :, None] * cos[:, None, None]), 0.0)
        T = 0.5 * (T + T.transpose(1, 0, 2))
        n_neg = int((T < 0).sum())
        T = np.maximum(T, 0.0)
        info = {"n_facets": len(self.pos), "dir_res": o["dir_res"], "normal_res": o["normal_res"],
                "rank_N": int(max(g["N"].rank for g in groups)), "rank_M": int(max(m.U.shape[1] for m in Ms.values())),
                "power_N": float(min(g["N"].power for g in groups)), "power_M": float(min(m.power for m in Ms.values())),
                "negatives_clamped": n_neg, "seconds_M": t_m, "seconds_product": time.perf_counter() - t0}
        return EffectiveBRDF(T, o["dir_res"], info)


def effective_brdf(vertices, faces, face_material, materials, **opts) -> EffectiveBRDF:
    """Effective large-scale BRDF (eq. 7, via eqs. 8-12) of a periodic small-scale tile.

    ``vertices`` (V, 3), ``faces`` (F, 3), ``face_material`` (F,) index into ``materials``
    (list of dicts, see ``precompute.biscale.brdfs``).  Options: ``period`` (tile side,
    default 1), ``color_weights`` ((F, 3) or (V, 3)), and ``DEFAULTS`` keys.  Returns an
    ``EffectiveBRDF`` whose ``.eval(wi, wo)`` is the reciprocal standard BRDF (1/sr)."""
    period = opts.pop("period", 1.0)
    cw = opts.pop("color_weights", None)
    tile = BiscaleTile(vertices, faces, face_material, period=period, color_weights=cw, **opts)
    return tile.effective_brdf(materials)


# ----------------------------------------------------------------------------- references
def brute_force_fr(tile: BiscaleTile, materials, chunk: int = 256, pairs=None) -> np.ndarray:
    """Direct eq. 8 without binning or SVD: f̄r(ωi, ωo) = Σ_s V_s(ωi) V_s(ωo) ΔA_s α_s
    f_r(n_s, ωi, ωo)(n_s·ωi)(n_s·ωo) / a_v(ωo), with each facet's own normal and the full RGB
    BRDF, for all D x D grid pairs.  Returns (D, D, 3) (eq. 7's f̄r, cosine-weighted).

    ``pairs``: optional (i, o) index arrays of grid pairs to compute (the others stay 0); the cost
    is proportional to their number (used by the benchmark to time a subset)."""
    V = tile.visibility
    dirs = tile.dirs
    D = len(dirs)
    out = np.zeros((D, D, 3))
    mats = [material_lobes(m) for m in materials]
    if pairs is None:
        ia, ib = np.meshgrid(np.arange(D), np.arange(D), indexing="ij")
        ia, ib = ia.ravel(), ib.ravel()
    else:
        ia, ib = (np.asarray(p, np.int64).ravel() for p in pairs)
        if ia.shape != ib.shape or ia.size == 0 or min(ia.min(), ib.min()) < 0 or max(ia.max(), ib.max()) >= D:
            raise ValueError(f"pairs: expected two equal-length non-empty index arrays in [0, {D - 1}]")
    for a in range(0, len(ia), chunk):      # chunks of direction pairs, vectorised over facets
        i, o = ia[a:a + chunk], ib[a:a + chunk]
        vis = (V[:, i] & V[:, o]) * tile.dA[:, None]     # (S, k)
        acc = np.zeros((len(i), 3))
        for m, lobes in enumerate(mats):
            sel = np.flatnonzero(tile.facet_material == m)
            if sel.size == 0:
                continue
            n = tile.n[sel][:, None, :]
            f = eval_material(lobes, n, dirs[i][None], dirs[o][None])   # (S_m, k, 3)
            cw = (n * dirs[i][None]).sum(-1).clip(0) * (n * dirs[o][None]).sum(-1).clip(0)
            acc += np.einsum("sk,skc,sc->kc", vis[sel] * cw, f, tile.alpha[sel])
        out[i, o] = acc / np.maximum(tile.a_v[o], 1e-300)[:, None]
    return out


def brute_force_fr_at(tile: BiscaleTile, materials, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Direct eq. 8 (as ``brute_force_fr``) at arbitrary direction pairs ``wi``, ``wo`` (P, 3),
    z > 0, with the visibility of the tile's facets ray cast for exactly those directions.
    Returns (P, 3) f̄r (cosine-weighted).  Used to measure the interpolation error of
    ``EffectiveBRDF.eval`` between grid directions."""
    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    if wi.shape != wo.shape or wi.shape[-1] != 3 or np.any(wi[:, 2] <= 0) or np.any(wo[:, 2] <= 0):
        raise ValueError("wi, wo: expected two (P, 3) arrays of equal shape with z > 0")
    tri = tile.tile.vertices[tile.tile.faces]
    _, fn = face_geometry(tile.tile.vertices, tile.tile.faces)
    dirs = np.concatenate([wi, wo])
    Vd = visibility_matrix(tri, tile.tile.period, tile.pos, dirs, point_normals=fn[tile.face],
                           closed=is_closed_surface(tile.tile))
    P = len(wi)
    Vi, Vo = Vd[:, :P], Vd[:, P:]
    a_v = (Vo * np.clip(tile.n @ wo.T, 0, None) * tile.dA[:, None]).sum(0)      # eq. 10
    out = np.zeros((P, 3))
    for m, mat in enumerate(materials):
        sel = np.flatnonzero(tile.facet_material == m)
        if sel.size == 0:
            continue
        n = tile.n[sel][:, None, :]
        f = eval_material(mat, n, wi[None], wo[None])                            # (S_m, P, 3)
        cw = (n * wi[None]).sum(-1).clip(0) * (n * wo[None]).sum(-1).clip(0)
        out += np.einsum("sp,spc,sc->pc", Vi[sel] * Vo[sel] * tile.dA[sel, None] * cw, f, tile.alpha[sel])
    return out / np.maximum(a_v, 1e-300)[:, None]


def render_reference_fr(tile: Tile, materials, wi: np.ndarray, wo: np.ndarray, n_rays: int = 4096,
                        seed: int = 0, face_color_weights=None) -> np.ndarray:
    """The paper's ground truth (§6) by Monte Carlo: for each pair, "render" the repeated tile
    seen from ωo (primary rays along -ωo through uniform points of the footprint, i.e.
    uniform in visible projected area), shade the first hit with a directional light from ωi
    (shadow ray towards ωi) and average V(ωi) f_r(n, ωi, ωo) (n·ωi)+ α.  That average is
    eq. 7's f̄r.  Independent of facet sampling, normal binning and SVD; shares only the
    ray caster.  ``wi``, ``wo`` (P, 3); returns (P, 3)."""
    from .visibility import TorusGrid, first_hit, occluded

    wi = np.atleast_2d(np.asarray(wi, np.float64))
    wo = np.atleast_2d(np.asarray(wo, np.float64))
    tri = tile.vertices[tile.faces]
    _, fn = face_geometry(tile.vertices, tile.faces)
    alpha = np.ones((len(tile.faces), 3)) if face_color_weights is None else np.asarray(face_color_weights, np.float64)
    mats = [material_lobes(m) for m in materials]
    P = tile.period
    z_top = tri[..., 2].max() + 0.01 * P
    eps = 1e-7 * (P + np.ptp(tri[..., 2]))
    rng = np.random.default_rng(seed)
    out = np.zeros((len(wi), 3))
    for o_dir in np.unique(wo, axis=0):                      # loop over view directions
        go = TorusGrid(tri, P, o_dir)
        g = int(np.sqrt(n_rays))
        jit = rng.random((g * g, 2))
        u = (np.stack(np.meshgrid(np.arange(g), np.arange(g), indexing="ij"), -1).reshape(-1, 2) + jit) / g * P
        zh, tid = first_hit(go, u, z_top)
        ok = tid >= 0
        pts = np.concatenate([u + zh[:, None] * go.shear, zh[:, None]], 1)[ok]
        t = tid[ok]
        n = fn[t]
        for k in np.flatnonzero(np.all(wo == o_dir, axis=1)):   # light directions for this view
            vis = ~occluded(TorusGrid(tri, P, wi[k]), pts, eps)
            val = np.zeros((len(t), 3))
            for m, lobes in enumerate(mats):
                sel = tile.face_material[t] == m
                if sel.any():
                    f = eval_material(lobes, n[sel], wi[k][None], o_dir[None])
                    val[sel] = f * np.clip(n[sel] @ wi[k], 0, None)[:, None] * alpha[t[sel]]
            out[k] = (val * vis[:, None]).sum(0) / len(u)      # escaped rays count as black
    return out


def psnr(test: np.ndarray, ref: np.ndarray) -> float:
    """PSNR (dB) of ``test`` against ``ref`` with the peak = max |ref| (as in §6, on the
    cosine-weighted BRDF)."""
    mse = float(np.mean((np.asarray(test) - np.asarray(ref)) ** 2))
    peak = float(np.max(np.abs(ref)))
    return float("inf") if mse == 0 else 10 * np.log10(peak * peak / mse)
