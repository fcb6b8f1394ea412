"""Node values for the tabulated closure's bilinear reconstruction that keep each cell's mass.

The closure (``tabulated_brdf``; the OSL shader and the node graph alike) reconstructs f bilinearly between
cell centres, with edges clamped: along one axis the cell average of the interpolant of node values v is

    (v[j-1] + 6 v[j] + v[j+1]) / 8                                              (``CELL_AVERAGE``)

so cell averages used directly as node values (what a box-averaged table holds) render blurred by about a
cell: a sharp lobe loses its peak (a rough brushed scan's NDF table: exit-direction second moments +0.004 at
normal view; a gold GGX α 0.05 MERL file at 32² half-vector cells: -12..-21 % of the light within 6° of the
mirror direction).  ``prefilter_cells`` inverts that average along both cell axes, clamps the ringing of
under-resolved peaks at 0 and keeps each node column's mass.
``deconvolve_cells`` reaches the same goal by Richardson-Lucy iterations: node values stay >= 0 and zeros stay 0
without a clamp, and mass moves only locally (the clamp's global rescale darkened a MERL file's far tail by 2 %, and
took 1.5 % albedo from a rough scan's NDF table at grazing).  The Dong NDF tables use it
(``microgeometry.ndf_brdf.deconvolve_cells``, 100 iterations); MERL imports use it on the residual of the floors (``tabulated_brdf.floor_parts`` with
``info["deconvolve_residual"]``): the floors are split from the cell averages, which they match exactly, and only
what the table closure renders is deconvolved (prefiltering the whole table pinned the Diffuse floor of a GGX +
Lambert file to 0: the clamped ringing touched 0 at nodes where the Lambertian is not).
"""
from __future__ import annotations

import numpy as np

__all__ = ["CELL_AVERAGE", "cell_average_matrix", "prefilter_cells", "deconvolve_cells", "DECONVOLVE_ITERATIONS"]

#: Cell average of the clamped bilinear interpolant per axis (``tabulated_brdf.closure_tables`` uses the same).
CELL_AVERAGE = (0.125, 0.75, 0.125)
#: Richardson-Lucy iterations of ``deconvolve_cells``: a gold GGX α 0.05 MERL residual at 48² cells reaches its
#: fixed point's cell-average misfit (2.7 % L1; 0 / 5 / 30 / 100 iterations: 9.9 / 3.4 / 2.70 / 2.70 %)
DECONVOLVE_ITERATIONS = 30


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


def _cell_filter(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M applied along both cell axes of x (res, res, k)."""
    x = np.tensordot(M, x, axes=(1, 0))                      # rows
    return np.tensordot(M, x, axes=(1, 1)).transpose(1, 0, 2)   # columns


def deconvolve_cells(rho: np.ndarray, res: int, iterations: int = DECONVOLVE_ITERATIONS) -> np.ndarray:
    """Node values x >= 0 (res², ...) whose bilinear reconstruction's cell averages A x approach ``rho`` (res², ...,
    >= 0; the first axis the res x res cells in row-major order; A = ``cell_average_matrix`` along both cell axes):
    Richardson-Lucy iterations (Richardson 1972, Lucy 1974; the multiplicative EM update for a non-negative
    blur) x <- x · Aᵀ(ρ / A x) / Aᵀ1 from x = ρ.  Each trailing index (view node, channel) is its own image; the
    update keeps x >= 0, leaves zeros of ρ at 0 and keeps Σ Aᵀ1 x = Σ ρ (the mass) at every step.  Units of ρ."""
    rho = np.asarray(rho, np.float64)
    if rho.ndim < 1 or rho.shape[0] != res * res:
        raise ValueError(f"rho: expected res² = {res * res} cells on the first axis, got shape {rho.shape}")
    if not np.all(np.isfinite(rho)) or (rho.size and rho.min() < 0):
        raise ValueError("rho: cell averages must be finite and >= 0")
    iterations = int(iterations)
    if not 0 <= iterations <= 1000:
        raise ValueError(f"iterations: expected 0..1000, got {iterations}")
    A = cell_average_matrix(res)
    r = rho.reshape(res, res, -1)
    norm = _cell_filter(A.T, np.ones_like(r))
    x = r.copy()
    for _ in range(iterations):
        Ax = _cell_filter(A, x)
        x = x * _cell_filter(A.T, np.where(Ax > 0, r / np.where(Ax > 0, Ax, 1.0), 0.0)) / norm
    return x.reshape(rho.shape)
