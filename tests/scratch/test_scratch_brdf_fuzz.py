"""Hypothesis fuzz of the scratch BRDF over profile shapes, depths, IORs and grazing angles."""
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from scratch_materials.precompute.scratch import fresnel, profiles
from scratch_materials.precompute.scratch.brdf import bin_cos_integrals, simulate

heights = st.lists(st.floats(-3.0, 1.0, allow_nan=False, allow_infinity=False), min_size=2, max_size=25)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(h=heights, width=st.floats(0.05, 20.0), seed=st.integers(0, 2**16), ior=st.floats(1.01, 4.0),
       k=st.floats(0.0, 6.0), M=st.sampled_from([8, 12, 16]),
       theta=st.floats(-np.pi / 2, np.pi / 2), phi=st.floats(-np.pi / 2, np.pi / 2))
def test_random_tabulated_profiles(h, width, seed, ior, k, M, theta, phi):
    rng = np.random.default_rng(seed)
    x = np.sort(rng.uniform(0.0, width, len(h)))
    x[0], x[-1] = 0.0, width
    if np.any(np.diff(x) <= 0):
        x = np.linspace(0.0, width, len(h))
    prof = profiles.tabulated(x, h)
    b = simulate(prof, M, fresnel.conductor(ior, k))
    C = bin_cos_integrals(M)
    for a in (b.rho0, b.rho_m, b.gamma):
        assert np.all(np.isfinite(a))
    assert b.rho_m.shape == (M, M)  # scalar n, k: mono
    e_m = np.tensordot(C, b.rho_m.astype(np.float64), axes=(0, 0))
    assert np.all(np.abs(e_m - 1.0) < 5e-3 + b.lost)  # lossless slice conserves energy
    e_0 = np.tensordot(C, b.rho0.astype(np.float64), axes=(0, 0))
    assert np.all(e_0 <= 1 + 1e-5)  # Fresnel never adds energy
    v = b.eval(theta, phi, -phi)
    assert np.all(np.isfinite(v)) and np.all(v >= 0)
    u = rng.random(4)
    phi_i, pdf = b.sample(np.full(4, phi), u)
    assert np.all(np.isfinite(phi_i)) and np.all(np.abs(phi_i) <= np.pi / 2) and np.all(np.isfinite(pdf))


@settings(max_examples=15, deadline=None)
@given(depth=st.floats(0.0, 2.0), angle=st.floats(2.0, 90.0), ior=st.floats(1.0001, 3.0),
       M=st.sampled_from([6, 9, 16]))
def test_analytic_families_and_dielectrics(depth, angle, ior, M):
    for prof in (profiles.quartic(depth, segments=32), profiles.v_groove(angle)):
        b = simulate(prof, M, fresnel.schlick(ior))
        assert b.rho0.shape == (M, M) and np.all(np.isfinite(b.rho0)) and np.all(np.isfinite(b.gamma))
        e = np.tensordot(bin_cos_integrals(M), b.rho_m.astype(np.float64), axes=(0, 0))
        assert np.all(np.abs(e - 1.0) < 5e-3 + b.lost)
        assert b.lost < 1e-3
