"""Explicit-geometry ground truth for measured-microgeometry materials (Dong et al. 2015, §5.1):
the height field smoothed by the §5.1 sigma filter (``precompute.microgeometry.heightfield.smoothed_heights``)
as a triangulated, flat-shaded mirror tile, instanced n_x x n_y times on the plane (one mesh, Cycles
instances), seen by an orthographic camera under the direction-coded worlds of ``biscale_truth`` /
``bench/scratch_truth``.  The image mean is then a moment of where light leaves the real surface.
Used by ``bench/microgeometry_truth`` and ``tests/microgeometry/test_ndf_truth.py``.
"""
from __future__ import annotations

import bpy
import numpy as np

from . import render
from .materials import new_material

__all__ = ["mirror_material", "heightfield_tiles"]

#: Most instances of one tile (memory stays bounded: instances share the mesh).
MAX_INSTANCES = 250_000


def mirror_material(name: str = "Truth mirror") -> bpy.types.Material:
    """A lossless mirror: Glossy BSDF, GGX roughness 0, colour 1."""
    m = new_material(name)
    tree = m.node_tree
    g = tree.nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "GGX"
    g.inputs["Roughness"].default_value = 0.0
    g.inputs["Color"].default_value = (1, 1, 1, 1)
    tree.links.new(g.outputs["BSDF"], tree.nodes["Material Output"].inputs["Surface"])
    return m


def _tile_mesh(heights_um, pixel_um: float, scale: float, name: str):
    """Flat-shaded triangle mesh of one periodic tile: (N+1) x (M+1) vertices (the wrap row / column
    repeats the first, so tiles join without a seam), x along columns, y along rows, z = height, all
    lengths in µm times ``scale`` (metres per µm)."""
    h = np.asarray(heights_um, np.float64)
    ny, nx = h.shape
    hw = np.pad(h, ((0, 1), (0, 1)), mode="wrap")
    J, I = np.meshgrid(np.arange(ny + 1), np.arange(nx + 1), indexing="ij")
    V = np.stack([I * pixel_um, J * pixel_um, hw], -1).reshape(-1, 3) * scale
    idx = (J * (nx + 1) + I)[:-1, :-1].ravel()
    a, b, c, d = idx, idx + 1, idx + nx + 1, idx + nx + 2
    F = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])   # counter-clockwise: normals up
    mesh = render.flat_triangle_mesh(name, V, F)   # facets: the surface itself
    mesh.validate()
    return mesh


def heightfield_tiles(scene, heights_um, pixel_um: float, n_x: int, n_y: int, period_m: float,
                      material=None, name: str = "Height field tiles"):
    """The periodic height field ``heights_um`` (µm, rows = y) as n_x x n_y instanced tiles centred at the
    origin, one tile ``period_m`` metres wide along x (heights scaled alike: slopes are kept); x of the
    height field along world x.  Returns the instancer object."""
    if not all(isinstance(n, int) and n >= 1 for n in (n_x, n_y)) or n_x * n_y > MAX_INSTANCES:
        raise ValueError(f"n_x, n_y: expected positive integers with n_x n_y <= {MAX_INSTANCES}, got {n_x!r}, {n_y!r}")
    h = np.asarray(heights_um, np.float64)
    ny, nx = h.shape
    scale = period_m / (nx * pixel_um)
    mesh = _tile_mesh(h - h.mean(), pixel_um, scale, f"{name} tile")
    mesh.materials.append(material if material is not None else mirror_material())
    tile = bpy.data.objects.new(f"{name} tile", mesh)
    py = ny * pixel_um * scale
    ix, iy = np.meshgrid(np.arange(n_x) - n_x / 2, np.arange(n_y) - n_y / 2, indexing="ij")
    P = np.stack([ix.ravel() * period_m, iy.ravel() * py, np.zeros(ix.size)], -1)
    pts = bpy.data.meshes.new(f"{name} points")
    pts.vertices.add(len(P))
    pts.vertices.foreach_set("co", P.astype(np.float32).ravel())
    pts.update()
    inst = bpy.data.objects.new(name, pts)
    inst.instance_type = "VERTS"
    scene.collection.objects.link(inst)
    scene.collection.objects.link(tile)
    tile.parent = inst
    return inst
