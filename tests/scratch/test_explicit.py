"""Explicit scratch geometry (precompute.scratch.explicit) for the ground-truth tier: the meshes are the
profiles and the layers they stand for (numpy only; the renders are in test_scratch_truth.py)."""
import numpy as np
import pytest

from scratch_materials.precompute.scratch import explicit as ex, layers as scratch_layers, profiles


def _normals(m):
    p0, p1, p2 = (m.verts[m.quads[:, k]] for k in range(3))
    n = np.cross(p1 - p0, p2 - p1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.mark.parametrize("prof", [profiles.v_groove(30.0), profiles.quartic(0.5, segments=32)], ids=["v30", "q05"])
def test_groove_field_is_the_periodic_profile(prof):
    period, n = 0.01, 10
    m = ex.groove_field(prof, n, period, x_range=(-1.0, 1.0))
    z = m.verts[:, 2]
    assert np.isclose(z.max(), 0.0) and np.isclose(z.min(), -period * prof.depth)
    assert np.isclose(m.meta["y_range"][1] - m.meta["y_range"][0], n * period)
    nrm = _normals(m)
    assert np.all(nrm[:, 2] > 0)                                   # counter-clockwise from above: normals up
    # the facets' slopes across the grooves are the profile's segment slopes, n times over
    v = prof.periodic_vertices()
    slope = np.diff(v[:, 1]) / np.diff(v[:, 0])
    np.testing.assert_allclose(-nrm[:, 1] / nrm[:, 2], np.tile(slope, n), atol=1e-9)
    if prof.name.startswith("v"):
        np.testing.assert_allclose(np.degrees(np.arccos(nrm[:, 2])), 60.0, atol=1e-9)   # half angle 30 deg
    assert np.all(nrm[:, 0] == 0)                                  # extruded along x: no slope along the scratch


def test_layer_field_places_grooves_where_the_layers_scratch():
    """Scratched fraction of the explicit layered field = the layer indicator's (Cycles' Voronoi twin) and,
    over a large window, the analytic mean coverage of eq. 7 (``layers.mean_coverage``)."""
    lp = scratch_layers.LayerParams(n_layers=3, theta_deg=40.0, length=0.2, width=0.02, density=0.2, seed=1)
    m = ex.layer_field(profiles.v_groove(30.0), lp, 0.004, (0.1, 0.1, 0.9, 0.9), plane_size=2.0)
    cov = np.array(m.meta["coverage"])
    c_bar = scratch_layers.mean_coverage(lp.density)
    # 0.8 x 0.8 UV window ~ 4 x 40 Voronoi cells per layer: sampling error of the coverage ~ 10 % relative
    np.testing.assert_allclose(cov, c_bar, rtol=0.25)
    union = 1.0 - np.prod(1.0 - cov)
    assert abs(m.meta["scratched"] - union) < 0.03                 # layers independent (offsets xi_k)
    assert m.quads.size and m.tris.size and np.all(_normals(m)[:, 2] >= -1e-9)
    with pytest.raises(ValueError, match="uv_window"):
        ex.layer_field(profiles.v_groove(30.0), lp, 0.004, (0.5, 0.5, 0.4, 0.9))


def test_voronoi_twin_matches_its_definition():
    """voronoi_f1: distance to the nearest feature point cell + hash(cell) among the 3x3 cells (brute force
    over 5x5 cells gives the same, so the 3x3 search is enough) and 0 at the feature points."""
    rng = np.random.default_rng(3)
    y = rng.uniform(-50, 50, (2000, 2))
    f1 = scratch_layers.voronoi_f1(y)
    cell = np.floor(y).astype(np.int64)
    best = np.full(len(y), np.inf)
    for j in range(-2, 3):
        for i in range(-2, 3):
            hx, hy = scratch_layers._hash_int2_to_vector2(cell[:, 0] + i, cell[:, 1] + j)
            best = np.minimum(best, np.hypot(cell[:, 0] + i + hx - y[:, 0], cell[:, 1] + j + hy - y[:, 1]))
    np.testing.assert_allclose(f1, best, rtol=1e-6, atol=1e-6)
    hx, hy = scratch_layers._hash_int2_to_vector2(cell[:5, 0], cell[:5, 1])
    np.testing.assert_allclose(scratch_layers.voronoi_f1(np.stack([cell[:5, 0] + hx, cell[:5, 1] + hy], -1)), 0.0,
                               atol=1e-6)
