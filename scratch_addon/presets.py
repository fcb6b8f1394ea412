"""Named material presets: one table, used by the API, the operators and the CLI.

Scratch presets reproduce the rows of Raymond et al. 2016, Table 1 (N, Θ, l, w, d) with the
materials of the figures they belong to.  Profiles are described as ``(family, parameter)``
(see ``precompute.profiles``) and Fresnel as ``None`` (lossless), a metal name
(``precompute.fresnel.PRESETS``) or ``("schlick", ior)``; the paper gives no profile depths,
so the depths below are our choices (shallow for brushed looks, steep for Fig. 14b).
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Preset:
    name: str
    kind: str  # "brushed" (SVM baseline) or "scratch" (scratch SV-BRDF)
    description: str
    params: dict = field(default_factory=dict)


PRESETS: dict[str, Preset] = {}


def _add(p: Preset) -> None:
    PRESETS[p.name] = p


def _layers(n, theta, length, width, density, seed=0):
    return dict(n_layers=n, theta_deg=theta, length=length, width=width, density=density, seed=seed)


_add(Preset("brushed", "brushed", "Anisotropic GGX brushed aluminium (SVM baseline)",
            dict(color=(0.91, 0.92, 0.92), roughness=0.35, anisotropy=0.85)))
_add(Preset("brushed_gold", "brushed", "Anisotropic GGX brushed gold (SVM baseline)",
            dict(color=(1.0, 0.78, 0.34), roughness=0.3, anisotropy=0.8)))

_add(Preset("fig1a_dense", "scratch", "Fig. 1a: densely packed parallel scratches (iron)",
            dict(profile=("quartic", 0.15), fresnel="iron", layers=None, base="mirror")))
_add(Preset("fig1b_brushed", "scratch", "Fig. 1b / Table 1: brushed metal, 4 layers around one direction",
            dict(profile=("quartic", 0.15), fresnel="iron", layers=_layers(4, 7, 0.2, 2e-4, 0.6), base="mirror")))
_add(Preset("fig1c_scratched", "scratch", "Fig. 1c / Table 1: 16 layers, all orientations, deep thin scratches",
            dict(profile=("quartic", 0.4), fresnel="iron", layers=_layers(16, 360, 0.1, 1e-5, 0.3), base="mirror")))
_add(Preset("fig1d_scratched", "scratch", "Fig. 1d / Table 1: 32 sparse layers, all orientations",
            dict(profile=("quartic", 0.3), fresnel="iron", layers=_layers(32, 360, 0.3, 3e-4, 0.05), base="mirror")))
_add(Preset("fig12a_gold", "scratch", "Fig. 12a / Table 1: scratched gold, tiny sparse scratches",
            dict(profile=("quartic", 0.15), fresnel="gold", layers=_layers(4, 4, 0.1, 5e-5, 0.5), base="mirror")))
_add(Preset("fig12b_painted_metal", "scratch", "Fig. 12b / Table 1: scratches through red paint to aluminium",
            dict(profile=("quartic", 0.3), fresnel="aluminium", layers=_layers(16, 360, 0.1, 2e-4, 0.1),
                 base={"type": "principled", "color": (0.55, 0.05, 0.04), "roughness": 0.35})))
_add(Preset("fig12c_plastic", "scratch", "Fig. 12c / Table 1: scratched plastic (n = 1.5) with a diffuse term",
            dict(profile=("quartic", 0.3), fresnel=("schlick", 1.5), layers=_layers(16, 360, 0.02, 2e-5, 0.1),
                 base="mirror", diffuse=(0.05, 0.12, 0.45))))
_add(Preset("fig12d_wood", "scratch", "Fig. 12d / Table 1: finished wood, textured diffuse term",
            dict(profile=("quartic", 0.3), fresnel=("schlick", 1.5), layers=_layers(32, 360, 0.1, 1e-5, 0.2),
                 base="mirror", diffuse="wood")))
_add(Preset("fig14a_shallow", "scratch", "Fig. 14a / Table 1: nearly flat profile, brushed",
            dict(profile=("quartic", 0.05), fresnel="iron", layers=_layers(4, 7, 0.02, 7e-4, 0.5), base="mirror")))
_add(Preset("fig14b_steep", "scratch", "Fig. 14b / Table 1: steep profile, scratched",
            dict(profile=("quartic", 0.6), fresnel="iron", layers=_layers(16, 360, 0.02, 1e-5, 0.2), base="mirror")))
#: The README demo (``make demo``, layout "highlights"): Fig. 1d / Table 1 as is (32 sparse layers of all
#: orientations, quartic 0.3, iron) on a floor under one small point light (``render.highlights_scene``): lit
#: scratches streak radially around the light's highlight, one by one near the camera, merging into a sheen far
#: away (issue 15 item 7).  The earlier demo (16 denser layers, d = 0.3, quartic 0.15, three lights) gave broad
#: noisy fans with no individual scratch anywhere: at 1 m per UV unit every floor pixel was in the far field.
_add(Preset("demo", "scratch", "README demo: Fig. 1d's 32 sparse layers of all orientations, quartic 0.3 (iron)",
            dict(profile=("quartic", 0.3), fresnel="iron", layers=_layers(32, 360, 0.3, 3e-4, 0.05), base="mirror")))


def names() -> list[str]:
    return sorted(PRESETS)


def get(name: str) -> Preset:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"preset must be one of {', '.join(names())}; got {name!r}") from None
