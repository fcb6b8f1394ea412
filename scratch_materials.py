"""TD entry point: the extension root package for scripts that run outside an installed extension.

    import sys; sys.path.insert(0, "/path/to/this/repo")
    import scratch_materials as sm
    sm.register()                                   # optional: operators, panels, material settings
    from scratch_materials.scratch_addon import api
    from scratch_materials.precompute.scratch import profiles

This module *is* the repository's root package (it sets ``__path__`` to the repository folder), so
``scratch_materials.precompute``, ``.osl``, ``.node_groups`` and ``.scratch_addon`` are the same
modules Blender loads as ``bl_ext.<repo>.scratch_addon.*``, reached by the same relative imports.
One name per module in a process: import the science through ``scratch_materials.precompute`` too
when you pass its objects to the API.  (``import precompute`` still works as a plain numpy library.)
"""
import os as _os

__path__ = [_os.path.dirname(_os.path.abspath(__file__))]
__package__ = __name__  # relative imports below resolve inside this package


from .__init__ import register, unregister  # noqa: E402,F401 - the root's entry points (bpy on first call)
