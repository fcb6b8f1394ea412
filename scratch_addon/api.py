"""Scripting API: the one way to make materials and demo renders (operators and the CLI call it).

    import scratch_addon.api as sa
    mat = sa.make_material("brushed")           # a material in the current file
    sa.demo_scene("brushed")                    # or: reset and build the demo scene
    sa.render("out.png", samples=32, res=(256, 256))

Bad values, unknown keywords included, raise ``ValueError`` naming the parameter and what is accepted;
a failed rebuild of an existing material leaves it as it was (``transaction.rebuild``).
"""
from __future__ import annotations

import inspect
import os

import bpy

from . import materials, presets, render as _render, scratch_material, transaction
from ..precompute.tables import files
from .keywords import checked, reject_unknown
from .merl_ops import material_from_merl  # noqa: F401 - public: measured BRDFs (MERL .binary)
from .tabulated_material import make_tabulated_material  # noqa: F401 - public: any TabulatedBRDF

#: keywords of ``make_scratched_material`` besides the scratch parameters (``scratch_material.validate``)
_BUILD_KEYWORDS = ("name", "material", "progress")


def scratch_parameters() -> list[str]:
    """Names of the scratch-material parameters (``make_scratched_material``'s ``**params``)."""
    return list(inspect.signature(scratch_material.validate).parameters)


@checked
def preset_names() -> list[str]:
    """Names accepted by ``make_material`` and the CLI's ``--preset``."""
    return presets.names()


@checked
def make_material(preset: str, **overrides) -> bpy.types.Material:
    """Build the material of a named preset; keyword arguments override its parameters."""
    p = presets.get(preset)
    if p.kind == "brushed":
        accepted = list(inspect.signature(materials.make_brushed_material).parameters)
        reject_unknown("make_material", overrides, accepted)
        return materials.make_brushed_material(**{"name": f"Scratch {p.name}", **p.params, **overrides})
    return make_scratched_material(preset, **overrides)


@checked
def make_scratched_material(preset: str | None = None, *, name: str | None = None, material=None,
                            progress=None, **params) -> bpy.types.Material:
    """The scratch SV-BRDF material of Raymond et al. 2016; it renders in any scene as it is.

    ``preset``: a scratch preset name (``preset_names()``) whose parameters ``params`` override.
    ``params``:
      profile     a ``precompute.profiles`` profile or ``(family, value)``, e.g. ``("quartic", 0.3)``
      fresnel     None (lossless mirror), a metal name ("iron", "gold", "copper", "aluminium",
                  "silver"), ``("schlick", ior)``, ``("conductor", n, k)`` or a ``precompute.fresnel`` model
      base        "mirror" (perfect mirror of the same Fresnel), "none", "diffuse", "glossy",
                  "principled", or a dict ``{"type": ..., "color": ..., "roughness": ...}``
      layers      None (dense scratches everywhere), a layer count, a dict of
                  ``precompute.scratch.layers.LayerParams`` fields (n_layers, theta_deg, length,
                  width, density, seed; length and width in UV units, in [1e-9, 1e9]) or a LayerParams
      lobes       K, at most this many fitted tilted GGX lobes per φo slice (1..16, default 8;
                  lobe_shape "fit"/"box" and the SVM backend)
      lobe_shape  "table" (default: tabulated-tilt lobes, ``precompute.scratch.lobe_table``: the slice sampled
                  bin by bin by one narrow lobe, < 0.1 % rel. L1 on quartics, no fit; OSL and SVM),
                  "fit" (<= K fitted tilted lobes, smooth, 5-11 % on quartics, a little less noise
                  under small lights) or "box" (fitted lobes with a tilt jitter each: the shader draws
                  the tilt in [t - j, t + j] per sample; closer fits of round profiles, slower fit)
      box_lobes   True = lobe_shape "box" (kept for scripts written before lobe_shape)
      mode        "lobes" (the product path, light sampling kept) or "reference" (validation: the
                  exact table through ray_portal_bsdf; no NEE and lamps are not seen, use world light)
      resolution  scratch-BRDF table size M (64/128/256/512), slices φo slices in the shader
      tint        RGB multiplier of the scratch reflectance; diffuse: None, RGB or "wood"
      backend     "osl" (default): the OSL shader where Cycles runs OSL on the CPU (scratch coverage
                  filtered over the pixel footprint) and its node-group twin everywhere else (Cycles
                  SVM, the default and the GPU path, and EEVEE), picked per scene by a switch that
                  needs no add-on at render time; "svm": the node groups only
    ``material``: rebuild this material in place instead of creating one; every parameter is checked
    first and the new node tree replaces the old one only once it is complete, so a failure (bad value,
    OSL compile error, OSError, KeyboardInterrupt) leaves the material exactly as it was.  Bad values
    raise ``ValueError`` naming the parameter and its allowed range.
    """
    reject_unknown("make_scratched_material", params, scratch_parameters() + list(_BUILD_KEYWORDS))
    merged = {}
    if preset is not None:
        p = presets.get(preset)
        if p.kind != "scratch":
            raise ValueError(f"preset {preset!r} is a {p.kind} preset, not a scratch preset")
        merged.update(p.params)
    merged.update(params)
    spec = scratch_material.validate(**merged)
    if material is not None and not isinstance(material, bpy.types.Material):
        raise ValueError(f"material must be a bpy.types.Material to rebuild, got {type(material).__name__}")
    if material is not None:
        scratch_material.build(material, spec, progress=progress)
    else:
        with transaction.new_datablocks():  # a failed build leaves no half material behind
            material = materials.new_material(name or f"Scratched {preset or 'material'}")
            scratch_material.build(material, spec, progress=progress)
    if hasattr(material, "scratch"):  # add-on registered: the panel shows what was built (every parameter,
        from . import live          # defaults included), so a later panel edit changes only what it edits

        material.scratch.from_spec(spec)
        live.mark_synced(material)
    return material


#: Scene layouts of ``demo_scene``.
LAYOUTS = ("torus", "highlights")


@checked
def demo_scene(preset: str = "demo", layout: str = "torus", **overrides) -> bpy.types.Scene:
    """Reset the file and build a demo scene with the preset's material.

    ``layout`` "torus": a curved UV-mapped object under a studio environment plus a small area light;
    "highlights" (the README image, ``render.highlights_scene``): a floor plane receding from a low camera
    under one small point light whose highlight sits in front of the camera, so one image shows lit
    scratches streaking around it, one by one near and merging into a sheen far away."""
    p = presets.get(preset)  # validate before wiping the file
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}; got {layout!r}")
    accepted = (inspect.signature(materials.make_brushed_material).parameters if p.kind == "brushed"
                else scratch_parameters())
    reject_unknown("demo_scene", overrides, accepted)
    scene = _render.reset_scene()
    material = make_material(preset, **overrides)
    if presets.get(preset).kind == "scratch":
        scene.cycles.shading_system = True
    if layout == "highlights":
        _render.highlights_scene(scene, material)
        return scene
    _render.studio_world(scene, strength=1.0)
    _render.add_torus(scene, material=material)
    _render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
    _render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
    return scene


def check_output_path(out) -> str:
    """``out`` as an absolute path Blender can write (.png or .exr, folder writable, not a folder itself),
    checked before a render rather than after it; ValueError naming ``out`` otherwise."""
    if not isinstance(out, (str, os.PathLike)) or not os.fspath(out):
        raise ValueError(f"out: expected an image path ending in .png or .exr, got {out!r}")
    path = os.path.abspath(os.fspath(out))
    if os.path.splitext(path)[1].lower() not in (".png", ".exr"):
        raise ValueError(f"out: the image must end in .png or .exr, got {os.fspath(out)!r}")
    if os.path.isdir(path):
        raise ValueError(f"out: {os.fspath(out)!r} is a folder, not an image file")
    try:
        files.check_writable(os.path.dirname(path))
        if os.path.exists(path) and not os.access(path, os.W_OK):
            raise PermissionError(13, "Permission denied", path)
    except OSError as exc:
        raise ValueError(f"out: cannot write {os.fspath(out)!r} ({files.one_line(exc)})") from None
    return path


@checked
def render(out: str, samples: int = 32, res=(320, 240), seed: int = 0, osl: bool = False) -> float:
    """Render the current scene on the CPU to ``out`` (.png or .exr; its folder is checked first);
    returns wall seconds."""
    samples = int(materials.check_range("samples", samples, 1, 1 << 16))
    if not isinstance(res, (tuple, list)) or len(res) != 2:
        raise ValueError(f"res must be (width, height) in pixels, got {res!r}")
    w = int(materials.check_range("res width", res[0], 4, 16384))
    h = int(materials.check_range("res height", res[1], 4, 16384))
    scene = bpy.context.scene
    for mat in bpy.data.materials:  # scratches follow UVs: a mesh without them cannot render them
        if mat.get("scratch_addon_kind") == "scratch_svbrdf":
            scratch_material.check_uvs(mat)
    out = check_output_path(out)  # before the render, not after it
    osl = bool(osl or scene.cycles.shading_system or _uses_osl(scene))
    _render.configure_cycles(scene, samples=samples, res=(w, h), seed=seed, osl=osl)
    scene.view_settings.view_transform = "AgX" if out.lower().endswith(".png") else "Standard"
    return _render.render_to_file(scene, out)


def _uses_osl(scene) -> bool:
    """True if a material in the scene has an OSL script node (the scratch materials do)."""
    from . import render_paths

    return any(render_paths.has_osl(m) for m in bpy.data.materials if m.node_tree)
