"""Material-panel UI: the scratch SV-BRDF settings of the active material."""
from __future__ import annotations

import bpy

from . import live, render_paths
from .ui_utils import draw_render_path

#: Render engines whose Material tab shows our panels: Cycles, and EEVEE (Material Preview).
ENGINES = ("CYCLES", "BLENDER_EEVEE", "BLENDER_EEVEE_NEXT", "BLENDER_WORKBENCH")


class SCRATCH_PT_material(bpy.types.Panel):
    bl_label = "Scratched Material"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        return context.engine in ENGINES

    def draw(self, context):
        layout = self.layout
        layout.operator_menu_enum("scratch.add_preset_material", "preset", text="Add from Preset")
        mat = context.material
        if mat is None:
            return
        if mat.get("scratch_addon_kind") or render_paths.has_osl(mat):
            draw_render_path(layout, mat, context.scene)
        s = mat.scratch
        col = layout.column()
        box = col.box()
        box.label(text="Profile and Fresnel")
        box.prop(s, "profile_type")
        if s.profile_type == "script":
            box.label(text=f"Set by a script: {s.get('script_profile', {}).get('name', '?')}")
        else:
            box.prop(s, "profile_file" if s.profile_type == "file" else "profile_value")
        box.prop(s, "fresnel_type")
        if s.fresnel_type == "metal":
            box.prop(s, "metal")
        elif s.fresnel_type == "conductor":
            row = box.row()
            row.prop(s, "ior_n")
            row.prop(s, "ior_k")
        elif s.fresnel_type == "schlick":
            box.prop(s, "ior")
        elif s.fresnel_type == "script":
            box.label(text=f"Set by a script: {s.get('script_fresnel', {}).get('model', '?')}")
        box.prop(s, "tint")
        box = col.box()
        box.prop(s, "use_layers")
        if s.use_layers:
            for name in ("n_layers", "theta_deg", "length", "width", "density", "seed"):
                box.prop(s, name)
        box = col.box()
        box.prop(s, "base_type")
        if s.base_type in ("diffuse", "glossy", "principled"):
            box.prop(s, "base_color")
        if s.base_type in ("glossy", "principled"):
            box.prop(s, "base_roughness")
        if s.base_type == "principled":
            box.prop(s, "base_metallic")
        box.prop(s, "diffuse_type")
        if s.diffuse_type == "color":
            box.prop(s, "diffuse_color")
        box = col.box()
        box.prop(s, "lobe_shape")
        row = box.row()
        sub = row.row()
        sub.active = s.lobe_shape != "table"   # K only shapes fitted lobes
        sub.prop(s, "lobes")
        row.prop(s, "resolution")
        row.prop(s, "slices")
        box.prop(s, "mode", expand=True)
        box.prop(s, "backend")
        col.operator("scratch.update_material", icon="FILE_REFRESH")   # forces a full rebuild
        error = mat.get(live.ERROR_KEY)
        if error:
            col.label(text=f"Not updated: {error}", icon="ERROR")
        elif live.pending():
            col.label(text="Updating tables…", icon="TIME")
        err = mat.get("scratch_addon_fit_error")
        if err is not None:
            col.label(text=f"Lobe fit error (worst slice): {100 * err:.1f} %")


classes = (SCRATCH_PT_material,)
