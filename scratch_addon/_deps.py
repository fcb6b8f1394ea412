"""Find the sibling packages (precompute, node_groups, osl/) in both install routes.

Installed extension: this package is ``bl_ext.<repo>.scratch_addon.scratch_addon`` and its
siblings are ``bl_ext.<repo>.scratch_addon.precompute`` etc.  Repo root on ``sys.path``
(TD scripts, tests): this package is ``scratch_addon`` and the siblings are top-level.
"""
from __future__ import annotations

import importlib
import os
from types import ModuleType

#: Add-on module name as Blender knows it (``bl_ext.<repo>.scratch_addon`` or ``scratch_addon``).
ADDON_PACKAGE = __package__.rpartition(".")[0] or __package__
_PARENT = __package__.rpartition(".")[0]

#: Repository / extension root folder (holds osl/, precompute/, ...).
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def sibling(name: str) -> ModuleType:
    """Import ``name`` (e.g. ``"precompute.cache"``) relative to the extension root."""
    return importlib.import_module(f"{_PARENT}.{name}" if _PARENT else name)


def is_extension() -> bool:
    """True when loaded as an installed Blender extension (``bl_ext.*``)."""
    return ADDON_PACKAGE.startswith("bl_ext.")
