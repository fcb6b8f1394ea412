"""Nothing lost: material (re)builds that leave the material exactly as it was when they fail.

``rebuild(material)`` wraps the part of a builder that touches a material's node tree.  Everything
that can fail without touching the material (validation, tables, shader sources) runs before it.
Inside it the builder adds its new nodes *next to* the old ones:

- on success with ``replace=True`` the old nodes are removed, so the new nodes replace the tree;
  with ``replace=False`` (a builder that edits the tree in place, e.g. inserting a layer) the old
  nodes stay;
- on any exception, KeyboardInterrupt included, the new nodes and the Text / Image / node-group
  datablocks created meanwhile are removed, and the old nodes' names, settings, socket values,
  custom properties, links, scripts (text and bytecode) and the material's custom properties and
  Cycles settings are restored; the exception propagates.

Why not build into a temporary material and copy it over: Blender has no API to move nodes between
trees nor to assign a material's (embedded) node tree, and swapping the whole material
(``user_remap``) would invalidate the caller's reference (``api.make_scratched_material(material=mat)``
returns ``mat``).  Keeping the old nodes until the new ones are complete (OSL compiled) costs no
second compile and no copy.  For ``replace=True`` the old nodes and the datablocks the builder
names after the material (``<material>.scratch.osl``, ``<material>.table.C``, ...) are renamed out of
the way first, so the builder sees a free namespace and finds, creates and names exactly what it
would in an empty tree.

``new_datablocks()`` is the same promise for builders that create a new material (bi-scale bake,
material from height field): on failure every material, image, text and node group created inside
it is removed.
"""
from __future__ import annotations

import contextlib

import bpy

_ASIDE = "~rebuild{}"
_SKIP_PROPS = {"rna_type", "name", "location_absolute", "select", "is_active_output", "dimensions"}


def _plain(value):
    """A comparable, detached copy of an RNA / ID property value."""
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if hasattr(value, "to_list"):
        return value.to_list()
    if isinstance(value, (str, bytes, int, float, bool)) or value is None:
        return value
    if isinstance(value, bpy.types.bpy_struct):
        return value  # pointers compare by identity
    try:
        return tuple(_plain(v) for v in value)
    except TypeError:
        return value


#: RNA type -> identifiers of its writable, non-collection properties (walking ``bl_rna.properties`` is most of
#: a snapshot's cost: a live table edit snapshots ~400 nodes; keyed with the property count, which changes when
#: an add-on registers properties on the type)
_PROP_IDS: dict = {}


def _prop_ids(rna) -> tuple:
    props = rna.properties
    key = (rna.identifier, len(props))
    ids = _PROP_IDS.get(key)
    if ids is None:
        ids = _PROP_IDS[key] = tuple(
            p.identifier for p in props
            if not (p.is_readonly or p.type == "COLLECTION" or p.identifier in _SKIP_PROPS
                    or p.identifier.startswith("bl_")))
    return ids


def _rna_props(struct) -> dict:
    """Writable, non-collection RNA properties of ``struct`` (settings and pointers) by identifier."""
    out = {}
    for identifier in _prop_ids(struct.bl_rna):
        try:
            out[identifier] = _plain(getattr(struct, identifier))
        except (AttributeError, TypeError):
            continue
    return out


def _restore_props(struct, saved: dict) -> None:
    for key, value in saved.items():
        try:
            if _plain(getattr(struct, key)) != value:
                setattr(struct, key, value)
        except (AttributeError, TypeError, ValueError, RuntimeError):
            continue


def _custom(idprops) -> dict:
    return {k: _plain(idprops[k]) for k in idprops.keys()}


def _restore_custom(idprops, saved: dict) -> None:
    for k in [k for k in idprops.keys() if k not in saved]:
        del idprops[k]
    for k, v in saved.items():
        if k not in idprops or _plain(idprops[k]) != v:
            idprops[k] = v


def _sockets(sockets) -> dict:
    out = {}
    for s in sockets:
        if hasattr(s, "default_value"):
            out[s.identifier] = _plain(s.default_value)
    return out


def _links(tree) -> set:
    return {(lk.from_node.as_pointer(), lk.from_socket.identifier, lk.to_node.as_pointer(), lk.to_socket.identifier,
             lk.is_muted) for lk in tree.links}


#: name prefixes of the datablocks builders share between materials by content hash
#: (``scratch_material.shader_text_name``, ``node_groups.scratch_svm.table_images``, ``scratch_material.shader_group``)
SHARED_PREFIXES = ("scratch_svbrdf.", "Scratch table ", "Scratch OSL ")
#: custom property of the per-material node groups an in-place update replaces by a copy
#: (``node_groups.scratch_svm.race_group``): dropped at commit when nothing uses them any more
_PER_MATERIAL_GROUP = "scratch_race_group"


def _shared(db) -> bool:
    return db.name.startswith(SHARED_PREFIXES) or bool(isinstance(db, bpy.types.NodeTree) and db.get(_PER_MATERIAL_GROUP))


def _shared_used(n) -> list:
    """The shared datablocks node ``n`` uses: its Text or Image, or a shared shader group and the Text in it
    (group first: dropping it can leave the Text unused)."""
    if n.bl_idname == "ShaderNodeScript":
        return [n.script]
    if n.bl_idname == "ShaderNodeTexImage":
        return [n.image]
    if n.bl_idname == "ShaderNodeGroup" and n.node_tree is not None and _shared(n.node_tree):
        return [n.node_tree] + [m.script for m in n.node_tree.nodes if m.bl_idname == "ShaderNodeScript"] + \
            [m.image for m in n.node_tree.nodes if m.bl_idname == "ShaderNodeTexImage" and m.image is not None]
    return []


def _owned(material, nodes) -> list:
    """Text, Image and node-group datablocks used by ``nodes`` and named after ``material`` (what a builder
    may look up by name and overwrite)."""
    prefix = material.name + "."
    out = []
    kinds = {"ShaderNodeScript": "script", "ShaderNodeTexImage": "image", "ShaderNodeGroup": "node_tree"}
    for n in nodes:
        db = getattr(n, kinds[n.bl_idname], None) if n.bl_idname in kinds else None
        if db is not None and db.name.startswith(prefix) and db not in out:
            out.append(db)
    return out


def _datablocks():
    return {kind: {db.as_pointer() for db in getattr(bpy.data, kind)}
            for kind in ("materials", "texts", "images", "node_groups")}


def _remove_new(before: dict) -> None:
    """Remove datablocks created since ``before`` (materials first: they use the others)."""
    for kind in ("materials", "node_groups", "images", "texts"):
        coll = getattr(bpy.data, kind)
        for _ in range(4):  # node groups may use each other: repeat until nothing is removable
            new = [db for db in coll if db.as_pointer() not in before[kind]]
            gone = 0
            for db in new:
                if kind == "materials" or db.users <= int(db.use_fake_user):
                    coll.remove(db)
                    gone += 1
            if not gone:
                break


class _State:
    """What ``rebuild`` restores: the material's settings and every node of its tree as they were."""

    def __init__(self, material, replace: bool):
        self.material = material
        self.tree = material.node_tree
        self.replace = replace
        self.custom = _custom(material)
        self.cycles = _rna_props(material.cycles) if hasattr(material, "cycles") else {}
        self.nodes = list(self.tree.nodes)
        self.pointers = {n.as_pointer() for n in self.nodes}
        self.names = [n.name for n in self.nodes]
        self.node_state = [(_rna_props(n), _custom(n), _sockets(n.inputs), _sockets(n.outputs),
                            [s.identifier for s in n.inputs], getattr(n, "is_active_output", None)) for n in self.nodes]
        self.scripts = {n.as_pointer(): (n.script.as_string(), n.bytecode, n.bytecode_hash, n.script)
                        for n in self.nodes if n.bl_idname == "ShaderNodeScript" and n.script is not None}
        # shared, content-hashed datablocks the nodes use now (dropped at commit when nothing uses them any more)
        self.shared = [db for n in self.nodes for db in _shared_used(n) if db is not None and _shared(db)]
        self.links = _links(self.tree)
        self.owned = [(db, db.name) for db in _owned(material, self.nodes)] if replace else []
        self.data = _datablocks()

    def move_aside(self) -> None:
        for i, node in enumerate(self.nodes):
            node.name = _ASIDE.format(i)
        for i, (db, _name) in enumerate(self.owned):
            db.name = _ASIDE.format(i) + db.name

    def commit(self) -> None:
        if self.replace:
            for node in self.nodes:
                self.tree.nodes.remove(node)
        removed, owned = set(), [(db.as_pointer(), db, name) for db, name in self.owned]
        for db in dict.fromkeys(self.shared):   # a shader text / table image no material uses any more
            if db.users <= int(db.use_fake_user):
                removed.add(db.as_pointer())
                self._collection(db).remove(db)
        for ptr, db, name in owned:
            if ptr in removed:   # (a per-material group is both)
                continue
            taken = self._collection(db).get(name)
            if taken is not None and taken != db and db.users <= int(db.use_fake_user):
                self._collection(db).remove(db)  # replaced by the builder's new one
            else:
                db.name = name  # still used elsewhere: back under its name (Blender adds .001 if taken)

    def rollback(self) -> None:
        tree = self.tree
        for node in [n for n in tree.nodes if n.as_pointer() not in self.pointers]:
            tree.nodes.remove(node)
        _remove_new(self.data)
        for db, name in self.owned:
            db.name = name
        for node, name in zip(self.nodes, self.names):
            if node.name != name:
                node.name = name
        for node, (props, custom, ins, outs, in_ids, active) in zip(self.nodes, self.node_state):
            script = self.scripts.get(node.as_pointer())
            if script is not None:
                self._restore_script(node, script, in_ids)
            _restore_props(node, props)
            _restore_custom(node, custom)
            for sockets, saved in ((node.inputs, ins), (node.outputs, outs)):
                for s in sockets:
                    if s.identifier in saved and _plain(s.default_value) != saved[s.identifier]:
                        s.default_value = saved[s.identifier]
            if active is not None and node.is_active_output != active:
                node.is_active_output = active
        by_ptr = {n.as_pointer(): n for n in self.nodes}
        now = _links(tree)
        for lk in list(tree.links):
            key = (lk.from_node.as_pointer(), lk.from_socket.identifier, lk.to_node.as_pointer(),
                   lk.to_socket.identifier, lk.is_muted)
            if key not in self.links:
                tree.links.remove(lk)
        for fn, fs, tn, ts, muted in self.links - now:
            src = next((s for s in by_ptr[fn].outputs if s.identifier == fs), None)
            dst = next((s for s in by_ptr[tn].inputs if s.identifier == ts), None)
            if src is not None and dst is not None:
                tree.links.new(src, dst).is_muted = muted
        _restore_custom(self.material, self.custom)
        if self.cycles:
            _restore_props(self.material.cycles, self.cycles)
        # datablocks an in-place update created and pointed kept nodes at (table images, shader texts): unused
        # only now that those nodes point back at the old ones
        _remove_new(self.data)

    @staticmethod
    def _collection(db):
        if isinstance(db, bpy.types.NodeTree):
            return bpy.data.node_groups
        return bpy.data.texts if isinstance(db, bpy.types.Text) else bpy.data.images

    @staticmethod
    def _restore_script(node, saved, in_ids) -> None:
        text, bytecode, bytecode_hash, datablock = saved
        if node.script != datablock:   # repointed to another (shared) Text: point back, never rewrite a shared one
            node.script = datablock
        if node.script is not None and node.script.as_string() != text:
            node.script.clear()
            node.script.write(text)
        if node.bytecode == bytecode and [s.identifier for s in node.inputs] == in_ids:
            return
        try:  # the sockets follow the compiled source: compile the old source again
            from . import osl_compile

            osl_compile.compile_script_node(node)
        except Exception:  # noqa: BLE001 - best effort; the bytecode below is what renders
            pass
        node.bytecode, node.bytecode_hash = bytecode, bytecode_hash


@contextlib.contextmanager
def rebuild(material, replace: bool = True):
    """Run a builder's tree edits as one transaction on ``material`` (see the module docstring); yields
    the node tree."""
    from .materials import ensure_nodes

    ensure_nodes(material)
    state = _State(material, replace)
    try:
        if replace:
            state.move_aside()
        yield material.node_tree
    except BaseException:
        state.rollback()
        raise
    state.commit()


@contextlib.contextmanager
def new_datablocks():
    """Remove every material, image, text and node group created inside the block if it fails."""
    before = _datablocks()
    try:
        yield
    except BaseException:
        _remove_new(before)
        raise
