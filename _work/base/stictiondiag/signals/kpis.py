"""Loop performance indicators, the figures a commercial loop monitor shows first.

Desborough & Miller (2002), "Increasing customer value of industrial control
performance monitoring: Honeywell's experience", CPC VI, AIChE Symposium Series 98,
169-189, list the measures of a plant-wide loop audit: service factor (time in
normal mode), valve saturation, valve travel and reversals, the control error and
its variability, oscillation; the Harris (1989) index compares the error's variance
with the minimum a controller could reach given the loop's dead time.

Each indicator of :func:`loop_kpis` is a :class:`Kpi` with its value, unit,
definition and citation; an indicator the record cannot give (no mode tag, no dead
time, op not in % of span) has value None and says why.  Every computation is O(n)
in the record length, the Harris index O(n p) with its AR order p.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from stictiondiag.core.robust import robust_std

__all__ = [
    "HARRIS_AR_ORDER",
    "SATURATION_BAND_PCT",
    "Kpi",
    "LoopKpis",
    "harris_index",
    "loop_kpis",
    "reversals",
]

#: op within this band of 0 % or 100 % of span counts as at a limit [% of span].
SATURATION_BAND_PCT = 0.5

#: Order of the AR model of the control error in the Harris index (Desborough &
#: Harris 1992 use 10 to 30 for routine monitoring).
HARRIS_AR_ORDER = 20

#: Hysteresis of a reversal count, in robust standard deviations of op's sample
#: differences: noise alone must not count as reversals.
REVERSAL_SIGMAS = 3.0

_DM2002 = "Desborough & Miller (2002)"
_DAY_S = 86400.0


@dataclass(frozen=True)
class Kpi:
    """One indicator: value [unit] (None when the record cannot give it), what it is."""

    name: str
    value: float | None
    unit: str
    definition: str
    citation: str
    note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "value": self.value,
            "unit": self.unit,
            "definition": self.definition,
            "citation": self.citation,
            "note": self.note,
        }


@dataclass(frozen=True)
class LoopKpis:
    """The indicators of one loop, by name (see :func:`loop_kpis`)."""

    items: tuple[Kpi, ...]

    def __getitem__(self, name: str) -> Kpi:
        for item in self.items:
            if item.name == name:
                return item
        raise KeyError(name)

    def values(self) -> dict[str, float | None]:
        return {item.name: item.value for item in self.items}

    def to_dict(self) -> dict[str, Any]:
        return {item.name: item.to_dict() for item in self.items}

    def to_pandas(self):
        import pandas as pd

        return pd.DataFrame([{"kpi": k.name, **k.to_dict()} for k in self.items]).set_index("kpi")


def reversals(x: np.ndarray, hysteresis: float) -> int:
    """Direction changes of ``x`` that travel more than ``hysteresis`` each way.

    A zig-zag filter: a reversal is counted when ``x`` comes back by more than
    ``hysteresis`` from its extreme in the current direction; the first direction is
    set by the first move of more than ``hysteresis`` and is not a reversal.  O(n).
    """
    values = np.asarray(x, dtype=float)
    if values.size < 2:
        return 0
    direction, count = 0, 0
    high = low = extreme = float(values[0])
    for v in values[1:].tolist():
        if direction == 0:
            high, low = max(high, v), min(low, v)
            if high - v > hysteresis:
                direction, extreme = -1, v
            elif v - low > hysteresis:
                direction, extreme = 1, v
        elif direction > 0:
            if v > extreme:
                extreme = v
            elif extreme - v > hysteresis:
                count, direction, extreme = count + 1, -1, v
        else:
            if v < extreme:
                extreme = v
            elif v - extreme > hysteresis:
                count, direction, extreme = count + 1, 1, v
    return count


def harris_index(error: np.ndarray, dead_time_samples: int, order: int = HARRIS_AR_ORDER) -> float:
    """Harris (1989) index ``eta = sigma_mv^2 / sigma_e^2`` of a control error, in (0, 1].

    An AR(``order``) model of the mean-removed error (least squares) gives the
    innovations' variance ``sigma_a^2`` and the impulse response ``psi``; the part of
    the variance no controller can remove within the dead time ``d`` [samples, >= 1]
    is ``sigma_mv^2 = sigma_a^2 sum_{i<d} psi_i^2``.  1 means minimum-variance
    control, values near 0 a loop far from it.
    """
    e = np.asarray(error, dtype=float)
    e = e - e.mean()
    d = max(int(dead_time_samples), 1)
    p = int(order)
    if e.size <= 4 * p or not np.var(e) > 0:
        return math.nan
    rows = np.column_stack([e[p - k - 1 : e.size - k - 1] for k in range(p)])
    target = e[p:]
    coef, *_ = np.linalg.lstsq(rows, target, rcond=None)
    residual = target - rows @ coef
    sigma_a2 = float(np.mean(residual**2))
    psi = np.zeros(d)
    psi[0] = 1.0
    for i in range(1, d):
        psi[i] = sum(coef[k] * psi[i - k - 1] for k in range(min(p, i)))
    eta = sigma_a2 * float(np.sum(psi**2)) / float(np.mean(target**2))
    return float(min(eta, 1.0))


def loop_kpis(
    pv: np.ndarray,
    op: np.ndarray,
    sp: np.ndarray | None,
    ts: float,
    *,
    op_in_percent: bool = True,
    mode: np.ndarray | None = None,
    service_factor_pct: float | None = None,
    dead_time_s: float | None = None,
    oscillation_period_s: float | None = None,
    oscillation_amplitude: float | None = None,
) -> LoopKpis:
    """The loop's indicators (module docstring) from its record.

    Parameters
    ----------
    pv, op, sp : ndarray
        Process variable [pv units], controller output [% of span, or op's units when
        ``op_in_percent`` is False] and set point [pv units] (None: not recorded).
    ts : float
        Sample time [s].
    mode : ndarray of bool, optional
        True where the controller was in automatic (or cascade); None when the mode
        is not recorded (no service factor).
    service_factor_pct : float, optional
        The service factor [% of time] already known (a record read with its mode tag
        and cut to its longest automatic stretch,
        :attr:`stictiondiag.io.tags.Tags.service_factor`); used when ``mode`` is None.
    dead_time_s : float, optional
        The loop's dead time [s] (identified or given); None: no Harris index.
    oscillation_period_s, oscillation_amplitude : float, optional
        The oscillation of pv found by :func:`stictiondiag.signals.oscillation.detect_oscillation`.
    """
    pv = np.asarray(pv, dtype=float)
    op = np.asarray(op, dtype=float)
    days = pv.size * float(ts) / _DAY_S
    op_unit = "% of span" if op_in_percent else "op units"
    items: list[Kpi] = []
    if mode is not None:
        service_factor_pct = 100.0 * float(np.mean(np.asarray(mode, dtype=bool)))
    items.append(
        Kpi(
            "service_factor",
            service_factor_pct,
            "% of time",
            "share of the record with the controller in automatic or cascade (its mode "
            "tag); over the whole record read, where the other indicators are over the "
            "samples analysed (the longest automatic stretch)",
            _DM2002,
            None if service_factor_pct is not None else "the export holds no usable mode tag",
        )
    )
    band = SATURATION_BAND_PCT
    saturated = float(np.mean((op <= band) | (op >= 100.0 - band))) if op_in_percent else None
    items.append(
        Kpi(
            "time_at_op_limits",
            None if saturated is None else 100.0 * saturated,
            "% of time",
            f"share of samples with op within {band:g} % of span of 0 or 100 % (valve saturated)",
            _DM2002,
            None if op_in_percent else "op is not in % of span: its limits are not known",
        )
    )
    travel = float(np.sum(np.abs(np.diff(op)))) / days if days > 0 else math.nan
    items.append(
        Kpi(
            "op_travel_per_day",
            travel,
            f"{op_unit} per day",
            "sum of |op[k] - op[k-1]| over the record, per day of record (valve travel)",
            _DM2002,
        )
    )
    steps = np.diff(op)
    noise = robust_std(steps)
    hysteresis = max(REVERSAL_SIGMAS * noise, 1e-9 * max(1.0, float(np.ptp(op))))
    items.append(
        Kpi(
            "op_reversals_per_day",
            reversals(op, hysteresis) / days if days > 0 else math.nan,
            "per day",
            f"direction changes of op of more than {hysteresis:.3g} {op_unit} "
            f"({REVERSAL_SIGMAS:g} robust std of op's steps), per day of record",
            _DM2002,
        )
    )
    error, error_items = _error_kpis(pv, sp)
    items.extend(error_items)
    items.append(
        Kpi(
            "pv_std", float(pv.std()), "pv units", "standard deviation of pv (variability)", _DM2002
        )
    )
    items.append(
        Kpi(
            "oscillation_period",
            oscillation_period_s,
            "s",
            "period of pv's oscillation (ACF zero crossings)",
            "Thornhill, Huang & Zhang (2003)",
            None if oscillation_period_s is not None else "pv does not oscillate",
        )
    )
    items.append(
        Kpi(
            "oscillation_amplitude",
            oscillation_amplitude,
            "pv units",
            "half the typical peak-to-peak range of pv's cycles",
            "Thornhill, Huang & Zhang (2003)",
            None if oscillation_amplitude is not None else "pv does not oscillate",
        )
    )
    items.append(_harris_kpi(error, float(ts), dead_time_s))
    return LoopKpis(tuple(items))


def _error_kpis(pv: np.ndarray, sp: np.ndarray | None) -> tuple[np.ndarray, list[Kpi]]:
    """The control error (sp - pv; pv about its mean without sp) and its two indicators."""
    items: list[Kpi] = []
    if sp is not None:
        error = np.asarray(sp, dtype=float) - pv
        items.append(
            Kpi("error_mean", float(error.mean()), "pv units", "mean of sp - pv (offset)", _DM2002)
        )
        items.append(
            Kpi(
                "error_std",
                float(error.std()),
                "pv units",
                "standard deviation of sp - pv",
                _DM2002,
            )
        )
    else:
        error = pv - pv.mean()
        items.append(
            Kpi("error_mean", None, "pv units", "mean of sp - pv (offset)", _DM2002, "no sp")
        )
        items.append(
            Kpi(
                "error_std",
                float(error.std()),
                "pv units",
                "standard deviation of sp - pv (no sp: of pv about its mean)",
                _DM2002,
            )
        )
    return error, items


def _harris_kpi(error: np.ndarray, ts: float, dead_time_s: float | None) -> Kpi:
    """The Harris index of the control error, given the loop's dead time [s]."""
    if dead_time_s is not None and math.isfinite(dead_time_s):
        d = max(int(round(dead_time_s / ts)), 1)
        eta = harris_index(error, d)
        return Kpi(
            "harris_index",
            None if math.isnan(eta) else eta,
            "-",
            f"minimum variance over actual variance of the control error, dead time "
            f"{d} samples (1 = minimum-variance control)",
            "Harris (1989); Desborough & Harris (1992)",
            None if not math.isnan(eta) else "record too short for the AR model",
        )
    return Kpi(
        "harris_index",
        None,
        "-",
        "minimum variance over actual variance of the control error",
        "Harris (1989); Desborough & Harris (1992)",
        "the loop's dead time is not known",
    )
