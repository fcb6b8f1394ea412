"""Bi-scale ground truth: explicit tiles rendered by Cycles vs the baked material (Wu et al. 2011).

The tile is repeated 100 x 100 on a 4 m plane with its small-scale materials as ordinary Cycles
BSDFs (``scratch_addon.biscale_truth``); the baked material covers a plain plane.  Both are seen by an
orthographic camera along several views, lit by a direction-coded environment (0.5 + 0.5 d) plus an
area lamp (NEE on), ``max_bounces`` 0 (direct light: Wu's model) or 16 (full GI).  Baked: the closure
table (Wu's single bounce), the same plus the inter-reflections inside the tile
(``precompute.biscale.interreflect``; GI rows), optionally the fitted closures of both (``--fit``).
Error per view: max over RGB of |mean(baked) - mean(explicit)| / mean(explicit), next to its render
noise (1σ, from two seeds per image: ``render_set(noise=True)``).

``--svm``: the baked materials render on Cycles SVM (the default shading system, and GPU): the closure table
through its node graph (``node_groups.tabulated_svm``, view grid included), the fits as nodes; the explicit
tiles (ordinary BSDFs) render on SVM too; every baked material is rendered on OSL as well in the same run
(rows "... (OSL)"), the same bake and explicit frames.  Output ``bench/out/biscale_truth_svm.md``.

    .venv/bin/python -m bench biscale_truth [--quick] [--fit] [--gi] [--svm] [--spp 64] [--seeds 2] [--figure]
        [--views "75/0,80/180"] [--bake-seeds 0,1] [--no-osl] [--tiles "..."] [--tag name]

``--views``: other views (θo/φo degrees); ``--bake-seeds``: several bakes in one run against the same explicit
frames (rows "table s0", "table s1"); ``--no-osl`` with ``--svm``: SVM rows only (``bench/out/biscale_truth_svm_views.md``).
"""
from __future__ import annotations

import argparse
import math
import tempfile
import time

import numpy as np

TILES = {
    # name: (tile factory kwargs, small-scale materials)
    "pyramid (diffuse)": ("pyramid_tile", dict(height=0.5), [{"model": "lambert", "albedo": (0.8, 0.6, 0.4)},
                                                            {"model": "lambert", "albedo": 0.5}]),
    "groove (diffuse + glossy)": ("groove_tile", dict(depth=0.4),
                                  [{"model": "lambert", "albedo": 0.7},
                                   {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.2, "F0": 1.0,
                                    "ks": 0.8},
                                   {"model": "lambert", "albedo": (0.2, 0.5, 0.8)}]),
    # a user's default Glossy BSDF (Multiscatter GGX, Roughness 0.5, colour 0.8) as the groove's walls
    "groove (default Glossy: Multiscatter GGX)": ("groove_tile", dict(depth=0.4),
                                                  [{"model": "lambert", "albedo": 0.7},
                                                   {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.25,
                                                    "fresnel": "none", "multiscatter": True, "F0": 1.0, "ks": 0.8},
                                                   {"model": "lambert", "albedo": (0.2, 0.5, 0.8)}]),
    # Principled BSDFs (Multiscatter GGX, the node's default): a metal floor, dielectric walls
    "pyramid (Principled: metal floor and dielectric sides)": (
        "pyramid_tile", dict(height=0.4, base=0.7),
        [{"model": "principled", "base_color": (0.9, 0.6, 0.3), "metallic": 1.0, "roughness": 0.4, "multiscatter": True},
         {"model": "principled", "base_color": (0.2, 0.5, 0.8), "metallic": 0.0, "roughness": 0.5, "multiscatter": True}]),
    "pyramid (glossy sides on diffuse floor)": ("pyramid_tile", dict(height=0.4, base=0.7),
                                                 [{"model": "lambert", "albedo": (0.7, 0.5, 0.3)},
                                                  {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3,
                                                   "F0": 1.0, "ks": 0.7, "kd": 0.2}]),
}
VIEWS = [(0.0, 0.0), (35.0, 0.0), (60.0, 90.0), (60.0, 20.0)]   # (θo, φo) degrees
GI_BOUNCES = 16


def _view(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def render_pair(tile, materials, mat, views, n=300, spp=64, res=32, bounces=0, lamp=True, tmp=None):
    """Mean RGB of the explicit tiles and of ``mat`` on a plane for each view; returns (explicit, baked, seconds)."""
    ex, bk, secs = render_set(tile, materials, {"baked": mat}, views, n=n, spp=spp, res=res, bounces=bounces,
                              lamp=lamp, tmp=tmp)
    return ex, bk["baked"], secs


def camera_shifts(k: int) -> np.ndarray:
    """``k`` offsets of the camera (fractions of the tile period, (k, 2)) stratified over the period cell:
    a rank-1 lattice (i / k, frac(i φ)), φ the golden ratio.  The explicit frame mean over a footprint
    that holds a non-integer number of periods depends on where the footprint starts (groove, 35° view,
    0.4 m footprint = 12.2 periods: ±1.2 % over 8 offsets, measured); averaging over offsets uniform in
    the cell makes it the tile average that the baked material stands for, whatever the footprint.

    The lattice is centred (its mean subtracted: mean offset 0), so the shifted footprints average to the baked
    plane's footprint, centred on the origin.  Uncentred (offsets in [0, 1)², mean (0.375, 0.427) periods for k = 4)
    the explicit footprint sat ~1.6 cm beside the baked one: under the area lamp 3 m away the metal floor's highlight
    tail falls ~10 % per (4, 4) cm (the lamp's direction turns ~1° per 5 cm; Principled pyramid 55/300), so the
    explicit frame was ~4 % darker than eq. 8 (floor-only tiles, black world: 1.9732 vs 2.0547 red; centred 2.0544)."""
    i = np.arange(int(k))
    lattice = np.stack([i / k, np.mod(i * 0.5 * (1 + 5 ** 0.5), 1.0)], 1)
    return lattice - lattice.mean(0)


def frame_mean_se(imgs):
    """Frame mean (3,) of renders ``imgs`` (seeds, pixels, 3) of one image with different seeds, and its
    standard error (3,): the per-pixel variance across seeds (ddof 1; the image's fixed spatial pattern
    cancels) averaged over the pixels, / (pixels x seeds).  NaN with one seed."""
    imgs = np.asarray(imgs, np.float64)
    mean = imgs.mean((0, 1))
    if imgs.shape[0] < 2:
        return mean, np.full(imgs.shape[-1], np.nan)
    return mean, np.sqrt(imgs.var(0, ddof=1).mean(0) / (imgs.shape[0] * imgs.shape[1]))


#: orthographic view width (m) of the truth renders, and the margin (m) kept between the footprint and the plane's edge
ORTHO_SCALE, EDGE_MARGIN = 0.4, 0.5


def plane_size(views) -> float:
    """Side (m) of the truth planes: 4 m, or more when a grazing view's footprint (ORTHO_SCALE / cos θo along the
    view) would come within EDGE_MARGIN of the edge — at 85° a 4 m plane filled only 87 % of the frame and the
    frame's far side showed the explicit array's last row of tiles, unshadowed by neighbours the baked plane assumes."""
    cos_min = min(max(abs(float(np.asarray(w)[2])), 1e-3) for w in views)
    return max(4.0, 2.0 * (0.5 * ORTHO_SCALE / cos_min + EDGE_MARGIN))


def render_set(tile, materials, mats: dict, views, n=300, spp=64, res=32, bounces=0, lamp=True, tmp=None,
               seed=7, seeds=None, noise=False, shifts=1, osl=True):
    """Mean RGB per view of the explicit tiles (rendered once per seed) and of every baked material in
    ``mats`` (name -> material) on a plane: returns (explicit (V, 3), {name: (V, 3)}, seconds per kind),
    and with ``noise=True`` a fourth item, the standard error of each mean ({"explicit" | name: (V, 3)}).

    Noise: every kind is rendered with each seed of ``seeds`` (default (seed, seed + 1)); the per-pixel
    Monte Carlo variance is the across-seed sample variance (ddof 1) averaged over the pixels (the
    pixels' fixed spatial pattern cancels: only the seeds differ), so the standard error of the
    frame mean (pixels independent) is sqrt(var_pix / (pixels x seeds)).

    ``shifts`` > 1: each image is the pixel mean of renders with the camera moved by ``camera_shifts``
    (x the tile's world period ``4 m / n``) at ``spp // shifts`` samples each (same total samples), so the
    explicit mean is the tile average, not one footprint's phase; the seeds see the same offsets, so the
    noise estimate stays the Monte Carlo noise only.  ``osl``: Cycles' shading system (False: SVM, what a
    default scene and the GPU render), or a dict kind -> bool ("explicit" or a key of ``mats``; missing: OSL)."""
    import bpy

    from scratch_materials.scratch_addon import biscale_truth, render

    seeds = tuple(seeds) if seeds is not None else ((seed, seed + 1) if noise else (seed,))
    tmp = tmp or tempfile.mkdtemp()
    size = plane_size(views)
    n = int(round(n * size / 4.0))                  # the tile's world period stays 4 m / n
    scene = bpy.context.scene
    out = {k: [] for k in ["explicit", *mats]}
    se = {k: [] for k in out}
    secs = {k: 0.0 for k in out}
    for kind in out:
        for o in list(scene.objects):
            bpy.data.objects.remove(o)
        biscale_truth.direction_world(scene, "first")
        if lamp:
            render.add_light(scene, "AREA", location=(-1.5, 1.0, 2.5), energy=300.0, size=1.5)
        if kind == "explicit":
            biscale_truth.explicit_tile_plane(scene, tile, materials, n=n, size=size)
        else:
            render.add_plane(scene, size=size, material=mats[kind])
        for wo in views:
            up = (0, 1, 0) if abs(wo[2]) > 0.999 else None
            imgs = np.zeros((len(seeds), res * res, 3))
            offs = camera_shifts(shifts) * (size / n) if kind == "explicit" else np.zeros((1, 2))
            for off in offs:
                for c in [o for o in scene.objects if o.type == "CAMERA"]:
                    bpy.data.objects.remove(c)
                tgt = np.array([off[0], off[1], 0.0])
                loc = tuple(tgt + 5 * wo + (np.array([0, -1e-3, 0]) if up else 0))
                render.add_camera(scene, location=loc, target=tuple(tgt), ortho_scale=ORTHO_SCALE)
                for j, sd in enumerate(seeds):
                    render.configure_cycles(scene, samples=max(1, spp // len(offs)), res=(res, res), seed=sd,
                                            osl=osl.get(kind, True) if isinstance(osl, dict) else osl,
                                            max_bounces=bounces)
                    img, s = render.render_array(scene, tmp, "explicit" if kind == "explicit" else "baked")
                    imgs[j] += img.reshape(-1, 3).astype(np.float64) / len(offs)
                    secs[kind] += s                                 # imgs: (seeds, pixels, 3)
            m, e = frame_mean_se(imgs)
            out[kind].append(m)
            se[kind].append(e)
    ex = np.array(out.pop("explicit"))
    res_ = (ex, {k: np.array(v) for k, v in out.items()}, secs)
    if noise:
        return (*res_, {k: np.array(v) for k, v in se.items()})
    return res_


def rel_error(ex, bk, se_ex=None, se_bk=None):
    """Per view: (max over RGB of |bk - ex| / mean(ex), the 1-sigma noise of that channel's difference
    relative to mean(ex), sqrt(se_ex² + se_bk²) / mean(ex)).  Arrays (V, 3)."""
    ex, bk = np.asarray(ex), np.asarray(bk)
    d = np.abs(bk - ex)
    c = d.argmax(1)
    err = d.max(1) / ex.mean(1)
    if se_ex is None:
        return err, np.full(len(err), np.nan)
    s = np.sqrt(np.asarray(se_ex) ** 2 + (0 if se_bk is None else np.asarray(se_bk)) ** 2)
    return err, s[np.arange(len(c)), c] / ex.mean(1)


def bake_variants(tile, mats, n_facets=10000, dir_res=10, fit=False, view="auto", seed=0, indirect=True):
    """The baked materials' tables for one tile: the direct (Wu) closure table, the same plus the
    inter-reflected part (``interreflect.tile_indirect``), optionally the closure fits of both.
    ``indirect=False`` (and no ``fit``): only the direct table (no inter-reflection pass; info None).
    Returns (dict name -> (TabulatedBRDF | ClosureFit, EffectiveBRDF), timings, indirect info)."""
    from scratch_materials.precompute.biscale import interreflect
    from scratch_materials.precompute.biscale import table as btable
    from scratch_materials.precompute.biscale.effective import BiscaleTile, EffectiveBRDF
    from scratch_materials.precompute.biscale.fit import fit_closures

    t0 = time.perf_counter()
    bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=n_facets, dir_res=dir_res, seed=seed)
    brdf = bt.effective_brdf(mats)
    t_eff = time.perf_counter() - t0
    t0 = time.perf_counter()
    table = btable.tabulate_tile(bt, mats, view=view)   # the closure's finer table (direct, eq. 8)
    t_tab = time.perf_counter() - t0
    vg = {"view_a": table.view_a, "view_b": table.view_b, "view_shift": table.view_shift, "view_anchor": table.view_anchor} if table.view_a is not None else {}
    if not indirect and not fit:
        return {"table": (table, brdf)}, {"effective (dir_res %d)" % dir_res: t_eff, "table": t_tab}, None
    ind, info = interreflect.tile_indirect(bt, mats, True, view=table.view_nodes() if vg else None)
    r = info["res"]
    add = interreflect.resample_wi(ind, r, table.res) if vg else interreflect.resample(ind, r, table.res)
    table_gi = btable.with_indirect(table, add)
    add = interreflect.resample_views(ind, r, vg["view_a"], vg["view_b"], brdf.dir_res) if vg else \
        interreflect.resample(ind, r, brdf.dir_res)
    brdf_gi = EffectiveBRDF(brdf.table + add, brdf.dir_res, brdf.info)
    out = {"table": (table, brdf), "table + inter-refl.": (table_gi, brdf_gi)}
    if fit:
        out["fit"] = (fit_closures(brdf), brdf)
        out["fit + inter-refl."] = (fit_closures(brdf_gi), brdf_gi)
    times = {"effective (dir_res %d)" % dir_res: t_eff, "table": t_tab, "inter-refl.": info["seconds"]}
    return out, times, info


def _material(name, obj, brdf):
    from scratch_materials.scratch_addon import biscale_material

    if name.startswith("fit"):
        return biscale_material.make_biscale_material(obj, name=name, mode="fit", brdf=brdf)
    return biscale_material.make_biscale_material(None, name=name, mode="table", brdf=brdf, table=obj)


def main(argv: list[str]) -> int:
    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="bench biscale_truth")
    ap.add_argument("--quick", action="store_true", help="2000 facets, 100 x 100 tiles, 2 views")
    ap.add_argument("--fit", action="store_true", help="also the fitted closures (with and without inter-reflections)")
    ap.add_argument("--gi", action="store_true", help="also full global illumination (16 bounces)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=2, help="renders per image (noise estimate from the seeds, >= 2)")
    ap.add_argument("--shifts", type=int, default=4, help="camera offsets over the tile period per explicit image")
    ap.add_argument("--tiles", default=",".join(TILES))
    ap.add_argument("--bake-seed", type=int, default=0, help="seed of the bake (facets, indirect paths)")
    ap.add_argument("--figure", action="store_true", help="only the side-by-side figure (docs/img/biscale_truth.png)")
    ap.add_argument("--svm", action="store_true", help="render on Cycles SVM (the default shading system) instead of OSL")
    ap.add_argument("--views", default="", help="views 'θo/φo,θo/φo,...' in degrees (default: 0/0,35/0,60/90,60/20)")
    ap.add_argument("--bake-seeds", default="", help="several bake seeds '0,1' in one run (the explicit frames shared); "
                                                      "overrides --bake-seed")
    ap.add_argument("--no-osl", action="store_true", help="with --svm: skip the OSL rows")
    ap.add_argument("--tag", default="", help="suffix of the output name (bench/out/biscale_truth[_svm]_<tag>.md)")
    args = ap.parse_args(argv)
    addon = blender()
    from scratch_materials.precompute.biscale import geometry
    from scratch_materials.scratch_addon import render

    render.reset_scene()
    if args.figure:
        return figure(args.spp)
    views = VIEWS[:2] if args.quick else VIEWS
    if args.views:
        views = [tuple(float(x) for x in v.split("/")) for v in args.views.split(",")]
        if any(len(v) != 2 or not 0 <= v[0] < 90 for v in views):
            raise ValueError(f"--views: expected 'θo/φo,...' with 0 <= θo < 90 (degrees), got {args.views!r}")
    bake_seeds = [int(x) for x in args.bake_seeds.split(",")] if args.bake_seeds else [args.bake_seed]
    n = 100
    rows = []
    for name in args.tiles.split(","):
        factory, kw, mats = TILES[name]
        tile = getattr(geometry, factory)(**kw)
        variants, bake_s = {}, []
        for bs in bake_seeds:
            var, times, info = bake_variants(tile, mats, n_facets=2000 if args.quick else 10000, fit=args.fit,
                                             seed=bs, indirect=args.gi)
            variants.update({(k if len(bake_seeds) == 1 else f"{k} s{bs}"): v for k, v in var.items()})
            bake_s.append(" / ".join(f"{k} {v:.1f}" for k, v in times.items()))
            if var["table"][0].view_a is not None:
                print(name, "bake seed", bs, "view nodes a (deg)", np.round(np.degrees(var["table"][0].view_a), 2).tolist(),
                      "b", np.round(np.degrees(var["table"][0].view_b), 2).tolist(), flush=True)
        bake_s = " ; ".join(bake_s)
        for bounces in ([0, GI_BOUNCES] if args.gi else [0]):
            use = [k for k in variants if bounces or "inter-refl." not in k]
            mats_bl = {k: _material(f"{name} {k}", *variants[k]) for k in use}
            osl = True
            if args.svm:        # each baked material on SVM and on OSL; the explicit tiles on SVM
                mats_bl = {f"{k} ({p})": m for k, m in mats_bl.items() for p in (("SVM",) if args.no_osl else ("SVM", "OSL"))}
                osl = {"explicit": False, **{k: k.endswith("(OSL)") for k in mats_bl}}
                use = list(mats_bl)
            ex, bk, secs, se = render_set(tile, mats, mats_bl, [_view(*v) for v in views], n=n, spp=args.spp,
                                          bounces=bounces, noise=True, seeds=range(7, 7 + args.seeds),
                                          shifts=args.shifts, osl=osl)
            for k in use:
                err, sig = rel_error(ex, bk[k], se["explicit"], se[k])
                for v, e, sg, a, b in zip(views, err, sig, ex, bk[k]):
                    rows.append([name, k, "direct" if bounces == 0 else f"GI ({bounces})", f"{v[0]:.0f}/{v[1]:.0f}",
                                 f"{100 * e:.1f} %", f"{100 * sg:.2f} %", np.round(a, 4).tolist(),
                                 np.round(b, 4).tolist(), bake_s])
                    print(rows[-1], flush=True)
        if info is not None:
            print(name, "indirect estimate", info["estimate"], flush=True)
    report(("biscale_truth_svm" if args.svm else "biscale_truth") + (f"_{args.tag}" if args.tag else ""), ["tile", "baked", "light", "view θo/φo", "max rel. err", "render noise 1σ", "explicit RGB", "baked RGB",
                             "bake s"], rows,
           notes=f"views {' '.join(f'{a:g}/{b:g}' for a, b in views)}; shading system {'SVM (explicit tiles and the rows (SVM): the baked table through its node graph; rows (OSL): the same material on OSL in the same run)' if args.svm else 'OSL'}; "
                 f"bake seed(s) {','.join(map(str, bake_seeds))}; explicit: {n} tiles per 4 m on a {plane_size([_view(*v) for v in views]):.1f} m plane (larger than 4 m only for views beyond ~78°: plane_size), orthographic 0.4 m views, 32x32 px x {args.spp} spp x "
                 f"{args.seeds} seeds, each explicit image the mean of {args.shifts} camera offsets over the tile period at "
                 f"spp/{args.shifts} (render noise 1σ: standard error of the difference of the two frame means, "
                 "from the across-seed per-pixel variance, explicit and baked; it does not include the bake's own "
                 "Monte Carlo noise (facet sampling, the indirect table's paths)), "
                 "direction-coded world 0.5+0.5d + area lamp (NEE on); GI: max bounces "
                 f"{GI_BOUNCES} for the explicit tiles (the baked plane has nothing to bounce off). 'table': Wu's "
                 "single-bounce effective BRDF (closure table: ωi res 31, ωo on a 31 x 31 view grid of projected view "
                 "angles, 2.5x denser beyond 65°, with the tile's visibility events on nodes, table.tile_view_grid, "
                 "interpolated between them by following the lobe, TabulatedBRDF.view_shift; "
                 "above MAX_FLOATS: rendered through the node graph on SVM and on OSL); '+ inter-refl.': plus "
                 "bounces >= 2 inside the periodic tile (precompute.biscale.interreflect: res 10 x 529 paths per "
                 "direction for diffuse tiles, res 19 x 289 for the GGX α 0.2 groove, interreflect.indirect_res; first "
                 "bounce QMC-stratified; computed at the view nodes, the camera-side and light-side estimators "
                 "combined by MIS)")
    del addon
    return 0


def figure(spp: int = 64) -> int:
    """Explicit tiles (full GI) | table + inter-reflections | Wu's single-bounce table, for the groove tile
    (diffuse + glossy) at θo = 35°, 16 bounces, 96x96 px; saved as docs/img/biscale_truth.png."""
    import bpy

    from bench._util import ROOT, pyplot
    from scratch_materials.precompute.biscale import geometry
    from scratch_materials.scratch_addon import biscale_truth, render

    name = "groove (diffuse + glossy)"
    factory, kw, mats = TILES[name]
    tile = getattr(geometry, factory)(**kw)
    variants, _, _ = bake_variants(tile, mats, n_facets=10000, dir_res=10)
    tmp = tempfile.mkdtemp()
    imgs = []
    scene = bpy.context.scene
    kinds = ("explicit", "table + inter-refl.", "table")
    for kind in kinds:
        for o in list(scene.objects):
            bpy.data.objects.remove(o)
        biscale_truth.direction_world(scene, "first")
        render.add_light(scene, "AREA", location=(-1.5, 1.0, 2.5), energy=300.0, size=1.5)
        if kind == "explicit":
            biscale_truth.explicit_tile_plane(scene, tile, mats, n=100, size=4.0)
        else:
            render.add_plane(scene, size=4.0, material=_material(kind, *variants[kind]))
        render.add_camera(scene, location=tuple(5 * _view(35, 0)), target=(0, 0, 0), ortho_scale=1.2)
        render.configure_cycles(scene, samples=spp, res=(96, 96), seed=7, osl=True, max_bounces=GI_BOUNCES)
        img, _ = render.render_array(scene, tmp, "fig")
        imgs.append(img)
    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(9, 3.8))
    titles = ("explicit grooves, 16 bounces", "table + inter-reflections", "table, single bounce (Wu)")
    ref = imgs[0].reshape(-1, 3).mean(0)
    for a, im, title in zip(ax, imgs, titles):
        a.imshow(np.clip(im / max(float(imgs[0].max()), 1e-6), 0, 1) ** (1 / 2.2))
        m = im.reshape(-1, 3).mean(0)
        a.set_title(f"{title}\nmean {m.mean():.3f} ({100 * (m.mean() / ref.mean() - 1):+.1f} %)", fontsize=9)
        a.axis("off")
    fig.suptitle("bi-scale groove (diffuse floor, GGX α 0.2 walls), θo = 35°, full GI", fontsize=10)
    fig.tight_layout()
    out = ROOT / "docs" / "img" / "biscale_truth.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    print(out, [float(im.mean()) for im in imgs])
    return 0
