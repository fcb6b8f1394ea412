"""Iridescent scratch layer in Cycles: route A (lobes) vs route B (closed-form lights) vs base alone.

Flat UV-mapped plane, oblique orthographic camera, one small sphere light (Cycles point light
with radius, soft falloff off), box pixel filter.  Reference: ``precompute.iridescence.evaluate``
(point evaluation, exact Si) at 4x4 sub-pixel positions per pixel, times the light's radiance.
Per route: render time at equal spp (median of 3, all in one run, so the ratios share the machine
state), ratio to the base material alone (a metallic GGX, roughness 0.2), relative error of the
image mean per channel and the relative L1 error of 8x8-pixel block means.

Run: ``.venv/bin/python -m bench iridescence_cycles [--quick]``.
The scene helpers (``flat_scene``, ``numpy_reference``) are shared with tests/test_iridescence_blender.py.
"""
from __future__ import annotations

import math
import os
import statistics
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PLANE_SIZE = 2.0          # m; UV 0..1 across it, so one UV unit = 2 m in the scene
ORTHO = 0.3               # m seen by the camera
CAM_THETA = math.radians(30.0)


def light_center(offset=(0.25, 0.0, 0.0), dist=2.0, theta=CAM_THETA):
    """World centre of the test light: near the mirror direction of the camera, plus ``offset``."""
    return np.array([0.0, dist * math.sin(theta), dist * math.cos(theta)]) + np.asarray(offset, float)


def test_scratches(scratch_set_mod, count=300, seed=1, uv_scale_um=2e4, domain=(0.4, 0.4, 0.6, 0.6)):
    """Dense random scratches over the camera's view (several segments within 3σ of every point)."""
    return scratch_set_mod.random_scratches(count, length_range=(0.05, 0.15), domain=domain, uv_scale_um=uv_scale_um,
                                            seed=seed)


def flat_scene(render, im, scratches, *, route="lobes", base=None, res=32, spp=16, seed=1,
               light=None, radius=0.1, energy=1000.0, samples=4, layer=True):
    """Reset the file and build the flat validation scene; returns (scene, material, camera matrix 4x4).

    ``base``: None (no base closure), "metal" (metallic Principled, roughness 0.2).
    ``light``: world centre of the sphere light (default ``light_center()``)."""
    import bpy

    scene = render.reset_scene()
    mat = bpy.data.materials.new("Irid Test")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    if base == "metal":
        b = tree.nodes.new("ShaderNodeBsdfPrincipled")
        b.inputs["Base Color"].default_value = (0.9, 0.9, 0.9, 1.0)
        b.inputs["Metallic"].default_value = 1.0
        b.inputs["Roughness"].default_value = 0.2
        tree.links.new(b.outputs[0], out.inputs["Surface"])
    if layer:
        c = light_center() if light is None else np.asarray(light, float)
        _add_point_light(scene, c, radius, energy)
        im.insert_layer(mat, scratches, route=route, samples=samples, scene=scene)
    render.add_plane(scene, size=PLANE_SIZE, material=mat)
    cam_dir = np.array([0.0, -math.sin(CAM_THETA), math.cos(CAM_THETA)])
    cam = render.add_camera(scene, location=tuple(5 * cam_dir), target=(0, 0, 0), ortho_scale=ORTHO)
    if not layer:
        c = light_center() if light is None else np.asarray(light, float)
        _add_point_light(scene, c, radius, energy)
    render.configure_cycles(scene, samples=spp, res=(res, res), seed=seed, osl=True)
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 1.0
    bpy.context.view_layer.update()
    return scene, mat, np.array(cam.matrix_world)


def _add_point_light(scene, center, radius, energy):
    import bpy

    data = bpy.data.lights.new("Sphere", "POINT")
    data.energy = energy
    data.shadow_soft_size = radius
    data.use_soft_falloff = False
    obj = bpy.data.objects.new("Sphere", data)
    scene.collection.objects.link(obj)
    obj.location = tuple(float(x) for x in center)
    return obj


def numpy_reference(ir, scratches, cam_matrix, res, light=None, radius=0.1, energy=1000.0, ss=4):
    """``ir.evaluate`` (point evaluation) averaged over ss x ss sub-pixel positions, × light radiance.

    ``ir`` is the repository's ``precompute.iridescence``; ``scratches`` any ScratchSet-like object."""
    S = ir.ScratchSet(scratches.p0, scratches.p1, scratches.width_um, scratches.depth_um, scratches.uv_scale_um)
    Mw = np.asarray(cam_matrix, float)
    right, up, fwd, org = Mw[:3, 0], Mw[:3, 1], -Mw[:3, 2], Mw[:3, 3]
    g = (np.arange(res * ss) + 0.5) / (res * ss) - 0.5
    X, Y = np.meshgrid(g * ORTHO, -g * ORTHO)                # rows top-down, like render_array
    o = org + X[..., None] * right + Y[..., None] * up
    pw = o + (-o[..., 2] / fwd[2])[..., None] * fwd
    uv = pw[..., :2] / PLANE_SIZE + 0.5
    wo = np.broadcast_to(-fwd, pw.shape)
    c = light_center() if light is None else np.asarray(light, float)
    c_uv = c / PLANE_SIZE + np.array([0.5, 0.5, 0.0])
    L = energy / (4 * math.pi ** 2 * radius ** 2)            # Cycles sphere light radiance (W/m²/sr)
    r = ir.evaluate(S, uv.reshape(-1, 2), wo.reshape(-1, 3), ir.SphereLight(c_uv, radius / PLANE_SIZE))
    return (r.scratch * L).reshape(res, ss, res, ss, 3).mean((1, 3))


def errors(img, ref, block=8):
    """(relative error of the image mean per channel (3,), relative L1 of block means)."""
    h = img.shape[0] // block
    bm = lambda a: a[:h * block, :h * block].reshape(h, block, h, block, 3).mean((1, 3))  # noqa: E731
    mean_err = img.mean((0, 1)) / ref.mean((0, 1)) - 1.0
    return mean_err, float(np.abs(bm(img) - bm(ref)).sum() / np.abs(bm(ref)).sum())


def _setup():
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp())
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    import scratch_addon

    try:
        scratch_addon.register()
    except ValueError:
        pass   # already registered
    from scratch_addon import iridescence_material as im, render

    return render, im


def main(argv) -> int:
    from bench._util import out_path, pyplot, report
    from precompute import iridescence as ir

    quick = "--quick" in argv
    render, im = _setup()
    res = 32 if quick else 64
    spp = 64 if quick else 256
    S = test_scratches(im.scratch_set, count=300 if quick else 1200,
                       domain=(0.4, 0.4, 0.6, 0.6))
    tmp = tempfile.mkdtemp()
    rows, imgs = [], {}
    times = {}
    configs = [("base alone", dict(layer=False, base="metal")),
               ("A lobes + base", dict(route="lobes", base="metal")),
               ("B lights + base", dict(route="lights", base="metal")),
               ("A lobes only", dict(route="lobes")),
               ("B lights only", dict(route="lights"))]
    for name, kw in configs:
        scene, mat, cam = flat_scene(render, im, S, res=res, spp=spp, **kw)
        ts = []
        for rep in range(3):
            img, sec = render.render_array(scene, tmp, f"r{rep}")
            ts.append(sec)
        times[name] = statistics.median(ts)
        imgs[name] = img
        if name == "base alone":
            cam_ref = cam
    ref = numpy_reference(ir, S, cam_ref, res)
    for name, _kw in configs:
        img = imgs[name]
        row = [name, times[name], times[name] / times["base alone"]]
        if name.endswith("only"):
            me, be = errors(img, ref)
            row += [f"{np.abs(me).max() * 100:.2f}", f"{be * 100:.2f}", bool(np.isfinite(img).all())]
        else:
            row += ["", "", bool(np.isfinite(img).all())]
        rows.append(row)
    notes = (f"{res}x{res} px, {spp} spp, {len(S)} segments, sphere light r = 0.1 m at 2 m, box filter; "
             "error = image mean per channel (max over RGB) and relative L1 of 8x8 block means, vs numpy "
             "`evaluate` (4x4 sub-pixel point evaluations, exact Si). Route B is deterministic (no light "
             "sampling), route A's error is Monte Carlo noise + bias.")
    report("iridescence_cycles", ["setup", "render s (median of 3)", "× base", "mean err %", "block L1 %", "finite"],
           rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(10, 3.6))
    vmax = float(np.percentile(ref, 99.5))
    for a, (title, im_) in zip(ax, [("numpy reference", ref), ("A: lobes", imgs["A lobes only"]),
                                    ("B: closed-form lights", imgs["B lights only"])]):
        a.imshow(np.clip(im_ / vmax, 0, 1) ** (1 / 2.2))
        a.set_title(title)
        a.axis("off")
    fig.tight_layout()
    fig.savefig(out_path("iridescence_cycles.png"), dpi=90)
    return 0
