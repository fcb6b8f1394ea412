"""Scripting API: the one way to make materials and demo renders (operators and the CLI call it).

    import scratch_addon.api as sa
    mat = sa.make_material("brushed")           # a material in the current file
    sa.demo_scene("brushed")                    # or: reset and build the demo scene
    sa.render("out.png", samples=32, res=(256, 256))
"""
from __future__ import annotations

import bpy

from . import materials, presets, render as _render


def preset_names() -> list[str]:
    """Names accepted by ``make_material`` and the CLI's ``--preset``."""
    return presets.names()


def make_material(preset: str, **overrides) -> bpy.types.Material:
    """Build the material of a named preset; keyword arguments override its parameters."""
    p = presets.get(preset)
    params = {**p.params, **overrides}
    if p.kind == "brushed":
        return materials.make_brushed_material(name=f"Scratch {p.name}", **params)
    raise ValueError(f"preset {preset!r}: unknown kind {p.kind!r}")  # pragma: no cover - table is internal


def demo_scene(preset: str = "demo", **overrides) -> bpy.types.Scene:
    """Reset the file and build the demo: a curved UV-mapped object with the preset's material
    under a studio environment plus a small area light."""
    presets.get(preset)  # validate before wiping the file
    scene = _render.reset_scene()
    material = make_material(preset, **overrides)
    _render.studio_world(scene, strength=1.0)
    _render.add_torus(scene, material=material)
    _render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
    _render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
    return scene


def render(out: str, samples: int = 32, res=(320, 240), seed: int = 0, osl: bool = False) -> float:
    """Render the current scene on the CPU to ``out`` (.png or .exr); returns wall seconds."""
    samples = int(materials.check_range("samples", samples, 1, 1 << 16))
    w = int(materials.check_range("res width", res[0], 4, 16384))
    h = int(materials.check_range("res height", res[1], 4, 16384))
    scene = bpy.context.scene
    _render.configure_cycles(scene, samples=samples, res=(w, h), seed=seed, osl=osl)
    scene.view_settings.view_transform = "AgX" if out.lower().endswith(".png") else "Standard"
    return _render.render_to_file(scene, out)
