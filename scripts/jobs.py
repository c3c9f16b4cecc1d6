"""Run a function over many jobs, in worker processes or in this one with progress.

Shared by the scripts that analyse many simulated or real loops and cache the rows
(``cause_fit.cached_map``, ``probability_features.family_features``).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor


def map_jobs(fn: Callable, jobs: Sequence, workers: int, every: int = 25) -> list:
    """``fn`` of each job, in order: in ``workers`` processes when more than one, else
    here, printing progress to stderr every ``every`` jobs."""
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            return list(pool.map(fn, jobs, chunksize=4))
    rows = []
    for i, job in enumerate(jobs):
        rows.append(fn(job))
        if (i + 1) % every == 0:
            print(f"  {i + 1}/{len(jobs)}", file=sys.stderr, flush=True)
    return rows
