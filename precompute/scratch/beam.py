"""Exact 2D beam tracer for the single-scratch BRDF (Raymond et al. 2016, §4.1-4.2).

For a piecewise-linear (periodic) profile, a parallel beam hitting a flat segment leaves as a
parallel beam.  So for one incident direction phi_i the light leaving the scratch is an *exact*
finite sum of directions with weights (beam widths times Fresnel products): no noise.

One bounce, for every beam at once (numpy, no loops over beams):

- Work in a frame where the beam travels towards +x (the profile is mirrored for beams that
  travel towards -x).  With travel direction ``d = (dx, dh)``, ``dx >= 0``, the signed distance
  of a point ``p`` to the ray line, ``s(p) = dx * p_h - dh * p_x``, is the *level* of the ray
  through ``p``; the profile is above a ray of level ``L`` where ``s > L``.
- The profile is x-monotone, so the first surface point hit by a ray of level ``L`` that
  leaves the profile at vertex ``v0`` is where the running maximum ``Q`` of ``s`` along the
  vertices after ``v0`` first reaches ``L``.  Segment ``w`` is therefore hit by the levels
  ``(Q_w, Q_{w+1}]`` (1D visibility), which splits the beam into sub-beams exactly.
- A free flight never spans more than one period (the highest point repeats every period),
  so the scan covers at most ``P`` segments.  The vertices where ``Q`` rises (the only ones that
  matter) are found by descending a max-level hierarchy of vertex bounding boxes (a 1D max mipmap
  over x, ``_Hierarchy``): ``O(log P)`` steps per hit and per escaping beam instead of a scan of the
  period, vectorised over all beams; the result is the scan's, bit for bit (``tests/scratch/
  test_beam_visibility.py`` holds it equal to a brute-force scan).  Profiles of at most
  ``_HIERARCHY_MIN_SEGMENTS`` (512) segments keep the bucket scan (``_visibility_scan``: windows of
  ~sqrt(P) vertices, buckets whose bounding box stays below the beam skipped), which takes fewer numpy
  passes there.  The first bounce, a parallel beam from above, is one running maximum over two periods
  per direction (``O(P)``).
- Sub-beams are reflected (mirror), attenuated by Fresnel with the 3D angle of §4.2
  (``cos = cos(theta_o) |d . n|``), and traced again; beams with no further hit leave.

Each leaving beam is recorded with a hash of its segment sequence (its *path*), so the caller
can follow each path continuously between neighbouring incident directions (the exit direction
of a path is ``phi_o = (-1)^bounces phi_i + const``).  Each beam also carries the two points that
bound it, *unfolded* back into the incident space (the reflections of its path undone): there
the beam is straight, so its width as a function of the incident angle is exactly
``|D x d_i(phi_i)| = |A cos(phi_i) + B sin(phi_i)|`` with ``D`` the difference of the two points, for
as long as the same vertices bound it.  The caller integrates that sinusoid over phi_i bins.

Limits: at most ``max_bounces`` bounces (default 64), and the tracing of an incident direction
stops once less than ``min_energy`` (1e-7) of its light is still inside (so the result for one
direction does not depend on which other directions are traced with it); beams narrower than
1e-12 of the incident beam are dropped.  All of this is returned as ``lost`` energy.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ExitRecords", "trace_exact", "path_fresnel"]

_HASH_MUL = np.int64(1_000_003)
_MIN_WIDTH = 1e-12  # relative to the incident beam width
_VIS_BEAMS = 1 << 16  # beams per visibility batch (~20 working arrays of 8 bytes each: ~10 MB)
_VIS_ELEMS = 1 << 21  # [beam, bucket] elements per scan batch (~6 such arrays: ~100 MB)
#: profiles with more segments use the hierarchy (``_visibility``), smaller ones the bucket scan
#: (``_visibility_scan``: fewer numpy passes there; measured on the 256-segment quartic at M = 256)
_HIERARCHY_MIN_SEGMENTS = 512
#: ``trace_exact(scan_tail=True)``: the hierarchy's searching beams finish by one scan once they are at most
#: ``_TAIL_ELEMS / P`` (their levels: ~1 MB; measured-4096, 16 traced directions per call: trace CPU -13 % at 2^17
#: and 2^18, -11 % at 2^15, +6 % at 2^19)
_TAIL_ELEMS = 1 << 17


@dataclass
class ExitRecords:
    """Beams leaving the scratch.  One row per (incident sample, path).

    ``sample``: index into the incident directions; ``pid``: path hash (segment sequence);
    ``bounces``: number of reflections; ``phi_o``: exit angle;
    ``weight``: fraction of the incident flux (no Fresnel); ``fresnel``: the same with Fresnel,
    shape ``(n, S, C)`` for the S requested theta_o slices; ``flux_ab``: ``(A, B)`` with
    ``A cos(phi_i) + B sin(phi_i)`` = the beam width per period of incident beam near this
    sample (= ``weight * cos(phi_i)`` at the sample); ``lost``: per-sample flux not accounted for
    (bounce/energy limits, degenerate rays).  ``bounds``: ``(n, 2, 2)``, the level coefficients
    ``(c1, c2)`` of the lower and upper bounding (unfolded) points: the incident ray through the
    point has level ``c1 cos(phi_i) + c2 sin(phi_i)`` (= ``x cos - h sin``), so the beam width is
    ``upper - lower`` (= ``flux_ab`` at the sample) for as long as the same points bound it.
    ``cos_path``: ``(n, B)`` the 2D cosine ``|d . n|`` of each bounce of the beam's path (0 past its
    ``bounces``), recorded with ``trace_exact(cos_path=True)``: the Fresnel weights of any model and θo follow
    from them (``path_fresnel``) without tracing again.
    """

    sample: np.ndarray
    pid: np.ndarray
    bounces: np.ndarray
    phi_o: np.ndarray
    weight: np.ndarray
    fresnel: np.ndarray | None
    flux_ab: np.ndarray
    lost: np.ndarray
    bounds: np.ndarray | None = None
    cos_path: np.ndarray | None = None


class _Hierarchy:
    """Max-level hierarchy over the unrolled vertices of both frames (a 1D max mipmap over x).

    Node ``i`` of level ``k`` holds the vertices ``[i 2^k, (i + 1) 2^k)``; over their bounding box the
    level ``s = dx h - dh x`` (``dx >= 0``) is at most ``dx hmax - dh xsel`` with ``xsel = xmin`` for
    ``dh >= 0`` and ``xmax`` for ``dh < 0`` (at level 0, one vertex, that is its level bit for bit).
    Flat arrays ``hmax``, ``xsel`` hold four tables (frame ``o`` x sign of ``dh``: ``t = 2 o + (dh < 0)``),
    node ``(t, k, i)`` at ``t * size + off[k] + i``; each level has one padding node past its end.
    """

    def __init__(self, X: np.ndarray, H: np.ndarray):
        xmin, xmax, hmax = [X], [X], [H]
        while xmin[-1].shape[1] > 1:
            a, b, c = xmin[-1], xmax[-1], hmax[-1]
            if a.shape[1] % 2:  # pad the odd node with a copy of the last one (same box)
                a, b, c = (np.concatenate([z, z[:, -1:]], 1) for z in (a, b, c))
            xmin.append(np.minimum(a[:, 0::2], a[:, 1::2]))
            xmax.append(np.maximum(b[:, 0::2], b[:, 1::2]))
            hmax.append(np.maximum(c[:, 0::2], c[:, 1::2]))
        self.top = len(xmin) - 1
        nk = np.array([z.shape[1] for z in xmin], np.int64) + 1  # + the padding node
        self.off = np.concatenate([[0], np.cumsum(nk)[:-1]]).astype(np.int64)
        self.size = int(nk.sum())
        pad = lambda z: np.concatenate([z, z[:, -1:]], 1)  # noqa: E731
        lev = lambda zs, o: np.concatenate([pad(z)[o] for z in zs])  # noqa: E731
        self.hmax = np.concatenate([lev(hmax, o) for o in (0, 0, 1, 1)])
        self.xsel = np.concatenate([lev(xmin, 0), lev(xmax, 0), lev(xmin, 1), lev(xmax, 1)])

    def table(self, o: np.ndarray, dh: np.ndarray) -> np.ndarray:
        """Offset of the table of each beam (frame ``o``, travel direction ``dh``)."""
        return (2 * o.astype(np.int64) + (dh < 0)) * self.size

    def ascend(self, k: np.ndarray, i: np.ndarray):
        """From node ``i`` (>= 1) of level ``k`` up while it is a first child (same first vertex): ``(k, i)``."""
        tz = ((i & -i).astype(np.float64).view(np.int64) >> 52) - 1023  # trailing zero bits of i
        tz = np.minimum(tz, self.top - k)
        return k + tz, i >> tz


class _Buckets:
    """Buckets of ``B ~ sqrt(P)`` consecutive unrolled vertices with their bounding boxes (``_visibility_scan``)."""

    def __init__(self, X: np.ndarray, H: np.ndarray, P: int, G: int):
        L = X.shape[1]
        self.bucket = B = G
        self.G = G
        nb = -(-L // B)
        idx = np.minimum(np.arange(nb)[:, None] * B + np.arange(B + 1)[None, :], L - 1)
        self.nbuckets = nb
        self.bxmin_f = X[:, idx].min(-1).ravel()
        self.bxmax_f = X[:, idx].max(-1).ravel()
        self.bhmax_f = H[:, idx].max(-1).ravel()
        # four tables (frame o x sign of dh: t = 2 o + (dh < 0)) of the bucket's top and of the x at which the
        # level's -dh x term is largest (xmin for dh >= 0, xmax for dh < 0): one gather each per beam and bucket
        xmin, xmax, hmax = (z.reshape(2, nb) for z in (self.bxmin_f, self.bxmax_f, self.bhmax_f))
        self.bxsel_t = np.concatenate([xmin[0], xmax[0], xmin[1], xmax[1]])
        self.bhmax_t = np.concatenate([hmax[0], hmax[0], hmax[1], hmax[1]])


class _Geometry:
    """The periodic polyline in both travel frames, unrolled over a few periods, plus its hierarchy."""

    def __init__(self, verts: np.ndarray, scan_tail: bool = False):
        self.scan_tail = bool(scan_tail)
        P = verts.shape[0] - 1
        if P < 1 or not np.all(np.isfinite(verts)) or np.any(np.diff(verts[:, 0]) < 0.0):
            raise ValueError("verts: expected a finite height-field polyline, x non-decreasing")
        self.P = P
        self.G = int(max(4, min(64, round(np.sqrt(P)))))
        L = 3 * P + 2 * self.G + 2
        k = np.arange(L)
        X = np.empty((2, L))
        H = np.empty((2, L))
        base1 = np.stack([-verts[::-1, 0], verts[::-1, 1]], 1)  # mirrored frame: V~_k = mirror(V_{P-k})
        for o, base in enumerate((verts, base1)):
            X[o] = base[k % P, 0] + (k // P) * 1.0
            H[o] = base[k % P, 1]
        self.X, self.H = X, H
        e = np.stack([X[:, 1 : P + 1] - X[:, :P], H[:, 1 : P + 1] - H[:, :P]], -1)  # (2, P, 2)
        ln = np.hypot(e[..., 0], e[..., 1])
        self.normal = np.stack([-e[..., 1], e[..., 0]], -1) / np.maximum(ln, 1e-300)[..., None]
        if P > _HIERARCHY_MIN_SEGMENTS:
            self.hier = _Hierarchy(X, H)
        else:
            self.buckets = _Buckets(X, H, P, self.G)
        # flat copies for fast 1D gathers (index = frame * length + position)
        self.Xf, self.Hf = X.ravel(), H.ravel()


def _apply(U, x, h):
    """Unfolding map ``U = (R [n,2,2], t [n,2])`` applied to points (x, h) -> [n, 2]."""
    R, t = U
    x0 = R[:, 0, 0] * x + R[:, 0, 1] * h + t[:, 0]
    out = np.empty(x0.shape + (2,))  # (np.stack costs more than the arithmetic on the small batches here)
    out[..., 0] = x0
    out[..., 1] = R[:, 1, 0] * x + R[:, 1, 1] * h + t[:, 1]
    return out


def _take(bm: dict, b) -> dict:
    return {k: (None if v is None else v[b]) for k, v in bm.items()}


def trace_exact(verts: np.ndarray, phi_i: np.ndarray, fresnel=None, cos_scales=(), *,
                max_bounces: int = 64, min_energy: float = 1e-7, scan_tail: bool = False,
                cos_path: bool = False, bounds: bool = True) -> ExitRecords:
    """Trace parallel beams incident at angles ``phi_i`` (radians, |phi_i| < pi/2) into the periodic profile.

    ``verts``: one period of the polyline, ``(P + 1, 2)`` with ``V_P = V_0 + (1, 0)``, max height 0.
    ``fresnel``: callable ``cos -> (..., C)`` or None; ``cos_scales``: ``cos(theta_o)`` of the Fresnel
    slices to track (the 3D incidence cosine of §4.2 is ``cos(theta_o) |d . n|``).
    ``scan_tail``: the hierarchy's last few searching beams finish by one scan (``_finish_by_scan``): the same
    records, in another order (sums over them, e.g. ``lost``, may differ in the last bit).
    ``cos_path``: also record every exit's bounce cosines (``ExitRecords.cos_path``; ``path_fresnel`` gives the
    ``fresnel`` weights from them, bit for bit those of a trace with that model).
    ``bounds`` False: no beam edges (``flux_ab`` and ``bounds`` None): the unfolding maps and edge points that only
    they need are not followed through the bounces; every other record is the same, bit for bit (the view
    slices of ``slices`` read exits, weights, bounces and Fresnel only).
    """
    g = _Geometry(np.asarray(verts, np.float64), scan_tail)
    P = g.P
    phi_i = np.asarray(phi_i, np.float64)
    E = phi_i.size
    S = len(cos_scales)
    C = fresnel.channels if (fresnel is not None and S) else 0
    cos_scales = np.asarray(cos_scales, np.float64)

    out = {k: [] for k in ("sample", "pid", "nb", "phi", "w", "f", "ab", "bd", "cp")}
    lost = np.zeros(E)
    inc = np.cos(phi_i)  # incident beam width per period (period = 1)

    # ---- first bounce: parallel beam from above, one period of it (2 periods of running max) ----
    d0x, d0h = -np.sin(phi_i), -np.cos(phi_i)
    o = (d0x < 0).astype(np.intp)
    dx, dh = np.abs(d0x), d0h
    Xs, Hs = g.X[o, : 2 * P + 1], g.H[o, : 2 * P + 1]
    s = dx[:, None] * Hs - dh[:, None] * Xs
    Q = np.maximum.accumulate(s, axis=1)
    lo, hi = Q[:, P : 2 * P], Q[:, P + 1 : 2 * P + 1]
    keep = (hi - lo) > _MIN_WIDTH * inc[:, None]
    e_idx, w_idx = np.nonzero(keep)
    sA, sB = s[:, P : 2 * P][keep], s[:, P + 1 : 2 * P + 1][keep]
    den = sB - sA
    t_lo = np.clip((lo[keep] - sA) / den, 0.0, 1.0)
    t_hi = np.clip((hi[keep] - sB) / den + 1.0, 0.0, 1.0)
    lost += inc - np.bincount(e_idx, hi[keep] - lo[keep], minlength=E)
    n0 = e_idx.size
    oo = o[e_idx]
    beams = dict(
        sample=e_idx, o=oo, j=w_idx, shift=np.ones(n0, np.intp), t0=t_lo, t1=t_hi, dx=dx[e_idx], dh=dh[e_idx],
        pid=np.zeros(n0, np.int64),
        f=True if C else None,   # (Fresnel products of no bounce yet: all ones, which the first bounce replaces)
        R=None, tr=None, P0=None, P1=None,
        cp=np.zeros((n0, 0)) if cos_path else None,
    )
    if bounds:  # the beams' edge points, unfolded (``ExitRecords.flux_ab`` / ``bounds``)
        # index of the vertex that holds the running maximum (the occluder)
        am = np.maximum.accumulate(np.where(s >= Q, np.arange(2 * P + 1)[None, :], 0), axis=1)
        R = np.zeros((n0, 2, 2))
        R[:, 0, 0] = np.where(oo == 0, 1.0, -1.0)  # frame 1 is the mirror image
        R[:, 1, 1] = 1.0
        U = (R, np.zeros((n0, 2)))
        v_lo = am[:, P : 2 * P][keep]
        v_hi = w_idx + P + 1
        beams.update(R=R, tr=U[1], P0=_apply(U, g.X[oo, v_lo], g.H[oo, v_lo]),
                     P1=_apply(U, g.X[oo, v_hi], g.H[oo, v_hi]))
    bounce = 0
    while beams["sample"].size:
        bounce += 1
        beams = _reflect(g, beams, fresnel, cos_scales)
        hits, esc = _visibility_batched(g, beams)
        _record(out, beams, esc, bounce, inc, phi_i, lost)  # leaving beams
        b = hits["beam"]  # beams hitting the profile again
        inside = np.bincount(beams["sample"][b], hits["width"], minlength=E)
        # bounce or energy limit, per incident direction: what is still inside is lost
        stop = (inside < min_energy * inc) if bounce < max_bounces else np.ones(E, bool)
        lost += np.where(stop, inside, 0.0)
        go = ~stop[beams["sample"][b]]
        nb_ = _take(beams, b[go])
        nb_.update({k: (None if v is None else v[go]) for k, v in hits.items() if k in ("o", "t0", "t1", "P0", "P1")})
        nb_.update(j=hits["seg"][go], shift=hits["shift"][go])
        beams = nb_
    cat = lambda k, dt: np.concatenate(out[k]).astype(dt) if out[k] else np.zeros(0, dt)  # noqa: E731
    return ExitRecords(
        sample=cat("sample", np.int64), pid=cat("pid", np.int64), 
        bounces=cat("nb", np.int64), phi_o=cat("phi", np.float64), weight=cat("w", np.float64),
        fresnel=(np.concatenate(out["f"]) if out["f"] else np.zeros((0, S, C))) if C else None,
        flux_ab=(np.concatenate(out["ab"]) if out["ab"] else np.zeros((0, 2))) if bounds else None,
        lost=np.maximum(lost, 0.0) / inc,
        bounds=(np.concatenate(out["bd"]) if out["bd"] else np.zeros((0, 2, 2))) if bounds else None,
        cos_path=None if not cos_path else _pad_paths(out["cp"], bounce),
    )


def _pad_paths(groups: list, bounces: int) -> np.ndarray:
    """One (n, B) array of the per-bounce cosine groups ``groups`` ((n_b, b) each), zero-padded to B columns."""
    B = max([c.shape[1] for c in groups], default=0)
    out = np.zeros((sum(c.shape[0] for c in groups), B))
    at = 0
    for c in groups:
        out[at:at + c.shape[0], :c.shape[1]] = c
        at += c.shape[0]
    return out


def path_fresnel(cos_path, bounces, weight, fresnel, cos_scales) -> np.ndarray:
    """Fresnel weights ``(n, S, C)`` of exits from their bounce cosines (``ExitRecords.cos_path``): the product
    over bounces of ``fresnel(cos(theta_o) |d . n|)`` (§4.2) times ``weight``, for the S ``cos_scales`` =
    cos(theta_o).  The same products, in the same order, as ``trace_exact(fresnel=..., cos_scales=...)``: bit for
    bit its ``fresnel`` records (the geometry is traced once, any metal re-weights it)."""
    cos_path = np.asarray(cos_path, np.float64)
    bounces = np.asarray(bounces)
    weight = np.asarray(weight, np.float64)
    cs = np.asarray(cos_scales, np.float64)
    n, S, C = bounces.size, cs.size, int(fresnel.channels)
    # longest paths first: the exits still bouncing at bounce k are a prefix (in-place products on views)
    order = np.argsort(-bounces, kind="stable")
    nb = bounces[order]
    f = np.ones((n, S, C))
    for k in range(int(nb[0]) if n else 0):
        m = int(np.searchsorted(-nb, -k, side="left"))      # exits with more than k bounces
        f[:m] *= fresnel(cos_path[order[:m], k][:, None] * cs[None, :])
    out = np.empty((n, S, C))
    out[order] = f * weight[order][:, None, None]
    return out


def _reflect(g: _Geometry, bm: dict, fresnel, cos_scales) -> dict:
    """Mirror-reflect beams sitting on segments, apply Fresnel, bring them to their travel frame.

    The unfolding map U (frame coordinates -> incident space) absorbs the period shift of the
    hit, the reflection and a frame flip, so that the beam's edge points stay fixed.
    """
    P = g.P
    o, j, k = bm["o"], bm["j"], bm["shift"]
    R, tr = bm["R"], bm["tr"]
    n = g.normal[o, j]
    if R is not None:   # the unfolding map (beam edges; ``trace_exact(bounds=False)``: not followed)
        # U <- U o translate(k, 0)
        tr = tr + k[:, None] * R[:, :, 0]
        # U <- U o reflect(line through A with unit normal n): p -> (I - 2 n n^T) p + 2 (A . n) n
        A = np.stack([g.X[o, j], g.H[o, j]], -1)
        Rf = np.eye(2)[None] - 2.0 * n[:, :, None] * n[:, None, :]
        tf = 2.0 * (A * n).sum(-1)[:, None] * n
        tr = np.matmul(R, tf[:, :, None])[:, :, 0] + tr
        R = np.matmul(R, Rf)
    dn = bm["dx"] * n[:, 0] + bm["dh"] * n[:, 1]  # < 0 for a hit
    dx = bm["dx"] - 2.0 * dn * n[:, 0]
    dh = bm["dh"] - 2.0 * dn * n[:, 1]
    inv = 1.0 / np.hypot(dx, dh)
    dx, dh = dx * inv, dh * inv
    f, cp = bm["f"], bm.get("cp")
    if f is not None or cp is not None:
        cos2d = np.clip(-dn, 0.0, 1.0)
    if f is not None:
        fz = fresnel(cos2d[:, None] * cos_scales[None, :])
        f = fz if f is True else f * fz     # 1 x F = F exactly: the first bounce multiplies nothing
    if cp is not None:
        cp = np.concatenate([cp, cos2d[:, None]], 1)
    j_orig = np.where(o == 0, j, P - 1 - j).astype(np.int64)
    code = (P + 1) * k.astype(np.int64)
    pid = bm["pid"] * _HASH_MUL + (j_orig + 1 + code)
    flip = dx < 0
    o = np.where(flip, 1 - o, o)
    j = np.where(flip, P - 1 - j, j)
    t0 = np.where(flip, 1.0 - bm["t0"], bm["t0"])
    t1 = np.where(flip, 1.0 - bm["t1"], bm["t1"])
    dx = np.abs(dx)
    # the levels s = dx h - dh x of the two edges (the points at t0, t1 on the segment; its ends gathered once)
    fj = o * g.X.shape[1] + j
    xa, ha = g.Xf[fj], g.Hf[fj]
    ex, eh = g.Xf[fj + 1] - xa, g.Hf[fj + 1] - ha
    l0 = dx * (ha + t0 * eh) - dh * (xa + t0 * ex)
    l1 = dx * (ha + t1 * eh) - dh * (xa + t1 * ex)
    out = dict(sample=bm["sample"], o=o, j=j, dx=dx, dh=dh, La=np.maximum(l0, l1), Lb=np.minimum(l0, l1),
               pid=pid, f=f, R=None, tr=None, cp=cp, Phi=None, Plo=None)
    if R is not None:
        R = R.copy()
        R[flip, :, 0] *= -1.0  # U <- U o mirror
        top0 = (l0 >= l1)[:, None]
        out.update(R=R, tr=tr, Phi=np.where(top0, bm["P0"], bm["P1"]), Plo=np.where(top0, bm["P1"], bm["P0"]))
    return out


def _visibility_batched(g: _Geometry, bm: dict):
    """``_visibility`` (or ``_visibility_scan`` for small profiles) on batches of beams (every beam is
    independent; the concatenated result equals one call on all beams): memory stays bounded."""
    n = bm["sample"].size
    vis = _visibility if hasattr(g, "hier") else _visibility_scan
    step = _VIS_BEAMS if vis is _visibility else max(1, _VIS_ELEMS // (-(-g.P // g.buckets.bucket) + g.G + 4))
    if n <= step:
        return vis(g, bm)
    hit_parts, esc_parts = [], []
    for a in range(0, n, step):  # a loop over batches (few)
        h, e = vis(g, {k: (None if v is None else v[a:a + step]) for k, v in bm.items()})
        h["beam"] = h["beam"] + a
        e["beam"] = e["beam"] + a
        hit_parts.append(h)
        esc_parts.append(e)
    cat = lambda parts: {k: None if parts[0][k] is None else np.concatenate([p[k] for p in parts])  # noqa: E731
                         for k in parts[0]}
    return cat(hit_parts), cat(esc_parts)


def _visibility(g: _Geometry, bm: dict):
    """Split each beam (leaving segment j towards +x in its frame) into sub-beams by first hit.

    The rays of level ``L`` in ``(Lcur, La]`` (``Lcur`` starts at the beam's lowest level ``Lb``) first
    hit the segment that ends at the next vertex ``v`` after ``j + 1`` whose level ``s(v)`` exceeds
    ``Lcur`` (a new running maximum): that segment takes the levels ``(Lcur, min(s(v), La)]``, then
    ``Lcur = s(v)``; what is left above the last maximum of one period escapes.  The next such vertex is
    found by descending the max-level hierarchy ``_Hierarchy``: ``O(log P)``
    steps per hit instead of a scan of the whole period, all beams advanced together.

    Returns ``hits`` (dict: beam, o, seg, shift, t0, t1, width, P0, P1 = unfolded edge points of
    the t0 / t1 edges) and ``escapes`` (dict: beam, width, Plo, Phi).
    """
    P, L = g.P, g.X.shape[1]
    hy = g.hier
    o, dx, dh, La, Lb = bm["o"], bm["dx"], bm["dh"], bm["La"], bm["Lb"]
    v0 = (bm["j"] + 1).astype(np.int64)
    edges = bm["Plo"] is not None   # beam edges followed (``trace_exact(bounds=True)``)
    # unfolded point of the vertex holding the running maximum (or the beam's edge)
    Pcur = bm["Plo"].copy() if edges else None
    hits, escapes = [], []
    # state of the beams still searching, compacted: beam, level, node, current maximum Lcur
    act = np.flatnonzero(Lb < La)  # a beam of zero width neither hits nor leaves
    k, i = hy.ascend(np.zeros(act.size, np.int64), v0[act])
    T = Lb[act].copy()
    tb, adx, adh, aLa, aend = hy.table(o[act], dh[act]), dx[act], dh[act], La[act], v0[act] + P
    off, top = hy.off, hy.top
    tail = _TAIL_ELEMS // max(P, 1) if g.scan_tail else 0
    while act.size:
        if act.size <= tail:  # a few beams with many vertices left: one scan instead of many tiny steps
            _finish_by_scan(g, bm, act, i << k, T, aend, Pcur, hits, escapes)
            break
        fin = (i << k) > aend
        flat = tb + off[k] + i
        b = adx * hy.hmax[flat] - adh * hy.xsel[flat]
        up = b > T  # the node may hold a vertex above the running maximum
        leaf = k == 0
        found = up & leaf & ~fin
        down = up & ~leaf & ~fin
        stop = fin.copy()
        if found.any():
            f = np.flatnonzero(found)
            ar, v, sB, Tf, Laf = act[f], i[f], b[f], T[f], aLa[f]
            of = o[ar]
            seg = v > v0[ar]  # the first vertex closes the beam's own segment: only a new maximum
            if seg.any():
                r, vr = ar[seg], v[seg]
                fA = of[seg] * L + vr - 1
                sA = dx[r] * g.Hf[fA] - dh[r] * g.Xf[fA]
                sb = sB[seg]
                lk, hk = Tf[seg], np.minimum(sb, Laf[seg])
                den = sb - sA
                t0 = np.clip((lk - sA) / den, 0.0, 1.0)
                t1 = np.clip((hk - sb) / den + 1.0, 0.0, 1.0)
                p_lo = p_hi = None
                if edges:
                    U = (bm["R"][r], bm["tr"][r])
                    fB = fA + 1
                    p_hi = np.where((sb < Laf[seg])[:, None], _apply(U, g.Xf[fB], g.Hf[fB]), bm["Phi"][r])
                    p_lo = Pcur[r]
                useg = vr - 1
                hits.append((r, o[r], useg % P, useg // P, t0, t1, hk - lk, p_lo, p_hi))
            done = sB >= Laf
            stop[f[done]] = True
            if edges:
                keep = ~done
                rk = ar[keep]
                fk = of[keep] * L + v[keep]
                Pcur[rk] = _apply((bm["R"][rk], bm["tr"][rk]), g.Xf[fk], g.Hf[fk])
            T[f] = sB
        # next node: down to the first child, or past this node (then up while it is a first child)
        ni = i + 1
        tz = np.minimum(((ni & -ni).astype(np.float64).view(np.int64) >> 52) - 1023, top - k)
        k = np.where(down, k - 1, k + tz)
        i = np.where(down, i << 1, ni >> tz)
        if stop.any():
            ge = act[fin]
            escapes.append((ge, La[ge] - T[fin], Pcur[ge] if edges else None))
            live = ~stop
            act, k, i, T = act[live], k[live], i[live], T[live]
            tb, adx, adh, aLa, aend = tb[live], adx[live], adh[live], aLa[live], aend[live]
    keys = ("beam", "o", "seg", "shift", "t0", "t1", "width", "P0", "P1")
    if hits:
        hit = {key: np.concatenate([h[q] for h in hits]) if (edges or q < 7) else None for q, key in enumerate(keys)}
        for key in ("beam", "o", "seg", "shift"):
            hit[key] = hit[key].astype(np.intp)
    else:
        hit = {key: np.zeros((0, 2) if key in ("P0", "P1") else 0, np.intp if q < 4 else np.float64)
               if (edges or q < 7) else None for q, key in enumerate(keys)}
    if escapes:
        esc = {"beam": np.concatenate([e[0] for e in escapes]).astype(np.intp),
               "width": np.concatenate([e[1] for e in escapes]),
               "Plo": np.concatenate([e[2] for e in escapes]).reshape(-1, 2) if edges else None}
    else:
        esc = {"beam": np.zeros(0, np.intp), "width": np.zeros(0), "Plo": np.zeros((0, 2)) if edges else None}
    esc["Phi"] = bm["Phi"][esc["beam"]] if edges else None
    return hit, esc


def _finish_by_scan(g: _Geometry, bm: dict, act, start, T, aend, Pcur, hits: list, escapes: list) -> None:
    """Finish ``_visibility`` for the beams ``act`` by scanning their vertices ``start .. aend`` at once.

    The same rule as the hierarchy's descent (a vertex whose level ``s = dx h - dh x`` exceeds the running
    maximum ``T`` ends the segment hit by the levels ``(T, min(s, La)]``), the same arithmetic, so the same
    hits and escapes (bit for bit), appended beam by beam.  For the last few beams of a batch, which can
    need hundreds of one-node steps (a beam split by a noisy far wall): one pass over ``len(act) * P`` levels."""
    P, L = g.P, g.X.shape[1]
    o, v0, La = bm["o"][act], bm["j"][act] + 1, bm["La"][act]
    dx, dh = bm["dx"][act], bm["dh"][act]
    n_left = np.maximum(aend - start + 1, 0)
    width = int(n_left.max(initial=0))
    edges = Pcur is not None
    if width == 0:  # past their period already: what is left above the running maximum escapes
        escapes.append((act, La - T, Pcur[act] if edges else None))
        return
    pos = start[:, None] + np.arange(width)[None, :]
    valid = pos <= aend[:, None]
    f = o[:, None] * L + np.minimum(pos, L - 1)
    s = dx[:, None] * g.Hf[f] - dh[:, None] * g.Xf[f]
    s[~valid] = -np.inf
    before = np.maximum.accumulate(np.concatenate([T[:, None], s[:, :-1]], 1), axis=1)  # running max before v
    new = s > before
    stop = new & (s >= La[:, None])  # the beam's top is reached: nothing is left to escape
    done = stop.any(1)
    last = np.where(done, np.argmax(stop, 1), width)
    new &= np.arange(width)[None, :] <= last[:, None]
    r, col = np.nonzero(new)  # row-major: each beam's new maxima in vertex order
    ar, v = act[r], pos[r, col]
    sB, Tf, Laf = s[r, col], before[r, col], La[r]
    if edges:
        U = (bm["R"][ar], bm["tr"][ar])
        fv = o[r] * L + v
        pts = _apply(U, g.Xf[fv], g.Hf[fv])  # the unfolded new maxima
        first = np.ones(r.size, bool)
        first[1:] = r[1:] != r[:-1]
        p_lo = np.where(first[:, None], Pcur[ar], np.roll(pts, 1, axis=0))  # the previous maximum (or the edge)
    seg = v > v0[r]  # the first vertex closes the beam's own segment: only a new maximum
    if seg.any():
        rs, vr, sb, lk, Las = r[seg], v[seg], sB[seg], Tf[seg], Laf[seg]
        ars = act[rs]
        fA = o[rs] * L + vr - 1
        sA = bm["dx"][ars] * g.Hf[fA] - bm["dh"][ars] * g.Xf[fA]
        hk = np.minimum(sb, Las)
        den = sb - sA
        t0 = np.clip((lk - sA) / den, 0.0, 1.0)
        t1 = np.clip((hk - sb) / den + 1.0, 0.0, 1.0)
        p_hi = np.where((sb < Las)[:, None], pts[seg], bm["Phi"][ars]) if edges else None
        useg = vr - 1
        hits.append((ars, bm["o"][ars], useg % P, useg // P, t0, t1, hk - lk, p_lo[seg] if edges else None, p_hi))
    esc = ~done
    if esc.any():
        tfin = np.maximum(T, s.max(1, initial=-np.inf))
        lastpt = None
        if edges:
            lastpt = Pcur[act].copy()
            has = new.any(1)
            if r.size:
                lastpt[has] = pts[np.flatnonzero(np.r_[r[1:] != r[:-1], True])]
            lastpt = lastpt[esc]
        ge = act[esc]
        escapes.append((ge, La[esc] - tfin[esc], lastpt))


def _visibility_scan(g: _Geometry, bm: dict):
    """``_visibility`` by scanning the period in windows of ``G`` vertices, skipping buckets of vertices
    whose bounding box stays below the beam (``_Buckets``): for small profiles (at most
    ``_HIERARCHY_MIN_SEGMENTS``), where it takes fewer numpy passes than the hierarchy's descent.

    Returns ``hits`` (dict: beam, o, seg, shift, t0, t1, width, P0, P1 = unfolded edge points of
    the t0 / t1 edges) and ``escapes`` (dict: beam, width, Plo, Phi).
    Arrays are laid out ``[window position, beam]`` so that numpy runs along beams.
    """
    P, L = g.P, g.X.shape[1]
    bk = g.buckets
    B, G = bk.bucket, bk.G
    o, dx, dh, La = bm["o"], bm["dx"], bm["dh"], bm["La"]
    n = o.size
    v0 = bm["j"] + 1
    end = v0 + P
    nbw = -(-P // B) + 2
    bidx = v0[:, None] // B + np.arange(nbw)[None, :]
    bstart = bidx * B
    fb = ((2 * o + (dh < 0)) * bk.nbuckets)[:, None] + bidx
    # upper bound of the level s over each bucket's bounding box ([beam, bucket]): dx hmax + max(-dh xmin, -dh xmax)
    dxc, dhc = dx[:, None], dh[:, None]
    bound = dxc * bk.bhmax_t[fb] + -dhc * bk.bxsel_t[fb]
    bound[bstart >= end[:, None]] = -np.inf
    bend = bstart + B
    Lcur = bm["Lb"].copy()
    edges = bm["Plo"] is not None   # beam edges followed (``trace_exact(bounds=True)``)
    Pcur = bm["Plo"].copy() if edges else None  # unfolded point of the edge at level Lcur
    pos = v0.copy()
    act = np.arange(n)
    hits, escapes = [], []
    k = np.arange(G + 1, dtype=np.int8 if G < 127 else np.int32)[:, None]  # small ints: cheap running argmax
    first_pass = True
    while act.size:
        if first_pass:
            valid = bound >= Lcur[:, None]  # every bucket ends after v0
            first_pass = False
        else:
            valid = (bend[act] > pos[act, None]) & (bound[act] >= Lcur[act, None])
        has = valid.any(1)
        gone = act[~has]
        escapes.append((gone, La[gone] - Lcur[gone], Pcur[gone] if edges else None))
        act = act[has]
        if not act.size:
            break
        first = np.argmax(valid[has], 1)
        u = np.maximum(pos[act], bstart[act, first])
        vi = u[None, :] + k
        oa = o[act]
        fi = oa[None, :] * L + vi
        dxa, dha, Lc, La_a = dx[act], dh[act], Lcur[act], La[act]
        xv, hv = g.Xf[fi], g.Hf[fi]
        sv = dxa * hv - dha * xv
        sv[vi > end[act][None, :]] = -np.inf
        Q = np.maximum.accumulate(sv, axis=0)
        if edges:
            am = np.maximum.accumulate(np.where(sv >= Q, k, 0), axis=0)  # row of the running-max vertex
        lo = np.maximum(Q[:-1], Lc)
        hi = np.minimum(Q[1:], La_a)
        keep = (hi - lo) > 0.0
        w, r = np.nonzero(keep)
        if r.size:
            sA, sB = sv[:-1][keep], sv[1:][keep]
            den = sB - sA
            lk, hk = lo[keep], hi[keep]
            t0 = np.clip((lk - sA) / den, 0.0, 1.0)
            t1 = np.clip((hk - sB) / den + 1.0, 0.0, 1.0)
            useg = u[r] + w
            ar = act[r]
            p_lo = p_hi = None
            if edges:
                U = (bm["R"][ar], bm["tr"][ar])
                # lower edge: the occluding vertex if it is above the current level, else the beam's own edge
                occ = Q[:-1][keep] > Lc[r]
                va = u[r] + am[:-1][keep]
                fa = o[ar] * L + va
                p_lo = np.where(occ[:, None], _apply(U, g.Xf[fa], g.Hf[fa]), Pcur[ar])
                # upper edge: the segment end vertex if it is below the beam top, else the beam's own edge
                capped = Q[1:][keep] < La_a[r]
                fb_ = o[ar] * L + useg + 1
                p_hi = np.where(capped[:, None], _apply(U, g.Xf[fb_], g.Hf[fb_]), bm["Phi"][ar])
            hits.append((ar, o[ar], useg % P, useg // P, t0, t1, hk - lk, p_lo, p_hi))
        raised = Q[-1] > Lc
        if raised.any():
            ra = act[raised]
            if edges:
                vr = u[raised] + am[-1][raised]
                fr = o[ra] * L + vr
                Pcur[ra] = _apply((bm["R"][ra], bm["tr"][ra]), g.Xf[fr], g.Hf[fr])
            Lcur[ra] = Q[-1][raised]
        pos[act] = u + G
        done = Lcur[act] >= La_a
        out_of_window = ~done & (pos[act] >= end[act])
        gone = act[out_of_window]
        escapes.append((gone, La[gone] - Lcur[gone], Pcur[gone] if edges else None))
        act = act[~done & ~out_of_window]
    keys = ("beam", "o", "seg", "shift", "t0", "t1", "width", "P0", "P1")
    if hits:
        hit = {key: np.concatenate([h[i] for h in hits]) if (edges or i < 7) else None for i, key in enumerate(keys)}
    else:
        hit = {key: np.zeros((0, 2) if key in ("P0", "P1") else 0, np.intp if i < 4 else np.float64)
               if (edges or i < 7) else None for i, key in enumerate(keys)}
    esc = {"beam": np.concatenate([e[0] for e in escapes]).astype(np.intp),
           "width": np.concatenate([e[1] for e in escapes]),
           "Plo": np.concatenate([e[2] for e in escapes]).reshape(-1, 2) if edges else None}
    esc["Phi"] = bm["Phi"][esc["beam"]] if edges else None
    return hit, esc


def _record(out: dict, bm: dict, esc: dict, bounce: int, inc: np.ndarray, phi_i: np.ndarray, lost: np.ndarray):
    """Store leaving beams; downward or vanishing ones are counted as lost."""
    b, width = esc["beam"], esc["width"]
    smp = bm["sample"][b]
    dh = bm["dh"][b]
    ok = (dh > 0.0) & (width > _MIN_WIDTH * inc[smp])
    np.add.at(lost, smp[~ok], np.maximum(width[~ok], 0.0))
    b, width, smp = b[ok], width[ok], smp[ok]
    dxo = np.where(bm["o"][b] == 0, bm["dx"][b], -bm["dx"][b])
    w = width / inc[smp]
    if esc["Phi"] is not None:
        _record_edges(out, esc, ok, phi_i[smp])
    out["sample"].append(smp)
    out["pid"].append(bm["pid"][b])
    out["nb"].append(np.full(b.size, bounce))
    out["phi"].append(np.arctan2(dxo, bm["dh"][b]))
    out["w"].append(w)
    if bm["f"] is not None:
        out["f"].append(bm["f"][b] * w[:, None, None])
    if bm.get("cp") is not None:
        out["cp"].append(bm["cp"][b])


def _record_edges(out: dict, esc: dict, ok, phi) -> None:
    """``flux_ab`` and ``bounds`` of the leaving beams ``esc[ok]`` (incident angles ``phi``)."""
    # width(phi) = |D x d_i(phi)| = |-D_x cos(phi) + D_h sin(phi)|, signed positive at the sample
    D = esc["Phi"][ok] - esc["Plo"][ok]
    a, bb = -D[:, 0], D[:, 1]
    sgn = np.where(a * np.cos(phi) + bb * np.sin(phi) >= 0.0, 1.0, -1.0)
    out["ab"].append(np.stack([a * sgn, bb * sgn], -1))
    # level coefficients (x, -h) of the two points; the lower one first (width = A cos + B sin > 0)
    c_lo = np.stack([esc["Phi"][ok][:, 0], -esc["Phi"][ok][:, 1]], -1)
    c_hi = np.stack([esc["Plo"][ok][:, 0], -esc["Plo"][ok][:, 1]], -1)
    pos = (sgn > 0)[:, None]
    out["bd"].append(np.stack([np.where(pos, c_lo, c_hi), np.where(pos, c_hi, c_lo)], 1))
