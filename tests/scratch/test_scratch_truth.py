"""Ground-truth tier (issue #15): the scratch material against Cycles path tracing explicit grooves.

A plane carrying ~500 parallel explicit grooves of the same profile (``precompute.scratch.explicit``, 15 per
pixel, orthographic, whole groove periods in the frame) under environments whose colour encodes the exit
direction d, so that image means are the albedo A and the moments E[d], E[d²] (``bench.scratch_truth``),
against the material on a flat plane, on the OSL path and on its SVM twin.  The views are those of the
issue where main erred: V-groove straight down (the exit peak smeared across the scratch: |ΔE[d²]| 0.030,
|ΔE[d]| 0.020 measured on main) and gold on a V-groove at 60 deg from the normal, 30 deg from the scratch
(albedo 7.0 % off on main, 4.2 % in E[d]); plus gold quartic across the scratch.  ``bench/scratch_truth``
holds the full table (more views, profiles, the studio world and a lamp).
"""
import numpy as np
import pytest

from bench import scratch_truth as st

pytestmark = [pytest.mark.bpy, pytest.mark.render]

RES, SPP = 32, 16


@pytest.mark.parametrize("case, view", [("v30", "down"), ("v30_gold", "oblique60/30"), ("q05_gold", "across45")])
def test_material_matches_explicit_grooves(addon, scene, case, view):
    c = st.cases(addon, [case])[0]
    ts = st.TruthScene(addon, c, res=RES, samples=SPP)
    meas = st.measure_view(ts, st.VIEWS[view], ("truth", "osl", "svm"), worlds=st.WORLDS)
    truth = meas["truth"]
    # the truth is what it should be: a mirror reflects everything, gold less in blue than in red
    if c.fresnel is None:
        np.testing.assert_allclose(truth["A"], 1.0, atol=2e-3)
    else:
        assert truth["A"][0] > truth["A"][2] + 0.1
    for path in ("osl", "svm"):
        e = st.errors(meas, path)
        print(case, view, path, {k: round(v, 5) for k, v in e.items()})
        # measured 1-sigma noise of the means at 32 px x 16 spp: 0.01-0.7 % (quadrants of the image); the
        # goal is 1 %: tolerance 1 % + 3 sigma, and the noise must stay below the errors main made (2-7 %)
        assert e["noise_A"] < 0.005 and e["noise_m1"] < 0.01 and e["noise_m2"] < 0.005, e
        assert e["A"] < 0.01 + 3 * e["noise_A"], (path, e)
        assert e["m1"] < 0.01 + 3 * e["noise_m1"], (path, e)
        assert e["m2"] < 0.01 + 3 * e["noise_m2"], (path, e)
