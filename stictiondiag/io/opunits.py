"""Guard on the units of op: is the controller output really in the units the user said?

S and J are reported in % of valve span (Choudhury, Thornhill & Shah 2005, Section
5.1), so op (and mv) must be converted to it; a file in other units read as percent
gives S and J scaled by the wrong factor without any other sign.  The usual
historian units are recognised from op's range:

=================  =========================  =======================================
op in the file     read as percent gives      what to pass
=================  =========================  =======================================
4-20 mA            S, J x 0.16 (16 mA span)   ``op_units="mA"`` (``--op-units mA``)
0-1 fraction       S, J x 0.01                ``op_range=(0, 1)`` (``--op-range 0 1``)
raw counts         S, J x 100/full scale      ``op_range=(0, FULL)``
=================  =========================  =======================================

A range that only suggests other units (4-20 is also a valid percent range of a
nearly closed valve) is a warning.  Units the user gave that the data contradict (op
from 0 to 90 declared as mA) are an error: every S and J would be wrong.
"""

from __future__ import annotations

import numpy as np

from stictiondiag.core.errors import DataError, UsageError

__all__ = ["MIN_TRAVEL_PCT", "WARN_TRAVEL_PCT", "check_op_travel", "check_op_units"]

#: Least travel of op over the record [% of span] that a given op range may leave:
#: below it the valve is read as all but still (stick-slip of a few hundredths of
#: a percent is below any positioner's resolution), so the range is refused.
MIN_TRAVEL_PCT = 0.05

#: Travel of op [% of span] below which a given op range is warned about.
WARN_TRAVEL_PCT = 1.0

#: Share of samples outside a range that makes the range wrong [-]: a few spikes
#: (a bad sample, a transmitter fault) do not.
OUTSIDE_SHARE = 0.01

#: Widest range of a live 4-20 mA signal [mA]: NAMUR NE 43 puts the fault signals
#: below 3.6 mA and above 21 mA.
MA_LIMITS = (3.6, 21.0)

#: Share of samples below 0 that says op is not in % of span (a valve demand rests
#: below its closed end only briefly; a mean-centred export spends half its time there).
NEGATIVE_SHARE = 0.1

#: Full scales of common converters [counts] (8- to 16-bit).
FULL_SCALES = (255.0, 1023.0, 4095.0, 16383.0, 32767.0, 65535.0)


def _share_outside(op: np.ndarray, low: float, high: float) -> float:
    return float(np.mean((op < low) | (op > high))) if op.size else 0.0


def check_op_units(
    op: np.ndarray,
    op_units: str,
    op_range: tuple[float, float] | None,
    label: str,
    where: str,
    notes: list[str],
) -> str:
    """Check raw ``op`` (in the file's units) against ``op_units`` and ``op_range``.

    Returns ``"percent"`` when op is in % of span (units or range given, or a range
    consistent with it) and ``"unknown"`` when its range says otherwise: beyond
    -5 to 105, below 0 for more than :data:`NEGATIVE_SHARE` of the record, within
    0-1, or filling most of 4-20 (at least 8 of its 16 units);
    S and J are then in op's own units, not % of span.

    Raises
    ------
    DataError
        ``op_units="mA"`` without ``op_range`` but op mostly outside 3.6-21 mA.

    Notes are appended for ranges that suggest other units (module docstring).
    """
    values = np.asarray(op, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0 or op_range is not None:
        scale = "percent"
        if values.size and op_range is not None:
            low, high = (float(v) for v in op_range)
            span = high - low
            if _share_outside(values, low - 0.05 * span, high + 0.05 * span) > OUTSIDE_SHARE:
                notes.append(
                    f"op {label!r}{where} spans {values.min():.4g} to {values.max():.4g}, beyond "
                    f"its op_range {low:g} to {high:g}: check op_units/op_range (CLI --op-range)"
                )
                scale = "unknown"
        return scale
    lo, hi = float(values.min()), float(values.max())
    if op_units == "mA":
        if _share_outside(values, *MA_LIMITS) > OUTSIDE_SHARE:
            raise DataError(
                f"op {label!r}{where} spans {lo:.4g} to {hi:.4g}: not a 4-20 mA signal; "
                "drop --op-units mA if op is in percent, or give --op-range LO HI"
            )
        return "percent"
    if _share_outside(values, -5.0, 105.0) > OUTSIDE_SHARE:
        if lo >= -5.0 and hi > 105.0:
            full = next((f for f in FULL_SCALES if f >= hi), None)
            hint = f"op_range=(0, {full:g}) (CLI --op-range 0 {full:g})" if full else "op_range"
            notes.append(
                f"op {label!r}{where} reaches {hi:.4g}, beyond 100 % of span: raw counts or "
                f"engineering units? give the values at 0 and 100 % with {hint}; "
                "check op_units/op_range (S and J are reported in % of span)"
            )
        else:
            notes.append(
                f"op {label!r}{where} spans {lo:.4g} to {hi:.4g}, beyond 0-100 % of span: "
                "check op_units/op_range (S and J are reported in these units)"
            )
        return "unknown"
    below = float(np.mean(values < 0.0))
    if below > NEGATIVE_SHARE:
        notes.append(
            f"op {label!r}{where} is below 0 for {100 * below:.0f} % of the record ({lo:.4g} "
            f"to {hi:.4g}): a normalised or deviation export, not % of span? give the "
            "values at 0 and 100 % with op_range (CLI --op-range LO HI); S and J are "
            "stated in op's own units"
        )
        return "unknown"
    if lo >= 0.0 and hi <= 1.0:
        notes.append(
            f"op {label!r}{where} stays within 0-1: if it is a fraction of span, give "
            "op_range=(0, 1) (CLI --op-range 0 1); read as percent, S and J are 100 times "
            "too small"
        )
        return "unknown"
    if lo >= MA_LIMITS[0] and hi <= MA_LIMITS[1]:
        notes.append(
            f"op {label!r}{where} stays within 4-20: if it is a 4-20 mA signal, pass "
            "op_units='mA' (CLI --op-units mA); read as percent, S and J are 0.16 times "
            "their size"
        )
        # A percent op that fills most of 4-20 and never leaves it is unlikely.
        return "unknown" if hi - lo >= 8.0 else "percent"
    return "percent"


def check_op_travel(
    op_pct: np.ndarray, op_range: tuple[float, float], label: str, notes: list[str]
) -> None:
    """Check how far op moves within a given ``op_range`` (op already in % of span).

    An op range whose scale leaves op nearly constant (``--op-range 0 1e6`` on an op
    between 40 and 59: 0.002 % of span) would report S and J in the wrong scale
    without any other sign.

    Raises
    ------
    UsageError
        op travels less than :data:`MIN_TRAVEL_PCT` of the span (or not at all).

    A travel below :data:`WARN_TRAVEL_PCT` is noted.
    """
    values = np.asarray(op_pct, dtype=float)
    values = values[np.isfinite(values)]
    travel = float(np.ptp(values)) if values.size else 0.0
    low, high = op_range
    if not travel >= MIN_TRAVEL_PCT:
        raise UsageError(
            f"op {label!r} moves by {travel:.3g} % of the op range {low:g} to {high:g}: "
            "the range makes op all but constant; give the op values at 0 and 100 % of "
            "the valve's span (CLI --op-range LO HI)"
        )
    if travel < WARN_TRAVEL_PCT:
        notes.append(
            f"op {label!r} moves by only {travel:.3g} % of the op range {low:g} to {high:g}: "
            "check op_range (CLI --op-range); S and J are reported in % of that range"
        )
