"""Numpy twins of what Cycles (Blender 5.0) evaluates, used as test oracles and by the lobe fits.

- ``ggx``       the GGX reflection closure (``bsdf_microfacet.h``) and the tilted-lobe cone collapse
- ``beckmann``  the Beckmann distribution as Cycles evaluates it
- ``glossy``    the Glossy node's (roughness, anisotropy) <-> (alpha_u, alpha_v) mapping, in one place
"""
