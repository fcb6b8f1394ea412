"""Generator of the tabulated-BRDF shader (``osl/tabulated_brdf.osl``).

``generate`` writes the arrays of ``precompute.tables.tabulated_brdf.closure_tables`` into the
shader (``osl.specialise``); the sampling, its density and the table layout are documented in
``precompute.tables.tabulated_brdf``, whose ``sample`` is the shader's numpy twin.
"""
from __future__ import annotations

from ..precompute.tables.tabulated_brdf import MAX_FLOATS, VIEW_GUIDE_BINS, closure_tables, view_guide
from . import const_array, specialise


def generate(brdf, name: str = "tabulated_brdf", alpha: float | None = None, floor=True) -> str:
    """OSL source of the closure for ``brdf`` (``TabulatedBRDF``): ``tabulated_brdf.osl`` with its
    tables, ISO/RES/NO/ALPHA defined.  Inputs ``Tangent`` (a Tangent node, UV map), ``Tint``;
    output ``BSDF``.  ``alpha``: the closure's GGX alpha (default ``default_alpha(res)``); ``floor``: split off
    the smooth Diffuse floor (``tabulated_brdf.floor_split``, FLOOR / KD_* defined when kd > 0) and the glossy
    floor (``tabulated_brdf.floor_parts``: True = "auto", "glossy", "diffuse", "none"; GFLOOR / KS_* / ALPHA_G /
    GDIST defined when ks > 0)."""
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"name: expected an OSL identifier, got {name!r}")
    size = getattr(getattr(brdf, "table", None), "size", 0)
    if size > MAX_FLOATS:
        raise ValueError(f"table: {size} floats; at most {MAX_FLOATS} are compiled into an OSL shader (larger "
                         f"tables render through the node graph, tabulated_material)")
    tb = closure_tables(brdf, alpha, floor)
    D = tb.res * tb.res
    tables = (const_array("F", tb.F.ravel()) + const_array("CDF", tb.cdf.ravel())
              + const_array("GUIDE", tb.guide.ravel(), "int"))
    view = {}
    if tb.view_a is not None:       # a view grid in the projected view angles (tabulated_brdf docstring)
        tables += (const_array("VA", tb.view_a) + const_array("VB", tb.view_b)
                   + const_array("VGA", view_guide(tb.view_a), "int") + const_array("VGB", view_guide(tb.view_b), "int"))
        view = dict(VIEW_GRID=True, NA=len(tb.view_a), NB=len(tb.view_b), VGBINS=VIEW_GUIDE_BINS)
        if tb.centroid is not None:  # the lobe-following view interpolation (TabulatedBRDF.view_shift)
            view.update(VIEW_SHIFT=True)
            tables += const_array("CEN", tb.centroid.ravel())
    if tb.kd.any():                 # the smooth Diffuse floor (tabulated_brdf.floor_split)
        view.update(FLOOR=True, KD_R=float(tb.kd[0]), KD_G=float(tb.kd[1]), KD_B=float(tb.kd[2]))
    if tb.ks.any():                 # the glossy floor (tabulated_brdf.glossy_floor_split)
        view.update(GFLOOR=True, KS_R=float(tb.ks[0]), KS_G=float(tb.ks[1]), KS_B=float(tb.ks[2]),
                    ALPHA_G=float(tb.alpha_g), GDIST=f'"{tb.dist_g}"')
        if tb.ks_view is not None:  # isotropic tables: the colour per θo node (tabulated_brdf.floor_ks)
            view.update(GFLOOR_VIEW=True)
            tables += const_array("KSV", tb.ks_view.ravel())
    return specialise("tabulated_brdf.osl",
                      dict(SHADER_NAME=name, ISO=bool(tb.iso), RES=tb.res, ND=D, NO=tb.n_o, CELL=2.0 / tb.res,
                           ALPHA=tb.alpha, HALF=bool(tb.half), EXTENT=float(tb.extent), **view),
                      {"tabulated_brdf_tables.h": tables}, "osl/tabulated_brdf.py")
