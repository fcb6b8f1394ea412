"""Height-field readers, validation and the seeded synthetic surfaces (issue items 1 and 7)."""
import numpy as np
import pytest

from scratch_materials.precompute.microgeometry.heightfield import (HeightField, HeightFieldError, detilt, gaussian_surface,
                                                  load_heightfield, save_heightfield, spectral_slope_covariance)


def grid_with_nan(seed=0):
    h = np.random.default_rng(seed).normal(size=(7, 9)) * 0.1
    h[2, 3] = np.nan
    return h


def test_npy_npz_roundtrip(tmp_path):
    h = grid_with_nan()
    np.save(tmp_path / "a.npy", h)
    hf = load_heightfield(tmp_path / "a.npy", pixel_um=0.11)
    np.testing.assert_array_equal(hf.heights, h)
    assert hf.pixel_um == 0.11 and hf.missing_fraction == pytest.approx(1 / 63)
    save_heightfield(tmp_path / "b.npz", hf)
    hf2 = load_heightfield(tmp_path / "b.npz")  # pixel size stored in the file
    np.testing.assert_array_equal(hf2.heights, h)
    assert hf2.pixel_um == 0.11
    assert load_heightfield(tmp_path / "b.npz", pixel_um=0.2).pixel_um == 0.2  # explicit override


def test_exr_roundtrip(tmp_path):
    h = grid_with_nan().astype(np.float32)
    save_heightfield(tmp_path / "a.exr", HeightField(h, 0.25))
    hf = load_heightfield(tmp_path / "a.exr")
    np.testing.assert_array_equal(hf.heights, h.astype(np.float64))
    assert hf.pixel_um == 0.25 and np.isnan(hf.heights[2, 3])


def test_text_grids(tmp_path):
    (tmp_path / "a.txt").write_text("# scan\n1 2 3\n4 nan 6\n")
    (tmp_path / "b.csv").write_text("1,2,3\n4,,6\n")
    for name in ("a.txt", "b.csv"):
        hf = load_heightfield(tmp_path / name, pixel_um=1.0, height_scale=1e-3)  # nm -> µm
        assert hf.shape == (2, 3) and np.isnan(hf.heights[1, 1])
        assert hf.heights[1, 2] == pytest.approx(0.006)


@pytest.mark.parametrize("content,match", [("1 2\n3\n", "ragged"), ("1 a\n2 3\n", "non-numeric"), ("", "empty")])
def test_bad_text(tmp_path, content, match):
    (tmp_path / "x.txt").write_text(content)
    with pytest.raises(HeightFieldError, match=match):
        load_heightfield(tmp_path / "x.txt", pixel_um=1)


def test_bad_files_and_arrays(tmp_path):
    with pytest.raises(HeightFieldError, match="no such file"):
        load_heightfield(tmp_path / "missing.npy", pixel_um=1)
    (tmp_path / "bad.npy").write_bytes(b"not numpy")
    with pytest.raises(HeightFieldError, match="unreadable"):
        load_heightfield(tmp_path / "bad.npy", pixel_um=1)
    (tmp_path / "bad.exr").write_bytes(b"not exr")
    with pytest.raises(ValueError):
        load_heightfield(tmp_path / "bad.exr", pixel_um=1)
    np.save(tmp_path / "one.npy", np.zeros(5))
    with pytest.raises(HeightFieldError, match="2D"):
        load_heightfield(tmp_path / "one.npy", pixel_um=1)
    np.save(tmp_path / "ok.npy", np.zeros((3, 3)))
    with pytest.raises(HeightFieldError, match="pixel_um"):
        load_heightfield(tmp_path / "ok.npy")
    with pytest.raises(HeightFieldError, match="format"):
        load_heightfield((tmp_path / "ok.npy").rename(tmp_path / "ok.foo"), pixel_um=1)
    (tmp_path / "scan.sur").write_bytes(b"\0" * 10)
    with pytest.raises(HeightFieldError, match="surfalize"):
        load_heightfield(tmp_path / "scan.sur", pixel_um=1)
    with pytest.raises(HeightFieldError, match="missing"):
        HeightField(np.full((4, 4), np.nan), 1.0)
    with pytest.raises(HeightFieldError, match="2x2"):
        HeightField(np.zeros((1, 8)), 1.0)
    with pytest.raises(HeightFieldError, match="pixel_um"):
        HeightField(np.zeros((4, 4)), -1.0)
    with pytest.raises(HeightFieldError, match="dtype"):
        HeightField(np.array([["a", "b"], ["c", "d"]]), 1.0)
    hf = HeightField(np.array([[0, np.inf], [1, 2]]), 1.0)  # inf is a missing point
    assert np.isnan(hf.heights[0, 1])


def test_detilt_removes_plane_exactly():
    y, x = np.mgrid[0:40, 0:50] * 0.5
    bump = np.sin(x) * np.cos(1.3 * y) * 0.01
    h = 3.0 + 0.2 * x - 0.1 * y + bump
    h[5:8, 5:9] = np.nan
    out = detilt(h, 0.5)
    ok = np.isfinite(out)
    # the least-squares residual is orthogonal to 1, x, y -> no remaining tilt
    for g in (np.ones_like(x), x, y):
        assert abs(np.sum(out[ok] * g[ok])) < 1e-9 * np.sum(np.abs(g[ok]))
    assert np.std(out[ok]) < 0.02


def test_gaussian_surface_known_statistics():
    # exact amplitudes + random phases: rms height exact, slope variance 2 s^2 / l^2 (continuum)
    s, l, pix = 0.2, 4.0, 0.25
    hf = gaussian_surface((512, 512), pix, s, l, seed=3)
    assert np.sqrt(np.mean(hf.heights**2)) == pytest.approx(s, rel=1e-12)
    C = spectral_slope_covariance(hf.heights, pix)
    # the periodic domain samples the spectrum at 2 pi / L; with L / l = 32 the discrete slope
    # variance matches the continuum value to ~0.3 % (at L / l = 8 it is 5 % off), so 2 % is safe
    np.testing.assert_allclose(np.diag(C), 2 * s * s / l**2, rtol=0.02)
    # finite differences of the surface agree with the spectral slopes (l >> pixel)
    fd = np.diff(hf.heights, axis=1) / pix
    assert np.mean(fd**2) == pytest.approx(C[0, 0], rel=0.01)
    a = gaussian_surface((64, 64), 0.1, 0.1, (8.0, 0.5), seed=1)
    Ca = spectral_slope_covariance(a.heights, 0.1)
    assert Ca[1, 1] > 50 * Ca[0, 0]  # brushed: slopes across the scratches dominate
    assert np.array_equal(gaussian_surface((16, 16), 0.1, 0.1, 1.0, seed=5).heights,
                          gaussian_surface((16, 16), 0.1, 0.1, 1.0, seed=5).heights)
