"""Table lobes of a live edit (issue 18): the box albedo of the occupied bins only
(``lobe_table.box_albedo(where=...)``).  Oracle: the evaluation of every bin (each lobe on its own)."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.precompute.scratch import lobe_table, slices, profiles


@pytest.mark.parametrize("M", [16, 64])
def test_box_albedo_of_selected_bins_equals_the_full_evaluation(M):
    rng = np.random.default_rng(M)
    S = 9
    phi = np.linspace(-1.55, 1.55, S)
    cen = rng.random((S, M))
    cen[:, ::5] = 0.0                                       # point aims (h = 0)
    full = lobe_table.box_albedo(phi, M, cen)
    where = rng.random((S, M)) < 0.3
    part = lobe_table.box_albedo(phi, M, cen, where=where)
    np.testing.assert_array_equal(part[where], full[where])
    assert np.all(part[~where] == 0.0) and np.any(full[~where] > 0.1)
    np.testing.assert_array_equal(lobe_table.box_albedo(phi, M, cen, where=np.ones((S, M), bool)), full)
    with pytest.raises(ValueError, match="where"):
        lobe_table.box_albedo(phi, M, cen, where=np.ones((S, M + 1), bool))


def test_table_lobes_skip_empty_bins_without_changing_the_weights():
    """``lobes._table_lobes`` evaluates the albedo where the slice has mass only: the weights (mass / a) and the
    lost flux equal those from the albedo of every bin."""
    from scratch_materials.precompute.scratch import lobes

    vs = slices.view_slices(profiles.quartic(0.12), 64, None, base=16, levels=2)
    assert (vs.mass == 0).mean() > 0.3
    got = lobes._table_lobes(vs)
    real = lobe_table.box_albedo
    try:
        lobe_table.box_albedo = lambda *a, where=None, **k: real(*a, **k)     # every bin
        ref = lobes._table_lobes(vs)
    finally:
        lobe_table.box_albedo = real
    for k in ("cdf", "total", "lost"):
        np.testing.assert_array_equal(got[k], ref[k], err_msg=k)
