"""Bi-scale truth, an independent audit (issue 16, "judged by independent explicit-geometry checks on other tiles,
materials and views"): tiles nobody had tried, built with the public tile constructor
(``precompute.biscale.geometry.heightfield_tile``), seen from views off the bench's list, rendered by Cycles as
explicit tiled geometry vs the baked closure table, direct light (Wu) and full GI (inter-reflections).

Tiles (``AUDIT_TILES``):
- asymmetric sawtooth: a shallow diffuse face (21.8°, coloured) and a steep glossy face (50°, GGX α 0.15);
- box on a floor (a step): diffuse box (walls 67°), rough GGX α 0.25 floor with a green diffuse part;
- bump with three materials: a faceted hemisphere (8 x 8 height field, r 0.35 P) on a diffuse blue floor, flanks
  rough GGX α 0.3 + orange diffuse, cap sharp GGX α 0.08 + red diffuse.

The scene, noise estimate and error measure are ``bench/biscale_truth``'s (imported: ``render_set``, ``rel_error``,
``bake_variants``; direction-coded world 0.5 + 0.5 d + area lamp, NEE on, orthographic 0.4 m views, explicit
frames averaged over 4 camera offsets in the tile period).  SVM (the default shading system) for explicit and baked;
``--osl``: the baked rows on OSL as well.

    .venv/bin/python -m bench biscale_truth_audit [--tiles sawtooth,box,bump] [--gi] [--spp 256] [--osl]
        [--views "0/0,20/30,..."] [--tag name] [--quick] [--no-lamp] [--bake-seed 0]
    .venv/bin/python -m bench biscale_truth_audit --lamp-term      # numpy: the lamp term, table vs exact eq. 8
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

VIEWS = [(0.0, 0.0), (20.0, 30.0), (45.0, 135.0), (55.0, 300.0), (65.0, 225.0), (70.0, 10.0)]
GI_BOUNCES = 16


def sawtooth_tile(height: float = 0.3):
    """Asymmetric sawtooth along x: heights 0, h/3, 2h/3, h at x = 0, 1/4, 1/2, 3/4 (wrapped): a shallow face over
    3/4 of the period (slope 4h/3, material 0) and a steep one over 1/4 (slope 4h, material 1)."""
    from scratch_materials.precompute.biscale import geometry

    h = np.array([[0.0, 1 / 3, 2 / 3, 1.0]] * 2)
    m = np.array([[0, 0, 0, 1]] * 2)
    return geometry.heightfield_tile(h, 1.0, height, materials=m)


def box_tile(height: float = 0.3, n: int = 8):
    """A square box on a floor: height field n x n, the vertices 2..5 (of 8) raised by ``height``; cells touching a
    raised vertex (top and walls) material 0, the floor material 1."""
    from scratch_materials.precompute.biscale import geometry

    raised = np.zeros((n, n))
    raised[2:6, 2:6] = 1.0
    up = np.pad(raised, ((0, 1), (0, 1)), mode="wrap")
    any_up = np.maximum.reduce([up[:-1, :-1], up[1:, :-1], up[:-1, 1:], up[1:, 1:]])
    return geometry.heightfield_tile(raised, 1.0, height, materials=np.where(any_up > 0, 0, 1))


def bump_tile(radius: float = 0.35, n: int = 8, cap: float = 0.2):
    """A faceted hemisphere z = sqrt(r² - d²) on an n x n height field centred in the tile; cells with all corners
    on the floor material 0, cells whose lowest corner is above ``cap`` material 2 (the cap), the rest 1 (flanks)."""
    from scratch_materials.precompute.biscale import geometry

    x = np.arange(n) / n
    X, Y = np.meshgrid(x, x, indexing="xy")
    h = np.sqrt(np.maximum(radius ** 2 - (X - 0.5) ** 2 - (Y - 0.5) ** 2, 0.0))
    w = np.pad(h, ((0, 1), (0, 1)), mode="wrap")
    corners = np.stack([w[:-1, :-1], w[1:, :-1], w[:-1, 1:], w[1:, 1:]])
    mat = np.where(corners.max(0) <= 0, 0, np.where(corners.min(0) > cap, 2, 1))
    return geometry.heightfield_tile(h, 1.0, 1.0, materials=mat)


AUDIT_TILES = {
    # name: (builder, small-scale materials: every one has an exact Cycles twin, biscale_truth.small_scale_blender_material)
    "sawtooth": (sawtooth_tile, [{"model": "lambert", "albedo": (0.75, 0.55, 0.35)},
                                 {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.15, "F0": 1.0,
                                  "ks": 0.9, "kd": 0.05}]),
    "box": (box_tile, [{"model": "lambert", "albedo": (0.6, 0.6, 0.65)},
                       {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.25, "F0": 1.0, "ks": 0.6,
                        "kd": (0.1, 0.3, 0.15)}]),
    "bump": (bump_tile, [{"model": "lambert", "albedo": (0.3, 0.45, 0.7)},
                         {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": 1.0, "ks": 0.5,
                          "kd": (0.35, 0.2, 0.1)},
                         {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.08, "F0": 1.0, "ks": 0.9,
                          "kd": (0.25, 0.05, 0.03)}]),
}
# the bump with its cap as rough as the flanks: isolates what the sharp (α 0.08) cap costs at the table's resolution
AUDIT_TILES["bump (cap α 0.3)"] = (bump_tile, AUDIT_TILES["bump"][1][:2] + [{**AUDIT_TILES["bump"][1][2], "alpha": 0.3}])


def _view(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def lamp_term(names=("bump", "bump (cap α 0.3)"), views=((0, 0), (55, 300), (70, 10)), n_facets=10000, n_lamp=4000):
    """Numpy, no render: the area lamp's contribution at the tile's centre, ∫_lamp f(ωi, ωo) cos θi dωi, from the
    closure table (``TabulatedBRDF.eval``, what the shaders interpolate) vs eq. 8 at the exact lamp directions from
    the same facets (``effective.brute_force_fr_at``, visibility ray cast for those directions; it returns f cos θi).
    Lamp points uniform on the 1.5 m square at (-1.5, 1, 2.5) facing the origin, weights cos_lamp cos θi / r².
    Prints table / exact - 1 per RGB channel."""
    from scratch_materials.precompute.biscale import table as btab
    from scratch_materials.precompute.biscale.effective import BiscaleTile, brute_force_fr_at

    from bench.biscale_gi_split import lamp_points

    d, w = lamp_points(n_lamp, np.random.default_rng(1))
    w = w * d[:, 2]                                              # cos_lamp cos θi / r² (up to a constant)
    for name in names:
        builder, mats = AUDIT_TILES[name]
        tile = builder()
        bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=n_facets, dir_res=4, seed=0)
        tab = btab.tabulate_tile(bt, mats, view="auto")
        for th, ph in views:
            wo = np.broadcast_to(_view(th, ph), d.shape).copy()
            ft = tab.eval(d, wo)
            fe = brute_force_fr_at(bt, mats, d, wo) / d[:, 2:3]
            ratio = (w[:, None] * ft).sum(0) / (w[:, None] * fe).sum(0)
            print(f"{name} {th:g}/{ph:g}: lamp term table / exact eq. 8 - 1 = {np.round(100 * (ratio - 1), 2)} %",
                  flush=True)
    return 0


def main(argv: list[str]) -> int:
    from bench import biscale_truth as bt
    from scratch_materials.precompute.biscale import table as btab
    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="bench biscale_truth_audit")
    ap.add_argument("--tiles", default=",".join(AUDIT_TILES))
    ap.add_argument("--gi", action="store_true", help="also full GI (16 bounces) vs table + inter-reflections")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--shifts", type=int, default=4)
    ap.add_argument("--osl", action="store_true", help="the baked rows on OSL too")
    ap.add_argument("--views", default="")
    ap.add_argument("--n-facets", type=int, default=10000)
    ap.add_argument("--quick", action="store_true", help="2000 facets, 2 views, 64 spp")
    ap.add_argument("--no-lamp", action="store_true", help="the direction-coded environment alone")
    ap.add_argument("--bake-seed", type=int, default=0)
    ap.add_argument("--lamp-term", action="store_true", help="numpy only: the lamp term of the table vs eq. 8 "
                                                                 "(bump, bump with a rough cap)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    if args.lamp_term:
        return lamp_term()
    addon = blender()
    from scratch_materials.scratch_addon import render

    render.reset_scene()
    views = VIEWS
    if args.views:
        views = [tuple(float(x) for x in v.split("/")) for v in args.views.split(",")]
    n_facets, spp = args.n_facets, args.spp
    if args.quick:
        views, n_facets, spp = views[:2], 2000, 64
    n = 100
    rows = []
    for name in args.tiles.split(","):
        builder, mats = AUDIT_TILES[name]
        tile = builder()
        t0 = time.perf_counter()
        var, times, info = bt.bake_variants(tile, mats, n_facets=n_facets, seed=args.bake_seed, indirect=args.gi)
        bake_s = " / ".join(f"{k} {v:.1f}" for k, v in times.items())
        print(name, "faces", len(tile.faces), "bake", bake_s, f"({time.perf_counter() - t0:.1f} s)", flush=True)
        for bounces in ([0, GI_BOUNCES] if args.gi else [0]):
            use = [k for k in var if bounces or "inter-refl." not in k]
            if bounces:
                use = [k for k in use if "inter-refl." in k]
            paths = ("SVM", "OSL") if args.osl else ("SVM",)
            mats_bl = {f"{k} ({p})": bt._material(f"{name} {k} {p}", *var[k]) for k in use for p in paths}
            osl = {"explicit": False, **{k: k.endswith("(OSL)") for k in mats_bl}}
            t0 = time.perf_counter()
            ex, bk, secs, se = bt.render_set(tile, mats, mats_bl, [_view(*v) for v in views], n=n, spp=spp,
                                             bounces=bounces, noise=True, seeds=range(7, 7 + args.seeds),
                                             shifts=args.shifts, osl=osl, lamp=not args.no_lamp)
            for k in mats_bl:
                err, sig = bt.rel_error(ex, bk[k], se["explicit"], se[k])
                for v, e, sg, a, b in zip(views, err, sig, ex, bk[k]):
                    rows.append([name, k, "direct" if bounces == 0 else f"GI ({bounces})", f"{v[0]:.0f}/{v[1]:.0f}",
                                 f"{100 * e:.1f} %", f"{100 * sg:.2f} %", f"{e / max(sg, 1e-9):.1f}",
                                 np.round(a, 4).tolist(), np.round(b, 4).tolist()])
                    print(rows[-1], flush=True)
            print(name, "renders", {k: round(v, 1) for k, v in secs.items()},
                  f"({time.perf_counter() - t0:.1f} s)", flush=True)
        if info is not None:
            print(name, "indirect estimate", info["estimate"], flush=True)
    report("biscale_truth_audit" + (f"_{args.tag}" if args.tag else ""),
           ["tile", "baked", "light", "view θo/φo", "max rel. err", "render noise 1σ", "err / σ", "explicit RGB",
            "baked RGB"], rows,
           notes=f"{'environment only (no lamp); ' if args.no_lamp else ''}bake seed {args.bake_seed}; SVM (explicit tiles and the baked table's node graph{'; (OSL) rows: the same material on OSL' if args.osl else ''}); "
                 f"{n_facets} facets, closure table ωi res {btab.CLOSURE_RES}, {btab.VIEW_NODES} x {btab.VIEW_NODES} view grid "
                 "2.5x denser beyond 65° (table.tile_view_grid), interpolated by following the lobe (view_shift), "
                 "sharp materials averaged over sub-cells (table.material_sub); "
                 f"explicit {n}x{n} tiles on a 4 m plane, orthographic 0.4 m views, 32x32 px x {spp} spp x "
                 f"{args.seeds} seeds, explicit images the mean of {args.shifts} camera offsets; direction-coded "
                 f"world 0.5+0.5d + area lamp 300 W at (-1.5, 1, 2.5) size 1.5 (NEE on); GI: {GI_BOUNCES} bounces.")
    del addon
    return 0
