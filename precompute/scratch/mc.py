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
             cos_scales=(), *, max_bounces: int = 64, chunk_rays: int = 1 << 18):
    """Monte Carlo tables ``(rho_m, rho_f, lost)`` on the ``[phi_o_bin, phi_i_bin]`` grid.

    ``rho_f``: shape ``(S, M, M, C)`` for the Fresnel slices ``cos_scales`` (None without Fresnel);
    ``lost``: per phi_i bin, the flux still inside after ``max_bounces``.  Rays are traced in batches of
    ``chunk_rays`` (bounded memory); each phi_i bin draws from its own two streams seeded by
    ``(seed, bin)``, so the result does not depend on the batching.
    """
    verts = np.asarray(verts, np.float64)
    M, N = int(resolution), int(rays_per_slice)
    geo = _mc_geometry(verts)
    edges = -0.5 * np.pi + np.arange(M + 1) * np.pi / M
    C_o = np.diff(np.sin(edges))
    cos_scales = np.asarray(cos_scales, np.float64)
    S = cos_scales.size
    C = fresnel.channels if (fresnel is not None and S) else 0
    acc = np.zeros(M * M)
    accf = np.zeros((S, C, M * M)) if C else None
    lost = np.zeros(M)
    streams = {}
    step = max(1, int(chunk_rays))
    # batches of (bin, first ray, count): whole bins while they fit, else parts of one bin
    batches, cur, n_cur = [], [], 0
    for b in range(M):  # a loop over phi_i bins to plan the batches (cheap)
        for r0 in range(0, N, step):
            cnt = min(step, N - r0)
            if n_cur + cnt > step and cur:
                batches.append(cur)
                cur, n_cur = [], 0
            cur.append((b, cnt))
            n_cur += cnt
    if cur:
        batches.append(cur)
    for batch in batches:  # a loop over ray batches
        ibin = np.concatenate([np.full(cnt, b) for b, cnt in batch])
        u = np.concatenate([_stream(streams, seed, b, 0).random(cnt) for b, cnt in batch])
        px = np.concatenate([_stream(streams, seed, b, 1).random(cnt) for b, cnt in batch]) - 0.5
        _trace_batch(geo, ibin, u, px, edges, M, fresnel, cos_scales, C, max_bounces, acc, accf, lost)
    norm = N * C_o[:, None]
    rho_m = acc.reshape(M, M) / norm
    rho_f = None
    if C:
        rho_f = np.moveaxis(accf.reshape(S, C, M, M), 1, -1) / norm[None, :, :, None]
    return rho_m, rho_f, lost / N


def _stream(streams: dict, seed: int, b: int, which: int):
    key = (b, which)
    if key not in streams:
        streams.clear() if len(streams) > 64 else None
        streams[key] = np.random.default_rng([int(seed), int(b), which])
    return streams[key]


def _mc_geometry(verts):
    """Two periods of segments for rays travelling towards +x, and the mirrored profile for the others."""
    ax = np.concatenate([verts[:-1, 0], verts[:-1, 0] + 1.0])
    ah = np.concatenate([verts[:-1, 1], verts[:-1, 1]])
    ex = np.tile(np.diff(verts[:, 0]), 2)
    eh = np.tile(np.diff(verts[:, 1]), 2)
    ln = np.hypot(ex, eh)
    mir = np.stack([-verts[::-1, 0], verts[::-1, 1]], 1)  # mirrored profile, same x range
    bx = np.concatenate([mir[:-1, 0], mir[:-1, 0] + 1.0])
    bh = np.concatenate([mir[:-1, 1], mir[:-1, 1]])
    fx = np.tile(np.diff(mir[:, 0]), 2)
    fh = np.tile(np.diff(mir[:, 1]), 2)
    fl = np.hypot(fx, fh)
    return dict(right=(ax, ah, ex, eh), left=(bx, bh, fx, fh), n=(-eh / ln, ex / ln), m=(-fh / fl, fx / fl))


def _trace_batch(geo, ibin, u, px, edges, M, fresnel, cos_scales, C, max_bounces, acc, accf, lost):
    """Trace one batch of rays (bins ``ibin``, uniforms ``u`` for phi_i, positions ``px``); accumulate in place."""
    nx, nh = geo["n"]
    mx, mh = geo["m"]
    S = cos_scales.size
    sin_phi = np.sin(edges[ibin]) + u * (np.sin(edges[ibin + 1]) - np.sin(edges[ibin]))
    phi = np.arcsin(np.clip(sin_phi, -1.0, 1.0))
    ph = np.zeros(ibin.size)
    dx, dh = -np.sin(phi), -np.cos(phi)
    wf = np.ones((ibin.size, S, C)) if C else None
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
        for sel, segs in ((right, geo["right"]), (~right, geo["left"])):
            if sel.any():
                t[sel], j[sel] = _intersect(xm[sel], h[sel], vxm[sel], vh[sel], *segs)
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
