"""Measured BRDFs (MERL binary format, Matusik et al. 2003) as materials: the API function
``material_from_merl``, the operator ``scratch.import_merl`` and its panel.

The file is read and resampled by ``precompute.tables.merl`` onto the isotropic grid of the
tabulated-BRDF closure; Cycles renders it exactly (OSL: ``osl/tabulated_brdf.osl``; SVM and GPU: the same
closure as nodes, ``node_groups/tabulated_svm``), EEVEE the nodes' EEVEE variant (``scratch_addon.tabulated_material``;
its smooth part as a Diffuse closure, ``tabulated_brdf.floor_split``).

Headless: ``bpy.ops.scratch.import_merl(filepath="gold-metallic-paint.binary")`` with a mesh active,
or ``material_from_merl(path)``.
"""
from __future__ import annotations

import os

import bpy
import numpy as np

from ..precompute import validation
from ..precompute.tables import merl, tabulated_brdf
from . import panels, tabulated_material, transaction
from .ui_utils import USER_ERRORS, assign_material, poll_active_mesh, progress, report_error


#: view angles θo (degrees) of the import's energy check (``energy_check``)
ALBEDO_VIEWS_DEG = (0.0, 45.0, 70.0)


def file_albedo(table, wo, n_theta: int = 90, n_phi: int = 180) -> np.ndarray:
    """Directional albedo ∫ f cos θi dωi (N, 3) of the measured BRDF itself (``table`` (90, 90, 180, 3), the MERL
    nearest-bin lookup ``merl.lookup``) for views ``wo`` (N, 3): midpoint rule over the half vector in MERL's own
    warping θh = x² π/2 (``n_theta`` = 90: one point per θh bin, dense at the peak) x ``n_phi`` φh, with
    ωi = reflect(ωo, h), dωi = 4 |h·ωo| dωh.  Measured on a GGX α 0.05 file against 1500 x 360 points: within
    0.14 % at θo 0 / 45 / 70° (a uniform 192² h grid of twice the cost: 0.3-0.6 %).  Dimensionless."""
    return merl.half_vector_albedo(lambda wi, wo_: merl.lookup(table, wi, wo_), wo, n_theta, n_phi)


def energy_check(table, brdf, floor=True) -> dict:
    """What the imported material reflects against what the file measures: the directional albedo (mean of R,
    G, B) at ``ALBEDO_VIEWS_DEG`` of the rendered closure (``tabulated_brdf.closure_albedo``: the floors
    (Diffuse kd, glossy ks g) plus the table residual) and of the file (``file_albedo``), and the worst relative difference.  The
    table's error is its resolution; this is its measure in energy (a white furnace renders this albedo)."""
    a = np.radians(ALBEDO_VIEWS_DEG)
    wo = np.stack([np.sin(a), np.zeros_like(a), np.cos(a)], 1)
    got = tabulated_brdf.closure_albedo(brdf, wo, floor).mean(1)
    want = file_albedo(table, wo).mean(1)
    rel = (got - want) / np.maximum(want, 1e-6)
    return {"views_deg": list(ALBEDO_VIEWS_DEG), "table": [float(v) for v in got], "file": [float(v) for v in want],
            "worst_rel": float(rel[np.argmax(np.abs(rel))])}


def import_resolution(table, res="auto", n_theta=None) -> dict:
    """The table size of an import: ``res`` "auto" (or None): from the file's specular peak (``merl.lobe_width``,
    ``merl.auto_resolution``: cells no wider than the peak's half width, 24..48), ``n_theta`` None: ``merl.AUTO_N_THETA``
    (32); integers are explicit overrides (``res`` 4..48, ``n_theta`` 4..90).  Returns {"res", "n_theta", "auto",
    "width" (the peak's half width, radians), "sharper" (the peak is narrower than the largest table's cells)}."""
    width = merl.lobe_width(table)
    auto = res is None or (isinstance(res, str) and res == "auto")
    if auto:
        res, sharper = merl.auto_resolution(width)
    else:
        if isinstance(res, str):
            raise ValueError(f"res: expected 'auto' or an integer in [4, 48], got {res!r}")
        res = int(validation.check_range("res", res, 4, 48))
        sharper = merl.cell_angle(res) > merl.CELLS_PER_WIDTH * width
    n_theta = merl.AUTO_N_THETA if n_theta is None else int(validation.check_range("n_theta", n_theta, 4, 90))
    return {"res": int(res), "n_theta": n_theta, "auto": bool(auto), "width": float(width), "sharper": bool(sharper)}


def material_from_merl(path, name: str | None = None, res="auto", n_theta: int | None = None, progress=None,
                       floor=True):
    """Material of the MERL BRDF in ``path`` (``res`` x ``res`` half-vector cells and ``n_theta`` view angles on
    the closure's isotropic grid; missing bins take their measured neighbour's value, ``merl.fill_missing``).
    ``res`` "auto" (default; None too): the grid follows the file's sharpness (``import_resolution``: cells no wider
    than the specular peak's half width, 24..48; ``n_theta`` None: 32); an integer 4..48 is an explicit override.
    What the table closure renders is deconvolved to the cells' averages (``merl.to_tabulated``).
    ``floor``: the BRDF's smooth part kd/π renders as a Diffuse closure and (True = "auto", or "glossy") a GGX /
    Beckmann lobe under its glossy part as a Glossy closure, only the rest through the table closure
    (``tabulated_brdf.floor_parts``: a point lamp then lights both at every sample); "diffuse": the Diffuse floor
    alone; False / "none": no floor.
    Custom properties ``merl_albedo_views`` / ``merl_albedo_table`` / ``merl_albedo_file``: the rendered
    closure's and the file's directional albedo at those view angles (``energy_check``); ``merl_res_auto``,
    ``merl_peak_width_deg`` (the peak's half width), ``merl_sharper_than_table``; what each render path
    shows: ``tabulated_svm`` / ``tabulated_eevee`` (``make_tabulated_material``).
    ValueError for unreadable / non-MERL files and out-of-range sizes; nothing is created then."""
    if not (res is None or isinstance(res, str)):
        validation.check_range("res", res, 4, 48)
    if n_theta is not None:
        validation.check_range("n_theta", n_theta, 4, 90)
    step = progress or (lambda f: None)
    step(0.0)
    table = merl.fill_missing(merl.read_merl(path))   # once: the table and the energy check read the same data
    size = import_resolution(table, res, n_theta)
    step(0.4)
    brdf = merl.to_tabulated(table, size["res"], size["n_theta"], fill=False)
    step(0.7)
    check = energy_check(table, brdf, floor)
    step(0.8)
    name = name or os.path.splitext(os.path.basename(os.fspath(path)))[0]
    with transaction.new_datablocks():
        mat = tabulated_material.make_tabulated_material(brdf, name, kind="merl", floor=floor)
        mat["merl_source"] = os.path.basename(os.fspath(path))
        mat["merl_albedo_views"] = check["views_deg"]
        mat["merl_albedo_table"] = check["table"]
        mat["merl_albedo_file"] = check["file"]
        mat["merl_res_auto"] = size["auto"]
        mat["merl_peak_width_deg"] = float(np.degrees(size["width"]))
        mat["merl_sharper_than_table"] = size["sharper"]
    step(1.0)
    return mat


def sharp_peak_text(mat, cell_deg: float) -> str:
    """What happens to a peak sharper than the table's cells (``cell_deg``): the glossy floor renders it exactly when
    its lobe is narrower than a cell (``merl.floor_points`` let it fit the file's own θh bins; custom properties
    ``tabulated_glossy_floor`` = (ks, α_g), ``tabulated_glossy_floor_dist``), else the table's cells blur it."""
    floor = list(mat.get("tabulated_glossy_floor", ()))
    dist = str(mat.get("tabulated_glossy_floor_dist", ""))
    if len(floor) == 4 and dist and max(floor[:3]) > 0:
        a = float(floor[3])
        half_deg = float(np.degrees(np.arctan((0.644 if dist == "ggx" else 0.833) * a)))
        if half_deg < cell_deg:
            return f"the peak is sharper than the cells, rendered by the glossy floor ({dist.upper()} α {a:.2g})"
    return "the peak is sharper than the cells: highlights may blur"


def import_summary(mat) -> str:
    """One line on an imported material: what renders where, and its energy against the file's."""
    paths = {"table": "the table", "fit": "a fitted Diffuse + Glossy twin"}
    svm, eevee = mat.get("tabulated_svm", "?"), mat.get("tabulated_eevee", "?")
    where = ("the table in Cycles (OSL and SVM) and EEVEE" if svm == eevee == "table" else
             f"the table in Cycles OSL; SVM: {paths.get(svm, svm)}; EEVEE: {paths.get(eevee, eevee)}")
    if "tabulated_twin_rel_l1" in mat:
        where += f" (twin fit error {100 * float(mat['tabulated_twin_rel_l1']):.0f} % rel. L1)"
    res = int(mat.get("tabulated_res", 0))
    text = f"{res}² directions"
    if "merl_peak_width_deg" in mat:
        w, cell = float(mat["merl_peak_width_deg"]), 90.0 / max(res, 1)
        text += (" (auto" if mat.get("merl_res_auto") else " (set") + f": peak half width {w:.2g}°, cells {cell:.2g}°"
        text += ("; " + sharp_peak_text(mat, cell) + ")") if mat.get("merl_sharper_than_table") else ")"
    text += f", {where}"
    if "merl_albedo_table" in mat:
        views, got, want = (list(mat[k]) for k in ("merl_albedo_views", "merl_albedo_table", "merl_albedo_file"))
        rel = [(g - w) / max(w, 1e-6) for g, w in zip(got, want)]
        worst = max(rel, key=abs)
        text += ("; albedo at " + "/".join(f"{v:g}" for v in views) + "°: " + "/".join(f"{g:.3f}" for g in got)
                 + ", file " + "/".join(f"{w:.3f}" for w in want) + f" ({100 * worst:+.1f} % worst)")
    kd = list(mat.get("tabulated_floor", ()))
    if kd:
        text += f"; smooth floor kd {max(kd):.3f}"
    return text


class SCRATCH_OT_import_merl(bpy.types.Operator):
    """Import a measured BRDF (MERL .binary) as a material on the active object: the table itself in Cycles
    (OSL or SVM, CPU or GPU) and EEVEE"""

    bl_idname = "scratch.import_merl"
    bl_label = "Import MERL BRDF"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(subtype="FILE_PATH")
    filter_glob: bpy.props.StringProperty(default="*.binary", options={"HIDDEN"})
    auto_res: bpy.props.BoolProperty(name="Automatic Resolution", default=True,
                                     description="Direction Resolution from the file's specular peak (cells no wider "
                                                 "than its half width, 24-48); off: the value below")
    res: bpy.props.IntProperty(name="Direction Resolution", default=32, min=4, max=48,
                               description="Half-vector cells per side of the table (hemi-octahedral); setting it "
                                           "turns Automatic Resolution off")
    n_theta: bpy.props.IntProperty(name="View Angles", default=32, min=4, max=90)

    @classmethod
    def poll(cls, context):
        return poll_active_mesh(cls, context)

    def invoke(self, context, event):
        if not self.filepath and context.window is not None:
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        obj = context.active_object
        props = self.properties
        if props.is_property_set("res") and not props.is_property_set("auto_res"):
            self.auto_res = False                      # a script's res=... is an explicit size, as before
        try:
            with progress(context) as update:
                mat = material_from_merl(self.filepath, res="auto" if self.auto_res else self.res,
                                         n_theta=self.n_theta, progress=update)
        except USER_ERRORS as exc:
            return report_error(self, exc, {"res": "Direction Resolution", "n_theta": "View Angles",
                                            "path": "File"})
        assign_material(obj, mat)
        self.report({"INFO"}, f"Assigned {mat.name} ({import_summary(mat)})")
        return {"FINISHED"}


class SCRATCH_PT_measured_brdf(bpy.types.Panel):
    bl_label = "Measured BRDF"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "material"
    bl_parent_id = "SCRATCH_PT_material"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return context.engine in panels.ENGINES

    def draw(self, context):
        layout = self.layout
        layout.operator(SCRATCH_OT_import_merl.bl_idname, icon="IMPORT")
        mat = context.material
        if mat is not None and "merl_source" in mat:
            layout.label(text=f"From: {mat['merl_source']}")
            layout.label(text=import_summary(mat))


classes = (SCRATCH_OT_import_merl, SCRATCH_PT_measured_brdf)
