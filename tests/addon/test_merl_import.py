"""MERL import computes only what renders and reports something true (issue: the fitted twin was computed and its
error reported though the table renders everywhere).

Oracles: the least-squares twin (``tabulated_brdf.glossy_twin``) is called exactly when a render path uses it
(counted); the reported energy is checked against independent references: the file's albedo against the
analytic BRDF the file was written from (a Lambertian: kd exactly; Cycles' GGX + Lambert: a dense half-vector
midpoint quadrature), and the rendered closure's against the analytic albedo within the resampling error
``merl.to_tabulated`` documents.
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest

from scratch_materials.precompute.tables import merl, tabulated_brdf as tb

KD = np.array([0.1, 0.2, 0.3])


def ggx_lambert(wi, wo):
    """Cycles' GGX (F = 1, α = 0.2, weight 0.8) plus Lambert KD (the file of tests/tables/test_merl.py)."""
    return 0.8 * tb._ggx_unit(wi, wo, 0.2)[:, None] * np.ones(3) + KD / np.pi


def lambert(wi, wo):
    return np.full((len(wi), 3), 0.5 / np.pi)


def ggx_sharp(wi, wo):
    """A GGX α 0.04 (peak half width 1.5°: sharper than the old default's 2.8° cells) + a dim Lambert."""
    return tb._ggx_unit(wi, wo, 0.04)[:, None] * np.array([0.9, 0.7, 0.4]) + 0.03 / np.pi


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("merl")
    out = {}
    for name, f in (("ggx", ggx_lambert), ("lambert", lambert), ("sharp", ggx_sharp)):
        out[name] = d / f"{name}.binary"
        merl.write_merl(out[name], merl.tabulate(f))
    return out


def _mod(addon, name):
    return importlib.import_module(addon.__name__.rpartition(".")[0] + name)


def reference_albedo(f, wo, n=1200, n_phi=360):
    """∫ f cos θi dωi of the analytic BRDF (not the file) by the midpoint rule over the half vector (θh = x² π/2,
    dense at the peak; dωi = 4 |ωo·h| dωh; tests/tables/test_merl.py: converged to < 0.1 % for GGX α >= 0.02)."""
    return merl.half_vector_albedo(f, wo, n, n_phi)


@pytest.fixture
def twin_calls(addon, monkeypatch):
    """Counts the calls of the add-on's glossy_twin."""
    tab = _mod(addon, ".precompute.tables.tabulated_brdf")
    calls = []
    real = tab.glossy_twin

    def counted(brdf):
        calls.append(brdf)
        return real(brdf)

    monkeypatch.setattr(tab, "glossy_twin", counted)
    return calls


def test_merl_import_computes_no_twin_when_the_table_renders_everywhere(addon, scene, files, twin_calls):
    ops = importlib.import_module(addon.__name__ + ".merl_ops")
    mat = ops.material_from_merl(files["ggx"], res=16, n_theta=16)
    assert (mat["tabulated_svm"], mat["tabulated_eevee"]) == ("table", "table")
    assert twin_calls == [] and "tabulated_twin_rel_l1" not in mat
    summary = ops.import_summary(mat)
    assert "the table in Cycles (OSL and SVM) and EEVEE" in summary and "twin" not in summary, summary


@pytest.mark.parametrize("kwargs, svm, eevee", [(dict(eevee_table=False), "table", "fit"),
                                                (dict(svm_table=False), "fit", "fit")])
def test_the_twin_is_computed_and_reported_where_a_path_renders_it(addon, scene, twin_calls, kwargs, svm, eevee):
    tm = importlib.import_module(addon.__name__ + ".tabulated_material")
    ops = importlib.import_module(addon.__name__ + ".merl_ops")
    B = tb.TabulatedBRDF.from_function(ggx_lambert, 8, iso=True, n_theta=8)
    mat = tm.make_tabulated_material(B, "tab", **kwargs)      # duck-typed: a TabulatedBRDF of any import name
    assert (mat["tabulated_svm"], mat["tabulated_eevee"], len(twin_calls)) == (svm, eevee, 1)
    assert 0.0 <= mat["tabulated_twin_rel_l1"] < 0.5
    assert "twin fit error" in ops.import_summary(mat)


def test_reported_albedo_is_the_files_and_the_tables(addon, scene, files):
    """The file's albedo (merl_ops.file_albedo) equals the analytic BRDF's it was written from (Lambert: 0.5 at
    every view, measured within 0.011 %, tolerance 0.1 %; GGX + Lambert: measured +0.02..+0.14 %, the MERL bins'
    quantisation of the peak, tolerance 0.5 %), and the rendered closure's is the analytic one within 1.5 %
    (measured -0.1..-0.7 % with 16² cells; to_tabulated documents -0.2..-0.4 % at 32²)."""
    ops = importlib.import_module(addon.__name__ + ".merl_ops")
    a = np.radians(ops.ALBEDO_VIEWS_DEG)
    wo = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], 1)
    lam = ops.file_albedo(merl.fill_missing(merl.read_merl(files["lambert"])), wo)
    np.testing.assert_allclose(lam, 0.5, rtol=1e-3)
    want = reference_albedo(ggx_lambert, wo).mean(1)
    got_file = ops.file_albedo(merl.fill_missing(merl.read_merl(files["ggx"])), wo).mean(1)
    np.testing.assert_allclose(got_file, want, rtol=0.005)
    mat = ops.material_from_merl(files["ggx"], res=16, n_theta=16)
    assert list(mat["merl_albedo_views"]) == list(ops.ALBEDO_VIEWS_DEG)
    np.testing.assert_allclose(list(mat["merl_albedo_file"]), got_file, rtol=1e-9)
    np.testing.assert_allclose(list(mat["merl_albedo_table"]), want, rtol=0.015)
    summary = ops.import_summary(mat)
    assert "albedo at 0/45/70°" in summary and "% worst" in summary, summary


def test_import_resolution_follows_the_file_and_keeps_explicit_sizes(addon, scene, files):
    """The default import ("auto") picks the grid from the file's peak (``merl.auto_resolution``): the sharp file
    through the operator's defaults gets the cap (48², flagged and reported as sharper than the cells, its peak
    rendered by the glossy floor: GGX α 0.04, ``merl.floor_points``), the broad
    GGX α 0.2 file through the API the floor (24²); an explicit size stays what it was (API ``res=16``; the
    operator's ``res=16`` from a script turns Automatic Resolution off, as the old operator honoured it); bad sizes
    are ValueErrors naming ``res``.  On the old code the defaults gave 32² for both files."""
    import bpy

    ops = importlib.import_module(addon.__name__ + ".merl_ops")
    broad = ops.material_from_merl(files["ggx"])
    assert (broad["tabulated_res"], broad["merl_res_auto"], broad["merl_sharper_than_table"]) == \
        (merl.AUTO_RES_MIN, True, False)
    assert broad["merl_peak_width_deg"] == pytest.approx(np.degrees(merl.lobe_width(
        merl.fill_missing(merl.read_merl(files["ggx"])))), rel=1e-9)
    fixed = ops.material_from_merl(files["sharp"], res=16, n_theta=8)
    assert (fixed["tabulated_res"], fixed["merl_res_auto"], fixed["merl_sharper_than_table"]) == (16, False, True)
    for bad in ("fine", 2, 64):
        with pytest.raises(ValueError, match="res"):
            ops.material_from_merl(files["sharp"], res=bad)
    addon.render.add_plane(scene)
    obj = scene.objects["Plane"]
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.scratch.import_merl(filepath=str(files["sharp"]), res=16) == {"FINISHED"}
    assert obj.active_material["tabulated_res"] == 16 and not obj.active_material["merl_res_auto"]
    assert bpy.ops.scratch.import_merl(filepath=str(files["sharp"])) == {"FINISHED"}
    mat = obj.active_material
    assert (mat["tabulated_res"], mat["merl_res_auto"], mat["merl_sharper_than_table"]) == (merl.AUTO_RES_MAX, True, True)
    summary = ops.import_summary(mat)
    assert "48² directions (auto: peak half width 1.5°" in summary and "sharper than the cells" in summary, summary
    assert "rendered by the glossy floor (GGX α 0.04)" in summary, summary     # Session 10: floor points
