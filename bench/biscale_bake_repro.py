"""Is the bi-scale truth bench reproducible?  The bake of ``bench/biscale_truth.py`` (``bake_variants``: facets,
visibility, Wu's table on its view grid, the inter-reflection table) run with the same ``--bake-seed`` in separate
processes that differ in what a user's machine may differ in: the hash seed (``PYTHONHASHSEED``: set and dict
orders), BLAS / OpenMP threads (1 vs 2: summation order), and the on-disk table cache (cold: an empty cache
folder, warm: the first run's).  Compares the baked tables (direct and + inter-reflections) element by element
and reports the largest relative difference and what it would do to the truth rows (the rows' baked RGB come
from these tables; the explicit renders are fixed-seed Cycles renders, reproduced to 4 digits in every
committed run).

    .venv/bin/python -m bench biscale_bake_repro [--tile "groove (diffuse + glossy)"] [--facets 10000] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from ._util import ROOT, out_path

_CHILD = r"""
import sys, json, time, numpy as np
sys.path.insert(0, {root!r})
from bench.biscale_truth import TILES, bake_variants
from scratch_materials.precompute.biscale import geometry
factory, kw, mats = TILES[{tile!r}]
tile = getattr(geometry, factory)(**kw)
t0 = time.perf_counter()
variants, times, info = bake_variants(tile, mats, n_facets={facets}, seed={seed})
out = {{k.replace(" ", "_").replace("+", "p").replace(".", ""): np.asarray(v[0].table) for k, v in variants.items()}}
va = variants["table"][0]
if getattr(va, "view_a", None) is not None:
    out["view_a"], out["view_b"] = np.asarray(va.view_a), np.asarray(va.view_b)
np.savez({path!r}, **out)
print(json.dumps({{"seconds": time.perf_counter() - t0, "times": times}}))
"""


def _run(tile: str, facets: int, seed: int, path: str, env_extra: dict, cache_dir: str) -> dict:
    env = dict(os.environ, SCRATCH_ADDON_CACHE=cache_dir, PYTHONPATH=str(ROOT), **env_extra)
    code = _CHILD.format(root=str(ROOT), tile=tile, facets=facets, seed=seed, path=path)
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=str(ROOT))
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench biscale_bake_repro")
    ap.add_argument("--tile", default="groove (diffuse + glossy)")
    ap.add_argument("--facets", type=int, default=10000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="bake_repro_")
    cache = os.path.join(tmp, "cache")
    runs = [("A: hash seed 1, 1 thread, cold cache", {"PYTHONHASHSEED": "1", "OMP_NUM_THREADS": "1",
                                                     "OPENBLAS_NUM_THREADS": "1"}),
            ("B: hash seed 2, 2 threads, warm cache", {"PYTHONHASHSEED": "2", "OMP_NUM_THREADS": "2",
                                                      "OPENBLAS_NUM_THREADS": "2"})]
    results = []
    load0 = os.getloadavg()[0]
    for i, (label, env) in enumerate(runs):
        path = os.path.join(tmp, f"run{i}.npz")
        info = _run(args.tile, args.facets, args.seed, path, env, cache)
        results.append((label, dict(np.load(path)), info))
        print(label, f"{info['seconds']:.1f} s", flush=True)
    load1 = os.getloadavg()[0]
    (la, a, ia), (lb, b, ib) = results
    lines = [f"# Bi-scale truth bench: is the bake reproducible? (bench/biscale_bake_repro.py)", "",
             f"Tile {args.tile!r}, {args.facets} facets, bake seed {args.seed} (`bench.biscale_truth.bake_variants`), "
             f"two processes: {la}; {lb}.  Load average {load0:.1f} -> {load1:.1f}.", "",
             "| table | shape | max abs diff | max rel diff (of the table's max) | identical |", "|---|---|---|---|---|"]
    for k in a:
        d = np.abs(a[k] - b[k]) if a[k].shape == b[k].shape else None
        if d is None:
            lines.append(f"| {k} | {a[k].shape} vs {b[k].shape} | - | - | no (shapes) |")
            continue
        scale = max(float(np.abs(a[k]).max()), 1e-30)
        lines.append(f"| {k} | {a[k].shape} | {d.max():.3g} | {d.max() / scale:.3g} | "
                     f"{'yes' if np.array_equal(a[k], b[k]) else 'no'} |")
    lines += ["", f"Bake seconds: {la} {ia['seconds']:.1f}; {lb} {ib['seconds']:.1f}."]
    p = out_path("biscale_bake_repro.md")
    p.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {p}")
    return 0
