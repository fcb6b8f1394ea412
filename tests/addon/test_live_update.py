"""Live look-dev (issue 18): panel settings update the material as they change, without an operator.

Oracles: socket edits change exactly one socket (and the OSL input it mirrors) and nothing else (same
nodes, same script text, same table images); table edits give the same shader text and table images as a
fresh build of the same settings, with the same nodes (in place); structure edits rebuild; a bad setting
leaves the material as it was; a drag (many values, UI mode) applies once, with the last value; a keyframed
density renders differently on two frames.
"""
from __future__ import annotations

import hashlib

import numpy as np
import pytest

RES = 64   # small tables keep the module fast (a cache miss at 64 is ~0.1 s)
#: the material the tests edit: Fig. 1d's 32 layers on iron, quartic 0.08 (pinned: the 'demo' preset may change)
MAT = dict(resolution=RES, profile=("quartic", 0.08),
           layers=dict(n_layers=32, theta_deg=360.0, length=0.3, width=3e-4, density=0.2))


def _image_hash(img) -> str:
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    return hashlib.sha1(px.tobytes()).hexdigest()


def _snapshot(mat) -> dict:
    """What a rebuild or a table update would change."""
    tree = mat.node_tree
    script = _script_node(mat)
    return {"nodes": sorted(n.as_pointer() for n in tree.nodes), "links": len(tree.links),
            "text": hashlib.sha1(script.script.as_string().encode()).hexdigest(), "bytecode": script.bytecode_hash,
            "C": _tables_hash(tree, ("N", "A", "C")), "B": _tables_hash(tree, ("Y", "Btheta"))}


def _tables_hash(tree, roles) -> str:
    """Content of the table images (by role: node_groups.scratch_svm.table_images) the tree's nodes read."""
    prefix = "Scratch table "
    imgs = {n.image.name.rsplit(" ", 1)[0][len(prefix):]: n.image for n in tree.nodes
            if n.bl_idname == "ShaderNodeTexImage" and n.image is not None and n.image.name.startswith(prefix)}
    assert imgs, "no table images in the tree"
    return hashlib.sha1("".join(f"{r}:{_image_hash(imgs[r])};" for r in sorted(roles) if r in imgs).encode()).hexdigest()


def _inputs(node) -> dict:
    return {s.identifier: (tuple(s.default_value) if hasattr(s.default_value, "__len__") else s.default_value)
            for s in node.inputs if hasattr(s, "default_value")}


@pytest.fixture
def mat(addon, scene):
    m = addon.api.make_scratched_material("demo", **MAT)
    assert addon.live.is_live(m)
    return m


def _script(mat):
    """The scratch shader's node in the material (the group node of its shared shader group)."""
    return mat.node_tree.nodes["Scratch Shader"]


def _script_node(mat):
    """The compiled script node (inside the shared group: scratch_material.shader_group)."""
    node = _script(mat)
    return node if node.bl_idname == "ShaderNodeScript" else \
        next(n for n in node.node_tree.nodes if n.bl_idname == "ShaderNodeScript")


SOCKET_EDITS = [("length", 0.05, "Length"), ("width", 3e-4, "Width"), ("density", 0.25, "Density"),
                ("tint", (0.9, 0.5, 0.2), "Tint")]


@pytest.mark.parametrize("prop, value, socket", SOCKET_EDITS)
def test_socket_setting_writes_its_socket_only(addon, mat, prop, value, socket):
    tree = mat.node_tree
    controls = tree.nodes["Scratch Controls"]
    before = _snapshot(mat)
    others = {n.as_pointer(): _inputs(n) for n in tree.nodes if n != controls and n.name != "Scratch Shader"}
    key = mat["scratch_live_table_key"]
    setattr(mat.scratch, prop, value)
    got = controls.inputs[socket].default_value
    want = np.atleast_1d(value)
    assert np.allclose(np.atleast_1d(got)[:want.size], want, rtol=1e-6)
    # the OSL input takes the value through a link from the controls node (and mirrors it)
    script = _script(mat)
    assert script.inputs[socket].is_linked and script.inputs[socket].links[0].from_node == controls
    assert np.allclose(np.atleast_1d(script.inputs[socket].default_value)[:want.size], want, rtol=1e-6)
    # ... and so does the SVM twin: some of its nodes read the controls output
    assert any(lk.from_node == controls and lk.to_node.name != "Scratch Shader"
               for lk in controls.outputs[socket].links)
    assert _snapshot(mat) == before, "a socket edit must not rebuild, recompile or touch the tables"
    assert {n.as_pointer(): _inputs(n) for n in tree.nodes if n != controls and n.name != "Scratch Shader"} == others
    assert mat["scratch_live_table_key"] == key


def test_base_and_diffuse_colour_are_sockets(addon, mat):
    mat.scratch.base_type = "glossy"          # structure: rebuilt
    mat.scratch.diffuse_type = "color"
    tree = mat.node_tree
    before = _snapshot(mat)
    mat.scratch.base_color = (0.2, 0.4, 0.6)
    mat.scratch.base_roughness = 0.45
    mat.scratch.diffuse_color = (0.7, 0.1, 0.3)
    assert np.allclose(tree.nodes["Scratch Base"].inputs["Color"].default_value[:3], (0.2, 0.4, 0.6), atol=1e-6)
    assert tree.nodes["Scratch Base"].inputs["Roughness"].default_value == pytest.approx(0.45)
    assert np.allclose(tree.nodes["Scratch Diffuse"].inputs["Color"].default_value[:3], (0.7, 0.1, 0.3), atol=1e-6)
    assert _snapshot(mat) == before


def test_table_setting_updates_like_a_fresh_build(addon, mat):
    """A table setting gives what a fresh build gives.  In place (same nodes) when the tables keep their
    shape; the adaptive view slices (precompute.scratch.slices) and the θo basis size follow the profile and
    the metal, so a profile or metal change usually changes the shape and rebuilds."""
    import bpy

    before = _snapshot(mat)
    mat.scratch.profile_value = 0.3
    mat.scratch.metal = "gold"
    after = _snapshot(mat)
    assert after["text"] != before["text"] and after["C"] != before["C"]
    assert addon.live.last_update()["kind"] in ("tables", "rebuild")
    # the oracle: a material built from scratch with the same settings
    fresh = bpy.data.materials.new("fresh")
    addon.api.make_scratched_material(material=fresh, **mat.scratch.to_params())
    want = _snapshot(fresh)
    assert after["text"] == want["text"] and after["C"] == want["C"] and after["B"] == want["B"]
    base, base_fresh = mat.node_tree.nodes["Scratch Base"], fresh.node_tree.nodes["Scratch Base"]
    assert _inputs(base) == _inputs(base_fresh)
    glossy = [n for n in mat.node_tree.nodes if n.get("scratch_table_glossy")]
    glossy_fresh = [n for n in fresh.node_tree.nodes if n.get("scratch_table_glossy")]
    assert glossy and [_inputs(n) for n in glossy] == [_inputs(n) for n in glossy_fresh]


def test_structure_setting_rebuilds(addon, mat):
    mat.scratch.n_layers = 3
    tree = mat.node_tree
    assert addon.live.last_update()["kind"] == "rebuild"
    assert sum(n.bl_idname == "ShaderNodeTexVoronoi" for n in tree.nodes) == 3
    assert "#define NL 3" in _script_node(mat).script.as_string() or "NL 3" in _script_node(mat).script.as_string()
    assert tree.nodes["Scratch Controls"].inputs["Density"].default_value == pytest.approx(mat.scratch.density)


def test_bad_setting_leaves_material_as_it_was(addon, mat):
    before = _snapshot(mat)
    mat.scratch.profile_type = "file"   # no file chosen: ValueError inside the update
    assert "profile file" in mat.get("scratch_live_error", "")
    assert _snapshot(mat) == before
    mat.scratch.profile_type = "quartic"
    assert "scratch_live_error" not in mat


def test_batch_applies_once(addon, mat, monkeypatch):
    sm = addon.scratch_material
    calls = []
    real = sm.apply_tables
    monkeypatch.setattr(sm, "apply_tables", lambda *a, **k: calls.append(1) or real(*a, **k))
    with addon.live.batch():
        for v in (0.1, 0.15, 0.2, 0.25):
            mat.scratch.profile_value = v
        mat.scratch.metal = "copper"
    assert len(calls) == 1
    assert '"quartic"' in mat["scratch_live_table_key"] and "0.25" in mat["scratch_live_table_key"]


def test_drag_in_the_ui_queues_one_update_with_the_last_value(addon, mat, monkeypatch):
    """UI mode (timers): a drag's intermediate values do not each rebuild; flush applies the last one."""
    live = addon.live
    monkeypatch.setattr(live, "_background", lambda: False)
    monkeypatch.setattr(live.bpy.app.timers, "register", lambda *a, **k: None)
    monkeypatch.setattr(live.bpy.app.timers, "is_registered", lambda *a, **k: True)
    prepared = []
    real = addon.scratch_material.prepare
    monkeypatch.setattr(addon.scratch_material, "prepare", lambda spec, *a: prepared.append(spec) or real(spec, *a))
    before = _snapshot(mat)
    for v in np.linspace(0.1, 0.4, 12):
        mat.scratch.profile_value = float(v)
        mat.scratch.density = float(v)      # sockets still follow at once
        assert mat.node_tree.nodes["Scratch Controls"].inputs["Density"].default_value == pytest.approx(v)
    assert _snapshot(mat) == before and live.pending()
    live.flush()
    assert not live.pending()
    sm = addon.scratch_material
    last = sm.live_keys(sm.validate(**mat.scratch.to_params()), mat.name)[0]
    assert mat.scratch.profile_value == pytest.approx(0.4)
    assert len(prepared) == 1 and sm.live_keys(prepared[0], mat.name)[0] == last == mat["scratch_live_table_key"]
    assert _snapshot(mat)["text"] != before["text"]


def test_undo_handler_resyncs_a_stale_material(addon, mat):
    """Memfile undo restores settings and tree together; a step taken while an update was pending leaves them
    out of step: the undo handler brings the tables back to the settings."""
    live = addon.live
    before = _snapshot(mat)
    with live.suspended():
        mat.scratch.profile_value = 0.35
    assert _snapshot(mat) == before
    live._on_undo()
    assert _snapshot(mat)["text"] != before["text"]
    assert mat["scratch_live_settings_key"] == mat["scratch_live_table_key"]


def test_keyframed_density_renders_differently_on_two_frames(addon, scene, tmp_path):
    import bpy

    render = addon.render
    scene = render.reset_scene()
    m = addon.api.make_scratched_material("demo", **MAT)
    render.studio_world(scene)
    render.add_torus(scene, material=m)
    render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
    m.scratch.base_type = "none"    # black between scratches: the density sets the brightness
    m.scratch.density = 0.02
    m.scratch.keyframe_insert("density", frame=1)
    m.scratch.density = 1.0
    m.scratch.keyframe_insert("density", frame=2)
    render.configure_cycles(scene, samples=4, res=(32, 24), seed=0, osl=False)
    means = []
    for frame in (1, 2):
        scene.frame_set(frame)
        want = 0.02 if frame == 1 else 1.0
        assert m.node_tree.nodes["Scratch Controls"].inputs["Density"].default_value == pytest.approx(want, abs=1e-6)
        out = tmp_path / f"f{frame}.exr"
        render.render_to_file(scene, str(out))
        img = bpy.data.images.load(str(out))
        px = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(px)
        means.append(px.reshape(-1, 4)[:, :3].mean())
        bpy.data.images.remove(img)
    assert means[1] > 1.5 * means[0], means


def _layer_constants(mat) -> dict:
    """The per-layer constants (eq. 7's Θ_k, ξ_k) of the nodes ``scratch_svm.build`` tags, by tag: unlinked input
    values, a layer Voronoi's texture mapping (where the picked-layer graph keeps Θ_k, ξ_k) and the pixels of a
    layer race's parameters image."""
    def values(node):
        out = []
        for s in node.inputs:
            if not s.is_linked and hasattr(s, "default_value"):
                v = s.default_value
                out.extend(float(x) for x in (v if hasattr(v, "__len__") else (v,)))
        tm = getattr(node, "texture_mapping", None)
        if tm is not None:
            out.extend(float(x) for x in (*tm.translation, *tm.rotation, *tm.scale))
        if getattr(node, "image", None) is not None:   # a layer race's rotations / offsets image
            out.append(_image_hash(node.image))
        return tuple(out)
    from bl_ext.user_default.scratch_addon.node_groups import scratch_svm

    return {n["scratch_layer_const"]: values(n) for n in scratch_svm.tree_nodes(mat.node_tree)
            if n.get("scratch_layer_const")}


def _constants_differ(a: dict, b: dict) -> list:
    """Tags whose constants differ beyond float32 rounding (an in-place update computes a Voronoi's offset from
    the float32 scale it reads back, a fresh build from the float64 length: 1 ulp apart) or whose image differs."""
    def same(x, y):
        return len(x) == len(y) and all(u == v if isinstance(u, str) or isinstance(v, str)
                                        else abs(u - v) <= 1e-6 * max(1.0, abs(u), abs(v)) for u, v in zip(x, y))
    return sorted(k for k in set(a) | set(b) if k not in a or k not in b or not same(a[k], b[k]))


#: the two layouts of the Cycles twin's layers (node_groups.scratch_svm.races): a race (32 sparse layers: about
#: 3 of 32 visited per sample) and the picked layer (4 such layers: a race would visit 3.9 of 4), with the kinds
#: of constant-holding nodes each has (``set_layer_constants`` tags) and how many per layer count n
LAYER_GRAPHS = {
    "race": (MAT, {"race_par"}, lambda n: 1),
    "picked": (dict(MAT, layers=dict(MAT["layers"], n_layers=4)), {"vor", "theta2", "theta3"},
               lambda n: 2 * n),   # per layer a Voronoi (Θ, ξ in its mapping), Θ in the pick's Mix chain
}


def _seed_spread_problems(addon, graph: str) -> list:
    """Build the ``graph`` material, change its seed and spread in the panel; what differs from a fresh API
    build of the changed parameters (empty: the in-place update equals the fresh build)."""
    import bpy

    params, want_kinds, per_layer = LAYER_GRAPHS[graph]
    mat = addon.api.make_scratched_material("demo", name=f"live {graph}", **params)
    n = mat.scratch.n_layers
    consts = _layer_constants(mat)
    tags = {t for key in consts for t in key.split(";") if t.startswith("svm/")}
    kinds = {t.split("/")[1] for t in tags}
    # the graph actually built is the one this case is about (a change of scratch_svm.races shows here)
    assert (kinds, len(tags)) == (want_kinds, per_layer(n)), (graph, sorted(tags))
    before = _snapshot(mat)
    mat.scratch.seed = 7
    mat.scratch.theta_deg = 40.0
    problems = []
    if addon.live.last_update()["kind"] != "tables":
        problems.append(f"kind {addon.live.last_update()['kind']} (want tables, in place)")
    after = _snapshot(mat)
    if after["nodes"] != before["nodes"]:
        problems.append("nodes replaced")
    changed = dict(params, layers=dict(params["layers"], seed=7, theta_deg=40.0))
    fresh = addon.api.make_scratched_material("demo", name=f"fresh {graph}", **changed)
    got, want = _layer_constants(mat), _layer_constants(fresh)
    if _constants_differ(got, want):
        problems.append(f"layer constants differ from a fresh build at {_constants_differ(got, want)[:4]}")
    if not _constants_differ(want, consts):
        problems.append("the seed / spread change does not change the fresh build's constants (the test sees nothing)")
    fresh_snap = _snapshot(fresh)
    for key in ("text", "C", "B"):
        if after[key] != fresh_snap[key]:
            problems.append(f"{key} differs from a fresh build")
    bpy.data.materials.remove(fresh)
    return problems


@pytest.mark.parametrize("graph", sorted(LAYER_GRAPHS))
def test_seed_and_spread_update_in_place_like_a_fresh_build(addon, scene, graph):
    """Seed and spread are layer constants rewritten in place (same nodes): the result equals a fresh build,
    on either layout of the Cycles twin's layers (race / picked layer) and on the EEVEE twin."""
    assert _seed_spread_problems(addon, graph) == []


def test_seed_and_spread_check_fails_on_a_broken_update(addon, scene, monkeypatch):
    """The check above can fail: an in-place update that misses the layers' change (its transforms are taken
    as unchanged, so no constant is rewritten) is caught on both layouts."""
    monkeypatch.setattr(addon.scratch_material, "_layer_transforms_change", lambda material, lp: False)
    for graph in sorted(LAYER_GRAPHS):
        problems = _seed_spread_problems(addon, graph)
        assert any("layer constants differ" in p for p in problems), (graph, problems)


def test_iridescent_layer_drag_compiles_once_with_the_last_value(addon, scene, monkeypatch):
    """Every iridescent-layer setting is compiled in (σ sizes the reach grid): a drag rebuilds once (UI)."""
    import bpy

    live, irid = addon.live, addon.iridescence_material
    m = bpy.data.materials.new("irid")
    node = m.node_tree.nodes.new("ShaderNodeScript")
    node.name = irid.NODE_NAME                      # stands for an inserted layer: insert_layer is counted
    calls = []
    monkeypatch.setattr(irid, "insert_layer", lambda mat, scratches, **kw: calls.append(kw))
    monkeypatch.setattr(live, "_background", lambda: False)
    monkeypatch.setattr(live.bpy.app.timers, "register", lambda *a, **k: None)
    monkeypatch.setattr(live.bpy.app.timers, "is_registered", lambda *a, **k: True)
    for sigma in (20.0, 30.0, 40.0, 55.0):
        m.scratch_iridescence.sigma_um = sigma
    m.scratch_iridescence.samples = 3
    assert calls == [] and live.pending()
    live.flush()
    assert len(calls) == 1 and calls[0]["sigma_um"] == pytest.approx(55.0) and calls[0]["samples"] == 3
    monkeypatch.setattr(live, "_background", lambda: True)     # headless: at once
    m.scratch_iridescence.sigma_um = 70.0
    assert len(calls) == 2 and calls[1]["sigma_um"] == pytest.approx(70.0)


def test_keyframed_settings_reach_the_sockets_before_the_frame_is_evaluated(addon, mat):
    """An animation render syncs a frame right after ``frame_change_pre``: the sockets must hold that frame's
    keyed values already there (evaluated from the F-curves), tint channels included."""
    import bpy

    live = addon.live
    mat.scratch.density = 0.1
    mat.scratch.keyframe_insert("density", frame=1)
    mat.scratch.density = 0.9
    mat.scratch.keyframe_insert("density", frame=11)
    mat.scratch.tint = (1.0, 1.0, 1.0)
    mat.scratch.keyframe_insert("tint", index=1, frame=1)
    mat.scratch.tint = (1.0, 0.2, 1.0)
    mat.scratch.keyframe_insert("tint", index=1, frame=11)
    scene = bpy.context.scene
    scene.frame_current = 6          # no evaluation: only the pre handler runs
    live._on_frame_pre(scene)
    controls = mat.node_tree.nodes["Scratch Controls"]
    assert controls.inputs["Density"].default_value == pytest.approx(0.5, abs=0.05)   # eased: near the middle
    assert 0.2 < controls.inputs["Tint"].default_value[1] < 1.0
    assert controls.inputs["Tint"].default_value[0] == pytest.approx(1.0)


# ------------------------------------------------------------------ table shape changes in place, preview tables
def _rows_image(mat, role):
    prefix = "Scratch table " + role + " "
    return next(n.image for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeTexImage" and n.image is not None
                and n.image.name.startswith(prefix))


def _pixels(img) -> np.ndarray:
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(img.size[1], img.size[0], 4)


def _theta_y(mat) -> np.ndarray:
    """What the node tree's θo factor evaluates to, per node row, bin group and θo sample: the Y image holds it
    pre-summed over the θo basis (node_groups.scratch_svm.theta_factor), so its shape does not follow the rank."""
    return _pixels(_rows_image(mat, "Y"))[..., :3].astype(np.float64)


def _row_constants(mat) -> list:
    """The 1/S of every row node (row = up / S + row_k; row_k = (k + 1/2) / S comes from the N image)."""
    return [n.inputs[1].default_value for n in mat.node_tree.nodes if n.get("scratch_table_rows")]


def _same_tables_as_fresh(addon, mat):
    import bpy

    fresh = bpy.data.materials.new("fresh")
    addon.api.make_scratched_material(material=fresh, **mat.scratch.to_params())
    assert _snapshot(mat)["text"] == _snapshot(fresh)["text"]
    assert _snapshot(mat)["C"] == _snapshot(fresh)["C"]          # N, A, C images: identical pixels
    np.testing.assert_allclose(_theta_y(mat), _theta_y(fresh), rtol=0, atol=1e-6)
    S = _rows_image(fresh, "A").size[1]
    assert _rows_image(mat, "A").size[1] == S
    rows = np.array(_row_constants(mat))
    assert rows.shape == np.array(_row_constants(fresh)).shape and rows.size
    np.testing.assert_allclose(rows, [1.0 / S] * len(rows), rtol=1e-6)
    return fresh


def test_table_shape_change_updates_in_place_like_a_fresh_build(addon, mat):
    """Profile + metal change whose adaptive tables have another node count S and a smaller θo rank: the same
    nodes (no rebuild), the rows constants follow S, the θo factor equals a fresh build's."""
    nodes = sorted(n.as_pointer() for n in mat.node_tree.nodes)
    S0 = _rows_image(mat, "A").size[1]
    with addon.live.batch():
        mat.scratch.metal = "aluminium"
        mat.scratch.profile_value = 0.15      # RES 64: S 87 -> 83, rank 8 -> 5
    assert addon.live.last_update()["kind"] == "tables"
    assert sorted(n.as_pointer() for n in mat.node_tree.nodes) == nodes
    fresh = _same_tables_as_fresh(addon, mat)
    assert _rows_image(fresh, "A").size[1] != S0                      # the shape did change


def test_theta_rank_growth_updates_in_place(addon, scene):
    """A metal whose θo basis needs more functions (aluminium -> iron): the SVM twin reads the factor pre-summed
    over the basis (one Y image whose shape does not follow the rank), so this too updates in place."""
    m = addon.api.make_scratched_material("demo", **dict(MAT, fresnel="aluminium", profile=("quartic", 0.2)))
    nodes = sorted(n.as_pointer() for n in m.node_tree.nodes)
    m.scratch.metal = "iron"
    assert addon.live.last_update()["kind"] == "tables"
    assert sorted(n.as_pointer() for n in m.node_tree.nodes) == nodes
    _same_tables_as_fresh(addon, m)


def _ui_mode(live, monkeypatch):
    monkeypatch.setattr(live, "_background", lambda: False)
    monkeypatch.setattr(live.bpy.app.timers, "register", lambda *a, **k: None)
    monkeypatch.setattr(live.bpy.app.timers, "is_registered", lambda *a, **k: True)


def test_ui_cache_miss_shows_preview_tables_then_the_full_ones(addon, mat, monkeypatch):
    """UI mode: a table edit that misses the cache applies quick preview tables from the worker first
    (marked), then the full ones, which equal a fresh build; the main thread never computes tables."""
    import threading
    import time

    live, sm = addon.live, addon.scratch_material
    _ui_mode(live, monkeypatch)
    threads = []
    real = sm.prepare
    monkeypatch.setattr(sm, "prepare", lambda spec, q="full": threads.append((threading.current_thread(), q))
                        or real(spec, q))
    live._stats["last"] = None                 # an earlier test's update record is not this edit's
    mat.scratch.profile_value = 0.237          # never seen: a miss
    live._pending[mat.name] = 0.0              # the debounce is over
    seen = []
    for _ in range(4000):
        again = live._tick()
        last = live.last_update()   # the record itself is kept in ``seen``: an id() of a freed one can be reused
        if last and last["kind"] == "tables" and (not seen or seen[-1][0] is not last):
            seen.append((last, bool(mat.get(sm.PREVIEW_KEY)), _rows_image(mat, "A").size[1]))
        if again is None:
            break
        time.sleep(0.01)
    assert not live.pending()
    assert sorted(q for _t, q in threads) == ["full", "preview"]   # each computed once (submitted together)
    assert all(t is not threading.main_thread() for t, _q in threads)
    assert [p for _i, p, _s in seen] == [True, False]
    assert seen[0][2] < seen[1][2]                       # the preview has fewer φo nodes
    assert sm.PREVIEW_KEY not in mat
    _same_tables_as_fresh(addon, mat)


def test_undo_to_a_preview_state_brings_the_full_tables(addon, mat):
    """An undo step taken while preview tables showed: the undo handler computes the full ones."""
    mat.scratch.profile_value = 0.21
    assert addon.live.last_update()["kind"] == "tables"
    mat[addon.scratch_material.PREVIEW_KEY] = 1
    addon.live._stats["last"] = None
    addon.live._on_undo()
    assert addon.scratch_material.PREVIEW_KEY not in mat
    assert addon.live.last_update()["kind"] == "tables"   # recomputed (a cache hit), not skipped as up to date
    _same_tables_as_fresh(addon, mat)


def test_a_file_saved_with_preview_tables_loads_with_the_full_ones(addon, mat, tmp_path):
    import bpy

    sm = addon.scratch_material
    mat.scratch.profile_value = 0.21
    want = _snapshot(mat)["C"]
    mat[sm.PREVIEW_KEY] = 1                   # saved during the ~1 s a preview shows
    mat.use_fake_user = True                  # (no object uses it: kept in the file anyway)
    name, path = mat.name, str(tmp_path / "preview.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    m = bpy.data.materials[name]
    assert sm.PREVIEW_KEY not in m and _snapshot(m)["C"] == want


def test_failed_shape_change_leaves_the_material_as_it_was(addon, mat, monkeypatch):
    """Nothing lost (scratch_addon.transaction): an in-place update that changes the tables' shape and fails at
    its last step leaves the images, the row constants, the shader and the nodes as they were, and no new
    table image behind."""
    import bpy

    sm = addon.scratch_material
    before, rows = _snapshot(mat), _row_constants(mat)
    images = {img.name for img in bpy.data.images}

    def broken(*_a, **_k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(sm, "_store_params", broken)
    with pytest.raises(RuntimeError, match="disk full"):
        with addon.live.batch():
            mat.scratch.metal = "aluminium"
            mat.scratch.profile_value = 0.15      # RES 64: S 87 -> 83, rank 8 -> 5
    assert _snapshot(mat) == before and _row_constants(mat) == rows
    assert {img.name for img in bpy.data.images} == images
