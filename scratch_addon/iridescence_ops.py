"""Operators and the sub-panel of the iridescent scratch layer (``iridescence_material``).

All operators act on the active object's active material, finish in ``execute()`` and report
errors instead of raising.  Register ``classes`` after ``iridescence_material.classes`` and add
``bpy.types.Material.scratch_iridescence = PointerProperty(type=SCRATCH_PG_iridescence)``.
"""
from __future__ import annotations

import bpy

from . import iridescence_material as im
from . import panels
from .ui_utils import USER_ERRORS, progress, report_error, report_render_path


def _material(context):
    mat = getattr(context, "material", None)
    if mat is None:
        obj = context.active_object
        mat = obj.active_material if obj is not None else None
    return mat


def _pg(mat):
    pg = getattr(mat, "scratch_iridescence", None)
    if pg is None:
        raise ValueError("scratch_iridescence properties are not registered on Material")
    return pg


def _poll_material(cls, context):
    if _material(context) is None:
        cls.poll_message_set("Select an object with a material")
        return False
    return True


def _generate(pg):
    return im.generate_scratch_set(pg.count, (pg.length_min, pg.length_max), (pg.width_min_um, pg.width_max_um),
                                   (pg.depth_min_um, pg.depth_max_um), pg.spread_deg, pg.angle_deg, pg.seed,
                                   pg.uv_scale_um)


def _build(mat, context, scratches=None):
    pg = _pg(mat)
    return im.insert_layer(mat, scratches, sigma_um=pg.sigma_um, route=pg.route.lower(), samples=pg.samples,
                           base_blend=pg.base_blend, scene=context.scene, candidates=pg.candidates,
                           base_weight=pg.base_weight.lower(), shadows=pg.shadows)


_ERRORS = USER_ERRORS  # a failed (re)build leaves the material as it was (im.insert_layer)


class SCRATCH_OT_add_iridescent_layer(bpy.types.Operator):
    """Insert the iridescent scratch layer between the material's surface and its output"""

    bl_idname = "scratch.add_iridescent_layer"
    bl_label = "Add Iridescent Scratch Layer"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(_poll_material)

    def execute(self, context):
        mat = _material(context)
        try:
            with progress(context):
                scratches = None if im.stored_scratches(mat) is not None else _generate(_pg(mat))
                _build(mat, context, scratches)
        except _ERRORS as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"Iridescent layer on {mat.name}")
        report_render_path(self, mat, context.scene)
        return {"FINISHED"}


class SCRATCH_OT_remove_iridescent_layer(bpy.types.Operator):
    """Remove the iridescent scratch layer and restore the original surface link"""

    bl_idname = "scratch.remove_iridescent_layer"
    bl_label = "Remove Iridescent Scratch Layer"
    bl_options = {"REGISTER", "UNDO"}

    poll = classmethod(_poll_material)

    def execute(self, context):
        mat = _material(context)
        if not im.remove_layer(mat):
            self.report({"ERROR"}, f"material {mat.name!r} has no iridescent layer")
            return {"CANCELLED"}
        return {"FINISHED"}


class SCRATCH_OT_generate_scratch_set(bpy.types.Operator):
    """Generate a random scratch set for the material (and rebuild its layer)"""

    bl_idname = "scratch.generate_scratch_set"
    bl_label = "Generate Scratch Set"
    bl_options = {"REGISTER", "UNDO"}

    count: bpy.props.IntProperty(name="Count", default=300, min=0, max=200000)
    length_min: bpy.props.FloatProperty(name="Length Min (UV)", default=0.05, min=0.0)
    length_max: bpy.props.FloatProperty(name="Length Max (UV)", default=0.3, min=0.0)
    width_min_um: bpy.props.FloatProperty(name="Width Min (µm)", default=0.8, min=0.0)
    width_max_um: bpy.props.FloatProperty(name="Width Max (µm)", default=6.0, min=0.0)
    depth_min_um: bpy.props.FloatProperty(name="Depth Min (µm)", default=0.8, min=0.0)
    depth_max_um: bpy.props.FloatProperty(name="Depth Max (µm)", default=6.0, min=0.0)
    spread_deg: bpy.props.FloatProperty(name="Orientation Spread (°)", default=180.0, min=0.0, max=180.0)
    angle_deg: bpy.props.FloatProperty(name="Main Direction (°)", default=0.0)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)
    uv_scale_um: bpy.props.FloatProperty(name="UV Scale (µm per UV)", default=1e4, min=0.0)
    use_material_settings: bpy.props.BoolProperty(
        name="Use Material Settings", default=True,
        description="Take the parameters from the material's iridescence settings (else from this operator)")

    poll = classmethod(_poll_material)

    def execute(self, context):
        mat = _material(context)
        try:
            pg = _pg(mat)
            if self.use_material_settings:
                scratches = _generate(pg)
            else:
                scratches = im.generate_scratch_set(
                    self.count, (self.length_min, self.length_max), (self.width_min_um, self.width_max_um),
                    (self.depth_min_um, self.depth_max_um), self.spread_deg, self.angle_deg, self.seed,
                    self.uv_scale_um)
            if im.layer_node(mat) is not None:
                _build(mat, context, scratches)
            else:
                im.store_scratches(mat, scratches)
        except _ERRORS as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"{len(scratches)} scratch segments on {mat.name}")
        return {"FINISHED"}


class SCRATCH_OT_scratches_from_curve(bpy.types.Operator):
    """Scratches from a curve drawn over the surface (closest point on the mesh, UV interpolated)"""

    bl_idname = "scratch.scratches_from_curve"
    bl_label = "Scratches from Curve"
    bl_options = {"REGISTER", "UNDO"}

    curve: bpy.props.StringProperty(name="Curve", description="Curve object (default: a selected curve)")
    target: bpy.props.StringProperty(name="Target", description="Mesh object (default: the active mesh)")
    append: bpy.props.BoolProperty(name="Append", default=False, description="Add to the stored scratch set")

    def execute(self, context):
        try:
            curve = bpy.data.objects.get(self.curve) if self.curve else next(
                (o for o in context.selected_objects if o.type == "CURVE"), None)
            target = bpy.data.objects.get(self.target) if self.target else context.active_object
            if curve is None or curve.type != "CURVE":
                raise ValueError(f"curve must name a curve object (got {self.curve!r})")
            if target is None or target.type != "MESH":
                raise ValueError(f"target must name a mesh object (got {self.target!r})")
            mat = target.active_material
            if mat is None:
                raise ValueError(f"target {target.name!r} has no material")
            pg = _pg(mat)
            s = im.scratches_from_curve(curve, target, pg.curve_width_um, pg.curve_depth_um, pg.uv_scale_um,
                                        context.evaluated_depsgraph_get())
            old = im.stored_scratches(mat) if self.append else None
            if old is not None:
                import numpy as np
                if abs(old.uv_scale_um - s.uv_scale_um) > 1e-9 * s.uv_scale_um:
                    raise ValueError("append: the stored set has a different uv_scale_um")
                s = im.scratch_set.ScratchSet(np.concatenate([old.p0, s.p0]), np.concatenate([old.p1, s.p1]),
                                              np.concatenate([old.width_um, s.width_um]),
                                              np.concatenate([old.depth_um, s.depth_um]), s.uv_scale_um)
            if im.layer_node(mat) is not None:
                _build(mat, context, s)
            else:
                im.store_scratches(mat, s)
        except _ERRORS as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"{len(s)} scratch segments on {mat.name}")
        return {"FINISHED"}


def _preset_items(_self, _context):
    return [(k, k.replace("_", " ").title(), f"Iridescent scratch preset {k}") for k in sorted(im.PRESETS)]


class SCRATCH_OT_iridescence_preset(bpy.types.Operator):
    """Apply an iridescent scratch preset (parameters + a new scratch set)"""

    bl_idname = "scratch.iridescence_preset"
    bl_label = "Iridescent Scratch Preset"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(name="Preset", items=_preset_items)
    poll = classmethod(_poll_material)

    def execute(self, context):
        mat = _material(context)
        try:
            pg = _pg(mat)
            im.apply_preset(pg, self.preset)
            s = _generate(pg)
            if im.layer_node(mat) is not None:
                _build(mat, context, s)
            else:
                im.store_scratches(mat, s)
        except _ERRORS as exc:
            return report_error(self, exc)
        return {"FINISHED"}


class SCRATCH_PT_iridescence(bpy.types.Panel):
    bl_label = "Iridescent Scratches"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_parent_id = "SCRATCH_PT_material"

    @classmethod
    def poll(cls, context):
        return context.engine in panels.ENGINES and getattr(context, "material", None) is not None

    def draw(self, context):
        layout = self.layout
        mat = context.material
        pg = getattr(mat, "scratch_iridescence", None)
        if im.layer_node(mat) is None:
            layout.operator("scratch.add_iridescent_layer", icon="ADD")
        else:
            layout.operator("scratch.remove_iridescent_layer", icon="REMOVE")
        if pg is None:
            return
        layout.operator_menu_enum("scratch.iridescence_preset", "preset", text="Preset")
        col = layout.column(align=True)
        for name in ("route", "sigma_um", "samples", "candidates", "base_blend"):
            col.prop(pg, name)
        sub = col.column(align=True)
        sub.active = pg.base_blend
        sub.prop(pg, "base_weight")
        sub = col.column(align=True)
        sub.active = pg.route == "LIGHTS"
        sub.prop(pg, "shadows")
        box = layout.box()
        box.label(text="Scratch set")
        col = box.column(align=True)
        for name in ("count", "length_min", "length_max", "width_min_um", "width_max_um", "depth_min_um",
                     "depth_max_um", "spread_deg", "angle_deg", "seed", "uv_scale_um"):
            col.prop(pg, name)
        box.operator("scratch.generate_scratch_set")
        col = box.column(align=True)
        col.prop(pg, "curve_width_um")
        col.prop(pg, "curve_depth_um")
        box.operator("scratch.scratches_from_curve")
        s = mat.get(im.SET_KEY)
        if s is not None:
            box.label(text=f"{len(s['segments']) // 6} segments stored")


classes = (SCRATCH_OT_add_iridescent_layer, SCRATCH_OT_remove_iridescent_layer, SCRATCH_OT_generate_scratch_set,
           SCRATCH_OT_scratches_from_curve, SCRATCH_OT_iridescence_preset, SCRATCH_PT_iridescence)
