"""Bad numeric input to the science layer (issue #14, items 3-4): a ValueError naming the parameter, or a
finite documented value -- never an IndexError/TypeError, NaN or a silent wrong answer.

Each case failed before the fix (IndexError, TypeError, NaN, or a message without the parameter's name).
"""
import numpy as np
import pytest

from scratch_materials.precompute.cycles import beckmann
from scratch_materials.precompute.iridescence import scratch_set
from scratch_materials.precompute.microgeometry import ellipsoid, heightfield, synthesis
from scratch_materials.precompute.scratch import fresnel, layers, lobe_table, profiles
from scratch_materials.precompute.scratch.brdf import simulate


@pytest.fixture(scope="module")
def brdf():
    return simulate(profiles.quartic(0.3, segments=64), 16, fresnel.conductor(0.2, 3.0))


@pytest.mark.parametrize("call, name", [
    (lambda b: b.eval(np.nan, 0.1, 0.2), "theta_o"),
    (lambda b: b.eval(0.1, [0.0, np.nan], 0.2), "phi_o"),
    (lambda b: b.eval(0.1, 0.2, np.inf), "phi_i"),
    (lambda b: b.pdf(np.nan, 0.2), "phi_o"),
    (lambda b: b.pdf(0.1, np.nan), "phi_i"),
    (lambda b: b.sample(np.nan, 0.5), "phi_o"),
    (lambda b: b.sample(0.1, np.nan), "u"),
    (lambda b: b.sample(0.1, 1.5), "u"),
])
def test_nan_angles_name_the_parameter(brdf, call, name):
    with pytest.raises(ValueError, match=name):
        call(brdf)


def test_below_horizon_is_a_documented_zero(brdf):
    """|phi| > pi/2 is a direction below the scratch's surface: eval and pdf give 0 (docstrings)."""
    assert np.all(brdf.eval(0.2, [2.0, 0.3], [0.3, -2.0]) == 0.0)
    assert np.all(brdf.pdf([0.1, 0.1], [1.7, -3.0]) == 0.0)


def test_exact_conductor_finite_at_grazing_for_n1_k0():
    """n = 1, k = 0 (no interface): F = 0 at every angle except exactly grazing, where every Fresnel -> 1."""
    F = fresnel.conductor(1.0, 0.0)(np.array([0.0, 1e-300, 1e-10, 0.5, 1.0]))
    assert np.all(np.isfinite(F)) and np.all((F >= 0) & (F <= 1))
    np.testing.assert_allclose(F[2:, 0], 0.0, atol=1e-12)


def test_beckmann_finite_just_above_the_horizon():
    """D -> 0 as m_z -> 0+ (exp(-tan^2/alpha^2) beats 1/cos^4); was 0/0 = NaN for m_z ~ 1e-170."""
    for mz in (1e-170, 1e-100, 1e-10, 1e-3):
        H = np.array([[np.sqrt(1 - mz * mz), 0.0, mz]])
        d = beckmann.beckmann_aniso_D(0.3, 0.5, H)
        assert np.all(np.isfinite(d)) and np.all(d >= 0)
    assert beckmann.beckmann_aniso_D(0.3, 0.5, np.array([[1.0, 0.0, 1e-170]]))[0] == 0.0
    m = np.array([[np.sqrt(1 - 1e-340), 0.0, 1e-170], [0.0, 0.0, 1.0]])
    d = ellipsoid.beckmann_ndf(m, 0.3, 0.5)
    assert np.all(np.isfinite(d)) and d[0] == 0.0
    # and unchanged where it was finite: D(n) = 1 / (pi ax ay)
    np.testing.assert_allclose(d[1], 1 / (np.pi * 0.15), rtol=1e-12)


@pytest.mark.parametrize("theta_z", [np.nan, np.inf, "x", None])
def test_theta_z_validated(theta_z):
    m = np.array([[0.0, 0.0, 1.0]])
    for f in (ellipsoid.ggx_ndf, ellipsoid.beckmann_ndf):
        with pytest.raises(ValueError, match="theta_z"):
            f(m, 0.3, 0.4, theta_z)


@pytest.mark.parametrize("n_nodes", [1, 0, -3, 2.5, "96", True])
def test_fit_ellipsoid_n_nodes(n_nodes):
    from scratch_materials.precompute.microgeometry.ndf import naive_ndf

    ndf = naive_ndf(heightfield.gaussian_surface((32, 32), 0.5, 0.2, 2.0, seed=1), resolution=65)
    with pytest.raises(ValueError, match="n_nodes"):
        ellipsoid.fit_ellipsoid(ndf, n_nodes=n_nodes)


def test_tabulated_nearly_coincident_x():
    """x = [0, 1e-17, ...] used to give a non-increasing normalised x; now refused, naming x."""
    with pytest.raises(ValueError, match="x: points 0 and 1"):
        profiles.tabulated([0.0, 1e-17, 0.5, 1.0], [0.0, -0.1, -0.2, 0.0])
    p = profiles.tabulated([0.0, 1e-6, 0.5, 1.0], [0.0, -0.1, -0.2, 0.0])  # close but resolvable: kept
    assert np.all(np.diff(p.x) > 0)


@pytest.mark.parametrize("depth", [5e-324, 1e-300, 1e-12])
def test_circular_tiny_depth_rejected(depth):
    with pytest.raises(ValueError, match=r"depth: allowed range is \[1e-06, 0.5\]"):
        profiles.circular(depth)


def test_circular_smallest_depth_finite():
    p = profiles.circular(profiles.CIRCULAR_MIN_DEPTH)
    assert np.all(np.isfinite(p.h)) and np.all(np.diff(p.x) > 0)
    np.testing.assert_allclose(p.h.min() - p.h.max(), -profiles.CIRCULAR_MIN_DEPTH, rtol=1e-6)


@pytest.mark.parametrize("call, name", [
    (lambda: fresnel.lazanyi(1.5, 0.0, alpha="x"), "alpha"),
    (lambda: fresnel.lazanyi(1.5, 0.0, alpha=[1, 2]), "alpha"),
    (lambda: fresnel.lazanyi(1.5, 0.0, alpha=np.nan), "alpha"),
    (lambda: fresnel.schlick("x"), "ior"),
    (lambda: fresnel.schlick(None), "ior"),
    (lambda: fresnel.conductor("a", 1.0), "n"),
    (lambda: lobe_table.fit_bins(np.ones((3, 8)), [0.1]), "phi_o"),
    (lambda: lobe_table.fit_bins([1.0, 2.0], [0.0]), "rows"),
    (lambda: lobe_table.proposal(np.array([[np.nan, 1.0]])), "w_m"),
    (lambda: lobe_table.proposal(np.array([[1.0, 1.0]]), np.array([[[np.nan], [1.0]]])), "w_0"),
])
def test_messages_name_the_parameter(call, name):
    with pytest.raises(ValueError, match=name):
        call()


def test_lazanyi_numeric_string_is_read_as_a_number():
    """Like ``float('6')``: a numeric string is a number (the same model as alpha=6)."""
    assert fresnel.lazanyi(1.5, 0.0, alpha="6").alpha == fresnel.lazanyi(1.5, 0.0, alpha=6).alpha


P5 = np.tile([0.3, 0.3, 0.0, 0.0, 0.0], (4, 1))


@pytest.mark.parametrize("call", [
    lambda s: simulate(profiles.quartic(0.2), 8, method="mc", rays_per_slice=100, seed=s),
    lambda s: heightfield.gaussian_surface((16, 16), 0.5, 0.2, 2.0, seed=s),
    lambda s: scratch_set.random_scratches(3, seed=s),
    lambda s: layers.mean_coverage(np.array([0.1]), samples=1000, seed=s),
    lambda s: synthesis.synthesize_parameter_texture(P5, P5, (8, 8), seed=s),
])
@pytest.mark.parametrize("seed", [-1, 2.5, "7", 2**70])
def test_seeds(call, seed):
    with pytest.raises(ValueError, match="seed must be an integer in"):
        call(seed)
