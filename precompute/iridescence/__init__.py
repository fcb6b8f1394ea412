"""Velinov, Werner, Hullin 2018, "Real-Time Rendering of Wave-Optical Effects on Scratched Surfaces".

- ``model``        the wave-optical scratch layer (§3, eqs. 3-11), footprints (§3.2), ``evaluate``
- ``lights``       closed-form sphere / polygon light integrals (§4), Si and its eq. 29 approximation
- ``scratch_set``  scratches as vector primitives and a uniform-grid spatial index (§3.1, §4)
- ``cie``          CIE 1931 colour matching to linear Rec.709
"""
from .lights import (polygon_light_integral, polygon_light_integral_mc, si, si_approx, sphere_light_integral,
                     sphere_light_integral_mc)
from .model import RGB_WAVELENGTHS_UM, evaluate

__all__ = ["si", "si_approx", "sphere_light_integral", "sphere_light_integral_mc", "polygon_light_integral",
           "polygon_light_integral_mc", "evaluate", "RGB_WAVELENGTHS_UM"]
