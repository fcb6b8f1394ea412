"""Operators: thin wrappers over ``api`` that report errors to the user instead of raising."""
from __future__ import annotations

import bpy

from . import api


def _preset_items(_self, _context):
    from . import presets

    return [(p.name, p.name.replace("_", " ").title(), p.description) for p in presets.PRESETS.values()]


class SCRATCH_OT_add_preset_material(bpy.types.Operator):
    """Create a material from a preset and assign it to the active object"""

    bl_idname = "scratch.add_preset_material"
    bl_label = "Add Scratch Material"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=_preset_items)

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            cls.poll_message_set("Select a mesh object")
            return False
        return True

    def execute(self, context):
        obj = context.active_object
        try:
            mat = api.make_material(self.preset)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if obj.data.materials:
            obj.data.materials[obj.active_material_index] = mat
        else:
            obj.data.materials.append(mat)
        self.report({"INFO"}, f"Assigned {mat.name}")
        return {"FINISHED"}


classes = (SCRATCH_OT_add_preset_material,)
