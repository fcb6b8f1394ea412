"""The beam tracer's visibility step (Raymond et al. 2016, §4.1) against brute force.

``beam._visibility`` finds, for every reflected beam, the next vertices whose ray level ``s = dx h - dh x``
is a new running maximum by descending a max-level hierarchy (``beam._Hierarchy``).  The oracle here scans
every vertex of one period for every beam (a per-beam Python loop over ``np.maximum.accumulate``), with the
same rules: segment ``(v - 1, v)`` takes the levels ``(Q_{v-1}, min(s_v, La)]`` where ``Q`` is the running
maximum from the beam's lowest level, and what stays above the period's maximum escapes.  Both are run
inside ``trace_exact`` (every bounce of every incident direction), and the whole exit records must agree.
"""
import numpy as np
import pytest

from scratch_materials.precompute.scratch import beam, fresnel, profiles


def brute_visibility(g, bm):
    P, L = g.P, g.X.shape[1]
    hits = {k: [] for k in ("beam", "o", "seg", "shift", "t0", "t1", "width", "P0", "P1")}
    esc = {"beam": [], "width": [], "Plo": []}
    for b in range(bm["o"].size):  # every beam, every vertex of one period
        o, v0 = int(bm["o"][b]), int(bm["j"][b]) + 1
        dx, dh, Lb, La = bm["dx"][b], bm["dh"][b], bm["Lb"][b], bm["La"][b]
        if not Lb < La:
            continue
        U = (bm["R"][b:b + 1], bm["tr"][b:b + 1])
        point = lambda v: beam._apply(U, g.X[o, v:v + 1], g.H[o, v:v + 1])[0]  # noqa: E731
        idx = np.arange(v0, v0 + P + 1)
        s = dx * g.H[o, idx] - dh * g.X[o, idx]
        Q, occ = Lb, bm["Plo"][b]
        done = False
        for m, v in enumerate(idx):
            if s[m] > Q:
                if m > 0:  # segment (v - 1, v) is hit by the levels (Q, min(s_v, La)]
                    hi = min(s[m], La)
                    den = s[m] - s[m - 1]
                    hits["beam"].append(b), hits["o"].append(o), hits["seg"].append((v - 1) % P)
                    hits["shift"].append((v - 1) // P), hits["width"].append(hi - Q)
                    hits["t0"].append(np.clip((Q - s[m - 1]) / den, 0.0, 1.0))
                    hits["t1"].append(np.clip((hi - s[m]) / den + 1.0, 0.0, 1.0))
                    hits["P0"].append(occ), hits["P1"].append(point(v) if s[m] < La else bm["Phi"][b])
                Q, occ = s[m], point(v)
                if Q >= La:
                    done = True
                    break
        if not done:
            esc["beam"].append(b), esc["width"].append(La - Q), esc["Plo"].append(occ)
    hit = {k: np.array(v, np.intp if k in ("beam", "o", "seg", "shift") else np.float64).reshape(
        (-1, 2) if k in ("P0", "P1") else (-1,)) for k, v in hits.items()}
    out = {"beam": np.array(esc["beam"], np.intp), "width": np.array(esc["width"], np.float64),
           "Plo": np.array(esc["Plo"], np.float64).reshape(-1, 2)}
    out["Phi"] = bm["Phi"][out["beam"]]
    return hit, out


def _canon(rec):
    key = np.lexsort((rec.phi_o, rec.weight, rec.pid, rec.sample))
    out = {k: getattr(rec, k)[key] for k in ("sample", "pid", "bounces", "phi_o", "weight", "flux_ab", "bounds")}
    if rec.fresnel is not None:
        out["fresnel"] = rec.fresnel[key]
    out["lost"] = rec.lost
    return out


def _noisy(seed, n, depth, noise, step=0.0):
    rng = np.random.default_rng(seed)
    x = np.sort(rng.uniform(0.0, 1.0, n))
    x[0], x[-1] = 0.0, 1.0
    h = -depth * np.sin(np.pi * x) ** 2 + noise * rng.standard_normal(n) + step * (x > 0.5)
    return profiles.tabulated(x, h)


PROFILES = {
    "noisy-shallow": _noisy(1, 200, 0.3, 0.01),
    "noisy-deep": _noisy(2, 120, 3.0, 0.05),  # many bounces
    "noisy-steps": _noisy(3, 90, 1.0, 0.02, step=0.4),  # a cliff inside and a vertical closing step
    "cliffs": profiles.tabulated([0, 0.3, 0.3001, 0.6, 0.6001, 1.0], [0, -1.0, -0.2, -0.9, -2.5, -0.1]),
    "v-groove-45": profiles.v_groove(45),  # exact ties: horizontal rays graze the two rims
    "v-groove-10": profiles.v_groove(10),  # deep: dozens of bounces
    "flat": profiles.flat(),
    "quartic": profiles.quartic(0.5, segments=64),
}


def _method_case(name, method, monkeypatch):
    """Profile ``name``'s periodic vertices, 26 incidence angles and a coloured conductor, with visibility method
    ``method`` forced ("scan", "hierarchy", "hierarchy+tail": the last searching beams finish by one scan from 3
    beams on, "tail-only": by one scan from the start); returns (verts, phi, F, scan_tail)."""
    verts = PROFILES[name].periodic_vertices()
    phi = np.concatenate([np.linspace(-1.5707, 1.5707, 23), [0.0, 0.3, -0.7853981633974483]])
    F = fresnel.conductor([0.2, 0.9, 1.1], [3.0, 2.5, 2.0])
    monkeypatch.setattr(beam, "_HIERARCHY_MIN_SEGMENTS", 10**9 if method == "scan" else 0)
    tail = "tail" in method
    if tail:
        monkeypatch.setattr(beam, "_TAIL_ELEMS", 3 * (verts.shape[0] - 1) if method == "hierarchy+tail" else 10**9)
    return verts, phi, F, tail


@pytest.mark.parametrize("method", ["hierarchy", "scan", "hierarchy+tail", "tail-only"])
@pytest.mark.parametrize("name", sorted(PROFILES))
def test_visibility_equals_brute_force(name, method, monkeypatch):
    """Both visibility methods (the hierarchy for profiles of more than ``_HIERARCHY_MIN_SEGMENTS``
    segments, the bucket scan for smaller ones; each forced here on every profile) give brute force's records;
    so does the hierarchy whose last searching beams finish by one scan (``scan_tail``: from 3 beams on, or
    from the start)."""
    verts, phi, F, tail = _method_case(name, method, monkeypatch)
    fast = _canon(beam.trace_exact(verts, phi, F, (1.0, 0.5), scan_tail=tail))
    monkeypatch.setattr(beam, "_HIERARCHY_MIN_SEGMENTS", 0)
    monkeypatch.setattr(beam, "_visibility", brute_visibility)
    ref = _canon(beam.trace_exact(verts, phi, F, (1.0, 0.5)))
    assert ref["sample"].size > phi.size
    for key in ref:
        assert fast[key].shape == ref[key].shape, key
        np.testing.assert_allclose(fast[key], ref[key], rtol=0, atol=1e-12, err_msg=key)


def test_small_batches_equal_one_batch(monkeypatch):
    """The beams of a bounce are split into batches (bounded memory): the split changes nothing."""
    verts = PROFILES["noisy-deep"].periodic_vertices()
    phi = np.linspace(-1.5, 1.5, 15)
    monkeypatch.setattr(beam, "_HIERARCHY_MIN_SEGMENTS", 0)
    a = _canon(beam.trace_exact(verts, phi))
    monkeypatch.setattr(beam, "_VIS_BEAMS", 7)
    b = _canon(beam.trace_exact(verts, phi))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])


@pytest.mark.parametrize("method", ["hierarchy", "scan", "hierarchy+tail"])
@pytest.mark.parametrize("name", sorted(PROFILES))
def test_trace_without_beam_edges_equals_the_full_trace(name, method, monkeypatch):
    """``trace_exact(bounds=False)`` (what the view slices trace: no unfolding maps, no edge points) gives the
    full trace's records bit for bit, in the same order, on every visibility method and in small batches;
    only ``flux_ab`` and ``bounds`` are left out."""
    verts, phi, F, tail = _method_case(name, method, monkeypatch)
    for batch in (None, 5):
        if batch:   # (batches change the records' order: compared with a full trace in the same batches)
            monkeypatch.setattr(beam, "_VIS_BEAMS", batch)
            monkeypatch.setattr(beam, "_VIS_ELEMS", batch * 8)
        full = beam.trace_exact(verts, phi, F, (1.0, 0.5), scan_tail=tail, cos_path=True)
        lean = beam.trace_exact(verts, phi, F, (1.0, 0.5), scan_tail=tail, cos_path=True, bounds=False)
        assert lean.flux_ab is None and lean.bounds is None
        for key in ("sample", "pid", "bounces", "phi_o", "weight", "fresnel", "lost", "cos_path"):
            np.testing.assert_array_equal(getattr(lean, key), getattr(full, key), err_msg=key)
    assert full.sample.size > phi.size


def test_polylines_that_are_not_height_fields_are_refused():
    """The tracer relies on x increasing (profiles.tabulated enforces it); a hand-made polyline that folds
    back gets a ValueError instead of a wrong table."""
    verts = np.array([[-0.5, 0.0], [0.1, -0.3], [-0.1, -0.5], [0.5, 0.0]])
    with pytest.raises(ValueError, match="verts"):
        beam.trace_exact(verts, np.array([0.1]))
