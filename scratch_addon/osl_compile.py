"""Compile OSL script nodes headless (no node editor needed).

Blender's ``bpy.ops.node.shader_script_update`` needs a node-editor context, so we
call Cycles' own ``cycles.osl.update_script_node`` instead.  That function imports
``oslquery``, which the PyPI bpy wheel ships in ``bpy/<ver>/python/lib/python3.11/
site-packages`` without putting it on ``sys.path``: ``ensure_oslquery()`` adds it.
"""
from __future__ import annotations

import contextlib
import glob
import os
import sys
import tempfile
import threading

import bpy


class OSLCompileError(RuntimeError):
    """The OSL source failed to compile; the message carries the compiler output."""


def _cycles_needs_oslquery() -> bool:
    """Blender >= 4.3 reads a compiled shader's parameters with the ``oslquery`` module; 4.2's
    ``cycles.osl`` asks ``_cycles.osl_update_node`` instead (its wheel ships no ``oslquery``)."""
    import inspect

    import cycles.osl  # Cycles' own add-on module, always present in bpy

    try:
        return "oslquery" in inspect.getsource(cycles.osl)
    except (OSError, TypeError):
        return True


def ensure_oslquery() -> None:
    """Make ``import oslquery`` work where Cycles needs it (no-op when it already does)."""
    try:
        import oslquery  # noqa: F401
        return
    except ImportError:
        pass
    candidates = []
    for base in {os.path.dirname(os.path.abspath(bpy.__file__)), os.path.dirname(bpy.app.binary_path or "")}:
        for up in (base, os.path.dirname(base), os.path.dirname(os.path.dirname(base)),
                   os.path.dirname(os.path.dirname(os.path.dirname(base)))):
            candidates += glob.glob(os.path.join(up, "*", "python", "lib", "python3*", "site-packages"))
            candidates += glob.glob(os.path.join(up, "python", "lib", "python3*", "site-packages"))
    for folder in candidates:
        if os.path.isdir(os.path.join(folder, "oslquery")) and folder not in sys.path:
            sys.path.append(folder)
            return
    if _cycles_needs_oslquery():
        raise OSLCompileError("cannot find the 'oslquery' module shipped with Blender; OSL script nodes cannot be compiled")


@contextlib.contextmanager
def _captured_stderr():
    """Capture the OSL compiler's messages (written by C++ straight to file descriptor 2)."""
    lines: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no usable stderr: compile without capturing
        yield lambda: lines
        return
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        sys.stderr.flush()
        os.dup2(tmp.fileno(), 2)
        try:
            yield lambda: lines
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text = tmp.read().decode(errors="replace")
            lines.extend(text.splitlines())
            if text:
                sys.stderr.write(text)  # still show it


# ------------------------------------------------------------------ compiling ahead (live edits, issue 18)
#: .oso bytecode of sources compiled ahead (``precompile``), by a hash of the text Cycles compiles; bounded
_PRECOMPILED: dict = {}
_PRECOMPILED_MAX = 16
_INFLIGHT: dict = {}     # text hash -> future of a precompile under way
_COMPILER = None         # one background thread: one OSL compile at a time
_LOCK = threading.Lock()
_COMPILE_LOCK = threading.Lock()   # never two OSL compiles at once (the compiler's thread safety)


def _text_key(text: str) -> str:
    import hashlib

    return hashlib.sha1(text.encode()).hexdigest()


def _compile_text(text: str) -> str | None:
    import _cycles

    with tempfile.TemporaryDirectory(prefix="scratch_osl_") as d:
        src, out = os.path.join(d, "shader.osl"), os.path.join(d, "shader.oso")
        with open(src, "w", encoding="utf-8") as f:
            f.write(text)
        with _COMPILE_LOCK:
            ok = _cycles.osl_compile(src, out)
        if not ok:
            return None
        with open(out, encoding="utf-8") as f:
            return f.read()


def precompile(source: str):
    """Start compiling the OSL ``source`` of an INTERNAL script node in a background thread (Cycles' compiler
    releases the GIL; no bpy data is touched) and return its future (None when already compiled); a later
    ``compile_script_node`` of a node holding this source waits for it and uses its bytecode instead of
    compiling again.  A live edit starts it as soon as its shader text exists, so the compile runs beside the
    table images' update (``scratch_material.prepare``).  A failed compile is not remembered:
    ``compile_script_node`` compiles again and reports the errors."""
    global _COMPILER
    text = source + "\n"            # what Cycles' update_internal_script writes: the Text plus a newline
    key = _text_key(text)
    with _LOCK:
        if key in _PRECOMPILED:
            return None
        if key in _INFLIGHT:
            return _INFLIGHT[key]
        if _COMPILER is None:
            import concurrent.futures

            _COMPILER = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="scratch_osl")

        def run():
            try:
                oso = _compile_text(text)
            except Exception:  # noqa: BLE001 - compiled again (and reported) by compile_script_node
                oso = None
            with _LOCK:
                _INFLIGHT.pop(key, None)
                if oso is not None:
                    while len(_PRECOMPILED) >= _PRECOMPILED_MAX:
                        _PRECOMPILED.pop(next(iter(_PRECOMPILED)))
                    _PRECOMPILED[key] = oso
            return oso is not None

        future = _INFLIGHT[key] = _COMPILER.submit(run)
    return future


def _precompiled(input_path: str) -> str | None:
    """The bytecode compiled ahead for the .osl file ``input_path`` (waiting for a compile under way), or None."""
    try:
        with open(input_path, encoding="utf-8") as f:
            key = _text_key(f.read())
    except (OSError, UnicodeDecodeError):
        return None
    with _LOCK:
        future = _INFLIGHT.get(key)
    if future is not None:
        future.result()
    with _LOCK:
        return _PRECOMPILED.get(key)


@contextlib.contextmanager
def _using_precompiled():
    """Inside the block Cycles' ``cycles.osl.osl_compile(input_path, report)`` (which every Blender from 4.2 on
    calls to compile a script node) takes bytecode compiled ahead when there is some for that text."""
    import cycles.osl

    real = cycles.osl.osl_compile

    def osl_compile(input_path, report):
        oso = _precompiled(input_path)
        if oso is None:
            with _COMPILE_LOCK:
                return real(input_path, report)
        out = tempfile.NamedTemporaryFile(mode="w", suffix=".oso", delete=False, encoding="utf-8")
        with out:
            out.write(oso)
        report({"INFO"}, "OSL shader compilation succeeded")
        return True, out.name

    cycles.osl.osl_compile = osl_compile
    try:
        yield
    finally:
        cycles.osl.osl_compile = real


def compile_script_node(node: bpy.types.ShaderNodeScript) -> None:
    """Compile ``node`` (INTERNAL or EXTERNAL) and update its sockets; raise OSLCompileError on failure.
    Bytecode compiled ahead for the same text (``precompile``) is used instead of compiling again."""
    ensure_oslquery()
    import cycles.osl  # Cycles' own add-on module, always present in bpy

    errors: list[str] = []

    def report(kind, message):
        if "ERROR" in kind:
            errors.append(message)

    with _captured_stderr() as captured, _using_precompiled():
        ok = cycles.osl.update_script_node(node, report)
    if errors or ok is False:
        details = [ln for ln in captured() if "error" in ln.lower()]
        raise OSLCompileError(f"OSL compile of node {node.name!r} failed:\n" + "\n".join(details + errors))


def script_node_from_source(tree: bpy.types.NodeTree, name: str, source: str) -> bpy.types.ShaderNodeScript:
    """Create an INTERNAL script node whose code lives in a Text datablock (saved in the .blend)."""
    ensure_oslquery()  # assigning the script may trigger Cycles' own compile, which imports oslquery
    text = bpy.data.texts.get(name) or bpy.data.texts.new(name)
    if text.as_string() != source:  # a shared text (same name, same source) is left as it is
        text.clear()
        text.write(source)
    node = tree.nodes.new("ShaderNodeScript")
    node.mode = "INTERNAL"
    node.script = text
    compile_script_node(node)
    return node


def uv_script_node(tree: bpy.types.NodeTree, name: str, source: str) -> bpy.types.ShaderNodeScript:
    """``script_node_from_source`` plus a UV Map node (makes Cycles export the UV attributes) and a UV
    Tangent node wired into the script's Tangent input: the shape of every table shader's node."""
    ensure_oslquery()  # before the node exists: assigning its script imports oslquery in Cycles' update
    script = script_node_from_source(tree, name, source)
    script.location = (0, 300)
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.location = (-400, 450)
    tangent = tree.nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (-400, 250)
    tree.links.new(tangent.outputs["Tangent"], script.inputs["Tangent"])
    return script
