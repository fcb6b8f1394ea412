"""Drive a stock Blender (bpy as a module, only bpy's own dependencies) the way an artist would.

Run by the stock environment's Python, never by the dev venv, and never importing anything from
this repository (only bpy, its bundled modules, the standard library and numpy)::

    .stock/bpy-5.0.1/bin/python tests/stock/artist_paths.py --zip scratch_addon-0.1.0-linux_x64.zip \
        --tier full --out result.json --workdir /tmp/w

The add-on is installed from the zip into a fresh ``BLENDER_USER_RESOURCES`` and used only through
operators (``bpy.ops.scratch.*``) and properties, starting from the default startup file
(``wm.read_homefile()``).  Each step is written to ``--out`` as soon as it ends, as
``{name, ok, seconds, error, details}``, so one failing step (or a crash) hides nothing else.

Renders: 48x32 px, 8 spp, CPU, adaptive sampling and denoising off, transparent film; each
material sits on its own UV sphere (the same geometry for all), and only that sphere renders.
A material is *not black* when the mean of its RGB over the sphere's pixels (the pixels a grey
diffuse reference sphere covers fully) exceeds ``BLACK_FRACTION`` of the reference's mean rendered
the same way, and every pixel is finite.  Lighting is the startup file's point light plus a
constant grey world, so no legitimate material is black by construction: the darkest plausible one,
a dielectric (F0 = 4 %) over a black base, is rendered as a control and must pass; an emission-free
black diffuse must fail (``harness_selfcheck``).
"""
from __future__ import annotations

import argparse
import faulthandler
import json
import os
import sys
import time
import traceback
from pathlib import Path

# Hermetic: nothing from the repository (this script's folder is sys.path[0] when run as a script).
_HERE = str(Path(__file__).resolve().parent)
sys.path[:] = [p for p in sys.path if p and os.path.abspath(p) != _HERE]
REPO_ROOT = Path(__file__).resolve().parents[2]

PKG = "scratch_addon"
REPO = "user_default"
MODULE = f"bl_ext.{REPO}.{PKG}"

RES = (48, 32)
SAMPLES = 8
BLACK_FRACTION = 0.05     # of the grey diffuse reference's mean (justified by the dielectric control)
WORLD_COLOR = (0.6, 0.6, 0.6)
REOPEN_TOLERANCE = 0.02   # relative change of the object mean after save/reopen or disable/enable

SMOKE_PRESETS = ("brushed", "fig12a_gold", "fig12b_painted_metal")
UPDATE_PRESET = "fig12a_gold"
IRIDESCENT_BASE_PRESET = "fig14a_shallow"
MERL_ALBEDO = 0.5         # the grey reference's albedo
MERL_TOLERANCE = 0.06     # Lambertian table vs Diffuse, object mean: table resolution (< 1 %) + 8-spp noise


# ----------------------------------------------------------------------------- recording


DIED = "did not finish: the process hung or crashed in this step"


class Recorder:
    """Steps as JSON.  A step is written as ``DIED`` before it starts, so a crash or a watchdog exit
    (``faulthandler.dump_traceback_later``: fires even while Blender's C code holds the GIL) leaves it
    named in the file.  ``skip`` maps step names to the reason they must not run again."""

    def __init__(self, out: Path, meta: dict, step_timeout: float = 0.0, skip: dict | None = None):
        self.out = out
        self.meta = meta
        self.step_timeout = step_timeout
        self.skip = skip or {}
        self.steps: list[dict] = []
        self.by_name: dict[str, dict] = {}
        self.write()

    def write(self) -> None:
        tmp = self.out.with_suffix(".tmp")
        tmp.write_text(json.dumps({"meta": self.meta, "steps": self.steps}, indent=1, default=_jsonable))
        tmp.replace(self.out)

    def ok(self, name: str) -> bool:
        rec = self.by_name.get(name)
        return bool(rec and rec["ok"])

    def run(self, name: str, fn, *, needs=()):
        """Run ``fn(details)``; an exception or a falsy ``needs`` step marks the step failed."""
        rec = {"name": name, "ok": False, "seconds": 0.0, "error": None, "summary": None, "details": {}}
        self.steps.append(rec)
        self.by_name[name] = rec
        missing = [n for n in needs if not self.ok(n)]
        if missing:
            rec["error"] = rec["summary"] = f"skipped: needs {', '.join(missing)}"
            self.write()
            return None
        if name in self.skip:
            rec["error"] = rec["summary"] = f"not run again: {self.skip[name]}"
            rec["details"]["skipped_after_previous_attempt"] = True
            self.write()
            return None
        print(f"[stock] {name} ...", flush=True)
        rec["error"] = rec["summary"] = DIED
        self.write()
        if self.step_timeout > 0:
            faulthandler.dump_traceback_later(self.step_timeout, exit=True)
        t0 = time.perf_counter()
        result = None
        try:
            result = fn(rec["details"])
            rec["ok"] = True
            rec["error"] = rec["summary"] = None
        except BaseException as exc:  # noqa: BLE001 - every failure is data here
            if isinstance(exc, KeyboardInterrupt):
                raise
            rec["error"] = f"{type(exc).__name__}: {exc}".strip()
            rec["summary"] = summarize(rec["error"])
            rec["details"]["traceback"] = traceback.format_exc().splitlines()[-12:]
        finally:
            faulthandler.cancel_dump_traceback_later()
        rec["seconds"] = round(time.perf_counter() - t0, 3)
        print(f"[stock] {name}: {'ok' if rec['ok'] else 'FAILED ' + rec['summary']} "
              f"({rec['seconds']} s)", flush=True)
        self.write()
        return result


def summarize(error: str, limit: int = 300) -> str:
    """One line: the first line of the error, plus the next one when the first ends with ':'."""
    lines = [ln.strip() for ln in error.splitlines() if ln.strip()] or ["(no message)"]
    s = lines[0]
    if s.endswith(":") and len(lines) > 1:
        s += " " + lines[1]
    return s if len(s) <= limit else s[:limit - 3] + "..."


def _jsonable(v):
    try:
        import numpy as np

        if isinstance(v, np.generic):
            return v.item()
        if isinstance(v, np.ndarray):
            return v.tolist()
    except ImportError:
        pass
    if isinstance(v, (set, tuple)):
        return list(v)
    return repr(v)


class StepFailed(AssertionError):
    pass


def check(cond, message: str) -> None:
    if not cond:
        raise StepFailed(message)


def op(fn, *args, **kwargs):
    """Call an operator and insist on FINISHED (an ERROR report raises RuntimeError by itself)."""
    result = fn(*args, **kwargs)
    check(result == {"FINISHED"}, f"{fn.idname_py()} returned {sorted(result)}")
    return result


# ----------------------------------------------------------------------------- the artist's scene


class Scene:
    """Probe spheres, render paths and object means; names survive save/reopen."""

    def __init__(self, bpy, np, workdir: Path):
        self.bpy, self.np, self.workdir = bpy, np, workdir
        self.renders = workdir / "renders"
        self.renders.mkdir(parents=True, exist_ok=True)
        items = [e.identifier for e in bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items]
        self.eevee = "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in items else "BLENDER_EEVEE"
        self.mask = None
        self.reference: dict[str, float] = {}
        self.probes: list[str] = []      # probe object names in creation order
        self.kind_of: dict[str, str] = {}  # probe -> material kind label used in step names
        self.before: dict[str, float] = {}  # probe -> Cycles SVM object mean before save

    # -- set-up
    def setup(self, details) -> None:
        bpy = self.bpy
        scene = bpy.context.scene
        details["startup_engine"] = scene.render.engine
        details["startup_shading_osl"] = bool(scene.cycles.shading_system)
        details["startup_objects"] = sorted(o.name for o in scene.objects)
        details["eevee_engine_id"] = self.eevee
        cube = bpy.data.objects.get("Cube")
        if cube is not None:
            bpy.data.objects.remove(cube)
        r = scene.render
        r.resolution_x, r.resolution_y = RES
        r.resolution_percentage = 100
        r.film_transparent = True
        s = r.image_settings
        s.file_format = "OPEN_EXR"
        s.color_depth = "32"
        s.color_mode = "RGBA"
        c = scene.cycles
        c.samples = SAMPLES
        c.use_adaptive_sampling = False
        c.use_denoising = False
        c.seed = 0
        scene.eevee.taa_render_samples = SAMPLES
        world = scene.world
        if world is None:
            world = bpy.data.worlds.new("World")
            scene.world = world
        details["world_use_nodes_at_startup"] = bool(getattr(world, "use_nodes", True))
        details["world_has_node_tree"] = world.node_tree is not None
        if bpy.app.version < (5, 0, 0) and not world.use_nodes:
            world.use_nodes = True
        bg = next((n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground"), None)
        check(bg is not None, "startup world has no Background node")
        bg.inputs["Color"].default_value = (*WORLD_COLOR, 1.0)
        bg.inputs["Strength"].default_value = 1.0
        light = bpy.data.objects.get("Light")
        details["light"] = None if light is None else [light.data.type, light.data.energy]

    def add_probe(self, name: str, material=None):
        """A smooth-shaded UV sphere filling about a third of the default camera's frame; active + selected."""
        bpy = self.bpy
        op(bpy.ops.mesh.primitive_uv_sphere_add, radius=2.2, segments=32, ring_count=16, location=(0, 0, 0))
        obj = bpy.context.active_object
        obj.name = obj.data.name = name
        op(bpy.ops.object.shade_smooth)
        check(len(obj.data.uv_layers) > 0, "UV sphere without a UV map")
        if material is not None:
            obj.data.materials.append(material)
        self.probes.append(obj.name)
        self.select(obj)
        return obj

    def select(self, obj) -> None:
        vl = self.bpy.context.view_layer
        for o in vl.objects:
            o.select_set(False)
        obj.select_set(True)
        vl.objects.active = obj

    # -- rendering
    def render(self, probe: str, path_kind: str, tag: str):
        """Render only ``probe`` with ``path_kind`` (cycles_svm, cycles_osl, eevee); RGBA float [H, W, 4]."""
        bpy, np = self.bpy, self.np
        scene = bpy.context.scene
        for o in scene.objects:
            if o.type == "MESH":
                o.hide_render = o.name != probe
        engine, osl = scene.render.engine, scene.cycles.shading_system
        if path_kind == "eevee":
            scene.render.engine = self.eevee
        else:
            scene.render.engine = "CYCLES"
            scene.cycles.shading_system = path_kind == "cycles_osl"
        path = str(self.renders / f"{tag}.exr")
        scene.render.filepath = path
        try:
            bpy.ops.render.render(write_still=True)
        finally:   # the operators keep seeing the artist's scene (startup engine, default shading system)
            scene.render.engine, scene.cycles.shading_system = engine, osl
        img = bpy.data.images.load(path, check_existing=False)
        try:
            w, h = img.size
            px = np.empty(w * h * 4, np.float32)
            img.pixels.foreach_get(px)
        finally:
            bpy.data.images.remove(img)
        return px.reshape(h, w, 4)

    def measure(self, img) -> dict:
        np = self.np
        m = self.mask
        rgb = img[..., :3]
        return {"mean": float(rgb[m].mean()), "finite": bool(np.isfinite(img).all()),
                "coverage": float(img[..., 3][m].mean()), "max": float(np.nanmax(rgb))}

    def render_mean(self, probe: str, path_kind: str, tag: str) -> float:
        return self.measure(self.render(probe, path_kind, tag))["mean"]

    def not_black(self, probe: str, path_kind: str, tag: str, details) -> float:
        img = self.render(probe, path_kind, tag)
        m = self.measure(img)
        ref = self.reference[path_kind]
        m["reference_mean"] = ref
        m["ratio_to_reference"] = m["mean"] / ref
        details.update(m)
        check(m["finite"], f"NaN/inf pixels ({path_kind})")
        check(m["ratio_to_reference"] > BLACK_FRACTION,
              f"black: object mean {m['mean']:.4g} = {100 * m['ratio_to_reference']:.2f} % of the grey diffuse "
              f"reference ({ref:.4g}), limit {100 * BLACK_FRACTION:.0f} % ({path_kind})")
        return m["mean"]


def diffuse_material(bpy, name, color):
    """A plain Diffuse BSDF material (the artist's 'New' material with its BSDF swapped)."""
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    d = tree.nodes.new("ShaderNodeBsdfDiffuse")
    d.inputs["Color"].default_value = (*color, 1.0)
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(d.outputs["BSDF"], out.inputs["Surface"])
    return mat


def dielectric_control(bpy, name):
    """Principled, black base colour, roughness 0.2: only the 4 % dielectric specular reflects."""
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    p = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    p.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    p.inputs["Roughness"].default_value = 0.2
    return mat


def heightfield_npy(np, path: Path, shape=(256, 256), pixel_um=0.5, rms_um=0.05, corr_um=(20.0, 1.5), seed=2):
    """Anisotropic Gaussian random surface (brushed along x), heights in micrometres."""
    rng = np.random.default_rng(seed)
    noise = rng.standard_normal(shape)
    fy = np.fft.fftfreq(shape[0], d=pixel_um)[:, None]
    fx = np.fft.fftfreq(shape[1], d=pixel_um)[None, :]
    filt = np.exp(-0.5 * ((2 * np.pi * fx * corr_um[0]) ** 2 + (2 * np.pi * fy * corr_um[1]) ** 2))
    h = np.real(np.fft.ifft2(np.fft.fft2(noise) * filt))
    h *= rms_um / h.std()
    np.save(path, h.astype(np.float64))
    return path


# ----------------------------------------------------------------------------- the session


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zip", required=True, type=Path)
    ap.add_argument("--tier", choices=("full", "smoke"), required=True)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--workdir", required=True, type=Path)
    ap.add_argument("--step-timeout", type=float, default=300.0,
                    help="seconds after which a step counts as hung: tracebacks are dumped and the process exits")
    ap.add_argument("--skip", action="append", default=[], metavar="STEP=REASON",
                    help="record STEP as failed with REASON instead of running it (it hung or crashed before)")
    args = ap.parse_args(argv)
    faulthandler.enable()   # a crash (also at interpreter exit) leaves a Python traceback in the log
    workdir = args.workdir.resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    # Before bpy is imported: a fresh user folder, the table cache in the work dir.
    os.environ.setdefault("BLENDER_USER_RESOURCES", str(workdir / "blender_user"))
    os.environ.setdefault("SCRATCH_ADDON_CACHE", str(workdir / "cache"))
    user_dir = Path(os.environ["BLENDER_USER_RESOURCES"])
    fresh = not user_dir.exists() or not any(user_dir.iterdir())

    import numpy as np

    import bpy  # noqa: I001 - bpy first: it puts addon_utils on sys.path
    import addon_utils

    meta = {"blender": bpy.app.version_string, "python": sys.version.split()[0], "numpy": np.__version__,
            "tier": args.tier, "zip": str(args.zip), "user_resources": str(user_dir), "user_resources_fresh": fresh,
            "cache": os.environ["SCRATCH_ADDON_CACHE"]}
    meta["step_timeout"] = args.step_timeout
    skip = dict(s.split("=", 1) if "=" in s else (s, "it died in a previous attempt") for s in args.skip)
    rec = Recorder(args.out, meta, args.step_timeout, skip)
    full = args.tier == "full"
    paths = ("cycles_svm", "eevee", "cycles_osl") if full else ("cycles_svm", "eevee")
    meta["render_paths"] = list(paths)
    sc = Scene(bpy, np, workdir)
    t_start = time.perf_counter()

    def addon_module(name):
        return sys.modules.get(f"{MODULE}.{PKG}.{name}")

    # -- install / enable
    def install(d):
        check(args.zip.is_file(), f"no zip at {args.zip}")
        op(bpy.ops.extensions.package_install_files, filepath=str(args.zip), repo=REPO, enable_on_install=True)
        loaded, enabled = addon_utils.check(MODULE)
        d["loaded"], d["enabled"] = loaded, enabled
        check(loaded and enabled, f"{MODULE} not enabled after install (loaded={loaded}, enabled={enabled})")
        check(hasattr(bpy.types, "SCRATCH_OT_add_preset_material"), "operators not registered")
        for dep in ("scipy", "OpenEXR"):
            try:
                mod = __import__(dep)
                d[dep] = [getattr(mod, "__version__", "?"), mod.__file__]
                check(str(user_dir) in mod.__file__, f"{dep} imported from outside the user folder: {mod.__file__}")
            except ImportError as exc:
                d[dep] = f"ImportError: {exc}"
                check(False, f"bundled wheel not importable after the install: {dep}: {exc}")

    def stock_python(d):
        """The interpreter is a stock Blender's: none of the add-on's third-party dependencies yet."""
        import importlib.util

        d["executable"] = sys.executable
        present = [m for m in ("scipy", "OpenEXR", "matplotlib") if importlib.util.find_spec(m) is not None]
        d["present"] = present
        check(not present, f"not a stock Blender Python: {present} importable before the install")

    rec.run("stock_python", stock_python)
    rec.run("install", install)
    INST = ("install",)

    def read_home(d):
        op(bpy.ops.wm.read_homefile)
        d["addon_enabled_after_read_homefile"] = addon_utils.check(MODULE)[1]
        sc.setup(d)

    rec.run("default_scene", read_home)
    SCENE = ("default_scene",)

    # -- references and the harness's own check
    ref_mats = {}

    def references(d):
        ref_mats["reference"] = diffuse_material(bpy, "Grey Diffuse Reference", (0.5, 0.5, 0.5))
        ref_mats["broken_black"] = diffuse_material(bpy, "Broken Black", (0.0, 0.0, 0.0))
        ref_mats["dielectric_control"] = dielectric_control(bpy, "Dielectric Control")
        for k, m in ref_mats.items():
            sc.add_probe(f"Probe {k}", m)
        for pk in paths:
            img = sc.render("Probe reference", pk, f"reference_{pk}")
            mask = img[..., 3] > 0.999
            if sc.mask is None:
                sc.mask = mask
                d["object_pixels"] = int(mask.sum())
                check(100 < mask.sum() < 0.8 * mask.size, f"reference sphere covers {int(mask.sum())} px")
            else:
                d[f"mask_mismatch_px_{pk}"] = int((mask != sc.mask).sum())
            m = sc.measure(img)
            check(m["finite"] and m["mean"] > 0.05, f"reference renders {m} in {pk}")
            sc.reference[pk] = m["mean"]
        d["reference_means"] = dict(sc.reference)

    rec.run("references", references, needs=SCENE)
    REF = ("references",)

    def selfcheck(d):
        """The detector must call an emission-free black diffuse black and a 4 % dielectric not black."""
        problems = []
        for pk in paths:
            sub = {}
            try:
                sc.not_black("Probe broken_black", pk, f"broken_black_{pk}", sub)
                problems.append(f"black diffuse not reported black in {pk}")
            except StepFailed:
                pass
            d[f"broken_black_{pk}"] = sub
            sub = {}
            try:
                sc.not_black("Probe dielectric_control", pk, f"dielectric_{pk}", sub)
            except StepFailed as exc:
                problems.append(f"dielectric control: {exc}")
            d[f"dielectric_control_{pk}"] = sub
        check(not problems, "; ".join(problems))

    rec.run("harness_selfcheck", selfcheck, needs=REF)

    # -- materials: one probe each, then its renders
    kinds: list[tuple[str, str]] = []   # (kind label, probe name) that got a material

    def renders_for(kind, probe, needs):
        if all(rec.ok(n) for n in needs):
            sc.kind_of[probe] = kind    # has its material: re-rendered after reopen / disable / enable
        for pk in paths:
            rec.run(f"render:{kind}:{pk}", lambda d, pk=pk: sc.not_black(probe, pk, f"{kind}_{pk}", d),
                    needs=(*needs, "references"))
        if rec.ok(f"render:{kind}:cycles_svm"):
            sc.before[probe] = rec.by_name[f"render:{kind}:cycles_svm"]["details"]["mean"]

    presets_info = {}

    def list_presets(d):
        items = []
        try:
            prop = bpy.ops.scratch.add_preset_material.get_rna_type().properties["preset"]
            items = [e.identifier for e in prop.enum_items]
        except (KeyError, AttributeError, RuntimeError) as exc:
            d["enum_error"] = str(exc)
        d["from_operator_enum"] = items
        mod = addon_module("presets")
        check(mod is not None, "presets module not loaded")
        for name, p in mod.PRESETS.items():
            presets_info[name] = p.kind
        d["presets"] = dict(presets_info)
        check(presets_info, "no presets")

    rec.run("list_presets", list_presets, needs=INST)
    preset_names = sorted(presets_info) if full else [p for p in SMOKE_PRESETS if p in presets_info or not presets_info]

    def add_preset(preset, probe_name):
        def fn(d):
            obj = sc.add_probe(probe_name)
            with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
                op(bpy.ops.scratch.add_preset_material, preset=preset)
            mat = obj.active_material
            check(mat is not None, "no material assigned")
            d["material"] = mat.name
            d["kind"] = mat.get("scratch_addon_kind")
            d["scene_osl_after_operator"] = bool(bpy.context.scene.cycles.shading_system)
            d["scene_engine_after_operator"] = bpy.context.scene.render.engine
            d["node_types"] = sorted({n.bl_idname for n in mat.node_tree.nodes})
            return mat
        return fn

    for preset in preset_names:
        probe = f"Probe {preset}"
        rec.run(f"preset:{preset}", add_preset(preset, probe), needs=SCENE + INST)
        renders_for(preset, probe, (f"preset:{preset}",))

    # -- Update Scratch Material after a panel edit
    def update(d):
        obj = bpy.data.objects[upd_probe]
        mat = obj.active_material
        s = mat.scratch
        d["density_before"] = s.density
        s.density = 0.25
        script = next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeScript"), None)
        src = script.script.as_string() if script is not None and script.script is not None else None
        with bpy.context.temp_override(material=mat, object=obj, active_object=obj):
            op(bpy.ops.scratch.update_material)
        d["density_after"] = mat.scratch.density
        check(abs(mat.scratch.density - 0.25) < 1e-6, "density reset by the update")
        script = next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeScript"), None)
        if src is not None and script is not None:
            d["shader_source_changed"] = script.script.as_string() != src

    upd_probe = f"Probe {UPDATE_PRESET} updated"
    rec.run(f"preset:{UPDATE_PRESET}+update", add_preset(UPDATE_PRESET, upd_probe), needs=SCENE + INST)
    rec.run("update_material", update, needs=(f"preset:{UPDATE_PRESET}+update",))
    renders_for("updated", upd_probe, ("update_material",))

    # -- Live look-dev (issue #18): panel edits reach the material without an operator call; keyframes animate it
    live_probe = "Probe live"

    def node_trees(tree, seen=None):
        seen = set() if seen is None else seen
        if tree is None or tree.name in seen:
            return
        seen.add(tree.name)
        yield tree
        for n in tree.nodes:
            if getattr(n, "node_tree", None) is not None:
                yield from node_trees(n.node_tree, seen)

    def table_digest(mat) -> str:
        """Hash of what a table edit must change: every image the material's nodes read, and script text."""
        import hashlib
        h = hashlib.sha1()
        for tree in node_trees(mat.node_tree):
            for n in sorted(tree.nodes, key=lambda n: n.name):
                img = getattr(n, "image", None)
                if img is not None:
                    px = np.empty(len(img.pixels), np.float32)
                    img.pixels.foreach_get(px)
                    h.update(px.tobytes())
                script = getattr(n, "script", None)
                if script is not None:
                    h.update(script.as_string().encode())
        return h.hexdigest()

    def differs(a, b) -> float:
        """Largest absolute pixel difference of two renders (the same seed renders a material identically)."""
        return float(np.abs(a[..., :3] - b[..., :3]).max())

    def edit_changes_render(d, tag: str, edit) -> None:
        """Render the live probe, ``edit(settings, material, d)`` (panel values only, no operator), render again:
        the render must change."""
        mat = bpy.data.objects[live_probe].active_material
        before = sc.render(live_probe, "cycles_svm", f"live_{tag}_before")
        edit(mat.scratch, mat, d)
        after = sc.render(live_probe, "cycles_svm", f"live_{tag}_after")
        d["max_pixel_change"] = differs(before, after)
        check(d["max_pixel_change"] > 1e-4, f"the render did not change after the {tag} edit")

    def density_edit(s, mat, d):
        d["density_before"] = s.density
        s.density = 0.05 if s.density > 0.3 else 0.9          # the panel edit, nothing else
        ctrl = next((n for n in mat.node_tree.nodes if n.name == "Scratch Controls"), None)
        check(ctrl is not None, "no Scratch Controls node")
        d["socket_after"] = ctrl.inputs["Density"].default_value
        check(abs(ctrl.inputs["Density"].default_value - s.density) < 1e-6,
              f"Density socket {ctrl.inputs['Density'].default_value:.4g} did not follow the panel ({s.density:.4g})")

    def profile_edit(s, mat, d):
        digest = table_digest(mat)
        d["profile_value_before"] = s.profile_value
        s.profile_value = s.profile_value * 2.5 if s.profile_value < 0.5 else s.profile_value * 0.4
        d["profile_value_after"] = s.profile_value
        check(table_digest(mat) != digest, "the tables (images / shader text) did not change after a profile edit")

    def live_keyframes(d):
        obj = bpy.data.objects[live_probe]
        mat = obj.active_material
        scene = bpy.context.scene
        s = mat.scratch
        s.density = 0.02
        s.keyframe_insert("density", frame=1)
        s.density = 0.95
        s.keyframe_insert("density", frame=2)
        imgs = []
        for f in (1, 2, 1):
            scene.frame_set(f)
            imgs.append(sc.render(live_probe, "cycles_svm", f"live_frame{f}_{len(imgs)}"))
        scene.frame_set(1)
        d["frame1_vs_frame2"] = differs(imgs[0], imgs[1])
        d["frame1_again"] = differs(imgs[0], imgs[2])
        check(d["frame1_vs_frame2"] > 1e-4, "a keyframed density renders the same on frames 1 and 2")
        check(d["frame1_again"] < 1e-6, "frame 1 renders differently the second time")

    rec.run(f"preset:{UPDATE_PRESET}+live", add_preset(UPDATE_PRESET, live_probe), needs=SCENE + INST)
    live_needs = (f"preset:{UPDATE_PRESET}+live", "references")
    rec.run("live_socket", lambda d: edit_changes_render(d, "density", density_edit), needs=live_needs)
    rec.run("live_table", lambda d: edit_changes_render(d, "profile", profile_edit), needs=live_needs)
    rec.run("live_keyframes", live_keyframes, needs=live_needs)

    # -- Measured BRDF (issue #16): a MERL-format file of a Lambertian (albedo 0.5) renders like the grey diffuse
    merl_path = workdir / "lambert_half.binary"

    def merl(d):
        shape = (90, 90, 180)
        scale = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])   # the MERL format's channel scales
        with open(merl_path, "wb") as fh:
            np.asarray(shape, "<i4").tofile(fh)
            for c in range(3):
                np.full(shape, MERL_ALBEDO / np.pi / scale[c], "<f8").tofile(fh)
        obj = sc.add_probe("Probe merl")
        with bpy.context.temp_override(active_object=obj, object=obj):
            op(bpy.ops.scratch.import_merl, filepath=str(merl_path))
        mat = obj.active_material
        check(mat is not None, "no material assigned")
        d["material"], d["kind"] = mat.name, mat.get("scratch_addon_kind")

    def merl_vs_diffuse(pk):
        def fn(d):
            mean = sc.render_mean("Probe merl", pk, f"merl_vs_reference_{pk}")
            ref = sc.reference[pk]
            d["mean"], d["reference_mean"], d["ratio"] = mean, ref, mean / ref
            check(abs(mean / ref - 1.0) < MERL_TOLERANCE, f"Lambertian MERL file renders {mean / ref:.3f}x the grey "
                  f"diffuse of the same albedo (limit {MERL_TOLERANCE:.0%}, {pk})")
        return fn

    rec.run("merl", merl, needs=SCENE + INST)
    renders_for("merl", "Probe merl", ("merl",))
    for pk in paths:
        rec.run(f"merl_vs_diffuse:{pk}", merl_vs_diffuse(pk), needs=("merl", "references"))

    # -- Bi-scale: a tile, one slot with the artist's own Principled material, baked onto a probe
    def biscale_tile(d):
        op(bpy.ops.scratch.add_biscale_tile, kind="PYRAMID")
        tile = bpy.context.active_object
        d["tile"] = tile.name
        d["slots"] = [s.material.name if s.material else None for s in tile.material_slots]
        before = set(bpy.data.materials)
        op(bpy.ops.material.new)          # the material panel's "New" button
        gold = next(iter(set(bpy.data.materials) - before))
        gold.name = "Tile Gold"
        p = next((n for n in gold.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)
        if p is not None:
            p.inputs["Base Color"].default_value = (1.0, 0.78, 0.34, 1.0)
            p.inputs["Metallic"].default_value = 1.0
            p.inputs["Roughness"].default_value = 0.3
        tile.material_slots[0].material = gold
        tile.hide_render = True   # the tile is the small-scale input, not part of the picture
        return tile

    state = {}

    def biscale_bake(d):
        tile = bpy.data.objects[state["tile"]]
        target = sc.add_probe("Probe biscale")
        tile.hide_render = True
        sc.select(tile)
        target.select_set(True)
        with bpy.context.temp_override(active_object=tile, object=tile, selected_objects=[tile, target]):
            # the full tier bakes with the operator's defaults (inter-reflections "AUTO": on for this tile); the
            # smoke tiers skip that numpy pass (30-70 s here; the same code as the full tier's, no bpy in it)
            op(bpy.ops.scratch.bake_biscale, target=target.name, n_facets=500, dir_res=4, n_lobes=2,
               **({} if full else {"interreflections": "OFF"}))
        mat = target.active_material
        check(mat is not None, "no material on the target")
        d["material"], d["kind"] = mat.name, mat.get("scratch_addon_kind")
        d["fit_psnr"] = mat.get("biscale_fit_psnr")

    def _tile(d):
        state["tile"] = biscale_tile(d).name

    rec.run("biscale_tile", _tile, needs=SCENE + INST)
    rec.run("biscale_bake", biscale_bake, needs=("biscale_tile",))
    renders_for("biscale", "Probe biscale", ("biscale_bake",))

    # -- Material from Height Field (average NDF; full tier also the synthesised texture)
    hf_path = workdir / "brushed_heightfield.npy"

    def heightfield(synth):
        def fn(d):
            heightfield_npy(np, hf_path)
            obj = sc.add_probe("Probe heightfield" + (" texture" if synth else ""))
            kw = dict(synthesize=True, texture_size=32, texel_um=4.0, texture_scale=2.0) if synth else {}
            with bpy.context.temp_override(active_object=obj, object=obj):
                op(bpy.ops.scratch.material_from_heightfield, filepath=str(hf_path), pixel_um=0.5, sigma_um=1.0, **kw)
            mat = obj.active_material
            check(mat is not None, "no material assigned")
            d["material"], d["kind"] = mat.name, mat.get("scratch_addon_kind")
        return fn

    rec.run("heightfield", heightfield(False), needs=SCENE + INST)
    renders_for("heightfield", "Probe heightfield", ("heightfield",))
    if full:
        rec.run("heightfield_texture", heightfield(True), needs=SCENE + INST)
        renders_for("heightfield_texture", "Probe heightfield texture", ("heightfield_texture",))

    # -- Iridescent layer on a scratch material (Generate Scratch Set, then Add Iridescent Layer)
    def iridescent(d):
        obj = bpy.data.objects["Probe iridescent"]
        mat = obj.active_material
        mat.scratch_iridescence.count = 60
        with bpy.context.temp_override(material=mat, object=obj, active_object=obj):
            op(bpy.ops.scratch.generate_scratch_set)
            op(bpy.ops.scratch.add_iridescent_layer)
        d["material"] = mat.name
        d["node_types"] = sorted({n.bl_idname for n in mat.node_tree.nodes})

    rec.run(f"preset:{IRIDESCENT_BASE_PRESET}+iridescent", add_preset(IRIDESCENT_BASE_PRESET, "Probe iridescent"),
            needs=SCENE + INST)
    rec.run("iridescent_layer", iridescent, needs=(f"preset:{IRIDESCENT_BASE_PRESET}+iridescent",))
    renders_for("iridescent", "Probe iridescent", ("iridescent_layer",))

    material_probes = [p for p in sc.probes if p in sc.kind_of]

    def compare_all(prefix, needs):
        for probe in material_probes:
            kind = sc.kind_of.get(probe, probe.removeprefix("Probe "))

            def fn(d, probe=probe, kind=kind):
                check(probe in bpy.data.objects, f"{probe} missing")
                mean = sc.not_black(probe, "cycles_svm", f"{prefix}_{kind}", d)
                before = sc.before.get(probe)
                d["mean_before"] = before
                if before is not None:
                    rel = abs(mean - before) / max(before, 1e-12)
                    d["relative_change"] = rel
                    check(rel < REOPEN_TOLERANCE, f"object mean {mean:.4g} vs {before:.4g} before ({100 * rel:.1f} %)")
            rec.run(f"{prefix}:{kind}", fn, needs=needs)

    # -- save, reopen, render again
    blend = workdir / "artist.blend"

    def save(d):
        op(bpy.ops.wm.save_as_mainfile, filepath=str(blend))
        d["bytes"] = blend.stat().st_size

    def reopen(d):
        op(bpy.ops.wm.open_mainfile, filepath=str(blend))
        d["addon_enabled"] = addon_utils.check(MODULE)[1]
        d["objects"] = sorted(o.name for o in bpy.context.scene.objects)
        upd = bpy.data.objects.get(upd_probe)
        if upd is not None and upd.active_material is not None and hasattr(upd.active_material, "scratch"):
            d["updated_density"] = upd.active_material.scratch.density
            check(abs(upd.active_material.scratch.density - 0.25) < 1e-6, "panel setting lost on reopen")

    rec.run("save_blend", save, needs=SCENE)
    rec.run("reopen_blend", reopen, needs=("save_blend",))
    compare_all("reopen", ("reopen_blend", "references"))

    # -- disable, render without the add-on, enable, use it again
    def disable(d):
        op(bpy.ops.preferences.addon_disable, module=MODULE)
        d["enabled"] = addon_utils.check(MODULE)[1]
        check(not d["enabled"], "still enabled")
        check(not hasattr(bpy.types, "SCRATCH_OT_add_preset_material"), "operators still registered")

    def enable(d):
        op(bpy.ops.preferences.addon_enable, module=MODULE)
        d["enabled"] = addon_utils.check(MODULE)[1]
        check(d["enabled"], "not enabled")
        check(hasattr(bpy.types, "SCRATCH_OT_add_preset_material"), "operators not registered")
        obj = sc.add_probe("Probe after re-enable")
        sc.probes.remove(obj.name)
        # the first preset that worked before must work again
        again = next((p for p in preset_names if rec.ok(f"preset:{p}")), None)
        check(again is not None, "no preset worked before disabling; nothing to repeat")
        d["preset"] = again
        with bpy.context.temp_override(active_object=obj, object=obj):
            op(bpy.ops.scratch.add_preset_material, preset=again)
        d["new_material"] = obj.active_material.name
        bpy.data.objects.remove(obj)

    rec.run("disable_addon", disable, needs=INST)
    compare_all("disabled", ("disable_addon", "references"))
    rec.run("enable_addon", enable, needs=("disable_addon",))
    compare_all("reenabled", ("enable_addon", "references"))

    # -- uninstall
    def uninstall(d):
        repos = [r.module for r in bpy.context.preferences.extensions.repos]
        idx = repos.index(REPO)
        ext_dir = Path(bpy.utils.user_resource("EXTENSIONS", path=f"{REPO}/{PKG}"))
        d["extension_dir_before"] = [str(ext_dir), ext_dir.exists()]
        op(bpy.ops.extensions.package_uninstall, repo_index=idx, pkg_id=PKG)
        loaded, enabled = addon_utils.check(MODULE)
        d["loaded"], d["enabled"] = loaded, enabled
        d["extension_dir_exists"] = ext_dir.exists()
        d["module_in_sys_modules"] = MODULE in sys.modules
        check(not enabled and MODULE not in sys.modules, f"module still there (enabled={enabled})")
        check(not ext_dir.exists(), f"{ext_dir} still exists")
        check(not hasattr(bpy.types, "SCRATCH_OT_add_preset_material"), "operators still registered")

    rec.run("uninstall", uninstall, needs=INST)

    def hermetic(d):
        """Nothing imported from the repository; user folder was fresh."""
        leaked = sorted(n for n, m in list(sys.modules.items())
                        if getattr(m, "__file__", None) and n != "__main__"
                        and Path(m.__file__).resolve().is_relative_to(REPO_ROOT)
                        and not Path(m.__file__).resolve().is_relative_to(REPO_ROOT / ".stock"))
        d["leaked"] = leaked
        check(fresh, f"BLENDER_USER_RESOURCES {user_dir} was not empty")
        check(not leaked, f"modules imported from the repository: {leaked[:5]}")

    rec.run("hermetic", hermetic)
    meta["seconds"] = round(time.perf_counter() - t_start, 1)
    meta["done"] = True
    rec.write()
    failed = [s["name"] for s in rec.steps if not s["ok"]]
    print(f"[stock] {len(rec.steps) - len(failed)}/{len(rec.steps)} steps ok in {meta['seconds']} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
