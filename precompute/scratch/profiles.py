"""Scratch profiles: the 1D cross-sections that are extruded along the scratch (Raymond et al. 2016, §4, §5.3).

A profile is a polyline in the (v, n) plane of the scratch frame: ``x`` across the scratch,
``h`` the height along the surface normal.  Lengths are in units of the scratch width, so
(§4.3) a profile describes every scratch of the same shape and aspect ratio:

- ``x`` is strictly increasing and spans exactly ``[-0.5, 0.5]``;
- ``h <= 0`` and ``max(h) == 0``: the base surface is at height 0 and the scratch is dug into it.

Bulges (§5.3): a tabulated profile whose points stick out above the base surface is shifted so
that its *highest* point is the base height, and the simulation treats the profile as periodic
(period 1): light that leaves one copy may hit the bulge of the next one.  If the two ends have
different heights, the period is closed by a vertical step at ``x = 0.5``.

Analytic families (sampled into polylines with ``segments`` pieces, placed uniformly in
turning angle + arc length so that curved parts get more vertices; symmetric families are
sampled on one half and mirrored, so they are bit-exactly symmetric):

- ``quartic(depth)``: ``h(x) = -depth (1 - (2x)^2)^2``; ``depth`` = depth/width ratio (the paper's
  "symmetric quartic", Fig. 5 top row).
- ``v_groove(half_angle_deg)``: two straight walls meeting at ``x = 0``; the half-angle is the
  angle between each wall and the *vertical* (surface normal), so depth = ``0.5 / tan(half_angle)``
  (90 deg is a flat surface, small angles are deep narrow grooves).
- ``circular(depth)``: circular arc through the two rims with sagitta ``depth``
  (``depth = 0.5`` is a semicircular "U" groove).
- ``tabulated(x, height)`` / ``from_file(path)``: measured profiles (any units; they are rescaled
  to unit width, keeping the aspect ratio).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Profile", "quartic", "v_groove", "circular", "flat", "tabulated", "from_file", "simplify", "MAX_POINTS"]

_DENSE = 4096  # dense samples per half profile when placing analytic vertices
_MIN_SPACING = 1e-9  # smallest x step of a tabulated profile, relative to its width
#: most points of a tabulated profile (a profilometer trace of a scratch has thousands; the simulation
#: simplifies it, see ``simplify``)
MAX_POINTS = 1 << 20


@dataclass(frozen=True, eq=False)
class Profile:
    """An immutable scratch profile polyline (units of the scratch width).

    ``x``: strictly increasing, from -0.5 to 0.5.  ``h``: heights, ``max(h) == 0``.
    ``is_symmetric``: ``h(-x) == h(x)`` vertex by vertex (used to halve the simulation).
    """

    x: np.ndarray
    h: np.ndarray
    name: str = "tabulated"
    params: dict = field(default_factory=dict)
    is_symmetric: bool = False

    def __post_init__(self):
        for a in (self.x, self.h):
            a.setflags(write=False)

    @property
    def segments(self) -> int:
        """Number of polyline segments of one period (without the closing step)."""
        return int(self.x.size - 1)

    @property
    def depth(self) -> float:
        """Depth of the scratch (highest minus lowest point), in scratch widths."""
        return float(-self.h.min())

    def cache_key(self) -> dict:
        """Inputs identifying the simulated geometry, for ``precompute.tables.cache``."""
        return {"name": self.name, "params": dict(self.params), "x": self.x, "h": self.h}

    def periodic_vertices(self) -> np.ndarray:
        """Vertices ``V_0 .. V_P`` of one period of the periodic polyline, shape ``(P + 1, 2)``.

        ``V_P = V_0 + (1, 0)``; a vertical step is appended when the two ends differ in height.
        """
        v = np.stack([self.x, self.h], axis=1)
        if self.h[-1] != self.h[0]:
            v = np.vstack([v, [[self.x[0] + 1.0, self.h[0]]]])
        return v

    def __repr__(self) -> str:
        return f"Profile({self.name}, segments={self.segments}, depth={self.depth:.4g}, symmetric={self.is_symmetric})"


def _check_segments(segments) -> int:
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) or not (4 <= segments <= 100_000):
        raise ValueError(f"segments: expected an integer in [4, 100000], got {segments!r}")
    return int(segments)


def _check_range(value, name: str, low: float, high: float, *, low_open: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {value!r}") from None
    ok = np.isfinite(v) and (v > low if low_open else v >= low) and v <= high
    if not ok:
        raise ValueError(f"{name}: allowed range is {'(' if low_open else '['}{low}, {high}], got {value!r}")
    return v


def _mirror_half(xh: np.ndarray, hh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half profile on x in [0, 0.5] (starting at x = 0) -> symmetric full profile."""
    x = np.concatenate([-xh[:0:-1], xh])
    h = np.concatenate([hh[:0:-1], hh])
    return x, h


def _place(t: np.ndarray, x: np.ndarray, h: np.ndarray, n: int) -> np.ndarray:
    """Parameters ``t`` of ``n + 1`` vertices spaced uniformly in turning angle + arc length."""
    dx, dh = np.diff(x), np.diff(h)
    ang = np.arctan2(dh, dx)
    ds = np.hypot(dx, dh)
    dturn = np.abs(np.diff(ang, prepend=ang[0]))
    total_turn, total_len = dturn.sum(), ds.sum()
    # half of the vertices follow the turning angle, half the arc length
    w = 0.5 * dturn / max(total_turn, 1e-300) + 0.5 * ds / total_len if total_turn > 0 else ds / total_len
    cum = np.concatenate([[0.0], np.cumsum(w)])
    cum /= cum[-1]
    return np.interp(np.linspace(0.0, 1.0, n + 1), cum, t)


def _analytic(name: str, params: dict, half, segments: int) -> Profile:
    """Symmetric analytic profile from ``half(t) -> (x, h)`` on t in [0, 1] (x from 0 to 0.5)."""
    segments = _check_segments(segments)
    if segments % 2:
        segments += 1
    t = np.linspace(0.0, 1.0, _DENSE + 1)
    xd, hd = half(t)
    tv = _place(t, xd, hd, segments // 2)
    xh, hh = half(tv)
    xh[0], xh[-1] = 0.0, 0.5
    x, h = _mirror_half(xh, hh)
    h = h - h.max()
    h[h == 0.0] = 0.0  # no negative zeros
    return Profile(x, h, name, dict(params, segments=segments), True)


def quartic(depth: float = 0.2, *, segments: int = 256) -> Profile:
    """Symmetric quartic ``h(x) = -depth (1 - (2x)^2)^2`` on x in [-1/2, 1/2] (Raymond et al. 2016, Fig. 5).

    ``depth``: depth/width ratio in [0, 5] (0 is flat).  ``segments``: polyline pieces (>= 4).
    """
    d = _check_range(depth, "depth", 0.0, 5.0)
    return _analytic("quartic", {"depth": d}, lambda t: (0.5 * t, -d * (1.0 - t * t) ** 2), segments)


def v_groove(half_angle_deg: float = 45.0) -> Profile:
    """V-shaped groove; ``half_angle_deg`` in [2, 90] is the angle between each wall and the vertical.

    Depth = ``0.5 / tan(half_angle)``; exactly two segments.  Below 2 deg light needs more
    bounces than the simulation follows (see ``scratch_brdf.MAX_BOUNCES``).
    """
    a = _check_range(half_angle_deg, "half_angle_deg", 2.0, 90.0)
    depth = 0.0 if a == 90.0 else 0.5 / np.tan(np.radians(a))
    x = np.array([-0.5, 0.0, 0.5])
    h = np.array([0.0, -depth, 0.0])
    return Profile(x, h, "v_groove", {"half_angle_deg": a}, True)


#: shallowest circular groove: below 1e-6 of its width an arc is flat to double precision in every
#: quantity the simulation uses (its radius exceeds 1e5 widths)
CIRCULAR_MIN_DEPTH = 1e-6


def circular(depth: float = 0.5, *, segments: int = 256) -> Profile:
    """Circular-arc ("round"/"U") groove through the rims with sagitta ``depth`` in [1e-6, 0.5].

    ``depth = 0.5`` is a semicircle.  Vertices are placed like the other families (turning angle +
    arc length).  With the half-angle ``psi_max = 2 atan(2 depth)`` of the arc and radius
    ``r = (1/4 + depth^2) / (2 depth)``, a point at angle psi is ``x = r sin(psi)``,
    ``h = 2 r sin^2(psi / 2) - depth`` (the sagitta form, without the cancellation of ``r cos(psi) - (r - d)``).
    """
    d = _check_range(depth, "depth", CIRCULAR_MIN_DEPTH, 0.5)
    r = (0.25 + d * d) / (2.0 * d)
    psi_max = 2.0 * np.arctan(2.0 * d)

    def half(t):
        psi = psi_max * t
        return r * np.sin(psi), 2.0 * r * np.sin(0.5 * psi) ** 2 - d

    return _analytic("circular", {"depth": d}, half, segments)


def flat(*, segments: int = 4) -> Profile:
    """A flat (unscratched) profile: a pure mirror, for tests."""
    segments = _check_segments(segments)
    x = np.linspace(-0.5, 0.5, segments + 1)
    return Profile(x, np.zeros_like(x), "flat", {"segments": segments}, True)


def tabulated(x, height, *, name: str = "tabulated") -> Profile:
    """A measured profile from samples ``(x, height)`` (any length unit, same for both).

    The profile is rescaled to unit width (aspect ratio kept: heights are divided by the width
    too), shifted so its highest point is the base height (bulges, §5.3), and treated as periodic.
    Raises ``ValueError`` for fewer than 2 points, NaN/inf, zero width or non-increasing ``x``.
    """
    try:
        x = np.array(x, dtype=np.float64)
        h = np.array(height, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"x, height: expected numeric 1D arrays ({exc})") from None
    if x.ndim != 1 or h.ndim != 1:
        raise ValueError(f"x, height: expected 1D arrays, got shapes {x.shape} and {h.shape}")
    if x.size != h.size:
        raise ValueError(f"x, height: lengths differ ({x.size} vs {h.size})")
    if x.size < 2:
        raise ValueError(f"x, height: need at least 2 points, got {x.size}")
    if x.size > MAX_POINTS:
        raise ValueError(f"x, height: at most {MAX_POINTS} points, got {x.size} (resample the trace)")
    for arr, nm in ((x, "x"), (h, "height")):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise ValueError(f"{nm}: contains NaN or inf (first at index {bad[0]})")
    width = x[-1] - x[0]
    if width == 0.0 or np.ptp(x) == 0.0:
        raise ValueError("x: zero width (first and last x are equal)")
    d = np.diff(x)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        raise ValueError(f"x: must be strictly increasing (non-monotonic at index {bad[0] + 1}: "
                         f"{x[bad[0]]!r} -> {x[bad[0] + 1]!r})")
    gap = np.flatnonzero(d < _MIN_SPACING * width)
    if gap.size:
        raise ValueError(f"x: points {gap[0]} and {gap[0] + 1} are closer than {_MIN_SPACING:g} of the profile width "
                         f"({x[gap[0]]!r} -> {x[gap[0] + 1]!r}); merge or drop such near-duplicate samples")
    xs = (x - x[0]) / width - 0.5
    xs[0], xs[-1] = -0.5, 0.5
    hs = (h - h.max()) / width
    if not np.all(np.isfinite(hs)) or np.ptp(hs) > 1e6:
        raise ValueError("height: range too large for the width (depth/width above 1e6)")
    hs[hs == 0.0] = 0.0
    tol = 1e-12
    sym = bool(np.all(np.abs(xs + xs[::-1]) <= tol) and np.all(np.abs(hs - hs[::-1]) <= tol * max(1.0, np.ptp(hs))))
    if sym:  # make the detected symmetry exact, so the simulation may rely on it
        n = xs.size
        xs = 0.5 * (xs - xs[::-1])
        hs = 0.5 * (hs + hs[::-1])
        if n % 2:
            xs[n // 2] = 0.0
    return Profile(xs, hs, str(name), {}, sym)


def from_file(path: str | os.PathLike, *, delimiter: str | None = None, name: str | None = None) -> Profile:
    """Load a tabulated profile from a CSV/text file with columns ``x, height``.

    Lines starting with ``#`` are comments; a non-numeric header line is skipped; columns
    may be separated by commas, semicolons, tabs or spaces.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"path: no such file {path!r}")
    rows = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for lineno, line in enumerate(f, 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split(delimiter) if delimiter else line.replace(",", " ").replace(";", " ").split()
            try:
                vals = [float(p) for p in parts if p.strip() != ""]
            except ValueError:
                if not rows:
                    continue  # header
                raise ValueError(f"{path}:{lineno}: not numeric: {line!r}") from None
            if len(vals) < 2:
                raise ValueError(f"{path}:{lineno}: expected two columns (x, height), got {line!r}")
            rows.append(vals[:2])
    if not rows:
        raise ValueError(f"{path}: no (x, height) rows found")
    a = np.array(rows)
    return tabulated(a[:, 0], a[:, 1], name=name or os.path.splitext(os.path.basename(path))[0])


def simplify(profile: Profile, max_exit_error: float) -> Profile:
    """The profile with runs of nearly collinear segments replaced by their chords (error-controlled).

    A run of segments is replaced by the chord of its end points when every segment's direction is
    within ``max_exit_error / 2`` (radians) of the chord's: a beam reflected once by any part of the
    run then leaves within ``max_exit_error`` of where it left before (a mirror turns by twice the
    normal's change), and every removed vertex lies within ``max_exit_error / 4`` of the run length
    from the chord.  Douglas-Peucker splitting (at the vertex farthest from the chord) until every
    run passes.  The end points, the highest point (the base height of §5.3) and, for a symmetric
    profile, the centre are kept, and symmetric profiles are simplified on one half and mirrored, so
    symmetry stays exact.  ``max_exit_error = 0`` returns the profile itself.

    Use: measured traces sample smooth stretches far more finely than a table bin resolves
    (``brdf.simulate`` simplifies to a fraction of its bin width ``pi / M``; ``bench/scratch_scale.py``
    reports the table error it adds).  Noise at the sampling pitch is *kept*: each of its facets
    scatters light elsewhere, so it changes the table (smooth such a trace first if it is
    measurement noise).
    """
    if not isinstance(profile, Profile):
        raise ValueError(f"profile: expected a precompute.profiles.Profile, got {type(profile).__name__}")
    tol = _check_range(max_exit_error, "max_exit_error", 0.0, np.pi / 2)
    if tol == 0.0 or profile.segments <= 2:
        return profile
    x, h = profile.x, profile.h
    n = x.size
    if profile.is_symmetric:
        mid = n // 2  # x[mid] == 0 for odd n (exact symmetry); else the half ends at the middle segment
        if n % 2:
            keep = _simplify_run(x[:mid + 1], h[:mid + 1], 0.5 * tol, [int(np.argmax(h[:mid + 1]))])
            left = np.flatnonzero(keep)
            idx = np.concatenate([left, (n - 1 - left[::-1])[1:]])
        else:
            keep = _simplify_run(x[:mid], h[:mid], 0.5 * tol, [int(np.argmax(h[:mid]))])
            left = np.flatnonzero(keep)
            idx = np.concatenate([left, n - 1 - left[::-1]])
    else:
        idx = np.flatnonzero(_simplify_run(x, h, 0.5 * tol, [int(np.argmax(h))]))
    if idx.size == n:
        return profile
    params = dict(profile.params, simplified_from=int(profile.segments), max_exit_error=float(tol))
    return Profile(x[idx].copy(), h[idx].copy(), profile.name, params, profile.is_symmetric)


def _simplify_run(x: np.ndarray, h: np.ndarray, max_turn: float, forced) -> np.ndarray:
    """Douglas-Peucker with a direction criterion: keep-mask of vertices such that on every kept
    chord each original segment's direction is within ``max_turn`` of the chord's.  ``forced``: indices kept."""
    n = x.size
    keep = np.zeros(n, bool)
    keep[[0, n - 1]] = True
    keep[list(forced)] = True
    ang = np.arctan2(np.diff(h), np.diff(x))  # segment directions, in (-pi/2, pi/2) (x increasing)
    cuts = np.flatnonzero(keep)
    stack = list(zip(cuts[:-1], cuts[1:]))
    while stack:  # a loop over kept chords (as many as output segments), each test vectorised
        i, j = stack.pop()
        if j - i < 2:
            continue
        dx, dh = x[j] - x[i], h[j] - h[i]
        chord = np.arctan2(dh, dx)
        if np.max(np.abs(ang[i:j] - chord)) <= max_turn:
            continue
        ln = np.hypot(dx, dh)
        dist = np.abs((x[i + 1:j] - x[i]) * dh - (h[i + 1:j] - h[i]) * dx) / ln
        k = i + 1 + int(np.argmax(dist))
        keep[k] = True
        stack += [(i, k), (k, j)]
    return keep
