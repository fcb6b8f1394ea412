"""Nothing lost (issue #14 item 2): every entry point that (re)builds a material validates first and
swaps in the new node tree only when it is complete; any failure (bad input, OSL compile error,
OSError, KeyboardInterrupt) leaves the material exactly as it was.

The oracle is an independent fingerprint of the material taken before and after a failing rebuild:
every node with every RNA setting (recursing into non-ID structs such as colour ramps), every input
and output socket value, node and material custom properties, Cycles settings, links, and the content
of the datablocks the tree uses (script texts and bytecode, image pixels, node groups)."""
from __future__ import annotations

import hashlib
import importlib
import re

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy]

FAST = dict(profile=("v_groove", 45.0), resolution=64, slices=16, layers=dict(n_layers=2, density=0.4))


# ----------------------------------------------------------------------------- the oracle

def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _id(db):
    import bpy

    if isinstance(db, bpy.types.Text):
        return ("Text", db.name, _digest(db.as_string().encode()))
    if isinstance(db, bpy.types.Image):
        px = np.empty(len(db.pixels), np.float32)
        db.pixels.foreach_get(px)
        return ("Image", db.name, tuple(db.size), _digest(px.tobytes()))
    if isinstance(db, bpy.types.NodeTree):
        return ("NodeTree", db.name, _tree(db))
    return (type(db).__name__, db.name)


def _value(v, depth):
    import bpy

    if isinstance(v, bpy.types.ID):
        return _id(v)
    if isinstance(v, bpy.types.bpy_struct):
        return _struct(v, depth + 1) if depth < 3 else type(v).__name__
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    if hasattr(v, "to_dict"):
        return v.to_dict()
    try:
        return tuple(_value(x, depth) for x in v)
    except TypeError:
        return repr(v)


def _struct(s, depth=0):
    out = {}
    for p in s.bl_rna.properties:
        if p.identifier in ("rna_type", "select", "dimensions", "location_absolute") or p.identifier.startswith("bl_"):
            continue
        if p.identifier in ("id_data",):
            continue
        try:
            v = getattr(s, p.identifier)
        except AttributeError:
            continue
        if p.type == "COLLECTION":
            if p.identifier in ("inputs", "outputs", "internal_links", "links"):
                continue
            out[p.identifier] = tuple(_struct(x, depth + 1) for x in v) if depth < 3 else len(v)
        else:
            out[p.identifier] = _value(v, depth)
    return out


def _sockets(sockets, driven=frozenset()):
    """Socket values; a driven value (the render-path switch follows the scene) is the driver's business."""
    return tuple((s.identifier, s.name, s.bl_idname, s.enabled, s.hide,
                  "<driven>" if s.path_from_id() + ".default_value" in driven else
                  _value(getattr(s, "default_value", None), 0)) for s in sockets)


def _tree(tree):
    anim = tree.animation_data
    driven = frozenset(d.data_path for d in anim.drivers) if anim is not None else frozenset()
    nodes = {}
    for n in tree.nodes:
        nodes[n.name] = (n.bl_idname, _struct(n), _sockets(n.inputs, driven), _sockets(n.outputs, driven),
                         tuple(sorted((k, repr(_value(n[k], 0))) for k in n.keys())))
    links = sorted((lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier,
                    lk.is_muted, lk.is_valid) for lk in tree.links)
    return nodes, links


def fingerprint(mat):
    """Everything a user could see of ``mat`` (see the module docstring)."""
    return {"tree": _tree(mat.node_tree), "custom": sorted((k, repr(_value(mat[k], 0))) for k in mat.keys()),
            "cycles": _struct(mat.cycles), "name": mat.name}


def _scratch_names():
    import bpy

    return {c: sorted(db.name for db in getattr(bpy.data, c)) for c in ("materials", "texts", "images", "node_groups")}


def _first_difference(a, b, path=""):
    """Where ``a`` and ``b`` first differ (a short message; pytest's own diff of these is very slow)."""
    if type(a) is not type(b):
        return f"{path}: {type(a).__name__} -> {type(b).__name__}"
    if isinstance(a, dict):
        for k in sorted(set(a) | set(b), key=str):
            if k not in a or k not in b:
                return f"{path}/{k}: {'added' if k in b else 'removed'}"
            if a[k] != b[k]:
                return _first_difference(a[k], b[k], f"{path}/{k}")
    if isinstance(a, (tuple, list)):
        if len(a) != len(b):
            return f"{path}: length {len(a)} -> {len(b)}"
        for i, (x, y) in enumerate(zip(a, b)):
            if x != y:
                return _first_difference(x, y, f"{path}[{i}]")
    return f"{path}: {str(a)[:200]} -> {str(b)[:200]}"


def _assert_unchanged(mat, before, data_before=None):
    after = fingerprint(mat)
    if after != before:
        pytest.fail("material changed: " + _first_difference(before, after), pytrace=False)
    if data_before is not None and _scratch_names() != data_before:
        pytest.fail(f"datablocks changed: {data_before} -> {_scratch_names()}", pytrace=False)


# ----------------------------------------------------------------------------- fixtures

@pytest.fixture
def built(addon, scene):
    """A scratch material that has been built once, with user additions (custom property, a driver-free
    extra node and link, a tweaked socket), on a UV-mapped plane."""
    obj = addon.render.add_plane(scene)
    mat = addon.api.make_scratched_material(name="Lost", **FAST)
    obj.data.materials.append(mat)
    mat["user_note"] = "keep me"
    val = mat.node_tree.nodes.new("ShaderNodeValue")
    val.name = "user value"
    val.outputs[0].default_value = 0.25
    script = mat.node_tree.nodes["Scratch Shader"]   # the group node of the shared shader group
    script.inputs["Tint"].default_value = (0.5, 0.6, 0.7, 1.0) if len(script.inputs["Tint"].default_value) == 4 \
        else (0.5, 0.6, 0.7)
    return mat


# ----------------------------------------------------------------------------- scratch material

def test_metallic_out_of_range_is_rejected_by_validate(addon):
    with pytest.raises(ValueError, match="base metallic.*\\[0.0, 1.0\\]"):
        addon.scratch_material.validate(base={"type": "principled", "metallic": 2})
    with pytest.raises(ValueError, match="base: unknown key 'metalic'.*accepted: type, color, roughness, metallic"):
        addon.scratch_material.validate(base={"type": "principled", "metalic": 0.5})
    with pytest.raises(ValueError, match="base: unknown key 'roughness'"):
        addon.scratch_material.validate(base={"type": "diffuse", "roughness": 0.5})
    assert addon.scratch_material.validate(base={"type": "principled", "metallic": 1}).base["metallic"] == 1.0


def test_bad_base_on_rebuild_leaves_the_material_as_it_was(addon, built, monkeypatch):
    before, data = fingerprint(built), _scratch_names()
    calls = []
    monkeypatch.setattr(addon.scratch_material, "tables", lambda *a, **k: calls.append(1) or pytest.fail("computed"))
    with pytest.raises(ValueError, match="base metallic"):
        addon.api.make_scratched_material(material=built, base={"type": "principled", "metallic": 2}, **FAST)
    assert not calls  # rejected before any table work
    _assert_unchanged(built, before, data)


def _broken_shader(*_a, **_k):
    return "shader broken(output closure color BSDF = 0) { this is not OSL; }\n"


@pytest.mark.parametrize("fault", ["osl compile error", "OSError mid-build", "KeyboardInterrupt in tables",
                                   "KeyboardInterrupt after the shader compiled"])
def test_failed_rebuild_leaves_the_material_exactly_as_it_was(addon, built, monkeypatch, fault):
    sm = addon.scratch_material
    if fault == "osl compile error":
        monkeypatch.setattr(sm, "shader_source", _broken_shader)
        expected = addon.osl_compile.OSLCompileError
    elif fault == "OSError mid-build":  # after the SVM node groups and images were built
        real = sm._build_svm

        def svm_then_disk_full(*a, **k):
            real(*a, **k)
            raise OSError(28, "No space left on device", "/cache")

        monkeypatch.setattr(sm, "_build_svm", svm_then_disk_full)
        expected = OSError
    elif fault == "KeyboardInterrupt in tables":
        def interrupted(*_a, **_k):
            raise KeyboardInterrupt

        monkeypatch.setattr(sm, "tables", interrupted)
        expected = KeyboardInterrupt
    else:  # the last step: custom properties half written
        def interrupted(*_a, **_k):
            raise KeyboardInterrupt

        monkeypatch.setattr(sm, "fit_error", interrupted)
        expected = KeyboardInterrupt
    before, data = fingerprint(built), _scratch_names()
    other = dict(FAST, layers=dict(n_layers=3, density=0.2), tint=(0.9, 0.8, 0.7), diffuse=(0.1, 0.1, 0.1))
    with pytest.raises(expected):
        addon.api.make_scratched_material(material=built, **other)
    _assert_unchanged(built, before, data)
    monkeypatch.undo()  # and the material still rebuilds afterwards
    addon.api.make_scratched_material(material=built, **other)
    assert "user value" not in built.node_tree.nodes and built["user_note"] == "keep me"


def test_failed_update_operator_reports_one_line_and_keeps_the_material(addon, built, monkeypatch):
    import bpy

    monkeypatch.setattr(addon.scratch_material, "shader_source", _broken_shader)
    built.scratch.from_params(dict(FAST, base="mirror"))
    before, data = fingerprint(built), _scratch_names()
    with bpy.context.temp_override(material=built), pytest.raises(RuntimeError) as err:
        bpy.ops.scratch.update_material()
    msg = str(err.value).strip()
    assert "OSL compile" in msg and "Traceback" not in msg and len(msg.splitlines()) == 1
    _assert_unchanged(built, before, data)


def test_successful_rebuild_equals_a_fresh_build(addon, built):
    import bpy

    params = dict(FAST, layers=dict(n_layers=12, density=0.3), base={"type": "principled", "metallic": 0.5},
                  diffuse=(0.2, 0.1, 0.05))
    addon.api.make_scratched_material(material=built, **params)
    fresh = addon.api.make_scratched_material(name="Fresh", **params)

    def normalised(mat):  # the compiler's temp file name is in the bytecode (and so in its hash)
        fp = repr((fingerprint(mat)["tree"], fingerprint(mat)["cycles"]))
        fp = re.sub(r"'bytecode_hash': '\w*'", "", re.sub(r"tmp\w+\.os[ol]", "tmp", fp))
        return fp.replace(f"'{mat.name}.", "'<material>.")

    a, b = normalised(built), normalised(fresh)
    if a != b:  # (not a bare assert: pytest's diff of two 1 MB strings takes minutes)
        i = next(i for i, (x, y) in enumerate(zip(a, b)) if x != y)
        pytest.fail(f"rebuild differs from a fresh build at ...{a[max(0, i - 200):i + 100]}...", pytrace=False)
    leftovers = [db.name for c in ("texts", "images") for db in getattr(bpy.data, c) if "~rebuild" in db.name]
    assert not leftovers and not [n.name for n in built.node_tree.nodes if "~rebuild" in n.name]
    # the same settings make the same shader: one shared group and Text (content-hashed), the replaced ones removed
    groups = [m.node_tree.nodes["Scratch Shader"].node_tree for m in (built, fresh)]
    assert groups[0] == groups[1] and groups[0].name.startswith("Scratch OSL ")
    assert [g.name for g in bpy.data.node_groups if g.name.startswith("Scratch OSL ")] == [groups[0].name]
    scripts = [n.script for n in groups[0].nodes if n.bl_idname == "ShaderNodeScript"]
    assert [t.name for t in bpy.data.texts] == [scripts[0].name] and scripts[0].name.startswith("scratch_svbrdf.")


def test_failed_new_material_leaves_nothing_behind(addon, scene, monkeypatch):
    monkeypatch.setattr(addon.scratch_material, "shader_source", _broken_shader)
    data = _scratch_names()
    with pytest.raises(addon.osl_compile.OSLCompileError):
        addon.api.make_scratched_material(name="Never", **FAST)
    assert _scratch_names() == data


# ----------------------------------------------------------------------------- iridescent layer

@pytest.fixture
def irid(addon):
    return importlib.import_module(addon.__name__ + ".iridescence_material")


def _glossy_material(addon):
    mat = addon.materials.new_material("Metal")
    glossy = mat.node_tree.nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.3
    mat.node_tree.links.new(glossy.outputs[0], mat.node_tree.nodes["Material Output"].inputs["Surface"])
    mat["user_note"] = "keep me"
    return mat


def test_failed_iridescent_insert_leaves_the_material_as_it_was(addon, irid, scene, monkeypatch):
    mat = _glossy_material(addon)
    before, data = fingerprint(mat), _scratch_names()
    monkeypatch.setattr(irid, "shader_source", _broken_shader)
    with pytest.raises(addon.osl_compile.OSLCompileError):
        irid.insert_layer(mat, irid.generate_scratch_set(20, seed=1), scene=scene)
    _assert_unchanged(mat, before, data)
    assert irid.stored_scratches(mat) is None


@pytest.mark.parametrize("fault", ["osl compile error", "KeyboardInterrupt after the compile"])
def test_failed_iridescent_regenerate_leaves_the_layer_as_it_was(addon, irid, scene, monkeypatch, fault):
    mat = _glossy_material(addon)
    irid.insert_layer(mat, irid.generate_scratch_set(20, seed=1), sigma_um=50.0, scene=scene)
    before, data = fingerprint(mat), _scratch_names()
    if fault == "osl compile error":
        monkeypatch.setattr(irid, "shader_source", _broken_shader)
        expected = addon.osl_compile.OSLCompileError
    else:
        real = irid._lights_hash

        def interrupted(*a, **k):  # after the new source compiled into the layer node
            real(*a, **k)
            raise KeyboardInterrupt

        monkeypatch.setattr(irid, "_lights_hash", interrupted)
        expected = KeyboardInterrupt
    with pytest.raises(expected):
        irid.insert_layer(mat, irid.generate_scratch_set(35, seed=2), sigma_um=20.0, scene=scene)
    _assert_unchanged(mat, before, data)
    assert len(irid.stored_scratches(mat)) == 20


# ----------------------------------------------------------------------------- bi-scale bake, height field

@pytest.fixture
def biscale(addon):
    return importlib.import_module(addon.__name__ + ".biscale_material"), \
        importlib.import_module(addon.__name__ + ".biscale_ops")


def test_failed_biscale_bake_keeps_the_targets_material(addon, scene, biscale, monkeypatch):
    import bpy

    bmat, ops = biscale
    geo = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.geometry")
    tile = ops.add_tile_object(bpy.context, geo.groove_tile(depth=0.4))
    target = addon.render.add_plane(scene, size=2.0)
    old = _glossy_material(addon)
    target.data.materials.append(old)
    before, data = fingerprint(old), _scratch_names()

    def link_fails(*_a, **_k):  # after the new material and its nodes exist
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(bmat.render_paths, "link_surface", link_fails)
    with pytest.raises(OSError):
        bmat.bake(tile, target, n_lobes=1, n_facets=200, dir_res=4, normal_res=21, l_M=40, interreflections=False)
    assert target.data.materials[0] == old
    _assert_unchanged(old, before, data)


def test_failed_heightfield_material_leaves_nothing_behind(addon, scene, tmp_path, monkeypatch):
    import bpy

    mg = importlib.import_module(addon.__name__ + ".microgeometry_ops")
    hf = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.microgeometry.heightfield")
    rng = np.random.default_rng(3)
    path = tmp_path / "scan.npy"
    np.save(path, np.cumsum(rng.standard_normal((96, 96)), axis=1) * 0.01)
    obj = addon.render.add_plane(scene)
    old = _glossy_material(addon)
    obj.data.materials.append(old)
    bpy.context.view_layer.objects.active = obj
    before, data = fingerprint(old), _scratch_names()

    def fails(*_a, **_k):  # after the parameter images were created
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(mg.mg_groups, "add_texture_nodes", fails)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.scratch.material_from_heightfield(filepath=str(path), pixel_um=1.0, synthesize=True, texture_size=8,
                                                  texel_um=8.0)
    assert "No space left on device" in str(err.value) and "Traceback" not in str(err.value)
    assert obj.data.materials[0] == old
    _assert_unchanged(old, before, data)
    del hf
