"""The alias tables (``precompute.tables.alias``): Vose's construction run on every row at once equals the
row-by-row construction bit for bit, and draws each bin with exactly its probability."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.tables import alias


def _vose_rows(cdf):
    """Reference: Vose's construction one row and one bin at a time (the scalar algorithm)."""
    n, M = cdf.shape[0], cdf.shape[1] - 1
    p = np.clip(np.diff(cdf, axis=1), 0.0, None)
    prob, al = np.ones((n, M)), np.tile(np.arange(M), (n, 1))
    for r in range(n):
        tot = p[r].sum()
        if tot <= 0:
            continue
        q = p[r] * (M / tot)
        small = [j for j in range(M) if q[j] < 1.0]
        large = [j for j in range(M) if q[j] >= 1.0]
        while small and large:
            j, k = small.pop(), large.pop()
            prob[r, j], al[r, j] = q[j], k
            q[k] -= 1.0 - q[j]
            (small if q[k] < 1.0 else large).append(k)
        for j in small + large:
            prob[r, j], al[r, j] = (1.0 if p[r, j] > 0 else 0.0), j
            if p[r, j] <= 0:
                al[r, j] = int(np.argmax(p[r]))
    return prob, al


def _cdf(p):
    c = np.concatenate([np.zeros((p.shape[0], 1)), np.cumsum(p, 1)], 1)
    return c / np.where(c[:, -1:] > 0, c[:, -1:], 1.0)


@pytest.mark.parametrize("seed", range(6))
def test_alias_rows_at_once_equal_the_scalar_construction(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        n, M = int(rng.integers(1, 12)), int(rng.integers(1, 300))
        p = rng.random((n, M)) ** int(rng.integers(1, 8))
        p[rng.random((n, M)) < rng.random()] = 0.0          # zero bins
        p[rng.random(n) < 0.2] = 0.0                        # empty rows
        if rng.random() < 0.2:
            p[:] = 1.0                                      # uniform: every bin exactly 1 (no pairing)
        cdf = _cdf(p)
        prob, al = alias.alias_tables(cdf)
        ref = _vose_rows(cdf)
        assert np.array_equal(prob, ref[0]) and np.array_equal(al, ref[1])
        tot = p.sum(1)
        live = tot > 0
        np.testing.assert_allclose(alias.alias_pmf(prob, al)[live], (p / np.where(tot > 0, tot, 1)[:, None])[live],
                                   atol=1e-12)


def test_alias_detects_a_wrong_pairing():
    """The comparison can fail: one alias moved to another bin changes the table and its distribution."""
    rng = np.random.default_rng(7)
    cdf = _cdf(rng.random((3, 64)) ** 3)
    prob, al = alias.alias_tables(cdf)
    j = int(np.argmin(prob[0]))
    al[0, j] = (al[0, j] + 1) % 64
    ref = _vose_rows(cdf)
    assert not np.array_equal(al, ref[1])
    assert np.abs(alias.alias_pmf(prob, al)[0] - np.diff(cdf[0])).max() > 1e-3
