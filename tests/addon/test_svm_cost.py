"""The SVM scratch twin's cheaper graph (issue 15 item 4): what was folded into the table images is exact.

Cycles' SVM runs one instruction per node plus one per unlinked input a node reads (bench/scratch_svm_profile:
a Math node with a constant operand ~83 instructions per shading point, a Voronoi ~770), so constants that only
depend on the table moved into the C image.  Oracles: the lobe tilt the shader now computes from the C image
(R + G ξ + B φo, two Math nodes) equals, for every bin of every φo node, the tilt written from the lobe table's
own quantities (exit centroid, spread, bounce parity, node angle: the formula of ``_table_lobe``'s docstring,
(exit + φo) / 2); and the rebuilt graph renders the OSL path's image mean (tests/scratch/test_scratch_svm.py
holds that within 3 %).
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest

pytestmark = [pytest.mark.bpy]


def _mods(addon):
    root = addon.__name__.rpartition(".")[0]
    return (importlib.import_module(root + ".precompute.scratch.material"),
            importlib.import_module(root + ".node_groups.scratch_svm"))


@pytest.mark.parametrize("fresnel", [None, "iron"], ids=["lossless", "iron"])
def test_c_image_tilt_equals_the_table_tilt(addon, fresnel):
    material, svm = _mods(addon)
    params = material.validate(profile=("quartic", 0.4), fresnel=fresnel, layers=None, backend="svm", resolution=64,
                               slices=16)
    data = material.tables(params)["svm_lobes"]
    img = svm.table_images("tilt-check", data)["C"]
    S, M = data["cdf"].shape[0], data["cdf"].shape[1] - 1
    assert img.depth == 96                                  # RGB: the shader reads no alpha
    c = np.array(img.pixels[:], np.float64).reshape(S, M, 4)
    phi_s = np.asarray(data["phi"], np.float64)[:, None]    # node angle φ_s
    code = np.asarray(data["cen"], np.float64)              # exit centroid in the bin (+2 for even bounces)
    even = code > 1.5
    cen = code - 2.0 * even
    half = np.minimum(cen, 1.0 - cen)
    sigma = np.where(even, -1.0, 1.0)
    rng = np.random.default_rng(7)
    for _ in range(4):
        xi = rng.random((S, M))
        phi_o = rng.uniform(-np.pi / 2, np.pi / 2, (S, M))
        # the exit direction of the lobe (odd bounces mirror-like: φ_s - φo added; even: subtracted) and the
        # tilt halfway between view and exit
        aim = (np.arange(M) + cen + (2 * xi - 1) * half) * np.pi / M - np.pi / 2
        exit_dir = aim + sigma * (phi_s - phi_o)
        want = 0.5 * (exit_dir + phi_o)
        got = c[..., 0] + c[..., 1] * xi + c[..., 2] * phi_o
        np.testing.assert_allclose(got, want, atol=2e-6)     # float32 image, |tilt| <= ~2 rad
    # a broken fold (the φo weight of odd bounces) is seen
    bad = c[..., 0] + c[..., 1] * xi + (c[..., 2] + 0.5 * (sigma > 0)) * phi_o
    assert np.abs(bad - want).max() > 0.1


def test_table_lobe_math_nodes(addon, scene):
    """The table lobe of a dense lossy material builds 17 Math nodes when its bins have their own θo coefficients
    (19 when grouped) and looks the one-row N image up without a Combine XYZ."""
    material, svm = _mods(addon)
    params = material.validate(profile=("quartic", 0.4), fresnel="iron", layers=None, backend="svm", resolution=64,
                               slices=16)
    data = material.tables(params)["svm_lobes"]
    mat = addon.materials.new_material("cost-count")
    before = set(mat.node_tree.nodes)
    svm.build(mat.node_tree, data, None, None, None, name="cost-count")
    new = [n for n in mat.node_tree.nodes if n not in before]
    n_math = sum(1 for n in new if n.bl_idname == "ShaderNodeMath")
    yg = int(data.get("y_group", 1))
    # table lobe (17 or 19) + the dense path's own (φo: arctan2)
    assert n_math == (17 if yg == 1 else 19) + 1, (n_math, yg)
    n_img = [n for n in new if n.bl_idname == "ShaderNodeTexImage" and n.image.name.startswith(svm.TABLE_IMAGE_PREFIX + "N")]
    assert len(n_img) == 1 and n_img[0].inputs["Vector"].links[0].from_node.bl_idname == "ShaderNodeMath"
