"""View slices of the scratch BRDF as the shader samples them (Raymond et al. 2016, §4.1-4.2 eq. 2, §5.1).

For a view (θo, φo) in the scratch frame (§4.1) light leaves on the cone θi = -θo, distributed in φi by
the slice ρs(θo, φo, ·) (eq. 1, 5).  The shader samples one φi per shading point from a *tabulated
slice*; this module computes those slices exactly and decides how many are needed.

φo: exact slices at adaptive nodes
----------------------------------
A slice is traced *at* its node φo (``beam.trace_exact`` with the beam incident from the view, by
reciprocity the distribution of where the viewed light comes from): a finite set of exit directions
with weights, binned into M φi bins as the flux fraction ``mass[s, b]`` (lossless, Σ_b mass = 1 - lost),
the centroid of the exits inside each bin (``centroid``, a fraction of the bin: the shader aims there, so
first moments do not depend on M) and whether the bin's light took an even number of bounces
(``even``).  Between two nodes the shader picks one of them stochastically (linear interpolation of the
weights) and moves each exit with the view: an odd-bounce exit moves as ``φi = -φo + c`` (mirror-like),
an even-bounce one as ``φi = φo + c`` (retro-like), which the shader reproduces by tilting its lobe for
the actual φo.  Interrupting paths (births, deaths, sharp caustics) are where that interpolation errs;
nodes are therefore refined adaptively (dyadic splits of a uniform start of ``base`` intervals, down to
a grid of ``G`` cells) wherever the moments of the interpolated slice (E[sin φi], E[cos φi],
E[sin² φi], and ρ0's channel albedos with Fresnel) miss the exact ones by more than ``tol_phi``.  The
64 uniform slices interpolated from the M x M table of earlier versions missed a V-groove's straight-down
exit by 0.03 in E[sin² φi] (a 2-bounce path whose weight vanishes like |φo| at φo = 0): the issue's
"along-scratch smear".

θo: Fresnel per bounce by a per-material basis (a generalised eq. 2)
-------------------------------------------------------------------
With Fresnel at every bounce (cosine ``cos θo |d.n|``, §4.2) a bin's reflectance depends on θo.  Eq. 2
writes it as ``ρ0 + (ρm - ρ0) R_γ(θo)``, R_γ = (2|θo|/π)^γ, γ fitted at θo = π/3 (three slices).  Measured
against exact traces that leaves up to 33 % (gold, V-groove 30) and 58 % (iron) of a slice's albedo at
some θo, 3-13 % at θo = 45-75 deg even with γ per colour channel (the earlier shader also averaged γ
over channels: blue 7.5 % off at the issue's view), and piecewise R_γ on five θo intervals still 4-10 %:
conductor Fresnel is not monotone in θo (iron's albedo dips from 0 to 60 deg, then rises to ρm), which a
monotone R_γ in [0, 1] cannot follow.  Here instead

    ρs(θo, φo, b) = ρm(φo, b) · Y_b(θo),    Y_b,c(θo) = Σ_k a_b,k,c B_k,c(x),  x = 2|θo|/π     (eq. 2, generalised)

with ``B_k,c`` a per-material, per-channel basis of K functions of θo (tabulated on NT points of x, linear
in between) learned by a mass-weighted SVD of the exact Y_b(θo) of every bin of every node, and ``a`` the
coefficients of each bin.  K is the smallest rank whose slices meet ``tol_theta`` (channel albedo
relative error and E_c[sin φi], E_c[cos φi] of every node at every θo sample); K = 2 is eq. 2's rank,
measured K = 3-5 meet 0.5 % for iron, gold, copper, aluminium on V-grooves, quartics, round and
measured-like profiles.  Lossless profiles need no basis (Y = 1).

Units: radians; ``mass`` is a fraction of the incident flux; angles φ in [-π/2, π/2].
"""
from __future__ import annotations

import contextlib
import sys
import threading
from dataclasses import dataclass, field

import numpy as np

from ..tables import cache as _cache
from .beam import ExitRecords, path_fresnel, trace_exact
from .profiles import Profile

__all__ = ["ViewSlices", "view_slices", "exact_slice", "expected_moments", "exact_moments", "VERSION",
           "aim_interval", "interval_moments", "theta_coordinate", "theta_of_coordinate"]

VERSION = "1"
_EDGE = 1e-6          # nodes at +-pi/2 are traced at +-(pi/2 - _EDGE)
MAX_BOUNCES = 64
MIN_ENERGY = 1e-7


@dataclass(frozen=True, eq=False)
class ViewSlices:
    """Exact view slices at adaptive φo nodes (see the module docstring).

    ``phi [S]`` node angles (radians, ascending, ``phi[0] = -π/2``, ``phi[-1] = π/2``, each a multiple of
    π/G from -π/2); ``cell_interval [G]`` the node interval holding each of the G uniform cells of φo;
    ``mass [S, M]`` lossless flux fraction per φi bin; ``centroid [S, M]`` mean exit inside the bin (fraction
    of the bin, 0.5 where empty); ``even [S, M]`` even-bounce-dominated bins; ``coef [S, M, K, C]`` and
    ``basis [K, NT, C]`` the θo dependence (None when lossless); ``errors`` measured residuals.
    """

    phi: np.ndarray
    cell_interval: np.ndarray
    mass: np.ndarray
    centroid: np.ndarray
    even: np.ndarray
    coef: np.ndarray | None = None
    basis: np.ndarray | None = None
    errors: dict = field(default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return int(self.phi.size)

    @property
    def bins(self) -> int:
        return int(self.mass.shape[1])

    @property
    def grid(self) -> int:
        return int(self.cell_interval.size)

    @property
    def rank(self) -> int:
        return 0 if self.basis is None else int(self.basis.shape[0])

    @property
    def channels(self) -> int:
        return 1 if self.basis is None else int(self.basis.shape[2])

    @property
    def y_group(self) -> int:
        """φi bins sharing one set of θo coefficients (M / coef.shape[1])."""
        return 1 if self.coef is None else self.bins // int(self.coef.shape[1])

    def y(self, theta_o) -> np.ndarray:
        """Y [S, M, C] at ``theta_o`` (radians) as the shader evaluates it (linear in x between basis samples,
        bin b reads the coefficients of its group b // y_group), clamped at 0; ones [S, M, 1] when lossless."""
        if self.basis is None:
            return np.ones(self.mass.shape + (1,))
        NT = self.basis.shape[1]
        x = float(theta_coordinate(theta_o)) * (NT - 1)
        i = min(int(np.floor(x)), NT - 2)
        f = x - i
        B = (1.0 - f) * self.basis[:, i] + f * self.basis[:, i + 1]                 # [K, C]
        Yg = np.maximum(np.einsum("sgkc,kc->sgc", self.coef, B), 0.0)
        return np.repeat(Yg, self.y_group, axis=1)

    def arrays(self) -> dict:
        out = {"phi": self.phi, "cell_interval": self.cell_interval.astype(np.float64), "mass": self.mass,
               "centroid": self.centroid, "even": self.even.astype(np.float64)}
        if self.basis is not None:
            out.update(coef=self.coef, basis=self.basis)
        out["errors"] = np.array([self.errors.get("phi", 0.0), self.errors.get("theta", 0.0),
                                  self.errors.get("lost", 0.0)])
        return out

    @classmethod
    def from_arrays(cls, a: dict) -> "ViewSlices":
        e = np.asarray(a["errors"], float).ravel()
        return cls(np.asarray(a["phi"], np.float64), np.asarray(a["cell_interval"]).astype(np.int64),
                   np.asarray(a["mass"], np.float64), np.asarray(a["centroid"], np.float64),
                   np.asarray(a["even"]) > 0.5,
                   None if "coef" not in a else np.asarray(a["coef"], np.float64),
                   None if "basis" not in a else np.asarray(a["basis"], np.float64),
                   {"phi": float(e[0]), "theta": float(e[1]), "lost": float(e[2])})


def theta_coordinate(theta_o):
    """The basis coordinate v = 1 - sqrt(cos θo) in [0, 1] (θo in radians): uniform samples of v crowd
    toward grazing, where Fresnel changes fastest (F(cos θo |d.n|) drops from 1 within cos θo ~ 0.1)."""
    c = np.cos(np.clip(np.abs(np.asarray(theta_o, np.float64)), 0.0, 0.5 * np.pi))
    return 1.0 - np.sqrt(np.maximum(c, 0.0))


def theta_of_coordinate(v):
    """Inverse of ``theta_coordinate``: θo = acos((1 - v)²) (radians)."""
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    return np.arccos((1.0 - v) ** 2)


# ------------------------------------------------------------------------------------------ exact traces
#: threads one trace is split over (interleaved directions: they are independent, ``beam.trace_exact`` traces
#: each on its own, bit for bit the same in any batch; numpy releases the GIL in its array passes); 1: one
#: call.  Off by default: on the shared 2-core machine (load 19) the split took 8 % more wall and CPU
#: (``python -m bench live_update``); fewer than ``_MIN_SPLIT`` directions are always traced in one call.
TRACE_WORKERS = 1
_MIN_SPLIT = 16
_POOL: list = []


#: exact traces are kept per profile as *geometry* (``beam.trace_exact(cos_path=True)``: exit angle, weight,
#: bounces and the cosine of every bounce of each view direction's exits) and weighted by Fresnel afterwards
#: (``beam.path_fresnel``, bit for bit the weights of a trace with that model): a direction traced once is
#: never traced again for this profile, whatever the metal, the θo samples or the table quality (a metal edit,
#: the full tables after the preview).  Bounded: at most ``GEOMETRY_BYTES`` over all profiles (least recently
#: used profiles dropped first); 0 turns the store off.
GEOMETRY_BYTES = 96 << 20
_GEOMETRY: dict = {}          # (vertices hash, MAX_BOUNCES, MIN_ENERGY) -> {phi: per-direction records}
_GEOMETRY_LOCK = threading.Lock()
#: what the store keeps of an exit (the view slices read no beam edges: ``trace_exact(bounds=False)``)
_FIELDS = ("pid", "bounces", "phi_o", "weight", "cos_path")


def _geometry_key(verts) -> tuple:
    import hashlib

    return hashlib.sha1(np.ascontiguousarray(verts, np.float64).tobytes()).hexdigest(), MAX_BOUNCES, MIN_ENERGY


def _store_bytes(store: dict) -> int:
    return sum(v[6] for v in store.values())


def _geometry_records(verts, phi, fresnel=None, cos_theta=()):
    """Per-direction records of ``phi`` [n]: (``_FIELDS`` arrays, lost, bytes[, Fresnel weights]) from the store;
    the directions not stored yet are traced (``TRACE_WORKERS`` threads) with ``fresnel`` at ``cos_theta`` and
    come back with the trace's own Fresnel weights as an 8th entry (the store keeps their geometry only).  When
    every direction is new (and ``phi`` ascending), the trace's ``ExitRecords`` themselves are returned."""
    key = _geometry_key(verts)
    with _GEOMETRY_LOCK:
        store = _GEOMETRY.pop(key, None)
        store = {} if store is None else store
        _GEOMETRY[key] = store                         # most recently used last
        have = {p: store.get(p) for p in set(phi.tolist())}
    new = np.array(sorted(p for p, r in have.items() if r is None), np.float64)
    traced = None
    if new.size:
        traced = r = _trace_directions(verts, new, fresnel, cos_theta, True)
        whole = new.size == phi.size and np.array_equal(new, phi)   # all new, in order: the trace is the answer
        extra = () if (r.fresnel is None or whole) else (r.fresnel,)
        # grouped by direction once (views into one sorted copy per field)
        order = np.argsort(r.sample, kind="stable")
        cuts = np.searchsorted(r.sample[order], np.arange(new.size + 1)).tolist()
        cols = [getattr(r, f)[order] for f in _FIELDS[:4]] + [x[order] for x in extra]
        row_bytes = sum(c[:1].nbytes for c in cols[:4])
        cp = r.cos_path          # (padded to the longest path: gathered per direction, to its own longest)
        for k in range(new.size):
            a, b = cuts[k], cuts[k + 1]
            geo = tuple(c[a:b] for c in cols[:4]) + (cp[order[a:b], :int(cols[1][a:b].max(initial=0))],)
            have[float(new[k])] = (geo + (float(r.lost[k]), row_bytes * (b - a) + geo[4].nbytes + 200)
                                   + tuple(c[a:b] for c in cols[4:]))
        if GEOMETRY_BYTES > 0:
            with _GEOMETRY_LOCK:
                store.update((float(p), have[float(p)][:7]) for p in new)
                total = sum(_store_bytes(v) for v in _GEOMETRY.values())
                while total > GEOMETRY_BYTES and _GEOMETRY:
                    oldest = next(iter(_GEOMETRY))
                    total -= _store_bytes(_GEOMETRY.pop(oldest))
        if whole:
            return traced
    return [have[p] for p in phi.tolist()]


def _trace_directions(verts, phi, fresnel, cos_theta, cos_path=False):
    def run(p, F=fresnel, cs=cos_theta, cp=cos_path):
        return trace_exact(verts, p, F if len(cs) else None, tuple(cs),
                           max_bounces=MAX_BOUNCES, min_energy=MIN_ENERGY, cos_path=cp, bounds=False)

    if TRACE_HELPER and phi.ndim == 1 and phi.size >= _HELPER_MIN:
        got = _helper_trace(verts, phi, fresnel, cos_theta, cos_path, run)
        if got is not None:
            return got
    n = int(TRACE_WORKERS)
    if n <= 1 or phi.ndim != 1 or phi.size < _MIN_SPLIT:
        return run(phi)
    if not _POOL or _POOL[0][0] != n:
        import concurrent.futures

        _POOL[:] = [(n, concurrent.futures.ThreadPoolExecutor(n, thread_name_prefix="scratch_trace"))]
    idx = [np.arange(k, phi.size, n) for k in range(n)]     # interleaved: grazing and normal views in each part
    return _merge(list(_POOL[0][1].map(run, [phi[i] for i in idx])), idx, phi.size)


# ----------------------------------------------------------------------------- a helper process (2 cores)
#: Trace half of each batch of new view directions in a helper process (a plain Python running ``beam.py``
#: alone, ``start_trace_helper``): the directions are independent and the tracer is many small numpy passes
#: that hold the GIL, so threads do not scale (``TRACE_WORKERS``) but two processes do.  The helper traces
#: geometry (``cos_path``); its directions' Fresnel weights are computed here (``beam.path_fresnel``, bit for
#: bit the traced ones).  Off by default (a script or a render farm gets no extra process); live edits turn it
#: on when ``scratch_addon.live.TRACE_HELPER`` is set (off: it did not pay on the shared test machine).  Any failure
#: of the helper falls back to tracing here.
TRACE_HELPER = False
#: start the helper in its own session (POSIX): with the kernel's autogroup scheduling every process of a
#: session shares one CPU share, so under load a helper in Blender's session only takes CPU from Blender
HELPER_OWN_SESSION = True
_HELPER_MIN = 24              # fewer new directions: traced here (the round trip costs ~1 ms)
_HELPER: dict = {"proc": None}
_HELPER_LOCK = threading.Lock()
_HELPER_FIELDS = ("sample", "pid", "bounces", "phi_o", "weight", "lost", "cos_path")
_HELPER_CODE = r"""
import importlib.util, pickle, sys
import numpy as np
spec = importlib.util.spec_from_file_location("_scratch_beam_helper", sys.argv[1])
beam = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = beam
spec.loader.exec_module(beam)
inp, out = sys.stdin.buffer, sys.stdout.buffer
pickle.dump("ready", out)
out.flush()
while True:
    try:
        verts, phi, kw, path = pickle.load(inp)
    except EOFError:
        break
    try:
        r = beam.trace_exact(verts, phi, None, (), cos_path=True, bounds=False, **kw)
        res = {f: getattr(r, f) for f in sys.argv[2].split(",")}
        cp = res.pop("cos_path")
        res["cos_flat"] = cp[np.arange(cp.shape[1])[None, :] < r.bounces[:, None]]   # no padding
        res["cos_width"] = cp.shape[1]
        with open(path, "wb") as f:      # a file, not the pipe: no chunked hand-over between busy processes
            pickle.dump(res, f, protocol=pickle.HIGHEST_PROTOCOL)
        res = "done"
    except Exception as exc:
        res = repr(exc)
    pickle.dump(res, out)
    out.flush()
"""


def _python() -> str | None:
    """The Python interpreter to run the helper with (Blender's bundled one; None if ``sys.executable`` is not a
    Python, e.g. Blender itself in old versions)."""
    import os

    exe = sys.executable or ""
    return exe if os.path.basename(exe).lower().startswith("python") else None


def start_trace_helper() -> bool:
    """Start the helper process now (it imports numpy in the background, ~0.2 s); True if it runs."""
    import pickle  # noqa: F401
    import subprocess

    with _HELPER_LOCK:
        proc = _HELPER["proc"]
        if proc is not None and proc.poll() is None:
            return True
        exe = _python()
        if exe is None:
            return False
        from . import beam as _beam

        try:
            if not _HELPER.get("atexit"):         # the helper ends with its stdin; its temp file goes here
                import atexit

                atexit.register(stop_trace_helper)
                _HELPER["atexit"] = True
            _HELPER["proc"] = subprocess.Popen([exe, "-c", _HELPER_CODE, _beam.__file__, ",".join(_HELPER_FIELDS)],
                                               stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                               stderr=subprocess.DEVNULL, start_new_session=HELPER_OWN_SESSION)
            _HELPER["ready"] = False
        except OSError:
            _HELPER["proc"] = None
            return False
    return True


def stop_trace_helper() -> None:
    """End the helper process (if any)."""
    with _HELPER_LOCK:
        proc, _HELPER["proc"] = _HELPER["proc"], None
    if proc is not None:
        try:
            proc.stdin.close()
            proc.wait(timeout=2)
        except Exception:  # noqa: BLE001 - it is ours: make sure it ends
            proc.kill()
    path = _HELPER.pop("file", None)
    if path is not None:
        import os

        with contextlib.suppress(OSError):
            os.remove(path)


#: seconds the helper may take beyond our own half before it is given up (and ended)
HELPER_TIMEOUT_S = 60.0


def _wait_readable(stream, timeout: float) -> bool:
    """True once ``stream`` has data (POSIX ``select``; elsewhere True: a blocking read)."""
    try:
        import select

        return bool(select.select([stream], [], [], timeout)[0])
    except (ImportError, OSError, ValueError):
        return True


def _helper_trace(verts, phi, fresnel, cos_theta, cos_path, run):
    """Half of ``phi`` (interleaved) traced by the helper, the other half here at the same time; None when the
    helper is busy (another thread), not running or failed (the caller traces everything here)."""
    import pickle

    if not _HELPER_LOCK.acquire(blocking=False):
        return None
    try:
        proc = _HELPER["proc"]
        if proc is None or proc.poll() is not None:
            _HELPER["proc"] = None          # ended: forgotten (``start_trace_helper`` starts a new one)
            return None
        idx = [np.arange(0, phi.size, 2), np.arange(1, phi.size, 2)]
        path = _HELPER.get("file")
        if path is None:
            import os
            import tempfile

            fd, path = tempfile.mkstemp(prefix="scratch_trace_", suffix=".pkl")
            os.close(fd)
            _HELPER["file"] = path
        try:
            pickle.dump((np.asarray(verts), phi[idx[1]], {"max_bounces": MAX_BOUNCES, "min_energy": MIN_ENERGY}, path),
                        proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            proc.stdin.flush()
        except (OSError, ValueError):
            _HELPER["proc"] = None
            return None
        mine = run(phi[idx[0]], cp=True)
        try:
            if not _wait_readable(proc.stdout, HELPER_TIMEOUT_S):
                raise TimeoutError("trace helper")
            if not _HELPER.get("ready"):
                if pickle.load(proc.stdout) != "ready":
                    raise ValueError("helper")
                _HELPER["ready"] = True
            if pickle.load(proc.stdout) != "done":
                raise ValueError("helper")
            with open(path, "rb") as f:
                res = pickle.load(f)
        except Exception:  # noqa: BLE001 - a dead or confused helper: stop it, trace here
            _HELPER["proc"] = None
            proc.kill()
            return None
        flat, width = res.pop("cos_flat"), int(res.pop("cos_width"))
        cp = np.zeros((res["bounces"].size, width))
        cp[np.arange(width)[None, :] < res["bounces"][:, None]] = flat
        theirs = ExitRecords(fresnel=None, cos_path=cp, flux_ab=None, bounds=None, **res)
        if mine.fresnel is not None:
            theirs.fresnel = path_fresnel(theirs.cos_path, theirs.bounces, theirs.weight, fresnel,
                                          np.asarray(cos_theta, np.float64))
        out = _merge([mine, theirs], idx, phi.size)
        if not cos_path:
            out.cos_path = None
        return out
    finally:
        _HELPER_LOCK.release()


def _trace(profile: Profile, phi, fresnel=None, cos_theta=()):
    """Exit records of view directions ``phi`` (``beam.ExitRecords``; Fresnel weights at ``cos_theta`` when
    ``fresnel`` is given), from the per-profile geometry store (``GEOMETRY_BYTES``): the records of each direction
    are those of ``beam.trace_exact`` bit for bit, grouped by direction (in its order within a direction), without
    the beam edges (``flux_ab``, ``bounds`` None: ``trace_exact(bounds=False)``, which the slices do not read)."""
    phi = np.clip(np.asarray(phi, np.float64), -0.5 * np.pi + _EDGE, 0.5 * np.pi - _EDGE)
    verts = profile.periodic_vertices()
    if GEOMETRY_BYTES <= 0 or phi.ndim != 1 or phi.size == 0 or not np.all(np.isfinite(phi)):
        return _trace_directions(verts, phi, fresnel, cos_theta)
    F = fresnel if (fresnel is not None and len(cos_theta)) else None
    cs = np.asarray(cos_theta, np.float64) if F is not None else ()
    recs = _geometry_records(verts, phi, F, cs)
    if isinstance(recs, ExitRecords):      # every direction traced just now
        return recs
    sample = np.repeat(np.arange(phi.size), [r[0].size for r in recs]).astype(np.int64)
    pid, nb, phi_o, w = (np.concatenate([r[q] for r in recs]) for q in range(4))
    cp = _pad_cat([r[4] for r in recs])                                  # bounce cosines, zero-padded
    fw = None
    if F is not None:           # stored directions: weighted now (traced ones carry the trace's own weights)
        old = [r for r in recs if len(r) == 7]
        done = iter(np.split(path_fresnel(_pad_cat([r[4] for r in old]), np.concatenate([r[1] for r in old]),
                                          np.concatenate([r[3] for r in old]), F, cs),
                             np.cumsum([r[0].size for r in old])[:-1])) if old else iter(())
        fw = np.concatenate([r[7] if len(r) > 7 else next(done) for r in recs])
    return ExitRecords(sample=sample, pid=pid, bounces=nb, phi_o=phi_o, weight=w, fresnel=fw, flux_ab=None,
                       lost=np.array([r[5] for r in recs]), bounds=None, cos_path=cp)


def _merge(parts, idx, E):
    """One ``ExitRecords`` of traces of the directions ``phi[idx[k]]`` (``parts[k]``), samples renumbered."""
    cat = lambda k: np.concatenate([getattr(r, k) for r in parts])  # noqa: E731
    lost = np.zeros(E)
    for r, i in zip(parts, idx):
        lost[i] = r.lost
    return type(parts[0])(
        sample=np.concatenate([i[r.sample] for r, i in zip(parts, idx)]), pid=cat("pid"), bounces=cat("bounces"),
        phi_o=cat("phi_o"), weight=cat("weight"), fresnel=None if parts[0].fresnel is None else cat("fresnel"),
        flux_ab=None if parts[0].flux_ab is None else cat("flux_ab"), lost=lost,
        bounds=None if parts[0].bounds is None else cat("bounds"),
        cos_path=None if parts[0].cos_path is None else _pad_cat([r.cos_path for r in parts]))


def _pad_cat(arrays) -> np.ndarray:
    """Row-wise concatenation of 2D arrays of different widths, zero-padded to the widest."""
    out = np.zeros((sum(a.shape[0] for a in arrays), max((a.shape[1] for a in arrays), default=0)))
    at = 0
    for a in arrays:
        out[at:at + a.shape[0], :a.shape[1]] = a
        at += a.shape[0]
    return out


def exact_slice(profile: Profile, phi_o, fresnel=None, theta_o=()):
    """The exact view slice at ``phi_o`` [n] (radians): exit records of ``beam.trace_exact`` with the beam
    incident from the view (reciprocity), Fresnel per bounce at the 3D cosine for each ``theta_o``.
    Returns ``(sample, phi_i, weight, bounces, fresnel_weight [n_exits, T, C] or None)``."""
    th = np.atleast_1d(np.asarray(theta_o, np.float64))
    r = _trace(profile, np.atleast_1d(phi_o), fresnel, np.cos(th) if fresnel is not None else ())
    return r.sample, r.phi_o, r.weight, r.bounces, r.fresnel


def exact_moments(profile: Profile, phi_o, fresnel=None, theta_o=0.0) -> np.ndarray:
    """Exact reflected energy and exit moments of views (θo, φo): ``[n, C, 4]`` with per channel the albedo A
    and A E[sin φi], A E[cos φi], A E[sin² φi] (C = 1 without Fresnel)."""
    phi_o = np.atleast_1d(np.asarray(phi_o, np.float64))
    smp, ph, w, _, fw = exact_slice(profile, phi_o, fresnel, [theta_o])
    W = w[:, None] if fw is None else fw[:, 0, :]
    f = np.stack([np.ones_like(ph), np.sin(ph), np.cos(ph), np.sin(ph) ** 2], -1)       # [n, 4]
    out = np.zeros((phi_o.size, W.shape[1], 4))
    for c in range(W.shape[1]):
        for q in range(4):
            out[:, c, q] = np.bincount(smp, W[:, c] * f[:, q], minlength=phi_o.size)
    return out


def _bin_rows(smp, ph, w, bounces, n, M, fw=None):
    """Rows at traced directions: mass [n, M], centroid [n, M], even [n, M] (and Fresnel mass [n, M, T, C])."""
    e = -0.5 * np.pi + np.arange(M + 1) * (np.pi / M)
    ib = np.clip(np.searchsorted(e, ph, side="right") - 1, 0, M - 1)
    key = smp * M + ib
    mass = np.bincount(key, w, minlength=n * M).reshape(n, M)
    pos = np.bincount(key, w * (ph - e[ib]) / (np.pi / M), minlength=n * M).reshape(n, M)
    odd = np.bincount(key, w * (bounces % 2), minlength=n * M).reshape(n, M)
    with np.errstate(divide="ignore", invalid="ignore"):
        cen = np.where(mass > 0, pos / np.where(mass > 0, mass, 1.0), 0.5)
    rows = (mass, np.clip(cen, 0.0, 1.0), odd < 0.5 * mass)
    if fw is None:
        return rows
    T, C = fw.shape[1:]
    # one bincount over (bin, θo sample, channel): each sum adds the same exits in the same order as one
    # bincount per (t, c) did (the same numbers, bit for bit), in one pass instead of T C
    TC = T * C
    fm = np.bincount((key[:, None] * TC + np.arange(TC)[None, :]).ravel(), np.reshape(fw, (-1,)),
                     minlength=n * M * TC)
    return rows + (fm.reshape(n, M, T, C),)


# ------------------------------------------------------------------------------------ the shader's model
def aim_interval(M: int, centroid, even, phi_node, phi_o):
    """Where the shader's lobe of each bin sends light for view ``phi_o`` from the slice of ``phi_node``:
    the aim is uniform in ``[c - h, c + h]`` of the bin (c its centroid, h = min(c, 1 - c)), then moved by
    ``phi_node - phi_o`` (odd bounces, mirror-like) or ``phi_o - phi_node`` (even, retro-like).  Returns
    (lo, hi) [..., M] in radians (not clipped to the horizon)."""
    e = -0.5 * np.pi + np.arange(M) * (np.pi / M)
    h = np.minimum(centroid, 1.0 - centroid)
    shift = np.where(even, phi_o - phi_node, phi_node - phi_o)
    lo = e + (centroid - h) * (np.pi / M) + shift
    hi = e + (centroid + h) * (np.pi / M) + shift
    return lo, hi


def interval_moments(lo, hi):
    """Mean of (1, sin, cos, sin²) of φ uniform in [lo, hi] ∩ [-π/2, π/2] times the fraction kept: [..., 4].

    With m = (a + b) / 2, h = (b - a) / 2 of the kept interval [a, b] and sinc h = sin h / h: E[sin] =
    sin m sinc h, E[cos] = cos m sinc h, E[sin²] = (1 - cos 2m sinc h cos h) / 2 (sum-to-product forms of
    the interval's integrals: four sines and cosines per element, exact as h -> 0)."""
    lo, hi = np.broadcast_arrays(np.asarray(lo, float), np.asarray(hi, float))
    a, b = np.clip(lo, -0.5 * np.pi, 0.5 * np.pi), np.clip(hi, -0.5 * np.pi, 0.5 * np.pi)
    d = hi - lo
    point = d < 1e-9
    w = np.maximum(b - a, 0.0)
    keep = np.where(point, (np.abs(lo) <= 0.5 * np.pi).astype(float), w / np.where(point, 1.0, d))
    m = 0.5 * (a + b)
    h = 0.5 * w
    sm, cm, ch = np.sin(m), np.cos(m), np.cos(h)
    sinc = np.where(h > 1e-12, np.sin(h) / np.where(h > 1e-12, h, 1.0), 1.0)
    ks = keep * sinc
    return np.stack([keep, ks * sm, ks * cm, keep * 0.5 * (1.0 - (cm * cm - sm * sm) * sinc * ch)], -1)


def _row_moments(mass, centroid, even, phi_node, phi_o, sparse: bool = False):
    """Moments [..., 4] the shader renders from rows (mass [..., M] or [..., M, C]) used at view phi_o.
    ``sparse``: the bins' interval moments only where the row has mass (mass [..., M, 0] > 0), zeros elsewhere,
    which the mass multiplies by 0 either way: the same sums but for the sign of an exact zero (the refinement's
    errors, absolute values, do not see it)."""
    M = centroid.shape[-1]
    lo, hi = aim_interval(M, centroid, even, phi_node, phi_o)
    if sparse:
        nz = (mass if mass.ndim == centroid.ndim else mass[..., 0]) > 0
        im = np.zeros(lo.shape + (4,))
        im[nz] = interval_moments(lo[nz], hi[nz])                                     # [..., M, 4]
    else:
        im = interval_moments(lo, hi)                                                 # [..., M, 4]
    if mass.ndim == centroid.ndim:
        return np.matmul(mass[..., None, :], im)[..., 0, :]
    return np.matmul(np.swapaxes(mass, -1, -2), im)


def _interval_of(vs_phi, cell_interval, phi_o):
    G = cell_interval.size
    g = np.clip(np.floor((np.asarray(phi_o, float) + 0.5 * np.pi) / np.pi * G).astype(np.int64), 0, G - 1)
    k = cell_interval[g]
    pa, pb = vs_phi[k], vs_phi[k + 1]
    f = np.clip((phi_o - pa) / (pb - pa), 0.0, 1.0)
    return k, f


def expected_moments(vs: ViewSlices, phi_o, theta_o=0.0) -> np.ndarray:
    """What the shader renders on average for views (θo, φo) (numpy twin of the table-lobe shader):
    ``[n, C, 4]`` per channel A, A E[sin φi], A E[cos φi], A E[sin² φi] (GGX lobe losses not included)."""
    phi_o = np.atleast_1d(np.asarray(phi_o, np.float64))
    k, f = _interval_of(vs.phi, vs.cell_interval, phi_o)
    Y = vs.y(theta_o)                                                                   # [S, M, C]
    out = np.zeros((phi_o.size, Y.shape[-1], 4))
    for node, p in ((k, 1.0 - f), (k + 1, f)):
        rows = vs.mass[node][..., None] * Y[node]                                       # [n, M, C]
        out += p[:, None, None] * _row_moments(rows, vs.centroid[node], vs.even[node], vs.phi[node][:, None],
                                               phi_o[:, None])
    return out


# ---------------------------------------------------------------------------------------- construction
def _moment_error(model, exact) -> np.ndarray:
    """Per view: max over channels of |ΔE[sin]|, |ΔE[cos]|, |ΔE[sin²]| (moments of the lossless geometry)
    and the relative albedo error of each channel; inputs [n, C, 4]."""
    d = np.abs(model[..., 1:] - exact[..., 1:]).max(-1)
    a = np.abs(model[..., 0] - exact[..., 0]) / np.maximum(exact[..., 0], 1e-6)
    return np.maximum(d, a).max(-1)


#: Views up to this far from the normal across the scratch (φo) get the full tolerance; beyond, the
#: tolerance grows like cos(GRAZING) / cos(φo) (their pixels shrink like cos(φo)).
GRAZING = np.radians(80.0)


def _relax(phi):
    """Tolerance factor of a view at ``phi`` (radians): 1 up to ``GRAZING``, cos(GRAZING) / cos(phi) beyond."""
    return np.maximum(1.0, np.cos(GRAZING) / np.maximum(np.cos(phi), 1e-3))


def _per_sample(smp, n: int, *arrays) -> list:
    """Exit records grouped by their slice: for each k < n, the tuple of ``arrays`` rows with ``smp == k``
    (in their original order)."""
    order = np.argsort(smp, kind="stable")
    cuts = np.searchsorted(smp[order], np.arange(n + 1))
    return [tuple(a[order[cuts[k]:cuts[k + 1]]] for a in arrays) for k in range(n)]


def _phi_nodes(profile, M, base, levels, tol, fresnel, max_nodes, theta=None, records=None):
    """Adaptive φo nodes: indices on the grid of G = base 2^levels cells and their rows (see module doc).

    ``theta`` (with Fresnel): the θo samples of the θo basis, whose first is 0; the start nodes (which every
    refinement keeps) are traced at all of them at once and their exit records go to ``records`` (grid index
    -> (φi, weight, bounces, Fresnel weight [n, T, C])), so ``_theta_basis`` traces only the added nodes."""
    G = base << levels
    ang = lambda i: -0.5 * np.pi + np.asarray(i) * (np.pi / G)  # noqa: E731
    cache = {}  # grid index -> (rows, exact moments)

    def traced(idx, keep=False):
        new = sorted(set(int(i) for i in idx) - set(cache))
        if not new:
            return
        ph = ang(np.array(new))
        keep = keep and fresnel is not None and theta is not None and records is not None
        # slice 0 of the θo samples is θo = 0: the same Fresnel weights as a trace at [0.0] alone, bit for bit
        smp, po, w, nb, fw = exact_slice(profile, ph, fresnel, theta if keep else [0.0] if fresnel is not None else ())
        if keep:
            records.update(zip(new, _per_sample(smp, len(new), po, w, nb, fw)))
            fw = fw[:, :1]
        mass, cen, even = _bin_rows(smp, po, w, nb, len(new), M)[:3]
        f = np.stack([np.ones_like(po), np.sin(po), np.cos(po), np.sin(po) ** 2], -1)
        W = [w] + ([] if fw is None else [fw[:, 0, c] for c in range(fw.shape[2])])
        mom = np.zeros((len(new), len(W), 4))
        fm = None
        if fw is not None:
            key = smp * M + np.clip(np.searchsorted(-0.5 * np.pi + np.arange(M + 1) * (np.pi / M), po, side="right") - 1,
                                    0, M - 1)
            fm = np.stack([np.bincount(key, fw[:, 0, c], minlength=len(new) * M).reshape(len(new), M)
                           for c in range(fw.shape[2])], -1)
        for c, wc in enumerate(W):
            for q in range(4):
                mom[:, c, q] = np.bincount(smp, wc * f[:, q], minlength=len(new))
        for j, i in enumerate(new):
            rows = mass[j][:, None] if fm is None else np.concatenate([mass[j][:, None], fm[j]], -1)
            cache[i] = (rows, cen[j], even[j], mom[j])

    nodes = list(range(0, G + 1, 1 << levels))
    traced(nodes, keep=True)
    worst = 0.0
    while True:
        tests, owner = [], []
        for a, b in zip(nodes[:-1], nodes[1:]):
            if b - a < 2:
                continue
            pts = [(a + b) // 2] + ([(3 * a + b) // 4, (a + 3 * b) // 4] if b - a >= 4 else [])
            tests += pts
            owner += [(a, b)] * len(pts)
        if not tests:
            break
        traced(tests)
        # every test view of this round at once: the interpolated slice's moments against the exact ones
        t_idx = np.array(tests)
        ends = np.array(owner)                                                       # [n, 2] (a, b)
        pt = ang(t_idx)
        f = (pt - ang(ends[:, 0])) / (ang(ends[:, 1]) - ang(ends[:, 0]))
        model = 0.0
        for node, p in ((ends[:, 0], 1.0 - f), (ends[:, 1], f)):
            rows = np.stack([cache[int(i)][0] for i in node])                        # [n, M, 1 + C]
            cen = np.stack([cache[int(i)][1] for i in node])
            ev = np.stack([cache[int(i)][2] for i in node])
            model = model + p[:, None, None] * _row_moments(rows, cen, ev, ang(node)[:, None], pt[:, None], True)
        exact = np.stack([cache[int(t)][3] for t in t_idx])                          # [n, 1 + C, 4]
        errs = _moment_error(model, exact) / _relax(pt)
        worst = float(errs.max())
        bad = {}
        for err, (a, b) in zip(errs.tolist(), owner):
            if err > tol:
                bad[(a, b)] = max(err, bad.get((a, b), 0.0))
        room = max_nodes - len(nodes)
        if not bad or room <= 0:
            break
        split = sorted(bad, key=bad.get, reverse=True)[:room]  # the worst intervals first
        nodes = sorted(set(nodes) | {(a + b) // 2 for a, b in split})
    return np.array(nodes), cache, worst


def _theta_basis(profile, fresnel, phi, M, NT, tol, kmax, group=1, known=None):
    """Basis [K, NT, C] and coefficients [S, M / group, K, C] of Y(θo) = ρs / ρm per group of ``group``
    φi bins (mass-weighted SVD).  ``known`` [S]: exit records of nodes traced already at these θo samples
    (``_phi_nodes``' ``records``; None: trace that node)."""
    th = theta_of_coordinate(np.linspace(0.0, 1.0, NT))
    known = [None] * phi.size if known is None else list(known)
    todo = [s for s in range(phi.size) if known[s] is None]
    if todo:
        t_smp, *t_rec = exact_slice(profile, phi[todo], fresnel, th)
        for s, rec in zip(todo, _per_sample(t_smp, len(todo), *t_rec)):
            known[s] = rec
    smp = np.concatenate([np.full(r[0].size, s, np.int64) for s, r in enumerate(known)])
    po, w, nb, fw = (np.concatenate([r[q] for r in known]) for q in range(4))
    mass_b, _, _, fm_b = _bin_rows(smp, po, w, nb, phi.size, M, fw)                   # fm [S, M, T, C]
    S, C = phi.size, fm_b.shape[-1]
    Mg = M // group
    mass = mass_b.reshape(S, Mg, group).sum(-1)
    fm = fm_b.reshape(S, Mg, group, NT, C).sum(2)
    with np.errstate(divide="ignore", invalid="ignore"):
        Y = np.where(mass[..., None, None] > 0, fm / np.where(mass > 0, mass, 1.0)[..., None, None], 0.0)
    live = mass > 0
    sw = np.sqrt(mass[live])                                                           # importance weights
    # exact slice moments per node, theta sample and channel (for the rank choice)
    e = -0.5 * np.pi + (np.arange(M) + 0.5) * (np.pi / M)
    basis_f = np.stack([np.ones(M), np.sin(e), np.cos(e)], 0)                         # [3, M]
    # (a batched matmul over the bins: tensordot's sums, without its transposed copy of fm_b)
    exact = np.matmul(basis_f, fm_b.reshape(S, M, -1)).reshape(S, 3, NT, C).transpose(0, 2, 3, 1)   # [S, T, C, 3]
    # the model's moments: Y is constant over a group of bins, so sum mass x moment function per group first
    gq = np.matmul(mass_b.reshape(S, Mg, group)[:, :, None, :],
                   basis_f.reshape(3, Mg, group).transpose(1, 2, 0)[None])[:, :, 0, :]    # [S, Mg, 3]
    best = None
    Ys = [Y[..., c][live] for c in range(C)]                                              # [L, T] per channel
    Vts = [np.linalg.svd(sw[:, None] * Yc, full_matrices=False)[2] for Yc in Ys]       # one SVD per channel
    for K in range(1, kmax + 1):
        B = np.zeros((K, NT, C))
        coef = np.zeros((S, Mg, K, C))
        for c in range(C):
            Yc = Ys[c]
            Bk = Vts[c][:K]
            B[:, :, c] = Bk
            coef[live, :, c] = Yc @ Bk.T
        Yk = np.maximum(np.matmul(coef.transpose(3, 0, 1, 2), B.transpose(2, 0, 1)[:, None]), 0.0)   # [C, S, Mg, T]
        model = np.matmul(Yk.transpose(0, 1, 3, 2), gq[None]).transpose(1, 2, 0, 3)                # [S, T, C, 3]
        a = np.abs(model[..., 0] - exact[..., 0]) / np.maximum(exact[..., 0], 1e-6)
        d = np.abs(model[..., 1:] - exact[..., 1:]).max(-1) / np.maximum(exact[..., 0], 1e-6)
        err = float((np.maximum(a, d).max(axis=(1, 2)) / _relax(phi)).max())
        best = (B, coef, err)
        if err <= tol:
            break
    return best


def view_slices(profile: Profile, resolution: int = 256, fresnel=None, *, base: int = 64, levels: int = 4,
                tol_phi: float = 3e-3, tol_theta: float = 2e-3, max_nodes: int = 385, theta_samples: int = 32,
                max_rank: int = 8, y_group: int = 8, cache: bool = False) -> ViewSlices:
    """Exact view slices of ``profile`` at adaptive φo nodes, with the θo basis of Fresnel (module doc).

    ``resolution`` M φi bins; ``base`` uniform start intervals, refined dyadically up to ``levels`` times
    (grid G = base 2^levels) where the interpolated moments miss by more than ``tol_phi``, at most
    ``max_nodes`` nodes; ``theta_samples`` NT samples of x = 2|θo|/π for the basis, whose rank (at most
    ``max_rank``) is the smallest meeting ``tol_theta``.  ``cache``: through ``precompute.tables.cache``.
    """
    if not isinstance(profile, Profile):
        raise ValueError(f"profile: expected a precompute.scratch.profiles.Profile, got {type(profile).__name__}")
    for name, v, lo, hi in (("resolution", resolution, 8, 4096), ("base", base, 2, 1024), ("levels", levels, 0, 8),
                            ("max_nodes", max_nodes, 3, 8193), ("theta_samples", theta_samples, 3, 1025),
                            ("max_rank", max_rank, 1, 16), ("y_group", y_group, 1, 64)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
            raise ValueError(f"{name}: expected an integer in [{lo}, {hi}], got {v!r}")
    if resolution % y_group:
        raise ValueError(f"y_group: expected a divisor of resolution ({resolution}), got {y_group}")
    if base % 2:
        raise ValueError(f"base: expected an even number of intervals (a node at φo = 0), got {base}")
    for name, v in (("tol_phi", tol_phi), ("tol_theta", tol_theta)):
        if not (isinstance(v, (int, float)) and np.isfinite(v) and 0 < v < 1):
            raise ValueError(f"{name}: expected a number in (0, 1), got {v!r}")
    if fresnel is not None and not (callable(fresnel) and getattr(fresnel, "channels", 0) in (1, 3)):
        raise ValueError("fresnel: expected None or a precompute.fresnel model (callable with .channels of 1 or 3)")
    M = int(resolution)

    def compute():
        th = theta_of_coordinate(np.linspace(0.0, 1.0, int(theta_samples)))
        records = {}   # exit records of the start nodes at every θo sample (reused by the θo basis)
        idx, traced, worst = _phi_nodes(profile, M, int(base), int(levels), float(tol_phi), fresnel, int(max_nodes),
                                        th, records)
        G = int(base) << int(levels)
        phi = -0.5 * np.pi + idx * (np.pi / G)
        rows = [traced[int(i)] for i in idx]
        mass = np.stack([r[0][:, 0] for r in rows])
        cen = np.stack([r[1] for r in rows])
        even = np.stack([r[2] for r in rows])
        cells = np.searchsorted(idx, np.arange(G), side="right") - 1
        out = {"phi": phi, "cell_interval": cells.astype(np.float64), "mass": mass, "centroid": cen,
               "even": even.astype(np.float64)}
        err_theta = 0.0
        if fresnel is not None:
            B, coef, err_theta = _theta_basis(profile, fresnel, phi, M, int(theta_samples), float(tol_theta),
                                              int(max_rank), int(y_group), [records.get(int(i)) for i in idx])
            out.update(coef=coef, basis=B)
        lost = float(np.max(1.0 - mass.sum(1)))
        out["errors"] = np.array([worst, err_theta, max(lost, 0.0)])
        return out

    inputs = {"profile": profile, "resolution": M, "fresnel": fresnel, "base": int(base), "levels": int(levels),
              "tol_phi": float(tol_phi), "tol_theta": float(tol_theta), "max_nodes": int(max_nodes),
              "theta_samples": int(theta_samples), "max_rank": int(max_rank), "y_group": int(y_group)}
    version = VERSION + "-" + _cache.code_version(sys.modules[__name__], sys.modules[trace_exact.__module__])
    arrays = _cache.cached_arrays("scratch_view_slices", version, inputs, compute, enabled=bool(cache))
    return ViewSlices.from_arrays(arrays)
