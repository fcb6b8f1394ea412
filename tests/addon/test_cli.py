"""The render CLI: real tiny renders succeed; bad input exits 2 with a message, no traceback."""
from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import ROOT

pytestmark = pytest.mark.bpy
CLI = str(ROOT / "scratch_addon" / "cli.py")


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, CLI, *args], capture_output=True, text=True, cwd=cwd or ROOT, timeout=300)


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--preset", "no_such_preset"], "--preset"),
        (["--res", "0", "10"], "--res"),
        (["--res", "10"], "--res"),
        (["--samples", "0"], "--samples"),
        (["--samples", "many"], "--samples"),
        (["--out", "x.jpg"], "--out"),
        (["--bogus"], "unrecognized"),
    ],
)
def test_bad_arguments_exit_2_without_traceback(args, needle, tmp_path):
    proc = _run(*args, "--out" if "--out" not in args else "--seed", str(tmp_path / "x.png") if "--out" not in args else "0")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert needle in proc.stderr and "Traceback" not in proc.stderr + proc.stdout
    assert not list(tmp_path.iterdir())  # nothing written


def test_blender_style_arguments_after_double_dash(tmp_path):
    # `blender -b -P cli.py -- args` leaves Blender's own arguments before "--".
    from scratch_materials.scratch_addon.cli import _script_args  # pytest.ini puts the repository on sys.path
    argv = ["blender", "-b", "-P", CLI, "--", "--preset", "demo", "--samples", "4"]
    assert _script_args(argv) == ["--preset", "demo", "--samples", "4"]
    assert _script_args(["cli.py", "--samples", "4"]) == ["--samples", "4"]


def test_tiny_render_writes_a_non_blank_png_and_prints_time(tmp_path):
    out = tmp_path / "demo.png"
    proc = _run("--preset", "demo", "--out", str(out), "--samples", "2", "--res", "48", "32")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "rendered" in proc.stdout and " s" in proc.stdout
    from matplotlib.image import imread

    img = imread(out)[..., :3]
    assert img.shape == (32, 48, 3)
    assert img.std() > 0.02 and 0.02 < img.mean() < 0.98  # not blank, not saturated


def test_list_presets():
    proc = _run("--list-presets")
    assert proc.returncode == 0 and "demo" in proc.stdout.split()


# ----------------------------------------------------------------------------- unwritable --out (issue #14 item 6)

# A render this size would take many minutes here: a run that ends in seconds failed before rendering.
_HUGE = ("--res", "4096", "4096", "--samples", "4096")


def _unwritable_out(kind, tmp_path):
    if kind == "path through a file":
        (tmp_path / "afile").write_text("x")
        return tmp_path / "afile" / "x.png"
    if kind == "read-only folder":
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        return ro / "x.png"
    if kind == "a directory named x.png":
        (tmp_path / "x.png").mkdir()
        return tmp_path / "x.png"
    assert kind == "read-only existing image"
    f = tmp_path / "x.png"
    f.write_bytes(b"old")
    f.chmod(0o444)
    return f


@pytest.mark.parametrize("kind", ["path through a file", "read-only folder", "a directory named x.png",
                                  "read-only existing image"])
def test_an_unwritable_out_fails_before_rendering_in_one_line_with_exit_2(kind, tmp_path):
    from fault_helpers import unprivileged

    out = _unwritable_out(kind, tmp_path)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    cmd = unprivileged([sys.executable, CLI, "--preset", "demo", "--out", str(out), *_HUGE])
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    err = proc.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in proc.stdout + proc.stderr, err
    assert "--out" in err and str(out) in err, err
    assert "rendered" not in proc.stdout
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written, no temp file left


def test_a_cache_folder_that_is_a_file_falls_back_with_a_one_line_warning(tmp_path):
    import os

    not_a_folder = tmp_path / "cache"
    not_a_folder.write_text("a file where the cache folder should be")
    out = tmp_path / "demo.png"
    env = dict(os.environ, SCRATCH_ADDON_CACHE=str(not_a_folder))
    proc = subprocess.run([sys.executable, CLI, "--preset", "demo", "--out", str(out), "--samples", "1",
                           "--res", "16", "16"], capture_output=True, text=True, cwd=ROOT, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.is_file() and not_a_folder.read_text().startswith("a file")
    warn = [ln for ln in proc.stderr.splitlines() if "warning" in ln and "cache folder" in ln]
    assert len(warn) == 1 and str(not_a_folder) in warn[0], proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
