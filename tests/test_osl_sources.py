"""The OSL sources in osl/ (plain .osl files specialised by the preprocessor) and their generators.

- every .osl file compiles on its own with Blender's compiler (``_cycles.osl_compile``), with its
  default flags and default tables;
- every feature combination the generators can emit compiles, from small but real tables (a
  simulated quartic scratch table at M = 16, fitted / box / table lobes over 4 slices, layer
  transforms and coverage, a random scratch set with sphere and polygon lights, a bi-scale table),
  and the compiled shader has exactly the sockets the spec asks for;
- every boolean flag combination also compiles with the .osl file's own default tables;
- the generators hold no OSL code (no raw-string shader blocks left in osl/*.py); the Si
  coefficients of the .osl file are the ones of the numpy twin.
"""
from __future__ import annotations

import ast
import glob
import itertools
import os
import re

import numpy as np
import pytest

from scratch_materials import osl
from scratch_materials.osl import biscale_reference, iridescent_layer, scratch_svbrdf
from scratch_materials.precompute.iridescence import layer as ly

OSL_FILES = sorted(glob.glob(os.path.join(osl.OSL_DIR, "*.osl")))
GENERATORS = sorted(glob.glob(os.path.join(osl.OSL_DIR, "*.py")))
#: Boolean feature flags of each shader (the rest of a generated header are sizes and values).
BOOL_FLAGS = {
    "scratch_svbrdf.osl": ("LAYERS", "PICK_LAYER", "ALPHA_MEAN", "USE_BASE", "BASE_PICK", "LOSSLESS", "LOBE_TABLE",
                           "LOBE_SUM", "JITTERED"),
    "scratch_reference.osl": ("LAYERS", "USE_BASE"),
    "iridescent_layer.osl": ("ROUTE_LIGHTS", "BASE_BLEND", "NSPH", "NPOLY"),
}


def _header_defines(src: str) -> dict:
    """The generated header's ``#define NAME value`` lines (before the .osl text)."""
    head = src.split("\n\n", 1)[0]
    return dict(m.groups() for m in re.finditer(r"^#define (\w+) (.*)$", head, re.M))


# ----------------------------------------------------------------------------- specs from real tables
@pytest.fixture(scope="module")
def scratch_specs():
    """(name, spec, expected sockets) for every scratch shader variant the generators can emit."""
    from scratch_materials.precompute.scratch import (brdf as scratch_brdf, fresnel, layers as scratch_layers,
                                                     lobes as scratch_lobes, profiles)
    from scratch_materials.precompute.scratch.layers import LayerParams

    coverage = scratch_layers.coverage_table()[1]

    def layer_kw(n):
        if n is None:
            return dict(layers=None)
        lp = LayerParams(n_layers=n, theta_deg=360.0, length=0.1, width=1e-3, density=0.2, seed=3)
        theta_k, xi_k = scratch_layers.layer_transforms(lp)
        return dict(layers=lp, theta_k=theta_k, xi_k=xi_k, coverage=coverage)

    lobes = {}
    for lossy in (False, True):
        brdf = scratch_brdf.simulate(profiles.quartic(0.3), resolution=16,
                                     fresnel=fresnel.conductor_preset("gold") if lossy else None)
        t = scratch_lobes.table_lobes(profiles.quartic(0.3), fresnel.conductor_preset("gold") if lossy else None,
                                      resolution=64, slices=4)
        lobes[lossy, "table"] = dict(lobes_m=None, table=scratch_svbrdf.TableLobes.from_tables(t, strata=4),
                                     alpha_x=t["alpha_x"])
        for shape in ("fit", "box"):
            f = scratch_lobes.lobe_tables(brdf, K=3, slices=4, jitter=shape == "box")
            lobes[lossy, shape] = dict(lobes_m=scratch_svbrdf.LobeTable.from_fit(f["m"]),
                                       lobes_0=None if f["0"] is None else scratch_svbrdf.LobeTable.from_fit(f["0"]),
                                       alpha_x=f["alpha_x"])
        lobes[lossy, "brdf"] = brdf
    out = []
    # layers dense / 1 / summed (2) / picked (16) x lossless / Fresnel x base / no base x fit, box, table
    # lobes x one picked lobe / all lobes (table: TK = strata) ; alpha_mode "mean" and base_pick=False
    # only change the layered eq. 4 / α code: every lobe shape with 16 layers
    for lossy, n, shape, mode, base, extra in itertools.product(
            (False, True), (None, 1, 2, 16), ("fit", "box", "table"), ("pick", "all"), (False, True),
            ({}, {"alpha_mode": "mean"}, {"base_pick": False})):
        if n is None and (base or extra) or extra and n != 16 or extra.get("base_pick") is False and not base:
            continue
        spec = scratch_svbrdf.ShaderSpec(**lobes[lossy, shape], use_base=base, lobe_mode=mode, **layer_kw(n),
                                         **extra, name=f"s_{len(out)}")
        sockets = (["UV"] if n else []) + (["Base"] if base and n else []) + (["Length", "Width", "Density"] if n
                                                                                else [])
        out.append(("svbrdf", spec, sockets + ["Tangent", "Tint", "BSDF", "Alpha"]))
    for n, base in itertools.product((None, 16), (False, True)):   # (ρ0 only changes the tables)
        if n is None and base:
            continue
        b = lobes[True, "brdf"]
        spec = scratch_svbrdf.ReferenceSpec(rho_m=b.rho_m, rho0=b.rho0, gamma=b.gamma, use_base=base, **layer_kw(n),
                                            name=f"r_{len(out)}")
        sockets = (["UV", "Length", "Width", "Density"] if n else []) + (["Base"] if base and n else [])
        out.append(("reference", spec, sockets + ["Tangent", "Tint", "BSDF", "Alpha"]))
    return out


def _iridescent_specs():
    from scratch_materials.precompute.iridescence.scratch_set import random_scratches

    S = random_scratches(20, seed=3, uv_scale_um=1e4)
    sphere = ly.SphereLightSpec((0.2, -0.1, 2.0), 0.1, (3.0, 2.0, 1.0))
    poly = ly.PolygonLightSpec(((0, 0, 2), (0, 1, 2), (1, 1, 2), (1, 0, 2.2)), (2.0, 2.0, 2.0), True)
    out = []
    # route A (lobes; lights are ignored) / route B with no, sphere, polygon, both lights x base_blend
    # x candidates all / RIS
    for (route, lights), blend, cand in itertools.product(
            [("lobes", [sphere]), ("lights", []), ("lights", [sphere]), ("lights", [poly]), ("lights", [sphere, poly])],
            (True, False), (0, 4)):
        out.append(ly.LayerSpec(S, route=route, lights=list(lights), base_blend=blend, candidates=cand,
                                              name=f"i_{len(out)}"))
    out.append(ly.LayerSpec(S, samples=3, name="i_samples"))
    out.append(ly.LayerSpec(random_scratches(0), name="i_empty"))
    return out


# ----------------------------------------------------------------------------- (a) standalone files
@pytest.mark.bpy
@pytest.mark.parametrize("path", OSL_FILES, ids=os.path.basename)
def test_every_osl_file_compiles_on_its_own(path):
    from osl.compiler import compile_file, oso_params, oso_shader_name

    oso = compile_file(path)
    assert oso_shader_name(oso) == os.path.basename(path)[:-4]
    assert any(kind == "oparam" for kind, _ in oso_params(oso).values())


def test_there_is_an_osl_file_per_generator():
    names = {os.path.basename(p) for p in OSL_FILES}
    assert {"scratch_svbrdf.osl", "scratch_reference.osl", "iridescent_layer.osl", "biscale_reference.osl"} <= names


# ----------------------------------------------------------------------------- (b) generated variants
@pytest.mark.bpy
def test_every_generated_feature_combination_compiles(scratch_specs):
    from osl.compiler import compile_source, oso_params, oso_shader_name

    sources = []   # (source, expected shader name, expected sockets or None)
    for kind, spec, sockets in scratch_specs:
        gen = scratch_svbrdf.generate if kind == "svbrdf" else scratch_svbrdf.generate_reference
        sources.append((gen(spec), spec.name, sockets))
    for spec in _iridescent_specs():
        sources.append((iridescent_layer.generate(spec), spec.name, ["Base", "UV", "Tangent", "BSDF"]))
    rng = np.random.default_rng(1)
    for res in (2, 4):
        brdf = type("EffectiveBRDF", (), {"dir_res": res, "table": rng.random((res * res, res * res, 3))})()
        sources.append((biscale_reference.generate(brdf, name=f"b_{res}"), f"b_{res}", ["Tangent", "Tint", "BSDF"]))

    headers = set()   # (.osl file, generated #defines)
    for src, name, sockets in sources:
        # self-contained: only Blender's own headers are left as includes
        assert set(re.findall(r'^\s*#\s*include\s+"([^"]+)"', src, re.M)) <= {"stdcycles.h", "node_voronoi.h"}
        oso = compile_source(src, name)
        assert oso_shader_name(oso) == name
        assert list(oso_params(oso)) == sockets, name
        source = re.match(r"// Generated by .* from osl/(\S+\.osl)", src).group(1)
        headers.add((source, tuple(sorted((k, v) for k, v in _header_defines(src).items() if k != "SHADER_NAME"))))
    # each spec is a distinct feature combination, and every boolean flag is compiled both ways
    assert len(headers) == len(sources) == 120 + 3 + 22 + 2
    for source, flags in BOOL_FLAGS.items():
        emitted = [dict(h) for src, h in headers if src == source]
        for flag in flags:
            assert {emitted_h[flag] != "0" for emitted_h in emitted} == {False, True}, (source, flag)


@pytest.mark.bpy
def test_every_flag_combination_compiles_with_the_default_tables():
    """The .osl files on their own: every combination of their boolean flags (as ``oslc -D...`` would
    set them) compiles against the default tables headers."""
    from osl.compiler import compile_source

    n = 0
    for source, flags in BOOL_FLAGS.items():
        for values in itertools.product((0, 1), repeat=len(flags)):
            d = dict(zip(flags, values))
            if source == "scratch_svbrdf.osl" and (d["LOBE_TABLE"] and (d["LOBE_SUM"] or d["JITTERED"])
                                                   or not d["LAYERS"] and (d["PICK_LAYER"] or d["USE_BASE"])
                                                   or not d["USE_BASE"] and d["BASE_PICK"]
                                                   or not d["LAYERS"] and d["ALPHA_MEAN"]):
                continue   # flags without effect in that combination: the generator never emits them
            if source == "iridescent_layer.osl" and not d["ROUTE_LIGHTS"] and (d["NSPH"] or d["NPOLY"]):
                continue
            if source == "scratch_reference.osl" and d["USE_BASE"] and not d["LAYERS"]:
                continue
            compile_source(osl.specialise(source, d), source[:-4])
            n += 1
    assert n == 130 + 3 + 10


# ----------------------------------------------------------------------------- (c) no OSL in Python
_OSL_CODE = re.compile(r"closure\s+color|\bshader\s+\w+\s*\(|microfacet\s*\(|hashnoise\s*\(|ray_portal_bsdf\s*\("
                       r"|\bfor\s*\(\s*int\b|\breturn\s+\w+\s*;|#\s*include\s+\"")


def _string_constants(tree):
    """Every string constant of a module except docstrings (f-string parts included)."""
    docs = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                docs.add(id(first.value))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            yield node


@pytest.mark.parametrize("path", GENERATORS, ids=os.path.basename)
def test_generators_hold_no_osl_code(path):
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    for node in _string_constants(tree):
        assert not _OSL_CODE.search(node.value), f"{os.path.basename(path)}:{node.lineno}: OSL code in a string"
        assert node.value.count("\n") <= 2, f"{os.path.basename(path)}:{node.lineno}: a multi-line text block"


def test_the_checks_above_can_fail():
    old_style = 'SNIPPET = r"""\nclosure color lobe(float t)\n{\n    return microfacet("ggx", N, 0.1);\n}\n"""\n'
    consts = list(_string_constants(ast.parse(old_style)))
    assert consts and all(_OSL_CODE.search(c.value) for c in consts)
    assert _header_defines("// x\n#define LAYERS 1\n#define NL 16\n\n#define LATER 2") == {"LAYERS": "1", "NL": "16"}


# ----------------------------------------------------------------------------- shared numbers
def test_si_coefficients_in_the_shader_are_the_numpy_twins():
    src = osl.read_source("iridescent_layer.osl")
    for name, ref in (("SF", ly.SI_F), ("SG", ly.SI_G)):
        body = re.search(rf"float {name}\[9\] = \{{([^}}]*)\}};", src).group(1)
        vals = np.array([float(v) for v in body.split(",")], np.float32)
        np.testing.assert_array_equal(vals, np.asarray(ref, np.float32))


def test_include_inlining():
    text = '#include "stdcycles.h"\n#include "scratch_layers.h"\n{\n#include "scratch_svbrdf_tables.h"\n}\n'
    out = osl.inline_includes(text, {"scratch_svbrdf_tables.h": "    float X[1] = {1};\n"})
    assert '#include "stdcycles.h"' in out and "float disk_overlap(" in out and "float X[1] = {1};" in out
    assert "scratch_svbrdf_tables.h\"" not in out and "LM_START" not in out
    assert osl.define_value(True) == "1" and osl.define_value(np.int64(3)) == "3" and osl.define_value(1e-6) == "1e-06"
