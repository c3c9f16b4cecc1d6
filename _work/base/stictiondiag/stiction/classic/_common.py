"""Shared input checks and half-cycle helpers of the classic stiction tests."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.core.filters import detrend_linear

VerdictLabel = Literal["stiction", "no_stiction", "inconclusive", "not_applicable"]

#: Verdict -> number for :func:`stictiondiag.stiction.classic.classic_features`
#: (``not_applicable`` is NaN: the test says nothing).
VERDICT_CODE = {"stiction": 1.0, "inconclusive": 0.0, "no_stiction": -1.0}


def signal(x, name: str, min_samples: int = 16) -> np.ndarray:
    """``x`` as a finite, non-constant 1-D float array, else a one-line DataError."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be numeric") from None
    if a.ndim != 1:
        raise DataError(f"{name} must be a one-dimensional signal, got shape {a.shape}")
    if a.size < min_samples:
        raise DataError(f"{name} has {a.size} samples; the test needs at least {min_samples}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{name} contains NaN or infinite values; fill or drop them first")
    if np.ptp(a) == 0:
        raise DataError(f"{name} is constant; the test needs a varying signal")
    return a


def same_length(*pairs: tuple[str, np.ndarray]) -> None:
    """DataError unless all named signals have the same length."""
    n0 = pairs[0][1].size
    for name, a in pairs[1:]:
        if a.size != n0:
            raise DataError(
                f"{pairs[0][0]} and {name} must have the same length, got {n0} and {a.size}"
            )


def lowpass(x: np.ndarray, dt: float, cutoff_hz: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass; ``x`` unchanged when the cut-off is near Nyquist."""
    wn = cutoff_hz * 2.0 * dt
    if not 0.0 < wn < 0.9 or x.size < 20:
        return x
    from scipy import signal as sps  # imported here: scipy.signal is slow to import

    b, a = sps.butter(order, wn)
    return sps.filtfilt(b, a, x, padlen=min(3 * max(len(a), len(b)), x.size - 1))


def half_cycles(x: np.ndarray, min_len: int = 4) -> list[tuple[int, int]]:
    """Half cycles of ``x``: index ranges ``[a, b)`` between consecutive zero crossings.

    ``x`` is linearly detrended first.  A crossing is where the sign changes; runs
    shorter than ``min_len`` samples (noise chatter around zero) are merged into their
    neighbours before the ranges are formed.  The partial half cycles at both ends of
    the record are left out.
    """
    y = detrend_linear(x)
    s = np.where(y >= 0.0, 1, -1)
    edges = np.flatnonzero(np.diff(s)) + 1
    bounds = [0, *edges.tolist(), y.size]
    runs = [[bounds[i], bounds[i + 1], int(s[bounds[i]])] for i in range(len(bounds) - 1)]
    merged: list[list[int]] = []
    for r in runs:
        if merged and (r[1] - r[0] < min_len or merged[-1][2] == r[2]):
            merged[-1][1] = r[1]
        else:
            merged.append(r)
    return [(a, b) for a, b, _ in merged[1:-1] if b - a >= min_len]


def extrema_segments(x: np.ndarray, period_samples: float) -> list[tuple[int, int]]:
    """Monotone stretches of ``x``: ranges ``[a, b]`` between consecutive extrema.

    The extremum of each half cycle (:func:`half_cycles`) is its largest ``|x|``;
    consecutive extrema bound a rise or a fall.  Stretches shorter than a tenth of a
    period are dropped.
    """
    y = detrend_linear(x)
    ext = [a + int(np.argmax(np.abs(y[a:b]))) for a, b in half_cycles(y)]
    min_len = max(4, int(0.1 * period_samples))
    return [(a, b) for a, b in zip(ext[:-1], ext[1:], strict=False) if b - a >= min_len]


def nan_if_none(v) -> float:
    """float, NaN for None (feature vectors)."""
    return math.nan if v is None else float(v)
