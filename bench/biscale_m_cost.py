"""Cost of the bi-scale M matrix (Wu et al. 2011, eqs. 4, 9; ``precompute.biscale.effective.precompute_M``)
on a cache miss — what a small-scale material edit costs (the glossy pyramid's effective bake was 291 s).

A/B in one run, interleaved: ``--base DIR`` is a checkout of the baseline (``git archive <rev> | tar -x -C DIR``),
each trial a fresh subprocess (A, B, A, B, ...) timing ``precompute_M(lobe, use_cache=False)`` for the
GGX lobe of the glossy pyramid (α 0.3, F0 1); reports medians and checks both give the same factors.

    .venv/bin/python -m bench biscale_m_cost --base /tmp/base [--dir-res 10] [--normal-res 81] [--trials 2]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from bench._util import ROOT, report

_SNIPPET = r"""
import sys, time, json, numpy as np
sys.path.insert(0, {root!r})
from scratch_materials.precompute.biscale.brdfs import material_lobes
from scratch_materials.precompute.biscale.effective import precompute_M, _M_MEMO
lobe = [l for l in material_lobes({mat!r}) if l.key != "lambert"][0]
t0 = time.perf_counter()
mf = precompute_M(lobe, dir_res={dr}, normal_res={nr}, use_cache=False)
dt = time.perf_counter() - t0
print(json.dumps({{"s": dt, "Mz": float(np.abs(mf.Mz).sum()), "mean": float(np.abs(mf.mean).sum())}}))
"""

MAT = {"model": "cook_torrance", "distribution": "ggx", "alpha": 0.3, "F0": 1.0, "ks": 0.7, "kd": 0.2}


def _trial(root, dr, nr):
    code = _SNIPPET.format(root=str(root), mat=MAT, dr=dr, nr=nr)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "2")})
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> int:
    import numpy as np

    ap = argparse.ArgumentParser(prog="bench biscale_m_cost")
    ap.add_argument("--base", required=True, help="folder holding the baseline checkout")
    ap.add_argument("--dir-res", type=int, default=10)
    ap.add_argument("--normal-res", type=int, default=81)
    ap.add_argument("--trials", type=int, default=2)
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    res = {"base": [], "new": []}
    for _ in range(args.trials):
        for k, root in (("base", args.base), ("new", ROOT)):
            res[k].append(_trial(root, args.dir_res, args.normal_res))
            print(k, res[k][-1], flush=True)
    med = {k: float(np.median([r["s"] for r in v])) for k, v in res.items()}
    same = all(np.isclose(res["base"][0][q], res["new"][0][q], rtol=1e-6) for q in ("Mz", "mean"))
    rows = [[f"GGX α 0.3 lobe, dir_res {args.dir_res}, normal_res {args.normal_res}", k,
             " / ".join(f"{r['s']:.1f}" for r in v), f"{med[k]:.1f}"] for k, v in res.items()]
    rows.append(["ratio base / new (medians)", "", "", f"{med['base'] / med['new']:.2f}"])
    report("biscale_m_cost", ["case", "code", "seconds per trial (interleaved)", "median s"], rows,
           notes=f"precompute_M on a cache miss, fresh process per trial, A/B interleaved; load average "
                 f"{load0[0]:.0f} at start, {os.getloadavg()[0]:.0f} at end (2 cores shared). Same pole column and mean: {same}.")
    return 0
