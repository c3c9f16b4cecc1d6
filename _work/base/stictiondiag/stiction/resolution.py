"""Resolution of a recorded valve position, and the stick-slip it can hide.

A recorded mv is a staircase whose steps need not be the valve's: a quantised signal
(an instrument or historian resolution, Fig. 6 of Choudhury, Thornhill & Shah 2005)
and an exception (deadband) archive rebuilt held
(:mod:`stictiondiag.io.compression`) both hold mv still while the valve moves, then
step.  :func:`resolution` is that step, one value for both; the stick and slip
segmentation counts mv as still within it
(:func:`stictiondiag.stiction.segments.segment_valve`), and S and J within what it
can hide (:func:`hidden_by_resolution`) are not called stiction
(:func:`stictiondiag.stiction.verdict.stiction_verdict`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

__all__ = [
    "MAX_ARCHIVE_DEADBAND_PCT",
    "hidden_by_resolution",
    "quantum",
    "resolution",
    "resolution_details",
]

#: Largest held step [% of span] read as an archive's compression deadband.  Historians
#: archive valve signals with exception deviations of fractions of a percent of span
#: (0.05-0.5 % in the exports of docs/historian_exports.md); an archive whose smallest
#: step is larger holds a valve that moves only by slips (a stick-slip valve without
#: moving phases, as sample ``slave_flow_stickslip``: every step a 3 % slip), and its
#: steps are the valve's.
MAX_ARCHIVE_DEADBAND_PCT = 1.0


def quantum(x: np.ndarray) -> float:
    """Resolution step of a quantised signal [units of x], 0 when not quantised.

    The signal is taken as quantised when it has few distinct levels and every gap
    between neighbouring levels is (within 10 %) a whole multiple of the smallest
    gap; the smallest gap is then the step (e.g. Fig. 6, the dryer's quantised flow).
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 10:
        return 0.0
    levels = np.unique(x)
    span = float(levels[-1] - levels[0])
    if levels.size < 2 or levels.size > x.size / 3 or span <= 0:
        return 0.0
    gaps = np.diff(levels)
    q = float(gaps.min())
    if q <= 1e-9 * span or q > span / 4:
        return 0.0
    ratio = gaps / q
    if np.all(np.abs(ratio - np.round(ratio)) <= 0.1):
        return q
    return 0.0


def resolution(mv: np.ndarray, deadband: float = 0.0) -> float:
    """Resolution of a recorded valve position [units of mv]: the larger of its
    quantisation step (:func:`quantum`) and the deadband of the exception archive it
    was rebuilt from (``deadband``, :attr:`stictiondiag.io.tags.Tags.archive_deadband`).

    Both make a staircase whose steps are not the valve's: mv counts as still within
    it (:func:`~stictiondiag.stiction.segments.segment_valve`), and stick-slip within what it can hide is not told
    from it (:func:`hidden_by_resolution`).  The deadband is not read from mv itself:
    a stick-slip valve without moving phases (sample ``slave_flow_stickslip``, every
    change a slip of 3 %) is a staircase just like a 3 % deadband archive; for the same
    reason a deadband above :data:`MAX_ARCHIVE_DEADBAND_PCT` is taken as the valve's.
    """
    return max(quantum(mv), _archive_deadband(deadband))


def _archive_deadband(deadband: float) -> float:
    """A held archive's deadband [% of span]; 0 above :data:`MAX_ARCHIVE_DEADBAND_PCT`."""
    d = float(deadband)
    return d if d <= MAX_ARCHIVE_DEADBAND_PCT else 0.0


def hidden_by_resolution(mv: np.ndarray, deadband: Mapping[str, float] | None) -> dict:
    """How large a stick-slip the recording of op and mv can make of a healthy valve.

    ``deadband``: role -> archive deadband [% of span] (``Tags.archive_deadband``).
    With ``r`` = :func:`resolution` of mv plus op's archive deadband: a smoothly moving
    valve archived with deadband ``d`` is held at each reversal until it has moved
    back past the last archived value by ``d``, so up to ``2 d`` of op travel with a
    still mv (an apparent ``S``), then steps by about ``d`` (an apparent ``J``); op's
    own archive shifts op against mv by up to its deadband.  ``S <= 2 r`` with
    ``J <= r`` is therefore within what the record can hide (a quantiser of step ``q``
    hides less: ``S`` and ``J`` up to ``q``).  Returns the parts, ``S_hidden`` and
    ``J_hidden`` [% of span].
    """
    d_mv = _archive_deadband((deadband or {}).get("mv", 0.0))
    d_op = _archive_deadband((deadband or {}).get("op", 0.0))
    r = resolution(mv, d_mv) + d_op
    return {
        "mv_quantum": quantum(mv),
        "mv_deadband": d_mv,
        "op_deadband": d_op,
        "S_hidden": 2.0 * r,
        "J_hidden": r,
    }


def resolution_details(
    mv: np.ndarray, deadband: Mapping[str, float] | None, S: float, J: float
) -> dict:
    """``details["resolution"]`` (:func:`hidden_by_resolution`, and whether S and J lie
    within it): given when the record is an archive or S and J are within it."""
    hidden = hidden_by_resolution(mv, deadband)
    within = hidden["J_hidden"] > 0 and S <= hidden["S_hidden"] and J <= hidden["J_hidden"]
    if not (within or hidden["mv_deadband"] or hidden["op_deadband"]):
        return {}  # a record of every sample, S and J resolved: details as before
    return {"resolution": {**hidden, "within": bool(within)}}
