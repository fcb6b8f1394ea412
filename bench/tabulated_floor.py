"""Noise against run time of the tabulated-BRDF closure with and without its floors (issue 16 items 1, 5:
``tabulated_brdf.floor_parts``: a Diffuse closure of kd, a GGX Glossy closure of ks (the glossy floor, when "auto"
finds it worth >= 10 % of the albedo), plus the one-lobe table closure of the residual).

Scene: what the user gets from File > New (the startup file's POINT lamp, 1000 W, radius 0.1, ~7.3 m away, and a
grey world 0.6), a UV sphere of radius 2.2 carrying the material, 64 x 48 px, adaptive sampling off, direct light
only.  Materials: MERL-format files written from analytic BRDFs (a Lambertian 0.5/π; Cycles' GGX α 0.2 x 0.8 +
Lambert (0.1, 0.2, 0.3); Cycles' Beckmann α 0.3 x 0.8 + the same Lambert: a lobe that is NOT the floor's GGX)
imported by ``merl_ops.material_from_merl`` with ``floor`` True ("auto": the glossy floor where it pays),
"diffuse" (last round's Diffuse floor alone) and False, and the analytic twins (Diffuse BSDF; Glossy GGX /
Beckmann + Diffuse) as references.  Per material and spp: CPU seconds per frame (this
process, user + sys) and the relative RMS error of the pixels against a reference image of the same material at
``--ref-spp`` (its own converged image: the noise), over ``--seeds`` seeds; rounds interleave the materials.
Error x sqrt(time) is the noise at equal time (lower is better; the ratio no floor / floor is the speed-up to the
same noise, squared).  The frame means vs the analytic twin check the bias.

The figure (``docs/img/tabulated_floor.png``): seed 0 of each material at ``--spp``, SVM and OSL rows.

    .venv/bin/python -m bench tabulated_floor [--quick] [--spp 8] [--seeds 4] [--ref-spp 1024]
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import tempfile


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv: list[str]) -> int:
    import numpy as np

    from bench._util import ROOT, blender, pyplot, report

    ap = argparse.ArgumentParser(prog="bench tabulated_floor")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--res", type=int, default=64)
    args = ap.parse_args(argv)
    if args.quick:
        args.seeds, args.ref_spp, args.res = 2, 128, 32
    blender()
    import bpy

    from scratch_materials.precompute.cycles import ggx
    from scratch_materials.precompute.tables import merl
    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.scratch_addon import materials, merl_ops, render

    scene = render.reset_scene()
    render.uniform_world(scene, 1.0, (0.6, 0.6, 0.6))
    render.add_light(scene, "POINT", location=(4.076, 1.005, 5.904), energy=1000.0, size=0.1)
    sphere = render.add_sphere(scene, radius=2.2, segments=32, rings=16)
    render.add_camera(scene, location=(7.36, -6.93, 4.96), target=(0, 0, 0), lens=50.0)
    W, H = args.res, args.res * 3 // 4
    tmp = tempfile.mkdtemp()
    kd_g = np.array([0.1, 0.2, 0.3])

    def glossy(wi, wo):
        return 0.8 * tb._ggx_unit(wi, wo, 0.2)[:, None] * np.ones(3) + kd_g / np.pi

    def beckmann(wi, wo):          # Cycles' Beckmann Glossy (F = 1): eval = f cos θi (``precompute.cycles.ggx``)
        ev, _ = ggx.bsdf_eval([0, 0, 1.0], [1.0, 0, 0], 0.3, 0.3, wo, wi, dist="beckmann")
        return 0.8 * (ev / np.maximum(wi[:, 2], 1e-9))[:, None] * np.ones(3) + kd_g / np.pi

    files = {"Lambert 0.5": os.path.join(tmp, "lambert.binary"), "GGX 0.2 + Lambert": os.path.join(tmp, "ggx.binary"),
             "Beckmann 0.3 + Lambert": os.path.join(tmp, "beckmann.binary")}
    merl.write_merl(files["Lambert 0.5"], np.full((*merl.SHAPE, 3), 0.5 / np.pi))
    merl.write_merl(files["GGX 0.2 + Lambert"], merl.tabulate(glossy))
    merl.write_merl(files["Beckmann 0.3 + Lambert"], merl.tabulate(beckmann))

    def analytic(kind):
        m = materials.new_material(f"analytic {kind}")
        nt = m.node_tree
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        if kind == "Lambert 0.5":
            d.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
            out = d.outputs[0]
        else:
            d.inputs["Color"].default_value = (*kd_g, 1.0)
            g = nt.nodes.new("ShaderNodeBsdfGlossy")
            g.distribution = "GGX" if kind.startswith("GGX") else "BECKMANN"
            g.inputs["Roughness"].default_value = (0.2 if kind.startswith("GGX") else 0.3) ** 0.5
            g.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
            a = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(d.outputs[0], a.inputs[0])
            nt.links.new(g.outputs[0], a.inputs[1])
            out = a.outputs[0]
        nt.links.new(out, nt.nodes["Material Output"].inputs["Surface"])
        return m

    mats = []
    for kind, path in files.items():
        for label, floor in (("auto floor", True), ("diffuse floor", "diffuse"), ("no floor", False)):
            if kind == "Lambert 0.5" and label == "diffuse floor":
                continue                                  # "auto" is the Diffuse floor there
            m = merl_ops.material_from_merl(path, f"{kind} {label}", floor=floor)
            mats.append((kind, label, m))
        mats.append((kind, "analytic", analytic(kind)))

    def render_img(mat, osl, spp, seed):
        sphere.data.materials.clear()
        sphere.data.materials.append(mat)
        render.configure_cycles(scene, samples=spp, res=(W, H), seed=seed, osl=osl, max_bounces=0)
        c0 = cpu_seconds()
        img, _ = render.render_array(scene, tmp, "f")
        return img.astype(np.float64), cpu_seconds() - c0

    rows, shots = [], {}
    load0 = os.getloadavg()
    for osl in (False, True):
        refs = {}
        for kind, label, m in mats:
            render_img(m, osl, 1, 0)                                  # warm-up: compile, sync
            refs[(kind, label)] = render_img(m, osl, args.ref_spp, 1000)[0]
        stats = {(k, lab): ([], []) for k, lab, _ in mats}
        for s in range(args.seeds):                                   # rounds interleave the materials
            for kind, label, m in mats:
                img, t = render_img(m, osl, args.spp, s)
                if s == 0:
                    shots[("OSL" if osl else "SVM", kind, label)] = img
                ref = refs[(kind, label)]
                mask = ref.sum(-1) > 1e-6
                err = np.sqrt(np.mean((img - ref)[mask] ** 2)) / ref[mask].mean()
                stats[(kind, label)][0].append(err)
                stats[(kind, label)][1].append(t)
        for kind, label, m in mats:
            errs, ts = stats[(kind, label)]
            e, t = float(np.sqrt(np.mean(np.square(errs)))), statistics.median(ts)
            bias = refs[(kind, label)].mean() / refs[(kind, "analytic")].mean() - 1.0
            if label != "analytic":
                kd, gf = m.get("tabulated_floor", [0.0])[0], list(m.get("tabulated_glossy_floor", [0.0] * 4))
                floors = f"{kd:.3f}" + (f" / {gf[0]:.3f}, α {gf[3]:.3f}" if gf[0] > 0 else " / -")
            else:
                floors = "-"
            rows.append(["OSL" if osl else "SVM", kind, label, floors, f"{100 * e:.1f} %", f"{1e3 * t:.0f}",
                         f"{e * np.sqrt(t):.4f}", f"{100 * bias:+.2f} %"])
    load1 = os.getloadavg()
    plt = pyplot()
    cols = [(k, lab) for k, lab, _ in mats]
    fig, axes = plt.subplots(2, len(cols), figsize=(1.3 * len(cols), 2.6))
    for i, sysname in enumerate(("SVM", "OSL")):
        for j, (k, lab) in enumerate(cols):
            ax = axes[i, j]
            ax.imshow(np.clip(shots[(sysname, k, lab)], 0, 1) ** (1 / 2.2), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f"{k}\n{lab}", fontsize=6)
            if j == 0:
                ax.set_ylabel(f"{sysname}, {args.spp} spp", fontsize=7)
    fig.tight_layout()
    img_path = ROOT / "docs" / "img" / "tabulated_floor.png"
    img_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(img_path, dpi=150)
    report("tabulated_floor", ["Cycles", "MERL file", "material", "kd / ks (R), α_g", f"pixel rel. RMS error, {args.spp} spp",
                               "CPU ms / frame", "error x sqrt(s)", f"mean vs analytic ({args.ref_spp} spp)"], rows,
           notes=f"startup-file lighting (POINT 1000 W radius 0.1 + grey world 0.6), UV sphere, {W}x{H} px, direct light "
                 f"only, adaptive sampling off; error: RMS over the sphere's pixels of (image - the same material at "
                 f"{args.ref_spp} spp) / its mean, over {args.seeds} seeds; CPU time of the render process (user + sys), "
                 f"median; materials interleaved per seed; load average {load0[0]:.1f} at start, {load1[0]:.1f} at end, "
                 f"2 cores")
    return 0
