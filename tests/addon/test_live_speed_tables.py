"""Live look-dev speed (issue 18), the parts of a table-changing edit outside Blender: the shader text's
constant arrays (``osl.const_array``: a table's values converted and formatted in one C-level pass).
Oracle: the per-element formatter it replaces (the same text, byte for byte: the same shader)."""
from __future__ import annotations

import numpy as np
import pytest

from scratch_materials.osl import const_array


def _const_array_reference(name, values, ctype="float", per_line=8):
    """The per-element formatter (``str.format`` of each value) as it was."""
    conv, fmt = (int, "{:d}") if ctype == "int" else (float, "{:.9g}")
    vals = [conv(v) for v in (values if hasattr(values, "__iter__") else [values])]
    if not vals:
        vals = [conv(0)]
    lines = []
    for i in range(0, len(vals), per_line):
        lines.append("        " + ", ".join(fmt.format(v) for v in vals[i:i + per_line]))
    return f"    {ctype} {name}[{len(vals)}] = {{\n" + ",\n".join(lines) + "\n    };\n"


_RNG = np.random.default_rng(7)


@pytest.mark.parametrize("values, ctype", [
    (_RNG.random(85 * 256), "float"), (_RNG.random(85 * 256).astype(np.float32), "float"),
    (_RNG.integers(0, 256, 85 * 257), "int"), (_RNG.integers(0, 256, 35).astype(np.float64), "int"),
    (_RNG.standard_normal(30) * 1e-30, "float"), (np.array([np.float32(0.1)] * 9), "float"),
    (np.array([]), "float"), ([], "int"), (3.0, "float"), ([1, 2, 3], "int"), (np.arange(16.0), "float"),
    (np.array([1e300, -0.0, 5e-324, 1.0 / 3.0]), "float"), (np.array([True, False, True]), "int")])
def test_const_array_text_is_the_per_element_formatters(values, ctype):
    assert const_array("TB_X", values, ctype) == _const_array_reference("TB_X", values, ctype)


def test_split_trace_equals_one_call_record_for_record(monkeypatch):
    """``slices._trace`` split over threads (``TRACE_WORKERS``, interleaved directions) gives the records of one
    ``beam.trace_exact`` call, bit for bit up to their order (the directions are traced independently), and the
    per-direction lost flux in place; the view slices built from them are identical."""
    from scratch_materials.precompute.scratch import material as pm, profiles, slices

    fres = pm.trace_fresnel(pm.validate(fresnel="gold"))
    prof = profiles.quartic(0.09)
    phi = np.linspace(-0.5 * np.pi, 0.5 * np.pi, 37)
    cos = np.cos(slices.theta_of_coordinate(np.linspace(0.0, 1.0, 5)))
    monkeypatch.setattr(slices, "GEOMETRY_BYTES", 0)          # every call traces (no stored geometry)
    monkeypatch.setattr(slices, "TRACE_WORKERS", 1)
    one = slices._trace(prof, phi, fres, cos)
    monkeypatch.setattr(slices, "TRACE_WORKERS", 3)
    split = slices._trace(prof, phi, fres, cos)
    assert split.sample.size == one.sample.size > phi.size
    assert not np.array_equal(split.sample, one.sample)          # really split: another order
    a, b = np.lexsort((one.pid, one.bounces, one.sample)), np.lexsort((split.pid, split.bounces, split.sample))
    for field in ("sample", "pid", "bounces", "phi_o", "weight", "fresnel"):
        np.testing.assert_array_equal(getattr(split, field)[b], getattr(one, field)[a], err_msg=field)
    np.testing.assert_array_equal(split.lost, one.lost)
    monkeypatch.setattr(slices, "TRACE_WORKERS", 2)
    vs2 = slices.view_slices(prof, 64, fres, base=16, levels=2)
    monkeypatch.setattr(slices, "TRACE_WORKERS", 1)
    vs1 = slices.view_slices(prof, 64, fres, base=16, levels=2)
    for k, v in vs1.arrays().items():
        np.testing.assert_allclose(vs2.arrays()[k], v, rtol=1e-12, atol=1e-15, err_msg=k)


def test_theta_basis_reuses_the_start_traces_and_equals_tracing_every_node(monkeypatch):
    """The start φo nodes are traced once at every θo sample (``_phi_nodes(..., theta, records)``); the θo basis
    then traces only the nodes refinement added.  The view slices equal those of the θo basis tracing every
    node again (the records are the same, bit for bit)."""
    from scratch_materials.precompute.scratch import material as pm, profiles, slices

    fres = pm.trace_fresnel(pm.validate(fresnel="copper"))
    prof = profiles.quartic(0.11)
    calls = []
    real = slices._trace
    monkeypatch.setattr(slices, "_trace", lambda p, phi, f=None, c=(): calls.append((np.size(phi), len(c)))
                        or real(p, phi, f, c))
    reused = slices.view_slices(prof, 64, fres, base=16, levels=2)
    T = 32
    theta_calls = [n for n, t in calls if t == T]
    assert theta_calls[0] == 17 and sum(theta_calls) == reused.phi.size      # 16 start intervals: 17 nodes
    real_nodes = slices._phi_nodes
    monkeypatch.setattr(slices, "_phi_nodes", lambda *a: real_nodes(*a[:7]))     # no records kept
    calls.clear()
    again = slices.view_slices(prof, 64, fres, base=16, levels=2)
    assert [n for n, t in calls if t == T] == [again.phi.size]                    # every node traced again
    for k, v in again.arrays().items():
        np.testing.assert_allclose(reused.arrays()[k], v, rtol=1e-12, atol=1e-15, err_msg=k)


def test_alias_table_of_a_distribution_seen_before_is_remembered_exactly():
    """``lobe_table.alias_table`` remembers the tables it built (a cache hit of a live edit builds none): the
    remembered table equals a fresh construction bit for bit, is handed out as a copy, and the memory is
    bounded."""
    from scratch_materials.precompute.scratch import lobe_table as lt

    rng = np.random.default_rng(5)
    w = rng.random((12, 32)) ** 4
    w[2] = 0.0
    cdf = lt.proposal(w)[0]
    first = lt.alias_table(cdf)
    fresh = lt._alias_table(np.asarray(cdf, float))
    again = lt.alias_table(cdf.copy())
    for a, b, c in zip(first, fresh, again):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(c, b)
    again[0][:] = -1.0                                   # a caller's edit does not reach the memory
    np.testing.assert_array_equal(lt.alias_table(cdf)[0], fresh[0])
    other = lt.proposal(np.roll(w, 1, axis=1))[0]        # another distribution: its own table
    assert not np.array_equal(lt.alias_table(other)[1], fresh[1])
    for k in range(lt._ALIAS_MAX + 5):
        lt.alias_table(lt.proposal(rng.random((2, 8)) + k)[0])
    assert len(lt._ALIAS) <= lt._ALIAS_MAX
