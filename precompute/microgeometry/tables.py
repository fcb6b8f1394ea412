"""A measured height field to the tables of its material (Dong et al. 2015, §5.1, §6, §8-9), cached.

``compute_tables`` reads a height field (.npy/.npz/.exr/text grid, see ``heightfield``), computes its
average NDF (filtered §5.1 / naive / Kirchhoff §6), fits the ellipsoid NDF (§8) and optionally
synthesises a spatially varying ellipsoid texture (§9) from a texel strip along x and one along y of
the scan.  Tables are cached (``tables.cache.cached_arrays``, key = file content hash + parameters),
so re-running with the same inputs is instant.  ``scratch_addon.microgeometry_ops`` turns them into
node trees.
"""
from __future__ import annotations

import hashlib
import os

import numpy as np

from ..tables import cache
from ..validation import check_range
from . import ellipsoid as ell, heightfield as hfm, ndf as mg, synthesis as syn

NDF_KINDS = (
    ("FILTERED", "Filtered", "Gaussian-weighted plane fits, sigma (§5.1; the paper's default)"),
    ("NAIVE", "Naive", "Triangle normals of the raw height field (§5.1)"),
    ("KIRCHHOFF", "Kirchhoff", "Kirchhoff D_K at wavelength lambda (eq. 6, Appendix A)"),
)
_NDF_RESOLUTION = 513
_TEXEL_TABLE_RESOLUTION = 257


def file_sha256(path: str) -> str:
    """SHA-256 of a file's bytes (the cache key of a height field)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _check_params(pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um):
    pixel_um = check_range("pixel_um", pixel_um, 1e-4, 1e4)
    sigma_um = check_range("sigma_um", sigma_um, 1e-4, 1e4)
    wavelength_um = check_range("wavelength_um", wavelength_um, 0.05, 100.0)
    if ndf_kind not in {k for k, _, _ in NDF_KINDS}:
        raise ValueError(f"ndf_kind must be one of {[k for k, _, _ in NDF_KINDS]}, got {ndf_kind!r}")
    texture_size = int(check_range("texture_size", texture_size, 8, 4096))
    texel_um = check_range("texel_um", texel_um, 1e-3, 1e5)
    return pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um


def compute_tables(filepath: str, pixel_um: float, sigma_um: float = 1.0, wavelength_um: float = 0.555,
                   ndf_kind: str = "FILTERED", synthesize: bool = False, texture_size: int = 256,
                   texel_um: float = 63.5, seed: int = 0, progress=None, with_ndf: bool = False) -> dict:
    """Average ellipsoid parameters (and optionally a synthesised (S, S, 5) texture), cached.

    Units: micrometres (pixel size, sigma, wavelength, texel size).  Returns
    ``{"ellipsoid": (5,), "texture": (S, S, 5) (if synthesize), "cached": bool}``.  ``progress(f)``
    is called with fractions in [0, 1].  Raises ``ValueError`` with the parameter's name on bad input.
    ``with_ndf``: also ``"ndf"``, the measured NDF table itself (``NDFTable.table``, (R, R) on the
    orthographic disk, §5.1) for the tabulated material (``ndf_brdf``).
    """
    pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um = _check_params(
        pixel_um, sigma_um, wavelength_um, ndf_kind, texture_size, texel_um)
    if not filepath or not os.path.isfile(filepath):
        raise ValueError(f"filepath: no such height-field file {filepath!r}")
    report = progress or (lambda f: None)
    version = cache.code_version(hfm, mg, ell, syn)
    f32 = lambda v: float(np.float32(v))  # noqa: E731 - operator properties are float32: same key either way
    uses_sigma = ndf_kind == "FILTERED" or synthesize
    inputs = {"file_sha256": file_sha256(filepath), "pixel_um": f32(pixel_um), "ndf_kind": ndf_kind,
              "sigma_um": f32(sigma_um) if uses_sigma else 0.0,
              "wavelength_um": f32(wavelength_um) if ndf_kind == "KIRCHHOFF" else 0.0,
              "synthesize": bool(synthesize), "texture_size": texture_size if synthesize else 0,
              "texel_um": f32(texel_um) if synthesize else 0.0, "seed": int(seed) if synthesize else 0}
    if ndf_kind == "FILTERED":
        inputs["periodic"] = "auto"   # the filtered NDF of a seamless scan wraps its windows (ndf.filtered_ndf)
    if with_ndf:
        inputs["with_ndf"] = True     # only then: the ellipsoid-only entries stay valid
    state = {"cached": True}

    def compute():
        state["cached"] = False
        hf = hfm.load_heightfield(filepath, pixel_um=pixel_um)
        report(0.1)
        if ndf_kind == "FILTERED":
            # a seamless (periodic) scan wraps its windows around, so no point gets a one-sided window: the NDF
            # is then exactly the normals of the σ-smoothed surface tiled (heightfield.smoothed_heights)
            ndf = mg.filtered_ndf(hf, sigma_um=sigma_um, resolution=_NDF_RESOLUTION, periodic="auto")
        elif ndf_kind == "NAIVE":
            ndf = mg.naive_ndf(hf, resolution=_NDF_RESOLUTION)
        else:
            ndf = mg.kirchhoff_ndf(hf, wavelength_um=wavelength_um, resolution=_NDF_RESOLUTION, normalize=True)
        report(0.4)
        out = {"ellipsoid": np.array(mg.fit_ellipsoid(ndf), dtype=np.float64)}
        if with_ndf:
            out["ndf"] = np.asarray(ndf.table, dtype=np.float64)
        report(0.5)
        if synthesize:
            strip_x, strip_y = _strips(hf, texel_um)
            out["texture"] = syn.synthesize_from_strips(strip_x, strip_y, (texture_size, texture_size), texel_um,
                                                        hf.pixel_um, sigma_um, int(seed), _TEXEL_TABLE_RESOLUTION)
        report(0.9)
        return out

    result = {k: np.array(v, dtype=np.float64) for k, v in
              cache.cached_arrays("microgeometry_material", version, inputs, compute).items()}
    for k, v in result.items():  # float32 storage can round a clamped bound just outside the valid range
        if k == "ndf":
            continue
        v[..., :2] = np.clip(v[..., :2], ell.ALPHA_MIN, ell.ALPHA_MAX)
        v[..., 2:4] = np.clip(v[..., 2:4], -ell.THETA_XY_MAX, ell.THETA_XY_MAX)
    result["cached"] = state["cached"]
    report(1.0)
    return result


def _strips(hf, texel_um: float):
    """§9 exemplars: the middle texel-high row band (along x) and texel-wide column band (along y)."""
    tp = int(round(texel_um / hf.pixel_um))
    ny, nx = hf.shape
    if tp < 4 or nx < 8 * tp or ny < 8 * tp:
        raise ValueError(f"texel_um: {texel_um} µm = {tp} px texels; texture synthesis needs >= 4 px texels and "
                         f">= 8 texels along each side of the {nx} x {ny} px height field")
    y0, x0 = (ny // tp // 2) * tp, (nx // tp // 2) * tp
    return hf.crop(y0, y0 + tp, 0, nx), hf.crop(0, ny, x0, x0 + tp)
