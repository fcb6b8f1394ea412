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

__all__ = ["Profile", "quartic", "v_groove", "circular", "flat", "tabulated", "from_file"]

_DENSE = 4096  # dense samples per half profile when placing analytic vertices


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


def circular(depth: float = 0.5, *, segments: int = 256) -> Profile:
    """Circular-arc ("round"/"U") groove through the rims with sagitta ``depth`` in (0, 0.5].

    ``depth = 0.5`` is a semicircle.  Vertices are uniform in angle along the arc.
    """
    d = _check_range(depth, "depth", 0.0, 0.5, low_open=True)
    r = (0.25 + d * d) / (2.0 * d)
    psi_max = np.arcsin(min(1.0, 0.5 / r))

    def half(t):
        psi = psi_max * t
        return r * np.sin(psi), -(r * np.cos(psi) - (r - d))

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
