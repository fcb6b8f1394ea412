"""Iridescent scratch layer in Cycles: route A (lobes) vs route B (closed-form lights) vs base alone.

Two scenes, each with all its renders interleaved in one run (median of 3), so the ratios share
the machine state:

* dense: flat UV-mapped plane, oblique orthographic camera, one small sphere light (Cycles point
  light with radius, soft falloff off), box pixel filter, 1200 segments (~50 within 3σ of every
  pixel).  Reference: ``precompute.iridescence.evaluate`` (point evaluation, exact Si) at 4x4
  sub-pixel positions per pixel, times the light's radiance.  Errors of the scratch part alone:
  image mean per channel, relative L1 of 8x8-pixel block means, per-pixel RMSE at equal spp and
  at equal time.
* plate (representative): the README figure's scene (``bench.iridescence_fig.plate_scene``).

Per setup: render time at equal spp and its ratio to the base material alone (metallic GGX).

Run: ``.venv/bin/python -m bench iridescence_cycles [--quick]``.
The scene helpers (``flat_scene``, ``numpy_reference``) are shared with tests/test_iridescence_blender.py.
"""
from __future__ import annotations

import math
import os
import statistics
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
               light=None, radius=0.1, energy=1000.0, samples=1, candidates=4, layer=True, shadows=True,
               base_weight="energy"):
    """Reset the file and build the flat validation scene; returns (scene, material, camera matrix 4x4).

    ``base``: None (no base closure), "metal" (metallic Principled, roughness 0.2), "emission" (unit white
    emission: the base weight is rendered directly).
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
    elif base == "emission":         # unit white emission: the render shows the base's weight itself
        b = tree.nodes.new("ShaderNodeEmission")
        b.inputs["Strength"].default_value = 1.0
        tree.links.new(b.outputs[0], out.inputs["Surface"])
    if layer:
        c = light_center() if light is None else np.asarray(light, float)
        _add_point_light(scene, c, radius, energy)
        im.insert_layer(mat, scratches, route=route, samples=samples, candidates=candidates, scene=scene,
                        shadows=shadows, base_weight=base_weight)
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


def numpy_reference(ir, scratches, cam_matrix, res, light=None, radius=0.1, energy=1000.0, ss=4, weight=False,
                    **eval_kw):
    """``ir.evaluate`` (point evaluation) averaged over ss x ss sub-pixel positions, × light radiance.

    ``ir`` is the repository's ``precompute.iridescence``; ``scratches`` any ScratchSet-like object.
    ``weight``: add the base's weight (the render of a unit-emission base, ``flat_scene(base="emission")``);
    ``eval_kw``: more ``evaluate`` keywords (blend=...)."""
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
    r = ir.evaluate(S, uv.reshape(-1, 2), wo.reshape(-1, 3), ir.SphereLight(c_uv, radius / PLANE_SIZE), **eval_kw)
    out = r.scratch * L + (r.weight if weight else 0.0)
    return out.reshape(res, ss, res, ss, 3).mean((1, 3))


def errors(img, ref, block=8):
    """(relative error of the image mean per channel (3,), relative L1 of block means)."""
    h = img.shape[0] // block
    bm = lambda a: a[:h * block, :h * block].reshape(h, block, h, block, 3).mean((1, 3))  # noqa: E731
    mean_err = img.mean((0, 1)) / ref.mean((0, 1)) - 1.0
    return mean_err, float(np.abs(bm(img) - bm(ref)).sum() / np.abs(bm(ref)).sum())


def _setup():
    """(render, iridescence_material): ``bench.iridescence_fig.setup`` (kept here for the other benches)."""
    from bench.iridescence_fig import setup

    return setup()


def _timed_runs(configs, build, reps, tmp):
    """Interleaved renders: for each of ``reps`` rounds, every config in turn (build, then render).
    Returns {name: (median seconds, last image)}."""

    times, imgs = {n: [] for n, _ in configs}, {}
    for rep in range(reps):
        for name, kw in configs:
            scene = build(**kw)
            img, sec = _render_array(scene, tmp, name)
            times[name].append(sec)
            imgs[name] = img
    return {n: (statistics.median(times[n]), imgs[n]) for n, _ in configs}


def _render_array(scene, tmp, name):
    from scratch_materials.scratch_addon import render

    return render.render_array(scene, tmp, name.replace(" ", "_").replace("+", "p"))


def main(argv) -> int:
    from bench._util import out_path, pyplot, report
    from bench.iridescence_fig import plate_scene, plate_scratches
    from scratch_materials.precompute.iridescence import model as ir

    quick = "--quick" in argv
    render, im = _setup()
    reps = 1 if quick else 3
    res = 32 if quick else 64
    spp = 64 if quick else 256
    S = test_scratches(im.scratch_set, count=300 if quick else 1200, domain=(0.4, 0.4, 0.6, 0.6))
    tmp = tempfile.mkdtemp()
    # (name, flat_scene kwargs); "old" = the previous defaults: every segment in reach, 4 lobes per sample
    A, A_old = dict(route="lobes"), dict(route="lobes", candidates=0, samples=4)
    B, B_old = dict(route="lights"), dict(route="lights", candidates=0)
    dense = [("base alone", dict(layer=False, base="metal")),
             ("A + base", dict(A, base="metal")), ("A old + base", dict(A_old, base="metal")),
             ("B + base", dict(B, base="metal")), ("B old + base", dict(B_old, base="metal")),
             ("A only", A), ("A old only", A_old), ("B only", B), ("B old only", B_old)]
    cam = {}

    def build_dense(**kw):
        scene, _mat, cam["m"] = flat_scene(render, im, S, res=res, spp=spp, **kw)
        return scene

    rd = _timed_runs(dense, build_dense, reps, tmp)
    ref = numpy_reference(ir, S, cam["m"], res)
    t_base, t_a_old = rd["base alone"][0], rd["A old only"][0]
    rows = []
    for name, _kw in dense:
        t, img = rd[name]
        row = ["dense", name, t, t / t_base]
        if name.endswith("only"):
            me, be = errors(img, ref)
            rmse = float(np.sqrt(np.mean((img - ref) ** 2)) / ref.mean())
            row += [f"{np.abs(me).max() * 100:.2f}", f"{be * 100:.2f}", f"{rmse:.3f}",
                    f"{rmse * math.sqrt(t / t_a_old):.3f}"]
        else:
            row += ["", "", "", ""]
        rows.append(row + [bool(np.isfinite(img).all())])
    # representative scene: the README figure's plate (6000 segments, dim world + small sphere light)
    Sp = plate_scratches(im)
    fres, fspp = ((64, 48), 16) if quick else ((128, 96), 64)
    plate = [("base alone", dict(layer=False)), ("A + base", dict(route="lobes")),
             ("A old + base", dict(route="lobes", candidates=0, samples=4)),
             ("B + base", dict(route="lights")), ("B old + base", dict(route="lights", candidates=0))]
    rp = _timed_runs(plate, lambda **kw: plate_scene(render, im, Sp, res=fres, spp=fspp, **kw), reps, tmp)
    for name, _kw in plate:
        t, img = rp[name]
        rows.append(["plate", name, t, t / rp["base alone"][0], "", "", "", "", bool(np.isfinite(img).all())])
    notes = (f"dense: flat plane, orthographic, {res}x{res} px, {spp} spp, {len(S)} segments (~50 within 3σ of "
             f"every pixel), sphere light r = 0.1 m at 2 m, box filter.  plate (representative, the README "
             f"figure's scene): {fres[0]}x{fres[1]} px, {fspp} spp, {len(Sp)} segments over a 2 m plate, dim "
             "studio world + sphere light r = 0.05 m, perspective.  All renders of a table interleaved in one run "
             f"(median of {reps}); × base = render time / base material alone in the same scene.  A/B = "
             "defaults (4 RIS candidates per sample, route A 1 lobe); 'old' = every segment in reach "
             "(route A 4 lobes, the previous defaults).  Errors ('only' rows, scratch part without base) vs "
             "numpy `evaluate` (4x4 sub-pixel point evaluations, exact Si): image mean (max over RGB), relative "
             "L1 of 8x8 block means, per-pixel RMSE / mean at equal spp, and the same scaled to the render time "
             "of 'A old only' (RMSE·√(t/t_A_old): equal-time error, lower is better; it includes the "
             "reference's own 16-point pixel integration, which is about what 'B old' shows).")
    report("iridescence_cycles", ["scene", "setup", "render s", "× base", "mean err %", "block L1 %",
                                  "pixel RMSE", "equal-time RMSE", "finite"], rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(1, 5, figsize=(16, 3.6))
    vmax = float(np.percentile(ref, 99.5))
    for a, (title, im_) in zip(ax[:3], [("numpy reference", ref), ("A (RIS, 1 lobe)", rd["A only"][1]),
                                        ("B (RIS, closed forms)", rd["B only"][1])]):
        a.imshow(np.clip(im_ / vmax, 0, 1) ** (1 / 2.2))
        a.set_title(title)
        a.axis("off")
    pv = float(np.percentile(rp["A + base"][1], 99.5))
    for a, (title, im_) in zip(ax[3:], [("plate: base alone", rp["base alone"][1]), ("plate: A + base", rp["A + base"][1])]):
        a.imshow(np.clip(im_ / pv, 0, 1) ** (1 / 2.2))
        a.set_title(title)
        a.axis("off")
    fig.tight_layout()
    fig.savefig(out_path("iridescence_cycles.png"), dpi=90)
    return 0
