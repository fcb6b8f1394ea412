"""``python -m bench biscale_closure_table``: bake time with and without the closure's finer table
(``precompute.biscale.table.tabulate_tile``) and its accuracy between the bake's directions.

Per tile, in one run: the bake (facets, visibility, BVNDF, M (disk cache off; the in-memory memo
serves the repeats), eq. 12) at ``dir_res`` 10, then ``tabulate_tile`` at ``closure_res``; repeated (A = bake, B = tabulation,
interleaved), medians.  Accuracy: mean f over 40 light directions spread over the 1.5 m area lamp of
the render test (-1.5, 1, 2.5) at views 0° and 35°, coarse table (``EffectiveBRDF.eval``) and fine table
vs the Monte Carlo ray-traced tile (``render_reference_fr``, 40k rays per view)."""
from __future__ import annotations

import argparse
import math
import os
import statistics
import time


def main(argv: list[str]) -> int:
    import numpy as np

    from bench._util import report
    from scratch_materials.precompute.biscale import table as btable
    from scratch_materials.precompute.biscale.effective import BiscaleTile, render_reference_fr
    from scratch_materials.precompute.biscale.geometry import groove_tile, pyramid_tile

    ap = argparse.ArgumentParser(prog="bench biscale_closure_table")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--facets", type=int, default=10000)
    a = ap.parse_args(argv)
    lam = lambda c: {"model": "lambert", "albedo": c}   # noqa: E731
    ct = {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": 1.0, "ks": 0.8}
    cases = [("pyramid h0.5, 2 Lambert", pyramid_tile(height=0.5), [lam(0.5), lam((0.8, 0.6, 0.4))]),
             ("groove d0.4, Lambert + GGX a0.3", groove_tile(depth=0.4), [lam(0.6), ct, lam(0.3)])]
    rng = np.random.default_rng(1)
    wi = np.array([-1.5, 1.0, 2.5]) + rng.uniform(-0.75, 0.75, (40, 3)) * [1, 1, 0]
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    rows = []
    for name, tile, mats in cases:
        t_bake, t_tab = [], []
        for _ in range(a.repeats):                       # A/B interleaved
            t0 = time.perf_counter()
            bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=a.facets, dir_res=10,
                             use_cache=False)
            brdf = bt.effective_brdf(mats)
            t_bake.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            fine = btable.tabulate_tile(bt, mats)
            t_tab.append(time.perf_counter() - t0)
        errs = []
        for th in (0.0, 35.0):
            wo = np.repeat([[math.sin(math.radians(th)), 0.0, math.cos(math.radians(th))]], len(wi), 0)
            ref = (render_reference_fr(tile, mats, wi, wo, n_rays=40000) / wi[:, 2:3]).mean(0)
            for t in (brdf, fine):
                errs.append(100 * float(np.abs(t.eval(wi, wo).mean(0) / ref - 1).max()))
        rows.append([name, a.facets, f"{statistics.median(t_bake):.1f}", fine.res, f"{statistics.median(t_tab):.1f}",
                     f"{errs[0]:.2f} / {errs[1]:.2f}", f"{errs[2]:.2f} / {errs[3]:.2f}"])
    load = os.getloadavg()[0]
    report("biscale_closure_table",
           ["tile", "facets", "bake dir_res 10 (s)", "closure res", "tabulate (s)",
            "0° err coarse / fine (%)", "35° err coarse / fine (%)"], rows,
           f"medians of {a.repeats} interleaved runs; load average {load:.1f} on {os.cpu_count()} cores. "
           "The bake's M comes from the in-memory memo after the first run. "
           "err: max over RGB of |mean f over the lamp's directions / ray-traced tile - 1|.")
    return 0
