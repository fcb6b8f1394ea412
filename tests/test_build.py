"""Per-platform extension zips with bundled wheels (build.py, issue #12), and what the add-on imports.

The build test runs ``python build.py`` for all four platforms into a temp dir (the wheels are
cached in the repo's git-ignored wheels/, so only the first run downloads, ~150 MB) and checks each
zip independently of build.py's own checks: Blender's validator, the wheel set against the
``# bundled`` pins of requirements.txt and against Blender's own wheel-tag -> platform rules, the
manifest's single platform, the size and the absence of dev files.  No bpy import in this process:
Blender's ``blender_ext.py`` is located with ``find_spec`` and loaded as a plain script.

The static test parses every shipped Python file and checks that each import resolves to the
standard library, numpy, Blender's own modules, the extension's packages or a bundled wheel; any
other package must be imported inside ``try: ... except ImportError`` (optional at run time).
"""
from __future__ import annotations

import ast
import hashlib
import importlib.machinery
import importlib.metadata
import importlib.util
import os
import re
import runpy
import subprocess
import sys
import tomllib
import zipfile
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PLATFORMS = ("linux-x64", "windows-x64", "macos-arm64", "macos-x64")
MAX_ZIP_MB = 80.0
OWN_PACKAGES = {"scratch_addon", "precompute", "osl", "node_groups"}
SHIPPED = ("__init__.py", "scratch_addon", "precompute", "osl", "node_groups")
# Modules a Blender (4.2 ... 5.0) provides to extensions: its API modules and bpy's numpy.
BLENDER_MODULES = {"bpy", "bpy_extras", "mathutils", "bmesh", "addon_utils", "cycles", "_cycles", "oslquery",
                   "gpu", "gpu_extras", "numpy"}
DEV_TOP = {"tests", "bench", "docs", "renders", "dist", "wheels", "build.py", "Makefile", "requirements.txt",
           "pytest.ini", "CONTRIBUTING.md"}


def bundled_pins() -> dict[str, str]:
    """Canonical name -> version of the ``# bundled`` lines of requirements.txt (parsed here, not by build.py)."""
    pins = {}
    for line in (ROOT / "requirements.txt").read_text().splitlines():
        if re.search(r"#\s*bundled\s*$", line):
            name, version = line.split("#", 1)[0].strip().split("==")
            pins[re.sub(r"[-_.]+", "-", name.strip()).lower()] = version.strip()
    return pins


@lru_cache(maxsize=1)
def blender_ext() -> tuple[Path, dict]:
    """Blender's extension CLI inside the bpy wheel (path, namespace), without importing bpy."""
    spec = importlib.util.find_spec("bpy")
    assert spec is not None and spec.origin, "bpy is not installed"
    cli = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))[-1]
    return cli, runpy.run_path(str(cli), run_name="blender_ext")


# --------------------------------------------------------------------------- the zips

@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """{platform: zip path} from one `python build.py --output-dir <tmp>` run (all four platforms)."""
    out = tmp_path_factory.mktemp("dist")
    manifest_before = hashlib.sha256((ROOT / "blender_manifest.toml").read_bytes()).hexdigest()
    proc = subprocess.run([sys.executable, str(ROOT / "build.py"), "--output-dir", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    # The build works in a staging copy: the committed manifest is never rewritten.
    assert hashlib.sha256((ROOT / "blender_manifest.toml").read_bytes()).hexdigest() == manifest_before
    version = tomllib.loads((ROOT / "blender_manifest.toml").read_text())["version"]
    zips = {p: out / f"scratch_addon-{version}-{p.replace('-', '_')}.zip" for p in PLATFORMS}
    assert sorted(out.iterdir()) == sorted(zips.values()), proc.stdout
    for z in zips.values():   # build.py prints each zip's name and size
        assert re.search(rf"{re.escape(z.name)}\s+\d+\.\d MB", proc.stdout), proc.stdout
    return zips


@pytest.mark.parametrize("platform", PLATFORMS)
def test_zip_per_platform(built, platform):
    cli, ext = blender_ext()
    zip_path = built[platform]
    proc = subprocess.run([sys.executable, str(cli), "validate", str(zip_path)], capture_output=True, text=True)
    assert proc.returncode == 0 and "Success" in proc.stdout, proc.stdout + proc.stderr

    size_mb = zip_path.stat().st_size / 1e6
    assert 1.0 < size_mb < MAX_ZIP_MB, size_mb   # > 1 MB: scipy is in it (a bare zip is ~0.3 MB)

    with zipfile.ZipFile(zip_path) as zf:
        names = [n for n in zf.namelist() if not n.endswith("/")]
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    ext["pkg_manifest_dict_apply_build_generated_table"](manifest)   # what Blender reads at install
    assert manifest["platforms"] == [platform]

    wheels = sorted(n.removeprefix("wheels/") for n in names if n.startswith("wheels/"))
    assert sorted(w.removeprefix("./wheels/") for w in manifest["wheels"]) == wheels
    pins = bundled_pins()
    assert set(pins) >= {"scipy", "openexr"}
    by_name = {}
    for w in wheels:
        dist, version, *_, py_tag, abi_tag, plat_tag = w[:-len(".whl")].split("-")
        by_name.setdefault(re.sub(r"[-_.]+", "-", dist).lower(), []).append(version)
        assert platform in ext["blender_platforms_from_wheel_platform"](plat_tag), (w, platform)
        assert (py_tag, abi_tag) == ("cp311", "cp311"), w   # Blender 4.2 ... 5.0 embed CPython 3.11
    assert by_name == {name: [version] for name, version in pins.items()}   # one wheel per pin, no others

    for n in names:
        parts = n.split("/")
        assert parts[0] not in DEV_TOP or (parts[0] == "wheels" and len(parts) == 2), n
        assert not any(p.startswith(".") for p in parts), n          # .venv, .stock, .git, .hypothesis ...
        assert "__pycache__" not in parts and not n.endswith((".pyc", ".zip")), n
    for required in ("__init__.py", "blender_manifest.toml", *(f"{p}/__init__.py" for p in sorted(OWN_PACKAGES))):
        assert required in names, required


def test_build_rejects_unknown_platform(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "build.py"), "--platform", "linux-arm64",
                           "--output-dir", str(tmp_path)], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1 and "linux-arm64" in proc.stderr, proc.stderr
    assert not list(tmp_path.iterdir())


def test_build_reports_failed_download(tmp_path):
    """An empty wheel cache and an unreachable index: one error line, status 2, no zip."""
    env = {**os.environ, "PIP_CONFIG_FILE": os.devnull, "PIP_INDEX_URL": "http://127.0.0.1:9/simple",
           "PIP_EXTRA_INDEX_URL": "", "PIP_FIND_LINKS": "", "PIP_NO_CACHE_DIR": "1", "PIP_RETRIES": "0",
           "PIP_DEFAULT_TIMEOUT": "5"}
    proc = subprocess.run([sys.executable, str(ROOT / "build.py"), "--platform", "linux-x64",
                           "--output-dir", str(tmp_path / "out"), "--wheels-dir", str(tmp_path / "wheels")],
                          cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "download failed for linux-x64" in lines[0], proc.stderr
    assert not (tmp_path / "out").exists()
    assert not list((tmp_path / "wheels").glob("*.whl"))


# --------------------------------------------------------------------------- what the add-on imports

def _top_level_modules(dist_name: str) -> set[str]:
    """Importable top-level names of an installed distribution (packages and extension modules)."""
    files = importlib.metadata.distribution(dist_name).files or []
    suffixes = sorted(importlib.machinery.all_suffixes(), key=len, reverse=True)
    names = set()
    for f in files:
        head = f.parts[0]
        if len(f.parts) > 1:
            if head.isidentifier():           # skips scipy.libs/, *.dist-info/
                names.add(head)
        else:
            for s in suffixes:
                if head.endswith(s) and head[:-len(s)].isidentifier():
                    names.add(head[:-len(s)])
                    break
    return names


def _bundled_modules() -> set[str]:
    mods = set()
    for name, version in bundled_pins().items():
        assert importlib.metadata.version(name) == version, f"dev venv {name} differs from the pin (make venv)"
        mods |= _top_level_modules(name)
    return mods


def _guarded(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    """Inside the body of a ``try`` that catches ImportError (or a base of it)."""
    catches = {"ImportError", "ModuleNotFoundError", "Exception", "BaseException"}
    child, p = node, parents.get(node)
    while p is not None:
        if isinstance(p, ast.Try) and child in p.body:
            for h in p.handlers:
                types = h.type.elts if isinstance(h.type, ast.Tuple) else [h.type]
                if h.type is None or any(isinstance(t, ast.Name) and t.id in catches for t in types):
                    return True
        child, p = p, parents.get(p)
    return False


def _imports(path: Path):
    """(top-level module, line, guarded) of each absolute import, incl. constant dynamic imports."""
    tree = ast.parse(path.read_text(), filename=str(path))
    parents = {c: p for p in ast.walk(tree) for c in ast.iter_child_nodes(p)}
    for node in ast.walk(tree):
        mods = []
        if isinstance(node, ast.Import):
            mods = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            mods = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            func = getattr(node.func, "attr", getattr(node.func, "id", ""))
            if func in ("import_module", "__import__", "sibling"):   # sibling: scratch_addon/_deps.py
                mods = [node.args[0].value]
        for m in mods:
            yield m.split(".")[0], node.lineno, _guarded(node, parents)


def test_shipped_imports_resolve_in_a_stock_blender():
    # scratch_materials: the extension root's TD name (cli.py loads the root __init__.py under it)
    allowed = set(sys.stdlib_module_names) | BLENDER_MODULES | OWN_PACKAGES | {"scratch_materials"} | _bundled_modules()
    assert {"scipy", "OpenEXR"} <= allowed
    files = [ROOT / "__init__.py"] + sorted(p for d in SHIPPED[1:] for p in (ROOT / d).rglob("*.py"))
    assert len(files) > 40
    bad, optional = [], []
    for f in files:
        for mod, line, guarded in _imports(f):
            if mod in allowed or mod.startswith("bl_"):
                continue
            (optional if guarded else bad).append(f"{f.relative_to(ROOT)}:{line}: {mod}")
    # Not shipped and not in a stock Blender: must be optional (try/except ImportError) or absent.
    assert not bad, "unbundled imports outside try/except ImportError:\n" + "\n".join(bad)
    assert all(o.split(": ")[-1] not in ("scipy", "OpenEXR") for o in optional)
