"""Per-material settings of the scratch SV-BRDF (``material.scratch``), edited in the Material panel.

``to_params()`` turns them into the keyword arguments of ``api.make_scratched_material``;
``from_params()`` / ``from_spec()`` fill *every* setting from what a material was built with (the API calls
them after each build, so a later panel edit starts from what was built, not from the panel's defaults).
Validation happens in one place (``scratch_material.validate``), so the UI reports the same messages as the API.

What the panel cannot show is kept, not dropped: a profile or Fresnel model given as an object by a script
(a tabulated or resampled profile, a Lazanyi or single-channel model, ...) is stored in the settings (ID
properties ``script_profile`` / ``script_fresnel``) and the panel shows *From Script*; panel edits of other
settings rebuild with it, picking another profile / Fresnel replaces it.  The panel's floats are float32:
``to_params`` returns the shortest decimal that rounds to the stored float32 (a typed 0.3 is 0.3, as in a
script), and a value a float32 cannot hold exactly (e.g. a depth of 0.123456789) makes the profile a
*From Script* one rather than a slightly different table.
"""
from __future__ import annotations

import json

import bpy
import numpy as np

from ..precompute.scratch import fresnel as _fresnel, layers as _layers, material as _material, profiles
from . import compat, live

#: the profile / Fresnel given by a script that the panel cannot express (``from_spec``)
SCRIPT_PROFILE_KEY = "script_profile"
SCRIPT_FRESNEL_KEY = "script_fresnel"
#: the analytic profile families the panel shows with one value, and their ``Profile.params`` key
_FAMILY_VALUE = {"quartic": "depth", "v_groove": "half_angle_deg", "circular": "depth"}

PROFILE_ITEMS = [
    ("quartic", "Quartic", "Symmetric quartic bowl; value = depth / width"),
    ("v_groove", "V-groove", "V-shaped groove; value = half angle of the walls in degrees"),
    ("circular", "Round", "Circular arc; value = depth / width"),
    ("file", "Measured (file)", "Tabulated profile from a CSV/text file of x, height"),
    ("script", "From Script", "The profile a script built this material with (kept in the material); "
                              "pick another to replace it"),
]
FRESNEL_ITEMS = [
    ("none", "Lossless Mirror", "Fresnel = 1 (mirror scratches, energy conserving)"),
    ("metal", "Metal Preset", "Exact conductor Fresnel of a named metal"),
    ("conductor", "Conductor n, k", "Exact conductor Fresnel from complex IOR per RGB channel"),
    ("schlick", "Dielectric (Schlick)", "Schlick's approximation from an index of refraction"),
    ("script", "From Script", "The Fresnel model a script built this material with (kept in the material); "
                              "pick another to replace it"),
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
    # hard limits = what the API accepts (``layers.SIZE_RANGE``), so an API build shows and keeps its values;
    # the soft limits are the drag range
    length: bpy.props.FloatProperty(update=_live("length"), name="Length", default=0.2, min=_layers.SIZE_RANGE[0],
                                    max=_layers.SIZE_RANGE[1], soft_min=1e-6, soft_max=10.0, precision=5,
                                    description="Mean scratch length (UV units)")
    width: bpy.props.FloatProperty(update=_live("width"), name="Width", default=2e-4, min=_layers.SIZE_RANGE[0],
                                   max=_layers.SIZE_RANGE[1], soft_min=1e-7, soft_max=1.0, precision=6,
                                   description="Mean scratch width (UV units)")
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

    slices: bpy.props.EnumProperty(update=_live("slices"), name="View Slices", default="64",
                                   items=[(v, v, f"{v} view (φo) slices in the shader") for v in ("16", "32", "64", "128")],
                                   description="φo slices the shader interpolates (at most the table size)")
    base_metallic: bpy.props.FloatProperty(update=_live("base_metallic"), name="Base Metallic", default=0.0,
                                           min=0.0, max=1.0, description="Metallic of a Principled base")

    def to_params(self) -> dict:
        """Keyword arguments for ``api.make_scratched_material`` (validated there)."""
        profile, fresnel = self._profile_param(), self._fresnel_param()
        layers = None
        if self.use_layers:
            layers = dict(n_layers=self.n_layers, theta_deg=_f32(self.theta_deg), length=_f32(self.length),
                          width=_f32(self.width), density=_f32(self.density), seed=self.seed)
        base = {"type": self.base_type}
        if self.base_type in ("diffuse", "glossy", "principled"):
            base["color"] = _f32(self.base_color)
        if self.base_type in ("glossy", "principled"):
            base["roughness"] = _f32(self.base_roughness)
        if self.base_type == "principled" and self.base_metallic > 0.0:
            base["metallic"] = _f32(self.base_metallic)
        diffuse = {"none": None, "color": _f32(self.diffuse_color), "wood": "wood"}[self.diffuse_type]
        return dict(profile=profile, fresnel=fresnel, layers=layers, lobes=self.lobes, base=base, mode=self.mode,
                    resolution=int(self.resolution), slices=min(int(self.slices), int(self.resolution)), tint=_f32(self.tint), diffuse=diffuse,
                    lobe_shape=self.lobe_shape, backend=self.backend)

    def _profile_param(self):
        if self.profile_type == "file":
            if not self.profile_file:
                raise ValueError("profile file: choose a CSV/text file of x, height")
            return _profile_from_file(bpy.path.abspath(self.profile_file))
        if self.profile_type == "script":
            return _stored_profile(self.get(SCRIPT_PROFILE_KEY))
        return (self.profile_type, _f32(self.profile_value))

    def _fresnel_param(self):
        if self.fresnel_type == "script":
            return _stored_fresnel(self.get(SCRIPT_FRESNEL_KEY))
        return {"none": None, "metal": self.metal, "schlick": ("schlick", _f32(self.ior)),
                "conductor": ("conductor", _f32(self.ior_n), _f32(self.ior_k))}[self.fresnel_type]

    def from_params(self, params: dict) -> None:
        """Fill every setting from ``make_scratched_material`` keyword arguments (a preset's parameters): the
        ones ``params`` names and the API's default for the others (``from_spec``).  ValueError (nothing
        changed) for parameters the API would reject.  The material is not updated (it was built from them:
        ``api.make_scratched_material``; else press *Update*)."""
        self.from_spec(_material.validate(**params))

    def from_spec(self, spec) -> None:
        """Fill every setting from validated parameters (``scratch_material.validate``; the API after a
        build): afterwards ``to_params()`` rebuilds exactly ``spec``, so a panel edit changes only the
        edited value.  A profile or Fresnel model the panel cannot express is stored and shown as *From
        Script*; a seed outside the panel's 32-bit range is shown as the 32-bit seed that gives the same
        layers (``layers`` uses ``seed & 0xFFFFFFFF``); without layers the layer settings keep their values
        (unticking and ticking *Scratch Layers* brings them back).  The material is not updated."""
        with live.suspended():
            self._from_spec(spec)

    def _from_spec(self, spec) -> None:
        self._set_profile(spec.profile)
        self._set_fresnel(spec.fresnel)
        lp = spec.layers
        self.use_layers = lp is not None
        if lp is not None:
            seed = int(lp.seed) & 0xFFFFFFFF
            self.n_layers, self.theta_deg, self.seed = int(lp.n_layers), float(lp.theta_deg), seed - (seed >> 31 << 32)
            self.length, self.width, self.density = float(lp.length), float(lp.width), float(lp.density)
        base = spec.base
        self.base_type = base["type"]
        if "color" in base:
            self.base_color = tuple(base["color"])[:3]
        if "roughness" in base:
            self.base_roughness = base["roughness"]
        self.base_metallic = float(base.get("metallic", 0.0))
        self.lobes, self.lobe_shape, self.mode, self.backend = spec.lobes, spec.lobe_shape, spec.mode, spec.backend
        self.resolution, self.slices = str(int(spec.resolution)), str(int(spec.slices))
        self.tint = tuple(spec.tint)[:3]
        if spec.diffuse is None:
            self.diffuse_type = "none"
        elif isinstance(spec.diffuse, str):
            self.diffuse_type = "wood"
        else:
            self.diffuse_type, self.diffuse_color = "color", tuple(spec.diffuse)[:3]

    def _set_profile(self, profile) -> None:
        """The panel shows ``profile``: as it is (a file it reads again, a stored one), as a family and value,
        or stored (*From Script*)."""
        if self.profile_type in ("file", "script") and _same_profile(_panel_or_none(self, "profile"), profile):
            return
        value_key = _FAMILY_VALUE.get(profile.name)
        if value_key is not None and value_key in profile.params:
            self.profile_type, self.profile_value = profile.name, float(profile.params[value_key])
            if _same_profile(_panel_or_none(self, "profile"), profile):
                self.pop(SCRIPT_PROFILE_KEY, None)
                return
        self[SCRIPT_PROFILE_KEY] = {"x": profile.x.tolist(), "h": profile.h.tolist(), "name": str(profile.name),
                                    "params": json.dumps(profile.params, default=float),
                                    "symmetric": bool(profile.is_symmetric)}
        self.profile_type = "script"

    def _set_fresnel(self, fresnel) -> None:
        """The panel shows ``fresnel``: none, a metal preset, n and k, a Schlick IOR, or stored (*From Script*)."""
        if fresnel is None:
            self.fresnel_type = "none"
            return
        if self.fresnel_type == "script" and _same_fresnel(_panel_or_none(self, "fresnel"), fresnel):
            return
        name = getattr(fresnel, "name", "")
        if isinstance(fresnel, _fresnel.Conductor) and name in _fresnel.PRESETS:
            self.fresnel_type, self.metal = "metal", name
        elif isinstance(fresnel, _fresnel.Conductor) and fresnel.n.size == 3 and fresnel.k.size == 3:
            self.fresnel_type, self.ior_n, self.ior_k = "conductor", fresnel.n.tolist(), fresnel.k.tolist()
        elif isinstance(fresnel, _fresnel.Schlick) and fresnel.f0.size == 1 and 0.0 <= fresnel.f0[0] < 1.0:
            r = float(np.sqrt(fresnel.f0[0]))
            ior = (1.0 + r) / (1.0 - r)
            if 1.0 <= ior <= 4.0:
                self.fresnel_type, self.ior = "schlick", ior
        if self.fresnel_type != "script" and _same_fresnel(_panel_or_none(self, "fresnel"), fresnel):
            self.pop(SCRIPT_FRESNEL_KEY, None)
            return
        self[SCRIPT_FRESNEL_KEY] = _fresnel_record(fresnel)
        self.fresnel_type = "script"


_FILE_PROFILES: dict = {}   # (path, mtime, size) -> Profile: a live rebuild reads the file once, not twice


def _profile_from_file(path: str) -> profiles.Profile:
    """``profiles.from_file(path)``, remembered while the file is unchanged (at most 2 files: profiles of up to
    ``profiles.MAX_POINTS`` points are tens of MB)."""
    import os

    try:
        st = os.stat(path)
        key = (path, st.st_mtime_ns, st.st_size)
    except OSError:
        return profiles.from_file(path)          # its own error names the file
    hit = _FILE_PROFILES.get(key)
    if hit is None:
        hit = profiles.from_file(path)
        if len(_FILE_PROFILES) >= 2:
            _FILE_PROFILES.pop(next(iter(_FILE_PROFILES)))
        _FILE_PROFILES[key] = hit
    return hit


def _f32(value):
    """A float32 panel value (or vector) as the shortest decimal that rounds to it: what the user typed."""
    if hasattr(value, "__len__"):
        return tuple(_f32(v) for v in value)
    return float(np.format_float_scientific(np.float32(value), unique=True))


def _panel_or_none(settings, key: str):
    """The profile / Fresnel model the panel's settings give now (validated), None if they give none."""
    try:
        if key == "profile":
            return _material._as_profile(settings._profile_param())
        return _material._as_fresnel(settings._fresnel_param())
    except (ValueError, OSError, KeyError, TypeError):
        return None


def _same_profile(a, b) -> bool:
    return (isinstance(a, profiles.Profile) and isinstance(b, profiles.Profile) and a.name == b.name
            and json.dumps(a.params, sort_keys=True, default=float) == json.dumps(b.params, sort_keys=True, default=float)
            and np.array_equal(a.x, b.x) and np.array_equal(a.h, b.h))


def _same_fresnel(a, b) -> bool:
    if a is None or b is None:
        return a is b
    try:
        return json.dumps(a.cache_key(), sort_keys=True) == json.dumps(b.cache_key(), sort_keys=True)
    except Exception:  # noqa: BLE001 - a model without a usable cache key: never the same as a stored one
        return False


def _stored_profile(rec) -> profiles.Profile:
    if rec is None:
        raise ValueError("profile: 'From Script' but this material keeps no script profile; "
                         "choose Quartic, V-groove, Round or Measured (file)")
    return profiles.Profile(np.array(rec["x"], float), np.array(rec["h"], float), str(rec["name"]),
                            json.loads(rec["params"]), bool(rec["symmetric"]))


def _fresnel_record(model) -> dict:
    """ID-property record of a Fresnel model (``_stored_fresnel`` rebuilds it); models of other classes are
    recorded by name only and cannot be rebuilt from the panel (it says so)."""
    arrays = lambda *names: {n: np.asarray(getattr(model, n), float).ravel().tolist() for n in names}  # noqa: E731
    if isinstance(model, _fresnel.Conductor):
        return {"model": "conductor", "name": str(model.name), **arrays("n", "k")}
    if isinstance(model, _fresnel.Schlick):
        return {"model": "schlick", **arrays("f0")}
    if isinstance(model, _fresnel.Lazanyi):
        return {"model": "lazanyi", "alpha": float(model.alpha), **arrays("n", "k", "a")}
    if isinstance(model, _fresnel.Tabulated):
        return {"model": "tabulated", "source": _fresnel_record(model.source), "error": float(model.error),
                "shape": list(model.value.shape), "value": model.value.ravel().tolist(),
                "slope": model.slope.ravel().tolist()}
    return {"model": "other", "repr": repr(model)[:200]}


def _stored_fresnel(rec):
    if rec is None:
        raise ValueError("fresnel: 'From Script' but this material keeps no script Fresnel model; choose another")
    rec = rec.to_dict() if hasattr(rec, "to_dict") else rec
    arr = lambda key: np.array(rec[key], float)  # noqa: E731
    kind = rec["model"]
    if kind == "conductor":
        return _fresnel.Conductor(arr("n"), arr("k"), rec.get("name", ""))
    if kind == "schlick":
        return _fresnel.Schlick(arr("f0"))
    if kind == "lazanyi":
        return _fresnel.Lazanyi(arr("n"), arr("k"), arr("a"), float(rec["alpha"]))
    if kind == "tabulated":
        shape = tuple(rec["shape"])
        return _fresnel.Tabulated(arr("value").reshape(shape), arr("slope").reshape(shape[0] - 1, shape[1]),
                                  _stored_fresnel(rec["source"]), float(rec["error"]))
    raise ValueError(f"fresnel: set by a script as {rec.get('repr', '?')}, a model the panel cannot store; "
                     "rebuild with make_scratched_material(material=..., fresnel=...) or choose a Fresnel here")


classes = (ScratchMaterialSettings,)


def register_pointer() -> None:
    from .iridescence_material import SCRATCH_PG_iridescence

    bpy.types.Material.scratch = bpy.props.PointerProperty(type=ScratchMaterialSettings)
    bpy.types.Material.scratch_iridescence = bpy.props.PointerProperty(type=SCRATCH_PG_iridescence)


def unregister_pointer() -> None:
    del bpy.types.Material.scratch_iridescence
    del bpy.types.Material.scratch
