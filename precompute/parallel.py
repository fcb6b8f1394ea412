"""Shared by every paper's pipeline: an ordered thread map with bounded memory.

numpy's FFTs, ufuncs and BLAS release the GIL, so threads give real parallelism on the large array jobs
(tracer parts, height-field tiles) without copying inputs into other processes.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor


def ordered_map(fn, jobs, workers: int, in_flight: int | None = None):
    """Yield ``fn(job)`` for ``jobs`` in job order, on ``workers`` threads, with at most ``in_flight``
    (default ``2 * workers``) jobs submitted and not yet yielded, so memory holds at most that many results."""
    jobs = list(jobs)
    if workers <= 1 or len(jobs) <= 1:
        for j in jobs:
            yield fn(j)
        return
    limit = max(int(in_flight or 2 * workers), 1)
    with ThreadPoolExecutor(workers) as ex:
        pending = []
        for j in jobs:
            pending.append(ex.submit(fn, j))
            if len(pending) >= limit:
                yield pending.pop(0).result()
        for f in pending:
            yield f.result()
