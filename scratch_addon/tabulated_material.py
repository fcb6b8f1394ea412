"""Tabulated-BRDF materials: any ``precompute.tables.tabulated_brdf.TabulatedBRDF`` as a Cycles material.

Cycles OSL (CPU) renders the table exactly with ``osl/tabulated_brdf.osl`` (one narrow microfacet
closure per sample, light sampling intact); Cycles SVM, GPU and EEVEE render a twin built from
ordinary nodes (``render_paths``): a caller-supplied surface (bi-scale: its fitted closures) or the
Diffuse + Glossy least-squares twin of ``tabulated_brdf.glossy_twin``.  The material's bump-map
correction is off (it would bend the closure's micro-normal back to the geometric normal).
"""
from __future__ import annotations

import bpy
import numpy as np

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


def tabulated_script(mat, source: str):
    """The table's INTERNAL OSL script node with UV Map and Tangent nodes wired in; returns its BSDF socket."""
    script = osl_compile.uv_script_node(mat.node_tree, f"{mat.name}.tabulated.osl", source)
    return script.outputs["BSDF"]


def make_tabulated_material(brdf, name: str = "Tabulated BRDF", alpha: float | None = None, svm_twin=None,
                            kind: str = "tabulated") -> bpy.types.Material:
    """Material rendering ``brdf`` (``TabulatedBRDF``) exactly in Cycles OSL and through a node twin
    elsewhere.  ``svm_twin(tree) -> socket`` builds the twin (default: ``glossy_twin``);
    ``alpha``: the closure's GGX alpha (default ``tabulated_brdf.default_alpha(res)``).
    Raises ValueError (nothing created) for tables that cannot be compiled."""
    if not all(hasattr(brdf, a) for a in ("table", "res", "iso", "view_nodes")):   # duck-typed: TDs may
        raise ValueError(f"brdf: expected a TabulatedBRDF, got {type(brdf).__name__}")  # import it by another name
    src = tabulated_osl.generate(brdf, alpha=alpha)      # ValueError before anything is created
    twin = None if svm_twin is not None else tabulated_brdf.glossy_twin(brdf)
    mat = new_material(name)
    try:
        tree = mat.node_tree
        svm = svm_twin(tree) if svm_twin is not None else glossy_twin_surface(tree, twin)
        osl = tabulated_script(mat, src)
    except Exception:
        bpy.data.materials.remove(mat)
        raise
    render_paths.link_surface(tree, svm, osl, tree.nodes["Material Output"])
    mat.cycles.use_bump_map_correction = False
    mat["scratch_addon_kind"] = kind
    mat["tabulated_res"] = int(brdf.res)
    mat["tabulated_iso"] = bool(brdf.iso)
    if getattr(brdf, "half", False):
        mat["tabulated_half_extent"] = float(brdf.extent)      # a half-vector table zoomed to its lobe
    if twin is not None:
        mat["tabulated_twin_rel_l1"] = float(twin["rel_l1"])
    mat.diffuse_color = (*[float(c) for c in np.clip(brdf.albedo(np.array([[0, 0, 1.0]]), 16, 32)[0], 0, 1)], 1.0)
    return mat


def make_ndf_material(ndf, name: str = "Measured NDF", F=(0.9, 0.9, 0.9), res: int | None = None,
                      svm_twin=None) -> bpy.types.Material:
    """Material of a measured NDF (Dong et al. 2015; ``precompute.microgeometry.ndf.NDFTable``, e.g. the
    filtered or Kirchhoff NDF of ``precompute.microgeometry.tables.compute_tables``) rendered as its own
    microfacet BRDF table (``precompute.microgeometry.ndf_brdf``: a half-vector table zoomed to the NDF's
    support), not its ellipsoid fit; reflectance ``F`` (RGB); ``res``: the half-vector grid side (default:
    ``ndf_brdf.table_layout``).  The SVM/EEVEE twin: ``svm_twin(tree) -> socket`` (Material from Height
    Field passes its ellipsoid lobe), else the Diffuse + Glossy fit of the table."""
    from ..precompute.microgeometry import ndf_brdf

    mat = make_tabulated_material(ndf_brdf.ndf_brdf(ndf, res=res, F=F), name, svm_twin=svm_twin,
                                  kind="microgeometry_table")
    mat["microgeometry_ndf_kind"] = str(getattr(ndf, "kind", "tabulated"))
    return mat
