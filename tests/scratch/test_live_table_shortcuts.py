"""Shortcuts of a live table edit's non-trace work (issue 18) against the plain computations they replace.

- ``slices._bin_rows``' Fresnel masses: one bincount over (bin, θo sample, channel) against one bincount per
  (θo sample, channel), bit for bit (the same exits summed in the same order);
- ``slices._row_moments(sparse=True)`` (the φo refinement's model moments, interval moments only for bins with
  mass) against the dense moments: equal up to the sign of an exact zero;
- the view slices of a profile against those built with the dense model moments, bit for bit.
"""
from __future__ import annotations

import numpy as np

from scratch_materials.precompute.scratch import material, profiles, slices


def _fm_reference(smp, ph, n, M, fw):
    e = -0.5 * np.pi + np.arange(M + 1) * (np.pi / M)
    key = smp * M + np.clip(np.searchsorted(e, ph, side="right") - 1, 0, M - 1)
    T, C = fw.shape[1:]
    fm = np.zeros((n * M, T, C))
    for t in range(T):
        for c in range(C):
            fm[:, t, c] = np.bincount(key, fw[:, t, c], minlength=n * M)
    return fm.reshape(n, M, T, C)


def test_fresnel_masses_in_one_bincount_equal_one_per_sample_and_channel():
    rng = np.random.default_rng(11)
    N, n, M = 5000, 7, 64
    smp = np.sort(rng.integers(0, n, N))
    ph = rng.uniform(-0.5 * np.pi, 0.5 * np.pi, N)
    w = rng.random(N)
    fw = rng.random((N, 5, 3)) * w[:, None, None]
    got = slices._bin_rows(smp, ph, w, rng.integers(1, 4, N), n, M, fw)[3]
    np.testing.assert_array_equal(got, _fm_reference(smp, ph, n, M, fw))
    fwt = np.ascontiguousarray(fw.transpose(0, 2, 1)).transpose(0, 2, 1)     # not C-contiguous: same sums
    np.testing.assert_array_equal(slices._bin_rows(smp, ph, w, np.ones(N, int), n, M, fwt)[3], got)
    # the test can fail: another exit order changes the last bits of some sums
    perm = rng.permutation(N)
    assert not np.array_equal(_fm_reference(smp[perm], ph[perm], n, M, fw[perm]), got)


def test_sparse_row_moments_equal_the_dense_ones():
    rng = np.random.default_rng(12)
    n, M, C = 40, 128, 4
    rows = rng.random((n, M, C)) * (rng.random((n, M, 1)) < 0.2)            # most bins empty, as in a slice
    cen, even = rng.random((n, M)), rng.random((n, M)) < 0.3
    node, view = rng.uniform(-1.5, 1.5, (n, 1)), rng.uniform(-1.5, 1.5, (n, 1))
    dense = slices._row_moments(rows, cen, even, node, view)
    sparse = slices._row_moments(rows, cen, even, node, view, sparse=True)
    assert np.all((dense == sparse) | (np.abs(dense) == 0) & (np.abs(sparse) == 0))
    assert np.abs(dense).max() > 0.1
    # the test can fail: a mask that drops bins with mass changes the moments
    nz = rows[..., 0] > 0
    lo, hi = slices.aim_interval(M, cen, even, node, view)
    im = np.zeros(lo.shape + (4,))
    half = nz & (np.arange(M)[None, :] < M // 2)
    im[half] = slices.interval_moments(lo[half], hi[half])
    assert not np.allclose(np.matmul(np.swapaxes(rows, -1, -2), im), dense)


def test_view_slices_equal_those_of_the_dense_model_moments(monkeypatch):
    prof = profiles.quartic(0.093)
    F = material.trace_fresnel(material.validate(fresnel="copper"))
    fast = slices.view_slices(prof, 64, F, base=16, levels=3).arrays()
    real = slices._row_moments
    monkeypatch.setattr(slices, "_row_moments", lambda *a, **k: real(*a[:5]))          # always dense
    monkeypatch.setattr(slices, "_GEOMETRY", {})
    dense = slices.view_slices(prof, 64, F, base=16, levels=3).arrays()
    for k, v in dense.items():
        np.testing.assert_array_equal(fast[k], v, err_msg=k)


def _theta_basis_with_tensordot():
    """``slices._theta_basis`` as it was: the exact moments by ``np.tensordot`` over the bins (its source with
    that one line put back)."""
    import inspect

    src = inspect.getsource(slices._theta_basis)
    new = ("exact = np.matmul(basis_f, fm_b.reshape(S, M, -1)).reshape(S, 3, NT, C).transpose(0, 2, 3, 1)")
    assert src.count(new) == 1
    ns = dict(vars(slices))
    exec(src.replace(new, "exact = np.tensordot(fm_b, basis_f, axes=([1], [1]))"), ns)  # noqa: S102
    return ns["_theta_basis"]


def test_theta_basis_moments_equal_tensordots(monkeypatch):
    """The θo basis's exact moments by a batched matmul over the bins (no transposed copy of the Fresnel masses):
    the view slices (basis, coefficients, error) equal those of ``np.tensordot``, bit for bit."""
    prof = profiles.quartic(0.087)
    F = material.trace_fresnel(material.validate(fresnel="gold"))
    fast = slices.view_slices(prof, 64, F, base=16, levels=3).arrays()
    monkeypatch.setattr(slices, "_theta_basis", _theta_basis_with_tensordot())
    ref = slices.view_slices(prof, 64, F, base=16, levels=3).arrays()
    for k, v in ref.items():
        np.testing.assert_array_equal(fast[k], v, err_msg=k)
