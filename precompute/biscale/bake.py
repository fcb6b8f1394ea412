"""The bi-scale bake without Blender (Wu et al. 2011, §3-5): a tile and its small-scale materials ->
the effective BRDF table, its fitted closures and the table file.

``get_tile`` keeps the last few ``BiscaleTile`` objects in memory, keyed by the mesh's content hash
and the options, so colour- and material-only edits reuse visibility and N (the fast path of §3.7);
``bake_tables`` runs the pipeline.  ``scratch_addon.biscale_material`` reads the tile from an object,
maps Blender materials to small-scale BRDFs and builds the node tree.
"""
from __future__ import annotations

import hashlib
import json
import os
import time
import warnings

import numpy as np

from ..tables import cache, files
from .brdfs import material_lobes
from .effective import BiscaleTile, check_options
from .fit import fit_closures
from ..tables.tabulated_brdf import view_directions
from .interreflect import check_mode, resample, resample_view_nodes, resample_views, resample_wi, tile_indirect
from .table import tabulate_tile, tile_view_grid, with_indirect

#: mesh content hash + options -> BiscaleTile (visibility, N cached inside)
_TILE_CACHE: dict = {}
_TILE_CACHE_MAX = 4


def mesh_hash(V, F, M, P) -> str:
    """Content hash of a tile (vertices, faces, face materials, period)."""
    h = hashlib.sha256()
    for a in (np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64), np.ascontiguousarray(M, np.int64)):
        h.update(a.tobytes())
    h.update(repr(float(P)).encode())
    return h.hexdigest()[:24]


def materials_hash(materials) -> str:
    """Deterministic hash of small-scale material dicts (the same in every session)."""
    return hashlib.sha256(json.dumps(materials, sort_keys=True, default=float).encode()).hexdigest()[:16]


def get_tile(V, F, M, P, color_weights=None, **opts):
    """Cached ``BiscaleTile`` (visibility + N reused when only colours or materials change); returns
    ``(tile, reused)``."""
    opts = check_options(opts)
    key = (mesh_hash(V, F, M, P), tuple(sorted(opts.items())))
    tile = _TILE_CACHE.get(key)
    hit = tile is not None
    if tile is None:
        tile = BiscaleTile(V, F, M, period=P, color_weights=color_weights, **opts)
        if len(_TILE_CACHE) >= _TILE_CACHE_MAX:
            _TILE_CACHE.pop(next(iter(_TILE_CACHE)))
        _TILE_CACHE[key] = tile
    elif color_weights is not None or tile.alpha.min() != 1.0 or tile.alpha.max() != 1.0:
        tile.set_color_weights(color_weights)  # colour edit: N only
    return tile, hit


def table_dir(exr_dir: str | None = None) -> str:
    """The writable folder the table EXR goes to, checked before a bake rather than after it.

    ``exr_dir`` given: it must be usable (ValueError naming it otherwise); None: the cache folder's
    ``biscale`` sub-folder, or the cache folder itself (with a ``CacheWarning``) if that is unusable."""
    if exr_dir is not None:
        try:
            return files.check_writable(exr_dir)
        except OSError as exc:
            raise ValueError(f"exr_dir: cannot write the table to {os.fspath(exr_dir)!r} ({files.one_line(exc)})") from None
    root = cache.get_cache_dir()
    try:
        return files.check_writable(os.path.join(root, "biscale"))
    except OSError as exc:
        warnings.warn(f"bi-scale table folder unusable ({files.one_line(exc)}); using {root!r}", cache.CacheWarning,
                      stacklevel=2)
        return root


def check_inputs(materials, n_lobes: int = 4, **opts) -> dict:
    """Everything a bake is given besides the mesh, checked before any work (so a bake never fails
    after minutes on a bad option): the options (``effective.check_options``: unknown keyword or out of
    range -> ValueError naming the keyword), ``n_lobes`` and the small-scale material dicts.  Returns the
    completed options."""
    if isinstance(n_lobes, (bool, np.bool_)) or not isinstance(n_lobes, (int, np.integer)) or not 0 <= n_lobes <= 8:
        raise ValueError(f"n_lobes: expected an integer in [0, 8], got {n_lobes!r}")
    if not isinstance(materials, (list, tuple)) or len(materials) == 0:
        raise ValueError("materials: expected a non-empty list of material dicts")
    for m in materials:
        material_lobes(m)
    check_mode(opts.get("interreflections", "auto"))
    return check_options(opts, also_accepted=("n_lobes", "exr_dir", "progress", "color_weights", "interreflections"))


#: View nodes per axis on which the inter-reflection pass traces a view-grid table (``table.VIEW_NODES`` = 31 for the
#: table itself): groove, 10,000 facets, quiet: 12.4 s at 19 x 19 vs 29.9 s at the table's 31 x 31.
INDIRECT_VIEW_NODES = 19


def bake_tables(V, F, M, P, materials, n_lobes: int = 4, exr_dir: str | None = None, progress=None,
                closure_table: bool = False, interreflections="auto", **opts):
    """Effective BRDF (eq. 8 via §3.4-3.7), its closure fit (``fit.fit_closures``) and the table saved as
    EXR in ``exr_dir`` (default: the cache folder's ``biscale``; checked before the bake, see ``table_dir``).
    ``materials``: small-scale BRDF dicts (``brdfs``), one per material index.  Returns ``(brdf, fit, info)``;
    ``info["exr"]`` is None when the table could not be written after all (the disk filled during the bake:
    a ``CacheWarning``, the bake itself is kept).

    ``interreflections`` ("auto" | True | False): add the light inter-reflected inside the periodic tile
    (``interreflect``, beyond Wu's single bounce) to the table and to what the closures are fitted to;
    "auto" turns it on when the first-bounce estimate exceeds 1 % (``info["interreflections"]`` says
    what was decided, ``info["indirect_estimate"]`` the estimate, ``info["seconds_indirect"]`` the cost)."""
    step = progress or (lambda f: None)
    check_inputs(materials, n_lobes, interreflections=interreflections, **opts)
    exr_dir = table_dir(exr_dir)
    M = np.minimum(M, len(materials) - 1)
    tile, reused = get_tile(V, F, M, P, **opts)
    step(0.3)
    brdf = tile.effective_brdf(materials)
    step(0.6)
    table = None
    if closure_table:
        t0 = time.perf_counter()
        table = tabulate_tile(tile, materials, view="auto")     # the tile's visibility events on view nodes
        t_table = time.perf_counter() - t0
    vg = {"view_a": table.view_a, "view_b": table.view_b, "view_shift": table.view_shift,
          "view_anchor": table.view_anchor} \
        if table is not None and table.view_a is not None else {}
    # the inter-reflected light is smooth in the view: traced on a coarser grid of the same layout (the tile's
    # events on nodes) and interpolated to the table's view nodes (the pass runs per view node: an edit's cost)
    coarse = tile_view_grid(tile, INDIRECT_VIEW_NODES, INDIRECT_VIEW_NODES) if vg else None
    ind, ind_info = tile_indirect(tile, materials, interreflections, view=view_directions(*coarse) if vg else None)
    if ind is not None:                                  # bounces >= 2 inside the tile, on both grids
        r = ind_info["res"]
        if vg:
            ind = resample_view_nodes(ind, *coarse, table.view_nodes())
        ind_brdf = resample_views(ind, r, vg["view_a"], vg["view_b"], brdf.dir_res) if vg else resample(ind, r, brdf.dir_res)
        brdf = type(brdf)(brdf.table + ind_brdf, brdf.dir_res, {**brdf.info, "interreflections": 1})
        if table is not None:
            ind_table = resample_wi(ind, r, table.res) if vg else resample(ind, r, table.res)
            table = with_indirect(table, ind_table)
    step(0.7)
    fit = fit_closures(brdf, n_lobes=n_lobes)
    step(0.9)
    exr = os.path.join(exr_dir, f"biscale_{mesh_hash(V, F, M, P)}_{materials_hash(materials)}.exr")
    try:
        brdf.save_exr(exr)
    except OSError as exc:
        warnings.warn(f"bi-scale table not written ({files.one_line(exc)})", cache.CacheWarning, stacklevel=2)
        exr = None
    info = {"reused_tile": reused, "rel_l1": fit.rel_l1, "psnr": fit.psnr, "exr": exr, "materials": materials,
            "interreflections": ind_info["interreflections"], "indirect_estimate": ind_info["estimate"],
            "seconds_indirect": ind_info["seconds"]}
    if table is not None:
        info.update(table=table, seconds_table=t_table)
    return brdf, fit, info
