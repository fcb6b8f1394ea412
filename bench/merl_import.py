"""MERL import time before / after computing the fitted twin only where a render path uses it (issue: the
least-squares ``tabulated_brdf.glossy_twin`` was computed on every import, though Cycles SVM and EEVEE render the
table whenever ``tabulated_svm.fits``).

Files: MERL-format files written from analytic BRDFs (no data set needed; the writers of tests/tables/test_merl.py):
Cycles' GGX α 0.2 x 0.8 + Lambert (0.1, 0.2, 0.3) and a sharper GGX α 0.05 x 0.9 + Lambert 0.05.  Per file and
table size (``res`` = ``n_theta``: 24, 32 (the operator's default), 48):

- **after**: ``merl_ops.material_from_merl`` as it is (no twin; an energy check ``merl_ops.energy_check``: the
  closure's and the file's albedo at three views, reported);
- **before**: the same import with the removed work put back: ``glossy_twin`` of the same table, and without the
  energy check (the previous code path: read, to_tabulated, make_tabulated_material + twin).

Rounds interleave after / before (A/B/A/B), wall seconds in this process, median over ``--rounds``; the phases
(read + fill, to_tabulated, energy check, twin, material) are timed once per round beside them.

    .venv/bin/python -m bench merl_import [--rounds 5] [--quick]

``--auto``: the import's automatic resolution (``merl_ops.material_from_merl`` default: the grid from the file's
peak, ``merl.auto_resolution``) against the old default 32² x 32, CPU seconds (``time.process_time``: the machine is
shared) of a first import (the floor search's caches cleared each round), median over ``--rounds``; files: the two
above and the merl_audit's gold (GGX α 0.05 conductor; and α 0.02, Session 10) and Beckmann α 0.1 + Lambert; writes
``bench/out/merl_import_auto.md``.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np

from ._util import blender, out_path


def _files(folder: str) -> dict:
    from scratch_materials.precompute.tables import merl, tabulated_brdf as tb

    def ggx_soft(wi, wo):
        return 0.8 * tb._ggx_unit(wi, wo, 0.2)[:, None] * np.ones(3) + np.array([0.1, 0.2, 0.3]) / np.pi

    def ggx_sharp(wi, wo):
        return 0.9 * tb._ggx_unit(wi, wo, 0.05)[:, None] * np.ones(3) + 0.05 / np.pi

    out = {}
    for name, f in (("ggx_a0.2", ggx_soft), ("ggx_a0.05", ggx_sharp)):
        out[name] = os.path.join(folder, f"{name}.binary")
        merl.write_merl(out[name], merl.tabulate(f))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench merl_import")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="2 rounds, res 32 only")
    ap.add_argument("--auto", action="store_true", help="automatic resolution vs the old default, CPU seconds")
    args = ap.parse_args(argv)
    if args.auto:
        return auto_main(2 if args.quick else args.rounds)
    rounds, sizes = (2, (32,)) if args.quick else (args.rounds, (24, 32, 48))
    blender(register=False)
    import bpy
    from scratch_materials.precompute.tables import merl, tabulated_brdf as tb
    from scratch_materials.scratch_addon import merl_ops, tabulated_material

    def before(path, res):
        """The previous import: read (fill inside to_tabulated), table, material, and the twin."""
        table = merl.read_merl(path)
        brdf = merl.to_tabulated(table, res, res)
        mat = tabulated_material.make_tabulated_material(brdf, "before", kind="merl")
        tb.glossy_twin(brdf)
        return mat

    def after(path, res):
        return merl_ops.material_from_merl(path, name="after", res=res, n_theta=res)

    def phases(path, res):
        t = {}
        t0 = time.perf_counter()
        table = merl.fill_missing(merl.read_merl(path))
        t["read + fill"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        brdf = merl.to_tabulated(table, res, res, fill=False)
        t["to_tabulated"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        merl_ops.energy_check(table, brdf)
        t["energy check"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        tb.glossy_twin(brdf)
        t["twin"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        mat = tabulated_material.make_tabulated_material(brdf, "phase", kind="merl")
        t["material"] = time.perf_counter() - t0
        bpy.data.materials.remove(mat)
        return t

    folder = tempfile.mkdtemp(prefix="bench_merl_")
    files = _files(folder)
    rows = []
    load0 = os.getloadavg()
    for name, path in files.items():
        for res in sizes:
            times = {"after": [], "before": []}
            ph = []
            after(path, res)                   # warm-up: OSL compile cache, imports
            for _ in range(rounds):
                for label, fn in (("after", after), ("before", before)):
                    t0 = time.perf_counter()
                    mat = fn(path, res)
                    times[label].append(time.perf_counter() - t0)
                    bpy.data.materials.remove(mat)
                ph.append(phases(path, res))
            med = {k: statistics.median(v) for k, v in times.items()}
            phm = {k: statistics.median(p[k] for p in ph) for k in ph[0]}
            rows.append((name, res, med["before"], med["after"], phm))
            print(f"{name} res {res}: before {med['before']:.3f} s, after {med['after']:.3f} s "
                  f"({med['after'] / med['before']:.2f}x); phases " + ", ".join(f"{k} {v:.3f}" for k, v in phm.items()))
    load1 = os.getloadavg()
    lines = ["# MERL import time: the fitted twin only where a path renders it (bench/merl_import.py)", "",
             f"Wall seconds in one process, median of {rounds} rounds, after / before interleaved; load average "
             f"{load0[0]:.1f} at the start, {load1[0]:.1f} at the end (2 cores shared).  'before' = the previous "
             "import (twin computed, no energy check), 'after' = `material_from_merl` now (no twin; the energy "
             "check of the report).", "",
             "| file | res = n_theta | before (s) | after (s) | after / before | read + fill | to_tabulated | "
             "energy check | twin (removed) | material |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, res, b, a, phm in rows:
        lines.append(f"| {name} | {res} | {b:.3f} | {a:.3f} | {a / b:.2f} | {phm['read + fill']:.3f} | "
                     f"{phm['to_tabulated']:.3f} | {phm['energy check']:.3f} | {phm['twin']:.3f} | {phm['material']:.3f} |")
    path = out_path("merl_import.md")
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")
    return 0


def auto_main(rounds: int) -> int:
    """``--auto``: CPU seconds of a first import at the automatic resolution vs the old default 32² x 32."""
    from bench.merl_audit import beckmann_lambert, gold_ggx

    blender(register=False)
    import bpy
    from scratch_materials.precompute.tables import merl, tabulated_brdf as tb
    from scratch_materials.scratch_addon import merl_ops

    def cold():
        for cache in (tb._FLOOR_CACHE, tb._HEMI_ALBEDO, tb._ALBEDO_MEMO):
            cache.clear()
        tb._LOBES.update(layout=None, geom=None, g={})

    folder = tempfile.mkdtemp(prefix="bench_merl_")
    files = _files(folder)
    for name, f in (("gold (merl_audit)", gold_ggx), ("beckmann (merl_audit)", beckmann_lambert),
                    ("gold0.02 (merl_audit)", lambda wi, wo: gold_ggx(wi, wo, 0.02))):
        files[name] = os.path.join(folder, name.split()[0] + ".binary")
        merl.write_merl(files[name], merl.tabulate(f))
    rows, load0 = [], os.getloadavg()[0]
    merl_ops.material_from_merl(files["ggx_a0.2"], name="warm-up")
    for name, path in files.items():
        times = {"auto": [], "32": []}
        for _ in range(rounds):
            for label, kw in (("auto", {}), ("32", {"res": 32, "n_theta": 32})):
                cold()
                t0 = time.process_time()
                mat = merl_ops.material_from_merl(path, name=label, **kw)
                times[label].append(time.process_time() - t0)
                if label == "auto":
                    info = (mat["tabulated_res"], mat["merl_peak_width_deg"], mat["merl_sharper_than_table"],
                            merl_ops.import_summary(mat))
                bpy.data.materials.remove(mat)
        med = {k: statistics.median(v) for k, v in times.items()}
        rows.append((name, info, med))
        print(f"{name}: auto {info[0]}² ({info[1]:.2f}°) {med['auto']:.2f} s CPU, 32² {med['32']:.2f} s CPU", flush=True)
    lines = ["# MERL import time at the automatic resolution (bench/merl_import.py --auto)", "",
             f"CPU seconds (`time.process_time`, all threads of the process) of a first import (the floor search's "
             f"caches cleared), median of {rounds} rounds, auto and the old default 32² x 32 interleaved; load "
             f"average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2 cores shared).", "",
             "| file | peak half width | auto res (n_theta 32) | sharper than the cells | auto (s CPU) | 32² x 32 (s CPU) |",
             "|---|---|---|---|---|---|"]
    for name, (res, w, sharp, _), med in rows:
        lines.append(f"| {name} | {w:.2f}° | {res}² | {'yes' if sharp else 'no'} | {med['auto']:.2f} | {med['32']:.2f} |")
    path = out_path("merl_import_auto.md")
    path.write_text("\n".join(lines) + "\n")
    print(f"wrote {path}")
    return 0
