"""Cost of inter-reflections in a bi-scale material edit (issue 16 item 3, ``precompute.biscale.interreflect``).

A material edit re-bakes with the tile reused (facets and visibility cached, ``bake.get_tile``); the
indirect table is material dependent, so an edit re-runs the path tracer (memoised per material: going
back to an earlier material is free).  Measured per tile: ``bake_tables(closure_table=True)`` with
``interreflections=False`` vs ``True``, interleaved A/B/A/B, a different albedo every run (defeats the
memo), medians; plus the first-bounce estimate and the measured change of the mean albedo.

    .venv/bin/python -m bench biscale_interreflect [--repeats 3] [--facets 10000]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np


def main(argv: list[str]) -> int:
    from bench._util import report
    from bench.biscale_truth import TILES
    from scratch_materials.precompute.biscale import bake, geometry
    from scratch_materials.precompute.biscale import interreflect as ir
    from scratch_materials.precompute.biscale.directions import direction_grid, direction_solid_angles

    ap = argparse.ArgumentParser(prog="bench biscale_interreflect")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--facets", type=int, default=10000)
    args = ap.parse_args(argv)
    tmp = tempfile.mkdtemp()
    rows = []
    load0 = os.getloadavg()[0]
    for name, (factory, kw, mats) in TILES.items():
        tile = getattr(geometry, factory)(**kw)
        opts = dict(n_facets=args.facets, dir_res=10, exr_dir=tmp, n_lobes=2, closure_table=True)
        bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, mats, interreflections=False, **opts)
        times = {False: [], True: []}
        k = 0
        for _ in range(args.repeats):
            for mode in (False, True):
                k += 1
                edited = [dict(m) for m in mats]
                edited[0] = {"model": "lambert", "albedo": 0.5 + 0.01 * k}    # a material edit, never memoised
                t0 = time.perf_counter()
                _, _, info = bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, edited,
                                              interreflections=mode, **opts)
                times[mode].append(time.perf_counter() - t0)
                assert info["reused_tile"]
        off, on = statistics.median(times[False]), statistics.median(times[True])
        t, _ = bake.get_tile(tile.vertices, tile.faces, np.minimum(tile.face_material, len(mats) - 1), 1.0,
                             n_facets=args.facets, dir_res=10)
        _, _, i_on = bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, mats,
                                      interreflections=True, **opts)
        ind, info = ir.tile_indirect(t, mats, True)
        tab = i_on["table"]
        d, dw = direction_grid(tab.res), direction_solid_angles(tab.res)
        w = (d[:, 2] * dw)[:, None, None]
        a_ind = (ir.resample(ind, info["res"], tab.res) * w).sum(0).mean(0)
        a_tot = (tab.table * w).sum(0).mean(0)
        change = a_ind / (a_tot - a_ind)
        rows.append([name, f"{off:.1f}", f"{on:.1f}", f"{on / off:.2f}", f"{100 * info['estimate']:.1f} %",
                     f"{100 * change.mean():.1f} %"])
        print(rows[-1], flush=True)
    load1 = os.getloadavg()[0]
    report("biscale_interreflect", ["tile", "material edit, off s", "material edit, on s", "ratio",
                                    "first-bounce estimate", "measured change (mean albedo)"], rows,
           notes=f"bake_tables(closure_table=True), {args.facets} facets, tile reused (visibility cached), a new "
                 f"albedo every run; off/on interleaved, median of {args.repeats}; indirect table res "
                 f"interreflect.indirect_res (10 diffuse .. 19 glossy), paths_for(res) per view direction.  Load average {load0:.1f} -> "
                 f"{load1:.1f} on {os.cpu_count()} cores (shared machine).")
    return 0
