"""OSL shader sources and the Python generators of specialised sources.

Generators return OSL source text with the material's tables compiled in as constant
arrays, so an INTERNAL script node holds everything a render farm needs (no external
files, no add-on).  Only the features a material uses are emitted.
"""
from __future__ import annotations

import os

#: Folder of the hand-written .osl sources and of Cycles-independent .h helpers.
OSL_DIR = os.path.dirname(os.path.abspath(__file__))


def read_source(name: str) -> str:
    """Text of a hand-written shader in this folder (e.g. ``"aniso_ggx.osl"``)."""
    with open(os.path.join(OSL_DIR, name), encoding="utf-8") as f:
        return f.read()


def const_array(name: str, values, ctype: str = "float", per_line: int = 8) -> str:
    """``float name[n] = {...};`` (or ``int``) with float32-exact literals (at least one element)."""
    conv, fmt = (int, "{:d}") if ctype == "int" else (float, "{:.9g}")
    vals = [conv(v) for v in (values if hasattr(values, "__iter__") else [values])]
    if not vals:
        vals = [conv(0)]
    lines = []
    for i in range(0, len(vals), per_line):
        lines.append("        " + ", ".join(fmt.format(v) for v in vals[i:i + per_line]))
    return f"    {ctype} {name}[{len(vals)}] = {{\n" + ",\n".join(lines) + "\n    };\n"
