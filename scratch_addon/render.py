"""Scene set-up and rendering helpers shared by the CLI, tests and benchmarks."""
from __future__ import annotations

import math
import os
import time

import bpy
import numpy as np

from ..precompute.tables import exr_io
from . import materials


def reset_scene() -> bpy.types.Scene:
    """Empty the file (keeps add-ons enabled, unlike read_factory_settings)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


def configure_cycles(scene, samples: int = 16, res=(128, 128), seed: int = 0, osl: bool = False,
                     max_bounces: int = 8, threads: int = 0) -> None:
    """Deterministic CPU Cycles: fixed seed, no denoising, no adaptive sampling, Standard view."""
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = int(samples)
    c.preview_samples = int(samples)
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = int(seed)
    c.use_animated_seed = False
    c.shading_system = bool(osl)
    c.max_bounces = max_bounces
    c.glossy_bounces = max_bounces
    c.diffuse_bounces = max_bounces
    c.transparent_max_bounces = max_bounces
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.blur_glossy = 0.0  # Filter Glossy widens lobes after the first bounce
    c.caustics_reflective = True
    scene.render.resolution_x, scene.render.resolution_y = int(res[0]), int(res[1])
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.render.threads_mode = "FIXED" if threads else "AUTO"
    if threads:
        scene.render.threads = threads
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0


def uniform_world(scene, strength: float = 1.0, color=(1.0, 1.0, 1.0)) -> None:
    """A constant environment (furnace tests)."""
    world = bpy.data.worlds.new("Uniform") if scene.world is None else scene.world
    scene.world = world
    tree = materials.ensure_nodes(world)
    tree.nodes.clear()
    bg = tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (*color, 1.0)
    bg.inputs["Strength"].default_value = strength
    out = tree.nodes.new("ShaderNodeOutputWorld")
    tree.links.new(bg.outputs["Background"], out.inputs["Surface"])


def studio_world(scene, strength: float = 1.0) -> None:
    """A procedural studio environment: bright sky gradient, soft-box stripes, dark floor."""
    world = bpy.data.worlds.new("Studio")
    scene.world = world
    tree = materials.ensure_nodes(world)
    tree.nodes.clear()
    n, link = tree.nodes, tree.links.new
    coord = n.new("ShaderNodeTexCoord")
    sep = n.new("ShaderNodeSeparateXYZ")
    link(coord.outputs["Generated"], sep.inputs["Vector"])
    ramp = n.new("ShaderNodeValToRGB")  # elevation (z) -> sky colour
    link(sep.outputs["Z"], ramp.inputs["Fac"])
    els = ramp.color_ramp.elements
    els[0].position, els[0].color = 0.45, (0.02, 0.02, 0.025, 1)
    els[1].position, els[1].color = 1.0, (0.55, 0.65, 0.85, 1)
    mid = els.new(0.52)
    mid.color = (0.9, 0.85, 0.8, 1)
    wave = n.new("ShaderNodeTexWave")  # soft-box stripes around the horizon
    wave.wave_type, wave.bands_direction = "BANDS", "X"
    wave.inputs["Scale"].default_value = 1.5
    wave.inputs["Distortion"].default_value = 0.0
    stripes = n.new("ShaderNodeMath")
    stripes.operation = "POWER"
    link(wave.outputs["Fac"], stripes.inputs[0])
    stripes.inputs[1].default_value = 12.0
    add = n.new("ShaderNodeMixRGB")
    add.blend_type = "ADD"
    add.inputs["Fac"].default_value = 1.0
    link(ramp.outputs["Color"], add.inputs["Color1"])
    above = n.new("ShaderNodeMapRange")  # soft boxes only above the horizon
    above.inputs["From Min"].default_value = 0.15
    above.inputs["From Max"].default_value = 0.5
    link(sep.outputs["Z"], above.inputs["Value"])
    masked = n.new("ShaderNodeMath")
    masked.operation = "MULTIPLY"
    link(stripes.outputs["Value"], masked.inputs[0])
    link(above.outputs["Result"], masked.inputs[1])
    scale = n.new("ShaderNodeMath")
    scale.operation = "MULTIPLY"
    scale.inputs[1].default_value = 4.0
    link(masked.outputs["Value"], scale.inputs[0])
    link(scale.outputs["Value"], add.inputs["Color2"])
    bg = n.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = strength
    link(add.outputs["Color"], bg.inputs["Color"])
    out = n.new("ShaderNodeOutputWorld")
    link(bg.outputs["Background"], out.inputs["Surface"])


def add_camera(scene, location=(0.0, -4.0, 1.6), target=(0.0, 0.0, 0.0), lens: float = 50.0, ortho_scale: float | None = None):
    """Camera looking at ``target``; orthographic when ``ortho_scale`` is given."""
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = lens
    if ortho_scale is not None:
        cam_data.type = "ORTHO"
        cam_data.ortho_scale = ortho_scale
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = location
    d = [t - l for t, l in zip(target, location)]
    cam.rotation_euler = (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0, math.atan2(d[1], d[0]) - math.pi / 2)
    scene.camera = cam
    return cam


def add_light(scene, kind: str = "AREA", location=(2.0, -2.0, 3.0), energy: float = 200.0, size: float = 0.3,
              color=(1.0, 1.0, 1.0), target=(0.0, 0.0, 0.0)):
    """A small light pointing at ``target``."""
    data = bpy.data.lights.new("Light", kind)
    data.energy = energy
    data.color = color
    if kind == "AREA":
        data.size = size
    elif kind in ("POINT", "SPOT"):
        data.shadow_soft_size = size
    obj = bpy.data.objects.new("Light", data)
    scene.collection.objects.link(obj)
    obj.location = location
    d = [t - l for t, l in zip(target, location)]
    obj.rotation_euler = (math.atan2(math.hypot(d[0], d[1]), -d[2]), 0.0, math.atan2(d[1], d[0]) - math.pi / 2)
    return obj


def flat_triangle_mesh(name: str, V, F, material_index=None) -> bpy.types.Mesh:
    """A flat-shaded mesh of triangles ``F`` [n, 3] (indices into ``V`` [m, 3], metres), facet normals (the
    explicit microgeometry of the ground-truth scenes), optional per-face ``material_index`` [n]."""
    V, F = np.asarray(V, np.float64), np.asarray(F, np.int64)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(V))
    mesh.vertices.foreach_set("co", V.astype(np.float32).ravel())
    mesh.loops.add(F.size)
    mesh.loops.foreach_set("vertex_index", F.astype(np.int32).ravel())
    mesh.polygons.add(len(F))
    mesh.polygons.foreach_set("loop_start", (np.arange(len(F)) * 3).astype(np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(F), 3, np.int32))
    if material_index is not None:
        mesh.polygons.foreach_set("material_index", np.asarray(material_index).astype(np.int32))
    mesh.polygons.foreach_set("use_smooth", np.zeros(len(F), bool))
    mesh.update()
    return mesh


def add_plane(scene, size: float = 2.0, material=None, name: str = "Plane", uv_size: float | None = None,
              location=(0.0, 0.0, 0.0)):
    """A UV-mapped plane in z = 0 (U along +x): UVs span [0, 1] over the plane, or with ``uv_size`` one UV
    unit is ``uv_size`` metres (scratch layers live in UV space: this sets their size in the world)."""
    import bmesh

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    uv_layer = bm.loops.layers.uv.new("UVMap")  # create_grid fills UVs only into an existing layer
    bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=size / 2, calc_uvs=True)
    if uv_size is not None:
        for face in bm.faces:
            for loop in face.loops:
                loop[uv_layer].uv = (loop.vert.co.x / uv_size, loop.vert.co.y / uv_size)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    obj.location = location
    if material is not None:
        mesh.materials.append(material)
    return obj


def add_sphere(scene, material=None, radius: float = 1.0, name: str = "Sphere", segments: int = 64, rings: int = 32):
    """A UV-mapped smooth UV sphere centred at the origin (U around z, V from pole to pole)."""
    import bmesh

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bm.loops.layers.uv.new("UVMap")  # create_uvsphere fills UVs only into an existing layer
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius, calc_uvs=True)
    for f in bm.faces:
        f.smooth = True
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    if material is not None:
        mesh.materials.append(material)
    return obj


def add_torus(scene, material=None, major: float = 1.0, minor: float = 0.4, name: str = "Torus"):
    """A UV-mapped smooth torus (U runs around the ring), a curved test object."""
    import bmesh

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    nu, nv = 96, 48
    uv_layer = bm.loops.layers.uv.new("UVMap")
    verts = []
    for i in range(nu):
        a = 2 * math.pi * i / nu
        row = []
        for j in range(nv):
            b = 2 * math.pi * j / nv
            r = major + minor * math.cos(b)
            row.append(bm.verts.new((r * math.cos(a), r * math.sin(a), minor * math.sin(b))))
        verts.append(row)
    for i in range(nu):
        for j in range(nv):
            i1, j1 = (i + 1) % nu, (j + 1) % nv
            f = bm.faces.new((verts[i][j], verts[i1][j], verts[i1][j1], verts[i][j1]))
            f.smooth = True
            for loop, (ii, jj) in zip(f.loops, ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1))):
                loop[uv_layer].uv = (ii / nu, jj / nv)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    if material is not None:
        mesh.materials.append(material)
    return obj


def highlights_scene(scene, material, camera_height: float = 1.2, highlights=((0.0, 1.5),),
                     light_height: float = 2.0, energy=(6000.0,), uv_size: float = 100.0,
                     light_size: float = 0.15, world: float = 0.02) -> None:
    """The README demo's stage: ``material`` on a large floor plane receding from a low camera, one small
    point light per highlight (on the floor, as (x, y) points), each placed on the mirror direction of its
    point so the base reflects it there and the scratches streak radially around it; a dim world.
    ``energy`` per light (W), ``uv_size`` metres per UV unit, ``light_size`` the lights' radius (m), ``world``
    the environment's strength.

    Defaults (issue 15 item 7, measured at 640x480 / 32 spp with the 'demo' preset = Fig. 1d's layers): one
    light whose highlight sits 2.5 m in front of the camera, so its streak fans run from the bottom of the
    frame (near) to the horizon (far).  uv_size 100 makes Fig. 1d's scratches (l = 0.3, w = 3e-4, d = 0.05 in
    UV units) 3 m long, 3 mm wide and 3 cm apart across: wider than a pixel's footprint near the camera, so
    they show one by one there, while far away a pixel covers many (the OSL far field: a sheen).  At
    uv_size 1 every pixel of the floor is in the far field and the image is a uniform speckled sheen."""
    uniform_world(scene, strength=world)
    add_plane(scene, size=60.0, material=material, uv_size=uv_size, location=(0.0, 28.0, 0.0))
    cam = (0.0, -1.0, camera_height)
    add_camera(scene, location=cam, target=(0.0, 3.0, 0.0), lens=30.0)
    for (x, y), e in zip(highlights, energy):
        d = (x - cam[0], y - cam[1], -cam[2])      # camera -> floor point; its mirror image goes up
        t = light_height / cam[2]
        light = add_light(scene, "POINT", location=(x + t * d[0], y + t * d[1], light_height), energy=e, size=light_size)
        light.data.use_soft_falloff = False


def render_to_file(scene, path: str) -> float:
    """Render the scene and write ``path`` (format from the extension: .png or .exr); returns seconds."""
    ext = os.path.splitext(path)[1].lower()
    settings = scene.render.image_settings
    if ext == ".exr":
        settings.file_format = "OPEN_EXR"
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"
    elif ext == ".png":
        settings.file_format = "PNG"
        settings.color_mode = "RGBA" if scene.render.film_transparent else "RGB"
        settings.color_depth = "8"
    else:
        raise ValueError(f"out: unsupported image extension {ext!r} (use .png or .exr)")
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    scene.render.filepath = path
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - t0


def render_array(scene, tmpdir: str, name: str = "render"):
    """Render to a float EXR in ``tmpdir`` and return (RGB float32 array [H, W, 3] top-down, seconds)."""
    import numpy as np

    path = os.path.join(tmpdir, f"{name}.exr")
    seconds = render_to_file(scene, path)
    channels, _ = exr_io.read_exr(path)
    keys = {k.split(".")[-1]: k for k in channels}
    rgb = np.stack([channels[keys[c]] for c in "RGB"], axis=-1)
    return rgb, seconds
