"""Tabulated-BRDF materials: any ``precompute.tables.tabulated_brdf.TabulatedBRDF`` as a Cycles material.

Cycles OSL (CPU) renders the table exactly with ``osl/tabulated_brdf.osl`` (one narrow microfacet
closure per sample, light sampling intact); Cycles SVM (the default shading system, and GPU) renders the
same closure from ordinary nodes (``node_groups.tabulated_svm``: alias-table bin pick, one narrow Glossy
node; the table itself, not a fit; view grids included).  EEVEE renders the same graph in its EEVEE variant
(``tabulated_svm.ensure(eevee=True)``: the atlas read by four Closest lookups, because EEVEE's Linear lookup
picks a mip level from the screen-space derivatives of a coordinate that jumps per pixel, and blurred the
table: 6-11 % dark in a white furnace, the cause of last round's EEVEE errors).  Measured against Cycles SVM
(aniso test table, 32² x 64-128 samples): studio world 0.0-1.3 %, area lamp 1.0-3.8 % at three views, white
furnace 0.2-0.6 % (all table kinds); the fitted twin misses the same renders by 5-52 %.  The closure is
sampled once per pixel sample, so EEVEE shows grain that falls with Render Samples (pixel std 2.4 % of the
mean at 64 samples in the furnace).  ``eevee_table=False`` keeps a fitted twin in EEVEE instead: a
caller-supplied surface (bi-scale: its fitted closures; Dong: the ellipsoid lobe) or the Diffuse + Glossy
least-squares twin of ``tabulated_brdf.glossy_twin``.  Tables whose images would exceed
``tabulated_svm.MAX_IMAGE_SIDE`` (or ``svm_table=False``) keep the fitted twin on Cycles SVM and EEVEE.  The
material's bump-map correction is off (it would bend the closure's micro-normal back to the geometric normal).
"""
from __future__ import annotations

import bpy
import numpy as np

from ..node_groups import tabulated_svm
from ..osl import tabulated_brdf as tabulated_osl
from ..precompute.cycles.glossy import glossy_node_params
from ..precompute.tables import tabulated_brdf
from . import osl_compile, render_paths
from .materials import new_material


def glossy_twin_surface(tree, twin: dict, location=(-300, -200)):
    """Diffuse BSDF + Glossy BSDF (GGX) + Add Shader from ``tabulated_brdf.glossy_twin``; returns the closure socket."""
    diff = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Color"].default_value = (*[float(c) for c in twin["diffuse"]], 1.0)
    diff.location = location
    glossy = tree.nodes.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    rough, _ = glossy_node_params(twin["alpha"], twin["alpha"])
    glossy.inputs["Roughness"].default_value = rough
    glossy.inputs["Color"].default_value = (*[float(c) for c in twin["specular"]], 1.0)
    glossy.location = (location[0], location[1] - 200)
    add = tree.nodes.new("ShaderNodeAddShader")
    add.location = (location[0] + 200, location[1] - 100)
    tree.links.new(diff.outputs["BSDF"], add.inputs[0])
    tree.links.new(glossy.outputs["BSDF"], add.inputs[1])
    return add.outputs["Shader"]


def table_surface(tree, tables, location=(-300, 200), eevee: bool = False):
    """The table graph (``node_groups.tabulated_svm``) of ``tables`` (``ClosureTables``) as a group node (``eevee``:
    its EEVEE variant); returns its BSDF socket."""
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = tabulated_svm.ensure(tables, eevee=eevee)
    node.name = node.label = "Tabulated BRDF (EEVEE)" if eevee else "Tabulated BRDF (SVM)"
    node.location = location
    return node.outputs["BSDF"]


def tabulated_script(mat, source: str):
    """The table's INTERNAL OSL script node with UV Map and Tangent nodes wired in; returns its BSDF socket."""
    script = osl_compile.uv_script_node(mat.node_tree, f"{mat.name}.tabulated.osl", source)
    return script.outputs["BSDF"]


def make_tabulated_material(brdf, name: str = "Tabulated BRDF", alpha: float | None = None, svm_twin=None,
                            kind: str = "tabulated", svm_table: bool = True, eevee_table: bool = True,
                            floor=True) -> bpy.types.Material:
    """Material rendering ``brdf`` (``TabulatedBRDF``) exactly in Cycles (OSL: ``osl/tabulated_brdf.osl``;
    SVM / GPU: the same closure as nodes, ``node_groups.tabulated_svm``) and EEVEE (the graph's EEVEE variant;
    ``eevee_table=False``: a fitted node twin).  ``svm_twin(tree) -> socket`` builds the fitted twin (default:
    ``glossy_twin``); it renders Cycles SVM and EEVEE when ``svm_table`` is False or the table exceeds the image
    limit (``tabulated_svm.fits``), and EEVEE when ``eevee_table`` is False; it is not built when unused.
    ``alpha``: the closure's GGX alpha (default ``tabulated_brdf.default_alpha(res)``).  Custom properties
    ``tabulated_svm`` / ``tabulated_eevee``: "table" or "fit" (what Cycles SVM / EEVEE render); ``tabulated_twin_rel_l1``:
    the fitted twin's error, only when a path renders the default twin (it is computed only then).  ``floor``: render
    the BRDF's smooth part kd/π as a Diffuse closure, and (glossy floor) a GGX lobe ks g_α under the table as a
    Glossy closure, only the residual through the table closure (``tabulated_brdf.floor_parts``: True = "auto",
    the glossy floor when it takes >= ``GLOSSY_SHARE_MIN`` of the albedo; "glossy", "diffuse", "none" / False;
    custom properties ``tabulated_floor``: kd, ``tabulated_glossy_floor``: (ks R, G, B, α_g), zeros when none (ks: the
    largest over the views when it varies with θo), ``tabulated_glossy_floor_dist``: "ggx" / "beckmann" / "").
    Tables above ``MAX_FLOATS`` (what an OSL array literal compiles) render through the graph under OSL as well
    (``tabulated_osl`` = "graph"; no script node: Cycles compiles the graph's builtin nodes for OSL); the bi-scale
    bake's default table (ωi 31², 31 x 31 view nodes, 2,770,563 floats) is one.
    Raises ValueError (nothing created) for tables that cannot be compiled."""
    if not all(hasattr(brdf, a) for a in ("table", "res", "iso", "view_nodes")):   # duck-typed: TDs may
        raise ValueError(f"brdf: expected a TabulatedBRDF, got {type(brdf).__name__}")  # import it by another name
    tables = tabulated_brdf.closure_tables(brdf, alpha, floor)       # ValueError before anything is created
    use_table = bool(svm_table) and tabulated_svm.fits(tables)
    # tables above what an OSL array literal compiles render through the node graph on every path (Cycles
    # compiles builtin nodes for OSL too): no script, no render-path switch
    graph_only = brdf.table.size > tabulated_osl.MAX_FLOATS
    if graph_only and not use_table:
        raise ValueError(f"table: {brdf.table.size} floats exceed what OSL compiles ({tabulated_osl.MAX_FLOATS}) and "
                         + ("svm_table is False" if not svm_table else "its images exceed "
                            f"{tabulated_svm.MAX_IMAGE_SIDE} texels")
                         + ": lower the resolution or the view nodes")
    src = None if graph_only else tabulated_osl.generate(brdf, alpha=alpha, floor=floor)
    ee_table = use_table and bool(eevee_table)
    # the least-squares twin only where a path renders it ("skip what a scene doesn't need": it is the
    # import's costliest step after the table itself and nothing reads it when SVM and EEVEE render the table)
    twin = None if ee_table or svm_twin is not None else tabulated_brdf.glossy_twin(brdf)
    n_groups, n_images = set(bpy.data.node_groups), set(bpy.data.images)
    mat = new_material(name)
    try:
        tree = mat.node_tree
        fitted = None if ee_table else svm_twin(tree) if svm_twin is not None else glossy_twin_surface(tree, twin)
        svm = table_surface(tree, tables) if use_table else fitted
        eevee = table_surface(tree, tables, (-300, -200), eevee=True) if ee_table else fitted
        osl = None if src is None else tabulated_script(mat, src)
    except BaseException:
        bpy.data.materials.remove(mat)
        for ng in set(bpy.data.node_groups) - n_groups:
            bpy.data.node_groups.remove(ng)
        for img in set(bpy.data.images) - n_images:
            bpy.data.images.remove(img)
        raise
    render_paths.link_surface(tree, svm, osl, tree.nodes["Material Output"], eevee_socket=eevee)
    mat["tabulated_svm"] = "table" if use_table else "fit"
    mat["tabulated_osl"] = "graph" if src is None else "script"   # what Cycles OSL renders
    mat["tabulated_eevee"] = "table" if ee_table else "fit"
    mat.cycles.use_bump_map_correction = False
    mat["scratch_addon_kind"] = kind
    mat["tabulated_res"] = int(brdf.res)
    mat["tabulated_iso"] = bool(brdf.iso)
    mat["tabulated_floor"] = [float(c) for c in tables.kd]
    mat["tabulated_glossy_floor"] = [*(float(c) for c in tables.ks), float(tables.alpha_g)]
    mat["tabulated_glossy_floor_dist"] = tables.dist_g if tables.ks.any() else ""
    if getattr(brdf, "half", False):
        mat["tabulated_half_extent"] = float(brdf.extent)      # a half-vector table zoomed to its lobe
    if twin is not None:
        mat["tabulated_twin_rel_l1"] = float(twin["rel_l1"])
    mat.diffuse_color = (*[float(c) for c in np.clip(brdf.albedo(np.array([[0, 0, 1.0]]), 16, 32)[0], 0, 1)], 1.0)
    return mat


def make_ndf_material(ndf, name: str = "Measured NDF", F=(0.9, 0.9, 0.9), res: int | None = None,
                      svm_twin=None, multiple_scattering: bool = True) -> bpy.types.Material:
    """Material of a measured NDF (Dong et al. 2015; ``precompute.microgeometry.ndf.NDFTable``, e.g. the
    filtered or Kirchhoff NDF of ``precompute.microgeometry.tables.compute_tables``) rendered as its own
    microfacet BRDF table (``precompute.microgeometry.ndf_brdf``: a half-vector table zoomed to the NDF's
    support), not its ellipsoid fit; reflectance ``F`` (RGB); ``res``: the half-vector grid side (default:
    ``ndf_brdf.table_layout``).  Cycles (OSL and SVM) renders the table; the EEVEE twin: ``svm_twin(tree) ->
    socket`` (Material from Height Field passes its ellipsoid lobe), else the Diffuse + Glossy fit of the table.
    ``multiple_scattering`` (default on: a mirror metal keeps its energy): the light Smith shadowing removes,
    scattered again on the Smith microsurface of the same NDF (``ndf_brdf``, Heitz et al. 2016), in the same table."""
    from ..precompute.microgeometry import ndf_brdf

    mat = make_tabulated_material(ndf_brdf.ndf_brdf(ndf, res=res, F=F, multiple_scattering=multiple_scattering),
                                  name, svm_twin=svm_twin, kind="microgeometry_table")
    mat["microgeometry_multiple_scattering"] = bool(multiple_scattering)
    mat["microgeometry_ndf_kind"] = str(getattr(ndf, "kind", "tabulated"))
    return mat
