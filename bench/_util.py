"""Shared helpers for benchmarks: timing medians, tables, output paths, plots."""
from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path
from typing import Callable, Sequence

OUT = Path(__file__).resolve().parent / "out"
ROOT = OUT.parent.parent


def blender(register: bool = False):
    """bpy, hermetic (a temporary ``BLENDER_USER_RESOURCES``); returns the glue package
    ``scratch_materials.scratch_addon`` (the extension root's TD name; ``python -m bench`` runs from the
    repository root, so it is importable), registered when asked (an earlier registration is kept)."""
    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="bench_bl_"))
    import scratch_materials
    from scratch_materials import scratch_addon

    if register:
        try:
            scratch_materials.register()
        except ValueError:
            pass  # already registered
    return scratch_addon


def out_path(filename: str) -> Path:
    """Path under ``bench/out/`` (created)."""
    OUT.mkdir(parents=True, exist_ok=True)
    return OUT / filename


def time_median(fn: Callable[[], object], repeats: int = 5, warmup: int = 1) -> tuple[float, object]:
    """Median wall time in seconds of ``fn()`` over ``repeats`` runs (after ``warmup`` runs); returns (median, last result)."""
    result = None
    for _ in range(warmup):
        result = fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def format_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """Markdown table (also readable as plain text)."""
    def fmt(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)
    cells = [[fmt(v) for v in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)]
    line = lambda r: "| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |"  # noqa: E731
    return "\n".join([line(headers), "|" + "|".join("-" * (w + 2) for w in widths) + "|"] + [line(r) for r in cells])


def report(name: str, headers: Sequence[str], rows: Sequence[Sequence[object]], notes: str = "") -> str:
    """Print the table and save it as ``bench/out/<name>.md``; returns the Markdown text."""
    text = format_table(headers, rows)
    if notes:
        text += "\n\n" + notes.strip() + "\n"
    print(text)
    out_path(f"{name}.md").write_text(f"# bench: {name}\n\nmachine: {os.cpu_count()} cores\n\n{text}\n")
    return text


def pyplot():
    """matplotlib.pyplot with the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
