"""Wu, Dorsey, Rushmeier 2011, "Physically-based interactive bi-scale material design".

- ``geometry``    small-scale tiles (§3.2, §4.2): flat, groove, pyramid, rods, woven, height field
- ``visibility``  directional visibility against the infinitely repeated tile (§3.3)
- ``directions``  direction and normal discretisations (§3.7)
- ``svd``         random-projection SVD with mean subtraction (Table 2, §3.4-3.7)
- ``brdfs``       small-scale BRDF models (§3.5, §6, Table 3)
- ``effective``   the effective large-scale BRDF of a tile (eq. 8 via §3.4-3.7): ``BiscaleTile``
- ``fit``         the table as a mixture of Cycles closures (§5 "rendering")
- ``bake``        tile + materials -> table, fit and table file, with the in-memory tile cache
"""
from .effective import BiscaleTile, EffectiveBRDF, effective_brdf

__all__ = ["BiscaleTile", "EffectiveBRDF", "effective_brdf"]
