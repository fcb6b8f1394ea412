"""Raymond et al. 2016, "Multi-Scale Rendering of Scratched Materials using a Structured SV-BRDF Model".

- ``profiles``    scratch cross-sections (§5.3): quartic, V-groove, round, tabulated / measured
- ``fresnel``     Fresnel per bounce: Schlick, Lazanyi-Szirmay-Kalos, exact conductor (§4.2)
- ``beam``        exact 2D beam tracer of a polyline profile (§4.1-4.2); ``mc`` its Monte Carlo reference
- ``brdf``        the (ρ0, ρm, γ) tables, eq. 2, importance sampling (§5.1): ``simulate`` -> ``ScratchBRDF``
- ``layers``      layer distributions (eq. 7) and the noise's mean coverage
- ``lobe_fit``, ``lobe_table``, ``lobes``   φo slices as tilted Cycles GGX lobes (fitted / tabulated)
- ``material``    the material's validated parameters and the tables every render path needs
"""
from .brdf import ScratchBRDF, simulate
from .fresnel import conductor, conductor_preset, lazanyi, schlick
from .profiles import Profile, circular, from_file, quartic, tabulated, v_groove

__all__ = ["ScratchBRDF", "simulate", "conductor", "conductor_preset", "lazanyi", "schlick", "Profile", "circular",
           "from_file", "quartic", "tabulated", "v_groove"]
