"""Random-projection accelerated SVD with mean subtraction (Wu et al. 2011, Table 2, §3.4-3.7).

Table 2 (after Vempala 2004), for an m x n matrix P and an m x l Gaussian matrix R:

1. Q = R^T P / sqrt(l)          (l x n sketch of the rows)
2. Q = U_Q Σ_Q V_Q^T             (small SVD)
3. P ≈ (P V_Q) V_Q^T

Before the SVD the mean row is subtracted ("standard PCA", §3.7).  Optionally ``n_power``
subspace (power) iterations à la Halko, Martinsson & Tropp (2011, Alg. 4.4) sharpen V_Q;
``n_power = 0`` is exactly the paper's algorithm.  The rank is the smallest r whose
singular values keep ``power`` of the (mean-subtracted) squared Frobenius norm (the paper
keeps 99.5 % for N and 98 % for M, §6).  As in §3.4 U absorbs Σ, so P ≈ 1 μ^T + U V^T.

Matrices too large for memory are given as a *row-chunk generator* (``rows(a, b)``
returns P[a:b]), so only chunks of P and R exist at any time (§3.7: "sub-matrices of M and
R are sampled/computed on the fly"); R chunks come from a seeded generator so that every
pass sees the same R.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["LowRank", "random_projection_svd", "random_projection_svd_streamed", "rank_for_power"]


@dataclass
class LowRank:
    """P ≈ 1 mean^T + U V^T; ``power`` is the exact fraction of the mean-subtracted squared
    Frobenius norm captured, ``sigma`` the sketch's singular values (all of them)."""
    mean: np.ndarray   # (n,)
    U: np.ndarray      # (m, r)  (= P V, i.e. U Σ of the paper)
    V: np.ndarray      # (n, r)  orthonormal columns
    power: float
    sigma: np.ndarray

    @property
    def rank(self) -> int:
        return self.V.shape[1]

    def dense(self) -> np.ndarray:
        return self.mean[None, :] + self.U @ self.V.T


def rank_for_power(sigma: np.ndarray, power: float) -> int:
    """Smallest r with Σ_{i<r} σ_i^2 >= power · Σ σ_i^2 (at least 1 if any σ > 0)."""
    s2 = np.asarray(sigma, np.float64) ** 2
    tot = s2.sum()
    if tot <= 0:
        return 0
    return int(min(len(s2), np.searchsorted(np.cumsum(s2), power * tot * (1 - 1e-12)) + 1))


def _check(power, l, n_power):
    if not (0.0 < power <= 1.0):
        raise ValueError(f"power: expected a fraction in (0, 1], got {power!r}")
    if not (isinstance(l, (int, np.integer)) and l >= 1):
        raise ValueError(f"l: expected a positive integer sketch size, got {l!r}")
    if not (isinstance(n_power, (int, np.integer)) and 0 <= n_power <= 10):
        raise ValueError(f"n_power: expected an integer in [0, 10], got {n_power!r}")


def random_projection_svd(P: np.ndarray, l: int = 50, power: float = 0.995, n_power: int = 0,
                          seed: int = 0, max_rank: int | None = None) -> LowRank:
    """Table 2 on an in-memory matrix P (m x n) with mean subtraction; see module docstring."""
    P = np.asarray(P, dtype=np.float64)
    m, n = P.shape
    return random_projection_svd_streamed(lambda a, b: P[a:b], m, n, l=l, power=power, n_power=n_power,
                                          seed=seed, max_rank=max_rank, chunk=max(1, 4_000_000 // max(n, 1)))


def random_projection_svd_streamed(rows: Callable[[int, int], np.ndarray], m: int, n: int, l: int = 50,
                                   power: float = 0.98, n_power: int = 0, seed: int = 0,
                                   max_rank: int | None = None, chunk: int = 2048) -> LowRank:
    """Table 2 with P given by row chunks ``rows(a, b) -> P[a:b]`` (float64 or float32).

    Passes over P: 1 (sketch + mean + norm) + ``n_power`` + 1 (U = (P - 1μ^T) V)."""
    _check(power, l, n_power)
    l = int(min(l, m))
    starts = list(range(0, m, chunk))

    def R_chunk(a, b):
        return np.random.default_rng([seed, a]).standard_normal((b - a, l))

    # pass 1: sketch Y = R^T P, column sums, squared norm
    Y = np.zeros((l, n))
    colsum = np.zeros(n)
    sq = 0.0
    rsum = np.zeros(l)
    for a in starts:
        b = min(a + chunk, m)
        Pc = np.asarray(rows(a, b), np.float64)
        R = R_chunk(a, b)
        Y += R.T @ Pc
        colsum += Pc.sum(0)
        sq += float(np.einsum("ij,ij->", Pc, Pc))
        rsum += R.sum(0)
    mean = colsum / m
    Y -= np.outer(rsum, mean)          # R^T (P - 1 μ^T)
    total = max(sq - m * float(mean @ mean), 0.0)
    Y /= np.sqrt(l)
    # optional Halko power iterations on the centred matrix X: Y <- (Y X^T) X
    for _ in range(n_power):
        Qy, _ = np.linalg.qr(Y.T)      # n x l orthonormal
        Yn = np.zeros((Qy.shape[1], n))
        for a in starts:
            b = min(a + chunk, m)
            X = np.asarray(rows(a, b), np.float64) - mean
            Yn += (X @ Qy).T @ X
        Y = Yn
    _, sig, VQt = np.linalg.svd(Y, full_matrices=False)
    keep = sig > sig[0] * 1e-12 if sig.size and sig[0] > 0 else np.zeros(sig.size, bool)
    VQ = VQt[keep].T                   # n x l' approximate right singular vectors (step 2)
    # last pass: U = (P - 1 μ^T) V_Q (step 3), then an exact small SVD of U to order the
    # components by the power they really capture and to pick the rank against the true total
    U = np.empty((m, VQ.shape[1]))
    for a in starts:
        b = min(a + chunk, m)
        U[a:b] = (np.asarray(rows(a, b), np.float64) - mean) @ VQ
    Uu, su, Wt = np.linalg.svd(U, full_matrices=False)
    r = rank_for_power(np.append(su, np.sqrt(max(total - float(su @ su), 0.0))), power)
    r = min(r, len(su))
    if max_rank is not None:
        r = min(r, int(max_rank))
    U = Uu[:, :r] * su[:r]
    V = VQ @ Wt[:r].T
    captured = float(su[:r] @ su[:r])
    sig = su
    tiny = total <= 1e-24 * max(sq, 1e-300)  # centred matrix is zero up to rounding
    return LowRank(mean, U, V, 1.0 if tiny else captured / total, sig)
