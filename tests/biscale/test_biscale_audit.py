"""Issue 16, an independent judge's checks (``bench/biscale_truth_audit``, ``bench/merl_audit``).

1. What the bake reads from a tile's material slots is what Cycles renders with them
   (``biscale_material.small_scale_material``): Cycles' Glossy BSDF has no Fresnel (its Color scales the GGX lobe
   at every angle), and Diffuse + Glossy summed by Add Shader / blended by Mix Shader is one material, not a grey
   Lambert.  Oracle: the numpy twin of those closures (Σ w kd / π + Σ w c · Cycles' GGX D G2 / (4 cos cos),
   ``tabulated_brdf._ggx_unit``) at random and grazing direction pairs.
2. A tile nobody had tried (an asymmetric sawtooth from the public ``heightfield_tile``) baked to the closure table
   renders on Cycles SVM like the explicit tiled geometry at views off the bench's list; the table of the mirrored
   sawtooth (a deliberately broken table: the steep glossy face on the wrong side) does not.
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest


def _mods(addon):
    root = addon.__name__.rpartition(".")[0]
    return (importlib.import_module(addon.__name__ + ".biscale_material"),
            importlib.import_module(root + ".precompute.biscale.brdfs"),
            importlib.import_module(root + ".precompute.tables.tabulated_brdf"))


def _node_material(name, build):
    """A material whose output is ``build(tree)``'s shader socket."""
    import bpy

    m = bpy.data.materials.new(name)
    tree = m.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(build(tree), out.inputs["Surface"])
    return m


def _diffuse(tree, c):
    d = tree.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*c, 1.0)
    return d.outputs["BSDF"]


def _glossy(tree, c, rough):
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Color"].default_value = (*c, 1.0)
    g.inputs["Roughness"].default_value = rough
    return g.outputs["BSDF"]


def _pairs(n=4000, seed=3):
    """Random (ωi, ωo) over the hemisphere, a quarter of them grazing (θ in 75-89°)."""
    rng = np.random.default_rng(seed)

    def dirs(k, lo, hi):
        t = np.arccos(rng.uniform(np.cos(np.radians(hi)), np.cos(np.radians(lo)), k))
        p = rng.uniform(0, 2 * np.pi, k)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], 1)
    wi = np.concatenate([dirs(3 * n // 4, 0, 89), dirs(n // 4, 75, 89)])
    wo = np.concatenate([dirs(3 * n // 4, 0, 89), dirs(n // 4, 75, 89)])
    return wi, wo


@pytest.mark.bpy
def test_tile_slot_materials_bake_what_cycles_renders(addon, scene):
    """Glossy (grey 0.8, Roughness 0.5), Diffuse + Glossy (Add Shader), Mix Shader (Fac 0.3) of a Diffuse and a
    Glossy, and a coloured Glossy (all GGX): the small-scale dict evaluates (``brdfs.eval_material``) to the closures'
    numpy twin within 1e-6 relative at every pair.  Before: the Glossy colour was a Schlick F0 (+10 % at ωi·h = cos
    80°; then, until session 9, c / max(c) as a Schlick F0: exact only at ωi·h = 1), Add / Mix Shader read as a grey
    Lambert of the viewport colour.  Distributions: ``test_biscale_glossy_distributions``."""
    bm, brdfs, tb = _mods(addon)
    n = np.array([0.0, 0.0, 1.0])
    wi, wo = _pairs()
    alpha = 0.25
    ggx = tb._ggx_unit(wi, wo, alpha)[:, None]
    kd = np.array([0.2, 0.4, 0.6])
    cases = {
        "glossy": (lambda t: _glossy(t, (0.8, 0.8, 0.8), 0.5), 0.8 * ggx * np.ones(3)),
        "add": (lambda t: _add_of(t, _diffuse(t, kd), _glossy(t, (0.7, 0.7, 0.7), 0.5)), kd / np.pi + 0.7 * ggx),
        "mix": (lambda t: _mix_of(t, 0.3, _diffuse(t, kd), _glossy(t, (0.9, 0.9, 0.9), 0.5)),
                0.7 * kd / np.pi + 0.3 * 0.9 * ggx),
    }
    for name, (build, want) in cases.items():
        d = bm.small_scale_material(_node_material(name, build))
        got = brdfs.eval_material(d, n, wi, wo)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9, err_msg=f"{name}: {d}")
    c = np.array([0.9, 0.6, 0.3])
    d = bm.small_scale_material(_node_material("coloured", lambda t: _glossy(t, tuple(c), 0.5)))
    np.testing.assert_allclose(brdfs.eval_material(d, n, wi, wo), ggx * c, rtol=1e-6, atol=1e-9)


def _add_of(tree, a, b):
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(a, add.inputs[0])
    tree.links.new(b, add.inputs[1])
    return add.outputs["Shader"]


def _mix_of(tree, fac, a, b):
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = fac
    tree.links.new(a, mix.inputs[1])
    tree.links.new(b, mix.inputs[2])
    return mix.outputs["Shader"]


@pytest.mark.bpy
def test_unsupported_slot_graphs_keep_the_viewport_colour(addon, scene):
    """A Mix Shader whose Fac is linked (a texture) or two Glossy roughnesses have no one-dict twin: the documented
    fallback (Lambert of the viewport colour), not a half-read graph."""
    bm, _, _ = _mods(addon)

    def linked_fac(t):
        out = _mix_of(t, 0.5, _diffuse(t, (0.2, 0.2, 0.2)), _glossy(t, (0.8, 0.8, 0.8), 0.3))
        tex = t.nodes.new("ShaderNodeTexNoise")
        t.links.new(tex.outputs["Fac"], out.node.inputs["Fac"])
        return out
    for build in (linked_fac, lambda t: _add_of(t, _glossy(t, (0.5,) * 3, 0.2), _glossy(t, (0.5,) * 3, 0.6))):
        m = _node_material("fallback", build)
        m.diffuse_color = (0.1, 0.3, 0.5, 1.0)
        d = bm.small_scale_material(m)
        assert d == {"model": "lambert", "albedo": pytest.approx((0.1, 0.3, 0.5))}


@pytest.mark.bpy
@pytest.mark.render
def test_sawtooth_table_matches_explicit_tiles(addon, scene, render_dir, capsys):
    """The asymmetric sawtooth of ``bench/biscale_truth_audit`` (shallow diffuse face, steep GGX α 0.15 face; built
    with the public ``heightfield_tile``) baked to the closure table (2000 facets, seed 0; the closure table is
    ωi res 19 on its view grid whatever the bake's dir_res, 4 here: only the unused fitted twin reads it) vs the
    explicit tiles (100 x 100 on a 4 m plane) on Cycles SVM, direct light, at views off the bench's list (55/300,
    70/10), direction-coded world + area lamp, 32x32 px x 64 spp x 2 seeds, explicit frames averaged over 2 camera
    offsets.
    Bound per view: 3 % (issue 16's goal) + 3σ of the render noise (σ: the across-seed per-pixel variance, ~0.7-1 %
    at 64 spp).  Measured: bench (10,000 facets, 256 spp) 0.3-1.3 %, σ 0.3-0.6 %; here 0.8 / 1.9 % (σ 0.65 / 0.8 %,
    111 s at load 11-14).  The
    table of the mirrored sawtooth (steep glossy face on the other side: a deliberately broken table whose
    x-symmetric averages are right) misses by more than 10 % at some view (measured 7.3 / 123 %: put in place of the
    table it fails the bound at both views)."""
    bench = importlib.import_module("bench.biscale_truth")
    audit = importlib.import_module("bench.biscale_truth_audit")
    geo = importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.biscale.geometry")
    _, mats = audit.AUDIT_TILES["sawtooth"]
    tile = audit.sawtooth_tile()
    h = np.array([[0.0, 1 / 3, 2 / 3, 1.0]] * 2)
    mirrored = geo.heightfield_tile(h[:, ::-1], 1.0, 0.3, materials=np.array([[0, 0, 0, 1]] * 2))
    bl = {k: bench._material(f"sawtooth {k}", *bench.bake_variants(t, mats, n_facets=2000, dir_res=4, seed=0,
                                                                    indirect=False)[0]["table"])
          for k, t in (("table", tile), ("broken", mirrored))}
    views = [(55.0, 300.0), (70.0, 10.0)]
    ex, bk, _, se = bench.render_set(tile, mats, bl, [audit._view(*v) for v in views], n=100, spp=64,
                                     noise=True, seeds=(7, 8), shifts=2, osl=False, tmp=str(render_dir))
    err, sig = bench.rel_error(ex, bk["table"], se["explicit"], se["table"])
    bad, _ = bench.rel_error(ex, bk["broken"])
    with capsys.disabled():
        print(f"\n[sawtooth audit] views {views}: table {np.round(100 * err, 2)} % (1σ {np.round(100 * sig, 2)} %), "
              f"mirrored table {np.round(100 * bad, 1)} %")
    assert np.all(err <= 0.03 + 3 * sig), (err, sig)
    assert bad.max() > 0.10, bad
