"""Missing values of a loop record: short gaps interpolated, long ones cut (rules in
:mod:`stictiondiag.io.tags`, "Missing values")."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.io.timebase import MAX_GAP_SAMPLES

__all__ = ["MIN_SAMPLES", "fill_gaps", "longest_true_run", "true_runs"]

#: Fewest samples a loop record must keep after gap handling. Stiction shows as
#: stick-slip cycles; 100 samples hold only a few cycles at typical sampling, which
#: is the least any of the later steps (oscillation detection, fitting) can use.
MIN_SAMPLES = 100


def true_runs(missing: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of True in a boolean array."""
    padded = np.concatenate(([False], missing, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def longest_true_run(good: np.ndarray) -> tuple[int, int]:
    """(start, stop) of the longest run of True, the earliest of equals; (0, 0) if none."""
    runs = true_runs(good)
    if not runs:
        return 0, 0
    return max(runs, key=lambda run: (run[1] - run[0], -run[0]))


def fill_gaps(
    arrays: dict[str, np.ndarray], labels: Mapping[str, str], notes: list[str]
) -> tuple[dict[str, np.ndarray], int]:
    """Interpolate short interior gaps, cut to the longest stretch without long gaps.

    Returns the signals and the index of their first sample in the input.
    """
    n = next(iter(arrays.values())).size
    if not any(np.isnan(values).any() for values in arrays.values()):
        return arrays, 0
    unusable = np.zeros(n, dtype=bool)
    long_gaps: dict[str, int] = {}
    for role, values in arrays.items():
        for start, stop in true_runs(np.isnan(values)):
            if stop - start > MAX_GAP_SAMPLES or start == 0 or stop == n:
                unusable[start:stop] = True
                if stop - start > MAX_GAP_SAMPLES:
                    long_gaps[role] = max(long_gaps.get(role, 0), stop - start)
    start, stop = longest_true_run(~unusable)
    # Cutting can leave a short gap of one signal at the new edge; edges cannot be
    # interpolated, so trim until every signal is present at both ends.
    while start < stop and any(np.isnan(values[start]) for values in arrays.values()):
        start += 1
    while stop > start and any(np.isnan(values[stop - 1]) for values in arrays.values()):
        stop -= 1
    if stop - start < MIN_SAMPLES:
        raise DataError(
            f"only {stop - start} contiguous samples without gaps longer than "
            f"{MAX_GAP_SAMPLES} remain (need at least {MIN_SAMPLES}): fill the gaps or "
            f"export a longer complete record"
        )
    if long_gaps:
        worst = ", ".join(f"{role} up to {size}" for role, size in long_gaps.items())
        notes.append(
            f"gaps longer than {MAX_GAP_SAMPLES} samples ({worst}): kept the longest complete "
            f"stretch, samples {start} to {stop - 1} ({stop - start} of {n})"
        )
    elif start > 0 or stop < n:
        notes.append(
            f"missing values at the start or end: kept samples {start} to {stop - 1} "
            f"({stop - start} of {n})"
        )
    index = np.arange(stop - start, dtype=float)
    filled: dict[str, np.ndarray] = {}
    interpolated: list[str] = []
    for role, values in arrays.items():
        part = values[start:stop].copy()
        missing = np.isnan(part)
        if missing.any():
            part[missing] = np.interp(index[missing], index[~missing], part[~missing])
            runs = true_runs(missing)
            interpolated.append(
                f"{labels.get(role, role)} ({len(runs)} gaps, {int(missing.sum())} samples)"
            )
        filled[role] = part
    if interpolated:
        notes.append(
            f"interpolated short gaps (<= {MAX_GAP_SAMPLES} samples) in " + ", ".join(interpolated)
        )
    return filled, start
