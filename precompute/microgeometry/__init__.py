"""Dong et al. 2015, "Predicting Appearance from Measured Microgeometry of Metal Surfaces".

- ``heightfield``  height-field input (§4): readers, detilting, synthetic surfaces
- ``ndf``          naive / filtered (§5.1) / Kirchhoff (§6, Appendix A) NDF tables
- ``ellipsoid``    the ellipsoid NDF (§8, eqs. 10-14): evaluation, G1, sampling, fits
- ``synthesis``    spatially varying ellipsoid-NDF textures from two strips (§9)
- ``glossy``       ellipsoid lobes as Cycles Glossy-node parameters
- ``tables``       a height-field file to its material's tables, cached
"""
from .ellipsoid import ellipsoid_ndf, fit_ellipsoid
from .ndf import filtered_ndf, kirchhoff_ndf, naive_ndf

__all__ = ["filtered_ndf", "naive_ndf", "kirchhoff_ndf", "fit_ellipsoid", "ellipsoid_ndf"]
