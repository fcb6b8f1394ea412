"""Memory and time budget of the scratch BRDF simulation (Raymond et al. 2016, §4.1; issue #14).

The exact tracer (``beam``) turns every traced incident direction into a few exit *records* per lit
profile segment (1.5-2.1 per segment measured on quartics and noisy traces), and the integration
(``brdf._integrate``) works record by record.  Both stream: the phi_i range is cut into parts whose
records fit ``part_budget`` bytes, each part's visibility step runs in beam batches, and each part
accumulates only its own phi_i columns.  What remains is the output: the ``[components, classes, M, M]``
float64 accumulator and the float32 tables.  So the peak is

    out_bytes + workers * part_bytes   (<= MEMORY_BUDGET, plus ~0.1-0.2 GiB of Python and numpy)

and the time is ``records * SECONDS_PER_RECORD / speed-up``.  ``brdf.estimate_cost`` fills these in for
a concrete input (with the records per direction measured on a few probe directions) and ``simulate``
refuses, before any work, an input whose estimate exceeds the bound (``ValueError`` with the estimate
and the range of the parameter to change).

Units: bytes, seconds (of the reference 2-core machine; other machines scale).
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["MEMORY_BUDGET", "MAX_SECONDS", "Cost", "output_bytes", "part_budget", "BYTES_PER_RECORD",
           "SECONDS_PER_RECORD", "FAST_RECORD_FACTOR", "FAST_BYTES_PER_STRIDE", "BYTES_PER_RAY", "SECONDS_PER_RAY_SEGMENT"]

#: bytes one simulation may allocate at its peak (with Python, numpy and scipy the process stays < 1 GiB)
MEMORY_BUDGET = 768 * 2**20
#: default limit of the estimated run time of one simulation (``simulate(..., max_seconds=...)``)
MAX_SECONDS = 600.0
#: working bytes per exit record while a part is traced and integrated (tracemalloc peaks measured at
#: 1.1-1.8 kB per record, more with many Fresnel components; margin included) plus 8 bytes per component
BYTES_PER_RECORD = 2600
BYTES_PER_RECORD_COMPONENT = 64
#: CPU seconds per exit record, trace + integration, one thread (times ``brdf._record_slowdown(P)``).
#: ``bench/out/scratch_tracer_scale_256.md`` (hierarchical visibility, 2-core machine at load 13-21): the CPU
#: time of ``simulate`` is 1.4-1.7x what 4.5e-6 predicted (the bucket scan before it: 2.3-2.7x), hence 6.5e-6
#: -- an upper value on an idle machine, so ``max_seconds`` refuses rather than lets a long run through
SECONDS_PER_RECORD = 6.5e-6
#: the fast method (``brdf.simulate(method="fast")``): CPU time per exit record relative to the exact method's
#: (each record is integrated over sub-bins several phi_i bins wide, and twice: the error estimate).  Measured
#: (measured-4096, M = 256, load 15): 10.6 us per record against the exact method's ~13 (0.8x; it was 1.35x
#: before the wide sub-bins' regular cuts, ``brdf._integrate_wide``); 1.0 keeps an upper value
FAST_RECORD_FACTOR = 1.0
#: and its working bytes per record grow with the sub-bin width (a path is cut at every bin edge it crosses):
#: tracemalloc peaks of the integration 1.8 / 1.9 / 2.5 / 3.6 kB per record at stride 1 / 2 / 4 / 8
#: (measured-4096, M = 256; 1.8 / 3.1 / 5.3 / 9.4 before ``brdf._integrate_wide``); a whole fast part (trace,
#: integration and error-estimate integration, 12 middle directions) peaks at 2.0 / 2.6 kB per record at stride
#: 2 / 4, so ``record_bytes * (1 + FAST_BYTES_PER_STRIDE (stride - 1))`` (3.7 / 4.9 kB with 7 components) keeps
#: the exact method's margin
FAST_BYTES_PER_STRIDE = 0.2
#: two threads on separate parts gain ~1.6x (the tracer is memory-bound)
THREAD_SPEEDUP = {1: 1.0, 2: 1.6}
#: Monte Carlo: bytes per ray in flight and CPU seconds per ray-segment intersection test
BYTES_PER_RAY = 160
SECONDS_PER_RAY_SEGMENT = 6e-9


@dataclass(frozen=True)
class Cost:
    """Estimated cost of one simulation: ``seconds`` (wall, reference machine), ``peak_bytes`` (this call's
    allocations), the traced ``segments``, ``nodes`` (incident directions), ``records`` (exit beams),
    ``out_bytes`` (accumulator + tables) and ``part_nodes`` (directions per streamed part)."""

    seconds: float
    peak_bytes: int
    segments: int
    nodes: int
    records: int
    out_bytes: int
    part_nodes: int

    def describe(self) -> str:
        return (f"~{_fmt_seconds(self.seconds)} and ~{self.peak_bytes / 2**20:.0f} MiB "
                f"({self.segments} segments, {self.nodes} traced directions, ~{self.records / 1e6:.2g} M exit beams)")


def _fmt_seconds(s: float) -> str:
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    return f"{s / 3600:.3g} h"


def output_bytes(M: int, components: int, classes: int, channels: int, split: bool) -> int:
    """The float64 accumulator ``[components, classes, M, M]`` plus the float32 tables (rho0, rho_m,
    gamma per channel, the bounce split) and row-chunked temporaries of the assembly."""
    acc = 8 * components * classes * M * M
    tables = 4 * M * M * (3 * channels + (3 if split else 0))
    return int(acc + tables + 8 * M * M)


def part_budget(out: int, workers: int) -> int:
    """Bytes each of ``workers`` parts in flight may use once the output is allocated."""
    return int(max(0, MEMORY_BUDGET - out) // max(1, workers))


def record_bytes(components: int) -> int:
    return BYTES_PER_RECORD + BYTES_PER_RECORD_COMPONENT * components
