"""The bi-scale effective BRDF (Wu, Dorsey, Rushmeier 2011, eq. 7) as a tabulated-BRDF closure
(``precompute.tables.tabulated_brdf``): the product path that renders the table itself, with light
sampling, instead of a fitted closure mixture (§5 "rendering").

``to_tabulated`` reuses the table as it is (same cell-centred hemi-octahedral grid for ωi and ωo,
standard BRDF in 1/sr, anisotropic); ``table_dir_res`` picks the direction resolution from the
sharpest small-scale material, so that a glossy lobe spans at least two cells.
"""
from __future__ import annotations

import math

import numpy as np

from ..tables.tabulated_brdf import MAX_FLOATS, TabulatedBRDF

__all__ = ["to_tabulated", "table_dir_res", "sharpest_alpha", "MIN_DIR_RES", "MAX_DIR_RES"]

#: Resolution of tiles with only rough / diffuse materials (the reference mode's default).
MIN_DIR_RES = 10
#: Largest automatic resolution: the bake's cost grows as dir_res⁴ (10: ~80 s, 14: ~250 s for a
#: 10,000-facet groove here); larger values can be asked for explicitly up to what a shader holds.
MAX_DIR_RES = 14
#: Largest resolution whose anisotropic table fits a shader (3 res⁴ floats <= MAX_FLOATS).
MAX_SHADER_DIR_RES = int((MAX_FLOATS / 3) ** 0.25)


def sharpest_alpha(materials) -> float:
    """Smallest microfacet-equivalent roughness α among small-scale material dicts
    (``precompute.biscale.brdfs``): cook_torrance / ward α, Blinn-Phong e -> sqrt(2 / (e + 2));
    Lambert: inf; tabulated: 0.1 (unknown sharpness: the automatic maximum)."""
    out = math.inf
    for m in materials:
        model = m.get("model") if isinstance(m, dict) else None
        if model in ("cook_torrance", "ward"):
            out = min(out, float(m.get("alpha", 0.2 if model == "cook_torrance" else 0.3)))
        elif model == "blinn_phong":
            out = min(out, math.sqrt(2.0 / (float(m.get("exponent", 20.0)) + 2.0)))
        elif model == "tabulated":
            out = min(out, 0.1)
    return out


def table_dir_res(materials) -> int:
    """Direction resolution for the table closure: ceil(π / α_min) (a hemi-octahedral cell spans about
    π / res rad, a GGX lobe of roughness α about ±2α around the mirror direction, so two cells per
    half-width), clamped to [MIN_DIR_RES, MAX_DIR_RES]."""
    a = sharpest_alpha(materials)
    res = MIN_DIR_RES if not math.isfinite(a) else math.ceil(math.pi / max(a, 1e-3))
    return int(np.clip(res, MIN_DIR_RES, MAX_DIR_RES))


def to_tabulated(brdf) -> TabulatedBRDF:
    """``EffectiveBRDF`` -> anisotropic ``TabulatedBRDF`` on the same grid (table[i, o], 1/sr)."""
    res = int(brdf.dir_res)
    if res > MAX_SHADER_DIR_RES:
        raise ValueError(f"dir_res: the table closure holds at most dir_res {MAX_SHADER_DIR_RES}, got {res}")
    return TabulatedBRDF(np.asarray(brdf.table, np.float64), res, False,
                         {"source": "biscale", **{k: v for k, v in brdf.info.items() if isinstance(v, (int, float, str))}})
