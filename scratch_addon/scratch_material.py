"""Build the scratch SV-BRDF material (Raymond et al. 2016) in a Cycles node tree.

Pipeline (all table work is cached by content hash in ``precompute.cache``):
profile + Fresnel -> ``precompute.scratch_brdf.simulate`` (ρ0, ρm, γ) ->
``precompute.scratch_lobes.lobe_tables`` (≤ K tilted GGX lobes per φo slice) ->
``osl.scratch_svbrdf.generate`` (specialised OSL source, tables compiled in) ->
INTERNAL script node, with UV Map and Tangent nodes wired in and the base closure linked
to its ``Base`` input.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import bpy
import numpy as np

from . import _deps, materials, osl_compile, render_paths

profiles = _deps.sibling("precompute.profiles")
fresnel_mod = _deps.sibling("precompute.fresnel")
scratch_brdf = _deps.sibling("precompute.scratch_brdf")
scratch_lobes = _deps.sibling("precompute.scratch_lobes")
scratch_layers = _deps.sibling("precompute.scratch_layers")
osl_gen = _deps.sibling("osl.scratch_svbrdf")

BASE_TYPES = ("mirror", "none", "diffuse", "glossy", "principled")
MODES = ("lobes", "reference")
BACKENDS = ("osl", "svm")
#: "fit": <= K fitted tilted lobes; "box": fitted lobes with a tilt jitter each; "table": tabulated-tilt
#: lobes (precompute.lobe_table: the slice sampled bin by bin, exact, no fit; the default)
LOBE_SHAPES = ("fit", "box", "table")


@dataclass
class ScratchParams:
    """Validated inputs of ``make_scratched_material`` (see ``api.make_scratched_material``)."""

    profile: object
    fresnel: object
    layers: object  # LayerParams or None (dense)
    lobes: int
    base: dict
    mode: str
    resolution: int
    slices: int
    tint: tuple
    diffuse: object = None  # None, an RGB colour or "wood": a Lambertian term added to the whole material
    backend: str = "osl"    # "osl" (CPU/OptiX, footprint-filtered α, hash-picked lobes) or "svm" (GPU/EEVEE)
    lobe_shape: str = "table"  # one of LOBE_SHAPES

    @property
    def box_lobes(self) -> bool:
        return self.lobe_shape == "box"


def _as_layers(layers):
    if layers is None or isinstance(layers, scratch_layers.LayerParams):
        return layers
    if isinstance(layers, dict):
        try:
            return scratch_layers.LayerParams(**layers)
        except TypeError as exc:
            raise ValueError(f"layers: {exc}") from None
    if isinstance(layers, (int,)) and not isinstance(layers, bool):
        return scratch_layers.LayerParams(n_layers=layers)
    raise ValueError(f"layers must be None (dense), an int (count), a dict or a LayerParams; got {layers!r}")


def _as_base(base) -> dict:
    if isinstance(base, str):
        base = {"type": base}
    if not isinstance(base, dict) or base.get("type") not in BASE_TYPES:
        raise ValueError(f"base must be one of {', '.join(BASE_TYPES)} (or a dict with 'type'); got {base!r}")
    out = dict(base)
    if "color" in out:
        out["color"] = materials.check_color("base color", out["color"])
    if "roughness" in out:
        out["roughness"] = materials.check_range("base roughness", out["roughness"], 0.0, 1.0)
    return out


def _as_profile(profile):
    if isinstance(profile, (tuple, list)) and len(profile) == 2 and isinstance(profile[0], str):
        family = getattr(profiles, profile[0], None)
        if family is None or profile[0] not in ("quartic", "v_groove", "circular"):
            raise ValueError(f"profile family must be quartic, v_groove or circular; got {profile[0]!r}")
        return family(profile[1])
    return profile


def _as_fresnel(fresnel):
    if fresnel is None or isinstance(fresnel, fresnel_mod.Fresnel):
        return fresnel
    if isinstance(fresnel, str):
        return fresnel_mod.conductor_preset(fresnel)
    if isinstance(fresnel, (tuple, list)) and len(fresnel) == 2 and fresnel[0] == "schlick":
        return fresnel_mod.schlick(fresnel[1])
    if isinstance(fresnel, (tuple, list)) and len(fresnel) == 3 and fresnel[0] == "conductor":
        return fresnel_mod.conductor(fresnel[1], fresnel[2])
    raise ValueError("fresnel must be None (lossless), a metal name, ('schlick', ior), ('conductor', n, k) "
                     f"or a precompute.fresnel model; got {fresnel!r}")


def validate(profile=None, fresnel=None, layers=None, lobes=8, base="mirror", mode="lobes", resolution=256,
             slices=64, tint=(1.0, 1.0, 1.0), diffuse=None, backend="osl", box_lobes=False,
             lobe_shape=None) -> ScratchParams:
    """Check every parameter; raise ValueError naming the parameter and its allowed range."""
    profile = profiles.quartic(0.2) if profile is None else _as_profile(profile)
    if not isinstance(profile, profiles.Profile):
        raise ValueError(f"profile must be a precompute.profiles profile (quartic, v_groove, tabulated...); got {profile!r}")
    fresnel = _as_fresnel(fresnel)
    if isinstance(lobes, bool) or not isinstance(lobes, int) or not 1 <= lobes <= 16:
        raise ValueError(f"lobes must be an integer in [1, 16], got {lobes!r}")
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
    if mode == "reference" and resolution > osl_gen.ReferenceSpec.MAX_M:
        raise ValueError(f"resolution must be <= {osl_gen.ReferenceSpec.MAX_M} in reference mode "
                         f"(the exact table is compiled into the shader); got {resolution}")
    if resolution not in (64, 128, 256, 512):
        raise ValueError(f"resolution must be one of 64, 128, 256, 512; got {resolution!r}")
    if slices not in (16, 32, 64, 128) or slices > resolution:
        raise ValueError(f"slices must be one of 16, 32, 64, 128 and <= resolution; got {slices!r}")
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if backend == "svm" and mode != "lobes":
        raise ValueError("mode must be 'lobes' with backend 'svm' (the reference mode needs OSL)")
    if not isinstance(box_lobes, bool):
        raise ValueError(f"box_lobes must be True or False, got {box_lobes!r}")
    if lobe_shape is None:  # default: the exact table lobes, on both backends
        lobe_shape = "box" if box_lobes else "table"
    if lobe_shape not in LOBE_SHAPES:
        raise ValueError(f"lobe_shape must be one of {', '.join(LOBE_SHAPES)}; got {lobe_shape!r}")
    if box_lobes and lobe_shape != "box":
        raise ValueError(f"box_lobes=True contradicts lobe_shape={lobe_shape!r} (use lobe_shape='box')")
    rgba = materials.check_color("tint", tint)
    if diffuse is not None and diffuse != "wood":
        diffuse = materials.check_color("diffuse", diffuse)[:3]
    return ScratchParams(profile, fresnel, _as_layers(layers), lobes, _as_base(base), mode, resolution, slices,
                         rgba[:3], diffuse, backend, lobe_shape)


def _check_uvs_for(obj_meshes) -> None:
    for mesh in obj_meshes:
        if not mesh.uv_layers:
            raise ValueError(f"mesh {mesh.name!r} has no UV map: scratch layers and directions follow the UVs "
                             "(add one with UV > Unwrap or Smart UV Project)")


def check_uvs(material: bpy.types.Material) -> None:
    """Raise ValueError if an object using ``material`` has a mesh without UVs."""
    users = [o.data for o in bpy.data.objects if o.type == "MESH" and material.name in [m.name for m in o.data.materials if m]]
    _check_uvs_for(users)


def _principled_conductor(nodes, fresnel):
    """A mirror conductor for Blender < 4.3: Principled metallic, F82-tint model (Cycles' principled
    metal: Base Color = F(0 deg), Specular Tint = F(82 deg) / Schlick(82 deg)), the closest built-in
    match to ``fresnel`` there; exact at normal incidence and at 82 deg."""
    f0 = np.broadcast_to(np.asarray(fresnel(np.array([1.0])), float).reshape(-1), (3,))
    f82 = np.broadcast_to(np.asarray(fresnel(np.array([1.0 / 7.0])), float).reshape(-1), (3,))
    schlick82 = f0 + (1.0 - f0) * (1.0 - 1.0 / 7.0) ** 5
    node = nodes.new("ShaderNodeBsdfPrincipled")
    node.inputs["Base Color"].default_value = (*np.clip(f0, 0.0, 1.0), 1.0)
    node.inputs["Metallic"].default_value = 1.0
    node.inputs["Roughness"].default_value = 0.0
    node.inputs["Specular Tint"].default_value = (*np.clip(f82 / np.maximum(schlick82, 1e-6), 0.0, 1.0), 1.0)
    return node


def _base_node(tree, params: ScratchParams):
    """The base material closure node (eq. 4's ρ_b), or None."""
    b = params.base
    kind = b["type"]
    n = tree.nodes
    if kind == "none":
        return None
    if kind == "mirror":
        f = params.fresnel
        if f is None:
            node = n.new("ShaderNodeBsdfGlossy")
            node.distribution = "GGX"
            node.inputs["Roughness"].default_value = 0.0
            node.inputs["Color"].default_value = (1, 1, 1, 1)
            return node
        if hasattr(f, "k") and not hasattr(bpy.types, "ShaderNodeBsdfMetallic"):
            return _principled_conductor(n, f)  # Blender < 4.3 has no Metallic BSDF node
        if hasattr(f, "k"):  # conductor (exact or Lazanyi): Cycles' own physical conductor
            node = n.new("ShaderNodeBsdfMetallic")
            node.fresnel_type = "PHYSICAL_CONDUCTOR"
            node.inputs["Roughness"].default_value = 0.0
            nn = [float(x) for x in (list(f.n) * 3)[:3]] if f.n.size == 1 else [float(x) for x in f.n]
            kk = [float(x) for x in (list(f.k) * 3)[:3]] if f.k.size == 1 else [float(x) for x in f.k]
            node.inputs["IOR"].default_value = nn
            node.inputs["Extinction"].default_value = kk
            return node
        node = n.new("ShaderNodeBsdfPrincipled")  # dielectric mirror: specular only
        node.inputs["Base Color"].default_value = (0, 0, 0, 1)
        node.inputs["Roughness"].default_value = 0.0
        f0 = float(f.f0.mean())
        node.inputs["IOR"].default_value = (1 + f0 ** 0.5) / max(1 - f0 ** 0.5, 1e-3)
        return node
    if kind == "diffuse":
        node = n.new("ShaderNodeBsdfDiffuse")
        node.inputs["Color"].default_value = b.get("color", (0.5, 0.5, 0.5, 1.0))
        return node
    if kind == "glossy":
        node = n.new("ShaderNodeBsdfGlossy")
        node.distribution = "MULTI_GGX"
        node.inputs["Color"].default_value = b.get("color", (0.9, 0.9, 0.9, 1.0))
        node.inputs["Roughness"].default_value = b.get("roughness", 0.1)
        return node
    node = n.new("ShaderNodeBsdfPrincipled")
    node.inputs["Base Color"].default_value = b.get("color", (0.8, 0.1, 0.1, 1.0))
    node.inputs["Roughness"].default_value = b.get("roughness", 0.3)
    if "metallic" in b:
        node.inputs["Metallic"].default_value = materials.check_range("base metallic", b["metallic"], 0.0, 1.0)
    return node


def shader_source(params: ScratchParams, brdf=None, lobe_data=None, **spec_options) -> str:
    """Generate the specialised OSL source for ``params`` (tables computed or taken from the cache)."""
    if brdf is None:
        brdf = scratch_brdf.simulate(params.profile, resolution=params.resolution, fresnel=params.fresnel, cache=True)
    layers = params.layers
    theta_k, xi_k = scratch_layers.layer_transforms(layers) if layers is not None else (None, None)
    layer_kw = {} if layers is None else dict(theta_k=theta_k, xi_k=xi_k, coverage=scratch_layers.coverage_table()[1])
    if params.mode == "reference":
        return osl_gen.generate_reference(osl_gen.ReferenceSpec(
            rho_m=brdf.rho_m, rho0=brdf.rho0, gamma=brdf.gamma, layers=layers,
            use_base=params.base["type"] != "none", **layer_kw))
    if lobe_data is None:
        lobe_data = _lobe_data(params, brdf)
    if params.lobe_shape == "table":
        lobes = dict(lobes_m=None, table=osl_gen.TableLobes.from_tables(lobe_data, strata=params.lobes))
    else:
        def table(entry):
            return None if entry is None else osl_gen.LobeTable.from_fit(entry)
        lobes = dict(lobes_m=table(lobe_data["m"]), lobes_0=table(lobe_data["0"]))
    spec = osl_gen.ShaderSpec(**lobes, alpha_x=lobe_data["alpha_x"], layers=layers,
                              use_base=params.base["type"] != "none", **layer_kw, **spec_options)
    return osl_gen.generate(spec)


def _lobe_data(params: ScratchParams, brdf) -> dict:
    """Lobe tables for ``params`` (cached): tabulated-tilt lobes, or <= K fitted (plain / box) lobes."""
    if params.lobe_shape == "table":
        return scratch_lobes.table_lobes(brdf, slices=params.slices)
    # the SVM path has one Glossy node per lobe column, so one distribution (GGX) for all slices
    return scratch_lobes.lobe_tables(brdf, K=params.lobes, slices=params.slices,
                                     dists="ggx" if params.backend == "svm" else "auto", jitter=params.box_lobes)


def fit_error(lobe_data: dict) -> float:
    """Worst per-slice rel. L1 error of ``lobe_data`` (fitted or table lobes) against ρ cos."""
    if "cdf" in lobe_data:
        errs = [lobe_data["error_m"]] + ([] if lobe_data.get("error_0") is None else [lobe_data["error_0"]])
    else:
        errs = [lobe_data["m"]["error"]] + ([] if lobe_data["0"] is None else [lobe_data["0"]["error"]])
    return float(max(np.max(e) for e in errs))


def _wood_texture(tree, socket) -> None:
    """Procedural wood rings (Wave texture through a brown colour ramp) into ``socket``."""
    wave = tree.nodes.new("ShaderNodeTexWave")
    wave.wave_type, wave.bands_direction = "RINGS", "Z"
    wave.inputs["Scale"].default_value = 2.0
    wave.inputs["Distortion"].default_value = 6.0
    wave.inputs["Detail"].default_value = 3.0
    wave.location = (-400, -450)
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.location = (-150, -450)
    ramp.color_ramp.elements[0].color = (0.20, 0.08, 0.03, 1)
    ramp.color_ramp.elements[1].color = (0.45, 0.22, 0.08, 1)
    tree.links.new(wave.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], socket)


def _jsonable(v):
    return v.tolist() if hasattr(v, "tolist") else float(v)


def build(material: bpy.types.Material, params: ScratchParams, progress=None, **spec_options) -> bpy.types.Material:
    """(Re)build ``material``'s node tree for ``params``; ``progress(fraction)`` is called along the way.

    Backend "svm": node groups only.  Backend "osl": the OSL script for Cycles with OSL on the CPU
    plus its SVM twin for Cycles SVM (the default, GPU) and EEVEE, chosen by ``render_paths``."""
    step = progress or (lambda _f: None)
    step(0.05)
    brdf = scratch_brdf.simulate(params.profile, resolution=params.resolution, fresnel=params.fresnel, cache=True)
    step(0.4)
    lobe_data = _lobe_data(params, brdf) if params.mode == "lobes" else None
    svm_lobes = lobe_data if params.backend == "svm" or params.lobe_shape == "table" else None
    if svm_lobes is None:  # the SVM twin of fitted (per-lobe GGX/Beckmann) or reference shaders: table lobes
        svm_lobes = scratch_lobes.table_lobes(brdf, slices=params.slices)
    step(0.7)
    src = None if params.backend == "svm" else shader_source(params, brdf, lobe_data, **spec_options)
    step(0.8)
    tree = material.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (900, 0)
    base = _base_node(tree, params)
    if base is not None:
        base.location = (-200, -250)
    svm_surface = _build_svm(tree, material, params, svm_lobes, base)
    osl_surface = None
    if src is not None:
        script = osl_compile.script_node_from_source(tree, f"{material.name}.scratch.osl", src)
        script.location = (200, 300)
        uv = tree.nodes.new("ShaderNodeUVMap")
        uv.location = (-200, 400)
        tangent = tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tangent.location = (-200, 250)
        if "UV" in script.inputs:
            tree.links.new(uv.outputs["UV"], script.inputs["UV"])
        tree.links.new(tangent.outputs["Tangent"], script.inputs["Tangent"])
        tint = script.inputs["Tint"]
        tint.default_value = (*params.tint, 1.0) if len(tint.default_value) == 4 else params.tint
        if base is not None and "Base" in script.inputs:
            tree.links.new(base.outputs[0], script.inputs["Base"])
        osl_surface = script.outputs["BSDF"]
    return _finish(material, tree, out, svm_surface, osl_surface, params, lobe_data, step)


def _build_svm(tree, material, params: ScratchParams, lobe_data, base) -> bpy.types.NodeSocket:
    """The node-group (SVM) path, framed: see ``node_groups/scratch_svm.py`` for how it differs from OSL."""
    svm = _deps.sibling("node_groups.scratch_svm")
    layers = params.layers
    theta_k, xi_k = scratch_layers.layer_transforms(layers) if layers is not None else (None, None)
    before = set(tree.nodes)
    surface = svm.build(tree, lobe_data, layers, theta_k, xi_k, tint=params.tint,
                        base_socket=None if base is None else base.outputs[0], name=material.name)
    frame = tree.nodes.new("NodeFrame")
    frame.label = "SVM path (Cycles SVM / GPU, EEVEE)"
    for node in set(tree.nodes) - before - {frame}:
        node.location = (node.location[0] - 1400, node.location[1] - 600)
        node.parent = frame
    return surface


def _finish(material, tree, out, svm_surface, osl_surface, params: ScratchParams, lobe_data, step) -> bpy.types.Material:
    """Diffuse term, output links (render paths), material flags and the stored parameters."""
    if params.diffuse is not None:  # a Lambertian term common to scratches and base (Fig. 12c, d)
        diff = tree.nodes.new("ShaderNodeBsdfDiffuse")
        diff.location = (400, -300)
        if params.diffuse == "wood":
            _wood_texture(tree, diff.inputs["Color"])
        else:
            diff.inputs["Color"].default_value = (*params.diffuse, 1.0)

        def with_diffuse(surface, y):
            add = tree.nodes.new("ShaderNodeAddShader")
            add.location = (600, y)
            tree.links.new(surface, add.inputs[0])
            tree.links.new(diff.outputs["BSDF"], add.inputs[1])
            return add.outputs["Shader"]

        svm_surface = with_diffuse(svm_surface, -150)
        if osl_surface is not None:
            osl_surface = with_diffuse(osl_surface, 150)
    render_paths.link_surface(tree, svm_surface, osl_surface, out)
    material.cycles.use_bump_map_correction = False  # it rotates tilted lobe normals back toward Ng
    material["scratch_addon_kind"] = "scratch_svbrdf"
    if lobe_data is not None:
        material["scratch_addon_fit_error"] = fit_error(lobe_data)
    material["scratch_addon_params"] = json.dumps({
        "profile": params.profile.cache_key(), "fresnel": None if params.fresnel is None else params.fresnel.cache_key(),
        "layers": None if params.layers is None else params.layers.cache_key(), "lobes": params.lobes,
        "base": {k: list(v) if isinstance(v, tuple) else v for k, v in params.base.items()}, "mode": params.mode,
        "resolution": params.resolution, "slices": params.slices, "tint": list(params.tint),
        "diffuse": params.diffuse, "backend": params.backend, "lobe_shape": params.lobe_shape}, default=_jsonable)
    step(1.0)
    return material
