"""Walker's alias method (Vose's construction): draw a bin of a tabulated distribution with one uniform
number and one table lookup, O(1) -- the sampler of the scratch material's table lobes on the SVM path
(``precompute.scratch.lobe_table``) and of the tabulated-BRDF node graph (``precompute.tables.tabulated_brdf``).
"""
from __future__ import annotations

import numpy as np

__all__ = ["alias_tables", "alias_pmf"]


def alias_tables(cdf):
    """Walker's alias table of each row's bin distribution P_k = cdf[k+1] - cdf[k] (Vose's construction).

    ``cdf`` (n, M+1) -> (prob (n, M), alias (n, M) int).  With one uniform h: u = h M, j = floor(u),
    f = u - j; the bin is j if f <= prob_j, else alias_j (the graph's ``prob_j < f`` test).  It draws bin k
    with probability exactly P_k (``alias_pmf``); zero bins get prob 0 (never drawn), empty rows prob 1."""
    cdf = np.asarray(cdf, np.float64)
    if cdf.ndim != 2 or cdf.shape[1] < 2:
        raise ValueError(f"cdf: expected shape (n, M+1) with M >= 1, got {cdf.shape}")
    n, M = cdf.shape[0], cdf.shape[1] - 1
    p = np.clip(np.diff(cdf, axis=1), 0.0, None)
    prob = np.ones((n, M))
    alias = np.tile(np.arange(M), (n, 1))
    for r in range(n):
        tot = p[r].sum()
        if tot <= 0:
            continue
        q = p[r] * (M / tot)
        small = [j for j in range(M) if q[j] < 1.0]
        large = [j for j in range(M) if q[j] >= 1.0]
        while small and large:
            j, k = small.pop(), large.pop()
            prob[r, j], alias[r, j] = q[j], k
            q[k] -= 1.0 - q[j]
            (small if q[k] < 1.0 else large).append(k)
        for j in small + large:               # round-off leftovers: themselves with probability 1
            prob[r, j], alias[r, j] = (1.0 if p[r, j] > 0 else 0.0), j
            if p[r, j] <= 0:                  # a zero bin left over (round-off): hand it to the largest bin
                alias[r, j] = int(np.argmax(p[r]))
    return prob, alias


def alias_pmf(prob, alias) -> np.ndarray:
    """The bin distribution (n, M) an alias table draws: (prob_k + Σ_{j: alias_j = k} (1 - prob_j)) / M."""
    prob, alias = np.asarray(prob, np.float64), np.asarray(alias, int)
    out = prob.copy()
    for r in range(len(prob)):
        np.add.at(out[r], alias[r], 1.0 - prob[r])
    return out / prob.shape[1]
