#!/usr/bin/env python3
"""Build the extension zips, one per platform, with the runtime wheels bundled (issue #12).

A stock Blender's Python has numpy but no scipy and no OpenEXR, so each zip ships them as
wheels (Blender's extension "Python Wheels": ``wheels = [...]`` + ``platforms = [...]`` in the
manifest).  The pins are the lines of ``requirements.txt`` that end in ``# bundled``.

For each platform::

    pip download --no-deps --only-binary=:all: --platform <tag> --python-version 3.11
                 --implementation cp --dest wheels/ <pins>          (skipped when cached)

then, in a staging copy of the source tree (the committed ``blender_manifest.toml`` is never
touched), the staged manifest gets that platform's ``wheels`` and ``platforms`` and Blender's own
``blender_ext.py build --split-platforms`` writes ``scratch_addon-<version>-<platform>.zip``,
``blender_ext.py validate`` checks it, and :func:`check_zip` checks its contents (exactly the
platform's wheels, mapped by Blender's own wheel-tag rules; the manifest declares that one
platform; no dev files).  Only zips that pass reach ``--output-dir``.

Usage::

    python build.py [--platform linux-x64 ...] [--output-dir dist]
    from build import build; build(["linux-x64"], "dist")   # -> [Path(...zip)]

Errors (unknown platform, failed download, failed check) print one line and exit with status 2.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import re
import runpy
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
REQUIREMENTS = ROOT / "requirements.txt"
WHEELS = ROOT / "wheels"          # the download cache (git-ignored), see ensure_wheels
MANIFEST = "blender_manifest.toml"
PYTHON_VERSION = "3.11"        # Blender 4.2 ... 5.0 embed CPython 3.11

#: Blender platform -> the pip ``--platform`` tag its wheels are downloaded for.
PLATFORMS: dict[str, str] = {
    "linux-x64": "manylinux2014_x86_64",
    "windows-x64": "win_amd64",
    "macos-arm64": "macosx_12_0_arm64",     # scipy's minimum macOS on arm64
    "macos-x64": "macosx_11_0_x86_64",
}

#: Top-level names the source staging copy leaves out (never shipped; some are huge).
_STAGE_SKIP_TOP = {"dist", "wheels", "renders"}
#: Paths a zip must not contain (first path component), besides dot-files, caches and other wheels.
_FORBIDDEN_TOP = {"tests", "bench", "docs", "renders", "dist", "build.py", "Makefile", "requirements.txt",
                  "pytest.ini", "CONTRIBUTING.md"}
_REQUIRED = ("blender_manifest.toml", "__init__.py", "scratch_addon/__init__.py", "precompute/__init__.py")


class BuildError(Exception):
    """A build failure with a one-line message for the user."""


# --------------------------------------------------------------------------- pins and wheels

def _canonical(name: str) -> str:
    """PEP 503 normalised project name (``OpenEXR`` -> ``openexr``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def bundled_pins(requirements: Path = REQUIREMENTS) -> list[tuple[str, str]]:
    """``(name, version)`` of each ``name==version`` line of requirements.txt ending in ``# bundled``."""
    pins = []
    for n, line in enumerate(requirements.read_text().splitlines(), 1):
        if not re.search(r"#\s*bundled\s*$", line):
            continue
        req = line.split("#", 1)[0].strip()
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)\s*==\s*([A-Za-z0-9.+!_-]+)", req)
        if not m:
            raise BuildError(f"{requirements.name}:{n}: a '# bundled' line must pin 'name==version', found {req!r}")
        pins.append((m.group(1), m.group(2)))
    if not pins:
        raise BuildError(f"{requirements.name}: no line ends in '# bundled' (the runtime pins to ship)")
    return pins


def parse_wheel_filename(filename: str) -> dict[str, str]:
    """Fields of ``{dist}-{version}(-{build})?-{python}-{abi}-{platform}.whl`` (PEP 427)."""
    parts = filename[:-len(".whl")].split("-") if filename.endswith(".whl") else []
    if len(parts) not in (5, 6):
        raise BuildError(f"not a wheel filename: {filename!r}")
    return {"name": _canonical(parts[0]), "version": parts[1], "python": parts[-3], "abi": parts[-2],
            "platform": parts[-1]}


def blender_ext_cli() -> Path:
    """Blender's extension build/validate CLI shipped inside the bpy wheel (as the Makefile finds it)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise BuildError("bpy is not installed in this Python (run `make venv` and use .venv/bin/python)")
    hits = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not hits:
        raise BuildError(f"blender_ext.py not found under {Path(spec.origin).parent}")
    return hits[-1]


_EXT_NS: dict | None = None


def blender_ext() -> dict:
    """The namespace of Blender's ``blender_ext.py`` (its wheel-platform and manifest rules)."""
    global _EXT_NS
    if _EXT_NS is None:
        _EXT_NS = runpy.run_path(str(blender_ext_cli()), run_name="blender_ext")
    return _EXT_NS


def wheel_platforms(filename: str) -> list[str]:
    """Blender platforms a wheel installs on, by Blender's own rules (``["*"]`` for ``any``)."""
    tag = parse_wheel_filename(filename)["platform"]
    # The whole tag, compressed sets included (manylinux_2_17_x86_64.manylinux2014_x86_64), exactly as
    # Blender's builder filters wheels per platform (blender_platform_compatible_with_wheel_platform).
    return ["*"] if tag == "any" else blender_ext()["blender_platforms_from_wheel_platform"](tag)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _load_index(wheels_dir: Path) -> dict:
    try:
        return json.loads((wheels_dir / "index.json").read_text())
    except (OSError, ValueError):
        return {}


def _check_wheel_for(platform: str, pin: tuple[str, str], filename: str) -> None:
    w = parse_wheel_filename(filename)
    if (w["name"], w["version"]) != (_canonical(pin[0]), pin[1]):
        raise BuildError(f"{platform}: pip gave {filename} for {pin[0]}=={pin[1]}")
    plats = wheel_platforms(filename)
    if "*" not in plats and platform not in plats:
        raise BuildError(f"{platform}: {filename} installs on {', '.join(plats)}, not {platform}")
    versions = blender_ext()["python_versions_from_wheel"](filename)
    if isinstance(versions, str) or not ({(3,), (3, 11)} & versions):
        raise BuildError(f"{platform}: {filename} is not for Python {PYTHON_VERSION} ({versions})")


def ensure_wheels(platform: str, pins: list[tuple[str, str]], *, wheels_dir: str | os.PathLike = WHEELS,
                  quiet: bool = False) -> list[Path]:
    """The wheels of ``pins`` for ``platform`` in ``wheels_dir``, downloading only those not cached.

    The cache is ``<wheels_dir>/index.json``: pip tag -> pin -> file name + sha256; a hit needs the
    file with that hash, so a truncated or replaced file is downloaded again.
    """
    tag = PLATFORMS[platform]
    cache = Path(wheels_dir).resolve()
    entries = _load_index(cache).get(tag, {})
    found: dict[str, Path] = {}
    for name, version in pins:
        key = f"{_canonical(name)}=={version}"
        e = entries.get(key)
        if e and (cache / e["file"]).is_file() and _sha256(cache / e["file"]) == e["sha256"]:
            found[key] = cache / e["file"]
    missing = [(n, v) for n, v in pins if f"{_canonical(n)}=={v}" not in found]
    if missing:
        cache.mkdir(parents=True, exist_ok=True)
        new: dict[str, dict] = {}
        with tempfile.TemporaryDirectory(prefix=".download-", dir=cache) as tmp:
            cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
                   "--platform", tag, "--python-version", PYTHON_VERSION, "--implementation", "cp",
                   "--dest", tmp, "--quiet", *[f"{n}=={v}" for n, v in missing]]
            if not quiet:
                print(f"{platform}: pip download {' '.join(f'{n}=={v}' for n, v in missing)} ({tag})", flush=True)
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                err = [ln.strip() for ln in (proc.stderr or proc.stdout).splitlines() if ln.strip()]
                errors = [ln for ln in err if ln.startswith("ERROR")]   # pip's last ERROR says what failed
                why = errors[-1] if errors else err[-1] if err else f"status {proc.returncode}"
                why = re.sub(r"\s*\(from versions:.*?\)", "", why)
                raise BuildError(f"download failed for {platform} ({tag}): {why}")
            got = sorted(p.name for p in Path(tmp).glob("*.whl"))
            for name, version in missing:
                key = f"{_canonical(name)}=={version}"
                mine = [f for f in got if (parse_wheel_filename(f)["name"], parse_wheel_filename(f)["version"])
                        == (_canonical(name), version)]
                if len(mine) != 1:
                    raise BuildError(f"download failed for {platform} ({tag}): expected one wheel of "
                                     f"{name}=={version}, got {mine or 'none'}")
                _check_wheel_for(platform, (name, version), mine[0])
                os.replace(Path(tmp) / mine[0], cache / mine[0])   # complete files only
                new[key] = {"file": mine[0], "sha256": _sha256(cache / mine[0])}
                found[key] = cache / mine[0]
        index = _load_index(cache)              # re-read: another build may have added entries meanwhile
        index.setdefault(tag, {}).update(new)
        fd, tmp_index = tempfile.mkstemp(prefix=".index-", dir=cache)
        with os.fdopen(fd, "w") as fh:
            fh.write(json.dumps(index, indent=1, sort_keys=True) + "\n")
        os.chmod(tmp_index, 0o644)
        os.replace(tmp_index, cache / "index.json")
    for (name, version) in pins:
        _check_wheel_for(platform, (name, version), found[f"{_canonical(name)}=={version}"].name)
    return [found[f"{_canonical(n)}=={v}"] for n, v in pins]


# --------------------------------------------------------------------------- staging and checks

def staged_manifest_text(text: str, wheels: list[str], platforms: list[str]) -> str:
    """``text`` with top-level ``wheels`` and ``platforms`` inserted before its first table."""
    data = tomllib.loads(text)
    for key in ("wheels", "platforms"):
        if key in data:
            raise BuildError(f"{MANIFEST} already declares '{key}'; build.py sets it per platform")
    block = ("# Added by build.py in the staging copy only.\n"
             "wheels = [\n" + "".join(f'  "./wheels/{w}",\n' for w in wheels) + "]\n"
             "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]\n\n")
    lines = text.splitlines(keepends=True)
    first_table = next((i for i, ln in enumerate(lines) if re.match(r"\s*\[", ln)), len(lines))
    out = "".join(lines[:first_table]) + block + "".join(lines[first_table:])
    if tomllib.loads(out) != {**data, "wheels": [f"./wheels/{w}" for w in wheels], "platforms": platforms}:
        raise BuildError(f"could not add wheels/platforms to {MANIFEST} (unexpected layout)")
    return out


def _stage_ignore(*skip_dirs: Path):
    def ignore(folder: str, names: list[str]) -> set[str]:
        skip = {n for n in names if n == "__pycache__" or n.endswith(".pyc")}
        here = Path(folder).resolve()
        if here == ROOT:
            skip |= {n for n in names if n.startswith(".") or n in _STAGE_SKIP_TOP}
        skip |= {n for n in names if (here / n).resolve() in skip_dirs}
        return skip
    return ignore


def _link_or_copy(src: Path, dst: Path) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def check_zip(zip_path: Path, platform: str, wheels: list[str], pins: list[tuple[str, str]]) -> list[str]:
    """Problems of a built zip (empty = fine): manifest, wheel set, platform tags, dev files."""
    problems: list[str] = []
    with zipfile.ZipFile(zip_path) as zf:
        names = [n for n in zf.namelist() if not n.endswith("/")]
        manifest = tomllib.loads(zf.read(MANIFEST).decode()) if MANIFEST in names else {}
    if not manifest:
        return [f"{zip_path.name}: no {MANIFEST}"]
    blender_ext()["pkg_manifest_dict_apply_build_generated_table"](manifest)
    if manifest.get("platforms") != [platform]:
        problems.append(f"manifest platforms {manifest.get('platforms')} != ['{platform}']")
    expect_name = f"{manifest['id']}-{manifest['version']}-{platform.replace('-', '_')}.zip"
    if zip_path.name != expect_name:
        problems.append(f"zip name {zip_path.name} != {expect_name}")
    in_zip = sorted(n.split("/", 1)[1] for n in names if n.startswith("wheels/"))
    if in_zip != sorted(wheels):
        problems.append(f"wheels in zip {in_zip} != expected {sorted(wheels)}")
    if sorted(manifest.get("wheels", [])) != sorted(f"./wheels/{w}" for w in wheels):
        problems.append(f"manifest wheels {manifest.get('wheels')} != expected")
    for w in in_zip:
        plats = wheel_platforms(w)
        if "*" not in plats and platform not in plats:
            problems.append(f"{w} is for {plats}, not {platform}")
    for name, version in pins:
        mine = [w for w in in_zip if (parse_wheel_filename(w)["name"], parse_wheel_filename(w)["version"])
                == (_canonical(name), version)]
        if len(mine) != 1:
            problems.append(f"{name}=={version}: {len(mine)} wheels in zip")
    for n in names:
        parts = n.split("/")
        if (parts[0] in _FORBIDDEN_TOP or any(p.startswith(".") for p in parts) or "__pycache__" in parts
                or n.endswith((".pyc", ".zip")) or (parts[0] == "wheels" and len(parts) != 2)):
            problems.append(f"dev file in zip: {n}")
    problems += [f"missing {r}" for r in _REQUIRED if r not in names]
    return problems


def _run_ext(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(blender_ext_cli()), *args], capture_output=True, text=True)


def _last_line(proc: subprocess.CompletedProcess) -> str:
    lines = [ln.strip() for ln in (proc.stdout + proc.stderr).splitlines() if ln.strip()]
    return lines[-1] if lines else f"status {proc.returncode}"


# --------------------------------------------------------------------------- build

def build(platforms: list[str] | None = None, output_dir: str | os.PathLike = "dist", *,
          wheels_dir: str | os.PathLike = WHEELS, quiet: bool = False) -> list[Path]:
    """Build, validate and check one zip per platform into ``output_dir``; return their paths.

    ``platforms``: Blender platform names from :data:`PLATFORMS` (None = all four);
    ``wheels_dir``: the wheel download cache (default: the repo's git-ignored wheels/).
    Raises :class:`BuildError` with a one-line message on any failure.
    """
    platforms = list(PLATFORMS) if not platforms else list(dict.fromkeys(platforms))
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown:
        raise BuildError(f"unknown platform {unknown[0]!r} (choose from {', '.join(PLATFORMS)})")
    output_dir, wheels_dir = Path(output_dir).resolve(), Path(wheels_dir).resolve()
    pins = bundled_pins()
    blender_ext()
    wheels = {p: ensure_wheels(p, pins, wheels_dir=wheels_dir, quiet=quiet) for p in platforms}

    manifest_text = (ROOT / MANIFEST).read_text()
    results: list[Path] = []
    with tempfile.TemporaryDirectory(prefix="scratch_build_") as tmp:
        stage, out = Path(tmp) / "src", Path(tmp) / "out"
        shutil.copytree(ROOT, stage, ignore=_stage_ignore(output_dir, wheels_dir))
        (stage / "wheels").mkdir()
        for ws in wheels.values():
            for w in ws:
                if not (stage / "wheels" / w.name).exists():
                    _link_or_copy(w, stage / "wheels" / w.name)
        for platform in platforms:
            names = [w.name for w in wheels[platform]]
            (stage / MANIFEST).write_text(staged_manifest_text(manifest_text, names, [platform]))
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            proc = _run_ext("build", "--split-platforms", "--source-dir", str(stage), "--output-dir", str(out))
            zips = sorted(out.glob("*.zip"))
            if proc.returncode != 0 or len(zips) != 1:
                raise BuildError(f"{platform}: blender_ext.py build failed: {_last_line(proc)}")
            proc = _run_ext("validate", str(zips[0]))
            if proc.returncode != 0:
                raise BuildError(f"{platform}: blender_ext.py validate {zips[0].name} failed: {_last_line(proc)}")
            problems = check_zip(zips[0], platform, names, pins)
            if problems:
                raise BuildError(f"{platform}: {zips[0].name}: " + "; ".join(problems))
            output_dir.mkdir(parents=True, exist_ok=True)
            dest = output_dir / zips[0].name
            shutil.move(str(zips[0]), str(dest))
            results.append(dest)
            if not quiet:
                print(f"{dest.name}  {dest.stat().st_size / 1e6:.1f} MB  ({', '.join(names)})", flush=True)
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="build.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("--platform", action="append", metavar="NAME",
                    help=f"build only this platform (repeatable; default: all of {', '.join(PLATFORMS)})")
    ap.add_argument("--output-dir", default="dist", help="where the zips go (default: dist)")
    ap.add_argument("--wheels-dir", default=str(WHEELS), help="wheel download cache (default: wheels/)")
    args = ap.parse_args(argv)
    # SIGTERM unwinds like Ctrl-C, so the staging and download temp dirs are removed.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(128 + signal.SIGTERM))
    t0 = time.perf_counter()
    try:
        zips = build(args.platform, args.output_dir, wheels_dir=args.wheels_dir)
    except BuildError as exc:
        print(f"build.py: error: {exc}", file=sys.stderr)
        return 2
    print(f"built {len(zips)} zip(s) into {Path(args.output_dir)} in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
