"""Live look-dev speed paths (issue 18): an in-place table update swaps the table images by one ID remap
(``scratch_material._repoint_images``) and skips socket writes that change nothing.  Oracles: a second
material sharing the same tables keeps its images (content and pointers); a failure after the swap leaves
the material as it was; the result equals a fresh build (tests/addon/test_live_update.py)."""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

MAT = dict(resolution=64, profile=("quartic", 0.08),
           layers=dict(n_layers=4, theta_deg=360.0, length=0.3, width=3e-4, density=0.2))
PREFIX = "Scratch table "


def _tables(mat) -> dict:
    """Per table node (by name): its image's name and a hash of its pixels."""
    out = {}
    for n in mat.node_tree.nodes:
        if n.bl_idname == "ShaderNodeTexImage" and n.image is not None and n.image.name.startswith(PREFIX):
            px = np.empty(len(n.image.pixels), np.float32)
            n.image.pixels.foreach_get(px)
            out[n.name] = (n.image.name, hashlib.sha1(px.tobytes()).hexdigest())
    assert out
    return out


@pytest.fixture
def two(addon, scene):
    a = addon.api.make_scratched_material("demo", name="live A", **MAT)
    b = addon.api.make_scratched_material("demo", name="live B", **MAT)
    assert {v[0] for v in _tables(a).values()} == {v[0] for v in _tables(b).values()}  # shared by content
    return a, b


def test_edit_keeps_the_tables_another_material_shares(addon, two):
    a, b = two
    b_before, a_before = _tables(b), _tables(a)
    a.scratch.profile_value = 0.11
    assert addon.live.last_update()["kind"] == "tables"
    assert _tables(b) == b_before                       # B still points at, and sees, the old tables
    a_after = _tables(a)
    assert set(a_after) == set(a_before) and all(a_after[k] != a_before[k] for k in a_after if "Y" not in k)
    # now A's images are A's alone: the next edit swaps them by remap, B still untouched
    a.scratch.profile_value = 0.12
    assert addon.live.last_update()["kind"] == "tables"
    assert _tables(b) == b_before
    import bpy

    assert not any(name in bpy.data.images for name, _ in a_after.values()
                   if name not in {v[0] for v in _tables(a).values()})  # the replaced ones are gone


def test_failure_after_the_swap_leaves_the_material_as_it_was(addon, scene, monkeypatch):
    import bpy

    m = addon.api.make_scratched_material("demo", name="live C", **MAT)
    m.scratch.profile_value = 0.13     # its tables are its own now (no other user): the remap path
    before = _tables(m)
    names = {v[0] for v in before.values()}
    sm = addon.scratch_material

    def fail(*a, **k):
        raise RuntimeError("injected after the image swap")

    monkeypatch.setattr(sm, "_store_params", fail)
    with addon.live.suspended():
        m.scratch.profile_value = 0.135
    with pytest.raises(RuntimeError, match="injected"):
        addon.live.sync(m)
    monkeypatch.undo()
    assert _tables(m) == before
    assert all(n in bpy.data.images for n in names)
    m.scratch.profile_value = 0.14
    assert addon.live.last_update()["kind"] == "tables" and _tables(m) != before


def test_table_update_equals_a_fresh_build_after_a_remap(addon, scene):
    import bpy

    m = addon.api.make_scratched_material("demo", name="live D", **MAT)
    for v in (0.15, 0.16):     # the second edit swaps images the material alone uses
        m.scratch.profile_value = v
        assert addon.live.last_update()["kind"] == "tables"
    fresh = bpy.data.materials.new("fresh D")
    addon.api.make_scratched_material(material=fresh, **m.scratch.to_params())
    have = sorted(h for _, h in _tables(m).values())
    want = sorted(h for _, h in _tables(fresh).values())
    assert have == want
