"""Load-free cost of the tabulated closure's floors (the extra Diffuse closure, ``tabulated_brdf.floor_split``, and the
glossy floor's Glossy closure with its per-view colour lookup, ``tabulated_brdf.glossy_floor_split``):
instructions per sample under valgrind, the method of ``bench/iridescence_callgrind`` (its helpers are reused).

One valgrind child renders the whole-frame scene of ``bench/tabulated_cost`` (UV sphere filling an orthographic
frame, studio world + area lamp, adaptive sampling off, one render thread) at 32 x 32 on Cycles SVM (no OSL JIT
under valgrind) for: the SVM anisotropic Glossy (the baseline), and a table of GGX α 0.2 x 0.8 + Lambert
(0.1, 0.15, 0.2) (iso 16² x 16) with the Diffuse + glossy floors (the default "auto"), the Diffuse floor alone
(kd 0.15-0.25) and no floor; per config 1 and N + 1 spp, calling getppid() after each
render (callgrind dumps there).  Instructions per sample = (Ir(N + 1) - Ir(1)) / N of Cycles'
``render_samples_full_pipeline`` (inclusive).

    .venv/bin/python -m bench tabulated_floor_callgrind [--spp 4]
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

NAMES = ["SVM aniso Glossy", "table, Diffuse + glossy floor", "table, Diffuse floor", "table, no floor"]


def _child(n: int) -> int:
    from bench._util import blender
    blender()
    from bench.tabulated_cost import baseline_material, cost_scene, glossy
    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.scratch_addon import render, tabulated_material

    scene, sphere = cost_scene()
    svm = baseline_material()
    tmp = tempfile.mkdtemp()
    brdf = tb.TabulatedBRDF.from_function(glossy, 16, iso=True, n_theta=16)     # small: numpy is slow under valgrind
    mats = {NAMES[0]: svm, NAMES[1]: tabulated_material.make_tabulated_material(brdf, "floor"),       # "auto": glossy
            NAMES[2]: tabulated_material.make_tabulated_material(brdf, "diffuse", floor="diffuse"),
            NAMES[3]: tabulated_material.make_tabulated_material(brdf, "nofloor", floor=False)}
    os.getppid()                                   # dump part 1: setup
    for name in NAMES:
        sphere.data.materials.clear()
        sphere.data.materials.append(mats[name])
        for spp in (1, n + 1):
            render.configure_cycles(scene, samples=spp, res=(32, 32), seed=0, osl=False, threads=1)
            render.render_to_file(scene, f"{tmp}/r.exr")
            print(f"PART {name} {spp}", flush=True)
            os.getppid()
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


def main(argv: list[str]) -> int:
    from bench._util import report
    from bench.iridescence_callgrind import _parts

    if argv[:1] == ["--child"]:
        return _child(int(argv[1]))
    n = int(argv[argv.index("--spp") + 1]) if "--spp" in argv else 4
    if shutil.which("valgrind") is None:
        print("tabulated_floor_callgrind: valgrind not found", file=sys.stderr)
        return 1
    work = tempfile.mkdtemp(prefix="cg_floor_")
    prefix = f"{work}/cg"
    cmd = ["valgrind", "--tool=callgrind", "--dump-before=getppid", f"--callgrind-out-file={prefix}",
           sys.executable, "-m", "bench", "tabulated_floor_callgrind", "--child", str(n)]
    with open(f"{work}/child.log", "w") as log:
        subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, check=True, env=dict(os.environ, PYTHONHASHSEED="0"),
                       cwd=str(Path(__file__).resolve().parent.parent))
    parts = _parts(prefix)[1:1 + 2 * len(NAMES)]
    ir = {name: (parts[2 * i + 1] - parts[2 * i]) / n for i, name in enumerate(NAMES)}
    base = ir[NAMES[0]]
    rows = [[name, f"{ir[name] / 1024:,.0f}", f"{ir[name] / base:.3f}x", f"{ir[name] / ir[NAMES[3]]:.3f}x",
             f"{ir[name] / ir[NAMES[2]]:.3f}x"] for name in NAMES]
    report("tabulated_floor_callgrind", ["material (Cycles SVM)", "Ir / pixel-sample", "vs SVM aniso Glossy",
                                         "vs no floor", "vs Diffuse floor"], rows,
           notes=f"valgrind callgrind, inclusive Ir of Cycles' render_samples_full_pipeline, (Ir({n + 1} spp) - Ir(1 spp)) / "
                 f"{n} / 1024 pixels, 32x32 whole-frame sphere, studio world + area lamp, one render thread; "
                 f"load-independent instruction counts")
    shutil.rmtree(work, ignore_errors=True)
    return 0
