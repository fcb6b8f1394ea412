"""Material from a height field in Blender (scratch_addon/microgeometry_ops.py, node_groups/microgeometry.py).

References: the numpy pipeline run directly (filtered NDF -> ellipsoid fit), the numpy twin of
Cycles' GGX closure (precompute.cycles.ggx: VNDF-sampled albedo, bsdf_eval) fed with the node
group's closure frame (precompute.microgeometry.glossy.closure_frame), and a diffuse render that
calibrates the sun's irradiance (so no light-unit convention is assumed).
"""
from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy]

# a tilted, rotated, anisotropic lobe: exercises every part of the closure frame
P_A = np.array([0.10, 0.30, 0.12, -0.10, 0.5])
P_B = np.array([0.25, 0.08, -0.05, 0.15, -0.3])


@pytest.fixture
def mg(addon):
    """The operator module; the installed add-on must have registered its operator."""
    import bpy

    assert hasattr(bpy.types, "SCRATCH_OT_material_from_heightfield"), "operator not registered by the add-on"
    return importlib.import_module(addon.__name__ + ".microgeometry_ops")


def _brushed_npy(tmp_path, shape=(256, 256), pixel_um=0.5, seed=2):
    from scratch_materials.precompute.microgeometry.heightfield import gaussian_surface

    hf = gaussian_surface(shape, pixel_um, 0.05, (20.0, 1.5), seed=seed)  # scratches along x
    path = tmp_path / "brushed.npy"
    np.save(path, hf.heights)
    return path, hf


# ----------------------------------------------------------------------------- operator


def test_operator_creates_average_material_matching_numpy_pipeline(scene, mg, addon, tmp_path):
    import bpy

    from scratch_materials.precompute.microgeometry.ndf import filtered_ndf, fit_ellipsoid
    from scratch_materials.precompute.microgeometry.glossy import glossy_from_ellipsoid

    path, hf = _brushed_npy(tmp_path)
    obj = addon.render.add_plane(scene)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.scratch.material_from_heightfield(filepath=str(path), pixel_um=0.5, sigma_um=1.0) == {"FINISHED"}
    mat = obj.active_material
    assert mat["scratch_addon_kind"] == "microgeometry_average" and not mat.cycles.use_bump_map_correction
    # the same numbers as the numpy pipeline run directly (cache stores float32: 1e-6 relative)
    expect = np.array(fit_ellipsoid(filtered_ndf(hf, sigma_um=1.0, resolution=513, periodic="auto")))
    np.testing.assert_allclose(mat["microgeometry_ellipsoid"], expect, rtol=1e-5, atol=1e-6)
    maps, _ = glossy_from_ellipsoid(expect)
    node = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeGroup")
    assert node.inputs["Anisotropy"].default_value == pytest.approx(float(maps["anisotropy"]), abs=1e-5)
    assert maps["anisotropy"] > 0.5  # brushed along x = UV tangent: lobe narrow along the tangent
    # second run: tables come from the cache
    mat2, info = mg.material_from_heightfield(str(path), 0.5, 1.0)
    assert info["cached"] and mat2 is not mat
    _, info3 = mg.material_from_heightfield(str(path), 0.5, 1.5)  # another sigma: recomputed
    assert not info3["cached"]


def test_operator_synthesised_texture_material(scene, mg, addon, tmp_path):
    import bpy

    path, _ = _brushed_npy(tmp_path)
    obj = addon.render.add_plane(scene)
    bpy.context.view_layer.objects.active = obj
    r = bpy.ops.scratch.material_from_heightfield(filepath=str(path), pixel_um=0.5, synthesize=True,
                                                  texture_size=32, texel_um=4.0, texture_scale=2.0)
    assert r == {"FINISHED"}
    mat = obj.active_material
    assert mat["scratch_addon_kind"] == "microgeometry_texture"
    texs = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage"]
    assert len(texs) == 2
    for t in texs:
        img = t.image
        assert tuple(img.size) == (32, 32) and img.is_float and img.colorspace_settings.is_data
        assert img.packed_file is not None
    px = np.empty(32 * 32 * 4, np.float32)
    next(t.image for t in texs if t.label == "Tilt").pixels.foreach_get(px)
    tilt = px.reshape(32, 32, 4)[..., :3]
    np.testing.assert_allclose(np.linalg.norm(tilt, axis=-1), 1.0, atol=1e-5)
    assert tilt[..., 2].min() > 0.5 and tilt[..., :2].std() > 1e-3  # tilts vary from texel to texel


def test_operator_bad_inputs_report_clear_errors(scene, mg, addon, tmp_path):
    import bpy

    obj = addon.render.add_plane(scene)
    bpy.context.view_layer.objects.active = obj
    with pytest.raises(RuntimeError, match="no such"):
        bpy.ops.scratch.material_from_heightfield(filepath=str(tmp_path / "missing.npy"), pixel_um=0.5)
    assert obj.active_material is None
    bad = tmp_path / "bad.npy"
    bad.write_bytes(b"not a numpy file at all")
    with pytest.raises(RuntimeError, match="bad.npy"):
        bpy.ops.scratch.material_from_heightfield(filepath=str(bad), pixel_um=0.5)
    line = tmp_path / "line.npy"
    np.save(line, np.zeros(16))
    with pytest.raises(RuntimeError, match="2D"):
        bpy.ops.scratch.material_from_heightfield(filepath=str(line), pixel_um=0.5)
    path, _ = _brushed_npy(tmp_path, shape=(64, 64))
    with pytest.raises(RuntimeError, match="texel_um"):
        bpy.ops.scratch.material_from_heightfield(filepath=str(path), pixel_um=0.5, synthesize=True, texel_um=10.0)
    assert obj.active_material is None
    for kwargs, match in [({"pixel_um": -1.0}, "pixel_um"), ({"pixel_um": float("nan")}, "pixel_um"),
                          ({"pixel_um": 0.5, "sigma_um": 0.0}, "sigma_um"),
                          ({"pixel_um": 0.5, "ndf_kind": "GONIO"}, "ndf_kind"),
                          ({"pixel_um": 0.5, "texture_size": 3, "synthesize": True}, "texture_size")]:
        with pytest.raises(ValueError, match=match):
            mg.material_from_heightfield(str(path), **kwargs)
    with pytest.raises(ValueError, match="params"):
        mg.make_average_material("x", [0.1, 0.1, 0.0])
    with pytest.raises(ValueError, match="texture"):
        mg.make_texture_material("x", np.ones((4, 4, 2)))


# ----------------------------------------------------------------------------- renders


def _twin_frame(params):
    from scratch_materials.precompute.microgeometry import glossy as mm

    maps, _ = mm.glossy_from_ellipsoid(params)
    return mm.closure_frame(maps["roughness"], maps["anisotropy"], maps["rotation"], maps["tilt"])


def _twin_albedo(params, n=1_000_000, seed=0):
    """Cycles' estimator for a white world seen straight down: E[eval/pdf] over VNDF samples (twin)."""
    from scratch_materials.precompute.cycles import ggx as cg

    N, X, au, av = _twin_frame(params)
    rng = np.random.default_rng(seed)
    _, ev, pdf = cg.bsdf_sample(N, X, au, av, np.array([0.0, 0.0, 1.0]), rng.random(n), rng.random(n))
    w = np.where(pdf > 0, ev / np.where(pdf > 0, pdf, 1.0), 0.0)
    return w.mean(), w.std() / math.sqrt(n)


def _tolerance(region):
    # per-pixel samples are independent: 4 standard errors of the region mean, plus 0.5 % for the
    # sun's 0.5 degree disc and float32 images
    return 4.0 * region.std() / math.sqrt(region.size) + 0.005 * abs(region.mean())


@pytest.mark.render
def test_furnace_albedo_matches_twin(scene, mg, addon, render_dir):
    r = addon.render
    mat, _, _ = mg.make_average_material("furnace", P_A, color=(1, 1, 1))
    r.uniform_world(scene, 1.0)
    r.add_plane(scene, size=4.0, material=mat)
    r.add_camera(scene, location=(0, 0, 5), target=(0, 0, 0), ortho_scale=1.0)
    r.configure_cycles(scene, samples=16, res=(32, 32), seed=1)
    img, _ = r.render_array(scene, str(render_dir))
    expect, se = _twin_albedo(P_A)
    lum = img.mean(-1)
    # single-scattering GGX loses energy (Smith G, samples below Ng): the twin says ~0.8-0.9, not 1
    assert 0.5 < expect < 0.97
    assert abs(lum.mean() - expect) < _tolerance(lum) + 4 * se, (lum.mean(), expect)


def _sun_scene(addon, scene, material, direction, res=32, samples=16, plane=2.0, ortho=1.0):
    import bpy

    r = addon.render
    world = bpy.data.worlds.new("Black")
    scene.world = world
    r.uniform_world(scene, 0.0)
    r.add_plane(scene, size=plane, material=material)
    cam = r.add_camera(scene, location=(0, 0, 5), target=(0, 0, 0), ortho_scale=ortho)
    cam.rotation_euler = (0.0, 0.0, 0.0)  # looking down -z: image right = +x = +u, image up = +y
    sun = r.add_light(scene, "SUN", location=tuple(5 * np.asarray(direction)), energy=1.0)
    sun.data.energy = 1.0  # strength (irradiance scale), calibrated below with a diffuse render
    sun.data.angle = math.radians(0.5)
    r.configure_cycles(scene, samples=samples, res=(res, res), seed=2)


def _diffuse_material(addon):
    mat = addon.materials.new_material("diffuse")
    d = mat.node_tree.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (1, 1, 1, 1)
    mat.node_tree.links.new(d.outputs["BSDF"], mat.node_tree.nodes["Material Output"].inputs["Surface"])
    return mat


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


@pytest.mark.render
def test_sun_lit_plane_radiance_matches_twin(scene, mg, addon, render_dir):
    from scratch_materials.precompute.cycles import ggx as cg

    up = np.array([0.0, 0.0, 1.0])
    N, X, au, av = _twin_frame(P_A)
    peak = _unit(2 * (N @ up) * N - up)  # mirror direction of the view about the lobe axis
    # off-peak light: rotated 12 degrees about n -- probes the lobe's anisotropy and orientation
    c, s = math.cos(0.21), math.sin(0.21)
    off = np.array([c * peak[0] - s * peak[1], s * peak[0] + c * peak[1], peak[2]])
    _sun_scene(addon, scene, _diffuse_material(addon), peak)
    diff, _ = addon.render.render_array(scene, str(render_dir), "diffuse")
    E = diff.mean() * math.pi / peak[2]  # white Lambertian: L = E cos / pi
    for k, d in enumerate((peak, off)):
        import bpy

        bpy.ops.wm.read_homefile(use_empty=True)
        mat, _, _ = mg.make_average_material(f"sun{k}", P_A, color=(1, 1, 1))
        _sun_scene(addon, bpy.context.scene, mat, d)
        img, _ = addon.render.render_array(bpy.context.scene, str(render_dir), f"glossy{k}")
        ev, _ = cg.bsdf_eval(N, X, au, av, up, d)
        lum = img.mean(-1)
        expect = E * float(ev)
        tol = _tolerance(lum) + _tolerance(diff.mean(-1)) * expect / diff.mean()
        assert abs(lum.mean() - expect) < tol, (k, lum.mean(), expect, tol)
    assert E > 0


@pytest.mark.render
def test_texture_material_texels_match_twin(scene, mg, addon, render_dir):
    """Left half of the texture holds lobe A, right half lobe B: each half renders as the twin predicts."""
    import bpy

    from scratch_materials.precompute.cycles import ggx as cg

    up = np.array([0.0, 0.0, 1.0])
    NA, XA, auA, avA = _twin_frame(P_A)
    d = _unit(2 * (NA @ up) * NA - up)
    tex = np.empty((8, 8, 5))
    tex[:, :4], tex[:, 4:] = P_A, P_B
    _sun_scene(addon, scene, _diffuse_material(addon), d, res=48, ortho=2.0)
    diff, _ = addon.render.render_array(scene, str(render_dir), "diffuse")
    diff = diff[4:44, 4:44]  # the plane exactly fills the frame: keep off its anti-aliased edge
    E = diff.mean() * math.pi / d[2]
    bpy.ops.wm.read_homefile(use_empty=True)
    mat, imgs, loss = mg.make_texture_material("tex", tex, color=(1, 1, 1), interpolation="Closest")
    assert loss.lossless
    _sun_scene(addon, bpy.context.scene, mat, d, res=48, ortho=2.0)
    img, _ = addon.render.render_array(bpy.context.scene, str(render_dir), "tex")
    lum = img.mean(-1)  # rows top-down; columns = +x = +u; the plane fills the frame
    for params, cols in ((P_A, slice(4, 20)), (P_B, slice(28, 44))):
        N, X, au, av = _twin_frame(params)
        ev, _ = cg.bsdf_eval(N, X, au, av, up, d)
        region = lum[4:44, cols]
        expect = E * float(ev)
        tol = _tolerance(region) + _tolerance(diff.mean(-1)) * expect / diff.mean()
        assert abs(region.mean() - expect) < tol, (region.mean(), expect, tol)


@pytest.mark.render
def test_operator_ndf_table_material_renders_its_table(scene, mg, addon, tmp_path, render_dir):
    """``ndf_model="TABLE"`` (panel: NDF Model = Table): the measured filtered NDF itself as a tabulated
    microfacet BRDF (``ndf_brdf`` of the numpy pipeline's NDF, same numbers), rendered by Cycles (OSL)
    in a white furnace at normal view: the frame mean is the closure's expected weight from its numpy
    twin (``tabulated_brdf.sample``, 200k samples), within the pixel noise + 2 %, and not black.
    A rough brushed surface (ellipsoid α 0.02 x 0.17); the table is a half-vector table zoomed to the NDF
    (sharp NDFs: tests/microgeometry/test_ndf_brdf.py).  On SVM the material renders its twin, the §8
    ellipsoid lobe: the same image as the Ellipsoid Fit material."""
    import bpy

    from scratch_materials.precompute.microgeometry.heightfield import gaussian_surface
    from scratch_materials.precompute.microgeometry.ndf import filtered_ndf
    from scratch_materials.precompute.microgeometry.ndf_brdf import ndf_brdf
    from scratch_materials.precompute.tables import tabulated_brdf as tb

    hf = gaussian_surface((256, 256), 0.5, 0.3, (20.0, 1.5), seed=2)
    path = tmp_path / "brushed.npy"
    np.save(path, hf.heights)
    obj = addon.render.add_plane(scene, size=4.0)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.scratch.material_from_heightfield(filepath=str(path), pixel_um=0.5, sigma_um=1.0,
                                                     ndf_model="TABLE") == {"FINISHED"}
    mat = obj.active_material
    assert mat["scratch_addon_kind"] == "microgeometry_table" and mat["microgeometry_source"] == "brushed.npy"
    assert mat["microgeometry_ndf_kind"] == "filtered"
    with pytest.raises(ValueError, match="ndf_model"):
        mg.material_from_heightfield(str(path), 0.5, 1.0, ndf_model="SPLINE")
    with pytest.raises(ValueError, match="ndf_model"):
        mg.material_from_heightfield(str(path), 0.5, 1.0, synthesize=True, ndf_model="TABLE")
    brdf = ndf_brdf(filtered_ndf(hf, sigma_um=1.0, resolution=513), F=(1.0, 1.0, 1.0))
    assert 0.9 < float(brdf.albedo(np.array([[0.0, 0.0, 1.0]])).mean()) < 1.05
    N = 200_000
    _, _, W, _ = tb.sample(tb.closure_tables(brdf), np.repeat([[0.0, 0.0, 1.0]], N, 0),
                           np.random.default_rng(0).random((N, 4)))
    expect = float(W.mean())
    mat2, info = mg.material_from_heightfield(str(path), 0.5, 1.0, ndf_model="TABLE", color=(1, 1, 1))
    assert info["cached"] and info["loss"] is None
    obj.data.materials[0] = mat2
    r = addon.render
    r.uniform_world(scene, 1.0)
    r.add_camera(scene, location=(0, 0, 5), target=(0, 0, 0), ortho_scale=1.0)
    r.configure_cycles(scene, samples=16, res=(32, 32), seed=1, osl=True)
    img, _ = r.render_array(scene, str(render_dir))
    lum = img.mean(-1)
    assert lum.mean() > 0.5
    assert abs(lum.mean() - expect) < _tolerance(lum) + 0.02 * expect, (lum.mean(), expect)
    # Cycles SVM (the default, GPU): the same table as node groups (node_groups/tabulated_svm), same furnace mean
    assert mat2["tabulated_svm"] == "table"
    r.configure_cycles(scene, samples=16, res=(32, 32), seed=1, osl=False)
    svm, _ = r.render_array(scene, str(render_dir), "svm_table")
    lum = svm.mean(-1)
    assert abs(lum.mean() - expect) < _tolerance(lum) + 0.02 * expect, (lum.mean(), expect)
    # EEVEE: the same table graph (its EEVEE variant, tabulated_material), not the §8 ellipsoid lobe
    ee = mat2.node_tree.nodes["Material Output (EEVEE)"].inputs["Surface"].links[0].from_node
    assert mat2["tabulated_eevee"] == "table" and ee.node_tree.name.endswith(" EEVEE")
