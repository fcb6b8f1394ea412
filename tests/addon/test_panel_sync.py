"""The panel shows what the API built (issue: API build leaves the panel unsynced).

A material built by ``api.make_scratched_material`` without a preset (or rebuilt with ``material=``) used to
keep the panel's defaults (aluminium, 4 layers, ...) while the material was built from other parameters; the
first panel edit then rebuilt from the panel and every other parameter silently reverted.  Oracle: after an API
build with non-default parameters and one panel edit, the material equals a fresh API build of the same
parameters with that one change (shader text, table images, every node's input values, the recorded
parameters), whatever kind of update the edit is (socket, tables in place, rebuild).  Parameters the panel
cannot show (a profile / Fresnel object from a script) are kept through panel edits (shown as From Script).
"""
from __future__ import annotations

import hashlib
import importlib
import json

import numpy as np
import pytest

#: every parameter away from its default (small tables keep the module fast)
PARAMS = dict(profile=("v_groove", 35.0), fresnel="gold", resolution=64, slices=32, tint=(0.9, 0.8, 0.7),
              layers=dict(n_layers=3, theta_deg=20.0, length=0.1, width=3e-4, density=0.3, seed=5),
              base={"type": "glossy", "color": (0.2, 0.3, 0.4), "roughness": 0.2}, diffuse=(0.1, 0.2, 0.3))

#: (panel setting, value, the API parameters it stands for)
EDITS = [
    ("density", 0.45, {"layers": dict(PARAMS["layers"], density=0.45)}),        # a socket
    ("seed", 9, {"layers": dict(PARAMS["layers"], seed=9)}),                    # tables in place
    ("profile_value", 25.0, {"profile": ("v_groove", 25.0)}),                   # tables
    ("n_layers", 2, {"layers": dict(PARAMS["layers"], n_layers=2)}),            # a rebuild
]


SOCKET_DEFINES = ("#define LAYER_LENGTH ", "#define LAYER_WIDTH ", "#define LAYER_DENSITY ")


def _pre(addon, name):
    return importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.scratch." + name)


def _image_hash(img) -> str:
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    return hashlib.sha1(px.tobytes()).hexdigest()


def _value(v):
    if hasattr(v, "__len__") and not isinstance(v, str):
        return tuple(round(float(x), 6) for x in v)
    return round(float(v), 6) if isinstance(v, float) else v


def _fingerprint(mat) -> dict:
    """What the material renders: every node's input values (by name, in nested groups the material owns),
    the OSL source, the table images' pixels and the parameters it records."""
    def tree_state(tree, prefix=""):
        out = {}
        for n in tree.nodes:
            out[prefix + n.name] = (n.bl_idname, {s.identifier: _value(s.default_value) for s in n.inputs
                                                   if hasattr(s, "default_value") and not s.is_linked})
            if n.bl_idname == "ShaderNodeScript" and n.script is not None:
                # the live sockets' compiled-in values are only the defaults of the script's linked inputs
                # (a socket edit does not recompile: test_live_update)
                lines = [ln for ln in n.script.as_string().splitlines() if not ln.startswith(SOCKET_DEFINES)]
                out[prefix + n.name + "/source"] = hashlib.sha1("\n".join(lines).encode()).hexdigest()
            if getattr(n, "image", None) is not None:
                out[prefix + n.name + "/image"] = _image_hash(n.image)
            if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None:
                out.update(tree_state(n.node_tree, prefix + n.name + "/"))
        return out

    return tree_state(mat.node_tree)


def _differences(a: dict, b: dict) -> list:
    return sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))


def test_api_build_without_preset_shows_every_parameter(addon, scene):
    mat = addon.api.make_scratched_material(name="api", **PARAMS)
    s = mat.scratch
    assert (s.profile_type, s.profile_value, s.fresnel_type, s.metal) == ("v_groove", pytest.approx(35.0), "metal", "gold")
    assert (s.use_layers, s.n_layers, s.seed, s.slices, s.resolution) == (True, 3, 5, "32", "64")
    assert (s.base_type, s.diffuse_type) == ("glossy", "color")
    # the panel's parameters rebuild exactly what was built: the same table key (float32 values included)
    sm = addon.scratch_material
    assert sm.live_keys(sm.validate(**s.to_params()), mat.name)[0] == mat[sm.TABLE_KEY]
    assert mat[addon.live.SETTINGS_KEY] == mat[sm.TABLE_KEY]


@pytest.mark.parametrize("prop, value, change", EDITS, ids=[e[0] for e in EDITS])
def test_a_panel_edit_after_an_api_build_changes_only_that_value(addon, scene, prop, value, change):
    import bpy

    mat = addon.api.make_scratched_material(name="api", **PARAMS)
    last = addon.live.last_update()
    setattr(mat.scratch, prop, value)
    if prop == "density":
        assert addon.live.last_update() is last, "a socket edit must not recompute tables or rebuild"
    fresh = addon.api.make_scratched_material(name="fresh", **dict(PARAMS, **change))
    got, want = _fingerprint(mat), _fingerprint(fresh)
    assert not _differences(got, want), _differences(got, want)[:8]
    if prop != "density":     # the record of what the material was built from (sockets do not rewrite it)
        assert json.loads(mat["scratch_addon_params"]) == json.loads(fresh["scratch_addon_params"])
    bpy.data.materials.remove(fresh)


def test_rebuild_with_material_keyword_updates_the_panel(addon, scene):
    mat = addon.api.make_scratched_material(name="api", **PARAMS)
    addon.api.make_scratched_material(material=mat, **dict(PARAMS, fresnel=None, layers=None, base="mirror"))
    s = mat.scratch
    assert (s.fresnel_type, s.use_layers, s.base_type) == ("none", False, "mirror")
    assert (s.n_layers, s.density) == (3, pytest.approx(0.3))   # unticking layers keeps the layer values


def test_script_profile_and_fresnel_survive_panel_edits(addon, scene):
    """A profile and Fresnel model the panel cannot express are kept (From Script) through a panel rebuild;
    choosing a panel profile replaces the script one."""
    profiles, fresnel = _pre(addon, "profiles"), _pre(addon, "fresnel")
    params = dict(PARAMS, profile=profiles.quartic(0.3, segments=64), fresnel=fresnel.lazanyi(2.0, 3.0, a=0.1))
    mat = addon.api.make_scratched_material(name="api", **params)
    assert (mat.scratch.profile_type, mat.scratch.fresnel_type) == ("script", "script")
    mat.scratch.n_layers = 2                                       # a rebuild from the panel
    fresh = addon.api.make_scratched_material(name="fresh", **dict(params, layers=dict(PARAMS["layers"], n_layers=2)))
    assert not _differences(_fingerprint(mat), _fingerprint(fresh))
    assert json.loads(mat["scratch_addon_params"]) == json.loads(fresh["scratch_addon_params"])
    mat.scratch.profile_type = "quartic"
    assert json.loads(mat["scratch_addon_params"])["profile"]["params"]["segments"] == 256


def test_panel_values_are_what_the_user_typed(addon, scene):
    """float32 panel values give the decimal typed (0.3, not 0.30000001192), so an API build with 0.3 and
    the panel agree on the tables (no needless recompute on the first edit)."""
    mat = addon.api.make_scratched_material(name="api", **dict(PARAMS, profile=("quartic", 0.3)))
    p = mat.scratch.to_params()
    assert p["profile"] == ("quartic", 0.3) and p["layers"]["width"] == 3e-4
    # a depth no float32 holds is kept exactly (From Script), not rounded into another table
    addon.api.make_scratched_material(material=mat, **dict(PARAMS, profile=("quartic", 0.123456789)))
    assert mat.scratch.profile_type == "script"
    assert mat.scratch.to_params()["profile"].params["depth"] == 0.123456789


def test_an_unstorable_fresnel_model_fails_panel_edits_loudly(addon, scene):
    """A Fresnel model of a class the panel cannot store: a panel rebuild says so and keeps the material."""
    fresnel = _pre(addon, "fresnel")

    class Grey(fresnel.Fresnel):
        def __call__(self, cos_theta):
            return np.full(np.shape(cos_theta) + (1,), 0.8)

        def cache_key(self):
            return {"model": "grey-0.8"}

    mat = addon.api.make_scratched_material(name="api", **dict(PARAMS, fresnel=Grey()))
    assert mat.scratch.fresnel_type == "script"
    before = _fingerprint(mat)
    mat.scratch.n_layers = 2
    assert "cannot store" in mat.get(addon.live.ERROR_KEY, "")
    assert not _differences(_fingerprint(mat), before)


IRID = dict(sigma_um=25.0, route="lobes", samples=3, base_blend=True, candidates=2, base_weight="paper", shadows=True)


def _layer_state(addon, mat) -> tuple:
    node = addon.iridescence_material.layer_node(mat)
    return json.loads(node["scratch_iridescence"]), hashlib.sha1(node.script.as_string().encode()).hexdigest()


def test_iridescent_layer_panel_edit_after_an_api_insert_changes_only_that_value(addon, scene):
    """insert_layer's parameters reach the panel (material.scratch_iridescence): a panel edit recompiles with
    them and the one edited value, equal to a fresh insert_layer with that change."""
    irid = addon.iridescence_material
    scratches = irid.generate_scratch_set(count=12, seed=3)
    mat, fresh = addon.materials.new_material("api"), addon.materials.new_material("fresh")
    irid.insert_layer(mat, scratches, **IRID)
    pg = mat.scratch_iridescence
    assert (pg.sigma_um, pg.samples, pg.candidates, pg.base_weight) == (pytest.approx(25.0), 3, 2, "PAPER")
    pg.shadows = False                    # headless: rebuilt at once from the panel
    irid.insert_layer(fresh, scratches, **dict(IRID, shadows=False))
    assert _layer_state(addon, mat) == _layer_state(addon, fresh)


def test_a_file_profile_stays_a_file_profile_and_is_read_once_per_rebuild(addon, scene, tmp_path, monkeypatch):
    """A measured profile chosen in the panel (a file) stays the panel's file through API rebuilds (not turned
    into a From Script copy), and a panel rebuild reads the file once."""
    profiles = _pre(addon, "profiles")
    x = np.linspace(-0.5, 0.5, 41)
    path = tmp_path / "groove.csv"
    np.savetxt(path, np.c_[x, -0.2 * (1 - (2 * x) ** 2) ** 2], delimiter=",")
    mat = addon.api.make_scratched_material(name="api", **PARAMS)
    reads = []
    real = profiles.from_file
    monkeypatch.setattr(profiles, "from_file", lambda p, **kw: reads.append(p) or real(p, **kw))
    with addon.live.batch():
        mat.scratch.profile_type = "file"
        mat.scratch.profile_file = str(path)
    assert mat.scratch.profile_type == "file" and json.loads(mat["scratch_addon_params"])["profile"]["name"] == "groove"
    assert len(reads) == 1, reads
    mat.scratch.n_layers = 2                                       # a rebuild: the file unchanged, not read again
    assert mat.scratch.profile_type == "file" and len(reads) == 1


#: the ends of the accepted scratch sizes (``layers.SIZE_RANGE``): the panel used to clamp length to >= 1e-6 and
#: width to >= 1e-7, so the first panel edit after such an API build silently rebuilt other scratches; a length
#: of 1e39 (accepted then) broke the OSL build with a KeyError
EXTREME_SIZES = [dict(length=1e-9, width=1e-9), dict(length=1e9, width=1e-9), dict(length=1e9, width=1e9),
                 dict(length=5e-7, width=5e-8)]


@pytest.mark.parametrize("sizes", EXTREME_SIZES, ids=lambda s: f"l{s['length']:g}-w{s['width']:g}")
def test_extreme_scratch_sizes_survive_panel_edits_and_render(addon, scene, render_dir, sizes):
    layers = dict(PARAMS["layers"], **sizes)
    params = dict(PARAMS, layers=layers, diffuse=None, base="mirror")
    mat = addon.api.make_scratched_material(name="api", **params)
    assert (mat.scratch.to_params()["layers"]["length"], mat.scratch.to_params()["layers"]["width"]) == \
        (sizes["length"], sizes["width"])
    mat.scratch.n_layers = 2                                       # a rebuild from the panel keeps the sizes
    assert json.loads(mat["scratch_addon_params"])["layers"] == dict(layers, n_layers=2)
    addon.render.add_plane(scene, size=2.0, material=mat)
    addon.render.add_camera(scene, location=(0, -1.5, 1.5), target=(0, 0, 0), ortho_scale=1.0)
    addon.render.uniform_world(scene, color=(0.8, 0.8, 0.8))
    for osl in (False, True):
        addon.render.configure_cycles(scene, samples=2, res=(8, 8), seed=0, osl=osl)
        img, _ = addon.render.render_array(scene, str(render_dir), f"x{int(osl)}")
        assert np.isfinite(img).all() and img[..., :3].mean() > 0.05, (osl, img[..., :3].mean())


@pytest.mark.parametrize("key, value", [("length", 2e9), ("width", 5e-10), ("length", 1e39), ("width", 0.0)])
def test_scratch_sizes_out_of_range_are_rejected_by_name(addon, scene, key, value):
    layers = dict(PARAMS["layers"], **{key: value})
    with pytest.raises(ValueError, match=rf"{key} must be in \[1e-09, 1e\+09\]"):
        addon.api.make_scratched_material(name="bad", **dict(PARAMS, layers=layers))
