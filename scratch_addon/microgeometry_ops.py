"""Material from a measured height field (Dong et al. 2015, §5.1, §6, §8-9): operator, panel, builders.

``scratch.material_from_heightfield`` reads a height field (.npy/.npz/.exr/text grid, see
``precompute.heightfield``), computes its average NDF (filtered §5.1 / naive / Kirchhoff §6),
fits the ellipsoid NDF (§8) and converts it to Glossy parameters
(``precompute.microgeometry_material``); optionally it synthesises a spatially varying ellipsoid
texture (§9) from a texel strip along x and one along y of the scan and packs it into two Non-Color
float images.  Tables are cached (``precompute.cache.cached_arrays``, key = file content hash +
parameters), so re-running with the same inputs is instant.

Headless use: ``bpy.ops.scratch.material_from_heightfield(filepath=..., pixel_um=..., ...)`` with a
mesh as the active object; or call :func:`material_from_heightfield` directly.
"""
from __future__ import annotations

import hashlib
import os

import bpy

import numpy as np

from . import _deps, materials, panels
from .ui_utils import assign_material, poll_active_mesh, progress

NDF_KINDS = (
    ("FILTERED", "Filtered", "Gaussian-weighted plane fits, sigma (§5.1; the paper's default)"),
    ("NAIVE", "Naive", "Triangle normals of the raw height field (§5.1)"),
    ("KIRCHHOFF", "Kirchhoff", "Kirchhoff D_K at wavelength lambda (eq. 6, Appendix A)"),
)
_NDF_RESOLUTION = 513
_TEXEL_TABLE_RESOLUTION = 257


def _pc(name):
    return _deps.sibling("precompute." + name)


def file_sha256(path: str) -> str:
    """SHA-256 of a file's bytes (the cache key of a height field)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _check_params(pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um):
    pixel_um = materials.check_range("pixel_um", pixel_um, 1e-4, 1e4)
    sigma_um = materials.check_range("sigma_um", sigma_um, 1e-4, 1e4)
    wavelength_um = materials.check_range("wavelength_um", wavelength_um, 0.05, 100.0)
    if ndf_kind not in {k for k, _, _ in NDF_KINDS}:
        raise ValueError(f"ndf_kind must be one of {[k for k, _, _ in NDF_KINDS]}, got {ndf_kind!r}")
    texture_size = int(materials.check_range("texture_size", texture_size, 8, 4096))
    texel_um = materials.check_range("texel_um", texel_um, 1e-3, 1e5)
    return pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um


def compute_tables(filepath: str, pixel_um: float, sigma_um: float = 1.0, wavelength_um: float = 0.555,
                   ndf_kind: str = "FILTERED", synthesize: bool = False, texture_size: int = 256,
                   texel_um: float = 63.5, seed: int = 0, progress=None) -> dict:
    """Average ellipsoid parameters (and optionally a synthesised (S, S, 5) texture), cached.

    Units: micrometres (pixel size, sigma, wavelength, texel size).  Returns
    ``{"ellipsoid": (5,), "texture": (S, S, 5) (if synthesize), "cached": bool}``.  ``progress(f)``
    is called with fractions in [0, 1].  Raises ``ValueError`` with the parameter's name on bad input.
    """
    pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um = _check_params(
        pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um)
    filepath = bpy.path.abspath(filepath) if filepath.startswith("//") else filepath
    if not filepath or not os.path.isfile(filepath):
        raise ValueError(f"filepath: no such height-field file {filepath!r}")
    report = progress or (lambda f: None)
    hfm, mg, syn, cache = _pc("heightfield"), _pc("microgeometry"), _pc("ndf_synthesis"), _pc("cache")
    ell = _pc("ellipsoid_ndf")
    version = cache.code_version(hfm, mg, ell, syn)
    f32 = lambda v: float(np.float32(v))  # noqa: E731 - operator properties are float32: same key either way
    uses_sigma = ndf_kind == "FILTERED" or synthesize
    inputs = {"file_sha256": file_sha256(filepath), "pixel_um": f32(pixel_um), "ndf_kind": ndf_kind,
              "sigma_um": f32(sigma_um) if uses_sigma else 0.0,
              "wavelength_um": f32(wavelength_um) if ndf_kind == "KIRCHHOFF" else 0.0,
              "synthesize": bool(synthesize), "texture_size": texture_size if synthesize else 0,
              "texel_um": f32(texel_um) if synthesize else 0.0, "seed": int(seed) if synthesize else 0}
    state = {"cached": True}

    def compute():
        state["cached"] = False
        hf = hfm.load_heightfield(filepath, pixel_um=pixel_um)
        report(0.1)
        if ndf_kind == "FILTERED":
            ndf = mg.filtered_ndf(hf, sigma_um=sigma_um, resolution=_NDF_RESOLUTION)
        elif ndf_kind == "NAIVE":
            ndf = mg.naive_ndf(hf, resolution=_NDF_RESOLUTION)
        else:
            ndf = mg.kirchhoff_ndf(hf, wavelength_um=wavelength_um, resolution=_NDF_RESOLUTION, normalize=True)
        report(0.4)
        out = {"ellipsoid": np.array(mg.fit_ellipsoid(ndf), dtype=np.float64)}
        report(0.5)
        if synthesize:
            strip_x, strip_y = _strips(hf, texel_um)
            out["texture"] = syn.synthesize_from_strips(strip_x, strip_y, (texture_size, texture_size), texel_um,
                                                        hf.pixel_um, sigma_um, int(seed), _TEXEL_TABLE_RESOLUTION)
        report(0.9)
        return out

    result = {k: np.array(v, dtype=np.float64) for k, v in
              cache.cached_arrays("microgeometry_material", version, inputs, compute).items()}
    for v in result.values():  # float32 storage can round a clamped bound just outside the valid range
        v[..., :2] = np.clip(v[..., :2], ell.ALPHA_MIN, ell.ALPHA_MAX)
        v[..., 2:4] = np.clip(v[..., 2:4], -ell.THETA_XY_MAX, ell.THETA_XY_MAX)
    result["cached"] = state["cached"]
    report(1.0)
    return result


def _strips(hf, texel_um: float):
    """§9 exemplars: the middle texel-high row band (along x) and texel-wide column band (along y)."""
    tp = int(round(texel_um / hf.pixel_um))
    ny, nx = hf.shape
    if tp < 4 or nx < 8 * tp or ny < 8 * tp:
        raise ValueError(f"texel_um: {texel_um} µm = {tp} px texels; texture synthesis needs >= 4 px texels and "
                         f">= 8 texels along each side of the {nx} x {ny} px height field")
    y0, x0 = (ny // tp // 2) * tp, (nx // tp // 2) * tp
    return hf.crop(y0, y0 + tp, 0, nx), hf.crop(0, ny, x0, x0 + tp)


# ----------------------------------------------------------------------------- material builders


def _finish_material(mat, kind: str) -> None:
    mat["scratch_addon_kind"] = kind
    if hasattr(mat, "cycles") and hasattr(mat.cycles, "use_bump_map_correction"):
        mat.cycles.use_bump_map_correction = False  # it would rotate the tilted lobe normals toward Ng


def make_average_material(name: str, params, color=(0.8, 0.8, 0.8)):
    """Material with one ellipsoid lobe (§8) from 5 parameters ``(alpha_x, alpha_y, theta_x, theta_y, theta_z)``.

    Returns ``(material, GlossyParams-like dict of the node inputs, LossReport)``.
    """
    rgba = materials.check_color("color", color)
    conv = _pc("microgeometry_material")
    try:
        maps, loss = conv.glossy_from_ellipsoid(np.asarray(params, dtype=np.float64))
    except ValueError as exc:
        raise ValueError(f"params: {exc}") from None
    group = _deps.sibling("node_groups.microgeometry").ensure_average()
    mat = materials.new_material(name)
    tree = mat.node_tree
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["Color"].default_value = rgba
    node.inputs["Roughness"].default_value = float(maps["roughness"])
    node.inputs["Anisotropy"].default_value = float(maps["anisotropy"])
    node.inputs["Rotation"].default_value = float(maps["rotation"])
    node.inputs["Tilt"].default_value = tuple(float(v) for v in maps["tilt"])
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
    conv = _pc("microgeometry_material")
    try:
        imgs, loss = conv.node_textures(np.asarray(texture, dtype=np.float64))
    except ValueError as exc:
        raise ValueError(f"texture: {exc}") from None
    params_img = _float_image(f"{name} params", imgs["params"])
    tilt_img = _float_image(f"{name} tilt", imgs["tilt"])
    mat = materials.new_material(name)
    tree = mat.node_tree
    group = _deps.sibling("node_groups.microgeometry").add_texture_nodes(tree, params_img, tilt_img, scale,
                                                                          interpolation)
    group.inputs["Color"].default_value = rgba
    tree.links.new(group.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    _finish_material(mat, "microgeometry_texture")
    return mat, {"params": params_img, "tilt": tilt_img}, loss


def material_from_heightfield(filepath: str, pixel_um: float, sigma_um: float = 1.0, wavelength_um: float = 0.555,
                              ndf_kind: str = "FILTERED", synthesize: bool = False, texture_size: int = 256,
                              texel_um: float = 63.5, texture_scale: float = 1.0, seed: int = 0,
                              color=(0.8, 0.8, 0.8), name: str | None = None, progress=None):
    """Height field file -> Cycles material (average NDF, or synthesised texture if ``synthesize``).

    Returns ``(material, info)`` with ``info = {"ellipsoid", "loss", "cached"}``.
    """
    tables = compute_tables(filepath, pixel_um, sigma_um, wavelength_um, ndf_kind, synthesize, texture_size,
                            texel_um, seed, progress)
    stem = os.path.splitext(os.path.basename(filepath))[0]
    if synthesize:
        mat, _, loss = make_texture_material(name or f"Microgeometry {stem} (texture)", tables["texture"], color,
                                             texture_scale)
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
        sub = col.column()
        sub.enabled = self.synthesize
        for prop in ("texture_size", "texel_um", "texture_scale", "seed"):
            sub.prop(self, prop)

    def execute(self, context):
        obj = context.active_object
        try:
            with progress(context) as update:
                mat, info = material_from_heightfield(
                    self.filepath, self.pixel_um, self.sigma_um, self.wavelength_um, self.ndf_kind, self.synthesize,
                    self.texture_size, self.texel_um, self.texture_scale, self.seed, progress=update)
        except (ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        assign_material(obj, mat)
        loss = info["loss"]
        self.report({"WARNING"} if not loss.lossless else {"INFO"},
                    f"Assigned {mat.name}{' (cached tables)' if info['cached'] else ''}; {loss}")
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
