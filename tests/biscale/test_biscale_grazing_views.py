"""Issue 16 item 2, "<= 3 % at every view": the closure table's view grid at grazing lamp-side views.

The groove (diffuse floor, GGX α 0.2 walls) seen at θo 80° from the lamp's side (φo 180°: a = -80°) shows the
lamp's highlight on a wall, which moves fast with the view.  Measured against the explicit tiles (SVM, 256 spp,
``bench/out/biscale_truth_svm_views.md``): main's grid (ωi 19², 19 x 19 view nodes spread evenly, the view
mid-gap between -85° and -74.7°) 5.5 % dark; the bake's grid (ωi 31², 31 x 31 nodes 2.5 x denser beyond 65°):
see that file.  Here the part the grid decides, in numpy and without Monte Carlo noise: the lamp term of the rendered
radiance (the bench's 1.5 m area lamp sampled over the view's 0.4 m orthographic footprint, lamp cosine / r²)
from the table (bilinear between view nodes and ωi cells, what the closure renders) against eq. 8 evaluated
directly at every (lamp direction, view) pair from the same facets (``brute_force_fr_at``: the ray-traced tile
agrees with it to 0.03 % there, 65,536 rays).  The same facets and directions enter both, so the difference is
the table's interpolation alone (deterministic; the sampled lamp / footprint points only choose where it is
measured).  Measured (10,000 facets, 48 x 80 lamp pairs): main's grid -3.1 %, ωi 23² with 25 x 25 nodes -0.95 %,
a view node exactly at the view -0.5 % (ωi 23²); here (24 x 40 pairs): main -3.3 %, the bake's grid -0.45 %."""
from __future__ import annotations

import math

import numpy as np

from scratch_materials.precompute.biscale import geometry
from scratch_materials.precompute.biscale import table as btable
from scratch_materials.precompute.biscale.effective import BiscaleTile, brute_force_fr_at

MATS = [{"model": "lambert", "albedo": 0.7},
        {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.2, "F0": 1.0, "ks": 0.8},
        {"model": "lambert", "albedo": (0.2, 0.5, 0.8)}]
LAMP = np.array([-1.5, 1.0, 2.5])          # bench/biscale_truth's area lamp (size 1.5 m, facing the origin)
N_FACETS_MIXED = 4000     # the Principled pyramid test: enough for its highlight (10,000: the same split)


def _lamp_pairs(theta, phi, n_s=24, n_l=40, seed=1):
    """Lamp directions (n_s n_l, 3) from points of the orthographic 0.4 m footprint of view (θo, φo) to points
    of the lamp, their weights (lamp cosine / r²), and ωo."""
    t, p = math.radians(theta), math.radians(phi)
    wo = np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])
    c = LAMP / np.linalg.norm(LAMP)
    u = np.cross(c, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(c, u)
    rng = np.random.default_rng(seed)
    s = rng.random((n_s, 2)) - 0.5
    surf = 0.4 * (s[:, :1] * np.array([math.cos(p), math.sin(p), 0.0]) / math.cos(t)
                  + s[:, 1:] * np.array([-math.sin(p), math.cos(p), 0.0]))
    q = (rng.random((n_s, n_l, 2)) - 0.5) * 1.5
    d = LAMP + q[..., :1] * u + q[..., 1:] * v - surf[:, None, :]
    r2 = (d ** 2).sum(-1)
    wl = (d / np.sqrt(r2)[..., None]).reshape(-1, 3)
    return wl, (np.clip(wl @ c, 0.0, None) / r2.ravel())[:, None], wo


def test_grazing_lamp_side_view_is_within_the_grid_budget():
    """Groove, θo 80° φo 180°: the bake's table (``tabulate_tile(view="auto")``) within 1 % of eq. 8 on the
    lamp term (measured -0.45 %; -0.27 % with the lobe-following view interpolation, ``view_shift``); main's grid (ωi
    19², 19 x 19 even nodes, rows blended) misses by > 2 % (measured -3.3 %; with ``view_shift`` -1.5 %), so the test
    fails on main."""
    g = geometry.groove_tile(depth=0.4)
    bt = BiscaleTile(g.vertices, g.faces, g.face_material, n_facets=10000, dir_res=10, seed=0)
    wl, w, wo = _lamp_pairs(80.0, 180.0)
    WO = np.repeat(wo[None], len(wl), 0)
    ref = float((brute_force_fr_at(bt, MATS, wl, WO) * w).sum())
    err = {}
    for label, res, view in (("bake", None, "auto"), ("main", 19, btable.tile_view_grid(bt, 19, 19, None))):
        T = btable.tabulate_tile(bt, MATS, res=res, view=view, view_shift=label == "bake")   # main blended rows
        err[label] = float((T.eval(wl, WO) * wl[:, 2:3] * w).sum()) / ref - 1.0
    print(f"\n[grazing 80/180 lamp term] table vs eq. 8: bake's grid {100 * err['bake']:+.2f} %, "
          f"main's {100 * err['main']:+.2f} %")
    assert abs(err["bake"]) < 0.01, err
    assert abs(err["main"]) > 0.02, err


def test_off_axis_highlight_view_follows_the_lobe():
    """Groove, θo 78° φo 200° (a = -77.3°, b = -58.1°: off both axes, the lamp on the wall's highlight).  Between view
    nodes the highlight moves with the view; blending the rows of the four bracketing nodes (bilinear in (a, b))
    spreads it over four places and the lamp term falls 3.7 % short of eq. 8 (the view-grid part; measured: a node
    exactly at the view -1.5 %, the ωi cells' part).  The lobe-following interpolation (``view_shift``, the bake's
    default: each node's row moved by the interpolated centroid minus its own) measures -1.6 %.  Only the bake grid's
    nodes bracketing the view are tabulated (the interpolation reads no others; each row's centroid is its own), so the
    test takes seconds.  Bounds: within 2.5 % with the shift; blending misses by more than 3 % (fails on the old code)."""
    from scratch_materials.precompute.tables import tabulated_brdf as tb

    g = geometry.groove_tile(depth=0.4)
    bt = BiscaleTile(g.vertices, g.faces, g.face_material, n_facets=10000, dir_res=10, seed=0)
    wl, w, wo = _lamp_pairs(78.0, 200.0)
    WO = np.repeat(wo[None], len(wl), 0)
    ref = float((brute_force_fr_at(bt, MATS, wl, WO) * w).sum())
    ga, gb = btable.tile_view_grid(bt)
    a, b = tb.view_angles(wo)
    ia, ib = np.searchsorted(ga, a), np.searchsorted(gb, b)
    view = (ga[ia - 2:ia + 2], gb[ib - 2:ib + 2])                 # two bake nodes on each side of the view
    T = btable.tabulate_tile(bt, MATS, view=view)
    assert T.view_shift
    blend = tb.TabulatedBRDF(T.table, T.res, view_a=T.view_a, view_b=T.view_b, view_shift=False)
    err = {k: float((B.eval(wl, WO) * wl[:, 2:3] * w).sum()) / ref - 1.0 for k, B in (("shift", T), ("blend", blend))}
    print(f"\n[grazing 78/200 lamp term] table vs eq. 8: lobe-following {100 * err['shift']:+.2f} %, "
          f"bilinear blend {100 * err['blend']:+.2f} %")
    assert abs(err["shift"]) < 0.025, err
    assert err["blend"] < -0.03, err


# Principled BSDFs as Cycles builds them (``precompute.cycles.principled``): a coloured metal floor, dielectric sides
# (``bench.biscale_truth.TILES["pyramid (Principled: metal floor and dielectric sides)"]``)
PRINCIPLED = [{"model": "principled", "base_color": (0.9, 0.6, 0.3), "metallic": 1.0, "roughness": 0.4,
               "multiscatter": True},
              {"model": "principled", "base_color": (0.2, 0.5, 0.8), "metallic": 0.0, "roughness": 0.5,
               "multiscatter": True}]


def test_mixed_lobes_view_anchor_follows_the_peak():
    """Pyramid of Principled BSDFs (metal floor α 0.16, dielectric sides α 0.25), θo/φo 55/300 under the lamp (issue 16
    item 2; the explicit-tile render missed by 9.4 %, baked too bright).  The rows hold the floor's highlight, which moves
    with the view, and the sides' broad diffuse + specular part, which barely does; the lobe-following interpolation
    moved every tap by its row's *mass* centroid, which the broad part drags, so the highlight was moved by the wrong
    amount: lamp term +4.9 % over eq. 8 (the floor alone +1.4 %, the sides alone +0.1 %, a node at the view +1.2 %:
    the ωi cells' part).  The bake's anchor is now the centroid of g² (``table.VIEW_ANCHOR``,
    ``TabulatedBRDF.view_anchor``, ``view_centroids``), which leans to the peak: +1.8 % (10,000 facets; g⁴ +1.1 % but worse on the audit's bump).  Only the bake grid's nodes
    bracketing the view are tabulated, from 4,000 facets (~10 s CPU).  Bounds: within 2.5 % with the new anchor
    (fails on the old code: +5.1 % with 4,000 facets); the mass centroid (p = 1) beyond 3 %."""
    from scratch_materials.precompute.tables import tabulated_brdf as tb

    g = geometry.pyramid_tile(height=0.4, base=0.7)
    bt = BiscaleTile(g.vertices, g.faces, g.face_material, n_facets=N_FACETS_MIXED, dir_res=10, seed=0)
    wl, w, wo = _lamp_pairs(55.0, 300.0)
    WO = np.repeat(wo[None], len(wl), 0)
    ref = (brute_force_fr_at(bt, PRINCIPLED, wl, WO) * w).sum(0)
    ga, gb = btable.tile_view_grid(bt)
    a, b = tb.view_angles(wo)
    ia, ib = np.searchsorted(ga, a), np.searchsorted(gb, b)
    T = btable.tabulate_tile(bt, PRINCIPLED, view=(ga[ia - 2:ia + 2], gb[ib - 2:ib + 2]))
    err = (T.eval(wl, WO) * wl[:, 2:3] * w).sum(0) / ref - 1.0
    io, wto = tb.view_taps(WO, T.view_a, T.view_b)
    mass = tb._shifted_eval(T.table, T.res, tb.view_centroids(T.table, T.res, power=1.0), wl, io, wto)
    err_mass = (mass * wl[:, 2:3] * w).sum(0) / ref - 1.0
    assert T.view_shift and T.view_anchor == btable.VIEW_ANCHOR
    print(f"\n[Principled pyramid 55/300 lamp term] table vs eq. 8: anchor g^{T.view_anchor:g} "
          f"{np.round(100 * err, 2)} %, mass centroid {np.round(100 * err_mass, 2)} %")
    assert np.abs(err).max() < 0.025, err
    assert err_mass.max() > 0.03, err_mass
