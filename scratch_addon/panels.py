"""Material-panel UI."""
from __future__ import annotations

import bpy


class SCRATCH_PT_material(bpy.types.Panel):
    bl_label = "Scratched Material"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.engine == "CYCLES"

    def draw(self, context):
        layout = self.layout
        layout.operator_menu_enum("scratch.add_preset_material", "preset", text="Add from Preset")
        mat = context.material
        if mat is not None and "scratch_addon_kind" in mat:
            layout.label(text=f"Kind: {mat['scratch_addon_kind']}")


classes = (SCRATCH_PT_material,)
