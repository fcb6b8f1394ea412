"""numpy twin of ``bench merl_audit`` (no renders): what the imported material renders in the audit's scenes,
computed from the closure's numpy twin, against the analytic BRDF, at the audit's views.

Rendered radiance = ∫ f(ωi, ωo) L(ωi) cos θi dωi with f = ``tabulated_brdf.floor_eval`` of ``floor_parts`` (the
floors exactly, the residual's bilinear reconstruction: the expectation of the one-lobe closure, whose own blur,
α 1/16 of a cell, is left out) or the analytic BRDF (``merl_audit.BRDFS``).  Lights as in the audit:
``lamp`` = the area lamp (300 W at (-1.5, 1, 2.5), 1.5 m square facing the origin; 160² points on it, a 3 x 3
grid of points over the camera's 0.4 m footprint), ``env`` = ``render.studio_world`` evaluated in numpy (sky
ramp, wave soft boxes: Cycles' wave texture formula, bands along x, scale 1.5, power 12, x4 above z 0.15..0.5)
by a half-vector midpoint rule (700 x 1440, θh = x² π/2).  Error per view: (imported - analytic) / mean(analytic)
of the channel with the largest difference, as the audit.  It reproduced the res-32 audit renders: gold lamp
+2.8 / -2.4 / +3.1 %, env -0.7 / -1.9 / -1.8 / +5.1 % (renders +2.9 / -2.4 / +3.6 %, -0.8 / -1.9 / -1.7 / +5.5 %);
Beckmann lamp 0/0 +2.0 % (render +1.9 %).

    .venv/bin/python -m bench merl_audit_numpy [--brdfs gold,beckmann] [--sizes auto,32/32/0] [--quick]

``--sizes``: "auto" (the import's default) or res/n_theta/deconvolve (1 / 0) per entry.
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

LAMP, LAMP_SIZE = np.array([-1.5, 1.0, 2.5]), 1.5


def studio(w):
    """``render.studio_world``'s radiance (N, 3) in directions w (N, 3) (its node tree in numpy)."""
    z = w[:, 2]
    pos = np.array([0.45, 0.52, 1.0])
    cols = np.array([[0.02, 0.02, 0.025], [0.9, 0.85, 0.8], [0.55, 0.65, 0.85]])
    c = np.stack([np.interp(z, pos, cols[:, k]) for k in range(3)], 1)
    p = (w * 1.5 + 1e-6) * 0.999999                                  # Cycles' svm_wave input
    wave = 0.5 + 0.5 * np.sin(p[:, 0] * 20.0 - 0.5 * np.pi)
    return c + (wave ** 12 * np.clip((z - 0.15) / 0.35, 0.0, 1.0) * 4.0)[:, None]


def env_radiance(f, wo, n=700, n_phi=1440):
    from scratch_materials.precompute.tables import tabulated_brdf as tb
    from scratch_materials.precompute.tables.merl import half_vector_grid

    h, dwh = half_vector_grid(n, n_phi)
    W = np.broadcast_to(wo, h.shape)
    wi, ok = tb.reflect(W, h)
    wi = np.where(ok[:, None], wi, [0.0, 0.0, 1.0])
    out = np.zeros(3)
    for s in np.array_split(np.arange(len(h)), 8):
        out += (f(wi[s], W[s]) * studio(wi[s]) * (ok[s] * wi[s, 2] * 4 * np.abs(h[s] @ wo) * dwh[s])[:, None]).sum(0)
    return out


def _lamp_frame():
    d = -LAMP                                                         # render.add_light's rotation, target origin
    rx, rz = math.atan2(math.hypot(d[0], d[1]), -d[2]), math.atan2(d[1], d[0]) - math.pi / 2
    cx, sx, cz, sz = math.cos(rx), math.sin(rx), math.cos(rz), math.sin(rz)
    R = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return R[:, 0], R[:, 1], -R[:, 2]


def lamp_radiance(f, wo, nl=160, npts=3):
    ex, ey, nrm = _lamp_frame()
    u = (np.arange(nl) + 0.5) / nl - 0.5
    U, V = np.meshgrid(u, u, indexing="ij")
    L = LAMP + LAMP_SIZE * (U.ravel()[:, None] * ex + V.ravel()[:, None] * ey)
    dA = (LAMP_SIZE / nl) ** 2
    up0 = np.array([0, 0, 1.0]) if abs(wo[2]) < 0.999 else np.array([0, 1.0, 0])
    right = np.cross(up0, wo)
    right /= np.linalg.norm(right)
    up = np.cross(wo, right)
    g = (np.arange(npts) + 0.5) / npts - 0.5
    out = np.zeros(3)
    for a in g:
        for b in g:
            q = 0.4 * (a * right + b * up)
            P = q - wo * q[2] / wo[2]                                 # the pixel's point on the plane z = 0
            d = L - P
            r2 = np.sum(d * d, 1)
            wi = d / np.sqrt(r2)[:, None]
            out += (f(wi, np.broadcast_to(wo, wi.shape)) * (wi[:, 2] * np.maximum(-(wi @ nrm), 0) / r2 * dA)[:, None]).sum(0)
    return out / npts ** 2


def main(argv: list[str]) -> int:
    from bench._util import report
    from bench.merl_audit import ALL_BRDFS, BRDFS, VIEWS, _view
    from scratch_materials.precompute.tables import merl, tabulated_brdf as tb

    ap = argparse.ArgumentParser(prog="bench merl_audit_numpy")
    ap.add_argument("--brdfs", default=",".join(BRDFS), help=f"of {', '.join(ALL_BRDFS)}")
    ap.add_argument("--sizes", default="auto,32/32/0")
    ap.add_argument("--quick", action="store_true", help="gold, auto only, lamp at the mirror view")
    args = ap.parse_args(argv)
    brdfs, sizes, views, lights = args.brdfs.split(","), args.sizes.split(","), VIEWS, ("lamp", "env")
    if args.quick:
        brdfs, sizes, views, lights = ["gold"], ["auto"], [(35.0, 326.0)], ("lamp",)
    rows = []
    for name in brdfs:
        f = ALL_BRDFS[name][0]
        T = merl.fill_missing(np.maximum(merl.tabulate(f), 0.0))
        width = merl.lobe_width(T)
        for spec in sizes:
            if spec == "auto":
                (res, _), nt, dec = merl.auto_resolution(width), merl.AUTO_N_THETA, True
            else:
                r, n, d = spec.split("/")
                res, nt, dec = int(r), int(n), d == "1"
            t0 = time.process_time()
            parts = tb.floor_parts(merl.to_tabulated(T, res, nt, fill=False, deconvolve=dec))
            cpu = time.process_time() - t0
            errs = []
            for light in lights:
                for th, ph in views:
                    wo = _view(th, ph)
                    rad = lamp_radiance if light == "lamp" else env_radiance
                    a = rad(f, wo)
                    b = rad(lambda wi, w: tb.floor_eval(parts, wi, w), wo)
                    c = int(np.abs(b - a).argmax())
                    errs.append(f"{light} {th:.0f}/{ph:.0f} {100 * (b[c] - a[c]) / a.mean():+.1f} %")
            worst = max(abs(float(e.split()[2])) for e in errs)
            rows.append([name, spec, f"{res}² x {nt}", "yes" if dec else "no", f"{math.degrees(width):.2f}°",
                         f"{cpu:.1f}", f"{worst:.1f} %", "; ".join(errs)])
            print(rows[-1], flush=True)
    report("merl_audit_numpy", ["BRDF", "size", "table", "deconvolved", "peak half width", "table + floors (s CPU)",
                                "worst", "per view (imported - analytic) / mean"], rows,
           notes="numpy twin of the merl_audit scenes (module docstring); no render noise.")
    return 0
