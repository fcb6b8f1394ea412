"""MERL import audit (issue 16, "a MERL-format file of a known BRDF rendered against its analytic twin"): MERL
binaries written from analytic BRDFs the tests do not use, imported through the panel operator
(``scratch.import_merl``, default Automatic Resolution (from the file's peak) / View Angles 32) and the API
(``material_from_merl``),
rendered in a default-like scene on Cycles SVM (the default shading system), OSL and EEVEE against the analytic
material made of Cycles' own closures.

BRDFs (``BRDFS``), each the numpy twin of the Blender nodes it is compared with:
- ``beckmann``: Glossy BSDF Beckmann α 0.1 (Roughness √0.1, colour 0.7, no Fresnel) + Diffuse BSDF (0.25, 0.1, 0.05)
  (``precompute.cycles.beckmann``: Cycles' D and its rational Smith Λ, height-correlated G2);
- ``gold``: Metallic BSDF, Physical Conductor (gold n, k at 650/550/450 nm), GGX α 0.05 (Roughness √0.05): the
  exact complex Fresnel (``precompute.fresnel.conductor``) x Cycles' GGX D G2 / (4 cos θi cos θo).

Scene: a 4 m plane seen by an orthographic 0.4 m camera along each view; light ``lamp`` (the bi-scale bench's area
lamp, 300 W at (-1.5, 1, 2.5), size 1.5, black world; NEE on) or ``env`` (``render.studio_world``, no lamp); max
bounces 0.  Error per view: max over RGB |mean(imported) - mean(analytic)| / mean(analytic), with its render noise
(1σ from two seeds per image, ``bench.biscale_truth.frame_mean_se``).  EEVEE: lamp + studio world together, 64
samples (its noise is not estimated; its own closures are the reference, so EEVEE's approximations cancel only
where they are the same).

    .venv/bin/python -m bench merl_audit [--spp 256] [--views "0/0,35/326"] [--no-eevee] [--brdfs beckmann,gold]
"""
from __future__ import annotations

import argparse
import functools
import math
import tempfile
import time

import numpy as np

VIEWS = [(0.0, 0.0), (35.0, 326.0), (55.0, 300.0), (70.0, 30.0)]   # 35/326: the lamp's mirror direction
EEVEE_VIEWS = [(35.0, 326.0), (55.0, 300.0)]


def _frame(wi, wo):
    h = wi + wo
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


def beckmann_lambert(wi, wo, alpha=0.1, ks=0.7, kd=(0.25, 0.1, 0.05)):
    """Cycles' Glossy BSDF Beckmann (colour ks, no Fresnel) + Diffuse kd: ks D G2 / (4 cos θi cos θo) + kd / π (1/sr)."""
    from scratch_materials.precompute.cycles import beckmann as bk

    h = _frame(wi, wo)
    D = bk.beckmann_aniso_D(alpha, alpha, h)
    G2 = 1.0 / (1.0 + bk.beckmann_aniso_lambda(alpha, alpha, wi) + bk.beckmann_aniso_lambda(alpha, alpha, wo))
    spec = ks * D * G2 / (4.0 * np.maximum(wi[:, 2], 1e-9) * np.maximum(wo[:, 2], 1e-9))
    return spec[:, None] + np.asarray(kd)[None] / np.pi


GOLD_N, GOLD_K = (0.166, 0.43, 1.40), (3.15, 2.46, 1.88)


def gold_ggx(wi, wo, alpha=0.05):
    """Cycles' Metallic BSDF (Physical Conductor, GGX): F_conductor(ωi·h; n + i k) D G2 / (4 cos θi cos θo) (1/sr)."""
    from scratch_materials.precompute.scratch import fresnel
    from scratch_materials.precompute.tables import tabulated_brdf as tb

    h = _frame(wi, wo)
    F = fresnel.conductor(GOLD_N, GOLD_K)(np.clip(np.sum(wi * h, -1), 0, 1))        # (N, 3)
    return tb._ggx_unit(wi, wo, alpha)[:, None] * F


def _rgb(v):
    return (*[float(x) for x in np.broadcast_to(np.asarray(v, float), 3)], 1.0)


def beckmann_material(name="analytic beckmann"):
    from scratch_materials.scratch_addon.materials import new_material

    m = new_material(name)
    tree = m.node_tree
    out = tree.nodes[0]
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "BECKMANN"
    g.inputs["Roughness"].default_value = math.sqrt(0.1)
    g.inputs["Color"].default_value = _rgb(0.7)
    d = tree.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = _rgb((0.25, 0.1, 0.05))
    d.inputs["Roughness"].default_value = 0.0
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(d.outputs["BSDF"], add.inputs[0])
    tree.links.new(g.outputs["BSDF"], add.inputs[1])
    tree.links.new(add.outputs["Shader"], out.inputs["Surface"])
    return m


def gold_material(name="analytic gold", alpha=0.05):
    from scratch_materials.scratch_addon.materials import new_material

    m = new_material(name)
    tree = m.node_tree
    out = tree.nodes[0]
    g = tree.nodes.new("ShaderNodeBsdfMetallic")
    g.fresnel_type = "PHYSICAL_CONDUCTOR"
    g.distribution = "GGX"
    g.inputs["IOR"].default_value = GOLD_N
    g.inputs["Extinction"].default_value = GOLD_K
    g.inputs["Roughness"].default_value = math.sqrt(alpha)
    tree.links.new(g.outputs["BSDF"], out.inputs["Surface"])
    return m


BRDFS = {"beckmann": (beckmann_lambert, beckmann_material), "gold": (gold_ggx, gold_material)}
#: sharper gold files (Session 10: peaks narrower than the 48² cells): not in the default run
SHARP_BRDFS = {f"gold{a}": (functools.partial(gold_ggx, alpha=a), functools.partial(gold_material, f"analytic gold {a}", a))
               for a in (0.02, 0.01)}
ALL_BRDFS = {**BRDFS, **SHARP_BRDFS}


def _view(theta, phi):
    t, p = math.radians(theta), math.radians(phi)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def set_light(scene, kind):
    """``lamp``: the area lamp in a black world; ``env``: the studio world alone; ``both``: the two."""
    import bpy

    from scratch_materials.scratch_addon import render

    for o in [o for o in scene.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(o)
    if kind in ("env", "both"):
        render.studio_world(scene, 1.0)
    else:
        render.uniform_world(scene, 0.0)
    if kind in ("lamp", "both"):
        render.add_light(scene, "AREA", location=(-1.5, 1.0, 2.5), energy=300.0, size=1.5)


def set_view(scene, theta, phi):
    import bpy

    from scratch_materials.scratch_addon import render

    for c in [o for o in scene.objects if o.type == "CAMERA"]:
        bpy.data.objects.remove(c)
    wo = _view(theta, phi)
    up = abs(wo[2]) > 0.999
    render.add_camera(scene, location=tuple(5 * wo + (np.array([0, -1e-3, 0]) if up else 0)), target=(0, 0, 0),
                      ortho_scale=0.4)


def render_means(scene, plane, mats: dict, spp, seeds, osl, tmp, res=32):
    """{name: (frame mean (3,), standard error (3,))} of each material on the plane (Cycles)."""
    from bench.biscale_truth import frame_mean_se
    from scratch_materials.scratch_addon import render

    out = {}
    for key, m in mats.items():
        plane.data.materials[0] = m
        imgs = []
        for sd in seeds:
            render.configure_cycles(scene, samples=spp, res=(res, res), seed=sd, osl=osl, max_bounces=0)
            img, _ = render.render_array(scene, tmp, "merl_audit")
            imgs.append(img.reshape(-1, 3))
        out[key] = frame_mean_se(np.array(imgs))
    return out


def main(argv: list[str]) -> int:
    from bench._util import blender, report

    ap = argparse.ArgumentParser(prog="bench merl_audit")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--views", default="")
    ap.add_argument("--brdfs", default=",".join(BRDFS), help=f"of {', '.join(ALL_BRDFS)}")
    ap.add_argument("--no-eevee", action="store_true")
    ap.add_argument("--eevee-samples", type=int, default=64)
    ap.add_argument("--res", default="auto", help="Direction Resolution of the import: 'auto' (the operator's "
                    "default: from the file's peak) or an integer")
    ap.add_argument("--n-theta", type=int, default=None, help="View Angles of the import (default 32)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    addon = blender(register=True)
    import bpy

    from scratch_materials.precompute.tables import merl
    from scratch_materials.scratch_addon import merl_ops, render

    views = VIEWS if not args.views else [tuple(float(x) for x in v.split("/")) for v in args.views.split(",")]
    tmp = tempfile.mkdtemp()
    render.reset_scene()
    scene = bpy.context.scene
    plane = render.add_plane(scene, size=4.0)
    rows, notes = [], []
    seeds = tuple(range(7, 7 + args.seeds))
    for name in args.brdfs.split(","):
        f, make = ALL_BRDFS[name]
        path = f"{tmp}/{name}.binary"
        t0 = time.perf_counter()
        merl.write_merl(path, merl.tabulate(f))
        t_write = time.perf_counter() - t0
        bpy.context.view_layer.objects.active = plane
        size = {} if args.res == "auto" else {"res": int(args.res)}
        if args.n_theta is not None:
            size["n_theta"] = args.n_theta
        t0, c0 = time.perf_counter(), time.process_time()
        assert bpy.ops.scratch.import_merl(filepath=path, **size) == {"FINISHED"}
        t_op, c_op = time.perf_counter() - t0, time.process_time() - c0
        imported = plane.data.materials[0]
        api = merl_ops.material_from_merl(path, name=f"{name} (API)", **size)
        same = all(str(imported[k]) == str(api[k]) for k in ("tabulated_svm", "tabulated_eevee")) and np.allclose(
            list(imported["merl_albedo_table"]), list(api["merl_albedo_table"]))
        notes.append(f"{name}: file written in {t_write:.1f} s, operator import {t_op:.1f} s wall, {c_op:.1f} s CPU "
                     f"({merl_ops.import_summary(imported)}); API material the same: {same}")
        print(notes[-1], flush=True)
        analytic = make()
        mats = {"imported": imported, "analytic": analytic}
        for light in ("lamp", "env"):
            set_light(scene, light)
            for th, ph in views:
                set_view(scene, th, ph)
                for path_name, osl in (("SVM", False), ("OSL", True)):
                    got = render_means(scene, plane, mats, args.spp, seeds, osl, tmp)
                    (a, sa), (b, sb) = got["analytic"], got["imported"]
                    d = np.abs(b - a)
                    c = int(d.argmax())
                    err, sig = d[c] / a.mean(), math.hypot(sa[c], sb[c]) / a.mean()
                    rows.append([name, light, path_name, f"{th:.0f}/{ph:.0f}", f"{100 * err:.1f} %",
                                 f"{100 * sig:.2f} %", f"{err / max(sig, 1e-12):.1f}", np.round(a, 4).tolist(),
                                 np.round(b, 4).tolist()])
                    print(rows[-1], flush=True)
        if not args.no_eevee:
            set_light(scene, "both")
            for th, ph in EEVEE_VIEWS:
                set_view(scene, th, ph)
                got = {}
                for key, m in mats.items():
                    plane.data.materials[0] = m
                    render.configure_cycles(scene, samples=1, res=(32, 32), seed=7)
                    scene.render.engine = "BLENDER_EEVEE"
                    scene.eevee.taa_render_samples = args.eevee_samples
                    t0 = time.perf_counter()
                    img, _ = render.render_array(scene, tmp, "merl_eevee")
                    got[key] = img.reshape(-1, 3).astype(np.float64).mean(0)
                    print(name, "EEVEE", key, f"{time.perf_counter() - t0:.1f} s", flush=True)
                a, b = got["analytic"], got["imported"]
                err = float(np.abs(b - a).max() / a.mean())
                rows.append([name, "lamp + env", f"EEVEE ({args.eevee_samples} samples)", f"{th:.0f}/{ph:.0f}",
                             f"{100 * err:.1f} %", "-", "-", np.round(a, 4).tolist(), np.round(b, 4).tolist()])
                print(rows[-1], flush=True)
            scene.render.engine = "CYCLES"
    report("merl_audit" + (f"_{args.tag}" if args.tag else ""),
           ["BRDF", "light", "path", "view θo/φo", "max rel. err", "render noise 1σ", "err / σ", "analytic RGB",
            "imported RGB"], rows,
           notes=f"import res {args.res}, n_theta {args.n_theta or 'default'}; " + "; ".join(notes) + f". 32x32 px x {args.spp} spp x {len(seeds)} seeds per Cycles image, max bounces 0.")
    del addon
    return 0
