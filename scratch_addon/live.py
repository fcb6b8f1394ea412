"""Live look-dev: every change in the Scratched Material panel updates the material as it changes.

Three kinds of panel value (``material.scratch``):

- **sockets** (``node_groups.scratch_controls.SOCKETS``: length, width, density, tint, base colour and
  roughness, diffuse colour): written straight into the "Scratch Controls" node (which feeds the OSL
  script *and* the SVM / EEVEE twins) or the base / diffuse node; no table, no shader text changes;
- **tables** (profile, Fresnel, lobe strata): new tables through the cache (``precompute.tables``), the new
  OSL source compiled into the script node and the tables written into the table images in place
  (``scratch_material.apply_tables``): no node is created;
- **structure** (layer count, orientation spread, seed, resolution, lobe shape, base / diffuse type,
  mode, backend): a full rebuild through ``api.make_scratched_material(material=...)`` (atomic:
  ``transaction.rebuild``).

In the UI, table and structure edits are debounced (``DEBOUNCE_S`` after the last change: a drag
queues one update with the last value), the tables are computed in worker threads and applied on the
main thread (the UI keeps running between the workers' numpy passes; the new shader's OSL compile, Cycles'
``_cycles.osl_compile``, holds the GIL for its ~0.1 s wherever it runs: ``bench live_update``).  On a cache miss of
table lobes quick *preview* tables (``precompute.scratch.lobes.table_lobes``, quality "preview": about a
quarter of the cost, moments within 3 %) and the full tables are submitted together (``WORKERS``
threads: with one, the full tables start as soon as the preview is computed, not after it is applied);
the preview is applied as soon as it is ready, then the full tables replace it (the material carries
``scratch_material.PREVIEW_KEY`` in between).  The exact traces behind the tables are kept per profile
as geometry (``precompute.scratch.slices.GEOMETRY_BYTES``): a metal edit, or the full tables after their
preview, re-weights directions already traced instead of tracing them again; ``TRACE_HELPER`` splits new
traces with a helper process (off: it did not pay on the loaded 2-core test machine).  Headless
(``blender -b``, tests) ``bpy.app.timers`` never fire, so edits apply synchronously, except inside
``batch()`` which applies once at its end.  ``flush()`` applies whatever is pending.

Undo/redo: Blender's memfile undo restores the settings and the node tree (tables are packed images,
the shader a Text datablock) together; an ``undo_post`` / ``redo_post`` handler re-syncs any material
whose stored table key disagrees with its settings (an undo step taken while an update was pending).
Animation: keyframed socket-valued settings are evaluated into their sockets before every frame
(``frame_change_pre``: an animation render syncs the new frame right after) and keyframed or driven ones
again after it (``frame_change_post``), so a keyframed density renders differently on two frames.  A .blend
rendered on a machine *without* the add-on keeps the sockets' saved values: keyframe the "Scratch
Controls" node's sockets themselves for a farm (they animate everywhere, except Length and Width on the SVM
twins: the layer Voronoi's texture mapping holds them, written by ``write_socket``; keyframe the panel values).
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import time
import traceback

import bpy

from ..node_groups import scratch_controls, scratch_svm
from . import scratch_material

DEBOUNCE_S = 0.15
ERROR_KEY = "scratch_live_error"
#: table key of the *settings* the material was last brought up to date with (undo: pending edits show)
SETTINGS_KEY = "scratch_live_settings_key"
SOCKET_PROPS = {s.prop for s in scratch_controls.SOCKETS}

_suspended = 0          # > 0: property updates do nothing (from_params, rebuilds writing the settings back)
_batch: list | None = None   # inside batch(): names of materials to sync at its end
_pending: dict = {}     # material name -> due time (UI debounce)
_calls: dict = {}       # key -> (due time, function): other debounced rebuilds (call_debounced)
_worker = None
_job = None             # (material name, table key, future, quality) of the running table computation
_ahead: dict = {}       # (material name, table key) -> future of the full tables, computed beside a preview
#: table computations at once.  2 computes a miss's preview and full tables side by side; on the shared
#: 2-core machine (load 30, bench live_update) that showed the preview 1.24 s after the change instead of
#: 0.74 s and the full tables no sooner (2.83 s vs 2.84 s), so one worker, the preview first
WORKERS = 1
_stats = {"last": None}  # the last applied update: kind and seconds (bench/live_update.py)


# ----------------------------------------------------------------------------- public helpers
@contextlib.contextmanager
def suspended():
    """Property writes inside the block do not update the material (used when the material is built from
    the same values)."""
    global _suspended
    _suspended += 1
    try:
        yield
    finally:
        _suspended -= 1


@contextlib.contextmanager
def batch():
    """Set many settings at once (scripts, ``blender -b``): the materials update once, at the end."""
    global _batch
    outer = _batch
    if outer is None:
        _batch = []
    try:
        yield
    finally:
        if outer is None:
            names, _batch = _batch, None
            for name in dict.fromkeys(names):
                mat = bpy.data.materials.get(name)
                if mat is not None:
                    sync(mat)


def mark_synced(material) -> None:
    """Record that ``material`` was just built from its settings (``api`` after ``from_params``)."""
    material.pop(ERROR_KEY, None)
    try:
        material[SETTINGS_KEY] = scratch_material.live_keys(_spec(material), material.name)[0]
    except Exception:  # noqa: BLE001 - settings the panel cannot express (a profile object): no record
        material.pop(SETTINGS_KEY, None)


def is_live(material) -> bool:
    """True if ``material`` is a scratch material built with live controls."""
    return (material is not None and material.get("scratch_addon_kind") == "scratch_svbrdf"
            and material.node_tree is not None and scratch_controls.NODE_NAME in material.node_tree.nodes)


def pending() -> bool:
    """True while an update waits for its debounce or its tables."""
    return bool(_pending) or bool(_calls) or _job is not None or bool(_ahead)


def last_update() -> dict | None:
    """{"kind": "sockets" | "tables" | "rebuild", "seconds": ..., "material": ...} of the last applied update."""
    return _stats["last"]


# ----------------------------------------------------------------------------- sockets
def _wanted(sock, settings) -> bool:
    if not sock.when:
        return True
    return bool(eval(sock.when, {}, {"base_type": settings.base_type, "diffuse_type": settings.diffuse_type}))  # noqa: S307


def _node_for(material, sock):
    nodes = material.node_tree.nodes
    return nodes.get({"controls": scratch_controls.NODE_NAME, "base": scratch_controls.BASE_NODE_NAME,
                      "diffuse": scratch_controls.DIFFUSE_NODE_NAME}[sock.node])


def write_socket(material, prop: str, value=None) -> bool:
    """Write setting ``prop`` of ``material.scratch`` into its socket(s) (``scratch_controls.SOCKETS``) and the
    OSL script's input of the same name; False if the material has no such socket (then it needs a rebuild)."""
    settings = material.scratch
    sock = next(s for s in scratch_controls.SOCKETS if s.prop == prop)
    if not _wanted(sock, settings):
        return True   # not used by this material's settings (e.g. base colour of a mirror base)
    node = _node_for(material, sock)
    if node is None:
        return False
    target = next((node.inputs[n] for n in sock.inputs if n in node.inputs), None)
    if target is None:
        return False
    value = getattr(settings, prop) if value is None else value
    value = value if isinstance(value, (int, float)) else tuple(value)
    scratch_controls.set_value(target, value)
    if prop in ("length", "width"):   # the SVM twins' layer texture mappings (compiled l, w: scratch_svm.set_layer_size)
        scratch_svm.set_layer_size(material.node_tree, node.inputs["Length"].default_value,
                                   node.inputs["Width"].default_value)
    if sock.osl:
        script = scratch_material.scratch_script(material)
        if script is not None and sock.osl in script.inputs:
            scratch_controls.set_value(script.inputs[sock.osl], value)   # mirrors the linked value
    return True


def write_sockets(material) -> bool:
    """Every socket-valued setting into its socket; False if one has no socket."""
    return all([write_socket(material, s.prop) for s in scratch_controls.SOCKETS])


# ----------------------------------------------------------------------------- tables / structure
def _spec(material):
    return scratch_material.validate(**material.scratch.to_params())


def sync(material, force: bool = False, prepared: dict | None = None) -> str:
    """Bring ``material`` up to date with its settings now; returns what it did: "none", "sockets", "tables"
    (in place) or "rebuild".  ``force``: full rebuild (the *Update* button).  Errors (bad settings, OSL
    compile) raise and leave the material as it was."""
    from . import api

    t0 = time.perf_counter()
    params = material.scratch.to_params()
    spec = scratch_material.validate(**params)
    table_key, _structure = scratch_material.live_keys(spec, material.name)
    kind = "none"
    if (not force and material.get(scratch_material.TABLE_KEY) == table_key and is_live(material)
            and not material.get(scratch_material.PREVIEW_KEY)):
        kind = "sockets" if _sockets_differ(material) else "none"
        write_sockets(material)
    else:
        done = False
        if not force and is_live(material):
            try:
                scratch_material.apply_tables(material, spec, prepared)
                kind, done = "tables", True
            except scratch_material.NeedsRebuild:
                pass
        if not done:
            with suspended():
                api.make_scratched_material(material=material, **params)
            kind = "rebuild"
        write_sockets(material)
    material.pop(ERROR_KEY, None)
    material[SETTINGS_KEY] = table_key
    if kind != "none":
        _stats["last"] = {"kind": kind, "seconds": time.perf_counter() - t0, "material": material.name}
    return kind


def _sockets_differ(material) -> bool:
    settings = material.scratch
    for sock in scratch_controls.SOCKETS:
        if not _wanted(sock, settings):
            continue
        node = _node_for(material, sock)
        target = None if node is None else next((node.inputs[n] for n in sock.inputs if n in node.inputs), None)
        if target is None:
            return True
        value = getattr(settings, sock.prop)
        have = target.default_value
        if isinstance(value, (int, float)):
            if abs(have - value) > 1e-7 * max(1.0, abs(value)):
                return True
        elif any(abs(a - b) > 1e-7 for a, b in zip(have, value)):
            return True
    return False


def _report(material, exc: BaseException) -> None:
    """A failed live update: the material stays as it was; the panel shows the reason."""
    from .ui_utils import error_line

    line = error_line(exc)
    if material is not None:
        material[ERROR_KEY] = line
    print(f"scratch_addon: {getattr(material, 'name', '?')} not updated: {line}")


def _background() -> bool:
    return bool(bpy.app.background)


def _trace_helper_on() -> None:
    """Live table edits trace on both cores: ``precompute.scratch.slices``' helper process (started at the first
    table edit, ended at ``unregister``; ``TRACE_HELPER`` False turns it off)."""
    from ..precompute.scratch import slices

    if TRACE_HELPER:
        slices.TRACE_HELPER = slices.start_trace_helper()     # (running already: nothing to do)


#: live edits split their exact traces with a helper process (``precompute.scratch.slices.TRACE_HELPER``).
#: Off: on the shared 2-core machine (load 6-8, autogroup scheduling) it did not pay in wall time
#: (``python -m bench live_update``: "trace helper" rows); on an idle machine it halves the trace
TRACE_HELPER = False


def request(material) -> None:
    """A table or structure setting of ``material`` changed: update it (now headless, debounced in the UI)."""
    _trace_helper_on()
    if _batch is not None:
        _batch.append(material.name)
        return
    if _background():
        try:
            sync(material)
        except Exception as exc:  # noqa: BLE001 - a property update must not raise into Blender
            _report(material, exc)
        return
    _pending[material.name] = time.perf_counter() + DEBOUNCE_S
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=DEBOUNCE_S, persistent=True)


def call_debounced(key: str, fn) -> None:
    """Run ``fn()`` once the edits of ``key`` stop for ``DEBOUNCE_S`` (UI), at once headless (the
    iridescent layer's settings: each change recompiles its shader)."""
    if _background():
        fn()
        return
    _calls[key] = (time.perf_counter() + DEBOUNCE_S, fn)
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=DEBOUNCE_S, persistent=True)


def _run_calls(now: float | None) -> None:
    for key, (due, fn) in list(_calls.items()):
        if now is None or due <= now:
            _calls.pop(key, None)
            try:
                fn()
            except Exception:  # noqa: BLE001 - reported by fn's owner; never break the timer
                traceback.print_exc()
            _redraw()


def flush() -> None:
    """Apply every pending update now (waits for a running table computation)."""
    global _job
    _run_calls(None)
    if _job is not None:
        name, _key, future, _quality = _job
        _job = None
        mat = bpy.data.materials.get(name)
        try:
            prepared = future.result()
        except Exception:  # noqa: BLE001 - recomputed (and reported) by sync below
            prepared = None
        if prepared is not None and prepared.get("quality") == "preview":
            prepared = None   # flush wants the final material: the full tables, now
            ahead = _ahead.pop((name, _key), None)
            if ahead is not None:
                try:
                    prepared = ahead.result()
                except Exception:  # noqa: BLE001 - recomputed (and reported) by sync below
                    prepared = None
        _drop_ahead(name)
        if mat is not None:
            _pending.setdefault(name, 0.0)
            _apply(mat, prepared)
            _pending.pop(name, None)
    for name in list(_pending):
        _pending.pop(name, None)
        mat = bpy.data.materials.get(name)
        if mat is not None:
            _apply(mat, None)


def _apply(material, prepared) -> None:
    try:
        sync(material, prepared=prepared)
    except Exception as exc:  # noqa: BLE001
        _report(material, exc)
    _redraw()


def _redraw() -> None:
    wm = getattr(bpy.context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type in ("PROPERTIES", "VIEW_3D", "NODE_EDITOR"):
                area.tag_redraw()


def _prepare(spec, quality: str = "full"):
    return scratch_material.prepare(spec, quality)


def _drop_ahead(name: str, keep: str | None = None) -> None:
    """Forget the full tables computed ahead for ``name`` (other than of table key ``keep``): a newer edit."""
    for k in [k for k in _ahead if k[0] == name and k[1] != keep]:
        _ahead.pop(k).cancel()   # a running one finishes (into the cache), a queued one never starts


def _start(name: str, key: str, spec, quality: str | None = None) -> None:
    """Submit the table computation of material ``name`` (``quality`` None: on a miss the preview, and the full
    tables beside it on the second worker; "full": the full tables, taken from that second worker if it has
    them under way)."""
    global _job, _worker
    if _worker is None:
        _worker = concurrent.futures.ThreadPoolExecutor(WORKERS, thread_name_prefix="scratch_live")
    _drop_ahead(name, keep=key)
    if quality is None and scratch_material.has_preview(spec) and not scratch_material.tables_cached(spec):
        future = _worker.submit(_prepare, spec, "preview")
        _ahead[(name, key)] = _worker.submit(_prepare, spec, "full")
    elif quality is None:
        future = _worker.submit(_prepare, spec)
    else:
        future = _ahead.pop((name, key), None) if quality == "full" else None
        future = future or _worker.submit(_prepare, spec, quality)
    _job = (name, key, future, quality)


def _tick():
    """UI timer: start the table computation of due materials in the worker, apply finished ones."""
    global _job, _worker
    now = time.perf_counter()
    _run_calls(now)
    if _job is not None:
        name, key, future, _quality = _job
        if not future.done():
            return 0.05
        _job = None
        mat = bpy.data.materials.get(name)
        if mat is not None:
            try:
                prepared = future.result()
            except Exception:  # noqa: BLE001 - sync recomputes and reports it
                prepared = None
            try:
                spec = _spec(mat)
                current = scratch_material.live_keys(spec, mat.name)[0]
            except Exception:  # noqa: BLE001
                current = None
            if current == key and name not in _pending:
                _apply(mat, prepared)
                if prepared is not None and prepared.get("quality") == "preview":
                    _start(name, key, spec, "full")   # the preview shows: now the full tables
            else:
                _pending.setdefault(name, now)   # changed again meanwhile: compute the newest
                _drop_ahead(name)
    due = [n for n, t in _pending.items() if t <= now]
    if due and _job is None:
        name = due[0]
        _pending.pop(name)
        mat = bpy.data.materials.get(name)
        if mat is not None:
            try:
                spec = _spec(mat)
                key = scratch_material.live_keys(spec, mat.name)[0]
            except Exception as exc:  # noqa: BLE001
                _report(mat, exc)
                _redraw()
            else:
                if (mat.get(scratch_material.TABLE_KEY) == key and is_live(mat)
                        and not mat.get(scratch_material.PREVIEW_KEY)):
                    _apply(mat, None)   # back to the built tables: sockets only
                else:
                    _start(name, key, spec)
    if _job is not None:
        return 0.05
    dues = list(_pending.values()) + [due for due, _fn in _calls.values()]
    if dues:
        return max(0.01, min(dues) - now)
    return None


# ----------------------------------------------------------------------------- property callbacks
def on_property(settings, context, prop: str) -> None:
    """``update`` of ``material.scratch.<prop>`` (see ``properties.py``)."""
    if _suspended:
        return
    material = settings.id_data
    if not isinstance(material, bpy.types.Material) or material.get("scratch_addon_kind") != "scratch_svbrdf":
        return   # settings of a material that is not (yet) a scratch material: applied by Add / Update
    try:
        if prop in SOCKET_PROPS and is_live(material) and write_socket(material, prop):
            material.pop(ERROR_KEY, None)
            return
    except Exception as exc:  # noqa: BLE001
        _report(material, exc)
        return
    request(material)


def updater(prop: str):
    """The update callback of setting ``prop``."""
    def update(self, context):
        on_property(self, context, prop)
    update.__name__ = f"update_{prop}"
    return update


# ----------------------------------------------------------------------------- handlers
def _layered_fcurves(action):
    """F-curves of a (Blender 4.4+) layered action, else its flat list."""
    try:
        return [fc for layer in action.layers for strip in layer.strips for bag in strip.channelbags
                for fc in bag.fcurves]
    except AttributeError:
        return list(getattr(action, "fcurves", ()))


def _animated(material) -> set:
    ad = material.animation_data
    if ad is None:
        return set()
    paths = [fc.data_path for fc in _layered_fcurves(ad.action)] if ad.action is not None else []
    paths += [d.data_path for d in ad.drivers]
    return {p[len("scratch."):] for p in paths if p.startswith("scratch.") and p[len("scratch."):] in SOCKET_PROPS}


@bpy.app.handlers.persistent
def _on_frame_pre(scene, depsgraph=None):
    """Before the frame is evaluated (an animation render syncs right after): keyframed socket settings
    evaluated from their F-curves at the new frame."""
    frame = scene.frame_current + getattr(scene, "frame_subframe", 0.0)
    for mat in bpy.data.materials:
        ad = mat.animation_data
        if ad is None or ad.action is None or not is_live(mat):
            continue
        curves = {}
        for fc in _layered_fcurves(ad.action):
            prop = fc.data_path[len("scratch."):] if fc.data_path.startswith("scratch.") else None
            if prop in SOCKET_PROPS and not fc.mute:
                curves.setdefault(prop, []).append(fc)
        for prop, fcs in curves.items():
            try:
                value = getattr(mat.scratch, prop)
                if isinstance(value, (int, float)):
                    value = fcs[0].evaluate(frame)
                else:
                    value = list(value)
                    for fc in fcs:
                        value[fc.array_index] = fc.evaluate(frame)
                write_socket(mat, prop, value)
            except Exception:  # noqa: BLE001 - never break playback or a render
                traceback.print_exc()


@bpy.app.handlers.persistent
def _on_frame(scene, depsgraph=None):
    """Animated / driven socket settings follow the frame (the panel values are not sockets themselves)."""
    for mat in bpy.data.materials:
        if not is_live(mat):
            continue
        props = _animated(mat)
        for prop in props:
            try:
                write_socket(mat, prop)
            except Exception:  # noqa: BLE001 - never break playback or a render
                traceback.print_exc()


@bpy.app.handlers.persistent
def _on_undo(*_args):
    """After undo / redo: re-sync materials whose settings and tables disagree (cache hits)."""
    _pending.clear()
    for mat in bpy.data.materials:
        if mat.get("scratch_addon_kind") != "scratch_svbrdf" or not hasattr(mat, "scratch"):
            continue
        try:
            key = scratch_material.live_keys(_spec(mat), mat.name)[0]
        except Exception:  # noqa: BLE001
            continue
        if SETTINGS_KEY in mat and (mat.get(SETTINGS_KEY) != key or mat.get(scratch_material.PREVIEW_KEY)
                                    or (is_live(mat) and _sockets_differ(mat))):
            request(mat)


@bpy.app.handlers.persistent
def _on_load(*_args):
    """A file loads: updates pending for the old file's materials are dropped."""
    global _job
    _pending.clear()
    _calls.clear()
    _job = None
    _ahead.clear()


@bpy.app.handlers.persistent
def _on_loaded(*_args):
    """A file saved while a live edit showed its preview tables: the full tables now."""
    for mat in bpy.data.materials:
        if mat.get(scratch_material.PREVIEW_KEY) and mat.get("scratch_addon_kind") == "scratch_svbrdf" \
                and hasattr(mat, "scratch"):
            request(mat)


_HANDLERS = (("frame_change_pre", _on_frame_pre), ("frame_change_post", _on_frame), ("undo_post", _on_undo), ("redo_post", _on_undo),
             ("load_pre", _on_load), ("load_post", _on_loaded))


def register() -> None:
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn not in handlers:
            handlers.append(fn)


def unregister() -> None:
    global _worker, _job
    for name, fn in _HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        if fn in handlers:
            handlers.remove(fn)
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
    _pending.clear()
    _calls.clear()
    _job = None
    _ahead.clear()
    if _worker is not None:
        _worker.shutdown(wait=False, cancel_futures=True)
        _worker = None
    from ..precompute.scratch import slices

    slices.TRACE_HELPER = False
    slices.stop_trace_helper()
