"""Spatially varying ellipsoid-NDF textures from two exemplar strips (Dong et al. 2015, §9).

1. :func:`texel_ellipsoid_params` - per-texel filtered NDFs along a strip of height data (one
   plane-fit pass for the whole strip, one batched histogram, one batched ellipsoid fit; no
   Python loop over texels), giving a 1D sequence of 5-vectors.
2. :func:`synthesize_parameter_texture` - per parameter: 1D amplitude spectra of the two exemplar
   sequences (one across, one along the scratches), their outer product as a separable 2D
   spectrum, resampled to the output size, random phase, inverse FFT.  The five parameters are
   synthesised independently, as in the paper; the output of each channel is rescaled to the
   exemplars' mean and standard deviation, then ``alpha`` is clamped to stay positive and
   ``theta_x, theta_y`` to (-pi/2, pi/2).
3. :func:`save_parameter_texture` / :func:`load_parameter_texture` - 5-channel float EXR
   (channels ``alpha_x, alpha_y, theta_x, theta_y, theta_z``; radians).

Units: heights, pixel and texel sizes in micrometres.
"""
from __future__ import annotations

import os

import numpy as np
from scipy.ndimage import map_coordinates

from ..validation import check_seed
from .ellipsoid import ALPHA_MAX, ALPHA_MIN, THETA_XY_MAX, box_nodes, fit_ellipsoid_samples
from .heightfield import as_heightfield
from .ndf import NDFTable, filtered_slopes, splat_table

__all__ = [
    "CHANNELS",
    "texel_ellipsoid_params",
    "synthesize_parameter_texture",
    "synthesize_from_strips",
    "save_parameter_texture",
    "load_parameter_texture",
]

CHANNELS = ("alpha_x", "alpha_y", "theta_x", "theta_y", "theta_z")


def texel_ellipsoid_params(heights, pixel_um=None, texel_um: float = 63.5, sigma_um: float = 1.0,
                           resolution: int = 257, detilt: bool = True, n_nodes: int = 64, reference=None):
    """Ellipsoid-NDF parameters of every texel of a height field (§9; default ~400 texels/inch).

    The (globally detilted) field is cut into ``texel_um`` squares; each texel's filtered NDF
    (§5.1) is fitted with the ellipsoid NDF (§8), all texels in one batched fit started from the
    fit to the field's mean NDF (keeps ``theta_z`` and the axis labels consistent between texels).
    ``reference``: optional 5 parameters whose axis labelling the mean fit must follow (so two
    strips get the same ``alpha_x``/``alpha_y`` assignment).  Returns ``(params (n_ty, n_tx, 5), mean_params (5,))``.
    """
    hf = as_heightfield(heights, pixel_um)
    if detilt:
        hf = hf.detilted()
    d = hf.pixel_um
    if not (np.isfinite(texel_um) and texel_um > 0):
        raise ValueError(f"texel_um: must be a positive texel size in micrometres, got {texel_um!r}")
    tp = int(round(texel_um / d))
    ny, nx = hf.shape
    n_ty, n_tx = ny // tp if tp else 0, nx // tp if tp else 0
    if tp < 4 or n_ty < 1 or n_tx < 1:
        raise ValueError(f"texel_um: {texel_um} µm gives {tp} px texels; need >= 4 px and at least one texel "
                         f"in the {nx} x {ny} px field")
    sx, sy, ok = filtered_slopes(hf, None, sigma_um, detilt=False)
    jj, ii = np.mgrid[0:ny, 0:nx]
    ok &= (jj < n_ty * tp) & (ii < n_tx * tp)
    texel = (jj // tp) * n_tx + (ii // tp)
    B = n_ty * n_tx
    s = 1.0 / np.sqrt(1 + sx * sx + sy * sy)
    sums = splat_table(-sx[ok] * s[ok], -sy[ok] * s[ok], np.ones(ok.sum()), resolution, texel[ok], B)
    h = 2.0 / (resolution - 1)
    mass = sums.sum((1, 2))
    if np.any(mass <= 0):
        raise ValueError("heights: some texels have no usable points (too many missing points)")
    tables = sums / (mass[:, None, None] * h * h)
    mean_tab = NDFTable(tables.mean(0), "filtered-mean")
    box = mean_tab.support_box(0.9995)
    R = resolution

    def eval_batch(m):  # (M, 3) -> (B, M), bilinear on each texel table
        fx = np.clip((m[:, 0] + 1) / h, 0, R - 1)
        fy = np.clip((m[:, 1] + 1) / h, 0, R - 1)
        bb = np.repeat(np.arange(B, dtype=np.float64), len(m))
        return map_coordinates(tables, [bb, np.tile(fy, B), np.tile(fx, B)], order=1).reshape(B, len(m))

    m, cell, dvals = box_nodes(eval_batch, box, n_nodes)
    dmean = dvals.mean(0)
    p_mean, _ = fit_ellipsoid_samples(m, dmean[None], cell, init=reference)
    params, _ = fit_ellipsoid_samples(m, dvals, cell, init=p_mean[0])
    return params.reshape(n_ty, n_tx, 5), p_mean[0]


def _power_on(seq: np.ndarray, n_out: int) -> np.ndarray:
    """Power spectrum of a 1D sequence, resampled (linear in |frequency|) to ``n_out`` FFT bins.

    A constant exemplar has no spectrum to offer; it contributes a flat (white) one so the other
    strip's spectrum still shapes the texture (the outer product would otherwise vanish).
    """
    n = len(seq)
    P = np.abs(np.fft.fft(seq - seq.mean())) ** 2
    if not np.any(P > 1e-30 * max(1.0, float(np.max(np.abs(seq))) ** 2)):
        P = np.ones(n)
        P[0] = 0.0
    f_src = np.abs(np.fft.fftfreq(n))
    order = np.argsort(f_src, kind="stable")
    fs, Ps = f_src[order], P[order]
    fs, idx = np.unique(fs, return_index=True)  # +-f have equal power for real input
    return np.interp(np.abs(np.fft.fftfreq(n_out)), fs, Ps[idx], right=0.0)


def synthesize_parameter_texture(params_x, params_y, out_shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    """Separable random-phase synthesis of a (H, W, 5) parameter texture (§9).

    ``params_x``: (Nx, 5) exemplar sequence along x (texture columns); ``params_y``: (Ny, 5) along
    y (rows); both at the output's texel pitch.  Per channel the 2D power spectrum is
    ``P(fy, fx) = Px(fx) Py(fy)`` (outer product, resampled to the output size), phases are
    uniformly random, and the real inverse FFT is rescaled to the exemplars' mean and standard
    deviation (averaged over the two strips).
    """
    px = np.asarray(params_x, dtype=np.float64)
    py = np.asarray(params_y, dtype=np.float64)
    for name, p in (("params_x", px), ("params_y", py)):
        if p.ndim != 2 or p.shape[1] != 5 or p.shape[0] < 2 or not np.all(np.isfinite(p)):
            raise ValueError(f"{name}: expected a finite (N >= 2, 5) array of ellipsoid parameters, got shape {p.shape}")
    H, W = (int(v) for v in out_shape)
    if not (1 <= H <= 16384 and 1 <= W <= 16384):
        raise ValueError(f"out_shape: each size must lie in [1, 16384], got {out_shape}")
    rng = np.random.default_rng(check_seed("seed", seed))
    out = np.empty((H, W, 5))
    for c in range(5):  # five independent channels (a loop over parameters, as in the paper)
        target_mean = 0.5 * (px[:, c].mean() + py[:, c].mean())
        target_std = np.sqrt(0.5 * (px[:, c].var() + py[:, c].var()))
        spec = np.sqrt(np.outer(_power_on(py[:, c], H), _power_on(px[:, c], W)))
        noise = np.fft.fft2(rng.standard_normal((H, W)))
        field = np.fft.ifft2(spec * noise / np.maximum(np.abs(noise), 1e-300)).real
        sd = field.std()
        field = (field - field.mean()) / sd * target_std if sd > 0 and target_std > 0 else np.zeros((H, W))
        out[..., c] = field + target_mean
    out[..., :2] = np.clip(out[..., :2], ALPHA_MIN, ALPHA_MAX)
    out[..., 2:4] = np.clip(out[..., 2:4], -THETA_XY_MAX, THETA_XY_MAX)
    return out


def synthesize_from_strips(strip_x, strip_y, out_shape, texel_um: float = 63.5, pixel_um=None,
                           sigma_um: float = 1.0, seed: int = 0, resolution: int = 257) -> np.ndarray:
    """§9 end to end: per-texel fits along a strip long in x and a strip long in y, then synthesis.

    Each strip's texels are averaged across the strip's short side into a 1D sequence.
    """
    tx, ref = texel_ellipsoid_params(strip_x, pixel_um, texel_um, sigma_um, resolution)
    ty, _ = texel_ellipsoid_params(strip_y, pixel_um, texel_um, sigma_um, resolution, reference=ref)
    seq_x = tx.mean(0) if tx.shape[1] >= tx.shape[0] else tx.mean(1)
    seq_y = ty.mean(1) if ty.shape[0] >= ty.shape[1] else ty.mean(0)
    return synthesize_parameter_texture(seq_x, seq_y, out_shape, seed)


def save_parameter_texture(path: str | os.PathLike, texture: np.ndarray, meta: dict | None = None) -> None:
    """Write a (H, W, 5) parameter texture as a float EXR with channels ``alpha_x ... theta_z`` (atomic)."""
    from ..tables.exr_io import write_exr  # noqa: PLC0415

    t = np.asarray(texture, dtype=np.float64)
    if t.ndim != 3 or t.shape[2] != 5 or t.shape[0] < 1 or t.shape[1] < 1:
        raise ValueError(f"texture: expected shape (H, W, 5), got {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(t[..., :2] <= 0):
        raise ValueError("texture: values must be finite with alpha_x, alpha_y > 0")
    m = {"model": "ellipsoid_ndf", "paper": "Dong et al. 2015 §8-9", "angles": "radians"}
    m.update(meta or {})
    write_exr(path, {name: t[..., i].astype(np.float32) for i, name in enumerate(CHANNELS)}, meta=m)


def load_parameter_texture(path: str | os.PathLike) -> tuple[np.ndarray, dict | None]:
    """Read a texture written by :func:`save_parameter_texture`; returns ``((H, W, 5), meta)``."""
    from ..tables.exr_io import ExrError, read_exr  # noqa: PLC0415

    chans, meta = read_exr(path)
    missing = [c for c in CHANNELS if c not in chans]
    if missing:
        raise ExrError(f"{os.fspath(path)}: not a parameter texture (missing channels {missing})")
    return np.stack([chans[c].astype(np.float64) for c in CHANNELS], -1), meta
