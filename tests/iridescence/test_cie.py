"""CIE CMF fit (Wyman, Sloan & Shirley 2013) and spectrum → Rec.709 conversion."""
import numpy as np
import pytest

from scratch_materials.precompute.iridescence.cie import (XYZ_TO_REC709, cmf_xyz, spectral_weights, spectrum_to_rgb, visible_wavelengths)


def test_ybar_peak_near_555nm_is_one():
    lam = np.arange(0.380, 0.781, 0.0005)
    y = cmf_xyz(lam)[:, 1]
    # CIE 1931: ȳ(555 nm) = 1.000; the multi-lobe fit is accurate to ~1 %
    assert 0.550 <= lam[np.argmax(y)] <= 0.560
    assert abs(y.max() - 1.0) < 0.02


def test_cmf_integrals_match_cie_tables():
    lam = np.arange(360, 831) / 1000.0        # 1 nm steps
    s = cmf_xyz(lam).sum(axis=0)
    # tabulated CIE 1931 sums at 1 nm: x̄ 106.8566, ȳ 106.8567, z̄ 106.8926; fit within a few %
    assert np.allclose(s, [106.857, 106.857, 106.893], rtol=0.03), s


def test_equal_energy_chromaticity_and_white_balance():
    lam = visible_wavelengths(64)
    xyz = cmf_xyz(lam).sum(axis=0)
    x, y = xyz[:2] / xyz.sum()
    # illuminant E has chromaticity (1/3, 1/3) by construction of the CIE tables; the fit reproduces it to ~1 %
    assert abs(x - 1 / 3) < 0.01 and abs(y - 1 / 3) < 0.01
    assert np.allclose(spectrum_to_rgb(np.ones(64), lam), 1.0, atol=1e-12)
    # a flat grey reflectance stays neutral on any grid
    lam2 = np.linspace(0.39, 0.77, 17)
    rgb = spectrum_to_rgb(np.full(17, 0.3), lam2)
    assert np.ptp(rgb) < 1e-12 and np.isclose(rgb[0], 0.3)


def test_sRGB_matrix_maps_d65_white_to_neutral():
    # D65 white point XYZ (0.95047, 1, 1.08883) → RGB (1, 1, 1) for the standard matrix
    assert np.allclose(XYZ_TO_REC709 @ [0.95047, 1.0, 1.08883], 1.0, atol=1e-3)


@pytest.mark.parametrize("lam_peak,channel", [(0.45, 2), (0.53, 1), (0.63, 0)])
def test_narrow_band_hues(lam_peak, channel):
    lam = visible_wavelengths(200)
    spec = np.exp(-0.5 * ((lam - lam_peak) / 0.01) ** 2)
    rgb = spectrum_to_rgb(spec, lam)
    assert np.argmax(rgb) == channel


def test_invalid():
    with pytest.raises(ValueError, match="lam_um"):
        cmf_xyz([0.5, -1.0])
    with pytest.raises(ValueError, match="lam_um"):
        spectral_weights([0.5, 0.4])
    with pytest.raises(ValueError, match="spectrum"):
        spectrum_to_rgb(np.ones(3), np.array([0.4, 0.5]))
    with pytest.raises(ValueError, match="n"):
        visible_wavelengths(1)
