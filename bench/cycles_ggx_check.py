"""Validate the numpy Cycles twin (precompute.cycles.ggx / cycles_beckmann) against real Cycles renders.

Scene: a flat plane (z = 0, scratch direction u = x, v = y), a uniform white world (radiance 1),
an orthographic camera looking at the plane from the view angle phi_o (in the v-n plane), and
ONE tilted OSL lobe ``microfacet(dist, N' = (0, sin t, cos t), u, ax, ay, 0, 0)`` with
``use_bump_map_correction = False``.  The rendered value is the lobe's directional albedo (the
integral of eval over all light directions, rejections included), compared with
``cycles_ggx.albedo(tilt, ax, ay, theta_o=0, phi_o, dist=...)``.  Writes bench/out/cycles_ggx_check.md
and a PNG.  ``--quick``: 4 configurations, 16x16 px, 64 spp.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

OSL_LOBE = """
shader tilted_lobe(float tilt = 0.0, float ax = 0.0001, float ay = 0.1, int beckmann = 0,
                   output closure color BSDF = 0)
{
    normal Np = normalize(normal(0.0, sin(tilt), cos(tilt)));
    vector T = vector(1.0, 0.0, 0.0);
    if (beckmann)
        BSDF = microfacet("beckmann", Np, T, ax, ay, 0.0, 0);
    else
        BSDF = microfacet("ggx", Np, T, ax, ay, 0.0, 0);
}
"""


def build_scene(render, materials, osl_compile, samples: int, res: int, phi_o: float, seed: int = 1):
    """Plane + white world + ortho camera at view angle phi_o (radians); returns (scene, script node)."""

    scene = render.reset_scene()
    render.uniform_world(scene, 1.0)
    mat = materials.new_material("TiltedLobe")
    mat.cycles.use_bump_map_correction = False
    tree = mat.node_tree
    node = osl_compile.script_node_from_source(tree, "tilted_lobe.osl", OSL_LOBE)
    tree.links.new(node.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    render.add_plane(scene, size=8.0, material=mat)
    loc = (0.0, 5.0 * np.sin(phi_o), 5.0 * np.cos(phi_o))
    render.add_camera(scene, location=loc, target=(0.0, 0.0, 0.0), ortho_scale=0.5)
    render.configure_cycles(scene, samples=samples, res=(res, res), seed=seed, osl=True, max_bounces=2)
    return scene, node


def _setup_bpy():
    from bench._util import blender

    blender()
    from scratch_materials.scratch_addon import materials, osl_compile, render

    return render, materials, osl_compile


def main(argv) -> int:
    from bench._util import out_path, pyplot, report
    from scratch_materials.precompute.cycles import ggx as cg

    quick = "--quick" in argv
    render, materials, osl_compile = _setup_bpy()
    samples, res = (64, 16) if quick else (256, 16)
    ax = 1e-4
    tilts = [0, 40] if quick else [0, 20, 40, 60]
    widths = [0.1] if quick else [0.02, 0.1, 0.3]
    views = [0.0] if quick else [0.0, 0.5]
    rows = []
    tmp = tempfile.mkdtemp(prefix="cycles_lobe_")
    for phi_o in views:
        scene, node = build_scene(render, materials, osl_compile, samples, res, phi_o)
        for dist in ("ggx", "beckmann"):
            for t_deg in tilts:
                for ay in widths:
                    t = np.radians(t_deg)
                    node.inputs["tilt"].default_value = float(t)
                    node.inputs["ax"].default_value = ax
                    node.inputs["ay"].default_value = float(ay)
                    node.inputs["beckmann"].default_value = int(dist == "beckmann")
                    img, sec = render.render_array(scene, tmp, f"r_{dist}_{t_deg}_{ay}_{phi_o}")
                    px = img[..., 1].ravel()
                    got = float(px.mean())
                    se = float(px.std() / np.sqrt(px.size))      # pixels are independent estimates
                    ref = float(cg.albedo(t, ax, ay, 0.0, phi_o, n=1024, dist=dist))
                    rows.append([dist, round(float(np.degrees(phi_o)), 1), t_deg, ay, got, se, ref, got - ref,
                                 (got - ref) / max(se, 1e-9), sec])
                    print(rows[-1], flush=True)
    report("cycles_ggx_check", ["dist", "phi_o_deg", "tilt_deg", "alpha_y", "cycles", "cycles_se", "numpy_albedo",
                                "diff", "diff/se", "render_s"], rows,
           notes=f"One OSL microfacet lobe (alpha_x = {ax}) on a plane under a uniform white world, orthographic "
                 f"camera at view angle phi_o in the v-n plane, {res}x{res} px, {samples} spp, "
                 "use_bump_map_correction off. cycles = mean pixel value (directional albedo incl. Smith G and "
                 "rejections); cycles_se = standard error over pixels; numpy_albedo = cycles_ggx.albedo (slope-space "
                 "quadrature, n = 1024).")
    plt = pyplot()
    fig, ax_ = plt.subplots(figsize=(6, 4))
    r = np.array([[x[4], x[6]] for x in rows])
    ax_.plot(r[:, 1], r[:, 0], "o")
    ax_.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax_.set_xlabel("numpy twin albedo")
    ax_.set_ylabel("Cycles render")
    fig.tight_layout()
    fig.savefig(out_path("cycles_ggx_check.png"), dpi=90)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
