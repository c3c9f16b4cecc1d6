"""Robust spread: the scaled median absolute deviation."""

from __future__ import annotations

import numpy as np

#: MAD of a standard normal sample is 1 / MAD_TO_STD [-]: ``1 / Phi^-1(3/4)``.
MAD_TO_STD = 1.4826


def mad(x: np.ndarray) -> float:
    """Median absolute deviation from the median (0 for an empty array)."""
    x = np.asarray(x, dtype=float)
    if x.size == 0:
        return 0.0
    return float(np.median(np.abs(x - np.median(x))))


def robust_std(x: np.ndarray) -> float:
    """Standard deviation of Gaussian data estimated from the MAD: ``1.4826 MAD(x)``.

    Insensitive to a minority of outliers (slips, steps, spikes).
    """
    return MAD_TO_STD * mad(x)
