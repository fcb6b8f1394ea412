"""Material from a measured height field (Dong et al. 2015, §5.1, §6, §8-9): operator, panel, builders.

``scratch.material_from_heightfield`` gets the height field's tables from
``precompute.microgeometry.tables.compute_tables`` (average NDF, ellipsoid fit, optional §9 texture;
cached by file content hash) and builds the material: Glossy parameters from
``precompute.microgeometry.glossy`` in the node groups of ``node_groups.microgeometry``, the texture
packed into two Non-Color float images.

Headless use: ``bpy.ops.scratch.material_from_heightfield(filepath=..., pixel_um=..., ...)`` with a
mesh as the active object; or call :func:`material_from_heightfield` directly.
"""
from __future__ import annotations

import os

import bpy

import numpy as np

from ..node_groups import microgeometry as mg_groups
from ..precompute.microgeometry import glossy as conv
from ..precompute.microgeometry import tables as mg_tables
from ..precompute.microgeometry.tables import NDF_KINDS, file_sha256  # noqa: F401 - re-exports
from . import materials, panels, transaction
from .keywords import checked
from .ui_utils import USER_ERRORS, assign_material, poll_active_mesh, progress, report_error, reported_warnings

# ----------------------------------------------------------------------------- material builders

#: How the average material renders the measured NDF (operator enum items).
NDF_MODELS = {"ELLIPSOID": ("Ellipsoid Fit", "One anisotropic Glossy lobe fitted to the NDF (§8); SVM, GPU, EEVEE"),
              "TABLE": ("Table", "The measured NDF itself as a tabulated microfacet BRDF with light sampling "
                                 "(Cycles OSL and SVM, GPU, EEVEE); the ellipsoid lobe only where the table "
                                 "does not fit the node-group images")}


def _finish_material(mat, kind: str) -> None:
    mat["scratch_addon_kind"] = kind
    if hasattr(mat, "cycles") and hasattr(mat.cycles, "use_bump_map_correction"):
        mat.cycles.use_bump_map_correction = False  # it would rotate the tilted lobe normals toward Ng


def _average_node(tree, maps, rgba):
    """The average-NDF node group (one ellipsoid lobe, §8) with the Glossy parameters ``maps``."""
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = mg_groups.ensure_average()
    node.inputs["Color"].default_value = rgba
    node.inputs["Roughness"].default_value = float(maps["roughness"])
    node.inputs["Anisotropy"].default_value = float(maps["anisotropy"])
    node.inputs["Rotation"].default_value = float(maps["rotation"])
    node.inputs["Tilt"].default_value = tuple(float(v) for v in maps["tilt"])
    return node


def make_average_material(name: str, params, color=(0.8, 0.8, 0.8)):
    """Material with one ellipsoid lobe (§8) from 5 parameters ``(alpha_x, alpha_y, theta_x, theta_y, theta_z)``.

    Returns ``(material, GlossyParams-like dict of the node inputs, LossReport)``.
    """
    rgba = materials.check_color("color", color)
    try:
        maps, loss = conv.glossy_from_ellipsoid(np.asarray(params, dtype=np.float64))
    except ValueError as exc:
        raise ValueError(f"params: {exc}") from None
    mat = materials.new_material(name)
    tree = mat.node_tree
    node = _average_node(tree, maps, rgba)
    tree.links.new(node.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    _finish_material(mat, "microgeometry_average")
    mat["microgeometry_ellipsoid"] = [float(v) for v in maps["ellipsoid"]]
    return mat, maps, loss


def _float_image(name: str, rgba: np.ndarray):
    H, W, _ = rgba.shape
    old = bpy.data.images.get(name)
    if old is not None and old.users == 0:
        bpy.data.images.remove(old)
    img = bpy.data.images.new(name, W, H, alpha=True, float_buffer=True, is_data=True)
    img.colorspace_settings.is_data = True
    img.pixels.foreach_set(np.ascontiguousarray(rgba, dtype=np.float32).ravel())  # row 0 = bottom = y = 0
    img.file_format = "OPEN_EXR"
    img.pack()  # a saved .blend renders without external files (float EXR, exact)
    return img


def make_texture_material(name: str, texture, color=(0.8, 0.8, 0.8), scale: float = 1.0,
                          interpolation: str = "Linear"):
    """Material with a per-texel ellipsoid lobe (§9) from an (H, W, 5) parameter texture.

    The texture is tiled ``scale`` times per UV unit (Mapping node "Texture Scale").  Returns
    ``(material, images dict, LossReport)``.
    """
    rgba = materials.check_color("color", color)
    scale = materials.check_range("scale", scale, 1e-6, 1e6)
    if interpolation not in ("Linear", "Closest", "Cubic"):
        raise ValueError(f"interpolation must be 'Linear', 'Closest' or 'Cubic', got {interpolation!r}")
    try:
        imgs, loss = conv.node_textures(np.asarray(texture, dtype=np.float64))
    except ValueError as exc:
        raise ValueError(f"texture: {exc}") from None
    params_img = _float_image(f"{name} params", imgs["params"])
    tilt_img = _float_image(f"{name} tilt", imgs["tilt"])
    mat = materials.new_material(name)
    tree = mat.node_tree
    group = mg_groups.add_texture_nodes(tree, params_img, tilt_img, scale, interpolation)
    group.inputs["Color"].default_value = rgba
    tree.links.new(group.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    _finish_material(mat, "microgeometry_texture")
    return mat, {"params": params_img, "tilt": tilt_img}, loss


@checked
def material_from_heightfield(filepath: str, pixel_um: float, sigma_um: float = 1.0, wavelength_um: float = 0.555,
                              ndf_kind: str = "FILTERED", synthesize: bool = False, texture_size: int = 256,
                              texel_um: float = 63.5, texture_scale: float = 1.0, seed: int = 0,
                              color=(0.8, 0.8, 0.8), name: str | None = None, progress=None,
                              ndf_model: str = "ELLIPSOID", multiple_scattering: bool = True):
    """Height field file -> Cycles material (average NDF, or synthesised texture if ``synthesize``).

    ``ndf_model`` (average NDF only): ``"ELLIPSOID"`` the §8 ellipsoid fit as one Glossy lobe (SVM, GPU,
    EEVEE), ``"TABLE"`` the measured NDF itself as a tabulated microfacet BRDF (issue 16:
    ``tabulated_material.make_ndf_material``: the OSL closure with light sampling, its node-group table on
    SVM / GPU / EEVEE; the ellipsoid lobe only where the table does not fit the images).
    ``multiple_scattering`` (table only; default on): the table also holds the light the single-scattering
    model's Smith shadowing loses, scattered again on the same NDF's Smith microsurface (Heitz et al. 2016), so a
    mirror-like metal keeps its energy at grazing views.  Returns ``(material, info)`` with ``info = {"ellipsoid", "loss", "cached"}`` (``loss``
    None for the table).  A failure leaves no new material or image behind.
    """
    if ndf_model not in NDF_MODELS:
        raise ValueError(f"ndf_model: expected one of {list(NDF_MODELS)}, got {ndf_model!r}")
    if not isinstance(multiple_scattering, (bool, np.bool_)):
        raise ValueError(f"multiple_scattering: expected True or False, got {multiple_scattering!r}")
    if ndf_model == "TABLE" and synthesize:
        raise ValueError("ndf_model: the measured-NDF table is the average material; the synthesised texture "
                         "(synthesize) uses the ellipsoid fit per texel")
    if not isinstance(filepath, (str, os.PathLike)):
        raise ValueError(f"filepath: expected a path to a height-field file, got {type(filepath).__name__}")
    filepath = os.fspath(filepath)
    filepath = bpy.path.abspath(filepath) if filepath.startswith("//") else filepath
    tables = mg_tables.compute_tables(filepath, pixel_um, sigma_um, wavelength_um, ndf_kind, synthesize, texture_size,
                                      texel_um, seed, progress, with_ndf=ndf_model == "TABLE")
    stem = os.path.splitext(os.path.basename(filepath))[0]
    with transaction.new_datablocks():
        if synthesize:
            mat, _, loss = make_texture_material(name or f"Microgeometry {stem} (texture)", tables["texture"], color,
                                                 texture_scale)
        elif ndf_model == "TABLE":
            from ..precompute.microgeometry.ndf import NDFTable
            from .tabulated_material import make_ndf_material

            rgba = materials.check_color("color", color)
            maps, _ = conv.glossy_from_ellipsoid(np.asarray(tables["ellipsoid"], dtype=np.float64))
            # OSL, SVM / GPU and EEVEE render the table; the §8 ellipsoid lobe (the Ellipsoid Fit material) is
            # the fallback twin where the table does not fit the node-group images
            mat, loss = make_ndf_material(NDFTable(tables["ndf"], kind=ndf_kind.lower()),
                                          name or f"Microgeometry {stem} (NDF table)", F=rgba[:3],
                                          svm_twin=lambda tree: _average_node(tree, maps, rgba).outputs["BSDF"],
                                          multiple_scattering=multiple_scattering), None
        else:
            mat, _, loss = make_average_material(name or f"Microgeometry {stem} (average)", tables["ellipsoid"], color)
        mat["microgeometry_source"] = os.path.basename(filepath)
    return mat, {"ellipsoid": tables["ellipsoid"], "loss": loss, "cached": tables["cached"]}


# ----------------------------------------------------------------------------- operator + panel


class SCRATCH_OT_material_from_heightfield(bpy.types.Operator):
    """Build a Cycles material from a measured height field (Dong et al. 2015) and assign it to the active object"""

    bl_idname = "scratch.material_from_heightfield"
    bl_label = "Material from Height Field"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(name="Height Field", subtype="FILE_PATH",
                                       description="Height field in micrometres (.npy, .npz, .exr, .txt, .csv)")
    filter_glob: bpy.props.StringProperty(default="*.npy;*.npz;*.exr;*.txt;*.csv;*.asc;*.dat", options={"HIDDEN"})
    pixel_um: bpy.props.FloatProperty(name="Pixel Size (µm)", default=0.11, min=1e-4, max=1e4, precision=4)
    sigma_um: bpy.props.FloatProperty(name="Sigma (µm)", default=1.0, min=1e-4, max=1e4,
                                      description="Gaussian plane-fit filter width (filtered NDF, §5.1)")
    wavelength_um: bpy.props.FloatProperty(name="Lambda (µm)", default=0.555, min=0.05, max=100.0,
                                           description="Effective Kirchhoff wavelength lambda_q (eq. 5-6)")
    ndf_kind: bpy.props.EnumProperty(name="NDF", items=NDF_KINDS, default="FILTERED")
    ndf_model: bpy.props.EnumProperty(name="NDF Model", default="ELLIPSOID",
                                      items=[(k, a, b) for k, (a, b) in NDF_MODELS.items()],
                                      description="Average material: the ellipsoid fit, or the measured NDF as a table")
    multiple_scattering: bpy.props.BoolProperty(
        name="Multiple Scattering", default=True,
        description="NDF table: also the light scattered more than once between the micro-facets (Heitz et al. "
                    "2016 random walk on the same NDF), so a mirror-like metal keeps its energy at grazing views")
    synthesize: bpy.props.BoolProperty(name="Synthesise Texture", default=False,
                                       description="Spatially varying ellipsoid NDF texture (§9) "
                                                   "instead of the average NDF")
    texture_size: bpy.props.IntProperty(name="Texture Size", default=256, min=8, max=4096)
    texel_um: bpy.props.FloatProperty(name="Texel (µm)", default=63.5, min=1e-3, max=1e5,
                                      description="Texel size of the synthesised texture (paper: ~400 texels/inch)")
    texture_scale: bpy.props.FloatProperty(name="Texture Repeats per UV", default=1.0, min=1e-6, max=1e6)
    seed: bpy.props.IntProperty(name="Seed", default=0, min=0)

    @classmethod
    def poll(cls, context):
        return poll_active_mesh(cls, context)

    def invoke(self, context, event):
        if not self.filepath and context.window is not None:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def draw(self, context):
        col = self.layout.column()
        for prop in ("pixel_um", "ndf_kind", "sigma_um", "wavelength_um", "synthesize"):
            col.prop(self, prop)
        row = col.row()
        row.enabled = not self.synthesize
        row.prop(self, "ndf_model", expand=True)
        row = col.row()
        row.enabled = not self.synthesize and self.ndf_model == "TABLE"
        row.prop(self, "multiple_scattering")
        sub = col.column()
        sub.enabled = self.synthesize
        for prop in ("texture_size", "texel_um", "texture_scale", "seed"):
            sub.prop(self, prop)

    def execute(self, context):
        obj = context.active_object
        try:  # a failure leaves the object's material slot as it was
            with reported_warnings(self), progress(context) as update:
                mat, info = material_from_heightfield(
                    self.filepath, self.pixel_um, self.sigma_um, self.wavelength_um, self.ndf_kind, self.synthesize,
                    self.texture_size, self.texel_um, self.texture_scale, self.seed, progress=update,
                    ndf_model="ELLIPSOID" if self.synthesize else self.ndf_model,
                    multiple_scattering=self.multiple_scattering)
        except USER_ERRORS as exc:
            return report_error(self, exc)
        assign_material(obj, mat)
        loss = info["loss"]
        cached = " (cached tables)" if info["cached"] else ""
        if loss is None:
            self.report({"INFO"}, f"Assigned {mat.name}{cached}; measured NDF as a table")
        else:
            self.report({"WARNING"} if not loss.lossless else {"INFO"}, f"Assigned {mat.name}{cached}; {loss}")
        return {"FINISHED"}


class SCRATCH_PT_microgeometry(bpy.types.Panel):
    bl_label = "Measured Microgeometry"
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
        layout.operator(SCRATCH_OT_material_from_heightfield.bl_idname, icon="FILE_IMAGE")
        mat = context.material
        if mat is not None and "microgeometry_source" in mat:
            layout.label(text=f"From: {mat['microgeometry_source']}")


classes = (SCRATCH_OT_material_from_heightfield, SCRATCH_PT_microgeometry)
