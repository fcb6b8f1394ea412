"""Input validation shared by every pipeline: bad input raises ``ValueError`` naming the parameter
and its allowed range, never NaN, an IndexError or a TypeError further down."""
from __future__ import annotations

import numpy as np


def finite(name: str, x) -> np.ndarray:
    """``x`` as a float64 array, or ValueError if it is not numeric or holds NaN / inf."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number or array of numbers, got {x!r}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (got NaN or inf)")
    return a


def in_range(name: str, x, lo: float, hi: float, lo_open: bool = False) -> np.ndarray:
    """``x`` (array) with every element in [lo, hi] (or (lo, hi] with ``lo_open``)."""
    a = finite(name, x)
    bad = (a <= lo) if lo_open else (a < lo)
    if np.any(bad) or np.any(a > hi):
        br = "(" if lo_open else "["
        raise ValueError(f"{name} must lie in {br}{lo}, {hi}] (got min {a.min():.6g}, max {a.max():.6g})")
    return a


def positive(name: str, x, hi: float = np.inf) -> np.ndarray:
    """``x`` (array) with every element in (0, hi]."""
    return in_range(name, x, 0.0, hi, lo_open=True)


def check_range(name: str, value, lo: float, hi: float) -> float:
    """A scalar in [lo, hi] as float, or ValueError naming the parameter and its allowed range."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {value!r}") from None
    if not (lo <= v <= hi):  # also rejects NaN
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value!r}")
    return v


def check_color(name: str, value) -> tuple[float, float, float, float]:
    """RGB or RGBA with components in [0, 1] -> RGBA tuple."""
    try:
        c = [float(x) for x in value]
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 or 4 numbers in [0, 1], got {value!r}") from None
    if len(c) not in (3, 4) or not all(0.0 <= x <= 1.0 for x in c):
        raise ValueError(f"{name} must be 3 or 4 numbers in [0, 1], got {value!r}")
    return tuple(c[:3]) + (c[3] if len(c) == 4 else 1.0,)


def check_int(name: str, value, lo: int, hi: int) -> int:
    """An integer (not a bool, not a float with a fraction) in [lo, hi], or ValueError naming the parameter."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        ok = isinstance(value, (float, np.floating)) and np.isfinite(value) and float(value).is_integer()
        if not ok:
            raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    v = int(value)
    if not (lo <= v <= hi):
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


#: seeds are non-negative integers below 2**63 (numpy's SeedSequence takes any non-negative integer;
#: the bound keeps them JSON- and int64-safe for cache keys)
SEED_MAX = 2**63 - 1


def check_seed(name: str, value) -> int:
    """A random seed: an integer in [0, 2**63 - 1] (negative seeds are refused by numpy's generators)."""
    return check_int(name, value, 0, SEED_MAX)
