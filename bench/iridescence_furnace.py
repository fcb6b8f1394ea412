"""White furnace of the iridescent layer in Cycles (issue #17 item 2).

A lossless mirror base (Glossy, roughness 0, white) under a uniform white world, seen by orthographic
cameras from several views: whatever the scratches do, a lossless surface reflects everything, so every
pixel must be 1.  The layer (route A, lobes: the route that sees the world) is rendered with the
energy-consistent base weight (default) and with eq. 6's (1 − ρ) ("paper", the previous behaviour), for
the issue's scratch sets and more densities, widths, depths, views and wavelength triples.

Run: ``.venv/bin/python -m bench iridescence_furnace [--quick]``.  ``furnace_scene`` is shared with
tests/iridescence/test_iridescence_furnace.py.
"""
from __future__ import annotations

import math
import tempfile

import numpy as np

PLANE = 2.0         # m; UV 0..1 across it
ORTHO = 0.3         # m across the (square) frame


def view_dir(theta_deg, phi_deg):
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def furnace_scene(render, im, S, *, view=(0.0, 0.0), res=32, spp=64, layer=True, seed=0, source_edit=None,
                  **layer_kw):
    """Reset the file: mirror plane with the layer (``layer_kw`` → ``insert_layer``), uniform white world,
    orthographic camera from ``view`` = (θ, φ) degrees.  ``source_edit(spec_kw) -> source`` replaces the
    generated shader (other wavelengths).  Returns the scene."""
    import bpy

    scene = render.reset_scene()
    render.uniform_world(scene, 1.0)
    mat = bpy.data.materials.new("Furnace mirror")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Roughness"].default_value = 0.0
    g.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(g.outputs[0], out.inputs["Surface"])
    if layer:
        node = im.insert_layer(mat, S, scene=scene, **layer_kw)
        if source_edit is not None:
            text = node.script
            text.clear()
            text.write(source_edit())
            from scratch_materials.scratch_addon import osl_compile

            osl_compile.compile_script_node(node)
    render.add_plane(scene, size=PLANE, material=mat)
    d = view_dir(*view)
    render.add_camera(scene, location=tuple(5.0 * d), target=(0.0, 0.0, 0.0), ortho_scale=ORTHO)
    render.configure_cycles(scene, samples=spp, res=(res, res), seed=seed, osl=True, max_bounces=2)
    return scene


def issue_sets(im):
    """The issue's scratch sets (length 0.3-0.6 UV, 1 cm per UV) plus more widths, depths and densities."""
    def gen(count, W, D, seed):
        return im.generate_scratch_set(count, length_range=(0.3, 0.6), width_range_um=W, depth_range_um=D,
                                       seed=seed, uv_scale_um=1e4)
    lam4 = (0.1375, 0.1375)
    return [
        ("300 x 3 um, depth 0", gen(300, (3.0, 3.0), (0.0, 0.0), 1)),
        ("300 x 3 um, lambda/4", gen(300, (3.0, 3.0), lam4, 2)),
        ("300 x 3 um, 1 um", gen(300, (3.0, 3.0), (1.0, 1.0), 3)),
        ("1000 x 3 um, lambda/4", gen(1000, (3.0, 3.0), lam4, 4)),
        ("3000 x 8 um, lambda/4", gen(3000, (8.0, 8.0), lam4, 5)),
        ("3000 x 5 um, depth 0", gen(3000, (5.0, 5.0), (0.0, 0.0), 6)),
        ("600 x 0.5-1.5 um, 0.2-1.2 um", gen(600, (0.5, 1.5), (0.2, 1.2), 7)),
        ("2000 x 0.8-6 um, 0.8-6 um", gen(2000, (0.8, 6.0), (0.8, 6.0), 8)),
    ]


VIEWS = [(0.0, 0.0), (45.0, 30.0), (70.0, 100.0), (80.0, 0.0)]


def main(argv) -> int:
    from bench._util import report
    from bench.iridescence_cycles import _setup
    from scratch_materials.osl import iridescent_layer as layer_gen
    from scratch_materials.precompute.iridescence import layer as ly

    quick = "--quick" in argv
    render, im = _setup()
    res, spp = (24, 32) if quick else (48, 256)
    sets = issue_sets(im)
    views = VIEWS[::3] if quick else VIEWS
    if quick:
        sets = sets[:2] + sets[3:5]
    tmp = tempfile.mkdtemp()
    rows = []
    for name, S in sets:
        for view in views:
            row = [name, f"{view[0]:.0f}/{view[1]:.0f}"]
            for bw in ("paper", "energy"):
                sc = furnace_scene(render, im, S, view=view, res=res, spp=spp, base_weight=bw)
                img, _ = render.render_array(sc, tmp, "furnace")
                m = img.mean((0, 1))
                row.append(" / ".join(f"{v:.3f}" for v in m))
                if bw == "energy":
                    row.append(f"{np.abs(m - 1).max() * 100:.2f}")
            rows.append(row)
            print(row, flush=True)
    # other wavelength triples (the shader's RGB mode evaluates the model at 3 wavelengths)
    S = sets[1][1]
    for lam in ((0.60, 0.55, 0.45), (0.70, 0.50, 0.40)):
        def edit(lam=lam):
            return layer_gen.generate(ly.LayerSpec(S, wavelengths_um=lam))
        sc = furnace_scene(render, im, S, view=(45.0, 30.0), res=res, spp=spp, source_edit=edit)
        img, _ = render.render_array(sc, tmp, "furnace")
        m = img.mean((0, 1))
        rows.append([f"{sets[1][0]}, lambda = {lam}", "45/30", "", " / ".join(f"{v:.3f}" for v in m),
                     f"{np.abs(m - 1).max() * 100:.2f}"])
    notes = (f"Mirror plane (Glossy, roughness 0, white) + iridescent layer (route A, 4 candidates), uniform white "
             f"world, orthographic {res}x{res} px, {spp} spp, frame 0.3 m = 0.15 UV at 1 cm per UV; image mean "
             "(R / G / B).  paper = eq. 6's (1 − ρ) base weight (the previous layer), energy = the energy-consistent "
             "weight (default).  Goal: 1 within 2 % (moderate density), 5 % (heavy overlap), exactly 1 at depth 0.")
    report("iridescence_furnace", ["scratch set", "view θ/φ (deg)", "paper (R / G / B)", "energy (R / G / B)",
                                   "energy max |err| %"], rows, notes)
    return 0
