"""Node values for the tabulated closure's bilinear reconstruction that keep each cell's mass.

The closure (``tabulated_brdf``; the OSL shader and the node graph alike) reconstructs f bilinearly between
cell centres, with edges clamped: along one axis the cell average of the interpolant of node values v is

    (v[j-1] + 6 v[j] + v[j+1]) / 8                                              (``CELL_AVERAGE``)

so cell averages used directly as node values (what a box-averaged table holds) render blurred by about a
cell: a sharp lobe loses its peak (a rough brushed scan's NDF table: exit-direction second moments +0.004 at
normal view; a gold GGX α 0.05 MERL file at 32² half-vector cells: -12..-21 % of the light within 6° of the
mirror direction).  ``prefilter_cells`` inverts that average along both cell axes, clamps the ringing of
under-resolved peaks at 0 and keeps each node column's mass.  Pure numpy; used by ``microgeometry.ndf_brdf``
(MERL tables not yet: their floors (``tabulated_brdf.floor_parts``) are split from cell-averaged lobes, and a
prefiltered table pinned the Diffuse floor of a GGX + Lambert file to 0).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CELL_AVERAGE", "cell_average_matrix", "prefilter_cells"]

#: Cell average of the clamped bilinear interpolant per axis (``tabulated_brdf.closure_tables`` uses the same).
CELL_AVERAGE = (0.125, 0.75, 0.125)


def cell_average_matrix(res: int) -> np.ndarray:
    """(res, res) matrix A: cell averages = A @ node values along one axis (edges clamped as the shader)."""
    A = np.zeros((res, res))
    for j in range(res):
        for d, w in zip((-1, 0, 1), CELL_AVERAGE):
            A[j, min(max(j + d, 0), res - 1)] += w
    return A


def prefilter_cells(rho: np.ndarray, res: int) -> np.ndarray:
    """Node values (res², ...) whose bilinear reconstruction has the cell averages ``rho`` (res², ...; the
    first axis the res x res cells in row-major order): ``cell_average_matrix`` inverted along both cell
    axes, clamped at 0, rescaled per trailing index (view node, channel) to the cell averages' mass."""
    rho = np.asarray(rho, np.float64)
    if rho.ndim < 1 or rho.shape[0] != res * res:
        raise ValueError(f"rho: expected res² = {res * res} cells on the first axis, got shape {rho.shape}")
    Ai = np.linalg.inv(cell_average_matrix(res))
    x = rho.reshape(res, res, *rho.shape[1:])
    x = np.einsum("ij,jk...->ik...", Ai, x)
    x = np.einsum("ij,kj...->ki...", Ai, x)
    x = np.maximum(x, 0.0).reshape(rho.shape)
    mass, got = rho.sum(0, keepdims=True), x.sum(0, keepdims=True)
    return x * np.where(got > 0, mass / np.where(got > 0, got, 1.0), 0.0)
