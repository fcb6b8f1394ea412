"""Layout contracts (fast, no Blender): the science never imports Blender, each paper's subpackage keeps
to itself and the shared parts, and every module of the extension has one import identity."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("precompute", "osl", "node_groups", "scratch_addon")
PAPERS = ("scratch", "microgeometry", "biscale", "iridescence")
SHARED = ("cycles", "tables", "validation", "parallel")
BLENDER = {"bpy", "bmesh", "mathutils", "addon_utils", "cycles", "_cycles", "bl_ui", "bl_operators"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """(absolute module name, line) of every import in ``path``; relative imports resolved against the
    repository root as the package root (``from ..precompute import x`` in scratch_addon -> precompute.x)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)] if package else []
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out += [(f"{mod}.{a.name}" if mod else a.name, node.lineno) for a in node.names]
    return out


def _files(*folders):
    return sorted(f for d in folders for f in (ROOT / d).rglob("*.py"))


def test_precompute_sources_never_import_blender_modules():
    files = _files("precompute")
    assert len(files) > 20
    offenders = {str(f.relative_to(ROOT)): sorted({m for m, _ in _imports(f)} & BLENDER) for f in files}
    assert not {k: v for k, v in offenders.items() if v}


def test_precompute_imports_in_a_process_without_bpy():
    code = (
        "import sys, pkgutil, importlib\n"
        "sys.modules['bpy'] = None  # any import of bpy now raises ImportError\n"
        "import scratch_materials.precompute as pc\n"
        "mods = [m.name for m in pkgutil.walk_packages(pc.__path__, pc.__name__ + '.')]\n"
        "[importlib.import_module(m) for m in mods]\n"
        "import precompute.profiles, precompute.fresnel, precompute.scratch_brdf  # the README's public names\n"
        "print(len(mods))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 30


def test_each_paper_imports_only_itself_and_the_shared_parts():
    bad = []
    for paper in PAPERS:
        for f in _files(f"precompute/{paper}"):
            for mod, line in _imports(f):
                parts = mod.split(".")
                if parts[0] != "precompute" or len(parts) < 2:
                    continue
                if parts[1] not in (paper, *SHARED):
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {mod}")
    assert not bad, "\n".join(bad)


def test_one_import_identity():
    # Our own packages are reached by relative imports only (one name per module, no top-level
    # ``precompute`` that could clash with another add-on's); no importlib in the normal imports and
    # no sys.path edits, except the two documented entry points below.
    allowed = {
        ("scratch_addon/cli.py", "importlib"),    # run as a script: loads the root package by its file
        ("scratch_addon/osl_compile.py", "sys.path"),  # Blender's own oslquery folder (not ours)
    }
    bad = []
    for f in _files(*PACKAGES):
        rel = str(f.relative_to(ROOT))
        text = f.read_text()
        for mod, line in _imports(f):
            top = mod.split(".")[0]
            if top in PACKAGES and not text.splitlines()[line - 1].lstrip().startswith("from ."):
                bad.append(f"{rel}:{line} absolute import of our package {mod}")
            if top == "importlib" and (rel, "importlib") not in allowed:
                bad.append(f"{rel}:{line} imports importlib")
        for node in ast.walk(ast.parse(text)):
            target = node.func.value if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) else None
            if isinstance(target, ast.Attribute) and ast.unparse(target) == "sys.path" \
                    and (rel, "sys.path") not in allowed:
                bad.append(f"{rel}:{node.lineno} edits sys.path")
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__":
                bad.append(f"{rel}:{node.lineno} calls __import__")
    assert not bad, "\n".join(bad)


def test_root_package_and_manifest():
    import tomllib

    # the root imports nothing at load time (Blender calls register(); the science needs no bpy)
    tree = ast.parse((ROOT / "__init__.py").read_text())
    assert not [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert {n.name for n in tree.body if isinstance(n, ast.FunctionDef)} == {"register", "unregister"}
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["schema_version"] == "1.0.0" and manifest["id"] == "scratch_addon"
    assert manifest["blender_version_min"] == "4.2.0"
    assert "files" in manifest["permissions"] and "network" not in manifest["permissions"]
    for folder in (*PACKAGES, "tests", "bench"):
        assert (ROOT / folder).is_dir(), folder
    for paper in PAPERS + SHARED[:2]:
        init = ROOT / "precompute" / paper / "__init__.py"
        assert init.is_file() and ast.get_docstring(ast.parse(init.read_text())), paper
