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


def test_rougher_surface_at_grazing_view_needs_multiple_scattering(addon, scene, render_dir):
    """The rougher brushed scan (rms 0.5 µm, correlation 6 x 1.5 µm) at 70° across the scratches on Cycles SVM
    (the default): the NDF table with multiple scattering (the material's default) keeps the explicit mirror surface's
    albedo 1.00 within 2 % and its E[dy²] within 0.013 (the goal 0.01 is the bench's, 64 px x 32 spp: 0.0073; here
    measured 0.0045); the single-scattering table (``multiple_scattering=False``) renders albedo 0.91 and misses by
    0.0125 here (the session-8 material: 0.89 and 0.0199 in the bench), at least 0.005 more than the new table, so
    the bounds can fail.  32 px x 8 spp, ~25 s (the walk is computed once per session cache)."""
    import importlib as il

    for name in ("biscale_truth", "microgeometry_truth"):
        il.import_module(f"{addon.__name__}.{name}")
    mg = il.import_module(addon.__name__ + ".microgeometry_ops")
    view = (70.0, 90.0)
    hf, smooth = mt.surface(mt.SURFACES["rougher"])
    path = str(render_dir / "rougher.npy")
    np.save(path, hf.heights)

    def factory(ms):
        return lambda: mg.material_from_heightfield(path, hf.pixel_um, mt.SIGMA_UM, ndf_model="TABLE",
                                                    color=(1, 1, 1), multiple_scattering=ms)[0]
    mats = {"table": factory(True), "single": factory(False)}
    e = mt.moments(addon, "explicit", [view], hf, smooth, spp=8, res=32, tmp=str(render_dir))[0][view]
    t = mt.moments(addon, "table_svm", [view], hf, smooth, mats, spp=8, res=32, tmp=str(render_dir))[0][view]
    s = mt.moments(addon, "table_svm", [view], hf, smooth, {"table": mats["single"]}, spp=8, res=32,
                   tmp=str(render_dir))[0][view]
    assert abs(t[2] - e[2]) < 0.013 and abs(t[1] - e[1]) < 0.013, (t, e)
    assert abs(t[0] - e[0]) < 0.02, (t, e)
    assert s[0] < 0.95 and abs(s[2] - e[2]) > abs(t[2] - e[2]) + 0.005, (s, t, e)
