"""A tabulated NDF (Dong et al. 2015) as its own BRDF table for the tabulated closure
(``precompute.microgeometry.ndf_brdf``): on analytic GGX NDF tables it reproduces the GGX BRDF's albedo
and the second moments of the exit direction (the issue-16 metric) within 0.01, and an anisotropic NDF
gives an anisotropic table."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.microgeometry import ndf_brdf as nb
from scratch_materials.precompute.microgeometry.ndf import NDFTable
from scratch_materials.precompute.tables import tabulated_brdf as tb


def ggx_table(ax, ay, R=129):
    g = np.linspace(-1, 1, R)
    X, Y = np.meshgrid(g, g)
    r2 = X ** 2 + Y ** 2
    mz2 = np.clip(1 - r2, 1e-12, 1)
    D = 1.0 / (np.pi * ax * ay * (X ** 2 / ax ** 2 + Y ** 2 / ay ** 2 + mz2) ** 2)
    return NDFTable(np.where(r2 < 1, D, 0.0))


def _moments(f, wo, n=96):
    """(albedo, E[ωx²], E[ωy²]) of the exit direction under f cos at view wo (midpoint rule in μ, φ)."""
    mu = (np.arange(n) + 0.5) / n
    ph = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    M, P = np.meshgrid(mu, ph, indexing="ij")
    s = np.sqrt(1 - M ** 2)
    w = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    v = f(w, np.broadcast_to(wo, w.shape))[:, 0] * w[:, 2]
    a = v.sum()
    return a * (2 * np.pi) / (n * 2 * n), (v * w[:, 0] ** 2).sum() / a, (v * w[:, 1] ** 2).sum() / a


@pytest.fixture(scope="module")
def iso():
    return nb.ndf_brdf(ggx_table(0.3, 0.3))


def test_isotropic_ggx_ndf_gives_the_ggx_brdf(iso):
    """GGX α = 0.3: the NDF's half-vector table (default layout: 19², the whole hemisphere for GGX's
    tails) vs Cycles' GGX BRDF evaluated analytically: albedo within 2 % (the grid's resolution: 1.2 % / 1.7 % low at
    0° / 45° at 19², 0.5 % at 32²), exit-direction second moments within 0.01
    (measured 0.004)."""
    def ggx(wi, wo):
        return tb._ggx_unit(wi, wo, 0.3)[:, None] * np.ones(3)
    assert iso.half and iso.res == nb.MAX_HALF_RES
    for wo in (np.array([0.0, 0.0, 1.0]), np.array([0.7071, 0.0, 0.7071])):
        a, mx, my = _moments(iso.eval, wo, 192)
        b, rx, ry = _moments(ggx, wo, 384)
        assert abs(a / b - 1) < 0.02
        assert abs(mx - rx) < 0.01 and abs(my - ry) < 0.01


def test_anisotropic_ndf_gives_an_anisotropic_table():
    """α_x = 0.3, α_y = 0.1: at normal view the exit direction spreads ~ (α_x/α_y)² more along x; the
    table's second moments follow (E[ωx²] > 3 E[ωy²]); a 90°-rotated NDF swaps them."""
    B = nb.ndf_brdf(ggx_table(0.3, 0.1), res=12)
    _, mx, my = _moments(B.eval, np.array([0.0, 0.0, 1.0]))
    assert mx > 3 * my                     # measured 0.199 vs 0.050 (a 12² grid blurs the narrow axis)
    C = nb.ndf_brdf(NDFTable(ggx_table(0.3, 0.1).table.T), res=12)
    _, mx2, my2 = _moments(C.eval, np.array([0.0, 0.0, 1.0]))
    assert abs(mx2 - my) < 0.01 and abs(my2 - mx) < 0.01


def test_lambda_and_errors():
    t = ggx_table(0.2, 0.2)
    assert nb.smith_lambda(t, np.array([[0.0, 0.0, 1.0]]))[0] < 1e-3      # no masking at normal view
    lam = nb.smith_lambda(t, np.array([[0.8, 0.0, 0.6], [0.98, 0.0, 0.2]]))
    assert lam[1] > lam[0] > 0                                           # grows towards grazing
    with pytest.raises(ValueError, match="F"):
        nb.ndf_brdf(t, res=4, F=1.5)
