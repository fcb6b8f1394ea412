"""The README demo (``make demo``, issue 15 item 7): individual scratches near the camera, a sheen far away.

Independent reference: the camera geometry.  A pixel's ray footprint on the floor (Cycles' isotropic ray
differential: radius t θ_pix at distance t, stretched 1 / cos along the view, osl/scratch_layer_alpha.h) against
the preset's scratch width w and length l in UV units: the OSL path resolves single scratches (binary α, fade 0)
where the footprint's longest axis spans less than 0.2 of a cell across, and averages every layer (far field)
where r_uv max(1/l, 1/w) >= 0.8 sqrt(2).  A demo whose floor is all far field (1 m per UV unit: the previous
demo) shows no individual scratch anywhere.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy]


def _footprint_uv(scene, plane, row: float):
    """(r_uv, cos_v) of the centre-column pixel at ``row`` (0 bottom, 1 top of the frame) on the floor z = 0."""
    cam = scene.camera
    w, h = 640, 480
    sensor = cam.data.sensor_width
    half_w = 0.5 * sensor / cam.data.lens
    theta_pix = 2.0 * half_w / w
    y_ndc = (row - 0.5) * 2.0 * half_w * h / w
    m = np.array(cam.matrix_world)
    d = m[:3, :3] @ np.array([0.0, y_ndc, -1.0])
    o = m[:3, 3]
    t = -o[2] / d[2]
    assert t > 0, "the pixel does not see the floor"
    dist = t * np.linalg.norm(d)
    cos_v = abs(d[2]) / np.linalg.norm(d)
    # metres per UV unit from the floor mesh
    mesh = plane.data
    uv = mesh.uv_layers.active.data
    loop = mesh.loops
    v0, v1 = mesh.vertices[loop[0].vertex_index].co, mesh.vertices[loop[1].vertex_index].co
    uv_size = (v1 - v0).length / (np.linalg.norm(np.array(uv[1].uv) - np.array(uv[0].uv)))
    pix = dist * theta_pix / math.sqrt(1.0 + y_ndc ** 2)   # the pixel's angular size shrinks off-axis
    return pix / uv_size, cos_v


def test_demo_resolves_scratches_near_and_averages_them_far(addon, scene):
    import bpy

    s = addon.api.demo_scene("demo", layout="highlights")
    bpy.context.view_layer.update()   # the camera's matrix_world
    p = addon.presets.get("demo").params["layers"]
    plane = next(o for o in s.objects if o.type == "MESH")
    r_near, cos_near = _footprint_uv(s, plane, 0.02)
    assert r_near / cos_near / p["width"] < 0.2, "no individual scratch near the camera"
    r_far, _ = _footprint_uv(s, plane, 0.78)   # just below the horizon (row 0.80)
    assert r_far * max(1.0 / p["length"], 1.0 / p["width"]) >= 0.8 * math.sqrt(2.0), "no far-field sheen"
    lights = [o for o in s.objects if o.type == "LIGHT"]
    assert len(lights) == 1 and lights[0].data.type == "POINT" and lights[0].data.shadow_soft_size <= 0.2
