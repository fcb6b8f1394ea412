"""CPU cost of a bi-scale bake's small-scale Cycles twins (Principled BSDF, Multiscatter Glossy; ``precompute.cycles``,
``precompute.biscale.brdfs``): before / after one shared microfacet evaluation per batch for all of a material's lobes.

A/B in one run, interleaved: ``--base DIR`` is a checkout of the baseline (``git archive <rev> | tar -x -C DIR``);
each trial is a fresh subprocess per code version (A, B, A, B, ...), a fresh table cache (``SCRATCH_ADDON_CACHE``), and
times with ``time.process_time`` (CPU, all threads; the machine's load varies):

- ``tabulate``: ``table.tabulate_tile(view="auto")`` of the groove (depth 0.4, 10,000 facets, dir_res 10; visibility
  included) with its walls as a Schlick GGX, the default Multiscatter Glossy, a Principled metal, a default Principled
  dielectric; and the truth bench's Principled pyramid (metal floor, dielectric sides);
- ``bake``: ``bake.bake_tables`` of the groove with three Principled metal slots (``tests/biscale/test_biscale_blender.py``'s
  operator test: n_facets 1500, dir_res 6, 2 lobes, closure table, interreflections "auto": on);
- ``eval``: one ``eval_material`` call of the interreflection pass's shape (4096 facets x 144 lights).

Medians over the trials; the checksums (sums of the tables) of A and B must agree (the values are unchanged).

    .venv/bin/python -m bench biscale_slot_cost --base /tmp/base [--trials 3] [--quick]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

from bench._util import ROOT, report

_SNIPPET = r"""
import os, sys, time, json, numpy as np
sys.path.insert(0, {root!r})
from scratch_materials.precompute.biscale import brdfs, geometry as geo, table as btable
from scratch_materials.precompute.biscale.bake import bake_tables
from scratch_materials.precompute.biscale.effective import BiscaleTile
facets, out = {facets}, {{}}
lam = lambda a: {{"model": "lambert", "albedo": a}}
metal = {{"model": "principled", "base_color": (0.9, 0.6, 0.3), "metallic": 1.0, "roughness": 0.4}}
diel = {{"model": "principled", "base_color": (0.2, 0.5, 0.8), "metallic": 0.0, "roughness": 0.5}}
walls = {{"Schlick GGX a0.2": {{"model": "cook_torrance", "distribution": "ggx", "alpha": 0.2, "F0": 1.0, "ks": 0.8}},
         "Multiscatter Glossy a0.25": {{"model": "cook_torrance", "distribution": "ggx", "alpha": 0.25, "fresnel": "none",
                                       "multiscatter": True, "F0": 1.0, "ks": 0.8}},
         "Principled metal r0.4": metal, "Principled dielectric r0.5": diel}}
g = geo.groove_tile(depth=0.4)
cases = [("groove, walls " + k, g, [lam(0.7), m, lam((0.2, 0.5, 0.8))]) for k, m in walls.items()]
cases.append(("pyramid, Principled metal floor + dielectric sides", geo.pyramid_tile(height=0.4, base=0.7), [metal, diel]))
for name, tile, mats in cases:
    bt = BiscaleTile(tile.vertices, tile.faces, tile.face_material, n_facets=facets, dir_res=10)
    t = time.process_time()
    tab = btable.tabulate_tile(bt, mats, view="auto")
    out["tabulate: " + name] = (time.process_time() - t, float(tab.table.sum()))
pm = {{"model": "principled", "base_color": (0.7, 0.5, 0.3), "metallic": 1.0, "roughness": 0.4}}
t = time.process_time()
brdf, fit, info = bake_tables(g.vertices, g.faces, g.face_material, g.period, [pm, pm, pm], n_lobes=2,
                              exr_dir=os.environ["SCRATCH_ADDON_CACHE"], closure_table=True, n_facets=1500, dir_res=6)
out["bake: groove, 3 Principled metal slots (1500 facets, dir_res 6)"] = (time.process_time() - t, float(info["table"].table.sum()))
rng = np.random.default_rng(1)
def unit(k):
    v = rng.normal(size=(k, 3)); v[:, 2] = abs(v[:, 2]); return v / np.linalg.norm(v, axis=1, keepdims=True)
ns, dirs, wp = unit(4096), unit(144), unit(4096)
for k, m in walls.items():
    lobes = brdfs.material_lobes(m)
    t = time.process_time()
    f = brdfs.eval_material(lobes, ns[:, None], dirs[None], wp[:, None])
    out["eval_material 4096 x 144: " + k] = (time.process_time() - t, float(f.sum()))
print(json.dumps(out))
"""


def _trial(root, facets):
    with tempfile.TemporaryDirectory(prefix="slot_cost_") as cache:
        code = _SNIPPET.format(root=str(root), facets=facets)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                             env={**os.environ, "SCRATCH_ADDON_CACHE": cache})
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(prog="bench biscale_slot_cost")
    ap.add_argument("--base", required=True, help="folder holding the baseline checkout")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="2,000 facets, one trial")
    args = ap.parse_args(argv)
    facets, trials = (2000, 1) if args.quick else (10000, args.trials)
    load0 = os.getloadavg()
    res = {"base": [], "new": []}
    for _ in range(trials):
        for k, root in (("base", args.base), ("new", ROOT)):
            res[k].append(_trial(root, facets))
            print(k, {c: round(v[0], 2) for c, v in res[k][-1].items()}, flush=True)
    rows = []
    for case in res["new"][0]:
        b = [r[case][0] for r in res["base"]]
        n = [r[case][0] for r in res["new"]]
        same = np.isclose(res["base"][0][case][1], res["new"][0][case][1], rtol=1e-12)
        rows.append([case, " / ".join(f"{x:.2f}" for x in b), " / ".join(f"{x:.2f}" for x in n),
                     f"{np.median(b):.2f}", f"{np.median(n):.2f}", f"{np.median(b) / np.median(n):.2f}",
                     "yes" if same else "NO"])
    report("biscale_slot_cost", ["case", "base CPU s (trials)", "new CPU s (trials)", "base median", "new median",
                                 "base / new", "same result"], rows,
           notes=f"CPU seconds (time.process_time), fresh process and table cache per trial, A/B interleaved, "
                 f"{trials} trial(s), {facets} facets for the tabulation; load average {load0[0]:.0f} at start, "
                 f"{os.getloadavg()[0]:.0f} at end (2 cores shared). 'same result': the table / BRDF sums of A and B "
                 f"agree to 1e-12.")
    return 0
