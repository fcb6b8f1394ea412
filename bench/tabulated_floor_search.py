"""Time of the floors' search (``tabulated_brdf.floor_parts``, issue 16: the glossy floor), per table kind:

- **diffuse**: ``floor="diffuse"`` (the Diffuse floor alone: one pass over the nodes);
- **auto, cold**: ``floor=True`` with every cache empty (a first import / bake);
- **auto, edit**: ``floor=True`` for another table of the same layout (an edit: other values, same grid), after a
  search of the first one: the glossy search's lobes are remembered per layout (``_layout_lobes``);
- **auto, the edit's table cold**: the same table with empty caches (what an edit cost before the layout cache);
- **auto, no search**: a Lambertian table of the same layout: the Diffuse floor leaves nothing for a glossy floor.

Tables: Cycles' GGX α 0.2 x 0.8 + Lambert (0.1, 0.15, 0.2) (the cost benches' BRDF) on the isotropic 32² x 32 grid
(a MERL import's size) and on a bi-scale-size 19² x 19 x 19 view grid; the edit scales the lobe by 0.7.
Wall seconds in this process, median over ``--rounds`` (kinds interleaved per round).

    .venv/bin/python -m bench tabulated_floor_search [--rounds 5]
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

from ._util import report


def _clear(tb) -> None:
    tb._FLOOR_CACHE.clear()
    tb._HEMI_ALBEDO.clear()
    tb._ALBEDO_MEMO.clear()
    tb._LOBES.update(layout=None, pairs=None, g={})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench tabulated_floor_search")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    from scratch_materials.precompute.tables import tabulated_brdf as tb

    from .tabulated_cost import glossy

    def lambert(wi, wo):
        return np.full((len(wi), 3), 0.5 / np.pi)

    vg = dict(view_a=tb.view_grid_nodes(19, events=(-0.6458, 0.6458)), view_b=tb.view_grid_nodes(19))
    layouts = {"iso 32² x 32": dict(res=32, iso=True, n_theta=32), "view grid 19² x 19x19": dict(res=19, **vg)}
    times: dict = {}
    load0 = os.getloadavg()[0]
    for _ in range(args.rounds):
        for lname, kw in layouts.items():
            first = tb.TabulatedBRDF.from_function(glossy, **kw)
            edit = tb.TabulatedBRDF.from_function(lambda wi, wo: 0.7 * glossy(wi, wo), **kw)
            lam = tb.TabulatedBRDF.from_function(lambert, **kw)
            cases = [("diffuse", first, "diffuse", True), ("auto, cold", first, True, True),
                     ("auto, edit", edit, True, False), ("auto, the edit's table cold (no layout cache)", edit, True, True),
                     ("auto, no search", lam, True, True)]
            for cname, brdf, floor, cold in cases:
                if cold:
                    _clear(tb)
                t = time.perf_counter()
                parts = tb.floor_parts(brdf, floor)
                times.setdefault((lname, cname), []).append((time.perf_counter() - t, parts))
    rows = []
    for (lname, cname), v in times.items():
        parts = v[-1][1]
        rows.append([lname, cname, f"{statistics.median(t for t, _ in v):.3f}", parts.mode,
                     f"{float(np.max(parts.ks)):.3f}", f"{parts.share:.2f}"])
    report("tabulated_floor_search", ["table", "floors", "wall s (median)", "mode", "ks max", "glossy share"], rows,
           notes=f"floor_parts in one process, {args.rounds} rounds (kinds interleaved), medians; 'auto, edit' runs after "
                 f"'auto, cold' of the same layout (its lobes remembered), every other case with cold caches; load "
                 f"average {load0:.1f} at start, {os.getloadavg()[0]:.1f} at end, {os.cpu_count()} cores")
    return 0
