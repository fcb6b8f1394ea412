"""Scratch profiles (Raymond et al. 2016, §5.3): analytic families, tabulated input, validation."""
import numpy as np
import pytest

from scratch_materials.precompute.scratch import profiles


def test_quartic_formula_and_range():
    p = profiles.quartic(0.3, segments=64)
    assert p.x[0] == -0.5 and p.x[-1] == 0.5 and np.all(np.diff(p.x) > 0)
    np.testing.assert_allclose(p.h, -0.3 * (1 - (2 * p.x) ** 2) ** 2, atol=1e-12)
    assert p.h.max() == 0.0 and abs(p.depth - 0.3) < 1e-12
    assert p.is_symmetric and np.array_equal(p.h, p.h[::-1]) and np.array_equal(p.x, -p.x[::-1])
    assert p.segments == 64


def test_v_groove_geometry():
    p = profiles.v_groove(30.0)
    wall = np.degrees(np.arctan2(0.5, p.depth))  # angle between wall and vertical
    assert abs(wall - 30.0) < 1e-9 and p.segments == 2
    assert profiles.v_groove(90).depth == 0.0


def test_circular_is_an_arc():
    p = profiles.circular(0.5, segments=32)
    np.testing.assert_allclose(p.x**2 + (p.h) ** 2, 0.25, atol=1e-12)  # semicircle centred at (0, 0)


@pytest.mark.parametrize("call", [
    lambda: profiles.quartic(-0.1), lambda: profiles.quartic(np.nan), lambda: profiles.quartic(0.2, segments=2),
    lambda: profiles.v_groove(0.5), lambda: profiles.v_groove(95), lambda: profiles.circular(0.0),
    lambda: profiles.circular(0.6),
])
def test_analytic_out_of_range(call):
    with pytest.raises(ValueError):
        call()


@pytest.mark.parametrize("x, h, word", [
    ([0.0], [0.0], "at least 2"),
    ([0, 1, np.nan], [0, -1, 0], "NaN"),
    ([0, 1, 2], [0, np.inf, 0], "NaN or inf"),
    ([1, 1], [0, -1], "zero width"),
    ([0, 2, 1, 3], [0, -1, -1, 0], "strictly increasing"),
    ([0, 1], [0, 0, 0], "lengths differ"),
])
def test_tabulated_invalid(x, h, word):
    with pytest.raises(ValueError, match=word):
        profiles.tabulated(x, h)


def test_tabulated_normalises_and_handles_bulges():
    x = np.array([10.0, 12.0, 15.0, 18.0, 20.0])
    h = np.array([0.0, 0.5, -2.0, 0.2, 0.0])  # bulges above the base surface
    p = profiles.tabulated(x, h)
    assert p.x[0] == -0.5 and p.x[-1] == 0.5
    assert p.h.max() == 0.0  # highest point becomes the base height
    np.testing.assert_allclose(p.h, (h - 0.5) / 10.0)  # aspect ratio kept (width 10)
    assert not p.is_symmetric
    v = p.periodic_vertices()
    np.testing.assert_allclose(v[-1], v[0] + [1.0, 0.0])


def test_tabulated_closing_step_and_symmetry_detection():
    p = profiles.tabulated([0, 1, 2], [0.0, -1.0, -0.5])
    v = p.periodic_vertices()
    assert v.shape == (4, 2) and v[-2, 0] == v[-1, 0]  # vertical step closes the period
    s = profiles.tabulated([-1, 0, 1], [0.0, -1.0, 0.0])
    assert s.is_symmetric


def test_from_file(tmp_path):
    f = tmp_path / "prof.csv"
    f.write_text("# measured\nx,height\n0,0\n1;-0.5\n2 -1\n3,0\n")
    p = profiles.from_file(f)
    assert p.segments == 3 and p.name == "prof"
    with pytest.raises(ValueError, match="no such file"):
        profiles.from_file(tmp_path / "missing.csv")
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0\n1 x\n")
    with pytest.raises(ValueError, match="not numeric"):
        profiles.from_file(bad)


def test_cache_key_distinguishes_profiles():
    from scratch_materials.precompute.tables.cache import content_key
    a = content_key("t", "1", {"p": profiles.quartic(0.2)})
    b = content_key("t", "1", {"p": profiles.quartic(0.2000001)})
    assert a != b and a == content_key("t", "1", {"p": profiles.quartic(0.2)})
