"""OSL vs SVM cost of the same anisotropic GGX material at equal samples.

Three set-ups render the demo scene (torus, studio world, small area light):
  svm        Glossy BSDF node group (GGX, anisotropic) on the SVM backend
  svm-on-osl the same node tree with the OSL shading system switched on
  osl        osl/aniso_ggx.osl (``microfacet("ggx", ...)``) as an INTERNAL script node
Each is timed (median of --repeats runs, all in this one process, interleaved) and its
error measured as relative L1 against a high-sample SVM reference.

    python -m bench osl_vs_svm [--quick] [--res 192 128] [--spp 16 64] [--repeats 3]
"""
from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _setup(kind: str):
    from bench._util import blender

    blender()
    from scratch_materials.scratch_addon import materials, osl_compile, render

    scene = render.reset_scene()
    if kind == "osl":
        mat = materials.new_material("OSL GGX")
        node = osl_compile.script_node_from_source(mat.node_tree, "aniso_ggx.osl", (ROOT / "osl" / "aniso_ggx.osl").read_text())
        node.inputs["Color"].default_value = (0.91, 0.92, 0.92, 1.0)
        node.inputs["Roughness"].default_value = 0.35
        node.inputs["Anisotropy"].default_value = 0.85
        tangent = mat.node_tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"  # same frame as the SVM group (OSL's dPdu is not the UV tangent)
        mat.node_tree.links.new(tangent.outputs["Tangent"], node.inputs["Tangent"])
        mat.node_tree.links.new(node.outputs["BSDF"], mat.node_tree.nodes["Material Output"].inputs["Surface"])
    else:
        mat = materials.make_brushed_material(color=(0.91, 0.92, 0.92), roughness=0.35, anisotropy=0.85)
        for n in mat.node_tree.nodes["Group"].node_tree.nodes:
            if "Bsdf" in n.bl_idname:
                n.distribution = "GGX"  # single scattering, as OSL microfacet("ggx")
    render.studio_world(scene)
    render.add_torus(scene, material=mat)
    render.add_light(scene, "AREA", location=(2.5, -2.0, 3.0), energy=150.0, size=0.25)
    render.add_camera(scene, location=(0.0, -4.2, 2.6), target=(0.0, 0.0, -0.1), lens=45.0)
    return scene, render


def _render(kind: str, spp: int, res, tmp: str):
    scene, render = _setup(kind)
    render.configure_cycles(scene, samples=spp, res=res, seed=0, osl=kind != "svm")
    return render.render_array(scene, tmp, f"{kind}_{spp}")


def main(argv: list[str]) -> int:
    import numpy as np

    from bench._util import out_path, pyplot, report

    ap = argparse.ArgumentParser(prog="python -m bench osl_vs_svm")
    ap.add_argument("--quick", action="store_true", help="tiny run (smoke test)")
    ap.add_argument("--res", type=int, nargs=2, default=(192, 128))
    ap.add_argument("--spp", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    if a.quick:
        a.res, a.spp, a.ref_spp, a.repeats = (64, 48), [8], 64, 1
    tmp = tempfile.mkdtemp(prefix="bench_osl_svm_")
    ref, _ = _render("svm", a.ref_spp, a.res, tmp)
    kinds = ("svm", "svm-on-osl", "osl")
    rows, curves = [], {k: [] for k in kinds}
    for spp in a.spp:
        times = {k: [] for k in kinds}
        imgs = {}
        for _ in range(a.repeats):  # interleaved so machine noise hits all set-ups alike
            for k in kinds:
                img, seconds = _render(k, spp, a.res, tmp)
                times[k].append(seconds)
                imgs[k] = img
        t_svm = statistics.median(times["svm"])
        for k in kinds:
            t = statistics.median(times[k])
            err = float(np.abs(imgs[k] - ref).sum() / np.abs(ref).sum())
            curves[k].append((t, err))
            rows.append((k, spp, t, t / t_svm, err))
    notes = (f"{a.res[0]}x{a.res[1]} px, CPU, median of {a.repeats} interleaved runs in one process; "
             f"error = relative L1 vs SVM at {a.ref_spp} spp (includes Monte Carlo noise).")
    report("osl_vs_svm", ["setup", "spp", "median s", "ratio vs svm", "rel L1 err"], rows, notes)
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for k, pts in curves.items():
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=k)
    ax.set_xlabel("render time (s)")
    ax.set_ylabel("relative L1 error")
    ax.set_title("Anisotropic GGX: OSL vs SVM")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_path("osl_vs_svm.png"), dpi=120)
    print(f"wrote {out_path('osl_vs_svm.png')}")
    return 0
