"""Closure fit of bi-scale effective BRDFs (precompute.biscale.effective.fit): cases Cycles represents exactly
must be recovered exactly; the Glossy-node parameter mapping must invert Cycles' own mapping."""
import numpy as np
import pytest

from scratch_materials.precompute.tables import cache
from scratch_materials.precompute.biscale.effective import BiscaleTile, EffectiveBRDF
from scratch_materials.precompute.biscale.directions import direction_grid
from scratch_materials.precompute.biscale.fit import ClosureFit, fit_closures, glossy_node_params, lobe_eval
from scratch_materials.precompute.biscale.geometry import flat_tile

SMALL = dict(n_facets=500, dir_res=6, normal_res=41, l_M=120)


@pytest.fixture(autouse=True, scope="module")
def _cache_dir(tmp_path_factory):
    cache.set_cache_dir(tmp_path_factory.mktemp("biscale_fit_cache"))
    yield
    cache.set_cache_dir(None)


def _flat(mats):
    t = flat_tile()
    return BiscaleTile(t.vertices, t.faces, t.face_material, **SMALL).effective_brdf(mats)


def test_flat_lambert_fits_exactly_with_diffuse_only():
    fit = fit_closures(_flat([{"model": "lambert", "albedo": (0.2, 0.5, 0.7)}]), n_lobes=3)
    np.testing.assert_allclose(fit.diffuse, (0.2, 0.5, 0.7), rtol=1e-6)
    assert fit.lobes == [] and fit.rel_l1 < 1e-6


def test_flat_ggx_recovers_the_cycles_lobe():
    """A flat tile of GGX (F0 = 1) is exactly Cycles' GGX closure: D G2 / (4 cos θo) = f cos θi."""
    fit = fit_closures(_flat([{"model": "cook_torrance", "alpha": 0.3, "F0": 1.0, "distribution": "ggx"}]),
                       n_lobes=2, max_nfev=30)
    assert fit.psnr > 50 and fit.rel_l1 < 0.01
    main = max(fit.lobes, key=lambda lb: lb.colour.sum())
    assert main.tilt < 0.02
    assert main.alpha_x == pytest.approx(0.3, rel=0.02) and main.alpha_y == pytest.approx(0.3, rel=0.02)
    np.testing.assert_allclose(main.colour, 1.0, rtol=0.02)


def test_synthetic_tilted_anisotropic_lobe_is_recovered():
    """Table built from a known diffuse + one tilted anisotropic Cycles lobe (independent of the tile
    pipeline): the fit reproduces it (PSNR >= 35 dB)."""
    res = 8
    d = direction_grid(res)
    D = len(d)
    i, o = np.meshgrid(np.arange(D), np.arange(D), indexing="ij")
    wi, wo = d[i.ravel()], d[o.ravel()]
    fcos = 0.1 * wi[:, 2] / np.pi + 0.6 * lobe_eval(0.35, 0.5, 0.3, 0.08, 0.3, wi, wo)
    table = np.repeat((fcos / wi[:, 2]).reshape(D, D, 1), 3, axis=2)
    fit = fit_closures(EffectiveBRDF(table, res), n_lobes=2, max_nfev=60)
    assert fit.psnr >= 35, fit.psnr
    np.testing.assert_allclose(fit.eval_cos(wi, wo)[:, 0], fcos, atol=0.05 * fcos.max())


@pytest.mark.parametrize("ax, ay", [(0.3, 0.3), (0.05, 0.4), (0.5, 0.02), (1.0, 1.0)])
def test_glossy_node_params_invert_cycles_mapping(ax, ay):
    r, an = glossy_node_params(ax, ay)
    a = r * r  # node_glossy_bsdf.osl
    if an >= 0:
        bx, by = a * (1 - an), a / (1 - an)
    else:
        bx, by = a / (1 + an), a * (1 + an)
    np.testing.assert_allclose([bx, by], [ax, ay], rtol=1e-9)


def test_bad_inputs():
    with pytest.raises(ValueError, match="alpha_x"):
        glossy_node_params(0.0, 0.3)
    with pytest.raises(ValueError, match="n_lobes"):
        fit_closures(EffectiveBRDF(np.zeros((36, 36, 3)), 6), n_lobes=-1)
    with pytest.raises(ValueError, match="table"):
        fit_closures(EffectiveBRDF(np.zeros((10, 10, 3)), 6))
    assert isinstance(fit_closures(EffectiveBRDF(np.zeros((36, 36, 3)), 6), n_lobes=1), ClosureFit)
