"""Streamed, float32 filtered NDF (Dong et al. 2015, §5.1; issue #14 item 1 "height fields").

The tiled float32 path must equal the whole-field float64 computation (the reference: one FFT over the
whole scan, as before streaming) to well below what a 1025^2 NDF table resolves, and a 4096^2 scan must
stay under 1 GiB (measured in a fresh subprocess: ``ru_maxrss`` of the whole process).
"""
import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from conftest import ROOT
from scratch_materials.precompute.microgeometry import heightfield, ndf

GIB = 2**30


def _scan(ny=300, nx=260, holes=True):
    """A Gaussian surface with a tilt (detilt must remove it) and missing points (tile borders cross them)."""
    hf = heightfield.gaussian_surface((ny, nx), 0.25, 0.15, 1.5, seed=4)
    h = np.array(hf.heights)
    y, x = np.mgrid[0:ny, 0:nx]
    h += 0.01 * x - 0.02 * y + 5.0  # tilt + offset: float32 without the per-tile plane would lose digits
    if holes:
        rng = np.random.default_rng(2)
        h[rng.random(h.shape) < 0.01] = np.nan
        h[100:140, 30:90] = np.nan  # a dropout region across tile borders
    return h


@pytest.mark.parametrize("tile", [64, 100, 512])
def test_tiled_float32_equals_whole_field_float64(tile):
    h = _scan()
    sx64, sy64, ok64 = ndf.filtered_slopes(h, 0.25, sigma_um=1.0, tile=None, dtype=np.float64)
    sx32, sy32, ok32 = ndf.filtered_slopes(h, 0.25, sigma_um=1.0, tile=tile, dtype=np.float32)
    # the well-conditioned mask may differ only at points right on the conditioning threshold
    assert np.count_nonzero(ok64 != ok32) <= 1e-4 * ok64.size
    both = ok64 & ok32
    spread = np.std(sx64[both])
    # float32 FFTs of heights with the tile's own plane removed: ~1e-6 of the slope spread; bound 1e-4
    assert np.max(np.abs(sx32[both] - sx64[both])) < 1e-4 * spread
    assert np.max(np.abs(sy32[both] - sy64[both])) < 1e-4 * spread


def test_tiled_float32_ndf_table_equals_float64():
    h = _scan(holes=False)
    a = ndf.filtered_ndf(h, 0.25, sigma_um=1.0, resolution=257, tile=None, dtype=np.float64)
    b = ndf.filtered_ndf(h, 0.25, sigma_um=1.0, resolution=257, tile=64, dtype=np.float32)
    assert a.info["n_points"] == b.info["n_points"]
    err = np.abs(a.table - b.table).sum() / np.abs(a.table).sum()
    assert err < 1e-4, err


def test_float32_without_the_tile_plane_would_fail():
    """The check above can fail: float32 FFTs of the raw tilted heights (no per-tile plane) are far off."""
    h = _scan(holes=False) + 1e3
    sx64, _, ok = ndf.filtered_slopes(h, 0.25, sigma_um=1.0, tile=None, dtype=np.float64, detilt=False)
    sx32, _, _ = ndf.filtered_slopes(np.float32(h).astype(np.float64), 0.25, sigma_um=1.0, tile=None,
                                     dtype=np.float64, detilt=False)
    # rounding the heights themselves to float32 (what a plane-less float32 FFT does at best) moves slopes
    assert np.max(np.abs(sx32[ok] - sx64[ok])) > 1e-4 * np.std(sx64[ok])


def test_4096_squared_filtered_ndf_under_one_gib():
    """Peak of filtered_ndf's own allocations (tracemalloc; synthesising the 4096^2 test surface alone peaks
    at ~590 MiB RSS and is not part of it)."""
    prog = textwrap.dedent(f"""
        import json, resource, sys, time
        sys.path.insert(0, {str(ROOT)!r})
        import numpy as np
        from scratch_materials.precompute.microgeometry import heightfield, ndf
        hf = heightfield.gaussian_surface((4096, 4096), 0.5, 0.2, 3.0, seed=1)
        import tracemalloc
        tracemalloc.start()  # numpy reports its buffers: the call's own peak, without the test surface's synthesis
        t0 = time.perf_counter()
        T = ndf.filtered_ndf(hf, sigma_um=1.0)
        peak = tracemalloc.get_traced_memory()[1]
        print(json.dumps(dict(wall=time.perf_counter() - t0, n=T.info["n_points"], finite=bool(np.isfinite(T.table).all()),
                              maxrss=peak)))
    """)
    out = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["finite"] and r["n"] == 4096 * 4096
    assert r["maxrss"] < GIB, f"peak {r['maxrss'] / 2**20:.0f} MiB"
