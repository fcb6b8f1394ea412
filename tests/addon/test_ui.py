"""Material-panel UI: preset and update operators (headless), settings round trip, error reports,
and a draw smoke test that checks every property the panel draws exists."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

pytestmark = pytest.mark.bpy


def _plane(addon, scene):
    import bpy

    obj = addon.render.add_plane(scene)
    bpy.context.view_layer.objects.active = obj
    return obj


def test_add_scratch_preset_then_update(addon, scene):
    import bpy

    obj = _plane(addon, scene)
    assert bpy.ops.scratch.add_preset_material(preset="fig14a_shallow") == {"FINISHED"}
    mat = obj.active_material
    # the scene stays as the user has it (SVM): the material's node-group twin renders there
    assert mat["scratch_addon_kind"] == "scratch_svbrdf" and not scene.cycles.shading_system
    s = mat.scratch
    assert (s.profile_type, s.n_layers, s.fresnel_type, s.metal) == ("quartic", 4, "metal", "iron")
    src_before = addon.scratch_material.script_node(mat).script.as_string()
    s.n_layers, s.resolution = 1, "64"
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.scratch.update_material() == {"FINISHED"}
    src_after = addon.scratch_material.script_node(mat).script.as_string()
    assert "#define NL 4" in src_before and "#define NL 1" in src_after


def test_update_reports_bad_settings(addon, scene):
    import bpy

    obj = _plane(addon, scene)
    mat = addon.materials.new_material("M")
    obj.data.materials.append(mat)
    mat.scratch.width, mat.scratch.length = 0.5, 0.1
    with bpy.context.temp_override(material=mat), pytest.raises(RuntimeError, match="width"):
        bpy.ops.scratch.update_material()


def test_settings_round_trip_every_scratch_preset(addon, scene):
    for name, p in addon.presets.PRESETS.items():
        if p.kind != "scratch":
            continue
        mat = addon.materials.new_material(name)
        mat.scratch.from_params(p.params)
        got = mat.scratch.to_params()
        addon.scratch_material.validate(**got)  # the UI produces valid parameters
        assert got["layers"] == (None if p.params["layers"] is None else {
            k: pytest.approx(v, rel=1e-6) for k, v in p.params["layers"].items()}), name
        assert got["profile"] == (p.params["profile"][0], pytest.approx(p.params["profile"][1])), name


class _FakeLayout:
    """Records ``prop`` calls; every other layout call returns another recorder (box, row, ...)."""

    def __init__(self, log):
        self.log = log

    def prop(self, data, name, **_kw):
        self.log.append((data, name))

    def __getattr__(self, _name):
        return lambda *a, **k: _FakeLayout(self.log)


def test_panel_draws_only_existing_properties(addon, scene):
    mat = addon.materials.new_material("Draw")
    log = []
    panel = SimpleNamespace(layout=_FakeLayout(log))
    ctx = SimpleNamespace(material=mat, scene=scene, engine="CYCLES")
    for flags in [dict(), dict(use_layers=False, fresnel_type="conductor", base_type="principled", diffuse_type="color"),
                  dict(fresnel_type="schlick", profile_type="file", base_type="glossy")]:
        for k, v in flags.items():
            setattr(mat.scratch, k, v)
        addon.panels.SCRATCH_PT_material.draw(panel, ctx)
    names = {name for _data, name in log}
    known = set(mat.scratch.bl_rna.properties.keys())
    assert len(names) > 15 and names <= known, names - known


def test_lobe_shape_from_the_panel_builds_table_lobes(addon, scene):
    import bpy

    obj = _plane(addon, scene)
    assert bpy.ops.scratch.add_preset_material(preset="fig14a_shallow") == {"FINISHED"}
    mat = obj.active_material
    s = mat.scratch
    assert s.lobe_shape == "table"
    src = addon.scratch_material.script_node(mat).script.as_string()
    assert "#define LOBE_TABLE 1" in src   # tabulated-tilt lobes compiled (osl/scratch_svbrdf.osl)
    assert mat["scratch_addon_fit_error"] < 0.03
    s.lobe_shape, s.resolution = "fit", "64"
    with bpy.context.temp_override(material=mat):
        assert bpy.ops.scratch.update_material() == {"FINISHED"}
    src = addon.scratch_material.script_node(mat).script.as_string()
    assert "#define LOBE_TABLE 0" in src and "#define LOBE_SUM 0" in src   # one picked fitted lobe
    assert mat.scratch.to_params()["lobe_shape"] == "fit"
    mat.scratch.from_params({"box_lobes": True})        # settings stored before lobe_shape existed
    assert mat.scratch.lobe_shape == "box"
