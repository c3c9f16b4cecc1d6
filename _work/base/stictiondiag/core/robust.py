"""Robust spread: the scaled median absolute deviation, and the white-noise level of a
signal read from it.  The one home of the factor 1.4826 (:data:`MAD_TO_STD`)."""

from __future__ import annotations

import math

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


def second_difference_noise_std(x: np.ndarray, min_samples: int = 3) -> float:
    """Robust white-noise standard deviation from second differences [units of x]:
    ``1.4826 MAD(diff2 x) / sqrt(6)``.

    Second differences of a smooth signal are small except at a few corners (a
    ramp's turn, a slip), so the median absolute deviation sees the noise (the
    variance of a second difference of white noise is 6 sigma^2).  0 for fewer
    than ``min_samples`` samples.
    """
    x = np.asarray(x, dtype=float)
    if x.size < max(min_samples, 3):
        return 0.0
    return MAD_TO_STD * mad(np.diff(x, 2)) / math.sqrt(6.0)
