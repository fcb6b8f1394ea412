"""Bi-scale operators and panel (Wu et al. 2011): add a procedural tile, bake its large-scale material."""
from __future__ import annotations

import bpy
import numpy as np

from ..precompute.biscale import geometry as geo
from . import ui_utils
from .ui_utils import USER_ERRORS, op_labels, progress, report_error, reported_warnings


def tile_mesh(kind: str, **params):
    """numpy ``Tile`` of a procedural kind (§4.2); heightfield-image reads ``image`` (a bpy image)."""
    if kind == "PYRAMID":
        return geo.pyramid_tile(n_sides=params.get("n_sides", 4), height=params.get("height", 0.5),
                                base=params.get("base", 1.0))
    if kind == "GROOVE":
        return geo.groove_tile(depth=params.get("depth", 0.5), floor=params.get("floor", 0.3), top=params.get("top", 0.2))
    if kind == "RODS":
        return geo.rods_tile(n_rods=params.get("n_rods", 4), length=params.get("height", 0.5),
                             tilt=params.get("tilt", 0.3), seed=params.get("seed", 0))
    if kind == "WOVEN":
        return geo.woven_tile(n_threads=params.get("n_threads", 2), height=params.get("height", 0.15))
    if kind == "HEIGHTFIELD":
        img = params.get("image")
        if img is None:
            raise ValueError("image: a height-field tile needs an image")
        w, h = img.size
        if w < 2 or h < 2:
            raise ValueError(f"image: expected at least 2 x 2 pixels, got {w} x {h}")
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        lum = px.reshape(h, w, 4)[..., :3].mean(-1)
        step = max(1, int(np.ceil(max(w, h) / params.get("resolution", 64))))
        return geo.heightfield_tile(lum[::step, ::step], height_scale=params.get("height", 0.1))
    raise ValueError(f"kind: expected one of PYRAMID, GROOVE, RODS, WOVEN, HEIGHTFIELD, got {kind!r}")


def add_tile_object(context, tile, name="Bi-scale Tile", n_materials=None):
    """Mesh object from a numpy tile (material slots created, one per material index)."""
    mesh = bpy.data.meshes.new(name)
    V, F = np.asarray(tile.vertices), np.asarray(tile.faces)
    mesh.vertices.add(len(V))
    mesh.vertices.foreach_set("co", V.astype(np.float32).ravel())
    mesh.loops.add(F.size)
    mesh.loops.foreach_set("vertex_index", F.astype(np.int32).ravel())
    mesh.polygons.add(len(F))
    mesh.polygons.foreach_set("loop_start", np.arange(0, F.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("material_index", np.asarray(tile.face_material, np.int32))
    mesh.update(calc_edges=True)
    mesh.validate()
    obj = bpy.data.objects.new(name, mesh)
    context.scene.collection.objects.link(obj)
    k = int(np.max(tile.face_material)) + 1 if n_materials is None else n_materials
    for i in range(k):
        m = bpy.data.materials.new(f"{name} part {i}")
        mesh.materials.append(m)
    return obj


class SCRATCH_OT_add_biscale_tile(bpy.types.Operator):
    """Add a procedural small-scale tile (pyramid, groove, rods, woven threads or an image height field)"""

    bl_idname = "scratch.add_biscale_tile"
    bl_label = "Add Bi-scale Tile"
    bl_options = {"REGISTER", "UNDO"}

    kind: bpy.props.EnumProperty(name="Kind", items=[
        ("PYRAMID", "Pyramid", "n-sided pyramid"), ("GROOVE", "Groove", "trapezoidal groove along y"),
        ("RODS", "Rods", "tilted rods on a floor (velvet)"), ("WOVEN", "Woven", "plain-weave threads"),
        ("HEIGHTFIELD", "Height Field Image", "height field from an image's luminance")], default="PYRAMID")
    n_sides: bpy.props.IntProperty(name="Sides", default=4, min=3, max=64)
    height: bpy.props.FloatProperty(name="Height", default=0.5, min=0.0, max=10.0)
    depth: bpy.props.FloatProperty(name="Depth", default=0.5, min=0.0, max=10.0)
    n_rods: bpy.props.IntProperty(name="Rods", default=4, min=1, max=100)
    tilt: bpy.props.FloatProperty(name="Tilt", default=0.3, min=0.0, max=1.4, subtype="ANGLE")
    n_threads: bpy.props.IntProperty(name="Threads", default=2, min=2, max=32, step=2)
    image: bpy.props.StringProperty(name="Image", default="")
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)

    def execute(self, context):
        try:
            img = bpy.data.images.get(self.image) if self.image else None
            if self.kind == "HEIGHTFIELD" and img is None:
                raise ValueError(f"image: no image named {self.image!r} (load one first)")
            tile = tile_mesh(self.kind, n_sides=self.n_sides, height=self.height, depth=self.depth,
                             n_rods=self.n_rods, tilt=self.tilt, n_threads=self.n_threads, image=img, seed=self.seed)
        except USER_ERRORS as exc:  # named as in the panel: a rods tile's "length" is the Height field
            return report_error(self, exc, op_labels(self, length="Height", height_scale="Height"))
        obj = add_tile_object(context, tile, name=f"Bi-scale {self.kind.title()}")
        for o in context.view_layer.objects:
            o.select_set(False)
        context.view_layer.objects.active = obj
        obj.select_set(True)
        return {"FINISHED"}


class SCRATCH_OT_bake_biscale(bpy.types.Operator):
    """Bake the large-scale material of the active tile object (its material slots are the small-scale
    materials) and apply it to the target object"""

    bl_idname = "scratch.bake_biscale"
    bl_label = "Bake Bi-scale Material"
    bl_options = {"REGISTER", "UNDO"}

    target: bpy.props.StringProperty(name="Target", default="",
                                     description="Object receiving the material (default: the other selected object)")
    n_lobes: bpy.props.IntProperty(name="Glossy Lobes", default=4, min=0, max=8)
    n_facets: bpy.props.IntProperty(name="Facets", default=10000, min=16, max=1000000)
    dir_res: bpy.props.IntProperty(name="Direction Resolution", default=0, min=0, max=24,
                                   description="Directions per side of the table (0: automatic, from the sharpest "
                                               "small-scale material in the Exact Table mode, 10 otherwise)")
    mode: bpy.props.EnumProperty(name="Mode", items=[
        ("TABLE", "Exact Table", "The table itself as one narrow closure per sample (OSL on the CPU, light "
                                 "sampling kept); the fitted closures render it on GPU, SVM and EEVEE"),
        ("FIT", "Fitted Closures", "Diffuse + GGX Glossy lobes fitted to the table (SVM, GPU, light sampling)"),
        ("REFERENCE", "Exact Reference", "The table importance-sampled in OSL through ray_portal_bsdf (CPU, no "
                                         "light sampling, turns on the scene's OSL backend; validation only)")],
        default="TABLE")
    interreflections: bpy.props.EnumProperty(name="Inter-reflections", items=[
        ("AUTO", "Automatic", "Light bouncing between the tile's facets (and its periodic neighbours) is added when a "
                              "first-bounce estimate says it changes the material by more than 1 %"),
        ("ON", "On", "Add the inter-reflected light (path traced inside the repeated tile; a few seconds)"),
        ("OFF", "Off", "Single bounce only, as Wu et al. 2011 (darker than the real geometry)")],
        default="AUTO")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            cls.poll_message_set("Make the tile mesh the active object")
            return False
        return True

    def execute(self, context):
        from . import biscale_material as bmat

        tile_obj = context.active_object
        target = bpy.data.objects.get(self.target) if self.target else next(
            (o for o in context.view_layer.objects if o.select_get() and o is not tile_obj and o.type == "MESH"), None)
        if self.target and target is None:
            self.report({"ERROR"}, f"target: no object named {self.target!r}")
            return {"CANCELLED"}
        try:  # a failure leaves the target's material slot as it was (bmat.bake)
            with reported_warnings(self), progress(context) as update:
                mat, brdf, fit, info = bmat.bake(tile_obj, target, n_lobes=self.n_lobes, progress=update,
                                                 depsgraph=context.evaluated_depsgraph_get(),
                                                 mode=self.mode.lower(), n_facets=self.n_facets,
                                                 interreflections={"AUTO": "auto", "ON": True,
                                                                   "OFF": False}[self.interreflections],
                                                 **({"dir_res": self.dir_res or 10}       # 0: automatic (table)
                                                    if self.dir_res or self.mode != "TABLE" else {}))
        except USER_ERRORS as exc:  # named as in the panel (Direction Resolution, not dir_res)
            return report_error(self, exc, op_labels(self))
        reused = " (tile reused)" if info["reused_tile"] else ""
        inter = (f", inter-reflections {'on' if info['interreflections'] else 'off'} "
                 f"(estimate {100 * info['indirect_estimate']:.1f} %)")
        self.report({"INFO"}, f"{mat.name}: fit error rel. L1 {fit.rel_l1:.3f}, PSNR {fit.psnr:.1f} dB{inter}{reused}")
        if info["mode"] in ("reference", "table"):
            ui_utils.report_render_path(self, mat, context.scene)
        return {"FINISHED"}


class SCRATCH_PT_biscale(bpy.types.Panel):
    bl_label = "Bi-scale Material"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_parent_id = "SCRATCH_PT_material"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.operator("scratch.add_biscale_tile")
        layout.operator("scratch.bake_biscale")
        mat = context.material
        if mat is not None and mat.get("scratch_addon_kind") == "biscale":
            if mat.get("biscale_mode") == "table":
                layout.label(text=f"Exact table ({mat.get('tabulated_res', 0)}² directions, OSL); elsewhere the fitted closures")
            if mat.get("biscale_mode") == "reference":
                layout.label(text="Exact reference (OSL, ray portal sampling); elsewhere the fitted closures")
            if "biscale_interreflections" in mat:
                layout.label(text=f"Inter-reflections {'on' if mat['biscale_interreflections'] else 'off'} "
                                  f"(first-bounce estimate {100 * mat.get('biscale_indirect_estimate', 0):.1f} %)")
            if "biscale_fit_psnr" in mat:
                layout.label(text=f"Fit: rel. L1 {mat.get('biscale_fit_rel_l1', 0):.3f}, "
                                  f"PSNR {mat.get('biscale_fit_psnr', 0):.1f} dB")


classes = (SCRATCH_OT_add_biscale_tile, SCRATCH_OT_bake_biscale, SCRATCH_PT_biscale)
