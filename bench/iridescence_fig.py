"""README figure: iridescent scratch glints on a metal plate under a small sphere light (cf. Velinov
et al. 2018, Fig. 1 right / Fig. 10), rendered in Cycles with the layer's default route (A, lobes).

Writes docs/img/iridescence_render.png (and bench/out/iridescence_render.png) and prints the
render time.  Run: ``.venv/bin/python -m bench iridescence_fig [--quick]``.
``plate_scene`` is also the representative scene of ``bench/iridescence_cycles.py``; ``setup`` (bpy and the
registered extension) is shared by the iridescence benches (this module imports no other bench module, so
``iridescence_cycles`` -> ``iridescence_fig`` is the only direction).
"""
from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent / "docs" / "img"


def setup():
    """(render, iridescence_material) of the registered extension (hermetic bpy, see ``bench._util.blender``)."""
    from bench._util import blender

    blender(register=True)
    from scratch_materials.scratch_addon import iridescence_material as im, render

    return render, im


def plate_scratches(im, count=6000):
    """6000 isotropic segments over a 2 m plate = 2 cm of steel (uv_scale 2e4 µm per UV)."""
    return im.generate_scratch_set(count, length_range=(0.05, 0.3), width_range_um=(0.8, 6.0),
                                   depth_range_um=(0.8, 6.0), spread_deg=180.0, seed=7, uv_scale_um=2e4)


def plate_scene(render, im, S, *, res=(128, 96), spp=64, layer=True, route="lobes", samples=1, candidates=4,
                seed=0, world_strength=0.05, **layer_kw):
    """Steel plate (metallic Principled, roughness 0.03), dim studio world, small sphere light,
    perspective camera; with ``layer`` the iridescent layer sits on the steel (``layer_kw``: more
    ``insert_layer`` keywords, e.g. base_weight).  Returns the scene."""
    import bpy

    scene = render.reset_scene()
    mat = bpy.data.materials.new("Scratched steel")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    base = tree.nodes.new("ShaderNodeBsdfPrincipled")
    base.inputs["Base Color"].default_value = (0.8, 0.8, 0.82, 1.0)
    base.inputs["Metallic"].default_value = 1.0
    base.inputs["Roughness"].default_value = 0.03
    tree.links.new(base.outputs[0], out.inputs["Surface"])
    render.studio_world(scene, strength=world_strength)
    light = bpy.data.lights.new("Sphere", "POINT")
    light.energy = 300.0
    light.shadow_soft_size = 0.05
    light.use_soft_falloff = False
    lo = bpy.data.objects.new("Sphere", light)
    scene.collection.objects.link(lo)
    lo.location = (0.3, 1.6, 1.2)
    bpy.context.view_layer.update()
    if layer:
        im.insert_layer(mat, S, route=route, scene=scene, samples=samples, candidates=candidates, **layer_kw)
    render.add_plane(scene, size=2.0, material=mat)
    render.add_camera(scene, location=(0.0, -2.2, 1.6), target=(0.0, 0.1, 0.0), lens=40.0)
    render.configure_cycles(scene, samples=spp, res=res, seed=seed, osl=True, max_bounces=4)
    return scene


def main(argv) -> int:
    from bench._util import out_path

    quick = "--quick" in argv
    render, im = setup()
    S = plate_scratches(im)
    res = (160, 120) if quick else (480, 360)
    spp = 32 if quick else 128
    scene = plate_scene(render, im, S, res=res, spp=spp)
    scene.view_settings.view_transform = "AgX"
    tmp = Path(tempfile.mkdtemp()) / "iridescence_render.png"
    seconds = render.render_to_file(scene, str(tmp))
    dst = out_path("iridescence_render.png")
    shutil.copy(tmp, dst)
    if not quick:
        DOCS.mkdir(parents=True, exist_ok=True)
        shutil.copy(tmp, DOCS / "iridescence_render.png")
    print(f"iridescence_render.png: {res[0]}x{res[1]}, {spp} spp, {len(S)} segments, render {seconds:.1f} s "
          f"({'bench/out only' if quick else 'docs/img'})")
    return 0
