"""The scratch material's inputs and tables, without Blender (Raymond et al. 2016, §4-5).

``validate(**params)`` checks every parameter of ``make_scratched_material`` (ValueError naming the
parameter and its range) and returns ``ScratchParams``; ``tables(params)`` computes, through the
content-hash cache, what every render path needs: the scratch BRDF (ρ0, ρm, γ; eq. 2), the lobe
data of the chosen lobe shape, and the table lobes the node-group (SVM) twin renders.  The glue
(``scratch_addon.scratch_material``) only builds node trees from these.
"""
from __future__ import annotations

import dataclasses
import difflib
from dataclasses import dataclass

import numpy as np

from ..validation import check_color, check_range
from . import brdf as scratch_brdf, fresnel as fresnel_mod, layers as layers_mod, lobes, profiles

#: Largest table the reference mode compiles into its shader (M x M per channel).
REFERENCE_MAX_M = 128

BASE_TYPES = ("mirror", "none", "diffuse", "glossy", "principled")
MODES = ("lobes", "reference")
BACKENDS = ("osl", "svm")
#: "fit": <= K fitted tilted lobes; "box": fitted lobes with a tilt jitter each; "table": tabulated-tilt
#: lobes (precompute.scratch.lobe_table: the slice sampled bin by bin, exact, no fit; the default)
LOBE_SHAPES = ("fit", "box", "table")


@dataclass
class ScratchParams:
    """Validated inputs of ``make_scratched_material`` (see ``api.make_scratched_material``)."""

    profile: object
    fresnel: object
    layers: object  # LayerParams or None (dense)
    lobes: int
    base: dict
    mode: str
    resolution: int
    slices: int
    tint: tuple
    diffuse: object = None  # None, an RGB colour or "wood": a Lambertian term added to the whole material
    backend: str = "osl"    # "osl" (CPU/OptiX, footprint-filtered α, hash-picked lobes) or "svm" (GPU/EEVEE)
    lobe_shape: str = "table"  # one of LOBE_SHAPES

    @property
    def box_lobes(self) -> bool:
        return self.lobe_shape == "box"


def _as_layers(layers):
    if layers is None or isinstance(layers, layers_mod.LayerParams):
        return layers
    if isinstance(layers, dict):
        accepted = [f.name for f in dataclasses.fields(layers_mod.LayerParams)]
        for key in layers:
            if key not in accepted:
                close = difflib.get_close_matches(str(key), accepted, n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise ValueError(f"layers: unknown key {key!r}{hint}; accepted: {', '.join(accepted)}")
        return layers_mod.LayerParams(**layers)
    if isinstance(layers, (int,)) and not isinstance(layers, bool):
        return layers_mod.LayerParams(n_layers=layers)
    raise ValueError(f"layers must be None (dense), an int (count), a dict or a LayerParams; got {layers!r}")


#: keys a base dict may carry, per base type (what ``scratch_addon.scratch_material`` reads)
BASE_KEYS = {"mirror": ("type",), "none": ("type",), "diffuse": ("type", "color"),
             "glossy": ("type", "color", "roughness"), "principled": ("type", "color", "roughness", "metallic")}


def _as_base(base) -> dict:
    """The base material dict, every value checked here so a rebuild never fails half-way on it."""
    if isinstance(base, str):
        base = {"type": base}
    if not isinstance(base, dict) or not isinstance(base.get("type"), str) or base["type"] not in BASE_TYPES:
        raise ValueError(f"base must be one of {', '.join(BASE_TYPES)} (or a dict with 'type'); got {base!r}")
    allowed = BASE_KEYS[base["type"]]
    unknown = [k for k in base if k not in allowed]
    if unknown:
        raise ValueError(f"base: unknown key {unknown[0]!r} for a {base['type']!r} base; accepted: {', '.join(allowed)}")
    out = dict(base)
    if "color" in out:
        out["color"] = check_color("base color", out["color"])
    if "roughness" in out:
        out["roughness"] = check_range("base roughness", out["roughness"], 0.0, 1.0)
    if "metallic" in out:
        out["metallic"] = check_range("base metallic", out["metallic"], 0.0, 1.0)
    return out


def _as_profile(profile):
    if isinstance(profile, (tuple, list)) and len(profile) == 2 and isinstance(profile[0], str):
        family = getattr(profiles, profile[0], None)
        if family is None or profile[0] not in ("quartic", "v_groove", "circular"):
            raise ValueError(f"profile family must be quartic, v_groove or circular; got {profile[0]!r}")
        return family(profile[1])
    return profile


def _as_fresnel(fresnel):
    if fresnel is None or isinstance(fresnel, fresnel_mod.Fresnel):
        return fresnel
    try:                             # the user's parameter is ``fresnel``: name it in the message
        if isinstance(fresnel, str):
            return fresnel_mod.conductor_preset(fresnel)
        if isinstance(fresnel, (tuple, list)) and len(fresnel) == 2 and fresnel[0] == "schlick":
            return fresnel_mod.schlick(fresnel[1])
        if isinstance(fresnel, (tuple, list)) and len(fresnel) == 3 and fresnel[0] == "conductor":
            return fresnel_mod.conductor(fresnel[1], fresnel[2])
    except ValueError as exc:
        raise ValueError(f"fresnel: {exc}") from None
    raise ValueError("fresnel must be None (lossless), a metal name, ('schlick', ior), ('conductor', n, k) "
                     f"or a precompute.fresnel model; got {fresnel!r}")


def validate(profile=None, fresnel=None, layers=None, lobes=8, base="mirror", mode="lobes", resolution=256,
             slices=64, tint=(1.0, 1.0, 1.0), diffuse=None, backend="osl", box_lobes=False,
             lobe_shape=None) -> ScratchParams:
    """Check every parameter; raise ValueError naming the parameter and its allowed range."""
    profile = profiles.quartic(0.2) if profile is None else _as_profile(profile)
    if not isinstance(profile, profiles.Profile):
        raise ValueError(f"profile must be a precompute.profiles profile (quartic, v_groove, tabulated...); got {profile!r}")
    fresnel = _as_fresnel(fresnel)
    if isinstance(lobes, bool) or not isinstance(lobes, int) or not 1 <= lobes <= 16:
        raise ValueError(f"lobes must be an integer in [1, 16], got {lobes!r}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if isinstance(resolution, bool) or resolution not in (64, 128, 256, 512):
        raise ValueError(f"resolution must be one of 64, 128, 256, 512; got {resolution!r}")
    resolution = int(resolution)
    if mode == "reference" and resolution > REFERENCE_MAX_M:
        raise ValueError(f"resolution must be <= {REFERENCE_MAX_M} in reference mode "
                         f"(the exact table is compiled into the shader); got {resolution}")
    if isinstance(slices, bool) or slices not in (16, 32, 64, 128) or slices > resolution:
        raise ValueError(f"slices must be one of 16, 32, 64, 128 and <= resolution; got {slices!r}")
    slices = int(slices)
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if backend == "svm" and mode != "lobes":
        raise ValueError("mode must be 'lobes' with backend 'svm' (the reference mode needs OSL)")
    if not isinstance(box_lobes, bool):
        raise ValueError(f"box_lobes must be True or False, got {box_lobes!r}")
    if lobe_shape is None:  # default: the exact table lobes, on both backends
        lobe_shape = "box" if box_lobes else "table"
    if lobe_shape not in LOBE_SHAPES:
        raise ValueError(f"lobe_shape must be one of {', '.join(LOBE_SHAPES)}; got {lobe_shape!r}")
    if box_lobes and lobe_shape != "box":
        raise ValueError(f"box_lobes=True contradicts lobe_shape={lobe_shape!r} (use lobe_shape='box')")
    rgba = check_color("tint", tint)
    if diffuse is not None and diffuse != "wood":
        diffuse = check_color("diffuse", diffuse)[:3]
    return ScratchParams(profile, fresnel, _as_layers(layers), lobes, _as_base(base), mode, resolution, slices,
                         rgba[:3], diffuse, backend, lobe_shape)


def lobe_data(params: ScratchParams, brdf, quality: str = "full") -> dict:
    """Lobe tables for ``params`` (cached): tabulated-tilt lobes (``quality`` "preview": the quick ones of a
    live edit, ``lobes.table_lobes``), or <= K fitted (plain / box) lobes."""
    if params.lobe_shape == "table":
        return table_lobe_data(params, quality)
    # the SVM path has one Glossy node per lobe column, so one distribution (GGX) for all slices
    return lobes.lobe_tables(brdf, K=params.lobes, slices=params.slices,
                                     dists="ggx" if params.backend == "svm" else "auto", jitter=params.box_lobes)


def fit_error(lobe_data: dict) -> float:
    """Worst per-slice rel. L1 error of ``lobe_data`` (fitted or table lobes) against ρ cos."""
    if "cdf" in lobe_data:
        errs = [lobe_data["error_m"]] + ([] if lobe_data.get("error_0") is None else [lobe_data["error_0"]])
    else:
        errs = [lobe_data["m"]["error"]] + ([] if lobe_data["0"] is None else [lobe_data["0"]["error"]])
    return float(max(np.max(e) for e in errs))

#: worst absolute Fresnel error the tracer may make (``fresnel.tabulated``: the conductor formula on a fine
#: cos θ grid instead of the exact formula at every bounce; a reflectance error far below the tables' own
#: tolerances, 2e-3 and 3e-3 of ``slices.view_slices``, and the ~2-digit n, k of the presets)
FRESNEL_TOL = 1e-5


def trace_fresnel(params: ScratchParams):
    """The Fresnel model the tables are traced with: ``params.fresnel`` tabulated (``fresnel.tabulated``,
    worst error ``FRESNEL_TOL``; None stays None)."""
    return None if params.fresnel is None else fresnel_mod.tabulated(params.fresnel, FRESNEL_TOL)


def table_lobe_data(params: ScratchParams, quality: str = "full") -> dict:
    """Table lobes of ``params`` from exact view slices (``lobes.table_lobes``, cached by content hash)."""
    return lobes.table_lobes(params.profile, trace_fresnel(params), resolution=params.resolution, slices=params.slices,
                             quality=quality)


def has_preview(params: ScratchParams) -> bool:
    """True if ``tables(params, "preview")`` differs from the full tables (table lobes: coarser view slices)."""
    return params.mode == "lobes" and params.lobe_shape == "table"


def tables_cached(params: ScratchParams, quality: str = "full") -> bool:
    """True if ``tables(params, quality)`` reads its lobe tables from the cache (False when unsure)."""
    if not has_preview(params):
        return False
    return lobes.table_lobes_cached(params.profile, trace_fresnel(params), params.resolution, params.slices, quality)


def brdf_table(params: ScratchParams):
    """The scratch BRDF of ``params`` (ρ0, ρm, γ; ``brdf.simulate``, cached by content hash)."""
    return scratch_brdf.simulate(params.profile, resolution=params.resolution, fresnel=trace_fresnel(params),
                                 cache=True)


def tables(params: ScratchParams, quality: str = "full") -> dict:
    """Every table ``params`` renders with (cached by content hash): ``brdf`` (ScratchBRDF; None for table
    lobes in the lobes mode, which do not render from it), ``lobes``
    (lobe data of ``params.lobe_shape``; None in reference mode) and ``svm_lobes`` (what the
    node-group twin renders: the same data for table lobes or the SVM backend, else table lobes).  ``quality``
    "preview": the quick table lobes of a live edit (``lobes.table_lobes``; only table lobes have one)."""
    # table lobes come from exact view slices: the M x M BRDF table (the tracer's largest job) is only
    # traced for the reference mode and fitted lobes, which render from it
    needs_brdf = params.mode == "reference" or params.lobe_shape != "table"
    brdf = brdf_table(params) if needs_brdf else None
    data = lobe_data(params, brdf, quality) if params.mode == "lobes" else None
    svm = data if data is not None and (params.backend == "svm" or params.lobe_shape == "table") else None
    if svm is None:  # the SVM twin of fitted (per-lobe GGX/Beckmann) or reference shaders: table lobes
        svm = table_lobe_data(params)
    return {"brdf": brdf, "lobes": data, "svm_lobes": svm}
