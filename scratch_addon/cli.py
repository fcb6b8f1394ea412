"""Scripted renders.  The same file works both ways:

    blender -b -P scratch_addon/cli.py -- --preset demo --out x.png --samples 32 --res 320 240
    .venv/bin/python scratch_addon/cli.py --preset demo --out x.png --samples 32 --res 320 240

Bad arguments, an unknown preset or an output path that cannot be written (checked before anything
is built or rendered) print a one-line error and exit with status 2; a file-system error later (the
disk fills during the render) prints one line and exits with status 1.  Warnings (an unusable cache
folder replaced by a temp folder, ...) are printed as one line each.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings


def _script_args(argv: list[str]) -> list[str]:
    """Arguments meant for this script: after ``--`` under Blender, else all of ``argv[1:]``."""
    if "--" in argv:
        return argv[argv.index("--") + 1:]
    return argv[1:]


def _import_api():
    if __package__:
        from . import api  # imported as <root>.scratch_addon.cli (bl_ext.<repo>.scratch_addon or scratch_materials)
        return api
    # Run as a script (``blender -b -P scratch_addon/cli.py``, from the repository or an installed
    # extension folder): load the extension root package from its own __init__.py under the TD name,
    # instead of putting its folder on sys.path (which would expose a top-level ``precompute``).
    if "scratch_materials" not in sys.modules:
        import importlib.util

        here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        spec = importlib.util.spec_from_file_location("scratch_materials", os.path.join(here, "__init__.py"),
                                                      submodule_search_locations=[here])
        root = importlib.util.module_from_spec(spec)
        sys.modules["scratch_materials"] = root
        spec.loader.exec_module(root)
    from scratch_materials.scratch_addon import api  # noqa: E402 - the root package loaded above
    return api


def _parser(preset_names: list[str]) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="scratch_addon/cli.py", description="Render a scratch-material preset with Cycles (CPU).")
    p.add_argument("--preset", default="demo", choices=preset_names, metavar="NAME",
                   help="material preset: " + ", ".join(preset_names))
    p.add_argument("--out", default="renders/demo.png", help="output image (.png or .exr)")
    p.add_argument("--samples", type=int, default=32, help="samples per pixel (1..65536)")
    p.add_argument("--res", type=int, nargs=2, default=(480, 320), metavar=("W", "H"), help="resolution in pixels")
    p.add_argument("--seed", type=int, default=0, help="Cycles sampling seed")
    p.add_argument("--layout", default="torus", choices=["torus", "highlights"],
                   help="scene: torus under a studio world, or highlights (a floor receding from the camera "
                        "under a small point light: the README demo)")
    p.add_argument("--osl", action="store_true", help="use the OSL shading backend")
    p.add_argument("--list-presets", action="store_true", help="print preset names and exit")
    return p


def _one_line_warnings(prog: str) -> None:
    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{prog}: warning: {' '.join(str(message).split())}", file=file or sys.stderr)

    warnings.showwarning = show


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv if argv is None else argv
    api = _import_api()
    parser = _parser(api.preset_names())
    args = parser.parse_args(_script_args(argv))  # exits 2 with a message on bad arguments
    if args.list_presets:
        print("\n".join(api.preset_names()))
        return 0
    if not 1 <= args.samples <= 65536:
        parser.error(f"--samples must be in [1, 65536], got {args.samples}")
    if not all(4 <= r <= 16384 for r in args.res):
        parser.error(f"--res W H must each be in [4, 16384], got {args.res[0]} {args.res[1]}")
    if os.path.splitext(args.out)[1].lower() not in (".png", ".exr"):
        parser.error(f"--out must end in .png or .exr, got {args.out!r}")
    try:
        api.check_output_path(args.out)  # before the scene is built and rendered, not after
    except ValueError as exc:
        print(f"{parser.prog}: error: --{' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    _one_line_warnings(parser.prog)
    try:
        api.demo_scene(args.preset, layout=args.layout)
        seconds = api.render(args.out, samples=args.samples, res=tuple(args.res), seed=args.seed, osl=args.osl)
    except ValueError as exc:
        print(f"{parser.prog}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{parser.prog}: error: {api.files.one_line(exc)}", file=sys.stderr)
        return 1
    w, h = args.res
    print(f"rendered {args.out} ({w}x{h}, {args.samples} spp, preset {args.preset}) in {seconds:.2f} s")
    return 0


if __name__ == "__main__":
    code = main()
    if code:
        sys.exit(code)
