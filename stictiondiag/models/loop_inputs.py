"""The closed-loop simulation's inputs checked (:func:`stictiondiag.models.loops.simulate_loop`).

Each check raises a one-line :class:`~stictiondiag.core.errors.UsageError` naming the
argument: numbers, per-sample series, the Gerry & Ruel integral band (Section 6.4) and
a friction that varies over time and with the direction of travel.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import UsageError


def _number(name: str, value, *, minimum: float | None = None, positive: bool = False) -> float:
    if isinstance(value, bool):
        raise UsageError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UsageError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise UsageError(f"{name} must be finite, got {v}")
    if positive and v <= 0:
        raise UsageError(f"{name} must be > 0, got {v}")
    if minimum is not None and v < minimum:
        raise UsageError(f"{name} must be >= {minimum:g}, got {v}")
    return v


def _series(name: str, value, n: int, default: float) -> np.ndarray:
    if value is None:
        return np.full(n, default)
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        v = float(arr)
        if not math.isfinite(v):
            raise UsageError(f"{name} must be finite, got {v}")
        return np.full(n, v)
    if arr.ndim != 1 or arr.size != n:
        raise UsageError(
            f"{name} must be a number or an array of one value per sample ({n}), "
            f"got shape {arr.shape}"
        )
    if not np.isfinite(arr).all():
        raise UsageError(f"{name} contains NaN or infinite values")
    return np.ascontiguousarray(arr)


def _integral_band(value, n: int) -> np.ndarray:
    """One band per sample [pv units]; -1 where the PI integrates normally."""
    if value is None:
        return np.full(n, -1.0)
    arr = np.asarray(value, dtype=float) if not isinstance(value, str) else None
    if arr is None or (arr.ndim == 0 and isinstance(value, bool)):
        raise UsageError(f"integral_band must be a number, got {value!r}")
    if arr.ndim == 0:
        return np.full(n, _number("integral_band", float(arr), minimum=0.0))
    if arr.ndim != 1 or arr.size != n:
        raise UsageError(
            f"integral_band must be a number or an array of one value per sample ({n}), "
            f"got shape {arr.shape}"
        )
    if np.any(arr < 0) or np.any(np.isinf(arr)):
        raise UsageError("integral_band must be >= 0 and finite (NaN = normal PI)")
    return np.where(np.isnan(arr), -1.0, arr)


def _band_setting(band: np.ndarray):
    """JSON-able description of the band: None, one number, or a summary."""
    on = band[band >= 0.0]
    if on.size == 0:
        return None
    if on.size == band.size and np.all(on == on[0]):
        return float(on[0])
    first = int(np.flatnonzero(band >= 0.0)[0])
    return {"values": sorted({float(v) for v in np.unique(on)})[:10], "first_sample": first}


def _checked_friction(scale, asymmetry, n: int) -> tuple[np.ndarray, float]:
    """``friction_scale`` as one positive factor per sample, and ``friction_asymmetry``
    checked to lie in (-1, 1)."""
    arr = _series("friction_scale", scale, n, 1.0)
    if np.any(arr <= 0.0):
        raise UsageError("friction_scale must be > 0")
    a = _number("friction_asymmetry", asymmetry)
    if not -1.0 < a < 1.0:
        raise UsageError(f"friction_asymmetry must lie in (-1, 1), got {a}")
    return arr, a


def _friction_setting(run) -> dict | None:
    """JSON-able description of a varying friction: None for a constant one."""
    f = run.friction_scale
    if run.friction_asymmetry == 0.0 and np.all(f == 1.0):
        return None
    return {
        "asymmetry": run.friction_asymmetry,
        "scale_min": float(f.min()),
        "scale_max": float(f.max()),
    }
