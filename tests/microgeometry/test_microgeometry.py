"""Naive / filtered geometric NDFs and the Kirchhoff distribution (Dong et al. 2015 §5.1, §6, App. A)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from scratch_materials.precompute.microgeometry.heightfield import (HeightField, gaussian_surface, is_periodic,
                                                                  spectral_slope_covariance)
from scratch_materials.precompute.microgeometry.ndf import (NDFTable, filtered_ndf, filtered_slopes, fit_beckmann, fit_ellipsoid,
                                          kirchhoff_integral_direct, kirchhoff_integral_fft, kirchhoff_ndf, naive_ndf)


def quad_integral(ndf, n=2001):
    """∫ D (m·n) dω = ∫ D dm_x dm_y on a grid *offset* from the table nodes (independent of node sums)."""
    g = np.linspace(-1, 1, n) + 0.37 / n
    X, Y = np.meshgrid(g, g)
    r2 = X**2 + Y**2
    ok = r2 < 1
    m = np.stack([X[ok], Y[ok], np.sqrt(1 - r2[ok])], -1)
    return ndf.eval(m).sum() * (2 / (n - 1)) ** 2


@pytest.fixture(scope="module")
def iso():
    # isotropic Gaussian surface, l = 4 µm = 36 px, rms slope 0.071 per axis
    return gaussian_surface((384, 512), 0.11, 0.2, 4.0, seed=1)


def test_normalisation(iso):
    for nd in (naive_ndf(iso), filtered_ndf(iso), filtered_ndf(iso, resolution=257)):
        assert nd.integral() == pytest.approx(1, abs=1e-12)
        # independent quadrature of eval(): bilinear table, 1 % per the issue
        assert quad_integral(nd) == pytest.approx(1, abs=0.01)


def test_flat_and_tilted_planes():
    y, x = np.mgrid[0:40, 0:40] * 0.2
    flat = naive_ndf(np.full((40, 40), 3.0), 0.2, resolution=65)
    c = flat.resolution // 2
    assert flat.table[c, c] == pytest.approx(1 / flat.h**2)  # all mass at m = n
    assert flat.eval(np.array([[0, 0, 1.0]]))[0] == pytest.approx(1 / flat.h**2)
    tilt = 0.25 * x  # dh/dx = 0.25 -> m = (-0.25, 0, 1)/|.|
    nd = filtered_ndf(tilt, 0.2, sigma_um=0.5, resolution=1025, detilt=False)
    mean, cov = nd.moments()
    assert mean == pytest.approx([0.25, 0.0], abs=2e-3)  # splat onto 2/1024 nodes
    assert np.all(np.abs(cov) < 1e-5)
    nd = filtered_ndf(tilt, 0.2, sigma_um=0.5, resolution=65, detilt=True)
    assert nd.table[32, 32] == pytest.approx(1 / nd.h**2)


def test_filtered_slopes_equal_gaussian_smoothed_gradient(iso):
    # independent reference: the LSQ plane slope == gradient smoothed by the normalised Gaussian,
    # i.e. transfer exp(-sigma^2 k^2 / 2) in the spectral domain (periodic surface, interior points)
    sx, sy, ok = filtered_slopes(iso, sigma_um=1.0, detilt=False)
    b = int(np.ceil(4 / 0.11))  # interior: full kernel support
    interior = (slice(b, -b), slice(b, -b))
    ref = spectral_slope_covariance(iso.heights, 0.11, sigma_um=1.0)
    F = np.fft.fft2(iso.heights)
    k = 2 * np.pi * np.fft.fftfreq(iso.shape[1], 0.11)
    KX = np.broadcast_to(k, iso.shape)
    KY = np.broadcast_to(2 * np.pi * np.fft.fftfreq(iso.shape[0], 0.11)[:, None], iso.shape)
    smooth_gx = np.fft.ifft2(1j * KX * F * np.exp(-0.5 * (KX**2 + KY**2))).real
    err = sx[interior] - smooth_gx[interior]
    # kernel truncated at 4 sigma and sampled at sigma = 9 px: pointwise agreement ~1e-3 of the rms
    assert np.sqrt(np.mean(err**2)) < 3e-3 * np.sqrt(ref[0, 0])
    # the continuum formula var_f = var * (l^2 / (l^2 + 4 sigma^2))^2 for a Gaussian spectrum
    C = spectral_slope_covariance(iso.heights, 0.11)
    assert ref[0, 0] / C[0, 0] == pytest.approx((16 / 20) ** 2, rel=0.02)


def _smoothed_gradient(hf, sigma_um=1.0):
    """(dh/dx, dh/dy) of the periodic ``hf`` smoothed by the Gaussian of std ``sigma_um`` (spectral)."""
    F = np.fft.fft2(hf.heights)
    KY = 2 * np.pi * np.fft.fftfreq(hf.shape[0], hf.pixel_um)[:, None]
    KX = 2 * np.pi * np.fft.fftfreq(hf.shape[1], hf.pixel_um)[None, :]
    g = F * np.exp(-0.5 * sigma_um ** 2 * (KX ** 2 + KY ** 2))
    return np.fft.ifft2(1j * KX * g).real, np.fft.ifft2(1j * KY * g).real


def test_a_seamless_scan_wraps_its_windows_around():
    """A periodic tile (seamless edges): every point's window wraps around, so the filtered NDF is the normals of
    the σ-smoothed surface tiled (the explicit surface of the NDF truth bench) at every point, border included;
    the paper's finite-scan treatment (one-sided windows at the border) widens this scan's NDF by ~20 %."""
    hf = gaussian_surface((256, 512), 0.11, 0.05, (20.0, 2.0), seed=4)
    assert is_periodic(hf.heights)
    gx, gy = _smoothed_gradient(hf)
    _, cov = filtered_ndf(hf, detilt=False, periodic="auto").moments()
    # truncated kernel (4 σ) + the table's binning: 2 %, as the interior test above
    assert cov[1, 1] == pytest.approx(np.mean((gy - gy.mean()) ** 2), rel=0.02)
    _, cov_finite = filtered_ndf(hf, detilt=False).moments()
    assert cov_finite[1, 1] > 1.1 * cov[1, 1]
    sx, sy, ok = filtered_slopes(hf, detilt=False, periodic=True)
    fx, fy, fok = filtered_slopes(hf, detilt=False)
    b = int(np.ceil(4 / 0.11))
    assert ok.all() and np.abs(sy - fy)[b:-b, b:-b].max() < 1e-6   # the interior is the finite scan's
    assert np.sqrt(np.mean((sy - gy) ** 2)) < 3e-3 * gy.std()          # and so is every point now
    # measured-like scans are not periodic: a crop, a tilt, a missing point ("auto" keeps the paper's border)
    h = hf.heights
    assert not is_periodic(h[:200, :300])
    assert not is_periodic(h + 0.002 * np.arange(h.shape[1])[None, :])
    holed = h.copy()
    holed[5, 5] = np.nan
    assert not is_periodic(holed)
    _, cov_holed = filtered_ndf(HeightField(holed, 0.11), detilt=False, periodic="auto").moments()
    assert cov_holed[1, 1] == pytest.approx(cov_finite[1, 1], rel=0.01)
    with pytest.raises(ValueError, match="periodic"):
        filtered_slopes(HeightField(holed, 0.11), periodic=True)
    with pytest.raises(ValueError, match="periodic"):
        filtered_ndf(hf, periodic="yes")


def test_material_from_a_seamless_scan_uses_whole_windows(tmp_path):
    """*Material from Height Field*'s tables (``tables.compute_tables``) of a seamless scan saved to a file: the
    NDF's slope covariance is the σ-smoothed surface's (the explicit-geometry truth), not the finite scan's."""
    from scratch_materials.precompute.microgeometry import tables

    hf = gaussian_surface((256, 256), 0.25, 0.3, (6.0, 2.0), seed=5)   # the rough surface of the NDF truth audit
    path = tmp_path / "rough.npy"
    np.save(path, hf.heights)
    out = tables.compute_tables(str(path), 0.25, 1.0, with_ndf=True)
    mean, cov = NDFTable(out["ndf"], "filtered").moments()
    # no tilt: a tile's mean slope is 0 (a least-squares plane of one period is not: 0.0034 in y here, which
    # tilted the exit lobe by 0.4° and moved E[d_y²] at a 50° view by 0.006)
    assert np.abs(mean).max() < 5e-4, mean
    gx, gy = _smoothed_gradient(hf)
    plane_free = [np.mean((g - g.mean()) ** 2) for g in (gx, gy)]
    # finite-scan treatment: +10 % in y for this realisation (one-sided windows at the border)
    assert cov[0, 0] == pytest.approx(plane_free[0], rel=0.03) and cov[1, 1] == pytest.approx(plane_free[1], rel=0.03)


@pytest.mark.parametrize("seed", [0, 1])
def test_recovered_roughness_filtered_and_naive(seed):
    # Gaussian slopes -> Beckmann NDF with alpha^2 = 2 var; var known from the surface's exact
    # spectrum (filtered: times the filter's transfer function exp(-sigma^2 k^2 / 2) on slopes).
    # Fixed spectral amplitudes make the variance exact; the *shape* of a finite realisation's
    # slope histogram still scatters: with 205 x 205 µm and l = 3 µm (~4600 correlation areas)
    # the fitted alpha scatters by < 1 % over seeds (a 56 x 42 µm field scatters by 3-4 %).
    pix = 0.2
    hf = gaussian_surface((1024, 1024), pix, 0.2, 3.0, seed=seed)
    var_f = spectral_slope_covariance(hf.heights, pix, sigma_um=1.0)[0, 0]
    fb = fit_beckmann(filtered_ndf(hf), isotropic=True)
    assert fb["alpha_x"] == pytest.approx(np.sqrt(2 * var_f), rel=0.02)
    var = spectral_slope_covariance(hf.heights, pix)[0, 0]
    nb = fit_beckmann(naive_ndf(hf), isotropic=True)
    assert nb["alpha_x"] == pytest.approx(np.sqrt(2 * var), rel=0.02)
    # and the filter really narrows the NDF (by (9/13)^2 in variance for l = 3, sigma = 1)
    assert fb["alpha_x"] < 0.8 * nb["alpha_x"]


def test_brushed_surface_anisotropy():
    # scratches along x: l_x = 20 µm >> l_y = 2 µm; slope covariance of the table vs the spectrum
    hf = gaussian_surface((256, 512), 0.11, 0.05, (20.0, 2.0), seed=4)
    nd = filtered_ndf(hf, detilt=False)
    _, cov = nd.moments()
    ref = spectral_slope_covariance(hf.heights, 0.11, sigma_um=1.0)
    # with l_y = 2 sigma the filter removes 75 % of the slope variance; border points (one-sided
    # windows, 28 % of this small scan) smooth less and inflate it by ~20 %: test the interior
    assert cov[1, 1] > 1.1 * ref[1, 1]
    _, cov = filtered_ndf(hf, detilt=False, border_sigmas=4).moments()
    # interior only, vs the spectrally smoothed gradient on the *same* interior points (a subset
    # of a periodic realisation is not exactly ref): truncated kernel + binning -> 2 %
    F = np.fft.fft2(hf.heights)
    KY = 2 * np.pi * np.fft.fftfreq(hf.shape[0], 0.11)[:, None]
    KX = 2 * np.pi * np.fft.fftfreq(hf.shape[1], 0.11)[None, :]
    gy = np.fft.ifft2(1j * KY * F * np.exp(-0.5 * (KX**2 + KY**2))).real
    b = int(np.ceil(4 / 0.11))
    inner = gy[b:-b, b:-b]
    assert cov[1, 1] == pytest.approx(np.mean((inner - inner.mean()) ** 2), rel=0.02)
    assert cov[0, 0] < 0.05 * cov[1, 1]
    fb = fit_beckmann(nd)
    assert min(fb["alpha_x"], fb["alpha_y"]) < 0.25 * max(fb["alpha_x"], fb["alpha_y"])
    p = fit_ellipsoid(nd)
    assert np.all(np.isfinite(p))


def test_missing_points_without_bias(iso):
    rng = np.random.default_rng(0)
    h = iso.heights.copy()
    h[rng.random(h.shape) < 0.04] = np.nan  # ~4 % scattered missing points, as in the paper
    h[100:120, 200:230] = np.nan  # and one missing blob
    hn = HeightField(h, 0.11)
    for f in (filtered_ndf, naive_ndf):
        _, c0 = f(iso).moments()
        nd = f(hn)
        _, c1 = nd.moments()
        assert np.all(np.isfinite(nd.table)) and nd.integral() == pytest.approx(1)
        # same surface statistics: moments agree to 2 % (sub-sampling noise << 2 %)
        np.testing.assert_allclose(np.diag(c1), np.diag(c0), rtol=0.02)


def test_missing_points_biased_fill_is_detected(iso):
    # control: filling holes with 0 instead of masking *does* bias the filtered NDF (test can fail)
    rng = np.random.default_rng(0)
    h = iso.heights.copy()
    h[rng.random(h.shape) < 0.04] = 0.0
    _, c0 = filtered_ndf(iso).moments()
    _, c1 = filtered_ndf(h, 0.11).moments()
    assert abs(c1[0, 0] / c0[0, 0] - 1) > 0.02


def test_kirchhoff_fft_equals_direct_sum():
    h = gaussian_surface((12, 16), 0.1, 0.15, 0.5, seed=3).heights.copy()
    h[3, 4] = np.nan
    k = 4 * np.pi / 0.5
    qx, qy, I, comp = kirchhoff_integral_fft(h, 0.1, k, pad=2, max_theta=1.2, tol=1e-13)
    QX, QY = np.meshgrid(qx, qy)
    q = np.stack([QX[comp], QY[comp], np.sqrt(k * k - QX[comp] ** 2 - QY[comp] ** 2)], -1)
    ref = kirchhoff_integral_direct(h, 0.1, q)
    assert comp.sum() > 100
    # float64 round-off over ~200-term sums: relative 1e-12
    assert np.max(np.abs(I[comp] - ref)) < 1e-12 * np.max(np.abs(ref))
    # a looser Taylor tolerance is looser (the tolerance parameter does something)
    _, _, I2, _ = kirchhoff_integral_fft(h, 0.1, k, pad=2, max_theta=1.2, tol=1e-2)
    assert np.max(np.abs(I2[comp] - ref)) > 1e-9 * np.max(np.abs(ref))


def test_kirchhoff_flat_surface_is_specular():
    kd = kirchhoff_ndf(np.zeros((64, 64)), 0.1, wavelength_um=0.5, patch_um=6.4, resolution=257, max_theta=0.5)
    c = kd.resolution // 2
    assert np.argmax(kd.table) == c * kd.resolution + c
    # Parseval: a flat patch sends all energy to the specular lobe, ∫ D_K = 1 up to the sinc tails
    assert kd.info["raw_integral"] == pytest.approx(1, abs=0.05)


def test_kirchhoff_geometric_optics_limit():
    # k sigma_h = 9 >> 1 and l = 20 px: D_K -> geometric NDF of the same surface (stationary phase)
    hf = gaussian_surface((256, 256), 0.1, 0.15, 2.0, seed=5)
    kd = kirchhoff_ndf(hf, wavelength_um=0.25, patch_um=12.8, resolution=513)
    assert kd.info["patches"] == 4
    assert kd.info["raw_integral"] == pytest.approx(1, abs=0.02)
    ak = fit_beckmann(kd.normalized(), isotropic=True)["alpha_x"]
    ag = fit_beckmann(naive_ndf(hf, resolution=513), isotropic=True)["alpha_x"]
    assert ak == pytest.approx(ag, rel=0.02)
    # at a long wavelength (k sigma_h ~ 1) the wave result differs from geometry: test can fail
    kl = kirchhoff_ndf(hf, wavelength_um=2.0, patch_um=12.8, resolution=513)
    al = fit_beckmann(kl.normalized(), isotropic=True)["alpha_x"]
    assert abs(al / ag - 1) > 0.05


def test_kirchhoff_nan_policies():
    hf = gaussian_surface((64, 128), 0.1, 0.15, 2.0, seed=6)
    h = hf.heights.copy()
    h[10:14, 10:14] = np.nan  # only in the first patch
    a = kirchhoff_ndf(h, 0.1, wavelength_um=0.5, patch_um=6.4, resolution=129, nan_policy="skip")
    assert a.info["patches"] == 1
    b = kirchhoff_ndf(h, 0.1, wavelength_um=0.5, patch_um=6.4, resolution=129, nan_policy="weight")
    assert b.info["patches"] == 2 and np.all(np.isfinite(b.table))


@settings(max_examples=25, deadline=None)
@given(ny=st.integers(2, 12), nx=st.integers(2, 12), scale=st.sampled_from([0.0, 1e-6, 1.0, 1e3, 1e6]),
       nan_frac=st.floats(0, 0.9), seed=st.integers(0, 5))
def test_fuzz_degenerate_inputs(ny, nx, scale, nan_frac, seed):
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(ny, nx)) * scale
    h[rng.random(h.shape) < nan_frac] = np.nan
    if not np.isfinite(h).any():
        h[0, 0] = 0.0
    for f in (lambda: naive_ndf(h, 0.1, resolution=65), lambda: filtered_ndf(h, 0.1, resolution=65),
              lambda: kirchhoff_ndf(h, 0.1, wavelength_um=0.5, resolution=65)):
        try:
            nd = f()
        except ValueError as exc:  # clear errors name the parameter
            assert any(w in str(exc) for w in ("heights", "sigma_um", "pixel_um"))
            continue
        assert np.all(np.isfinite(nd.table)) and np.all(nd.table >= 0)


def test_bad_parameters():
    h = np.zeros((8, 8))
    with pytest.raises(ValueError, match="resolution"):
        naive_ndf(h, 0.1, resolution=1024)
    with pytest.raises(ValueError, match="sigma_um"):
        filtered_ndf(h, 0.1, sigma_um=-1)
    with pytest.raises(ValueError, match="pixel_um"):
        filtered_ndf(h, None)
    with pytest.raises(ValueError, match="wavelength_um"):
        kirchhoff_ndf(h, 0.1, wavelength_um=0)
    with pytest.raises(ValueError, match="nan_policy"):
        kirchhoff_ndf(h, 0.1, nan_policy="fill")
    with pytest.raises(ValueError, match="m:"):
        NDFTable(np.ones((9, 9))).eval(np.zeros((3, 2)))
