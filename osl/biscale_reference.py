"""Generator of the bi-scale exact reference shader (Wu, Dorsey, Rushmeier 2011, eq. 7).

The shader is ``osl/biscale_reference.osl``; ``generate`` writes one table of
``precompute.biscale.reference.reference_tables`` into it (``osl.specialise``).  The sampling, its
pdf and the table layout are documented in ``precompute.biscale.reference``, whose ``sample_numpy``
is the shader's numpy twin.
"""
from __future__ import annotations

from ..precompute.biscale.reference import DEFENSIVE, MAX_DIR_RES, reference_tables  # noqa: F401 - re-exports
from . import const_array, specialise


def generate(brdf, name: str = "biscale_reference") -> str:
    """OSL source of the reference shader for ``brdf`` (``EffectiveBRDF``): ``biscale_reference.osl``
    with its tables.  Inputs: ``Tangent`` (connect a Tangent node, UV map), ``Tint``; output ``BSDF``."""
    if not name.isidentifier():
        raise ValueError(f"name: expected an OSL identifier, got {name!r}")
    tb = reference_tables(brdf)
    res, D = tb.res, tb.res * tb.res
    tables = const_array("F", tb.F.ravel()) + const_array("CDF", tb.cdf.ravel())
    return specialise("biscale_reference.osl", dict(SHADER_NAME=name, RES=res, ND=D, CELL=2.0 / res),
                      {"biscale_reference_tables.h": tables}, "osl/biscale_reference.py")
