"""precompute.tables.cache / exr_io: bit-exact round trips, atomic writes, corrupt files recomputed."""
from __future__ import annotations

import os
import sys
import warnings

import numpy as np
import pytest

from scratch_materials.precompute.tables import cache, exr_io


@pytest.fixture
def cache_dir(tmp_path):
    cache.set_cache_dir(tmp_path)
    yield tmp_path
    cache.set_cache_dir(None)


def _tables(seed=0):
    rng = np.random.default_rng(seed)
    special = np.array([0.0, -0.0, 1e-45, 3.4e38, -3.4e38, np.float32(np.pi)], np.float32)
    rho = rng.standard_normal((16, 16)).astype(np.float32)
    rho.ravel()[: special.size] = special
    return {"rho": rho, "cdf": rng.random((16, 17)), "idx": np.arange(10, dtype=np.int32)}


def test_round_trip_is_bit_exact(cache_dir):
    calls = []

    def compute():
        calls.append(1)
        return _tables()

    a = cache.cached_arrays("t", "1", {"depth": 0.3, "profile": np.linspace(0, 1, 5)}, compute)
    b = cache.cached_arrays("t", "1", {"depth": 0.3, "profile": np.linspace(0, 1, 5)}, compute)
    assert len(calls) == 1
    assert a["rho"].tobytes() == b["rho"].tobytes()  # bit-exact, incl. -0.0 and denormals
    assert b["idx"].dtype == np.int32 and np.array_equal(a["idx"], b["idx"])
    np.testing.assert_array_equal(b["cdf"], a["cdf"].astype(np.float32))


def test_key_changes_with_any_input(cache_dir):
    base = cache.content_key("t", "1", {"x": 0.1, "a": np.zeros(3)})
    assert base == cache.content_key("t", "1", {"a": np.zeros(3), "x": 0.1})  # order-free
    assert base != cache.content_key("t", "1", {"x": np.nextafter(0.1, 1.0), "a": np.zeros(3)})
    assert base != cache.content_key("t", "1", {"x": 0.1, "a": np.zeros(3, np.float32)})
    assert base != cache.content_key("t", "2", {"x": 0.1, "a": np.zeros(3)})
    assert base != cache.content_key("u", "1", {"x": 0.1, "a": np.zeros(3)})
    with pytest.raises(TypeError, match="cannot hash"):
        cache.content_key("t", "1", {"x": object()})


def test_corrupt_file_is_recomputed_with_a_warning(cache_dir):
    cache.cached_arrays("t", "1", {"k": 1}, _tables)
    (path,) = list(cache_dir.glob("t-*.exr"))
    path.write_bytes(path.read_bytes()[:100])  # truncated
    with pytest.warns(cache.CacheWarning, match="recomputing"):
        again = cache.cached_arrays("t", "1", {"k": 1}, lambda: _tables(seed=0))
    np.testing.assert_array_equal(again["rho"], _tables()["rho"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the rewritten file is good again
        cache.cached_arrays("t", "1", {"k": 1}, lambda: pytest.fail("should be cached"))


def test_failed_write_leaves_no_file(tmp_path, monkeypatch):
    import OpenEXR

    class Boom(Exception):
        pass

    def broken_write(self, path):
        with open(path, "wb") as f:
            f.write(b"partial")
        raise Boom("disk full")

    monkeypatch.setattr(OpenEXR.File, "write", broken_write)
    target = tmp_path / "t.exr"
    with pytest.raises(Boom):
        exr_io.write_exr(target, {"R": np.ones((2, 2), np.float32)})
    assert os.listdir(tmp_path) == []


def test_exr_io_errors_name_the_problem(tmp_path):
    with pytest.raises(ValueError, match="channels"):
        exr_io.write_exr(tmp_path / "a.exr", {"R": np.ones(3)})
    with pytest.raises(ValueError, match="differs"):
        exr_io.write_exr(tmp_path / "a.exr", {"R": np.ones((2, 2)), "G": np.ones((2, 3))})
    with pytest.raises(exr_io.ExrError, match="no such file"):
        exr_io.read_exr(tmp_path / "missing.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr")
    with pytest.raises(exr_io.ExrError, match="unreadable"):
        exr_io.read_exr(tmp_path / "junk.exr")


def test_clear_and_disabled_cache(cache_dir):
    cache.cached_arrays("t", "1", {"k": 1}, _tables)
    cache.cached_arrays("u", "1", {"k": 1}, _tables)
    assert cache.clear("t") == 1 and cache.clear() == 1
    calls = []
    cache.cached_arrays("t", "1", {"k": 1}, lambda: calls.append(1) or _tables(), enabled=False)
    cache.cached_arrays("t", "1", {"k": 1}, lambda: calls.append(1) or _tables(), enabled=False)
    assert len(calls) == 2 and not list(cache_dir.glob("*.exr"))


def test_code_version_tracks_source(tmp_path, monkeypatch):
    import importlib

    monkeypatch.syspath_prepend(str(tmp_path))
    (tmp_path / "mod_a.py").write_text("X = 1\n")
    a = importlib.import_module("mod_a")
    v1 = cache.code_version(a)
    assert v1 == cache.code_version(a)
    (tmp_path / "mod_a.py").write_text("X = 2\n")
    assert cache.code_version(a) != v1
    with pytest.raises(TypeError, match="no source file"):
        cache.code_version(sys)
