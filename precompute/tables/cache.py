"""Content-hash-keyed cache of precomputed float tables, stored as EXR files.

A table is identified by a *namespace* (what it is, e.g. ``"scratch_brdf"``), a
*version* (bumped whenever the code that computes it changes) and the *inputs*
it was computed from.  The key is a SHA-256 of a canonical JSON rendering of
those inputs (numpy arrays contribute dtype, shape and raw bytes), so equal
inputs hit the same file and any change of input misses.

Where files go: ``set_cache_dir()`` (the Blender add-on calls it with its
preference or ``bpy.utils.extension_path_user(..., path="cache")``), else the
``SCRATCH_ADDON_CACHE`` environment variable, else ``<tempdir>/scratch_addon_cache``.
This module never imports bpy.

Files are written atomically (``exr_io.write_exr``), read back bit-exactly, and
a corrupt or mismatching file is recomputed with a ``CacheWarning``.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
import warnings
from typing import Callable, Mapping

import numpy as np

from . import exr_io

__all__ = ["set_cache_dir", "get_cache_dir", "code_version", "content_key", "cached_arrays", "CacheWarning", "clear"]

_cache_dir: str | None = None
_PACK_WIDTH = 1024


class CacheWarning(UserWarning):
    """A cache file was unusable and its table is being recomputed."""


def set_cache_dir(path: str | os.PathLike | None) -> None:
    """Use ``path`` for cache files (``None`` restores the default)."""
    global _cache_dir
    _cache_dir = None if path is None else os.fspath(path)


def get_cache_dir() -> str:
    """The folder cache files go to (created on demand)."""
    d = _cache_dir or os.environ.get("SCRATCH_ADDON_CACHE") or os.path.join(tempfile.gettempdir(), "scratch_addon_cache")
    os.makedirs(d, exist_ok=True)
    return d


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


def _unpack(channels: dict[str, np.ndarray], meta: dict) -> dict[str, np.ndarray]:
    out = {}
    if meta["packed"]:
        flat = channels["data"].ravel()
        offset = 0
        for name, dtype, shape in meta["layout"]:
            n = int(np.prod(shape, dtype=np.int64))
            out[name] = flat[offset : offset + n].reshape(shape).astype(dtype)
            offset += n
    else:
        for name, dtype, shape in meta["layout"]:
            out[name] = channels[name].reshape(shape).astype(dtype)
    return out


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
    if os.path.exists(path):
        try:
            channels, meta = exr_io.read_exr(path)
            if not meta or meta.get("key") != key:
                raise exr_io.ExrError(f"{path}: key mismatch")
            return _unpack(channels, meta)
        except (exr_io.ExrError, KeyError, ValueError, TypeError) as exc:
            warnings.warn(f"cache file unusable, recomputing: {exc}", CacheWarning, stacklevel=2)
    result = {k: np.asarray(v) for k, v in compute().items()}
    channels, meta = _pack(result)
    meta.update(key=key, namespace=namespace, version=version)
    try:
        exr_io.write_exr(path, channels, meta)
    except OSError as exc:  # read-only or full disk: still return the result
        warnings.warn(f"cache not written ({exc})", CacheWarning, stacklevel=2)
    # the stored (float32) form, so that a first call and later cached calls give identical arrays (and so
    # identical generated shaders, which materials then share)
    return _unpack(channels, meta)


def clear(namespace: str | None = None) -> int:
    """Delete cache files (of one namespace, or all); returns how many were removed."""
    d = get_cache_dir()
    n = 0
    for name in os.listdir(d):
        if name.endswith(".exr") and (namespace is None or name.startswith(namespace + "-")):
            os.unlink(os.path.join(d, name))
            n += 1
    return n
