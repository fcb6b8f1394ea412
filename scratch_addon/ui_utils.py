"""Small helpers shared by the operators: progress reporting, material assignment, polls."""
from __future__ import annotations

import contextlib

from . import render_paths


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
