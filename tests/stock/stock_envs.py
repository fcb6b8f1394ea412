"""Stock-Blender Python environments: ``python3 -m venv .stock/bpy-<v>`` + ``pip install bpy==<v>``, nothing else.

Cached (git-ignored) under ``<repo>/.stock/bpy-<version>``.  A stamp file written after a verified
install marks an environment complete; without it (a half-made environment, an interrupted pip) the
folder is verified and stamped, or deleted and rebuilt.  An environment in which the add-on's own
dependencies (scipy, OpenEXR, matplotlib) are importable is not stock and is rebuilt too.

Pre-create them from the command line (the tests do it on first use)::

    .venv/bin/python tests/stock/stock_envs.py 5.0.1 4.5.15 4.2.23
"""
from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
STOCK = ROOT / ".stock"
STAMP = ".stock-ready"
NOT_STOCK = ("scipy", "OpenEXR", "matplotlib")


class StockEnvError(RuntimeError):
    pass


def env_dir(version: str) -> Path:
    return STOCK / f"bpy-{version}"


def env_python(version: str) -> Path:
    return env_dir(version) / "bin" / "python"


def base_python() -> str:
    """A Python 3.11 to make venvs from: $STOCK_PYTHON, else the interpreter this venv was made from."""
    exe = os.environ.get("STOCK_PYTHON") or getattr(sys, "_base_executable", None) or shutil.which("python3")
    if not exe:
        raise StockEnvError("no python3 to create the stock environments with (set STOCK_PYTHON)")
    return exe


def _clean_env() -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "BLENDER_USER_RESOURCES", "SCRATCH_ADDON_CACHE")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


_PROBE = """\
import importlib.util, json, sys
out = {"python": sys.version.split()[0],
       "present": [m for m in %r if importlib.util.find_spec(m) is not None],
       "bpy": importlib.util.find_spec("bpy") is not None}
try:
    from importlib.metadata import version
    out["bpy_version"] = version("bpy")
except Exception as exc:  # noqa: BLE001
    out["bpy_version"] = repr(exc)
print(json.dumps(out))
""" % (NOT_STOCK,)


def probe(version: str) -> dict:
    """What the environment holds (without importing bpy: fast)."""
    import json

    py = env_python(version)
    if not py.exists():
        return {"exists": False}
    proc = subprocess.run([str(py), "-c", _PROBE], capture_output=True, text=True, env=_clean_env(), timeout=120)
    if proc.returncode != 0:
        return {"exists": True, "error": proc.stderr[-2000:]}
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["exists"] = True
    pip = subprocess.run([str(py), "-m", "pip", "check"], capture_output=True, text=True, env=_clean_env(), timeout=300)
    out["pip_check"] = pip.returncode == 0
    out["pip_check_output"] = (pip.stdout + pip.stderr)[-1000:]
    return out


def _complete(info: dict, version: str) -> bool:
    return (info.get("exists") and "error" not in info and info.get("bpy") and info.get("bpy_version") == version
            and info.get("pip_check") and not info.get("present"))


@contextmanager
def _lock(version: str):
    STOCK.mkdir(parents=True, exist_ok=True)
    with open(STOCK / f".bpy-{version}.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def ensure_env(version: str, log=print) -> Path:
    """The stock environment's python for ``bpy==version``, created on first use."""
    d = env_dir(version)
    stamp = d / STAMP
    want = f"bpy=={version}\n"
    with _lock(version):
        if stamp.is_file() and stamp.read_text() == want and env_python(version).exists():
            info = probe(version) if os.environ.get("STOCK_VERIFY") else None
            if info is None or _complete(info, version):
                return env_python(version)
        if d.exists():
            info = probe(version)
            if _complete(info, version):        # made before stamps existed (or stamp lost): adopt it
                stamp.write_text(want)
                return env_python(version)
            log(f"[stock] {d} is incomplete or not stock ({info}); rebuilding")
            shutil.rmtree(d)
        log(f"[stock] creating {d} (python -m venv + pip install bpy=={version}; about 1 GB, a few minutes)")
        logfile = STOCK / f"log-{version}"
        exe = base_python()
        steps = [([exe, "-m", "venv", str(d)], "python -m venv"),
                 ([str(env_python(version)), "-m", "pip", "install", f"bpy=={version}"], f"pip install bpy=={version}")]
        with open(logfile, "w") as fh:
            for cmd, what in steps:
                fh.write(f"$ {' '.join(cmd)}\n")
                fh.flush()
                proc = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                      env=_clean_env(), cwd=STOCK, timeout=3600)
                fh.write(proc.stdout)
                if proc.returncode != 0:
                    tail = "\n".join(proc.stdout.strip().splitlines()[-15:])
                    raise StockEnvError(f"{what} failed (exit {proc.returncode}) for the stock environment {d}; "
                                        f"full log: {logfile}\n{tail}")
        info = probe(version)
        if not _complete(info, version):
            raise StockEnvError(f"stock environment {d} is not usable after pip install bpy=={version}: {info}")
        stamp.write_text(want)
        return env_python(version)


if __name__ == "__main__":
    for v in sys.argv[1:] or ["5.0.1", "4.5.15", "4.2.23"]:
        print(v, ensure_env(v))
