"""Bi-scale options are checked before any work and errors name the option as the caller spelt it
(issue #14 item 4): the keyword of ``bake_tables`` / ``BiscaleTile``, never the parameter name of an
inner function (``l``, ``n_power``, ``options``), and never a TypeError from numpy."""
from __future__ import annotations

import time

import pytest

from scratch_materials.precompute.biscale import bake, geometry as geo
from scratch_materials.precompute.biscale.effective import DEFAULTS, BiscaleTile

TILE = geo.groove_tile(depth=0.4)
MATS = [{"model": "lambert", "albedo": 0.8}]
# options that would make a slow bake if anything ran before the check
HEAVY = dict(n_facets=200_000, dir_res=16, normal_res=81)


@pytest.mark.parametrize("bad, name", [
    (dict(n_facet=100), "'n_facet'"), (dict(dir_res="10"), "dir_res"), (dict(normal_res=4), "normal_res"),
    (dict(normal_res=41.0), "normal_res"), (dict(power_N=2), "power_N"), (dict(power_M="x"), "power_M"),
    (dict(l_M=-1), "l_M"), (dict(l_N=0), "l_N"), (dict(l_N=10**9), "l_N"), (dict(n_power_M=11), "n_power_M"),
    (dict(seed=-1), "seed"), (dict(seed=1.5), "seed"), (dict(smooth_normals="yes"), "smooth_normals"),
    (dict(use_cache="no"), "use_cache"), (dict(n_facets=True), "n_facets"), (dict(n_lobes=9), "n_lobes"),
    (dict(n_lobes="2"), "n_lobes"),
])
def test_bad_options_name_the_keyword_before_any_work(bad, name, tmp_path):
    opts = {**HEAVY, **bad}
    t0 = time.perf_counter()
    with pytest.raises(ValueError) as err:
        bake.bake_tables(TILE.vertices, TILE.faces, TILE.face_material, TILE.period, MATS, exr_dir=str(tmp_path),
                         **opts)
    assert time.perf_counter() - t0 < 1.0  # a 200k-facet tile takes far longer
    msg = str(err.value)
    assert not isinstance(err.value, TypeError)
    assert msg.startswith(name + ":") or f"unknown bi-scale option {name}" in msg, msg
    for internal in ("l:", "n_power:", "options:", "power:"):
        assert not msg.startswith(internal), msg
    assert not list(tmp_path.iterdir())


def test_an_unknown_option_lists_the_accepted_ones_and_suggests_one():
    with pytest.raises(ValueError, match=r"unknown bi-scale option 'dir_resolution' \(did you mean 'dir_res'\?\); "
                                         r"accepted: .*n_facets.*l_M"):
        BiscaleTile(TILE.vertices, TILE.faces, TILE.face_material, dir_resolution=8)


def test_bad_material_dicts_are_rejected_before_the_tile_is_built(monkeypatch, tmp_path):
    monkeypatch.setattr(bake, "BiscaleTile", lambda *a, **k: pytest.fail("the tile was built"))
    monkeypatch.setattr(bake, "_TILE_CACHE", {})
    with pytest.raises(ValueError, match="cook_torrance.alpha"):
        bake.bake_tables(TILE.vertices, TILE.faces, TILE.face_material, TILE.period,
                         [{"model": "cook_torrance", "alpha": -1.0}], exr_dir=str(tmp_path))


def test_equal_options_share_one_tile_whether_spelt_out_or_defaulted(monkeypatch):
    monkeypatch.setattr(bake, "_TILE_CACHE", {})
    small = dict(n_facets=64, dir_res=4, normal_res=21, l_M=20, l_N=20)
    a, hit_a = bake.get_tile(TILE.vertices, TILE.faces, TILE.face_material, TILE.period, **small)
    b, hit_b = bake.get_tile(TILE.vertices, TILE.faces, TILE.face_material, TILE.period,
                             **small, seed=DEFAULTS["seed"], use_cache=True)
    assert not hit_a and hit_b and a is b
