"""Pure-numpy science for the scratch add-on: one subpackage per paper, plus shared parts.

Never imports ``bpy``: usable as a plain library (``import precompute`` with the repository on
``sys.path``) and tested without Blender.  Inside the extension it is reached by relative imports
(``from ..precompute.scratch import brdf``), so it has one name per process.

Papers
- ``scratch``        Raymond et al. 2016 — structured scratch SV-BRDF: profiles, Fresnel, the exact
                     2D beam tracer and its tables (eq. 2), layers (eq. 7), lobes for the shader
- ``microgeometry``  Dong et al. 2015 — measured height fields to filtered / Kirchhoff NDFs, the
                     ellipsoid NDF (eqs. 10-14), §9 synthesis, Glossy-node parameters
- ``biscale``        Wu, Dorsey, Rushmeier 2011 — a small-scale tile to an effective BRDF table
- ``iridescence``    Velinov, Werner, Hullin 2018 — the wave-optical scratch layer, area lights, Si

Shared
- ``cycles``         numpy twins of Cycles' closures (GGX, Beckmann) and the one Glossy-node mapping
- ``tables``         content-hash cache of float tables, EXR read/write
- ``validation``     the validators every pipeline uses (ValueError naming the parameter and range)

The public API names of earlier releases keep working (re-exports): ``precompute.profiles``,
``precompute.fresnel`` and ``precompute.scratch_brdf`` are ``precompute.scratch.profiles``,
``.fresnel`` and ``.brdf``; ``precompute.microgeometry``, ``precompute.biscale`` and
``precompute.iridescence`` export their public functions from the subpackage.
"""
import sys as _sys

from .scratch import brdf as scratch_brdf, fresnel, profiles

for _name, _module in (("profiles", profiles), ("fresnel", fresnel), ("scratch_brdf", scratch_brdf)):
    _sys.modules.setdefault(f"{__name__}.{_name}", _module)  # ``import precompute.profiles`` keeps working
del _name, _module
