"""Extension root package: Blender loads this folder as ``bl_ext.<repo>.scratch_addon``.

Every module below imports its siblings relatively (``from ..precompute.scratch import brdf``), so the
whole extension has one import identity rooted here.  TD scripts get the same package as
``scratch_materials`` (see ``scratch_materials.py``).  ``register``/``unregister`` import the Blender
glue on first use, so the science (``precompute``) stays importable without bpy.
"""


def register() -> None:
    from .scratch_addon import register as _register

    _register()


def unregister() -> None:
    from .scratch_addon import unregister as _unregister

    _unregister()
