"""Ground truth for the scratch material: Cycles path tracing the explicit groove geometry (issue #15).

The scratch material (Raymond et al. 2016) stands for parallel grooves of one profile; the strongest
reference is Cycles tracing those grooves.  For each case (profile x Fresnel x dense / layered) and each
view, two scenes are rendered with the same orthographic camera:

* truth: ``precompute.scratch.explicit`` grooves (the profile polyline repeated across the plane,
  extruded along the scratch direction, flat facets), Glossy roughness 0 colour 1 (a lossless mirror)
  or Cycles' Metallic BSDF as a physical conductor with the same n, k (coloured Fresnel per bounce),
  ``glossy_bounces`` high enough for every inter-reflection, ~15 grooves per pixel;
* material: a flat plane with the scratch material as a user builds it (default table lobes) on the
  OSL path (Cycles OSL) and on its SVM twin (Cycles SVM, the same material).

Environments make the image mean a moment of where light leaves the surface (Texture Coordinate
"Generated" in a world shader is the ray direction d):

* ``white``  colour 1: the albedo A_c per channel;
* ``first``  colour 0.5 + 0.5 d (RGB = xyz): A_c (1 + E_c[d_c]) / 2, decoded to m1_c = E_c[d_c];
* ``second`` colour d² per channel: A_c E_c[d_c²] = m2_c A_c (sums to the albedo for a grey surface);
* ``studio`` the README's studio environment plus a small area light (an ordinary scene);
* ``below``  1 for d_z < 0 (leaving below the horizon, impossible for grooves): the fraction of the truth's
  samples that slipped through the mesh (Cycles' ray / edge precision at grazing views).

The camera is rolled so that the scratch direction is vertical in the image and its width is a whole
number of projected groove periods, the pixel filter is a 1-px box: the image mean of the explicit scene
is then the exact average over whole grooves (no partial groove biases it).  Errors per view: albedo
relative error, |Δm1|, |Δm2| (direction-cosine units), studio image-mean relative error; noise from
several seeds (std of the material-minus-truth differences).

    python -m bench scratch_truth [--quick] [--cases v30,q05,...] [--seeds 3]

Writes bench/out/scratch_truth.md (per-view errors) and, with ``--figure``, docs/img/scratch_truth.png.
The scene helpers are shared with tests/scratch/test_scratch_truth.py (they take the glue package).
"""
from __future__ import annotations

import argparse
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

#: views (theta from the normal, azimuth of the view from the scratch direction u), degrees
VIEWS = {
    "down": (0.0, 0.0),
    "along45": (45.0, 0.0),
    "along70": (70.0, 0.0),
    "across45": (45.0, 90.0),
    "across70": (70.0, 90.0),
    "oblique60/30": (60.0, 30.0),
    "oblique60/60": (60.0, 60.0),
    "oblique35/15": (35.0, 15.0),
    "grazing80/0": (80.0, 0.0),
    "grazing80/45": (80.0, 45.0),
    "grazing80/90": (80.0, 90.0),
}
WORLDS = ("white", "first", "second")

#: metres seen across the image (before snapping to whole periods; a 17 mm groove period at 64 px).  The image
#: mean is exact only with whole periods in the frame and a period count coprime to the pixel count (see
#: ``snapped_scale``).
ORTHO = 16.0
RES = 16             # pixels across
GROOVES_PER_PIXEL = 15


def view_vector(theta_deg: float, azimuth_deg: float) -> np.ndarray:
    """Unit vector towards the viewer: ``theta`` from the normal (+z), azimuth from the scratch direction (+x)."""
    t, a = math.radians(theta_deg), math.radians(azimuth_deg)
    return np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])


def camera_frame(omega: np.ndarray, u=np.array([1.0, 0.0, 0.0])):
    """(right, up, back) of an orthographic camera looking along -omega with the scratch direction u
    projected onto the image's vertical axis (straight down: up = u)."""
    up = u - np.dot(u, omega) * omega
    up /= np.linalg.norm(up)
    right = np.cross(up, omega)
    return right, up, omega


def projected_period(omega: np.ndarray, period: float) -> float:
    """Width on the image of one groove period (grooves along x, periodic in y) for the camera of ``camera_frame``.

    Moving by s along the image's x axis moves the ray's hit on z = 0 by s (e_x - (e_x.z / w.z) w): its y
    changes by s (e_x.y - e_x.z w.y / w.z).
    """
    ex, _, w = camera_frame(omega)
    dy = ex[1] - ex[2] * w[1] / w[2]
    return period / abs(dy)


def snapped_scale(omega: np.ndarray, period: float, scale: float = ORTHO, res: int | None = None) -> float:
    """The orthographic scale (image width) nearest to ``scale`` holding a whole number N of projected periods,
    with N coprime to the pixel count ``res``: the grooves' phase then steps by 1/res of a period from pixel to
    pixel.  With a whole number of periods per pixel every pixel sees the same sub-pixel pattern, and Cycles'
    per-pixel sample positions are correlated enough to bias the image mean (quartic 0.5, gold, straight down:
    blue albedo 0.239 at 15 periods per pixel, 0.226-0.237 at 15.25-15.5, 0.2291 exact)."""
    p = projected_period(omega, period)
    n = max(1, round(scale / p))
    if res:
        while math.gcd(n, int(res)) != 1:
            n += 1
    return n * p


def footprint(omega: np.ndarray, scale: float) -> tuple[float, float]:
    """Half extents (x, y) on z = 0 of the square orthographic view of width ``scale`` (a bound)."""
    right, up, w = camera_frame(omega)
    corners = [(sx * right + sy * up) * 0.5 * scale for sx in (-1, 1) for sy in (-1, 1)]
    hits = [c - (c[2] / w[2]) * w for c in corners]
    return max(abs(h[0]) for h in hits), max(abs(h[1]) for h in hits)


# --------------------------------------------------------------------------------------------- bpy side
def add_mesh(scene, mesh, material, name: str = "Grooves"):
    """A flat-shaded object from a ``precompute.scratch.explicit.Mesh``."""
    import bpy

    me = bpy.data.meshes.new(name)
    V = np.ascontiguousarray(mesh.verts, np.float32)
    polys = [mesh.quads, mesh.tris]
    sizes = np.concatenate([np.full(len(mesh.quads), 4), np.full(len(mesh.tris), 3)]).astype(np.int32)
    loops = np.concatenate([p.reshape(-1) for p in polys]).astype(np.int32)
    me.vertices.add(V.shape[0])
    me.vertices.foreach_set("co", V.ravel())
    me.loops.add(loops.size)
    me.loops.foreach_set("vertex_index", loops)
    me.polygons.add(sizes.size)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
    me.polygons.foreach_set("loop_start", starts)
    me.polygons.foreach_set("use_smooth", np.zeros(sizes.size, bool))
    me.update(calc_edges=True)
    me.validate(verbose=False)
    if material is not None:
        me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    scene.collection.objects.link(obj)
    return obj


def mirror_material(addon, fresnel, name: str = "Truth mirror"):
    """The grooves' surface: Glossy roughness 0 colour 1 (lossless) or Cycles' physical conductor (n, k)."""
    mat = addon.materials.new_material(name)
    tree = mat.node_tree
    if fresnel is None:
        node = tree.nodes.new("ShaderNodeBsdfGlossy")
        node.distribution = "GGX"
        node.inputs["Roughness"].default_value = 0.0
        node.inputs["Color"].default_value = (1, 1, 1, 1)
    else:
        if not hasattr(fresnel, "k"):
            raise ValueError("fresnel: the truth scenes need a conductor (n, k) or None")
        node = tree.nodes.new("ShaderNodeBsdfMetallic")
        node.fresnel_type = "PHYSICAL_CONDUCTOR"
        node.distribution = "GGX"
        node.inputs["Roughness"].default_value = 0.0
        rgb = lambda a: [float(x) for x in np.broadcast_to(np.asarray(a, float).ravel(), (3,))]  # noqa: E731
        node.inputs["IOR"].default_value = rgb(fresnel.n)
        node.inputs["Extinction"].default_value = rgb(fresnel.k)
    tree.links.new(node.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    return mat


def set_world(addon, scene, kind: str) -> None:
    """Direction-coded ("white", "first", "second") or ordinary ("studio") environment."""
    import bpy

    if kind == "studio":
        addon.render.studio_world(scene, 1.0)
        return
    world = bpy.data.worlds.get(f"Truth {kind}") or bpy.data.worlds.new(f"Truth {kind}")
    scene.world = world
    tree = addon.materials.ensure_nodes(world)
    tree.nodes.clear()
    bg = tree.nodes.new("ShaderNodeBackground")
    out = tree.nodes.new("ShaderNodeOutputWorld")
    tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
    if kind == "white":
        bg.inputs["Color"].default_value = (1, 1, 1, 1)
        return
    coord = tree.nodes.new("ShaderNodeTexCoord")
    vm = tree.nodes.new("ShaderNodeVectorMath")
    if kind == "first":
        vm.operation = "MULTIPLY_ADD"
        vm.inputs[1].default_value = (0.5, 0.5, 0.5)
        vm.inputs[2].default_value = (0.5, 0.5, 0.5)
        tree.links.new(coord.outputs["Generated"], vm.inputs[0])
    elif kind == "second":
        vm.operation = "MULTIPLY"
        tree.links.new(coord.outputs["Generated"], vm.inputs[0])
        tree.links.new(coord.outputs["Generated"], vm.inputs[1])
    elif kind == "below":
        # 1 where the ray leaves below the horizon (d_z < 0): impossible for the grooves, so its image mean is
        # the fraction of the truth's samples that slipped through the mesh (a measurement artefact)
        vm.operation = "DOT_PRODUCT"
        vm.inputs[1].default_value = (0.0, 0.0, 1.0)
        tree.links.new(coord.outputs["Generated"], vm.inputs[0])
        lt = tree.nodes.new("ShaderNodeMath")
        lt.operation = "LESS_THAN"
        lt.inputs[1].default_value = 0.0
        tree.links.new(vm.outputs["Value"], lt.inputs[0])
        tree.links.new(lt.outputs["Value"], bg.inputs["Color"])
        return
    else:
        raise ValueError(f"kind: expected white, first, second, below or studio, got {kind!r}")
    tree.links.new(vm.outputs["Vector"], bg.inputs["Color"])


def set_camera(scene, omega: np.ndarray, scale: float, target=(0.0, 0.0, 0.0), distance: float = 20.0 * ORTHO):
    """Orthographic camera looking along -omega at ``target``, scratch direction vertical in the image."""
    import bpy
    from mathutils import Matrix

    cam = scene.camera
    if cam is None:
        data = bpy.data.cameras.new("Truth camera")
        cam = bpy.data.objects.new("Truth camera", data)
        scene.collection.objects.link(cam)
        scene.camera = cam
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = float(scale)
    cam.data.clip_start = 0.01
    cam.data.clip_end = 2 * distance + 100.0
    right, up, back = camera_frame(np.asarray(omega, float))
    loc = np.asarray(target, float) + distance * back
    m = Matrix(((right[0], up[0], back[0], loc[0]), (right[1], up[1], back[1], loc[1]),
                (right[2], up[2], back[2], loc[2]), (0, 0, 0, 1)))
    cam.matrix_world = m
    return cam


def configure(addon, scene, samples: int, res: int, seed: int, osl: bool, bounces: int = 64) -> None:
    """Deterministic CPU Cycles with a 1-px box filter (the image mean is the area average)."""
    addon.render.configure_cycles(scene, samples=samples, res=(res, res), seed=seed, osl=osl, max_bounces=bounces)
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 1.0
    scene.render.use_persistent_data = True


def lamp(addon, scene, omega_view: np.ndarray, energy: float = 400.0 * ORTHO ** 2, size: float = 0.5 * ORTHO):
    """A small area light near the mirror direction of the view (rotated 20 deg about the normal)."""
    a = math.atan2(omega_view[1], omega_view[0]) + math.pi + math.radians(20.0)
    t = max(math.acos(min(max(omega_view[2], -1.0), 1.0)), math.radians(20.0))
    d = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])
    return addon.render.add_light(scene, "AREA", location=tuple(6.0 * ORTHO * d), energy=energy, size=size)


@dataclass
class Case:
    """A ground-truth case: profile, Fresnel (None = lossless) and layers (None = dense)."""

    name: str
    profile: object
    fresnel: object = None
    layers: object = None
    material_kw: dict = field(default_factory=dict)


def image_means(img: np.ndarray) -> np.ndarray:
    return img.reshape(-1, 3).mean(0).astype(np.float64)


def moments(values: dict) -> dict:
    """Decode the per-channel image means of the worlds into albedo A, m1 = E[d_c], m2 = E[d_c^2]."""
    A = values["white"]
    out = {"A": A}
    if "first" in values:
        out["m1"] = (2.0 * values["first"] - A) / np.maximum(A, 1e-9)
    if "second" in values:
        out["m2"] = values["second"] / np.maximum(A, 1e-9)
    return out



# ------------------------------------------------------------------------------------------------- cases
def science(addon, name: str):
    """``precompute.scratch.<name>`` of the package holding the glue ``addon`` (one import identity)."""
    import importlib

    return importlib.import_module(addon.__name__.rpartition(".")[0] + ".precompute.scratch." + name)


def measured_like(profiles, name: str = "bulges"):
    """A measured-like asymmetric profile with bulges on both rims (Mérillou-style, §5.3): 48 samples."""
    x = np.linspace(0.0, 1.0, 48)
    h = (0.07 * np.exp(-((x - 0.07) / 0.05) ** 2) + 0.04 * np.exp(-((x - 0.94) / 0.04) ** 2)
         - 0.32 * np.exp(-((x - 0.42) / 0.2) ** 2) - 0.08 * np.exp(-((x - 0.7) / 0.08) ** 2))
    return profiles.tabulated(x, h, name=name)


def cases(addon, names=None) -> list[Case]:
    """The bench's cases: V-groove 30 deg, quartic 0.5, round 0.5, measured-like with bulges; lossless and gold."""
    profiles, fresnel = science(addon, "profiles"), science(addon, "fresnel")
    gold = fresnel.conductor_preset("gold")
    profs = {"v30": profiles.v_groove(30.0), "q05": profiles.quartic(0.5, segments=64),
             "round": profiles.circular(0.5, segments=64), "bulges": measured_like(profiles)}
    out = []
    for key, prof in profs.items():
        out.append(Case(key, prof))
        out.append(Case(key + "_gold", prof, gold))
    if names:
        want = set(names)
        out = [c for c in out if c.name in want]
        if len(out) != len(want):
            raise ValueError(f"cases: unknown {sorted(want - {c.name for c in out})}; choose from "
                             + ", ".join(c.name for c in cases(addon)))
    return out


class TruthScene:
    """One Blender scene per case: the explicit grooves and the material plane (toggled), an orthographic
    camera moved per view, direction-coded worlds and a studio world with a small lamp."""

    def __init__(self, addon, case: Case, res: int = RES, samples: int = 16, grooves_per_pixel: int = GROOVES_PER_PIXEL):
        sm = addon.scratch_material
        self.addon, self.case, self.res, self.samples = addon, case, int(res), int(samples)
        self.period = ORTHO / (res * grooves_per_pixel)
        self.scene = addon.render.reset_scene()
        configure(addon, self.scene, samples, res, 0, False)
        params = sm.validate(profile=case.profile, fresnel=case.fresnel, layers=case.layers, base="mirror",
                             **case.material_kw)
        self.material = sm.build(addon.materials.new_material(f"Scratch {case.name}"), params)
        self.plane = addon.render.add_plane(self.scene, size=40.0 * ORTHO, material=self.material, name="Material plane")
        self.truth_mat = mirror_material(addon, case.fresnel)
        self.grooves = None
        self.light = None
        self.worlds = {}
        for kind in WORLDS + ("below",):
            set_world(addon, self.scene, kind)
            self.worlds[kind] = self.scene.world
            self.scene.world.name = f"Truth {kind}"
        addon.render.studio_world(self.scene, 1.0)
        self.worlds["studio"] = self.scene.world
        self.tmp = tempfile.mkdtemp(prefix="scratch_truth_")
        self.omega = None

    def set_view(self, theta_deg: float, azimuth_deg: float):
        import bpy

        omega = view_vector(theta_deg, azimuth_deg)
        self.omega = omega
        scale = snapped_scale(omega, self.period, res=self.res)
        hx, hy = footprint(omega, scale)
        n = int(math.ceil(2.0 * (hy + 4 * self.period) / self.period))
        mesh = science(self.addon, "explicit").groove_field(
            self.case.profile, n, self.period, x_range=(-hx - 0.5 * ORTHO, hx + 0.5 * ORTHO))
        if self.grooves is not None:
            old = self.grooves.data
            bpy.data.objects.remove(self.grooves)
            bpy.data.meshes.remove(old)
        self.grooves = add_mesh(self.scene, mesh, self.truth_mat)
        set_camera(self.scene, omega, scale)
        if self.light is not None:
            data = self.light.data
            bpy.data.objects.remove(self.light)
            bpy.data.lights.remove(data)
        self.light = lamp(self.addon, self.scene, omega)
        return mesh

    def render(self, what: str, world: str, seed: int = 0) -> np.ndarray:
        """Image [res, res, 3] of ``what`` ("truth", "osl", "svm") under ``world``."""
        self.grooves.hide_render = what != "truth"
        self.plane.hide_render = what == "truth"
        self.light.hide_render = world != "studio"
        self.scene.world = self.worlds[world]
        self.scene.cycles.shading_system = what == "osl"
        self.scene.cycles.seed = int(seed)
        img, _ = self.addon.render.render_array(self.scene, self.tmp, f"{what}_{world}")
        return img


def quadrant_noise(img: np.ndarray) -> np.ndarray:
    """Std error of the image mean per channel from its 4 quadrants (std of quadrant means / 2)."""
    h, w = img.shape[0] // 2, img.shape[1] // 2
    q = np.stack([img[:h, :w], img[:h, w:], img[h:, :w], img[h:, w:]]).reshape(4, -1, 3).mean(1)
    return q.std(0, ddof=1) / 2.0


def measure_view(ts: TruthScene, view, paths=("truth", "osl", "svm"), worlds=WORLDS + ("studio",), seed: int = 0):
    """Moments of every path at one view: {path: {"A", "m1", "m2", "studio", "noise": {...}, "img": {...}}}."""
    ts.set_view(*view)
    out = {}
    for p in paths:
        vals, noise, imgs = {}, {}, {}
        for w in worlds:
            img = ts.render(p, w, seed)
            vals[w], noise[w], imgs[w] = image_means(img), quadrant_noise(img), img
        m = moments(vals)
        m["studio"] = vals.get("studio")
        m["noise"] = noise
        m["img"] = imgs
        out[p] = m
    return out


def errors(meas: dict, path: str) -> dict:
    """Errors of ``path`` against the truth: A relative (max over RGB), |Δm1|, |Δm2| (max over components,
    direction-cosine units), studio relative (max over RGB), and the noise (1 sigma) of each."""
    t, m = meas["truth"], meas[path]
    A_t = np.maximum(t["A"], 1e-6)
    e = {"A": float(np.max(np.abs(m["A"] - t["A"]) / A_t))}
    for k in ("m1", "m2"):
        if k in t:
            e[k] = float(np.max(np.abs(m[k] - t[k])))
    if t.get("studio") is not None:
        e["studio"] = float(np.max(np.abs(m["studio"] - t["studio"]) / np.maximum(t["studio"], 1e-6)))
    # noise of the difference (quadrants of material - truth: the scratch pattern both share cancels)
    dn = lambda w: quadrant_noise(m["img"][w] - t["img"][w])  # noqa: E731
    nz = lambda d, w: float(np.max(dn(w) / A_t))  # noqa: E731
    e["noise_A"] = nz(m, "white")
    if "first" in t["noise"]:
        e["noise_m1"] = 2 * nz(m, "first")
    if "second" in t["noise"]:
        e["noise_m2"] = nz(m, "second")
    if "studio" in t["noise"]:
        e["noise_studio"] = float(np.max(dn("studio") / np.maximum(t["studio"], 1e-6)))
    return e


# ------------------------------------------------------------------------------------------------ layered
#: layered case: 3 layers spread over 40 deg, 0.2 x 0.02 UV scratches, density 0.2, on a 2 m plane
LAYERED = dict(n_layers=3, theta_deg=40.0, length=0.2, width=0.02, density=0.2, seed=1)
LAYERED_VIEWS = {"down": (0.0, 0.0), "along45": (45.0, 0.0), "across45": (45.0, 90.0), "oblique60/30": (60.0, 30.0)}


class LayeredTruthScene(TruthScene):
    """Layered scratches (eq. 4, 7) vs explicit grooves placed by the same layer parameters
    (``explicit.layer_field``: grooves of ``period`` under every scratched cell of Cycles' own Voronoi, a flat
    mirror lid elsewhere) in a UV window; the camera looks at the window's centre."""

    def __init__(self, addon, case: Case, window=(0.35, 0.35, 0.65, 0.65), res: int = 64, samples: int = 16,
                 period: float = ORTHO / 1000.0):
        super().__init__(addon, case, res=res, samples=samples)
        u0, v0, u1, v1 = window
        size = 2.0 * ORTHO                                        # the UV plane (add_plane(size=40 ORTHO) scaled)
        self.plane.scale = (size / (40.0 * ORTHO), size / (40.0 * ORTHO), 1.0)
        self.mesh = science(addon, "explicit").layer_field(case.profile, case.layers, period, window, plane_size=size)
        self.grooves = add_mesh(self.scene, self.mesh, self.truth_mat, "Layered grooves")
        self.span = size * min(u1 - u0, v1 - v0)
        self.centre = (0.5 * size * (u0 + u1 - 1.0), 0.5 * size * (v0 + v1 - 1.0), 0.0)     # plane coords of the window centre

    def set_view(self, theta_deg: float, azimuth_deg: float):
        import bpy

        omega = view_vector(theta_deg, azimuth_deg)
        self.omega = omega
        # the view's footprint must stay inside the window: shrink the image by 1/cos
        scale = 0.8 * self.span * max(omega[2], 0.2)
        set_camera(self.scene, omega, scale, target=self.centre)
        if self.light is not None:
            data = self.light.data
            bpy.data.objects.remove(self.light)
            bpy.data.lights.remove(data)
        self.light = lamp(self.addon, self.scene, omega)
        return self.mesh


def layered_cases(addon) -> list[Case]:
    profiles, fresnel, layers = science(addon, "profiles"), science(addon, "fresnel"), science(addon, "layers")
    lp = layers.LayerParams(**LAYERED)
    return [Case("q05 3 layers", profiles.quartic(0.5, segments=32), None, lp),
            Case("v30_gold 3 layers", profiles.v_groove(30.0), fresnel.conductor_preset("gold"), lp)]


# ------------------------------------------------------------------------------------------------- figure
FIGURE_CASES = ("v30_gold", "q05_gold", "bulges")
FIGURE_VIEWS = {"along the scratch": 0.0, "across the scratch": 90.0}


def figure_images(addon, case: Case, azimuth_deg: float, res: int = 128, samples: int = 64,
                  elevation_deg: float = 40.0, period: float = 1.0 / 1200.0):
    """Perspective renders (truth, osl, svm) [res, res, 3] of a plane of explicit grooves and of the material
    plane under the studio world and a small area light placed opposite the camera (the highlight streak)."""
    import bpy

    sm = addon.scratch_material
    scene = addon.render.reset_scene()
    configure(addon, scene, samples, res, 0, False)
    params = sm.validate(profile=case.profile, fresnel=case.fresnel, layers=None, base="mirror")
    mat = sm.build(addon.materials.new_material(f"Scratch {case.name}"), params)
    plane = addon.render.add_plane(scene, size=8.0, material=mat)
    mesh = science(addon, "explicit").groove_field(case.profile, int(3.2 / period), period, x_range=(-3.0, 3.0))
    grooves = add_mesh(scene, mesh, mirror_material(addon, case.fresnel))
    addon.render.studio_world(scene, 1.0)
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    cam = addon.render.add_camera(scene, location=tuple(2.2 * d), target=(0.0, 0.0, 0.0), lens=70.0)
    scene.camera = cam
    ld = np.array([-d[0], -d[1], d[2]]) * 3.0
    ld = ld + 0.25 * np.array([-math.sin(a), math.cos(a), 0.0])
    addon.render.add_light(scene, "AREA", location=tuple(ld), energy=60.0, size=0.15)
    tmp = tempfile.mkdtemp(prefix="scratch_truth_fig_")
    out = {}
    for what in ("truth", "osl", "svm"):
        grooves.hide_render = what != "truth"
        plane.hide_render = what == "truth"
        scene.cycles.shading_system = what == "osl"
        out[what], _ = addon.render.render_array(scene, tmp, what)
    return out


def write_figure(addon, path, res: int = 128, samples: int = 64, table_rows=None) -> list:
    """docs/img/scratch_truth.png: explicit grooves next to the material (OSL), same view; per panel the image
    mean rel. error and the 8x8-block rel. L1 error of the OSL and SVM paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cs = {c.name: c for c in cases(addon)}
    nrow, ncol = len(FIGURE_CASES), 2 * len(FIGURE_VIEWS)
    fig, axes = plt.subplots(nrow, ncol, figsize=(2.3 * ncol, 2.45 * nrow))
    stats = []
    for r, cname in enumerate(FIGURE_CASES):
        for j, (vname, az) in enumerate(FIGURE_VIEWS.items()):
            imgs = figure_images(addon, cs[cname], az, res, samples)
            t = imgs["truth"]
            err = {}
            for p in ("osl", "svm"):
                mean = float(np.max(np.abs(imgs[p].mean((0, 1)) - t.mean((0, 1))) / t.mean((0, 1))))
                b = lambda im: im.reshape(res // 8, 8, res // 8, 8, 3).mean((1, 3))  # noqa: E731
                block = float(np.abs(b(imgs[p]) - b(t)).sum() / b(t).sum())
                err[p] = (mean, block)
            stats.append((cname, vname, err))
            show = lambda im: np.clip(im / (1.0 + im), 0, 1) ** (1 / 2.2)  # noqa: E731
            for k, (im, lab) in enumerate(((t, "explicit grooves"), (imgs["osl"], "material (OSL)"))):
                ax = axes[r, 2 * j + k]
                ax.imshow(show(im))
                ax.set_xticks([])
                ax.set_yticks([])
                title = f"{cname}, {vname}\n{lab}"
                if k == 1:
                    title += (f"\nmean {100 * err['osl'][0]:.1f} %, blocks {100 * err['osl'][1]:.1f} %"
                              f"\n(SVM {100 * err['svm'][0]:.1f} / {100 * err['svm'][1]:.1f} %)")
                ax.set_title(title, fontsize=7)
    fig.suptitle(f"Scratch material vs Cycles path tracing explicit grooves ({res} px, {samples} spp, studio "
                 "world + small area light; errors: image mean, 8x8 blocks)", fontsize=8)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return stats


def main(argv: list[str]) -> int:
    from bench import _util

    ap = argparse.ArgumentParser(prog="python -m bench scratch_truth")
    ap.add_argument("--cases", default="", help="comma-separated case names (default: all)")
    ap.add_argument("--views", default="", help="comma-separated view names (default: all)")
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--paths", default="osl,svm")
    ap.add_argument("--out", default="scratch_truth.md")
    ap.add_argument("--label", default="")
    ap.add_argument("--figure", action="store_true", help="only write docs/img/scratch_truth.png")
    ap.add_argument("--layered", action="store_true", help="the layered cases (explicit.layer_field) instead")
    a = ap.parse_args(argv)
    addon = _util.blender(register=True)
    if a.figure:
        stats = write_figure(addon, ROOT / "docs" / "img" / "scratch_truth.png")
        for row in stats:
            print(row)
        return 0
    views = [v for v in VIEWS if not a.views or v in a.views.split(",")]
    paths = tuple(a.paths.split(","))
    rows = []
    t0 = time.perf_counter()
    todo = layered_cases(addon) if a.layered else cases(addon, [c for c in a.cases.split(",") if c] or None)
    if a.layered:
        views = [v for v in LAYERED_VIEWS if not a.views or v in a.views.split(",")]
    for case in todo:
        ts = (LayeredTruthScene(addon, case, res=a.res, samples=a.samples) if a.layered
              else TruthScene(addon, case, res=a.res, samples=a.samples))
        if a.layered:
            print(case.name, {k: ts.mesh.meta[k] for k in ("coverage", "overlap", "scratched", "runs")}, flush=True)
        for vname in views:
            meas = measure_view(ts, (LAYERED_VIEWS if a.layered else VIEWS)[vname], ("truth",) + paths)
            for p in paths:
                e = errors(meas, p)
                rows.append([case.name, vname, p, 100 * e["A"], 100 * e["m1"], 100 * e["m2"], 100 * e["studio"],
                             100 * max(e["noise_A"], e["noise_m1"], e["noise_m2"]), 100 * e["noise_studio"]])
                print(" | ".join(str(r) if not isinstance(r, float) else f"{r:.2f}" for r in rows[-1]), flush=True)
    head = ["case", "view (theta/azimuth from scratch)", "path", "A %", "m1 x100", "m2 x100", "studio %",
            "noise (1 sigma) x100", "studio noise %"]
    text = (f"# Scratch material vs explicit grooves (Cycles){' - ' + a.label if a.label else ''}\n\n"
            f"{a.res}x{a.res} px orthographic, {GROOVES_PER_PIXEL} grooves per pixel, {a.samples} spp; "
            f"A: albedo rel. error (max RGB); m1, m2: |error| of E[d], E[d^2] of the exit direction (max component, "
            f"x100); studio: image mean rel. error under the studio world + a small area light.  Views: "
            + ", ".join(f"{k} = {v[0]:g}/{v[1]:g}" for k, v in (LAYERED_VIEWS if a.layered else VIEWS).items()
                        if k in views)
            + (f".  Layered: {LAYERED}, explicit grooves of period 1 mm in a 0.6 m window" if a.layered else "")
            + f".  {time.perf_counter() - t0:.0f} s.\n\n" + _util.format_table(head, rows) + "\n")
    _util.out_path(a.out).write_text(text)
    print(text)
    return 0
