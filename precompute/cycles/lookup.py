"""Cycles' reads of its precomputed lookup tables (``intern/cycles/kernel/tables.h``: ``lookup_table_read``,
``lookup_table_read_2D``, ``lookup_table_read_3D``), for the tables ``multiscatter`` (``ggx_E``, ``ggx_Eavg``: 32
nodes per axis) and ``principled`` (``ggx_gen_schlick_ior_s``: 16 per axis) integrate on Cycles' nodes.

A table of ``size`` nodes per axis holds the values at x = i / (size - 1); x is clamped to [0, 1] and read linearly
between the two nodes around it (Cycles: ``x = saturatef(x) * (size - 1)``, ``index = min(int(x), size - 1)``,
``t = x - index``; here the last cell is [size - 2, size - 1] with t = 1 at x = 1: the same value).
"""
from __future__ import annotations

import numpy as np

__all__ = ["lookup_index", "lookup_table_read", "lookup_table_read_2D"]


def lookup_index(x, size: int):
    """(i, t): the cell i (int array, 0 <= i <= size - 2) and the fraction t in [0, 1] of ``x`` (broadcast,
    clamped to [0, 1]) on ``size`` nodes i / (size - 1)."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0) * (size - 1)
    i = np.minimum(np.floor(x).astype(np.int64), size - 2)
    return i, x - i


def lookup_table_read(table: np.ndarray, x):
    """Cycles ``lookup_table_read``: ``table`` (size,) read linearly at ``x`` (broadcast)."""
    i, t = lookup_index(x, len(table))
    return (1 - t) * table[i] + t * table[i + 1]


def lookup_table_read_2D(table: np.ndarray, x, y):
    """Cycles ``lookup_table_read_2D``: ``table`` (size_x, size_y) indexed [x, y], read linearly in x on the two
    nodes of y around ``y``, then linearly in y (Cycles' order); x, y broadcast.  One x (a material's roughness):
    the two x nodes are mixed once and the result read along y (the same arithmetic)."""
    i, t = lookup_index(x, table.shape[0])
    j, s = lookup_index(y, table.shape[1])
    if np.ndim(i) == 0:
        along_y = (1 - t) * table[i] + t * table[i + 1]
        return (1 - s) * along_y.take(j) + s * along_y.take(j + 1)
    return (1 - s) * ((1 - t) * table[i, j] + t * table[i + 1, j]) + s * ((1 - t) * table[i, j + 1] + t * table[i + 1, j + 1])
