"""Helpers for file-system fault tests: permissions that hold even when the tests run as root.

Root ignores permission bits (CAP_DAC_OVERRIDE), so a read-only folder is writable to it.  A process
started through ``unprivileged(cmd)`` drops the capabilities that bypass them (``setpriv``), so it
meets a read-only folder as any artist or farm user would."""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

_DROP = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner"]


def unprivileged(cmd: list[str]) -> list[str]:
    """``cmd`` run so that permission bits apply to it (skips the test when that cannot be arranged)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return list(cmd)
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: permission faults cannot be exercised")
    probe = subprocess.run([*_DROP, "true"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"setpriv cannot drop capabilities here: {probe.stderr.decode().strip()}")
    return [*_DROP, *cmd]

