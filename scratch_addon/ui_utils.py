"""Small helpers shared by the operators: progress reporting, error and warning reports, material
assignment, polls."""
from __future__ import annotations

import contextlib
import re
import warnings

from ..precompute.tables import files
from . import osl_compile, render_paths

#: What an operator reports instead of raising: bad input (ValueError), file-system faults (OSError:
#: permission, full disk, a path through a file ...) and OSL compile errors.
USER_ERRORS = (ValueError, OSError, osl_compile.OSLCompileError)


def error_line(exc: BaseException) -> str:
    """One line for the operator report (no traceback, no errno); an OSL compile error keeps its first
    compiler message."""
    if isinstance(exc, OSError):
        return files.one_line(exc)
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    if not lines:
        return type(exc).__name__
    return lines[0] if len(lines) == 1 else f"{lines[0]} {lines[1]}"


def op_labels(op, **aliases) -> dict:
    """Parameter names an error message may use -> what the user sees in ``op``'s panel: each operator
    property's identifier -> its UI name, plus ``aliases`` (names of inner functions' parameters that an
    operator property feeds, e.g. ``length="Height"`` for a rods tile)."""
    labels = {p.identifier: p.name for p in op.properties.bl_rna.properties if p.identifier != "rna_type" and p.name}
    labels.update(aliases)
    return labels


def relabel(line: str, labels: dict) -> str:
    """``line`` with the parameter names of ``labels`` replaced by their user-facing labels: a name with an
    underscore (``dir_res``) wherever it stands as a word, a plain word (``height``) only where it leads
    the message as ``height: ...`` (so ``no image named ...`` keeps its words)."""
    for name in sorted(labels, key=len, reverse=True):
        label = labels[name]
        if "_" in name:
            line = re.sub(rf"(?<![\w.']){re.escape(name)}(?![\w'])", lambda _m: label, line)
        else:
            line = re.sub(rf"^{re.escape(name)}(?=:)", lambda _m: label, line)
    return line


def report_error(op, exc: BaseException, labels: dict | None = None) -> set:
    """Report ``exc`` as one ERROR line (parameter names turned into ``labels``, see ``op_labels``);
    returns ``{"CANCELLED"}`` for ``execute`` to return."""
    line = error_line(exc)
    op.report({"ERROR"}, relabel(line, labels) if labels else line)
    return {"CANCELLED"}


@contextlib.contextmanager
def reported_warnings(op):
    """Report user-facing warnings raised inside the block (``UserWarning``s: an unusable cache folder,
    a cache file recomputed, ...) as WARNING lines of ``op``, each once; other warnings (numpy's
    RuntimeWarnings, deprecations) go to the console as before."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            seen = set()
            for w in caught:
                if not issubclass(w.category, UserWarning):
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
                    continue
                line = " ".join(str(w.message).split())
                if line not in seen:
                    seen.add(line)
                    op.report({"WARNING"}, line)


@contextlib.contextmanager
def progress(context, total: int = 100):
    """``wm.progress_begin/update/end`` around a block (harmless headless); yields ``update(fraction)``."""
    wm = context.window_manager
    wm.progress_begin(0, total)
    try:
        yield lambda fraction: wm.progress_update(int(total * fraction))
    finally:
        wm.progress_end()


def assign_material(obj, material) -> None:
    """Put ``material`` in the object's active slot (or a new slot)."""
    if obj.data.materials:
        obj.data.materials[obj.active_material_index] = material
    else:
        obj.data.materials.append(material)


def poll_active_mesh(cls, context, message: str = "Select a mesh object") -> bool:
    """Operator poll: the active object must be a mesh (shows ``message`` otherwise)."""
    obj = context.active_object
    if obj is None or obj.type != "MESH":
        cls.poll_message_set(message)
        return False
    return True


def report_render_path(op, material, scene) -> None:
    """Tell the user, in the operator's report, which path renders ``material`` in ``scene`` (a warning
    when the OSL part of it cannot render there)."""
    icon, line = render_paths.describe(material, scene)
    op.report({"INFO"} if icon == "CHECKMARK" else {"WARNING"}, f"{material.name}: {line}")


def draw_render_path(layout, material, scene) -> None:
    """One panel line saying which path renders ``material`` and why, with a button to render with OSL."""
    icon, line = render_paths.describe(material, scene)
    row = layout.row()
    row.label(text=line, icon=icon)
    if render_paths.has_osl(material) and not render_paths.render_path.osl_renders(scene):
        row.operator("scratch.use_osl", text="Use OSL", icon="SCRIPT")
