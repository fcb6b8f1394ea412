"""Per-material settings of the scratch SV-BRDF (``material.scratch``), edited in the Material panel.

``to_params()`` turns them into the keyword arguments of ``api.make_scratched_material``;
``from_params()`` fills them from a preset.  Validation happens in one place
(``scratch_material.validate``), so the UI reports the same messages as the API.
"""
from __future__ import annotations

import bpy

from ..precompute.scratch import fresnel as _fresnel, profiles
from . import compat, live

PROFILE_ITEMS = [
    ("quartic", "Quartic", "Symmetric quartic bowl; value = depth / width"),
    ("v_groove", "V-groove", "V-shaped groove; value = half angle of the walls in degrees"),
    ("circular", "Round", "Circular arc; value = depth / width"),
    ("file", "Measured (file)", "Tabulated profile from a CSV/text file of x, height"),
]
FRESNEL_ITEMS = [
    ("none", "Lossless Mirror", "Fresnel = 1 (mirror scratches, energy conserving)"),
    ("metal", "Metal Preset", "Exact conductor Fresnel of a named metal"),
    ("conductor", "Conductor n, k", "Exact conductor Fresnel from complex IOR per RGB channel"),
    ("schlick", "Dielectric (Schlick)", "Schlick's approximation from an index of refraction"),
]
BASE_ITEMS = [
    ("mirror", "Mirror", "Perfect mirror of the same Fresnel"),
    ("none", "None", "Black between scratches"),
    ("diffuse", "Diffuse", "Lambertian base"),
    ("glossy", "Glossy", "Rough glossy base"),
    ("principled", "Principled", "Principled BSDF base (paint, plastic)"),
]


#: A static list (no items callback: see ``compat.PROPERTY_GROUP_CALLBACKS``).
METAL_ITEMS = [(k, k.title(), f"n, k of {k} at 650/550/450 nm") for k in sorted(_fresnel.PRESETS)]


def _live(prop: str):
    """Update callback: the material follows the setting at once (``live``; sockets or tables)."""
    return compat.update(live.updater(prop))


class ScratchMaterialSettings(bpy.types.PropertyGroup):
    """Every setting updates the material as it changes (``live``): sockets at once, tables after a drag."""

    profile_type: bpy.props.EnumProperty(update=_live("profile_type"), name="Profile", items=PROFILE_ITEMS, default="quartic")
    profile_value: bpy.props.FloatProperty(update=_live("profile_value"), name="Value", default=0.2, min=0.001, soft_max=2.0,
                                           description="Depth/width ratio (quartic, round) or half angle in degrees (V-groove)")
    profile_file: bpy.props.StringProperty(update=_live("profile_file"), name="Profile File", subtype="FILE_PATH")
    fresnel_type: bpy.props.EnumProperty(update=_live("fresnel_type"), name="Fresnel", items=FRESNEL_ITEMS, default="metal")
    metal: bpy.props.EnumProperty(update=_live("metal"), name="Metal", items=METAL_ITEMS)
    ior_n: bpy.props.FloatVectorProperty(update=_live("ior_n"), name="n", size=3, default=(2.91, 2.95, 2.65), min=0.01)
    ior_k: bpy.props.FloatVectorProperty(update=_live("ior_k"), name="k", size=3, default=(3.09, 2.93, 2.80), min=0.0)
    ior: bpy.props.FloatProperty(update=_live("ior"), name="IOR", default=1.5, min=1.0, max=4.0)
    tint: bpy.props.FloatVectorProperty(update=_live("tint"), name="Tint", subtype="COLOR", size=3, default=(1, 1, 1), min=0, max=1)
    lobes: bpy.props.IntProperty(update=_live("lobes"), name="Lobes (K)", default=8, min=1, max=16,
                                 description="At most this many tilted GGX lobes per view slice")
    lobe_shape: bpy.props.EnumProperty(update=_live("lobe_shape"), 
        name="Lobe Shape", default="table",
        items=[("fit", "Fitted", "At most K fitted tilted GGX lobes per view slice (smooth, least noise)"),
               ("box", "Box", "Fitted lobes with a tilt jitter each (stochastic box lobes): closer fit of "
                              "round profiles, slower fit"),
               ("table", "Table", "Tabulated-tilt lobes: the table sampled bin by bin, exact (< 1 %), no fit; "
                                  "a little more noise under small lights")])
    use_layers: bpy.props.BoolProperty(update=_live("use_layers"), name="Scratch Layers", default=True,
                                       description="Off: scratches everywhere (densely brushed)")
    n_layers: bpy.props.IntProperty(update=_live("n_layers"), name="Layers", default=4, min=1, max=64)
    theta_deg: bpy.props.FloatProperty(update=_live("theta_deg"), name="Orientation Spread", default=7.0, min=0.0, max=360.0)
    length: bpy.props.FloatProperty(update=_live("length"), name="Length", default=0.2, min=1e-6, precision=5, description="Mean scratch length (UV units)")
    width: bpy.props.FloatProperty(update=_live("width"), name="Width", default=2e-4, min=1e-7, precision=6, description="Mean scratch width (UV units)")
    density: bpy.props.FloatProperty(update=_live("density"), name="Density", default=0.6, min=0.0, max=1.0)
    seed: bpy.props.IntProperty(update=_live("seed"), name="Seed", default=0)
    base_type: bpy.props.EnumProperty(update=_live("base_type"), name="Base", items=BASE_ITEMS, default="mirror")
    base_color: bpy.props.FloatVectorProperty(update=_live("base_color"), name="Base Color", subtype="COLOR", size=3, default=(0.5, 0.5, 0.5), min=0, max=1)
    base_roughness: bpy.props.FloatProperty(update=_live("base_roughness"), name="Base Roughness", default=0.3, min=0.0, max=1.0)
    diffuse_type: bpy.props.EnumProperty(update=_live("diffuse_type"), name="Diffuse Term", items=[
        ("none", "None", "No diffuse term"), ("color", "Color", "Uniform Lambertian term under everything"),
        ("wood", "Wood", "Procedural wood-grain Lambertian term")], default="none")
    diffuse_color: bpy.props.FloatVectorProperty(update=_live("diffuse_color"), name="Diffuse Color", subtype="COLOR", size=3, default=(0.05, 0.12, 0.45),
                                                 min=0, max=1)
    mode: bpy.props.EnumProperty(update=_live("mode"), name="Mode", items=[("lobes", "Lobes", "Product path: light sampling kept"),
                                                     ("reference", "Reference", "Exact table via ray portals (validation)")])
    backend: bpy.props.EnumProperty(update=_live("backend"), 
        name="Shaders", default="osl",
        items=[("osl", "OSL + Node Groups", "OSL shader where Cycles runs OSL on the CPU (footprint-filtered "
                                           "scratch coverage), its node-group twin everywhere else (Cycles SVM, "
                                           "GPU, EEVEE)"),
               ("svm", "Node Groups Only", "Only the node-group (SVM) path: GPU, EEVEE and Cycles OSL alike; "
                                          "scratch coverage is sampled per pixel")])
    resolution: bpy.props.EnumProperty(update=_live("resolution"), name="Table", items=[(v, v, f"{v}x{v} scratch BRDF table") for v in ("64", "128", "256", "512")],
                                       default="256")

    def to_params(self) -> dict:
        """Keyword arguments for ``api.make_scratched_material`` (validated there)."""
        if self.profile_type == "file":
            if not self.profile_file:
                raise ValueError("profile file: choose a CSV/text file of x, height")
            profile = profiles.from_file(bpy.path.abspath(self.profile_file))
        else:
            profile = (self.profile_type, self.profile_value)
        fresnel = {"none": None, "metal": self.metal, "conductor": ("conductor", tuple(self.ior_n), tuple(self.ior_k)),
                   "schlick": ("schlick", self.ior)}[self.fresnel_type]
        layers = None
        if self.use_layers:
            layers = dict(n_layers=self.n_layers, theta_deg=self.theta_deg, length=self.length, width=self.width,
                          density=self.density, seed=self.seed)
        base = {"type": self.base_type}
        if self.base_type in ("diffuse", "glossy", "principled"):
            base["color"] = tuple(self.base_color)
        if self.base_type in ("glossy", "principled"):
            base["roughness"] = self.base_roughness
        diffuse = {"none": None, "color": tuple(self.diffuse_color), "wood": "wood"}[self.diffuse_type]
        return dict(profile=profile, fresnel=fresnel, layers=layers, lobes=self.lobes, base=base, mode=self.mode,
                    resolution=int(self.resolution), tint=tuple(self.tint), diffuse=diffuse, lobe_shape=self.lobe_shape,
                    backend=self.backend)

    def from_params(self, params: dict) -> None:
        """Fill the settings from preset parameters (only the fields a preset names); the material is not
        updated (it was built from them: ``api.make_scratched_material``; else press *Update*)."""
        with live.suspended():
            self._from_params(params)

    def _from_params(self, params: dict) -> None:
        prof = params.get("profile")
        if isinstance(prof, (tuple, list)):
            self.profile_type, self.profile_value = prof[0], float(prof[1])
        fr = params.get("fresnel", None)
        if fr is None:
            self.fresnel_type = "none"
        elif isinstance(fr, str):
            self.fresnel_type, self.metal = "metal", fr
        elif fr[0] == "schlick":
            self.fresnel_type, self.ior = "schlick", float(fr[1])
        elif fr[0] == "conductor":
            self.fresnel_type, self.ior_n, self.ior_k = "conductor", fr[1], fr[2]
        layers = params.get("layers")
        self.use_layers = layers is not None
        for key, value in (layers or {}).items():
            setattr(self, key, value)
        base = params.get("base", "mirror")
        base = {"type": base} if isinstance(base, str) else base
        self.base_type = base["type"]
        if "color" in base:
            self.base_color = base["color"][:3]
        if "roughness" in base:
            self.base_roughness = base["roughness"]
        if "lobes" in params:
            self.lobes = params["lobes"]
        if "lobe_shape" in params:
            self.lobe_shape = params["lobe_shape"]
        elif "box_lobes" in params:
            self.lobe_shape = "box" if params["box_lobes"] else "fit"
        if "backend" in params:
            self.backend = params["backend"]
        if "resolution" in params:
            self.resolution = str(int(params["resolution"]))
        if "mode" in params:
            self.mode = params["mode"]
        if "tint" in params:
            self.tint = tuple(params["tint"])[:3]
        diffuse = params.get("diffuse")
        if diffuse is None:
            self.diffuse_type = "none"
        elif diffuse == "wood":
            self.diffuse_type = "wood"
        else:
            self.diffuse_type, self.diffuse_color = "color", diffuse[:3]


classes = (ScratchMaterialSettings,)


def register_pointer() -> None:
    from .iridescence_material import SCRATCH_PG_iridescence

    bpy.types.Material.scratch = bpy.props.PointerProperty(type=ScratchMaterialSettings)
    bpy.types.Material.scratch_iridescence = bpy.props.PointerProperty(type=SCRATCH_PG_iridescence)


def unregister_pointer() -> None:
    del bpy.types.Material.scratch_iridescence
    del bpy.types.Material.scratch
