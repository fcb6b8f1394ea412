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
