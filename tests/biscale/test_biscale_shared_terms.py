"""The Principled / Multiscatter GGX lobes share one microfacet evaluation per batch (``brdfs._MicrofacetTerms``):
``eval_material`` makes the half vector, D G, Fresnel weight and E(co) once for all of a material's lobes instead of
once per lobe (a Principled metal is four lobes: the interreflection pass of a bake spent 55 s of 168 in them).

The values must not change.  References, independent of how ``brdfs`` splits a material into lobes:
- the Principled BSDF written out from Cycles' closure setup (``svm/closure.h``: F82-tint metal, real-curve dielectric
  specular, Lambert base under ``closure_layering_weight``, Multiscatter GGX's ``microfacet_ggx_preserve_energy``)
  with single-scatter GGX from the vector twin of ``bsdf_microfacet_eval`` (``precompute.cycles.ggx.bsdf_eval``), the
  Fresnel and table functions of ``precompute.cycles.principled`` / ``multiscatter``;
- each lobe called on its own (``Lobe.f``: its terms made for it alone): the shared evaluation must give their sum.
"""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.biscale import brdfs
from scratch_materials.precompute.cycles import ggx as cg
from scratch_materials.precompute.cycles import lookup, multiscatter as ms, principled as pr

PRINCIPLED = [
    dict(base_color=(0.9, 0.6, 0.3), metallic=1.0, roughness=0.4),                      # the bench's metal floor
    dict(base_color=(0.2, 0.5, 0.8), metallic=0.0, roughness=0.5),                      # a default dielectric
    dict(base_color=(0.5, 0.7, 0.9), metallic=0.5, roughness=0.35, ior=1.8, specular_ior_level=0.7,
         specular_tint=(1.0, 0.6, 0.3)),                                                 # tinted: F82 B != 0
    dict(base_color=(0.7, 0.2, 0.4), metallic=0.3, roughness=0.05, ior=1.3, specular_tint=(0.5, 0.5, 0.5),
         multiscatter=False),
    dict(base_color=0.4, metallic=0.0, roughness=0.8, ior=0.7, specular_tint=(1.0, 0.6, 0.3)),
    dict(base_color=0.4, metallic=0.0, roughness=0.8, ior=1.0),                          # no specular layer
]


def _directions(rng, k, grazing=0.0):
    """k unit vectors on the upper hemisphere, a fraction ``grazing`` of them within 1° of the horizon."""
    v = rng.normal(size=(k, 3))
    v[:, 2] = np.abs(v[:, 2])
    g = rng.random(k) < grazing
    v[g, 2] = np.linalg.norm(v[g, :2], axis=1) * np.tan(np.radians(rng.uniform(0.01, 1.0, g.sum())))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _principled_reference(mat, light, view):
    """Cycles' opaque Principled BSDF f(light, view) (1/sr, RGB) at a normal z, written out from ``svm/closure.h``
    with the twins' Fresnel and table functions; (..., 3)."""
    d = {**pr.PRINCIPLED_DEFAULTS, **mat}
    b = np.broadcast_to(np.asarray(d["base_color"], float), 3)
    tint = np.broadcast_to(np.asarray(d["specular_tint"], float), 3)
    m, r = d["metallic"], d["roughness"]
    alpha = max(r * r, 1e-3)
    rough = np.sqrt(alpha)
    ev, _ = cg.bsdf_eval([0, 0, 1.0], [1.0, 0, 0], alpha, alpha, view, light)      # D G2 / (4 cos view)
    cos_l, mu = light[..., 2], view[..., 2]
    f_ss = (ev / cos_l)[..., None]
    h = (light + view) / np.linalg.norm(light + view, axis=-1, keepdims=True)
    c = np.sum(view * h, -1)[..., None]
    Ea = ms.ggx_E_avg(rough)

    def energy(Fss):                        # microfacet_ggx_preserve_energy: 1 + Fms (1 - E) / E, or 1
        return ms.multiscatter_factor(rough, mu[..., None], Fss) if d["multiscatter"] else 1.0

    B = pr.f82_tint_B(b, np.minimum(tint, 1.0))
    F_metal = b + (1 - b) * (1 - c) ** 5 - B * c * (1 - c) ** 6
    f = m * F_metal * f_ss * energy(b + (1 - b) / 21 - B / 126)
    f0, eta = pr.dielectric_f0_eta(d["ior"], d["specular_ior_level"])
    if eta == 1.0:                          # no specular layer
        return f + (1 - m) * b / np.pi
    f0t = np.clip(f0 * tint, 0, 1)
    F0_eta = pr.F0_from_ior(eta)
    Fss = f0t + (1 - f0t) * np.clip((pr.fresnel_dielectric_Fss(eta) - F0_eta) / (1 - F0_eta), 0, 1)
    f = f + (1 - m) * (f0t + (1 - f0t) * pr.real_curve_s(c, eta)) * f_ss * energy(Fss)
    A = f0t + (1 - f0t) * pr.gen_schlick_ior_s(r, mu, eta)[..., None]            # closure_layering_weight
    if d["multiscatter"]:
        E = ms.ggx_E(rough, mu)[..., None]
        A = A * (E + ms.F_ms(Fss, Ea) * (1 - E))
    return f + (1 - m) * b * np.clip(1 - A.max(-1), 0, 1)[..., None] / np.pi


@pytest.mark.parametrize("k", range(len(PRINCIPLED)))
def test_principled_matches_cycles_written_out(k):
    """eval_material of a Principled dict = the BSDF written out from Cycles (rtol 1e-9: only rounding differs —
    GGX from vectors here, from cosines in ``brdfs``), 2000 random light/view pairs, 10 % within 1° of the horizon."""
    rng = np.random.default_rng(k)
    light, view = _directions(rng, 2000, 0.1), _directions(rng, 2000, 0.1)
    mat = {"model": "principled", **PRINCIPLED[k]}
    got = brdfs.eval_material(mat, np.array([0.0, 0.0, 1.0]), light, view)
    want = _principled_reference(mat, light, view)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())


MATERIALS = [{"model": "principled", **p} for p in PRINCIPLED] + [
    {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.25, "fresnel": "none", "multiscatter": True,
     "F0": (1.0, 0.5, 0.2), "ks": 0.8, "kd": 0.1},                                  # Multiscatter Glossy
    {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": (0.9, 0.5, 0.2)},
    {"model": "cook_torrance", "distribution": "beckmann", "alpha": 0.3, "F0": 0.4},
    {"model": "cook_torrance", "distribution": "beckmann_smith", "alpha": 0.3, "F0": (0.9, 0.5, 0.2), "fresnel": "none"},
]


@pytest.mark.parametrize("k", range(len(MATERIALS)))
def test_shared_terms_give_each_lobes_own_value(k):
    """One batch of terms for all lobes (eval_material) = the lobes evaluated one by one (each with its own terms),
    at random facet normals x lights x views (50 x 40 x 30, lights and views below some facets: those entries 0),
    to 1e-12; and the terms are made once per batch, not once per lobe (a Lambert alone has none)."""
    rng = np.random.default_rng(100 + k)
    unit = lambda n: (lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True))(rng.normal(size=(n, 3)))  # noqa: E731
    n, wi, wo = unit(50)[:, None, None], unit(40)[None, :, None], unit(30)[None, None, :]
    lobes = brdfs.material_lobes(MATERIALS[k])
    ci, co, cio = (np.sum(a * b, -1) for a, b in ((n, wi), (n, wo), (wi, wo)))
    ok = (ci > 0) & (co > 0)
    ci_, co_ = np.where(ok, ci, 1.0), np.where(ok, co, 1.0)
    one_by_one = sum(np.where(ok, lb.f(ci_, co_, cio), 0.0)[..., None] * np.asarray(lb.colour) for lb in lobes)
    shared = [lb.shared for lb in lobes if lb.shared is not None]
    made = []

    def counted(ci, co, cio):
        made.append(1)
        return shared[0](ci, co, cio)
    counted_lobes = [brdfs.Lobe(lb.key, lb.f, lb.colour, lb.reciprocal, counted if lb.shared else None, lb.of_shared)
                     for lb in lobes]
    got = brdfs.eval_material(counted_lobes, n, wi, wo)
    np.testing.assert_allclose(got, one_by_one, rtol=1e-12, atol=1e-14 * np.abs(one_by_one).max())
    one = brdfs.eval_material(MATERIALS[k], n[7, 0, 0], wi[0, 11, 0], wo[0, 0, 13])    # single vectors (0-d cosines)
    np.testing.assert_allclose(one, got[7, 11, 13], rtol=1e-12, atol=1e-14 * np.abs(one_by_one).max())
    assert len(set(shared)) == min(len(shared), 1) and len(made) == min(len(shared), 1), (len(shared), len(made))


def test_one_table_read_serves_both_tables():
    """``lookup.lookup_table_read_2D`` (Cycles' bilinear read) returns the node values on the nodes and is linear
    between them along each axis, for the 32² E table and a 16² slice of the S table; ``gen_schlick_ior_s`` is
    linear in z between two slices."""
    E = ms.ggx_E_table()[0]
    i = np.arange(32)
    np.testing.assert_array_equal(ms.ggx_E(i[:, None] / 31, i[None, :] / 31), E)
    x = (7 + 0.3) / 31
    np.testing.assert_allclose(ms.ggx_E(x, 5 / 31), 0.7 * E[7, 5] + 0.3 * E[8, 5], rtol=1e-12)
    np.testing.assert_allclose(ms.ggx_E(2.0, -1.0), E[31, 0])                     # clamped to [0, 1]
    ior = 1.45
    k, t = lookup.lookup_index(np.sqrt((ior - 1) / (ior + 1)), pr.S_TABLE)
    S0, S1 = pr._s_slice(int(k)), pr._s_slice(int(k) + 1)
    j = np.arange(16)
    np.testing.assert_allclose(pr.gen_schlick_ior_s(j[:, None] / 15, j[None, :] / 15, ior),
                               (1 - t) * S0 + t * S1, rtol=1e-12)
    y = (3 + 0.25) / 15
    np.testing.assert_allclose(lookup.lookup_table_read_2D(S0, 4 / 15, y), 0.75 * S0[4, 3] + 0.25 * S0[4, 4],
                               rtol=1e-12)
