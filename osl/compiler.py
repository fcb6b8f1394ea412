"""Compile OSL text with Blender's own compiler (``_cycles.osl_compile``, the oslc that Cycles uses)
and read the result: for tests and for checking a generated shader by hand.

Needs Blender: ``import bpy`` (as a module or inside Blender) makes ``_cycles`` importable; nothing
here is imported by the generators.  ``#include "stdcycles.h"`` and Blender's other shader headers
are found by the compiler itself; includes of this folder's headers resolve next to the input file.
"""
from __future__ import annotations

import os
import tempfile


class OSLCompileError(RuntimeError):
    """The compiler rejected the source (its messages went to stderr)."""


def compile_file(path: str) -> str:
    """Compile the .osl file ``path``; return the text of the .oso bytecode."""
    import bpy  # noqa: F401  (registers the _cycles module)
    import _cycles

    fd, out = tempfile.mkstemp(suffix=".oso")
    os.close(fd)
    try:
        if not _cycles.osl_compile(os.path.abspath(path), out):
            raise OSLCompileError(f"OSL compile of {path} failed (compiler messages on stderr)")
        with open(out, encoding="utf-8") as f:
            return f.read()
    finally:
        os.remove(out)


def compile_source(text: str, name: str = "shader") -> str:
    """Compile OSL source ``text`` (e.g. a generator's output, as Blender compiles an INTERNAL
    script node: written to a temporary file); return the .oso text."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"{name}.osl")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text + "\n")
        return compile_file(path)


def oso_shader_name(oso: str) -> str:
    """Name of the shader compiled into ``oso``."""
    for line in oso.splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0] in ("shader", "surface", "displacement", "volume"):
            return parts[1]
    raise ValueError("oso: no shader line")


def oso_params(oso: str) -> dict:
    """Parameters of the compiled shader: name -> (``"param"`` | ``"oparam"``, type), in socket order."""
    out = {}
    for line in oso.splitlines():
        cols = line.split("\t")
        if cols[0] in ("param", "oparam") and len(cols) >= 3:
            out[cols[2]] = (cols[0], cols[1])
    return out


def oso_symbols(oso: str) -> set:
    """Names of the local variables, constants' string values and called functions in ``oso``
    (what the preprocessor kept), e.g. ``"L0_W"`` or ``"disk_overlap"``."""
    names = set()
    for line in oso.splitlines():
        cols = line.split("\t")
        if cols[0] in ("local", "temp", "param", "oparam", "global") and len(cols) >= 3:
            names.add(cols[2].split("___")[-1].split("_", 1)[-1] if cols[2].startswith("___") else cols[2])
        elif cols[0] == "const" and len(cols) >= 4 and cols[3].startswith('"'):
            names.add(cols[3].strip('"'))
    return names
