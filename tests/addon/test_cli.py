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
