"""Fixtures shared by the bi-scale tests."""
from __future__ import annotations

import importlib

import pytest


@pytest.fixture
def bs(addon):
    import bpy

    mat = importlib.import_module(addon.__name__ + ".biscale_material")
    ops = importlib.import_module(addon.__name__ + ".biscale_ops")
    registered = []
    for c in ops.classes:
        if not hasattr(bpy.types, c.__name__):
            bpy.utils.register_class(c)
            registered.append(c)
    yield mat, ops
    for c in reversed(registered):
        bpy.utils.unregister_class(c)
