"""Checks of arguments shared by every layer: one message for one mistake."""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import DataError, UsageError


def check_dt(dt, name: str = "sample time dt") -> float:
    """Sample time [s] as a positive finite float, else a one-line UsageError.

    ``name`` is how the message calls the argument (``"ts"`` for the readers'
    option, ``"sample time dt"`` for the functions of the library).
    """
    try:
        value = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"{name} must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise UsageError(f"{name} must be a positive number of seconds, got {value}")
    return value


def as_signal(x, name: str) -> np.ndarray:
    """``x`` as a one-dimensional float array, else a one-line UsageError naming it."""
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise UsageError(f"{name} must be a one-dimensional signal")
    return a


def signal_pair(
    x, y, dt, names: tuple[str, str], *, min_samples: int, purpose: str = ""
) -> tuple[np.ndarray, np.ndarray, float]:
    """Two recorded signals of one loop and their sample time, checked for an
    estimator: one-dimensional float arrays of equal length, at least
    ``min_samples`` long, finite, and a positive finite ``dt`` [s]; else a
    one-line DataError naming the signals (``purpose`` ends the length message,
    e.g. ``" for a fit"``)."""
    a, b = names
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 1 or y.ndim != 1 or x.shape != y.shape:
        raise DataError(
            f"{a} and {b} must be one-dimensional and of equal length, got {x.shape} and {y.shape}"
        )
    if x.size < min_samples:
        raise DataError(
            f"only {x.size} samples of {a} and {b}: need at least {min_samples}{purpose}"
        )
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise DataError(f"{a} or {b} contains NaN or inf: fill or drop the gaps first")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise DataError(f"sampling time must be a number, got {dt!r}") from None
    if not (dt > 0 and math.isfinite(dt)):
        raise DataError(f"sampling time must be positive, got {dt}")
    return x, y, dt


def span_offset(*signals) -> float:
    """Shift that brings valve signals into the models' 0-100 % span [% of span].

    The valve models clip their input and output to 0-100 % of span, the travel of a
    real valve.  Plant exports often record op and mv mean-centred or normalised
    (-1..1); such signals, when they span less than 100 units, are moved by the
    offset returned here so that their middle sits at 50 %, and moved back for
    output.  A valve model does not care about an offset of its input (S and J are
    differences).  0 when every signal lies within 0-100 already, or spans more than
    100 (its units are not % of span, and no shift makes it so).  ``None`` signals
    are skipped.
    """
    lo, hi = math.inf, -math.inf
    for x in signals:
        if x is None:
            continue
        a = np.asarray(x, dtype=float)
        if a.size:
            lo = min(lo, float(a.min()))
            hi = max(hi, float(a.max()))
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return 0.0
    if (lo < 0.0 or hi > 100.0) and hi - lo < 100.0:
        return 50.0 - 0.5 * (lo + hi)
    return 0.0
