"""An independent check of the ground-truth tier (issue #15): a profile, a conductor and views that the tier's own
test (test_scratch_truth.py) does not use.

The asymmetric sawtooth (a tabulated profile: a gentle wall 27 deg and a steep wall 63 deg from the surface,
``bench.scratch_truth_audit.sawtooth``) is the profile where a wrong orientation of the table would show: its
exit distribution is not symmetric about the normal, so mirroring the profile (or the view) changes E[d]
across the scratch.  The views have azimuths beyond 90 deg from the scratch, on both sides of the profile
(50/120: the view leans towards +v, 40/240: towards -v, the other half of the table's view angles), which go
through the material's mirror handling of the view; copper is a coloured conductor other than the tier's gold
(at 40/240 its blue albedo is 0.31 against 0.88 in red: the sawtooth inter-reflects).

Explicit grooves path traced by Cycles (``bench.scratch_truth``) against the material on a flat plane, OSL path
and SVM twin; the worlds give the albedo A and the moments E[d], E[d²] of the exit direction.  The second test
shows that the first can fail: the material built from the mirrored sawtooth (a deliberately wrong table) is
far outside the same tolerance.
"""
import numpy as np
import pytest

from bench import scratch_truth as st
from bench import scratch_truth_audit as au

pytestmark = [pytest.mark.bpy, pytest.mark.render]

RES, SPP = 32, 16


def _tolerance_ok(e):
    # goal 1 % (x100 <= 1) + 3 sigma of the measured noise (quadrants of material - truth)
    return (e["A"] < 0.01 + 3 * e["noise_A"] and e["m1"] < 0.01 + 3 * e["noise_m1"]
            and e["m2"] < 0.01 + 3 * e["noise_m2"])


@pytest.mark.parametrize("case, view", [("sawtooth", "50/120"), ("sawtooth_copper", "40/240")])
def test_asymmetric_tabulated_profile_matches_explicit_grooves(addon, scene, case, view):
    c = au.audit_cases(addon, [case])[0]
    ts = st.TruthScene(addon, c, res=RES, samples=SPP)
    meas = st.measure_view(ts, au.VIEWS[view], ("truth", "osl", "svm"), worlds=st.WORLDS)
    truth = meas["truth"]
    if c.fresnel is None:
        np.testing.assert_allclose(truth["A"], 1.0, atol=2e-3)       # a lossless mirror keeps everything
    else:
        assert truth["A"][0] > truth["A"][2] + 0.2                   # copper: red well above blue
    for path in ("osl", "svm"):
        e = st.errors(meas, path)
        print(case, view, path, {k: round(v, 5) for k, v in e.items()})
        # the noise must stay well below the goal so that the test has power.  Measured at 32 px x 16 spp: noise
        # 0.03-0.26, errors 0.09 (lossless 50/120) and 0.68-0.72 (copper 40/240; 0.31 at 64 spp, 0.06-0.14 at
        # 64 px x 32 spp in bench/out/scratch_truth_audit.md: sampling error the 4-quadrant sigma underestimates)
        assert max(e["noise_A"], e["noise_m1"], e["noise_m2"]) < 0.005, e
        assert _tolerance_ok(e), (path, e)


def test_mirrored_table_fails_the_same_check(addon, scene):
    """The check has power: the material of the mirrored sawtooth against the sawtooth's grooves."""
    c = au.audit_cases(addon, ["sawtooth"])[0]
    ts = st.TruthScene(addon, c, res=RES, samples=SPP)
    profiles = st.science(addon, "profiles")
    mirrored = profiles.tabulated(-c.profile.x[::-1], c.profile.h[::-1], name="sawtooth mirrored")
    sm = addon.scratch_material
    params = sm.validate(profile=mirrored, fresnel=None, layers=None, base="mirror")
    ts.plane.data.materials[0] = sm.build(addon.materials.new_material("Scratch mirrored"), params)
    meas = st.measure_view(ts, au.VIEWS["20/60"], ("truth", "svm"), worlds=st.WORLDS)
    e = st.errors(meas, "svm")
    print("mirrored", {k: round(v, 5) for k, v in e.items()})
    assert not _tolerance_ok(e), e
    assert e["m1"] > 0.05, e
