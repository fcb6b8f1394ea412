"""README figure for issue #17: the iridescent layer before (eq. 6's 1 − ρ base weight) and after (the
energy-consistent weight, ``precompute.iridescence.energy``), side by side, same scenes, same seeds.

Top row: the README's plate (``iridescence_fig.plate_scene``: 6000 scratches 0.8-6 µm wide and deep,
steel, small sphere light, dim studio world): the paper's glints survive unchanged.  Bottom row: the
same plate with 4000 shallow scratches (3 µm wide, 0.25-0.3 µm deep, about λ/2 for green) under a
brighter studio world: eq. 6 darkens the mirror reflection by ρ and adds the diffraction on top;
the energy-consistent layer takes from the mirror what the scratches diffract, per wavelength, so
the reflection of the studio takes the complementary (green) tint.

Writes docs/img/iridescence_energy.png (bench/out/iridescence_energy.png with --quick).
Run: ``.venv/bin/python -m bench iridescence_energy_fig [--quick]``.
"""
from __future__ import annotations

import shutil
import tempfile

import numpy as np


def shallow_scratches(im, count=4000):
    """Dense shallow isotropic scratches: the base weight's tint is visible (about λ/2 for green)."""
    return im.generate_scratch_set(count, length_range=(0.05, 0.3), width_range_um=(3.0, 3.0),
                                   depth_range_um=(0.25, 0.3), spread_deg=180.0, seed=11, uv_scale_um=2e4)


def main(argv) -> int:
    from bench._util import out_path, pyplot
    from bench.iridescence_fig import DOCS, plate_scene, plate_scratches, setup

    quick = "--quick" in argv
    render, im = setup()
    res = (160, 120) if quick else (256, 192)
    spp = 16 if quick else 64
    tmp = tempfile.mkdtemp()
    rows = [("README plate: 6000 scratches", plate_scratches(im), 0.05),
            ("4000 shallow scratches (D ≈ λ/2)", shallow_scratches(im), 0.6)]
    imgs, means = [], []
    for title, S, ws in rows:
        pair = []
        for bw in ("paper", "energy"):
            scene = plate_scene(render, im, S, res=res, spp=spp, world_strength=ws, base_weight=bw)
            img, sec = render.render_array(scene, tmp, f"{bw}_{len(imgs)}")
            print(f"{title} / {bw}: {sec:.1f} s, mean RGB {img.mean((0, 1))}", flush=True)
            pair.append(img)
        imgs.append(pair)
        means.append([p.mean((0, 1)) for p in pair])
    plt = pyplot()
    fig, axs = plt.subplots(2, 2, figsize=(2 * res[0] / 80, 2 * res[1] / 80 + 0.9))
    for r, ((title, _S, _ws), pair, mm) in enumerate(zip(rows, imgs, means)):
        for c, (lab, img, m) in enumerate(zip(("before: eq. 6, base × (1 − ρ)", "after: energy-consistent base"),
                                              pair, mm)):
            x = np.clip(img, 0.0, None)
            x = x / (1.0 + x)                                  # Reinhard, same on both sides
            x = np.clip(x, 0.0, 1.0) ** (1 / 2.2)
            ax = axs[r, c]
            ax.imshow(x)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{lab}\nmean RGB {m[0]:.3f} {m[1]:.3f} {m[2]:.3f}", fontsize=7)
        axs[r, 0].set_ylabel(title, fontsize=7)
    fig.suptitle("Iridescent layer: eq. 6 vs energy-consistent base weight", fontsize=8)
    fig.tight_layout()
    dst = out_path("iridescence_energy.png")
    fig.savefig(dst, dpi=100)
    plt.close(fig)
    if not quick:
        DOCS.mkdir(parents=True, exist_ok=True)
        shutil.copy(dst, DOCS / "iridescence_energy.png")
    print(f"iridescence_energy.png: {res[0]}x{res[1]} per panel, {spp} spp ({'bench/out only' if quick else 'docs/img'})")
    return 0
