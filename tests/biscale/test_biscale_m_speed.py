"""The faster M (Wu et al. 2011, eqs. 4, 9; issue 16, glossy pyramid bake 291 s): one microfacet evaluation
with the full Schlick term per grey-Fresnel Cook-Torrance lobe (was the F0 and the 1 parts separately), and
the exact pole column of M evaluated alone (was every row of M a second time).  Both give the old values."""
from __future__ import annotations

import numpy as np

from scratch_materials.precompute.biscale import brdfs
from scratch_materials.precompute.biscale.directions import direction_grid, normal_grid, pole_index
from scratch_materials.precompute.biscale.effective import _M_rows, precompute_M


def test_grey_schlick_lobe_is_the_sum_of_its_parts():
    rng = np.random.default_rng(0)
    ci, co = rng.uniform(0.01, 1, 500), rng.uniform(0.01, 1, 500)
    cio = rng.uniform(-1, 1, 500)
    for dist in ("ggx", "beckmann"):
        lobe = brdfs.material_lobes({"model": "cook_torrance", "distribution": dist, "alpha": 0.3, "F0": 0.4})[0]
        two = 0.4 * brdfs._microfacet(0.3, dist, "f0")(ci, co, cio) + brdfs._microfacet(0.3, dist, "one")(ci, co, cio)
        np.testing.assert_allclose(lobe(ci, co, cio), two, rtol=1e-9, atol=1e-12)


def test_pole_column_is_the_full_matrix_column():
    lobe = brdfs.material_lobes({"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": 1.0})[0]
    mf = precompute_M(lobe, dir_res=5, normal_res=9, l=40, use_cache=False)
    rows, K = _M_rows(lobe, direction_grid(5), normal_grid(9))
    np.testing.assert_allclose(mf.Mz, rows(0, K)[:, pole_index(9)], rtol=1e-6, atol=1e-7)
