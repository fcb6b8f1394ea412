"""Ground truth for the Dong NDF materials (issue 16 item 4): Cycles path tracing the explicit surface
(the brushed height field smoothed by the §5.1 sigma filter, a flat-shaded mirror instanced ~100 periods
across the frame) vs *Material from Height Field* on the same scan (NDF Model Table and Ellipsoid).
Metric: the second moments E[dx²], E[dy²] of the exit direction (direction-coded d² world over a white
world), at normal view and 70° across the scratches.  Scenes from ``bench/microgeometry_truth``."""
from __future__ import annotations

import importlib

import numpy as np
import pytest

from bench import microgeometry_truth as mt

pytestmark = [pytest.mark.bpy, pytest.mark.render]


def test_ndf_table_matches_the_explicit_surface_and_the_ellipsoid_does_not(addon, scene, render_dir):
    """The NDF table is within 0.01 of the explicit surface's second moments at normal view and 70°
    across the scratches (the issue's goal; bench at 64 px x 16 spp: 0.0023 and 0.0096); the ellipsoid
    fit is not (measured 0.031 / 0.070: its GGX lobe spreads light about twice as wide), so the bound can
    fail.  32 px x 8 spp: the bench's 32 px x 8 spp and 64 px x 16 spp runs differ by <= 2e-4 (normal view)."""
    for name in ("biscale_truth", "microgeometry_truth"):
        importlib.import_module(f"{addon.__name__}.{name}")
    views = [(0.0, 0.0), (70.0, 90.0)]
    hf, smooth = mt.surface()
    mats, _ = mt.build_materials(addon, hf, str(render_dir))
    res = {kind: mt.moments(addon, kind, views, hf, smooth, mats, spp=8, res=32, tmp=str(render_dir))[0]
           for kind in ("explicit", "table", "ellipsoid")}
    for v in views:
        e, t, el = (np.array(res[k][v][1:3]) for k in ("explicit", "table", "ellipsoid"))
        assert np.abs(t - e).max() < 0.01, (v, t, e)
        assert np.abs(el - e).max() > 0.02, (v, el, e)
    assert res["explicit"][(0.0, 0.0)][1] < 0.5 * res["explicit"][(0.0, 0.0)][2]     # brushed: narrow along x
