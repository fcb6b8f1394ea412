"""Float EXR read/write for precomputed tables.

Writes are atomic: the file is written under a temporary name in the target
folder (``files.temp_file``: mode 0o666 & ~umask, so shared folders stay readable by
the group) and renamed into place, so a crash never leaves a half-written table; a
killed writer's temp file is removed by ``files.sweep_orphans``.
Values round-trip bit-exactly for float32 (EXR ``FLOAT`` channels, lossless ZIP).
``finite=True`` (tables) rejects NaN and infinities on write and on read.
"""
from __future__ import annotations

import errno
import json
import os

import numpy as np

from . import files

__all__ = ["write_exr", "read_exr", "ExrError"]

_META_KEY = "scratch_meta"


class ExrError(ValueError):
    """The file is missing, unreadable or not a table written by ``write_exr``."""


def _openexr():
    try:
        import OpenEXR  # noqa: PLC0415 - optional heavy import, only when needed
    except ImportError as exc:  # pragma: no cover - requirements.txt installs it
        raise ImportError("precompute.tables.exr_io needs the 'OpenEXR' package (pip install OpenEXR)") from exc
    return OpenEXR


def _check_finite(name: str, a: np.ndarray, error=ValueError, where: str = "") -> None:
    if not np.all(np.isfinite(a)):
        bad = int(np.count_nonzero(~np.isfinite(a)))
        raise error(f"{where}channels[{name!r}]: {bad} of {a.size} values are NaN or infinite (a table must be finite)")


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], meta: dict | None = None, *,
              finite: bool = False) -> None:
    """Write 2D float32 arrays of equal shape as named EXR channels, atomically.

    ``meta`` (JSON-serialisable) is stored in the header and returned by ``read_exr``.
    ``finite=True``: a channel holding NaN or an infinity raises ValueError and nothing is written.
    """
    OpenEXR = _openexr()
    if not channels:
        raise ValueError("channels: need at least one named 2D array")
    arrays = {}
    shape = None
    for name, a in channels.items():
        a = np.ascontiguousarray(np.asarray(a, dtype=np.float32))
        if a.ndim != 2 or a.size == 0:
            raise ValueError(f"channels[{name!r}]: expected a non-empty 2D array, got shape {a.shape}")
        if shape is not None and a.shape != shape:
            raise ValueError(f"channels[{name!r}]: shape {a.shape} differs from {shape}")
        if finite:
            _check_finite(str(name), a)
        shape = a.shape
        arrays[str(name)] = a
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if meta is not None:
        header[_META_KEY] = json.dumps(meta, sort_keys=True)
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"path: {path!r} is a folder; expected a file name (.exr)")
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
        tmp = files.temp_file(folder, ".exr")
    except OSError as e:          # name the user's path, not the temp file or a parent
        raise OSError(e.errno, f"cannot write {path!r}: {e.strerror}") from e
    try:
        try:
            OpenEXR.File(header, arrays).write(tmp)
        except RuntimeError as e:  # OpenEXR reports I/O failures (a full disk, a vanished folder) as RuntimeError
            code = errno.ENOSPC if "No space left" in str(e) else errno.EIO
            raise OSError(code, os.strerror(code) if code == errno.ENOSPC else files.one_line(e)) from e
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError):
            raise OSError(e.errno, f"cannot write {path!r}: {e.strerror}") from e
        raise


def read_exr(path: str | os.PathLike, *, finite: bool = False) -> tuple[dict[str, np.ndarray], dict | None]:
    """Read every channel of an EXR as float32 arrays; returns ``(channels, meta)``.

    Raises ``ExrError`` for missing, truncated or non-EXR files, and with ``finite=True`` (tables) for
    a channel holding NaN or an infinity.
    """
    OpenEXR = _openexr()
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ExrError(f"{path}: no such file")
    try:
        f = OpenEXR.File(path, separate_channels=True)
        chans = {name: np.array(c.pixels, dtype=np.float32) for name, c in f.channels().items()}
        raw = f.header().get(_META_KEY)
    except Exception as exc:  # OpenEXR raises plain Exceptions for corrupt files
        raise ExrError(f"{path}: unreadable EXR ({exc})") from exc
    meta = None
    if raw is not None:
        try:
            meta = json.loads(raw if isinstance(raw, str) else raw.decode())
        except (ValueError, AttributeError) as exc:
            raise ExrError(f"{path}: corrupt metadata ({exc})") from exc
    if finite:
        for name, a in chans.items():
            _check_finite(name, a, ExrError, f"{path}: ")
    return chans, meta
