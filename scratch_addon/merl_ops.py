"""Measured BRDFs (MERL binary format, Matusik et al. 2003) as materials: the API function
``material_from_merl``, the operator ``scratch.import_merl`` and its panel.

The file is read and resampled by ``precompute.tables.merl`` onto the isotropic grid of the
tabulated-BRDF closure; Cycles renders it exactly (OSL: ``osl/tabulated_brdf.osl``; SVM and GPU: the same
closure as nodes, ``node_groups/tabulated_svm``), EEVEE the nodes' EEVEE variant (``scratch_addon.tabulated_material``;
its smooth part as a Diffuse closure, ``tabulated_brdf.floor_split``).

Headless: ``bpy.ops.scratch.import_merl(filepath="gold-metallic-paint.binary")`` with a mesh active,
or ``material_from_merl(path)``.
"""
from __future__ import annotations

import os

import bpy

from ..precompute import validation
from ..precompute.tables import merl
from . import panels, tabulated_material, transaction
from .ui_utils import USER_ERRORS, assign_material, poll_active_mesh, progress, report_error


def material_from_merl(path, name: str | None = None, res: int = 32, n_theta: int = 32, progress=None,
                       floor=True):
    """Material of the MERL BRDF in ``path`` (``res`` x ``res`` ωi cells and ``n_theta`` view angles on
    the closure's isotropic grid; missing bins take their measured neighbour's value, ``merl.fill_missing``).
    ``floor``: the BRDF's smooth part kd/π renders as a Diffuse closure and (True = "auto", or "glossy") a GGX /
    Beckmann lobe under its glossy part as a Glossy closure, only the rest through the table closure
    (``tabulated_brdf.floor_parts``: a point lamp then lights both at every sample); "diffuse": the Diffuse floor
    alone; False / "none": no floor.
    ValueError for unreadable / non-MERL files and out-of-range sizes; nothing is created then."""
    validation.check_range("res", res, 4, 48)
    validation.check_range("n_theta", n_theta, 4, 90)
    step = progress or (lambda f: None)
    step(0.0)
    table = merl.read_merl(path)
    step(0.4)
    brdf = merl.to_tabulated(table, int(res), int(n_theta))
    step(0.8)
    name = name or os.path.splitext(os.path.basename(os.fspath(path)))[0]
    with transaction.new_datablocks():
        mat = tabulated_material.make_tabulated_material(brdf, name, kind="merl", floor=floor)
        mat["merl_source"] = os.path.basename(os.fspath(path))
    step(1.0)
    return mat


class SCRATCH_OT_import_merl(bpy.types.Operator):
    """Import a measured BRDF (MERL .binary) as a material on the active object: the table itself in Cycles
    (OSL or SVM, CPU or GPU) and EEVEE"""

    bl_idname = "scratch.import_merl"
    bl_label = "Import MERL BRDF"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(subtype="FILE_PATH")
    filter_glob: bpy.props.StringProperty(default="*.binary", options={"HIDDEN"})
    res: bpy.props.IntProperty(name="Direction Resolution", default=32, min=4, max=48,
                               description="Light directions per side of the table (hemi-octahedral cells)")
    n_theta: bpy.props.IntProperty(name="View Angles", default=32, min=4, max=90)

    @classmethod
    def poll(cls, context):
        return poll_active_mesh(cls, context)

    def invoke(self, context, event):
        if not self.filepath and context.window is not None:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        obj = context.active_object
        try:
            with progress(context) as update:
                mat = material_from_merl(self.filepath, res=self.res, n_theta=self.n_theta, progress=update)
        except USER_ERRORS as exc:
            return report_error(self, exc, {"res": "Direction Resolution", "n_theta": "View Angles",
                                            "path": "File"})
        assign_material(obj, mat)
        kd = list(mat.get("tabulated_floor", (0.0, 0.0, 0.0)))
        self.report({"INFO"}, f"Assigned {mat.name} ({mat.get('tabulated_res', 0)}² directions; smooth floor kd "
                              f"{max(kd):.3f}; SVM: {mat.get('tabulated_svm', '?')}, EEVEE: {mat.get('tabulated_eevee', '?')})")
        return {"FINISHED"}


class SCRATCH_PT_measured_brdf(bpy.types.Panel):
    bl_label = "Measured BRDF"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_parent_id = "SCRATCH_PT_material"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return context.engine in panels.ENGINES

    def draw(self, context):
        layout = self.layout
        layout.operator(SCRATCH_OT_import_merl.bl_idname, icon="IMPORT")
        mat = context.material
        if mat is not None and "merl_source" in mat:
            layout.label(text=f"From: {mat['merl_source']} ({mat.get('tabulated_res', 0)}² directions, "
                              f"the table in Cycles and EEVEE)")


classes = (SCRATCH_OT_import_merl, SCRATCH_PT_measured_brdf)
