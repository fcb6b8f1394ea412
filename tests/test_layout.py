"""Layout contracts: precompute never imports bpy; the root shim stays two lines."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in ("import_module", "__import__"):
            if node.args and isinstance(node.args[0], ast.Constant) and str(node.args[0].value).split(".")[0] in ("bpy", "bmesh", "mathutils"):
                names.add(str(node.args[0].value).split(".")[0])
    return names


def test_precompute_sources_never_import_blender_modules():
    files = sorted((ROOT / "precompute").rglob("*.py"))
    assert files, "precompute/ has no modules"
    offenders = {str(f.relative_to(ROOT)): sorted(_imports(f) & {"bpy", "bmesh", "mathutils", "addon_utils"}) for f in files}
    assert not {k: v for k, v in offenders.items() if v}


def test_precompute_imports_in_a_process_without_bpy():
    code = (
        "import sys, pkgutil, importlib, precompute\n"
        "sys.modules['bpy'] = None  # any import of bpy now raises ImportError\n"
        "mods = [m.name for m in pkgutil.iter_modules(precompute.__path__)]\n"
        "[importlib.import_module('precompute.' + m) for m in mods]\n"
        "print(len(mods))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 2


def test_root_shim_is_two_lines_and_manifest_fields():
    import tomllib

    lines = [ln for ln in (ROOT / "__init__.py").read_text().splitlines() if ln.strip()]
    assert len(lines) == 2
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["schema_version"] == "1.0.0" and manifest["id"] == "scratch_addon"
    assert manifest["blender_version_min"] == "4.2.0"
    assert "files" in manifest["permissions"] and "network" not in manifest["permissions"]
    for folder in ("scratch_addon", "precompute", "osl", "node_groups", "tests", "bench"):
        assert (ROOT / folder).is_dir(), folder
