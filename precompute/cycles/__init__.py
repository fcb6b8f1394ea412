"""Numpy twins of what Cycles (Blender 5.0) evaluates, used as test oracles and by the lobe fits.

- ``ggx``       the GGX reflection closure (``bsdf_microfacet.h``) and the tilted-lobe cone collapse
- ``beckmann``  the Beckmann distribution as Cycles evaluates it
- ``glossy``    the Glossy node's (roughness, anisotropy) <-> (alpha_u, alpha_v) mapping, in one place
- ``multiscatter``  Multiscatter GGX's energy preservation (E, E_avg on Cycles' table nodes)
- ``principled``    the Principled BSDF of an opaque surface (F82 metal, real-curve dielectric, layered base)
- ``lookup``        Cycles' linear reads of those tables (``lookup_table_read``, ``_2D``) on their nodes
"""
