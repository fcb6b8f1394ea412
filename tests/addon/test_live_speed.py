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


def _script(mat):
    """The compiled script node of ``mat`` (inside its shared shader group)."""
    grp = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None
               and n.node_tree.name.startswith("Scratch OSL "))
    return next(n for n in grp.node_tree.nodes if n.bl_idname == "ShaderNodeScript")


def test_osl_compiled_ahead_gives_the_same_bytecode_and_sockets(addon, scene, monkeypatch):
    """``osl_compile.precompile`` compiles a source in a background thread; a script node of that source then
    takes its bytecode without compiling again, and the node equals one compiled the ordinary way (bytecode,
    hash, sockets).  Oracle: Cycles' own ``update_script_node`` compile."""
    import re
    import threading

    import cycles.osl

    oc = addon.osl_compile
    src = addon.scratch_material.prepare(addon.scratch_material.validate(
        profile=("quartic", 0.083), resolution=64, layers=dict(n_layers=2, theta_deg=90.0)))["src"]
    calls = []
    real = cycles.osl.osl_compile
    monkeypatch.setattr(cycles.osl, "osl_compile", lambda p, r: calls.append(threading.current_thread()) or real(p, r))
    import bpy

    # the ordinary compile (nothing ahead for this text)
    key = oc._text_key(src + "\n")
    if key in oc._INFLIGHT:                      # prepare() compiles a new source ahead: let it finish first
        oc._INFLIGHT[key].result()
    oc._PRECOMPILED.pop(key, None)
    tree = bpy.data.node_groups.new("plain", "ShaderNodeTree")
    plain = oc.script_node_from_source(tree, "plain.osl", src)
    assert len(calls) == 1
    # compiled ahead, in another thread, then taken by the node
    compiled_in = []
    real_text = oc._compile_text
    monkeypatch.setattr(oc, "_compile_text", lambda t: compiled_in.append(threading.current_thread()) or real_text(t))
    future = oc.precompile(src)
    assert future is not None and future.result() is True
    assert compiled_in and compiled_in[0] is not threading.main_thread()
    assert oc.precompile(src) is None                              # known: nothing to do
    tree2 = bpy.data.node_groups.new("ahead", "ShaderNodeTree")
    ahead = oc.script_node_from_source(tree2, "ahead.osl", src)     # another Text, the same source
    assert len(calls) == 1                                          # no second compile
    # the bytecode names its temporary .osl / .oso files (two ordinary compiles differ there too)
    norm = lambda b: re.sub(r"[^\s\"{}]+\.os[lo]\b", "TMP", b)   # noqa: E731
    assert ahead.bytecode and ahead.bytecode_hash and ahead.bytecode != plain.bytecode
    assert norm(ahead.bytecode) == norm(plain.bytecode)
    assert [(s.name, s.type) for s in ahead.inputs] == [(s.name, s.type) for s in plain.inputs]
    assert [(s.name, s.type) for s in ahead.outputs] == [(s.name, s.type) for s in plain.outputs]
    # another source is not served from it
    other = src + "// another source\n"
    oc.script_node_from_source(bpy.data.node_groups.new("other", "ShaderNodeTree"), "other.osl", other)
    assert len(calls) == 2


def test_live_table_edit_compiles_its_shader_in_the_background(addon, scene, monkeypatch):
    """A table edit's new shader is compiled off the main thread (started by ``prepare``), and the material
    then equals a fresh build (same shader group, hence bytecode)."""
    import threading

    import bpy

    oc = addon.osl_compile
    where = []
    real_text = oc._compile_text
    monkeypatch.setattr(oc, "_compile_text", lambda t: where.append(threading.current_thread()) or real_text(t))
    m = addon.api.make_scratched_material("demo", name="live E", **MAT)
    import cycles.osl

    real = cycles.osl.osl_compile
    main = []
    monkeypatch.setattr(cycles.osl, "osl_compile", lambda p, r: main.append(p) or real(p, r))
    where.clear()
    m.scratch.profile_value = 0.171                      # a miss: a new source
    assert addon.live.last_update()["kind"] == "tables"
    assert len(where) == 1 and where[0] is not threading.main_thread()
    assert main == []                                    # and not compiled a second time on the main thread
    fresh = bpy.data.materials.new("fresh E")
    addon.api.make_scratched_material(material=fresh, **m.scratch.to_params())
    assert _script(m).bytecode_hash == _script(fresh).bytecode_hash and _script(m).bytecode


def test_ui_miss_queues_the_full_tables_with_the_preview(addon, scene, monkeypatch):
    """UI mode, a cache miss: the first tick submits the preview *and* the full tables (``live._ahead``), so
    the full ones start as soon as a worker is free, not after the main thread applied the preview; the full
    ones are then applied from that same computation (computed once)."""
    import time

    live, sm = addon.live, addon.scratch_material
    monkeypatch.setattr(live, "_background", lambda: False)
    monkeypatch.setattr(live.bpy.app.timers, "register", lambda *a, **k: None)
    monkeypatch.setattr(live.bpy.app.timers, "is_registered", lambda *a, **k: True)
    m = addon.api.make_scratched_material("demo", name="live F", **MAT)
    qualities = []
    real = sm.prepare
    monkeypatch.setattr(sm, "prepare", lambda spec, q="full": qualities.append(q) or real(spec, q))
    m.scratch.profile_value = 0.187                # never seen: a miss
    live._pending[m.name] = 0.0
    live._tick()
    key = sm.live_keys(sm.validate(**m.scratch.to_params()), m.name)[0]
    assert live._job is not None and live._job[3] is None         # the preview job
    assert (m.name, key) in live._ahead                            # the full tables: already submitted
    for _ in range(4000):
        if live._tick() is None:
            break
        time.sleep(0.01)
    assert not live.pending() and not live._ahead
    assert sorted(qualities) == ["full", "preview"]                # nothing computed twice
    assert sm.PREVIEW_KEY not in m and m[sm.TABLE_KEY] == key
