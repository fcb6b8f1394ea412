"""Monte Carlo reference for the single-scratch BRDF (Raymond et al. 2016, §4.1), independent of the beam tracer.

For every phi_i bin, ``rays_per_slice`` rays enter through the base plane at uniform random
positions over one period, with phi_i drawn inside the bin with density proportional to
``cos(phi_i)`` (so the estimate is the cosine-weighted bin average).  Each ray is traced by
brute force against every segment of two periods of the periodic profile (the period it is
in and the next one in its travel direction; a free flight never spans more than one
period), mirror-reflected, attenuated by Fresnel with the 3D angle of §4.2, until it leaves
upwards.  Its weight goes to the phi_o bin it leaves in; the table entry is
``sum(weight) / (N * C_o)`` with ``C_o = integral of cos over the phi_o bin`` (the paper's
``M / (N cos phi_o)`` with exact bin integrals).  Noise falls as ``1 / sqrt(N)``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["trace_mc"]

_CHUNK_ELEMS = 2_000_000  # rays x segments per intersection batch


def _intersect(px, ph, dx, dh, ax, ah, ex, eh):
    """First hit (t > eps) of rays p + t d with segments a + s e; returns (t, segment) with t = inf if none."""
    n = px.size
    best_t = np.full(n, np.inf)
    best_j = np.full(n, -1, np.intp)
    step = max(1, _CHUNK_ELEMS // max(1, ax.size))
    for s0 in range(0, n, step):
        sl = slice(s0, s0 + step)
        qx = ax[None, :] - px[sl, None]
        qh = ah[None, :] - ph[sl, None]
        den = dx[sl, None] * eh[None, :] - dh[sl, None] * ex[None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (qx * eh[None, :] - qh * ex[None, :]) / den
            u = (qx * dh[sl, None] - qh * dx[sl, None]) / den
        ok = (den != 0) & (u >= 0.0) & (u <= 1.0) & (t > 1e-9)
        t = np.where(ok, t, np.inf)
        j = np.argmin(t, axis=1)
        best_t[sl] = t[np.arange(t.shape[0]), j]
        best_j[sl] = j
    return best_t, best_j


def trace_mc(verts: np.ndarray, resolution: int, rays_per_slice: int, seed: int = 0, fresnel=None,
             cos_scales=(), *, max_bounces: int = 64):
    """Monte Carlo tables ``(rho_m, rho_f, lost)`` on the ``[phi_o_bin, phi_i_bin]`` grid.

    ``rho_f``: shape ``(S, M, M, C)`` for the Fresnel slices ``cos_scales`` (None without Fresnel);
    ``lost``: per phi_i bin, the flux still inside after ``max_bounces``.
    """
    verts = np.asarray(verts, np.float64)
    M, N = int(resolution), int(rays_per_slice)
    rng = np.random.default_rng(seed)
    # two periods of segments, for rays travelling towards +x (mirror x for the others)
    ax = np.concatenate([verts[:-1, 0], verts[:-1, 0] + 1.0])
    ah = np.concatenate([verts[:-1, 1], verts[:-1, 1]])
    ex = np.tile(np.diff(verts[:, 0]), 2)
    eh = np.tile(np.diff(verts[:, 1]), 2)
    ln = np.hypot(ex, eh)
    nx, nh = -eh / ln, ex / ln
    mir = np.stack([-verts[::-1, 0], verts[::-1, 1]], 1)  # mirrored profile, same x range
    bx = np.concatenate([mir[:-1, 0], mir[:-1, 0] + 1.0])
    bh = np.concatenate([mir[:-1, 1], mir[:-1, 1]])
    fx = np.tile(np.diff(mir[:, 0]), 2)
    fh = np.tile(np.diff(mir[:, 1]), 2)
    fl = np.hypot(fx, fh)
    mx, mh = -fh / fl, fx / fl

    edges = -0.5 * np.pi + np.arange(M + 1) * np.pi / M
    C_o = np.diff(np.sin(edges))
    cos_scales = np.asarray(cos_scales, np.float64)
    S = cos_scales.size
    C = fresnel.channels if (fresnel is not None and S) else 0

    ibin = np.repeat(np.arange(M), N)
    u = rng.random(ibin.size)
    sin_phi = np.sin(edges[ibin]) + u * (np.sin(edges[ibin + 1]) - np.sin(edges[ibin]))
    phi = np.arcsin(np.clip(sin_phi, -1.0, 1.0))
    px = rng.random(ibin.size) - 0.5
    ph = np.zeros(ibin.size)
    dx, dh = -np.sin(phi), -np.cos(phi)
    wf = np.ones((ibin.size, S, C)) if C else None

    acc = np.zeros(M * M)
    accf = np.zeros((S, C, M * M)) if C else None
    lost = np.zeros(M)
    alive = np.arange(ibin.size)
    for _ in range(max_bounces + 1):
        if not alive.size:
            break
        x, h, vx, vh = px[alive], ph[alive], dx[alive], dh[alive]
        x = x - np.floor(x + 0.5)  # back to the base period
        right = vx >= 0
        # rays towards -x are traced in the mirrored profile
        xm = np.where(right, x, -x)
        vxm = np.abs(vx)
        t = np.full(alive.size, np.inf)
        j = np.full(alive.size, -1, np.intp)
        for sel, (sx, sh, sex, seh) in ((right, (ax, ah, ex, eh)), (~right, (bx, bh, fx, fh))):
            if sel.any():
                t[sel], j[sel] = _intersect(xm[sel], h[sel], vxm[sel], vh[sel], sx, sh, sex, seh)
        hit = np.isfinite(t)
        # leaving rays
        esc = ~hit
        up = esc & (vh > 0)
        a = alive[up]
        phi_o = np.arctan2(vx[up], vh[up])
        obin = np.clip(((phi_o + 0.5 * np.pi) * M / np.pi).astype(np.intp), 0, M - 1)
        flat = obin * M + ibin[a]
        acc += np.bincount(flat, minlength=M * M)
        if C:
            for si in range(S):
                for c in range(C):
                    accf[si, c] += np.bincount(flat, wf[a, si, c], minlength=M * M)
        lost += np.bincount(ibin[alive[esc & ~up]], minlength=M)
        # reflecting rays
        a = alive[hit]
        th, jh, rgt = t[hit], j[hit], right[hit]
        nxs = np.where(rgt, nx[jh], mx[jh])
        nhs = np.where(rgt, nh[jh], mh[jh])
        nxs = np.where(rgt, nxs, -nxs)  # mirrored normal back to the original frame
        qx = x[hit] + th * vx[hit]
        qh = h[hit] + th * vh[hit]
        dn = vx[hit] * nxs + vh[hit] * nhs
        dx[a] = vx[hit] - 2 * dn * nxs
        dh[a] = vh[hit] - 2 * dn * nhs
        px[a], ph[a] = qx, qh
        if C:
            wf[a] *= fresnel(np.clip(-dn, 0.0, 1.0)[:, None] * cos_scales[None, :])
        alive = a
    if alive.size:
        lost += np.bincount(ibin[alive], minlength=M)
    norm = N * C_o[:, None]
    rho_m = acc.reshape(M, M) / norm
    rho_f = None
    if C:
        rho_f = np.moveaxis(accf.reshape(S, C, M, M), 1, -1) / norm[None, :, :, None]
    return rho_m, rho_f, lost / N
