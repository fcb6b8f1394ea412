"""File-system helpers for table files: temp files for atomic writes, the orphan sweep, writable folders.

Writers (``exr_io.write_exr``) write under a temporary name ``.tmp-<pid>-<random><suffix>`` in the
target folder and rename it into place, so a reader never sees a half file.  A writer killed
mid-write (SIGKILL, power loss) leaves its temp file behind: ``sweep_orphans`` deletes temp files
older than ``ORPHAN_AGE_S`` (a live writer's temp file is seconds old, so it is never touched).

Temp files are created with mode ``0o666`` filtered by the process umask (what ``open()`` gives), not
``0o600`` as ``tempfile.mkstemp`` would: a studio's shared cache folder stays readable by the group.
This module never imports bpy.
"""
from __future__ import annotations

import os
import secrets
import time

__all__ = ["TMP_PREFIX", "ORPHAN_AGE_S", "temp_file", "sweep_orphans", "check_writable", "one_line"]

#: Name prefix of in-flight temp files (hidden on POSIX).
TMP_PREFIX = ".tmp-"
#: A temp file older than this (seconds) belongs to a dead writer and is swept.
ORPHAN_AGE_S = 300.0


def one_line(exc: BaseException) -> str:
    """A one-line description of an OS error: ``Permission denied: '/path'`` (no errno, no newlines)."""
    if isinstance(exc, OSError) and exc.strerror:
        where = f": {exc.filename!r}" if exc.filename is not None else ""
        return f"{exc.strerror}{where}"
    return " ".join(str(exc).split()) or type(exc).__name__


def temp_file(folder: str, suffix: str = "") -> str:
    """Create an empty, uniquely named temp file in ``folder`` (mode 0o666 & ~umask); returns its path.

    The name carries the writer's pid and 48 random bits, so concurrent writers (threads, processes,
    machines sharing the folder) never collide."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(64):
        path = os.path.join(folder, f"{TMP_PREFIX}{os.getpid()}-{secrets.token_hex(6)}{suffix}")
        try:
            fd = os.open(path, flags, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return path
    raise FileExistsError(f"could not create a unique temp file in {folder!r}")


def sweep_orphans(folder: str, max_age_s: float = ORPHAN_AGE_S, *, depth: int = 1) -> int:
    """Delete ``TMP_PREFIX`` files older than ``max_age_s`` seconds in ``folder`` (and its sub-folders down
    to ``depth`` levels); returns how many were deleted.  Races with writers and other sweepers are
    harmless (a vanished file is skipped); errors never propagate (a sweep is housekeeping)."""
    now = time.time()
    removed = 0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for entry in entries:
        try:
            if entry.is_dir(follow_symlinks=False):
                if depth > 0:
                    removed += sweep_orphans(entry.path, max_age_s, depth=depth - 1)
                continue
            if not entry.name.startswith(TMP_PREFIX) or not entry.is_file(follow_symlinks=False):
                continue
            if now - entry.stat(follow_symlinks=False).st_mtime < max_age_s:
                continue  # possibly in flight
            os.unlink(entry.path)
            removed += 1
        except OSError:  # vanished (renamed into place / swept by another process) or not ours to delete
            continue
    return removed


def check_writable(folder: str) -> str:
    """Create ``folder`` if needed and prove it writable by creating and deleting a temp file (robust
    where permission bits lie: ACLs, read-only mounts, network shares); returns the absolute folder.

    Raises ``OSError`` (``NotADirectoryError`` for a path through or to a regular file,
    ``PermissionError``, ...)."""
    folder = os.path.abspath(os.fspath(folder))
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise NotADirectoryError(20, "Not a directory", folder)
    os.makedirs(folder, exist_ok=True)
    probe = temp_file(folder, ".probe")
    try:
        os.unlink(probe)
    except FileNotFoundError:
        pass
    return folder
