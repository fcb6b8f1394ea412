"""Named material presets: one table, used by the API, the operators and the CLI."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Preset:
    name: str
    kind: str  # which builder in api.py makes it
    description: str
    params: dict = field(default_factory=dict)


PRESETS: dict[str, Preset] = {}


def _add(p: Preset) -> None:
    PRESETS[p.name] = p


_add(Preset("brushed", "brushed", "Anisotropic GGX brushed aluminium (SVM baseline)",
            dict(color=(0.91, 0.92, 0.92), roughness=0.35, anisotropy=0.85)))
_add(Preset("brushed_gold", "brushed", "Anisotropic GGX brushed gold (SVM baseline)",
            dict(color=(1.0, 0.78, 0.34), roughness=0.3, anisotropy=0.8)))
#: The README demo material (switches to the scratch SV-BRDF once it exists).
_add(Preset("demo", "brushed", "README demo material", dict(color=(0.91, 0.92, 0.92), roughness=0.35, anisotropy=0.85)))


def names() -> list[str]:
    return sorted(PRESETS)


def get(name: str) -> Preset:
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"preset must be one of {', '.join(names())}; got {name!r}") from None
