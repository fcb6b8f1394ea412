"""Operators: thin wrappers over ``api`` that report errors to the user instead of raising.

Long work (table simulation, lobe fitting, OSL compile) runs inside ``execute()`` with
``wm.progress_*`` so it also works headless (``blender -b``).
"""
from __future__ import annotations

import bpy

from . import api, presets, scratch_material
from .ui_utils import (USER_ERRORS, assign_material, poll_active_mesh, progress, report_error, report_render_path,
                       reported_warnings)


def _preset_items(_self, _context):
    return [(p.name, p.name.replace("_", " ").title(), p.description) for p in presets.PRESETS.values()]


class SCRATCH_OT_add_preset_material(bpy.types.Operator):
    """Create a material from a preset and assign it to the active object"""

    bl_idname = "scratch.add_preset_material"
    bl_label = "Add Scratch Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=_preset_items)

    @classmethod
    def poll(cls, context):
        return poll_active_mesh(cls, context)

    def execute(self, context):
        obj = context.active_object
        p = presets.get(self.preset)
        try:
            with reported_warnings(self), progress(context) as update:
                if p.kind == "scratch":
                    mat = api.make_scratched_material(self.preset, progress=update)
                    mat.scratch.from_params(p.params)
                else:
                    mat = api.make_material(self.preset)
        except USER_ERRORS as exc:
            return report_error(self, exc)
        assign_material(obj, mat)
        if p.kind == "scratch" and not obj.data.uv_layers:
            self.report({"WARNING"}, f"{obj.name} has no UV map: scratches follow UVs, add one")
        self.report({"INFO"}, f"Assigned {mat.name}")
        report_render_path(self, mat, context.scene)
        return {"FINISHED"}


class SCRATCH_OT_update_material(bpy.types.Operator):
    """Recompute the scratch tables and shader of the active material from its settings"""

    bl_idname = "scratch.update_material"
    bl_label = "Update Scratch Material"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        mat = getattr(context, "material", None)
        if mat is None:
            cls.poll_message_set("No active material")
            return False
        return True

    def execute(self, context):
        mat = context.material
        try:  # a failure leaves the material as it was (api.make_scratched_material)
            with reported_warnings(self), progress(context) as update:
                params = mat.scratch.to_params()
                api.make_scratched_material(material=mat, progress=update, **params)
        except USER_ERRORS as exc:
            return report_error(self, exc)
        try:
            scratch_material.check_uvs(mat)
        except ValueError as exc:
            self.report({"WARNING"}, str(exc))
        err = mat.get("scratch_addon_fit_error")
        self.report({"INFO"}, f"Updated {mat.name}" + (f" (lobe fit error {100 * err:.1f} %)" if err is not None else ""))
        report_render_path(self, mat, context.scene)
        return {"FINISHED"}


class SCRATCH_OT_use_osl(bpy.types.Operator):
    """Render this scene with Cycles' Open Shading Language on the CPU, so OSL shaders (scratch coverage
    filtered over the pixel footprint, iridescent glints, exact references) render instead of their
    node-group twins"""

    bl_idname = "scratch.use_osl"
    bl_label = "Use OSL"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        changed = [name for name, value in (("engine", scene.render.engine != "CYCLES"),
                                            ("device", scene.cycles.device != "CPU"),
                                            ("shading system", not scene.cycles.shading_system)) if value]
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.shading_system = True
        self.report({"INFO"}, "Cycles, CPU, Open Shading Language" + (f" (changed: {', '.join(changed)})" if changed else ""))
        return {"FINISHED"}


classes = (SCRATCH_OT_add_preset_material, SCRATCH_OT_update_material, SCRATCH_OT_use_osl)
