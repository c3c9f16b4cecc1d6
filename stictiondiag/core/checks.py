"""Checks of arguments shared by every layer: one message for one mistake."""

from __future__ import annotations

import math

from stictiondiag.core.errors import UsageError


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
