"""Content-hash-keyed cache of precomputed float tables, stored as EXR files.

A table is identified by a *namespace* (what it is, e.g. ``"scratch_brdf"``), a
*version* (bumped whenever the code that computes it changes) and the *inputs*
it was computed from.  The key is a SHA-256 of a canonical JSON rendering of
those inputs (numpy arrays contribute dtype, shape and raw bytes), so equal
inputs hit the same file in every process and session (no salted ``hash()``), and
any change of input misses.

Where files go: ``set_cache_dir()`` (the Blender add-on calls it with its
preference or ``bpy.utils.extension_path_user(..., path="cache")``), else the
``SCRATCH_ADDON_CACHE`` environment variable, else ``<tempdir>/scratch_addon_cache``.
A folder that cannot be used (a regular file, no permission, a read-only parent)
is replaced by a temp folder with a ``CacheWarning`` (``cache_dir_problem()`` says
why).  This module never imports bpy.

Faults and sharing:
- files are written atomically (``exr_io.write_exr``: temp file + rename), readable by
  the group (umask respected), and read back bit-exactly;
- a writer killed mid-write leaves only a ``.tmp-*`` file, swept once it is older than
  ``files.ORPHAN_AGE_S`` (on first use of a folder, then at most every ``ORPHAN_AGE_S``);
- a corrupt file (unreadable, truncated, corrupt or mismatching metadata, NaN values)
  is recomputed with a ``CacheWarning``; a computed table holding NaN or infinities is
  refused (``ValueError``) and never written;
- two processes computing the same entry both write complete files under temp names
  and rename them into place: one file, identical contents;
- ``clear()`` deletes only finished tables, never another process's in-flight temp
  file, and ignores files that vanish under it.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import time
import warnings
from typing import Callable, Mapping

import numpy as np

from . import exr_io, files

__all__ = ["set_cache_dir", "get_cache_dir", "cache_dir_problem", "code_version", "content_key", "cached_arrays",
           "CacheWarning", "clear", "sweep"]

_cache_dir: str | None = None
_PACK_WIDTH = 1024
#: configured folder -> (folder in use, problem or None)
_resolved: dict[str, tuple[str, str | None]] = {}
#: folder -> time of its last orphan sweep
_swept: dict[str, float] = {}
#: dtypes a cache file may declare (what ``_pack`` stores exactly)
_DTYPE_KINDS = "fiub"


class CacheWarning(UserWarning):
    """A cache file was unusable and its table is being recomputed (or the cache folder was unusable)."""


def set_cache_dir(path: str | os.PathLike | None) -> None:
    """Use ``path`` for cache files (``None`` restores the default)."""
    global _cache_dir
    _cache_dir = None if path is None else os.fspath(path)


def _default_dir() -> str:
    return os.path.join(tempfile.gettempdir(), "scratch_addon_cache")


def _configured_dir() -> str:
    return _cache_dir or os.environ.get("SCRATCH_ADDON_CACHE") or _default_dir()


def _fallback_dirs(wanted: str):
    """Temp folders to use instead of an unusable ``wanted``: the default, then a per-user one (another
    user may own the default on a shared /tmp), then a fresh one."""
    user = str(os.getuid()) if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    for d in (_default_dir(), os.path.join(tempfile.gettempdir(), f"scratch_addon_cache-{user}")):
        if os.path.abspath(d) != os.path.abspath(wanted):
            yield d
    yield tempfile.mkdtemp(prefix="scratch_addon_cache-")


def get_cache_dir() -> str:
    """The folder cache files go to (created on demand).  An unusable folder (a regular file, a path
    through a file, no permission) is replaced by a temp folder, with one ``CacheWarning``."""
    wanted = _configured_dir()
    hit = _resolved.get(wanted)
    if hit is not None and os.path.isdir(hit[0]):
        folder = hit[0]
    else:
        try:
            folder, problem = files.check_writable(wanted), None
        except OSError as exc:
            problem = files.one_line(exc)
            for folder in _fallback_dirs(wanted):
                try:
                    folder = files.check_writable(folder)
                    break
                except OSError:
                    continue
            warnings.warn(f"cache folder {wanted!r} is unusable ({problem}); using {folder!r}", CacheWarning,
                          stacklevel=2)
        _resolved[wanted] = (folder, problem)
    if time.time() - _swept.get(folder, -math.inf) > files.ORPHAN_AGE_S:
        _swept[folder] = time.time()
        files.sweep_orphans(folder)
    return folder


def cache_dir_problem() -> str | None:
    """Why the configured cache folder is not in use (one line), or None when it is."""
    wanted = _configured_dir()
    if wanted not in _resolved:
        get_cache_dir()
    return _resolved[wanted][1]


def sweep(max_age_s: float = files.ORPHAN_AGE_S) -> int:
    """Delete temp files of killed writers (older than ``max_age_s``) in the cache folder and its
    sub-folders; returns how many.  Runs by itself when a folder is first used."""
    return files.sweep_orphans(get_cache_dir(), max_age_s)


def _canonical(obj):
    """JSON-able canonical form; arrays are replaced by a digest of dtype, shape and bytes."""
    if isinstance(obj, np.ndarray) or (hasattr(obj, "__array__") and not isinstance(obj, (str, bytes))):
        a = np.ascontiguousarray(np.asarray(obj))
        h = hashlib.sha256(a.tobytes()).hexdigest()
        return {"__array__": [str(a.dtype), list(a.shape), h]}
    if isinstance(obj, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj).hex()  # exact: 0.1 and 0.1000000001 differ
    if isinstance(obj, (np.integer, int, bool)) or obj is None or isinstance(obj, str):
        return obj if not isinstance(obj, np.integer) else int(obj)
    if hasattr(obj, "cache_key"):
        return _canonical(obj.cache_key())
    raise TypeError(f"cache inputs: cannot hash value of type {type(obj).__name__}")


def code_version(*modules) -> str:
    """SHA-256 (first 16 hex digits) of the source files of ``modules``: use as ``version`` so a
    change of the computing code invalidates its cached tables."""
    h = hashlib.sha256()
    for m in modules:
        path = getattr(m, "__file__", None)
        if not path:
            raise TypeError(f"code_version: module {m!r} has no source file")
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:16]


def content_key(namespace: str, version: str, inputs: Mapping) -> str:
    """SHA-256 hex key of (namespace, version, inputs)."""
    blob = json.dumps([namespace, version, _canonical(inputs)], sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def _path(namespace: str, key: str) -> str:
    return os.path.join(get_cache_dir(), f"{namespace}-{key[:32]}.exr")


def _pack(arrays: Mapping[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict]:
    """Arrays of one 2D shape become EXR channels; anything else is packed into one channel."""
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    layout = [[k, str(v.dtype), list(v.shape)] for k, v in arrays.items()]  # ordered
    shapes = {v.shape for v in arrays.values()}
    if len(shapes) == 1 and len(next(iter(shapes))) == 2 and 0 not in next(iter(shapes)):
        return {k: v.astype(np.float32) for k, v in arrays.items()}, {"layout": layout, "packed": False}
    flat = np.concatenate([v.astype(np.float32).ravel() for v in arrays.values()]) if arrays else np.zeros(0, np.float32)
    rows = max(1, -(-flat.size // _PACK_WIDTH))
    buf = np.zeros(rows * _PACK_WIDTH, np.float32)
    buf[: flat.size] = flat
    return {"data": buf.reshape(rows, _PACK_WIDTH)}, {"layout": layout, "packed": True}


def _layout(channels: dict[str, np.ndarray], meta) -> tuple[bool, list]:
    """Validated ``(packed, layout)`` of a cache file's metadata; ExrError when it cannot describe
    ``channels`` (not a dict, bad types, negative or inconsistent shapes, unknown dtypes)."""
    if not isinstance(meta, dict):
        raise exr_io.ExrError(f"corrupt metadata: expected a JSON object, got {type(meta).__name__}")
    packed, layout = meta.get("packed"), meta.get("layout")
    if not isinstance(packed, bool) or not isinstance(layout, list):
        raise exr_io.ExrError("corrupt metadata: 'packed' must be a bool and 'layout' a list")
    sizes = []
    for item in layout:
        ok = (isinstance(item, list) and len(item) == 3 and isinstance(item[0], str) and isinstance(item[1], str)
              and isinstance(item[2], list)
              and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in item[2]))
        if not ok:
            raise exr_io.ExrError(f"corrupt metadata: bad layout entry {item!r}")
        try:
            kind = np.dtype(item[1]).kind
        except TypeError:
            kind = None
        if kind is None or kind not in _DTYPE_KINDS:
            raise exr_io.ExrError(f"corrupt metadata: unsupported dtype {item[1]!r}")
        sizes.append(math.prod(item[2]))
    if len({item[0] for item in layout}) != len(layout):
        raise exr_io.ExrError("corrupt metadata: duplicate array names")
    if packed:
        data = channels.get("data")
        if data is None or sum(sizes) > data.size:
            raise exr_io.ExrError("corrupt metadata: the packed layout does not fit the data channel")
    else:
        for (name, _dtype, _shape), n in zip(layout, sizes):
            if name not in channels or channels[name].size != n:
                raise exr_io.ExrError(f"corrupt metadata: array {name!r} does not match its channel")
    return packed, layout


def _unpack(channels: dict[str, np.ndarray], meta) -> dict[str, np.ndarray]:
    packed, layout = _layout(channels, meta)
    out = {}
    if packed:
        flat = channels["data"].ravel()
        offset = 0
        for name, dtype, shape in layout:
            n = math.prod(shape)
            out[name] = flat[offset : offset + n].reshape(shape).astype(dtype)
            offset += n
    else:
        for name, dtype, shape in layout:
            out[name] = channels[name].reshape(shape).astype(dtype)
    return out


def _check_finite(namespace: str, arrays: Mapping[str, np.ndarray]) -> None:
    for name, a in arrays.items():
        if a.dtype.kind in "fc" and not np.all(np.isfinite(a)):
            bad = int(np.count_nonzero(~np.isfinite(a)))
            raise ValueError(f"{namespace}: computed table {name!r} has {bad} NaN or infinite values of {a.size} "
                             "(not cached)")


def cached_arrays(
    namespace: str,
    version: str,
    inputs: Mapping,
    compute: Callable[[], Mapping[str, np.ndarray]],
    *,
    enabled: bool = True,
) -> dict[str, np.ndarray]:
    """Return ``compute()``'s named arrays, from the cache when the same inputs were seen before.

    Values are stored as float32 (bit-exact for float32 data; integer arrays are
    restored to their dtype and are exact up to 2**24).  ``enabled=False`` skips the cache.
    """
    if not enabled:
        return {k: np.asarray(v) for k, v in compute().items()}
    key = content_key(namespace, version, inputs)
    path = _path(namespace, key)
    try:
        channels, meta = exr_io.read_exr(path, finite=True)
        if not isinstance(meta, dict) or meta.get("key") != key:
            raise exr_io.ExrError(f"{path}: key mismatch")
        return _unpack(channels, meta)
    except Exception as exc:  # noqa: BLE001 - whatever is wrong with a cache file, recompute it
        if os.path.exists(path):  # (a file that is simply not there is an ordinary miss)
            warnings.warn(f"cache file unusable, recomputing: {exc}", CacheWarning, stacklevel=2)
    result = {k: np.asarray(v) for k, v in compute().items()}
    _check_finite(namespace, result)
    channels, meta = _pack(result)
    meta.update(key=key, namespace=namespace, version=version)
    try:
        exr_io.write_exr(path, channels, meta, finite=True)
    except OSError as exc:  # read-only or full disk: still return the result
        warnings.warn(f"cache not written ({files.one_line(exc)})", CacheWarning, stacklevel=2)
    # the stored (float32) form, so that a first call and later cached calls give identical arrays (and so
    # identical generated shaders, which materials then share)
    return _unpack(channels, meta)


def is_cached(namespace: str, version: str, inputs: Mapping) -> bool:
    """True if ``cached_arrays`` with these arguments would read a stored file (no compute), as far as a
    file's presence tells (a damaged file is still recomputed)."""
    return os.path.isfile(_path(namespace, content_key(namespace, version, inputs)))


def clear(namespace: str | None = None) -> int:
    """Delete cache files (of one namespace, or all); returns how many were removed.

    Safe while other threads or processes write: only finished tables are deleted (never a writer's
    in-flight ``.tmp-*`` file; orphans of killed writers are swept by age), and files that vanish or
    cannot be deleted (a colleague's file in a shared folder) are skipped."""
    d = get_cache_dir()
    n = 0
    try:
        entries = list(os.scandir(d))
    except FileNotFoundError:
        return 0
    for entry in entries:
        name = entry.name
        if name.startswith(files.TMP_PREFIX) or not name.endswith(".exr"):
            continue
        if namespace is not None and not name.startswith(namespace + "-"):
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            os.unlink(entry.path)
            n += 1
        except FileNotFoundError:
            continue
        except OSError as exc:
            warnings.warn(f"cache file not removed ({files.one_line(exc)})", CacheWarning, stacklevel=2)
    files.sweep_orphans(d)
    return n
