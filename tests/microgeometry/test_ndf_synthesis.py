"""§9 texture synthesis: per-texel ellipsoid fits, separable random-phase synthesis, EXR I/O."""
import os

import numpy as np
import pytest

from scratch_materials.precompute.microgeometry.ellipsoid import rotation_matrix
from scratch_materials.precompute.microgeometry.heightfield import HeightField, gaussian_surface
from scratch_materials.precompute.microgeometry.synthesis import (CHANNELS, load_parameter_texture, save_parameter_texture,
                                                synthesize_from_strips, synthesize_parameter_texture,
                                                texel_ellipsoid_params)


def test_texel_fits_recover_known_skew():
    # a known tilt (no detilt) shifts every texel's NDF peak to m0 = (-0.05, 0.03, 1)/|.|;
    # the ellipsoid's peak is R^T z (§8), so the fitted thetas must point there
    base = gaussian_surface((64, 512), 0.2, 0.1, 3.0, seed=2)
    y, x = np.mgrid[0:64, 0:512] * 0.2
    hf = HeightField(base.heights + 0.05 * x - 0.03 * y, 0.2)
    params, mean = texel_ellipsoid_params(hf, texel_um=12.8, detilt=False)
    assert params.shape == (1, 8, 5)
    R = rotation_matrix(params[..., 2], params[..., 3], params[..., 4]).reshape(-1, 3, 3)
    peaks = R.transpose(0, 2, 1)[:, :, 2]
    m0 = np.array([-0.05, 0.03, 1.0]) / np.linalg.norm([-0.05, 0.03, 1.0])
    # each 12.8 µm texel holds ~18 correlation areas: its own mean slope scatters by ~0.1/sqrt(18)
    # around the tilt; the average over 8 texels is within 0.01
    assert np.linalg.norm(peaks.mean(0) - m0) < 0.01
    # detilted: the mean peak returns to n
    p2, _ = texel_ellipsoid_params(hf, texel_um=12.8, detilt=True)
    R2 = rotation_matrix(p2[..., 2], p2[..., 3], p2[..., 4]).reshape(-1, 3, 3)
    assert np.linalg.norm(R2.transpose(0, 2, 1)[:, :, 2].mean(0) - [0, 0, 1]) < 0.01


def test_synthesis_statistics_and_separable_spectrum():
    n = 64
    i = np.arange(n)
    px = np.tile([0.1, 0.2, 0.0, 0.0, 0.3], (n, 1)).astype(float)
    py = px.copy()
    px[:, 0] += 0.02 * np.sin(2 * np.pi * i / 8)  # alpha_x varies with period 8 texels along x
    py[:, 0] += 0.02 * np.random.default_rng(0).normal(size=n) * 0.2
    py[:, 2] += 0.01 * np.sin(2 * np.pi * i / 16)  # theta_x varies with period 16 along y
    tex = synthesize_parameter_texture(px, py, (128, 256), seed=1)
    assert tex.shape == (128, 256, 5) and np.all(np.isfinite(tex))
    for c in range(5):
        target_mean = 0.5 * (px[:, c].mean() + py[:, c].mean())
        target_sd = np.sqrt(0.5 * (px[:, c].var() + py[:, c].var()))
        assert tex[..., c].mean() == pytest.approx(target_mean, abs=1e-9)
        assert tex[..., c].std() == pytest.approx(target_sd, abs=1e-9)
    # separability: alpha_x's spectrum along x peaks at the exemplar's frequency (256/8 = 32)
    row_power = np.abs(np.fft.rfft(tex[..., 0] - tex[..., 0].mean(), axis=1)).mean(0)
    assert np.argmax(row_power) == 32
    col_power = np.abs(np.fft.rfft(tex[..., 2] - tex[..., 2].mean(), axis=0)).mean(1)
    assert np.argmax(col_power) == 128 // 16
    # seeded: deterministic, and different seeds give different textures
    np.testing.assert_array_equal(tex, synthesize_parameter_texture(px, py, (128, 256), seed=1))
    assert not np.allclose(tex, synthesize_parameter_texture(px, py, (128, 256), seed=2))


def test_end_to_end_brushed_and_exr_roundtrip(tmp_path):
    sx = gaussian_surface((64, 1024), 0.25, 0.05, (20.0, 1.0), seed=1)  # strip long in x
    sy = gaussian_surface((1024, 64), 0.25, 0.05, (20.0, 1.0), seed=2)  # strip long in y
    tex = synthesize_from_strips(sx, sy, (32, 32), texel_um=16.0, seed=0)
    assert tex.shape == (32, 32, 5) and np.all(np.isfinite(tex))
    # brushed along x: the NDF is narrow in x-slope, wide in y-slope -> alpha_x << alpha_y everywhere
    assert np.median(tex[..., 0]) < 0.5 * np.median(tex[..., 1])
    path = tmp_path / "params.exr"
    save_parameter_texture(path, tex, {"texel_um": 16.0})
    back, meta = load_parameter_texture(path)
    np.testing.assert_allclose(back, tex.astype(np.float32), rtol=0, atol=0)
    assert meta["texel_um"] == 16.0


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="params_x"):
        synthesize_parameter_texture(np.zeros((4, 4)), np.zeros((4, 5)), (8, 8))
    with pytest.raises(ValueError, match="out_shape"):
        synthesize_parameter_texture(np.ones((4, 5)), np.ones((4, 5)), (0, 8))
    with pytest.raises(ValueError, match="texel_um"):
        texel_ellipsoid_params(np.zeros((16, 16)), 0.1, texel_um=100.0)
    bad = np.ones((4, 4, 5))
    bad[0, 0, 1] = np.nan
    with pytest.raises(ValueError, match="texture"):
        save_parameter_texture(tmp_path / "bad.exr", bad)
    assert not os.path.exists(tmp_path / "bad.exr")  # nothing half-written
    with pytest.raises(ValueError, match="texture"):
        save_parameter_texture(tmp_path / "bad.exr", np.ones((4, 4, 3)))
    from scratch_materials.precompute.tables.exr_io import write_exr
    write_exr(tmp_path / "other.exr", {"R": np.zeros((2, 2), np.float32)})
    with pytest.raises(ValueError, match="missing channels"):
        load_parameter_texture(tmp_path / "other.exr")
    assert CHANNELS == ("alpha_x", "alpha_y", "theta_x", "theta_y", "theta_z")


def test_constant_surface_texels_are_finite():
    # a flat strip: every texel NDF is a spike at n; fits must stay finite (alpha at its floor)
    params, _ = texel_ellipsoid_params(np.zeros((32, 128)), 0.25, texel_um=8.0)
    assert np.all(np.isfinite(params)) and np.all(params[..., :2] > 0)
