"""precompute.tables under faults and sharing (issue #14 item 5): killed writers, concurrent writers and
clears, corrupt metadata, NaN tables, group-readable files, unusable folders, deterministic names.

Processes are real subprocesses (SIGKILL mid-write, two writers racing for one entry); permission
faults run through ``fault_helpers.unprivileged`` so that they hold when the tests run as root."""
from __future__ import annotations

import errno
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from conftest import ROOT
from fault_helpers import unprivileged
from scratch_materials.precompute.tables import cache, exr_io, files


@pytest.fixture
def cache_dir(tmp_path):
    folder = tmp_path / "cache"
    cache.set_cache_dir(folder)
    yield folder
    cache.set_cache_dir(None)


def _tables(seed=0, n=16):
    rng = np.random.default_rng(seed)
    return {"rho": rng.random((n, n)).astype(np.float32), "idx": np.arange(10, dtype=np.int32)}


def _names(folder):
    return sorted(p.name for p in folder.iterdir())


def _run(code: str, *, env=None, cmd_prefix=None, timeout=120):
    cmd = [sys.executable, "-c", code]
    cmd = cmd_prefix(cmd) if cmd_prefix else cmd
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


# ----------------------------------------------------------------------------- orphans of killed writers

def _age(path, seconds):
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_sweep_removes_old_orphans_and_keeps_fresh_temp_files(tmp_path):
    old, fresh = tmp_path / ".tmp-123-aaaa.exr", tmp_path / ".tmp-456-bbbb.exr"
    sub = tmp_path / "biscale"
    sub.mkdir()
    old_sub, table = sub / ".tmp-1-cccc.exr", tmp_path / "t-0123.exr"
    for p in (old, fresh, old_sub, table):
        p.write_bytes(b"x")
    _age(old, files.ORPHAN_AGE_S + 5)
    _age(old_sub, files.ORPHAN_AGE_S + 5)
    _age(table, 10 * files.ORPHAN_AGE_S)  # an old finished table is not an orphan
    assert files.sweep_orphans(str(tmp_path)) == 2
    assert _names(tmp_path) == sorted([fresh.name, table.name, "biscale"]) and not list(sub.iterdir())


def test_first_use_of_a_cache_folder_sweeps_it(tmp_path):
    folder = tmp_path / "c"
    folder.mkdir()
    orphan = folder / ".tmp-99-dead.exr"
    orphan.write_bytes(b"half a table")
    _age(orphan, files.ORPHAN_AGE_S + 60)
    cache.set_cache_dir(folder)
    try:
        cache.cached_arrays("t", "1", {"k": 1}, _tables)
    finally:
        cache.set_cache_dir(None)
    assert not orphan.exists() and len(list(folder.glob("t-*.exr"))) == 1


_WRITER = """
import sys, time
import numpy as np
from scratch_materials.precompute.tables import cache
cache.set_cache_dir(sys.argv[1])
def compute():
    rng = np.random.default_rng(1)
    return {f"c{i}": rng.random((2048, 2048), dtype=np.float32) for i in range(8)}  # ~1 s to write
print("computing", flush=True)
cache.cached_arrays("big", "1", {"k": 1}, compute)
print("done", flush=True)
"""


def _size(p) -> int:
    """Bytes in ``p``, 0 when it vanished between the glob and the stat (the cache's short-lived write probe)."""
    try:
        return p.stat().st_size
    except FileNotFoundError:
        return 0


def test_writer_killed_mid_write_leaves_no_half_file_and_the_orphan_is_swept(tmp_path):
    folder = tmp_path / "cache"
    folder.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(folder)], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 60
        tmp = []
        while time.time() < deadline and proc.poll() is None:  # kill once the temp file has data in it
            tmp = [p for p in folder.glob(".tmp-*") if _size(p) > 0]
            if tmp:
                break
            time.sleep(0.002)
        assert tmp, f"writer never started writing: {proc.communicate()}"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    assert not list(folder.glob("big-*.exr")), "a half-written table under its final name"
    (orphan,) = folder.glob(".tmp-*")
    # a reader now: the entry is missing (recomputed), the fresh orphan might be in flight: kept
    read = _run("import sys\nfrom scratch_materials.precompute.tables import cache\n"
                "cache.set_cache_dir(sys.argv[1])\n"
                "r = cache.cached_arrays('big', '1', {'k': 1}, lambda: {'c0': __import__('numpy').ones((4, 4))})\n"
                "print(float(r['c0'].sum()))", cmd_prefix=lambda c: [*c, str(folder)])
    assert read.returncode == 0 and read.stdout.strip() == "16.0", read.stderr
    assert orphan.exists()
    _age(orphan, files.ORPHAN_AGE_S + 1)  # minutes later: the next process sweeps it
    again = _run("import sys\nfrom scratch_materials.precompute.tables import cache\n"
                 "cache.set_cache_dir(sys.argv[1])\n"
                 "r = cache.cached_arrays('big', '1', {'k': 1}, lambda: 1 / 0)\n"  # cached: compute is not called
                 "print(float(r['c0'].sum()))", cmd_prefix=lambda c: [*c, str(folder)])
    assert again.returncode == 0 and again.stdout.strip() == "16.0", again.stderr
    assert not list(folder.glob(".tmp-*")) and len(list(folder.glob("big-*.exr"))) == 1


_RACER = """
import hashlib, sys, time
import numpy as np
from scratch_materials.precompute.tables import cache
cache.set_cache_dir(sys.argv[1])
start = float(sys.argv[2])
def compute():
    time.sleep(max(0.0, start - time.time()))   # both processes compute at the same moment
    rng = np.random.default_rng(7)
    return {"rho": rng.random((512, 512)).astype(np.float32), "n": np.arange(5, dtype=np.int64)}
r = cache.cached_arrays("race", "1", {"k": [1, 2.5, "x"]}, compute)
print(hashlib.sha256(r["rho"].tobytes() + r["n"].tobytes()).hexdigest())
"""


def test_two_processes_computing_the_same_entry_write_one_identical_file(tmp_path):
    folder = tmp_path / "cache"
    start = str(time.time() + 3.0)
    procs = [subprocess.Popen([sys.executable, "-c", _RACER, str(folder), start], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outs = [p.communicate(timeout=120) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1] for o in outs]
    digests = {o[0].strip() for o in outs}
    assert len(digests) == 1
    assert [p.name for p in folder.iterdir()] == [p.name for p in folder.glob("race-*.exr")]  # one file, no temp
    assert len(list(folder.iterdir())) == 1
    cache.set_cache_dir(folder)
    try:
        r = cache.cached_arrays("race", "1", {"k": [1, 2.5, "x"]}, lambda: pytest.fail("should be cached"))
    finally:
        cache.set_cache_dir(None)
    assert hashlib.sha256(r["rho"].tobytes() + r["n"].tobytes()).hexdigest() in digests


# ----------------------------------------------------------------------------- clear() vs writers

def test_clear_never_deletes_an_in_flight_temp_file(cache_dir):
    cache.cached_arrays("t", "1", {"k": 1}, _tables)
    in_flight = cache_dir / ".tmp-4242-abcdef.exr"  # another process is writing this right now
    in_flight.write_bytes(b"partial")
    assert cache.clear() == 1
    assert in_flight.exists() and not list(cache_dir.glob("t-*.exr"))


def test_clear_ignores_files_that_vanish_under_it(cache_dir, monkeypatch):
    for k in range(3):
        cache.cached_arrays("t", "1", {"k": k}, _tables)
    real_unlink = os.unlink

    def racing_unlink(path, *a, **kw):  # another process deleted (or renamed) it a moment earlier
        real_unlink(path)
        raise FileNotFoundError(2, "No such file or directory", path)

    monkeypatch.setattr(os, "unlink", racing_unlink)
    assert cache.clear() == 0
    assert not list(cache_dir.glob("t-*.exr"))


_HAMMER = """
import sys, time, warnings
import numpy as np
from scratch_materials.precompute.tables import cache
cache.set_cache_dir(sys.argv[1])
t_end = time.time() + float(sys.argv[2])
n = failed = 0
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    while time.time() < t_end:
        cache.cached_arrays("h", "1", {"k": n % 7}, lambda: {"a": np.full((64, 64), n % 7, np.float32)})
        n += 1
    failed = sum("not written" in str(w.message) for w in caught)
print(n, failed)
"""


def test_clear_while_another_process_writes(cache_dir):
    cache_dir.mkdir()
    writer = subprocess.Popen([sys.executable, "-c", _HAMMER, str(cache_dir), "2.0"], cwd=ROOT,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    cleared, errors = 0, []
    while writer.poll() is None:
        try:
            cleared += cache.clear()
        except Exception as exc:  # noqa: BLE001 - any exception is the failure under test
            errors.append(repr(exc))
    out, err = writer.communicate(timeout=60)
    assert writer.returncode == 0, err
    writes, failed = map(int, out.split())
    assert not errors, errors[:3]
    assert failed == 0, f"{failed} of {writes} writes lost their temp file to clear()"
    assert writes > 20 and cleared > 0


# ----------------------------------------------------------------------------- corrupt and NaN files

def _plant(namespace, inputs, channels, meta):
    """A cache file for (namespace, "1", inputs) with the given channels and metadata."""
    key = cache.content_key(namespace, "1", inputs)
    exr_io.write_exr(cache._path(namespace, key), channels, {**meta, "key": key})


@pytest.mark.parametrize("channels, meta", [
    ({"rho": np.ones((4, 4))}, "a JSON list"),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "float32", [-4, -4]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "float32", [4, 5]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "object", [4, 4]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "not_a_dtype", [4, 4]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": "no", "layout": [["rho", "float32", [4, 4]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": {"rho": [4, 4]}}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "float32"]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["missing", "float32", [4, 4]]]}),
    ({"rho": np.ones((4, 4))}, {"packed": False, "layout": [["rho", "float32", [4.0, 4]]]}),
    ({"data": np.ones((1, 8))}, {"packed": True, "layout": [["a", "float32", [10 ** 12]]]}),
    ({"data": np.ones((1, 8))}, {"packed": True, "layout": [["a", "float32", [-1, 4]]]}),
    ({"data": np.ones((1, 8))}, {"packed": True, "layout": [["a", "float32", [4]], ["a", "float32", [4]]]}),
    ({"rho": np.ones((4, 4))}, {"layout": [["rho", "float32", [4, 4]]]}),
])
def test_corrupt_metadata_is_recomputed_with_a_warning(cache_dir, channels, meta):
    inputs = {"case": 1}
    key = cache.content_key("c", "1", inputs)
    if meta == "a JSON list":
        exr_io.write_exr(cache._path("c", key), channels, [key, "layout"])
    else:
        _plant("c", inputs, channels, meta)
    with pytest.warns(cache.CacheWarning, match="recomputing"):
        got = cache.cached_arrays("c", "1", inputs, lambda: _tables(3))
    np.testing.assert_array_equal(got["rho"], _tables(3)["rho"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the file was replaced by a good one
        again = cache.cached_arrays("c", "1", inputs, lambda: pytest.fail("should be cached"))
    np.testing.assert_array_equal(again["rho"], got["rho"])


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_cache_file_holding_nan_is_recomputed(cache_dir, bad):
    inputs = {"case": "nan"}
    good = _tables(5)
    poisoned = good["rho"].copy()
    poisoned[3, 4] = bad
    _plant("n", inputs, {"rho": poisoned}, {"packed": False, "layout": [["rho", "float32", [16, 16]]]})
    with pytest.warns(cache.CacheWarning, match="NaN or infinite"):
        got = cache.cached_arrays("n", "1", inputs, lambda: {"rho": good["rho"]})
    assert np.all(np.isfinite(got["rho"])) and np.array_equal(got["rho"], good["rho"])


def test_a_computed_table_holding_nan_is_refused_and_not_written(cache_dir):
    bad = _tables()
    bad["rho"][0, 0] = np.nan
    with pytest.raises(ValueError, match="'rho'.*NaN"):
        cache.cached_arrays("t", "1", {"k": 1}, lambda: bad)
    assert not cache_dir.exists() or not list(cache_dir.glob("*.exr"))


def test_exr_io_finite_tables_and_nan_holes_in_data(tmp_path):
    a = np.ones((4, 4), np.float32)
    a[1, 2] = np.nan
    with pytest.raises(ValueError, match=r"channels\['Z'\].*NaN"):
        exr_io.write_exr(tmp_path / "t.exr", {"Z": a}, finite=True)
    assert not list(tmp_path.iterdir())
    exr_io.write_exr(tmp_path / "h.exr", {"Z": a})  # data with holes (height fields) is still allowed
    chans, _ = exr_io.read_exr(tmp_path / "h.exr")
    assert np.isnan(chans["Z"][1, 2])
    with pytest.raises(exr_io.ExrError, match="NaN or infinite"):
        exr_io.read_exr(tmp_path / "h.exr", finite=True)


# ----------------------------------------------------------------------------- sharing: modes and names

@pytest.mark.parametrize("umask", [0o002, 0o022, 0o077])
def test_files_respect_the_umask_not_0600(cache_dir, umask):
    old = os.umask(umask)
    try:
        cache.cached_arrays("m", "1", {"umask": umask}, _tables)
    finally:
        os.umask(old)
    (path,) = cache_dir.glob("m-*.exr")
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask


_KEY = """
import numpy as np
from scratch_materials.precompute.tables import cache
from scratch_materials.precompute.biscale.bake import materials_hash, mesh_hash
inputs = {"profile": ("quartic", 0.3), "names": ["iron", "gold"], "x": 0.1, "a": np.linspace(0, 1, 7),
          "nested": {"b": (1, 2), "a": None}}
mats = [{"model": "lambert", "albedo": (0.5, 0.4, 0.3)}, {"model": "cook_torrance", "alpha": 0.2}]
V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.5]]); F = np.array([[0, 1, 2]]); M = np.array([0])
print(cache.content_key("scratch_brdf", "v1", inputs), mesh_hash(V, F, M, 1.0), materials_hash(mats))
"""


def test_names_are_the_same_in_every_process():
    outs = {_run(_KEY, env={"PYTHONHASHSEED": seed}).stdout for seed in ("1", "2", "random")}
    assert len(outs) == 1 and len(next(iter(outs)).split()) == 3


# ----------------------------------------------------------------------------- unusable cache folders

def _warned_dir(expect_problem):
    with pytest.warns(cache.CacheWarning, match=expect_problem) as rec:
        folder = cache.get_cache_dir()
    return folder, rec


@pytest.mark.parametrize("kind", ["regular file", "path through a file"])
def test_an_unusable_cache_folder_falls_back_to_a_temp_folder(tmp_path, kind):
    f = tmp_path / "not_a_folder"
    f.write_text("x")
    wanted = f if kind == "regular file" else f / "cache"
    cache.set_cache_dir(wanted)
    try:
        folder, _ = _warned_dir("unusable")
        assert os.path.isdir(folder) and not str(folder).startswith(str(f))
        assert "directory" in cache.cache_dir_problem().lower()
        got = cache.cached_arrays("fb", "1", {"k": 1}, _tables)  # and it works there
        assert np.array_equal(got["rho"], _tables()["rho"]) and list(os.scandir(folder))
        assert cache.clear("fb") == 1
    finally:
        cache.set_cache_dir(None)
    assert f.read_text() == "x"


_READONLY = """
import sys, warnings
import numpy as np
from scratch_materials.precompute.tables import cache
cache.set_cache_dir(sys.argv[1])
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    r = cache.cached_arrays("ro", "1", {"k": 1}, lambda: {"a": np.arange(6.0).reshape(2, 3)})
    folder = cache.get_cache_dir()
print(folder)
print(r["a"].sum())
print(" | ".join(str(x.message) for x in w))
"""


@pytest.mark.parametrize("case", ["read-only parent", "no permission"])
def test_a_folder_without_permission_falls_back_with_a_warning(tmp_path, case):
    parent = tmp_path / "studio"
    parent.mkdir()
    wanted = parent / "cache"
    if case == "no permission":
        wanted.mkdir()
        wanted.chmod(0o000)
    else:
        parent.chmod(0o555)
    try:
        proc = _run(_READONLY, cmd_prefix=lambda c: unprivileged([*c, str(wanted)]))
    finally:
        parent.chmod(0o755)
        if wanted.exists():
            wanted.chmod(0o755)
    assert proc.returncode == 0, proc.stderr
    folder, total, warned = proc.stdout.splitlines()
    assert float(total) == 15.0 and not folder.startswith(str(parent))
    assert "unusable" in warned and "Permission denied" in warned and str(wanted) in warned
    assert not wanted.exists() or not list(wanted.iterdir())


def test_bake_tables_checks_its_folder_before_baking(tmp_path, monkeypatch):
    from scratch_materials.precompute.biscale import bake, geometry

    f = tmp_path / "file"
    f.write_text("x")
    tile = geometry.pyramid_tile()

    def no_bake(*a, **k):  # the bake must not start when its table cannot be written
        raise AssertionError("baked before checking the output folder")

    monkeypatch.setattr(bake, "get_tile", no_bake)
    with pytest.raises(ValueError, match="exr_dir.*Not a directory"):
        bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, [{"model": "lambert", "albedo": 0.5}],
                         exr_dir=str(f / "tables"))


def test_bake_tables_default_folder_falls_back_and_a_late_write_failure_keeps_the_bake(cache_dir, monkeypatch):
    from scratch_materials.precompute.biscale import bake, effective, geometry

    cache_dir.mkdir()
    (cache_dir / "biscale").write_text("a file where the table folder should be")
    tile = geometry.pyramid_tile()
    small = dict(n_facets=200, dir_res=4, normal_res=21, l_M=40)
    mats = [{"model": "lambert", "albedo": 0.5}]
    with pytest.warns(cache.CacheWarning, match="bi-scale table folder unusable"):
        brdf, fit, info = bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, mats, n_lobes=1, **small)
    assert os.path.dirname(info["exr"]) == str(cache_dir) and os.path.isfile(info["exr"])

    def disk_full(self, path):
        raise OSError(28, "No space left on device", path)

    (cache_dir / "biscale").unlink()
    monkeypatch.setattr(effective.EffectiveBRDF, "save_exr", disk_full)
    with pytest.warns(cache.CacheWarning, match="No space left"):
        brdf2, _, info2 = bake.bake_tables(tile.vertices, tile.faces, tile.face_material, 1.0, mats, n_lobes=1, **small)
    assert info2["exr"] is None and np.array_equal(brdf2.table, brdf.table)


def test_write_exr_to_a_folder_or_an_unwritable_place_names_the_path(tmp_path):
    """Issue #14: ``ScratchBRDF.save`` / ``write_exr`` onto a folder wrote its temp file into the folder's parent and
    died with IsADirectoryError about the temp file; a missing or impossible parent named only the temp file.
    Now: a folder is a ValueError naming ``path``; an OSError names the user's path; nothing is left behind."""
    a = {"x": np.ones((2, 2), np.float32)}
    (tmp_path / "sub").mkdir()
    with pytest.raises(ValueError, match="path"):
        exr_io.write_exr(tmp_path / "sub", a)
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(OSError, match="file/x.exr"):
        exr_io.write_exr(blocker / "x.exr", a)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "sub"] and not any((tmp_path / "sub").iterdir())


def test_full_disk_while_writing_a_cache_entry_still_returns_the_result(cache_dir, monkeypatch):
    """A full disk (found with a 200 kB tmpfs as the cache folder): OpenEXR reports the failed write as a
    RuntimeError, which went through the cache and ``simulate(..., cache=True)`` after the whole computation.
    Now it is an OSError naming the path (ENOSPC): the cache warns once, returns the result, leaves no file."""
    real = exr_io._openexr()

    class FullDisk:
        def __init__(self, header, arrays):
            pass

        def write(self, path):
            open(path, "wb").write(b"partial")
            raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')

    class Fake:
        File = FullDisk
        ZIP_COMPRESSION, scanlineimage = real.ZIP_COMPRESSION, real.scanlineimage

    monkeypatch.setattr(exr_io, "_openexr", lambda: Fake)
    with pytest.warns(cache.CacheWarning, match="No space left on device"):
        out = cache.cached_arrays("fault", "1", {"x": 1}, lambda: {"a": np.ones((2, 2))})
    assert np.array_equal(out["a"], np.ones((2, 2)))
    assert not [p for p in os.listdir(cache_dir) if not p.startswith(".")] and not [
        p for p in os.listdir(cache_dir) if p.startswith(files.TMP_PREFIX)]
    with pytest.raises(OSError) as exc:
        exr_io.write_exr(os.path.join(cache_dir, "y.exr"), {"a": np.ones((2, 2))})
    assert exc.value.errno == errno.ENOSPC and "y.exr" in str(exc.value)
