"""Pure-numpy science for the scratch add-on.

This package never imports ``bpy``: it is usable as a plain Python library
(``import precompute``) and is tested without Blender.  One concept per module:

- ``exr_io``       float EXR read/write (atomic writes)
- ``cache``        content-hash-keyed EXR cache of precomputed tables
- ``profiles``     scratch profiles (Raymond et al. 2016, §5.3)
- ``fresnel``      Fresnel reflectance (Schlick, Lazanyi, exact conductor)
- ``scratch_brdf`` single-scratch BRDF tables (Raymond et al. 2016, §4.1-4.2)
"""
