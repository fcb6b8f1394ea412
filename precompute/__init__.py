"""Pure-numpy science for the scratch add-on.

This package never imports ``bpy``: it is usable as a plain Python library
(``import precompute``) and is tested without Blender.  One concept per module:

Infrastructure
- ``exr_io``            float EXR read/write (atomic writes)
- ``cache``             content-hash-keyed EXR cache of precomputed tables

Raymond et al. 2016 — structured scratch SV-BRDF
- ``profiles``          scratch profiles (§5.3): quartic, V-groove, round, tabulated/measured
- ``fresnel``           Fresnel reflectance: Schlick, Lazanyi-Szirmay-Kalos, exact conductor
- ``scratch_beam``      exact 2D beam tracer of a polyline profile (§4.1-4.2)
- ``scratch_mc``        Monte Carlo reference tracer
- ``scratch_brdf``      the (ρ0, ρm, γ) tables, eq. 2, importance sampling (§5.1)
- ``scratch_layers``    layer distributions (eq. 7) and the noise's mean coverage
- ``cycles_ggx``        numpy twin of Cycles' GGX closure and its cone collapse
- ``lobe_fit``          tilted-lobe fits of table slices
- ``scratch_lobes``     lobe tables for the shader (energy-preserving, per-channel weights)

Dong et al. 2015 — measured microgeometry
- ``heightfield``       height-field readers and synthetic surfaces
- ``microgeometry``     naive / filtered / Kirchhoff NDFs
- ``ellipsoid_ndf``     ellipsoid NDF (eqs. 10-14), GGX/Beckmann fits
- ``ndf_synthesis``     NDF texture synthesis (§9)

Wu, Dorsey, Rushmeier 2011 — bi-scale material design
- ``biscale``           effective BRDF of a small-scale tile (public entry point)
- ``biscale_geometry``, ``biscale_visibility``, ``biscale_directions``, ``biscale_brdfs``, ``biscale_svd``

Velinov, Werner, Hullin 2018 — iridescent scratches
- ``iridescence``       wave-optical scratch layer (public entry point)
- ``iridescence_lights`` closed-form sphere/polygon light integrals, Si
- ``scratch_set``       scratch sets, spatial grid, shader export
- ``cie``               CIE colour matching (Wyman et al. 2013 fit) to linear Rec.709
"""
