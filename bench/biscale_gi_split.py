"""Bi-scale inter-reflections split exactly, numpy only (issue 16 item 3): the tile's inter-reflected radiance at one
view under the audit scene's light (direction-coded world 0.5 + 0.5 d + the area lamp, ``biscale_truth_audit``), from

* **reference**: an independent Monte Carlo path tracer of the periodic tile (its own GGX / Lambert evaluation and
  sampling, primary rays cast through the footprint with ``interreflect.periodic_ray_cast``, world by BSDF-sampled
  escapes, lamp by next-event estimation with a shadow ray per vertex), per bounce order;
* **raw**: ``interreflect.indirect_table`` at exactly that view (no view grid, no ωi grid: ωi = the quadrature's and
  the lamp's directions; camera-side estimator only, no MIS);
* **baked**: what the bench renders, the closure table's inter-reflected part ``tile_indirect(view=view nodes)``
  resampled onto the table's ωi grid (``resample_wi``) and read by ``TabulatedBRDF.eval`` (bilinear in ωi and in the
  view), and the bake's own path (``bake.INDIRECT_VIEW_NODES`` coarse grid + ``resample_view_nodes``).

The lamp is given as directions from the tile (it is 3 m away, the views 0.4 m): radiance 1, so the lamp columns are
per unit lamp radiance (Cycles' area lamp radiance: ``LAMP_RADIANCE``).

    .venv/bin/python -m bench biscale_gi_split [--tile box] [--view 65/225] [--paths 200000] [--quick]
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

#: Cycles area lamp of power P (W) and area A: radiance P / (π A) per unit colour (300 W, 1.5 m square).
LAMP_RADIANCE = 300.0 / (math.pi * 1.5 * 1.5)


def lamp_points(n, rng):
    """Directions (n, 3) from the origin to uniform points of the audit's area lamp (1.5 m square at (-1.5, 1, 2.5)
    facing the origin) and their solid-angle weights cos_lamp / r² A / n (sr)."""
    c = np.array([-1.5, 1.0, 2.5])
    nrm = -c / np.linalg.norm(c)
    u = np.cross(nrm, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    st = rng.uniform(-0.75, 0.75, (n, 2))
    P = c + st[:, :1] * u + st[:, 1:] * v
    r2 = np.sum(P * P, 1)
    d = P / np.sqrt(r2)[:, None]
    return d, np.clip(np.sum(-d * nrm, 1), 0, None) / r2 * (1.5 * 1.5) / n


def env(d):
    """The direction-coded world 0.5 + 0.5 d (RGB = xyz)."""
    return 0.5 + 0.5 * d


# ------------------------------------------------------------------ independent small-scale BRDFs (Cycles' twins)
def _ggx_lambda(c, a2):
    c = np.clip(c, 1e-9, 1.0)
    return 0.5 * (-1 + np.sqrt(1 + a2 * (1 - c * c) / (c * c)))


def brdf(mat, n, wi, wo):
    """f(ωi, ωo) (N, 3): Lambert albedo / π, or kd / π + ks D G2 / (4 cos cos) (GGX, height-correlated Smith,
    F = 1: Cycles' Diffuse + Glossy GGX)."""
    ci, co = (n * wi).sum(-1), (n * wo).sum(-1)
    ok = (ci > 0) & (co > 0)
    if mat["model"] == "lambert":
        f = np.broadcast_to(np.asarray(mat["albedo"], float), (len(ci), 3)) / np.pi
        return np.where(ok[:, None], f, 0.0)
    a2 = mat["alpha"] ** 2
    h = wi + wo
    h /= np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    nh = np.clip((n * h).sum(-1), 0, 1)
    D = a2 / (np.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    G = 1 / (1 + _ggx_lambda(ci, a2) + _ggx_lambda(co, a2))
    spec = D * G / (4 * np.maximum(ci, 1e-9) * np.maximum(co, 1e-9))
    kd = np.broadcast_to(np.asarray(mat.get("kd", 0.0), float), 3)
    f = kd[None] / np.pi + mat.get("ks", 1.0) * spec[:, None]
    return np.where(ok[:, None], f, 0.0)


def _frame(n):
    a = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    t = np.cross(n, a)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def sample(mats, m, n, wo, rng):
    """Next direction: cosine (Lambert) or ½ cosine + ½ GGX half vector (GGX materials); returns (ω, f cos / pdf)."""
    N = len(n)
    t, b = _frame(n)
    u1, u2, pick = rng.random(N), rng.random(N), rng.random(N)
    phi = 2 * np.pi * u2
    r = np.sqrt(u1)
    wc = (r * np.cos(phi))[:, None] * t + (r * np.sin(phi))[:, None] * b + np.sqrt(1 - u1)[:, None] * n
    alpha = np.array([mm.get("alpha", np.nan) if mm["model"] != "lambert" else np.nan for mm in mats])[m]
    glossy = np.isfinite(alpha)
    a = np.where(glossy, alpha, 1.0)
    tan2 = a * a * u1 / np.maximum(1 - u1, 1e-12)
    ch = 1 / np.sqrt(1 + tan2)
    sh = np.sqrt(np.maximum(1 - ch * ch, 0))
    hv = (sh * np.cos(phi))[:, None] * t + (sh * np.sin(phi))[:, None] * b + ch[:, None] * n
    ws = 2 * (wo * hv).sum(1, keepdims=True) * hv - wo
    spec = glossy & (pick < 0.5)
    w = np.where(spec[:, None], ws, wc)
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    cos = (n * w).sum(1)
    hm = w + wo
    hm /= np.maximum(np.linalg.norm(hm, axis=1, keepdims=True), 1e-300)
    nh = np.clip((n * hm).sum(1), 0, 1)
    a2 = a * a
    pdf_s = a2 / (np.pi * (nh * nh * (a2 - 1) + 1) ** 2) * nh / np.maximum(4 * np.abs((wo * hm).sum(1)), 1e-12)
    pdf_c = np.maximum(cos, 0) / np.pi
    pdf = np.where(glossy, 0.5 * pdf_c + 0.5 * pdf_s, pdf_c)
    f = np.zeros((N, 3))
    for mi in np.unique(m):
        s = m == mi
        f[s] = brdf(mats[mi], n[s], w[s], wo[s])
    wgt = np.where(((cos > 0) & (pdf > 0))[:, None], f * np.maximum(cos, 0)[:, None] / np.maximum(pdf, 1e-300)[:, None], 0.0)
    return w, wgt


def reference(tile, mats, wo, n_paths=200_000, max_order=12, n_lamp=1, seed=1, chunk=50_000):
    """Radiance towards ``wo`` per bounce order k = 1 (direct) .. max_order, (max_order, 2, 3): [k-1, 0] the world
    (0.5 + 0.5 d), [k-1, 1] the lamp at radiance 1; and the per-path standard errors (same shape)."""
    from scratch_materials.precompute.biscale.geometry import face_geometry
    from scratch_materials.precompute.biscale.interreflect import _CellGrid, periodic_ray_cast

    P = float(tile.period)
    tri = tile.vertices[tile.faces]
    _, fn = face_geometry(tile.vertices, tile.faces)
    fmat = np.asarray(tile.face_material)
    grid = _CellGrid(tri, P)
    eps = 1e-7 * (P + grid.zmax - grid.zmin)
    rng = np.random.default_rng(seed)
    s1 = np.zeros((max_order, 2, 3))
    s2 = np.zeros((max_order, 2, 3))
    n_done = 0
    while n_done < n_paths:
        N = min(chunk, n_paths - n_done)
        per = np.zeros((N, max_order, 2, 3))
        o = np.concatenate([rng.random((N, 2)) * P, np.full((N, 1), grid.zmax + 1e-3)], 1)
        d = np.broadcast_to(-wo, (N, 3)).copy()
        _, fid, pos = periodic_ray_cast(tri, P, o, d, grid=grid)
        idx = np.flatnonzero(fid >= 0)
        pos, fid, wprev = pos[idx], fid[idx], -d[idx]
        beta = np.ones((len(idx), 3))
        for k in range(max_order):
            if len(idx) == 0:
                break
            n = fn[fid]
            m = fmat[fid]
            # lamp: next-event estimation, shadow ray through the repeated tile
            dl, wl = lamp_points(len(idx), rng)
            wl = wl * len(idx)                          # one lamp point per vertex
            f = np.zeros((len(idx), 3))
            for mi in np.unique(m):
                s = m == mi
                f[s] = brdf(mats[mi], n[s], dl[s], wprev[s])
            cosl = np.clip((n * dl).sum(1), 0, None)
            _, occ, _ = periodic_ray_cast(tri, P, pos + eps * n, dl, grid=grid)
            vis = (occ < 0) & (cosl > 0)
            per[idx, k, 1] += beta * f * (cosl * wl * vis)[:, None]
            # world: BSDF-sampled escape (counts as order k: light reflected k times)
            w, wgt = sample(mats, m, n, wprev, rng)
            b2 = beta * wgt
            _, nid, npos = periodic_ray_cast(tri, P, pos + eps * n, w, grid=grid)
            esc = (nid < 0) & (w[:, 2] > 0)
            per[idx[esc], k, 0] += b2[esc] * env(w[esc])
            keep = (nid >= 0) & (b2.max(1) > 0)
            if k >= 3:                                  # Russian roulette
                q = np.clip(b2.max(1), 0.05, 1.0)
                keep &= rng.random(len(q)) < q
                b2 = b2 / q[:, None]
            nn = fn[nid[keep]]
            front = (nn * -w[keep]).sum(1) > 0
            sel = np.flatnonzero(keep)[front]
            idx, pos, fid, wprev, beta = idx[sel], npos[sel], nid[sel], -w[sel], b2[sel]
        s1 += per.sum(0)
        s2 += (per ** 2).sum(0)
        n_done += N
    mean = s1 / n_done
    se = np.sqrt(np.maximum(s2 / n_done - mean ** 2, 0) / n_done)
    return mean, se


def table_radiance(fn, wo, n_lamp=4000, n_theta=48, n_phi=96, seed=2):
    """(world, lamp) radiance towards ``wo`` of a BRDF ``fn(wi (N, 3), wo (N, 3)) -> (N, 3)``: world by the
    midpoint rule, lamp by ``n_lamp`` points (radiance 1)."""
    from scratch_materials.precompute.tables.tabulated_brdf import hemisphere_midpoints

    wi, dw = hemisphere_midpoints(n_theta, n_phi)
    Le = (fn(wi, np.broadcast_to(wo, wi.shape)) * (wi[:, 2] * dw)[:, None] * env(wi)).sum(0)
    dl, wl = lamp_points(n_lamp, np.random.default_rng(seed))
    Ll = (fn(dl, np.broadcast_to(wo, dl.shape)) * (dl[:, 2] * wl)[:, None]).sum(0)
    return Le, Ll


def main(argv):
    from bench.biscale_truth_audit import AUDIT_TILES, _view
    from scratch_materials.precompute.biscale import bake, interreflect
    from scratch_materials.precompute.biscale import table as btable
    from scratch_materials.precompute.biscale.effective import BiscaleTile
    from scratch_materials.precompute.tables.tabulated_brdf import TabulatedBRDF, hemisphere_midpoints, view_directions

    ap = argparse.ArgumentParser(prog="bench biscale_gi_split")
    ap.add_argument("--tile", default="box")
    ap.add_argument("--view", default="65/225")
    ap.add_argument("--paths", type=int, default=200_000)
    ap.add_argument("--n-facets", type=int, default=10000)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-baked", action="store_true", help="reference and raw only")
    args = ap.parse_args(argv)
    th, ph = (float(x) for x in args.view.split("/"))
    wo = _view(th, ph)
    builder, mats = AUDIT_TILES[args.tile]
    tile = builder()
    t0 = time.process_time()
    ref, se = reference(tile, mats, wo, n_paths=20_000 if args.quick else args.paths)
    print(f"reference ({time.process_time() - t0:.0f} s CPU), per order [world, lamp]:")
    for k in range(len(ref)):
        print(f"  order {k + 1}: world {np.round(ref[k, 0], 4)} ± {np.round(se[k, 0], 4)}   lamp {np.round(ref[k, 1], 4)} ± {np.round(se[k, 1], 4)}")
    ind_ref = ref[1:].sum(0)
    ind_se = np.sqrt((se[1:] ** 2).sum(0))
    print("reference orders >= 2: world", np.round(ind_ref[0], 4), "±", np.round(ind_se[0], 4),
          " lamp", np.round(ind_ref[1], 4), "±", np.round(ind_se[1], 4))
    Lr = LAMP_RADIANCE
    print("  frame (world + lamp x", round(Lr, 2), "):", np.round(ind_ref[0] + Lr * ind_ref[1], 4))

    bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=args.n_facets, dir_res=10, seed=0)
    # raw: indirect_table at exactly wo, ωi = the quadrature's and the lamp's directions (camera side only)
    wq, dw = hemisphere_midpoints(16, 32)
    dl, wl = lamp_points(200, np.random.default_rng(2))
    t0 = time.process_time()
    tab, _ = interreflect.indirect_table(bt, mats, res=interreflect.indirect_res(mats), n_paths=4096,
                                         seed=3, wo=wo[None], wi=np.concatenate([wq, dl]), mis=False)
    raw_e = (tab[:len(wq), 0] * (wq[:, 2] * dw)[:, None] * env(wq)).sum(0)
    raw_l = (tab[len(wq):, 0] * (dl[:, 2] * wl)[:, None]).sum(0)
    print(f"raw indirect_table at wo ({time.process_time() - t0:.0f} s CPU): world", np.round(raw_e, 4),
          "lamp", np.round(raw_l, 4), "frame", np.round(raw_e + Lr * raw_l, 4))
    if args.no_baked:
        return 0
    t0 = time.process_time()
    table = btable.tabulate_tile(bt, mats, view="auto")
    print(f"direct table ({time.process_time() - t0:.0f} s CPU), res {table.res}, view nodes {table.n_o}")
    de, dlm = table_radiance(table.eval, wo)
    print("  direct table: world", np.round(de, 4), "lamp", np.round(dlm, 4), " reference order 1: world",
          np.round(ref[0, 0], 4), "lamp", np.round(ref[0, 1], 4))
    vg = {"view_a": table.view_a, "view_b": table.view_b}
    t0 = time.process_time()
    ind, info = interreflect.tile_indirect(bt, mats, True, view=table.view_nodes())
    r = info["res"]
    tgi = TabulatedBRDF(interreflect.resample_wi(ind, r, table.res), table.res, False, {}, **vg)
    be, bl = table_radiance(tgi.eval, wo)
    print(f"baked (bench path: traced at the {table.n_o} view nodes, res {r}, {info['n_paths']} paths; "
          f"{time.process_time() - t0:.0f} s CPU): world", np.round(be, 4), "lamp", np.round(bl, 4),
          "frame", np.round(be + Lr * bl, 4))
    t0 = time.process_time()
    coarse = btable.tile_view_grid(bt, bake.INDIRECT_VIEW_NODES, bake.INDIRECT_VIEW_NODES)
    ind2, info2 = interreflect.tile_indirect(bt, mats, True, view=view_directions(*coarse))
    ind2 = interreflect.resample_view_nodes(ind2, *coarse, table.view_nodes())
    tgi2 = TabulatedBRDF(interreflect.resample_wi(ind2, r, table.res), table.res, False, {}, **vg)
    be2, bl2 = table_radiance(tgi2.eval, wo)
    print(f"baked (bake_tables path: coarse {bake.INDIRECT_VIEW_NODES}² view nodes; {time.process_time() - t0:.0f} s CPU):"
          " world", np.round(be2, 4), "lamp", np.round(bl2, 4), "frame", np.round(be2 + Lr * bl2, 4))
    return 0
