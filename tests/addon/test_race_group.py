"""The layer race (node_groups.scratch_svm._layer_race) as instances of one node group per material.

A copy of the lobe graph per race position made Fig. 1d's 32 layers 1,795 nodes: Blender's cost of adding a
node grows with the tree, so it took ~27 s CPU to build and ~160 s to rebuild.  The group renders the same
graph (Cycles inlines groups at sync; checked pixel for pixel against the copies when the change was made,
16 and 32 layers).  Oracles here: every position uses the one group, the tree stays small, an in-place table
edit of one of two materials sharing the group (Material.copy) leaves the other's group as it was, and edits
and rebuilds leave exactly one group, named after the material.
"""
from __future__ import annotations

import numpy as np

#: Fig. 1d's 32 layers: a race (scratch_svm.races) on the Cycles twin
MAT = dict(resolution=64, profile=("quartic", 0.08),
           layers=dict(n_layers=32, theta_deg=360.0, length=0.3, width=3e-4, density=0.2))


def _race_nodes(addon, mat):
    svm = addon.scratch_material.scratch_svm
    return [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None
            and n.node_tree.get(svm.RACE_GROUP)]


def test_race_positions_share_one_group_and_the_tree_stays_small(addon, scene):
    mat = addon.api.make_scratched_material("demo", **MAT)
    nodes = _race_nodes(addon, mat)
    assert len(nodes) == 32
    assert len({n.node_tree.as_pointer() for n in nodes}) == 1
    assert sorted(n.inputs["Position"].default_value for n in nodes) == list(range(32))
    # a copy of the lobe graph per position made 1,795 nodes (a minute to build): now the positions are group nodes
    assert len(mat.node_tree.nodes) < 400, len(mat.node_tree.nodes)


def test_table_edit_of_a_copy_leaves_the_original_group(addon, scene):
    import bpy

    mat = addon.api.make_scratched_material("demo", **MAT)
    other = mat.copy()
    grp = _race_nodes(addon, other)[0].node_tree
    assert _race_nodes(addon, mat)[0].node_tree == grp       # Material.copy shares node groups
    images = sorted(n.image.name for n in grp.nodes if n.bl_idname == "ShaderNodeTexImage")
    mat.scratch.profile_value = 0.3                           # a table edit, in place
    assert addon.live.last_update()["kind"] == "tables"
    mine = _race_nodes(addon, mat)[0].node_tree
    assert mine != grp and all(n.node_tree == mine for n in _race_nodes(addon, mat))
    assert sorted(n.image.name for n in grp.nodes if n.bl_idname == "ShaderNodeTexImage") == images
    assert sorted(n.image.name for n in mine.nodes if n.bl_idname == "ShaderNodeTexImage") != images
    assert all(n.node_tree == grp for n in _race_nodes(addon, other))
    assert grp.name in bpy.data.node_groups


def test_rebuild_and_edits_leave_one_group_named_after_the_material(addon, scene):
    import bpy

    mat = addon.api.make_scratched_material("demo", **MAT)
    mat.scratch.profile_value = 0.3          # in place: a copy replaces the group
    mat.scratch.base_type = "glossy"         # structure: rebuilt
    groups = [g.name for g in bpy.data.node_groups if g.get(addon.scratch_material.scratch_svm.RACE_GROUP)]
    assert groups == [f"{mat.name}.scratch race"], groups
    assert np.all([n.node_tree.name == groups[0] for n in _race_nodes(addon, mat)])
