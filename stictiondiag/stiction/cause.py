"""Why does the loop oscillate?  The verdict in two stages.

Plant experts do not ask whether a valve has *any* friction; they ask why a loop
oscillates (the ISDB comments name stiction, tight tuning, an external disturbance,
quantisation, or no oscillation at all).  The verdict asks that question:

**Stage 1, is there a cycle to explain?**  A sticky valve in a control loop with
integral action makes a sustained limit cycle (Choudhury, Thornhill & Shah 2005,
Sections 4.2.2 and 5.3), found by the oscillation test of
:mod:`stictiondiag.signals.oscillation` in pv (or the control error) or op: its
period, its regularity and the number of cycles the record holds
(:func:`find_cycle`).  A record that shows two to three periods of a regular
pattern, too few for the test, is *short* and counts as a cycle to explain.

A loop without a cycle gets a definite answer: ``no_stiction``, cause ``none``, with
the reason "no limit cycle: the valve is not driving an oscillation", S and J still
reported.  Stick-slip without a cycle can still be called stiction where the
evidence is direct (:func:`direct_stick_slip`): the recorded valve position's stick
and slip phases, Kano et al.'s stuck sections, or a Hammerstein improvement that
holds over the cycles and in both halves of the record.

**Stage 2, what causes the cycle?**  One probability per cause (:data:`CAUSES`):
the valve (stiction or dead band), the controller's tuning, an external oscillating
disturbance, quantisation or another non-valve nonlinearity; from the model of
:mod:`stictiondiag.stiction.cause_model`, fitted on simulated loops labelled by
counterfactual twins (:mod:`stictiondiag.apps.family_causes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.stiction.probability_evidence import band_limited


class Cause(StrEnum):
    """Why a loop oscillates: the causes of stage 2 and ``none`` (no limit cycle).

    The value is the word the JSON carries; code compares members, never words.
    """

    VALVE = "valve"
    TUNING = "tuning"
    EXTERNAL = "external"
    OTHER = "other"
    NONE = "none"


#: The causes of stage 2, in the order of the model's classes.
CAUSES: tuple[str, ...] = ("valve", "tuning", "external", "other")

#: What to do for each cause (the findings and the report say it).
ACTIONS: dict[str, str] = {
    "valve": "inspect the valve: schedule a valve inspection (packing, actuator, positioner)",
    "tuning": "retune: the loop cycles without the valve's help",
    "external": "look upstream: the cycle comes from outside",
    "other": "check the measurement: the cycle comes from a quantised or nonlinear signal",
    "none": "nothing to do for the valve: the loop does not cycle",
}

#: Words for each cause.
CAUSE_WORDS: dict[str, str] = {
    "valve": "the valve (stiction or dead band)",
    "tuning": "the controller's tuning",
    "external": "an external oscillating disturbance",
    "other": "quantisation or another non-valve nonlinearity",
    "none": "no limit cycle",
}

#: The reason a loop without a cycle is not called stiction.
NO_CYCLE_REASON = "no limit cycle: the valve is not driving an oscillation"


@dataclass(frozen=True)
class Cycle:
    """Stage 1: the limit cycle the loop shows, if any.

    Attributes
    ----------
    present : bool
        A regular, sustained cycle in pv (or the control error) or op, or a short
        record showing two to three periods of one.
    signal : str or None
        ``"pv"`` or ``"op"``: where the cycle was found (pv preferred), None without.
    period_s : float or None
        Its period [s].
    regularity : float or None
        Thornhill et al.'s regularity of that signal [-].
    n_cycles : float or None
        Periods the record holds [-].
    short_record : bool
        The record holds fewer periods than the oscillation test needs.
    setpoint_share : float or None
        How much of the cycle the set point carries: the spread of the set point over
        that of pv, both band-limited around the cycle [-] (:func:`setpoint_share`);
        near 1 when pv follows a cycling set point (a cascade slave whose master
        cycles), near 0 when the set point holds still; None without a moving set
        point or a period.
    """

    present: bool
    signal: str | None
    period_s: float | None
    regularity: float | None
    n_cycles: float | None
    short_record: bool = False
    setpoint_share: float | None = None

    @property
    def setpoint_carries(self) -> bool:
        """The set point carries the cycle (:data:`SETPOINT_CARRIES` or more of pv's
        spread at the cycle)."""
        return self.setpoint_share is not None and self.setpoint_share >= SETPOINT_CARRIES

    def to_dict(self) -> dict:
        """JSON-able dict (period in s)."""
        return to_plain(
            {
                "present": self.present,
                "signal": self.signal,
                "period_s": self.period_s,
                "regularity": self.regularity,
                "n_cycles": self.n_cycles,
                "short_record": self.short_record,
                "setpoint_share": self.setpoint_share,
            }
        )


@dataclass(frozen=True)
class CauseReading:
    """Stage 2: P of each cause of the cycle [-], summing to 1, from the cause model
    (:func:`stictiondiag.stiction.cause_model.cause_probabilities`).

    Attributes
    ----------
    valve, tuning, external, other : float
        P that the valve (stiction or dead band), the controller's tuning, an
        external oscillating disturbance, or quantisation or another non-valve
        nonlinearity causes the cycle [-].
    atypicality : float or None
        How far the evidence lies from the simulated loops the most likely cause was
        learnt from: its squared Mahalanobis distance to them over the 99th
        percentile of theirs [-] (:func:`stictiondiag.stiction.cause_model.atypicality`).
        Above 1 the record is unlike 99 % of them and the probabilities are an
        extrapolation; None when the model carries no reference.
    """

    valve: float
    tuning: float
    external: float
    other: float
    atypicality: float | None = None

    @classmethod
    def of(cls, probs: dict[str, float], atypicality: float | None = None) -> CauseReading:
        """The reading of the cause model's ``{cause: P}`` (keys :data:`CAUSES`)."""
        return cls(**{c: float(probs[c]) for c in CAUSES}, atypicality=atypicality)

    @property
    def atypical(self) -> bool:
        """The evidence lies outside 99 % of the simulated loops of the most likely
        cause (:attr:`atypicality` above 1): the call is an extrapolation."""
        return self.atypicality is not None and self.atypicality > 1.0

    def p(self, cause: Cause | str) -> float:
        """P of one cause of stage 2 [-]."""
        return float(getattr(self, Cause(cause).value))

    def ranked(self) -> tuple[Cause, ...]:
        """The causes of stage 2, most likely first (ties in :data:`CAUSES` order)."""
        return tuple(sorted((Cause(c) for c in CAUSES), key=lambda c: -self.p(c)))

    def runner_up(self, first: Cause | str | None) -> tuple[Cause, float]:
        """The most likely cause other than ``first``, with its P [-] (ties: the later
        cause in :data:`CAUSES` order)."""
        rest = sorted(((self.p(c), Cause(c)) for c in CAUSES if c != first), reverse=True)
        return rest[0][1], rest[0][0]

    def to_dict(self) -> dict[str, float]:
        """``{cause: P}`` in :data:`CAUSES` order."""
        return {c: self.p(c) for c in CAUSES}


#: Share of pv's spread at the cycle from which the set point is said to carry the
#: cycle [-]: half, a set point that moves at least half as much as pv does.
SETPOINT_CARRIES = 0.5


def setpoint_share(sp, pv, dt: float, period_s: float | None) -> float | None:
    """The spread of ``sp`` over that of ``pv`` [-], both band-limited around the
    cycle of ``period_s`` [s] (a third of its frequency to six harmonics,
    :func:`~stictiondiag.stiction.probability_evidence.band_limited`); None without a
    moving set point, a period or a moving pv."""
    if sp is None or period_s is None or not math.isfinite(period_s) or period_s <= 0:
        return None
    sp, pv = np.asarray(sp, dtype=float), np.asarray(pv, dtype=float)
    if sp.size < 32 or float(np.ptp(sp)) == 0.0 or not np.all(np.isfinite(sp)):
        return None
    s_pv = float(np.std(band_limited(pv, dt, period_s)))
    if not s_pv > 0:
        return None
    return float(np.std(band_limited(sp, dt, period_s)) / s_pv)


def find_cycle(
    oscillation, oscillation_op, *, short_record: bool, setpoint_share: float | None = None
) -> Cycle:
    """Stage 1 from the oscillation test of pv (or the control error) and of op, and
    the short-record check of :func:`stictiondiag.analysis.check_record_length`;
    ``setpoint_share`` (:func:`setpoint_share`, at the cycle's period) is kept with a
    cycle."""
    for name, osc in (("pv", oscillation), ("op", oscillation_op)):
        if osc is not None and getattr(osc, "present", False):
            return Cycle(
                True,
                name,
                getattr(osc, "period_s", None),
                getattr(osc, "regularity", None),
                getattr(osc, "n_cycles", None),
                short_record,
                setpoint_share,
            )
    if short_record:
        return Cycle(True, None, None, None, None, True)
    return Cycle(False, None, None, None, None, False)


#: Lowest P(the valve has friction) of the friction model
#: (:mod:`stictiondiag.stiction.probability`) that, with direct evidence, calls a
#: loop without a cycle ``stiction`` [-]: its own stiction level, 0.7.
DIRECT_LEVEL = 0.7

#: Lowest bootstrap support over the cycles for the Hammerstein improvement to count
#: as holding over the record [-].
DIRECT_SUPPORT = 0.95


def direct_stick_slip(
    features: dict, has_mv: bool, p_friction: float, *, min_improvement: float
) -> str | None:
    """The direct evidence of stick-slip in a loop without a cycle, as a reason; None
    when there is none.

    Direct means seen in the valve's own movement, not inferred from a cycle: the
    friction model (:mod:`stictiondiag.stiction.probability`) must favour friction
    at least 7 to 3 (:data:`DIRECT_LEVEL`), and one of

    * the valve position is recorded (its stick and slip phases are the evidence,
      Figs. 3 and 6);
    * Kano et al.'s test finds stuck sections (``kano`` +1);
    * the stiction model beats a linear valve materially in at least
      :data:`DIRECT_SUPPORT` of the cycle resamples and in both halves of the record
      (``support``, ``halves_improvement`` above ``min_improvement``, the share of
      the linear valve's residual that counts as material).
    """
    if not p_friction > DIRECT_LEVEL:
        return None
    if has_mv:
        return "the recorded valve position sticks and slips"
    if float(features.get("kano", 0.0)) > 0.5:
        return "Kano et al.'s test finds the valve stuck while op moves"
    if (
        float(features.get("support", 0.0)) >= DIRECT_SUPPORT
        and float(features.get("halves_missing", 1.0)) < 0.5
        and float(features.get("halves_improvement", 0.0)) > min_improvement
    ):
        return "the stiction model beats a linear valve over the whole record and in both halves"
    return None


def cycle_text(cycle: Cycle) -> str:
    """One line on the cycle of stage 1."""
    if not cycle.present:
        return "no limit cycle in pv, the control error or op"
    if cycle.signal is None:
        return "a cycle in a record too short to confirm it"
    per = f"period {cycle.period_s:.4g} s" if cycle.period_s else "period unknown"
    reg = (
        f", regularity {cycle.regularity:.2g}"
        if cycle.regularity is not None and math.isfinite(cycle.regularity)
        else ""
    )
    n = f", {cycle.n_cycles:.1f} cycles in the record" if cycle.n_cycles else ""
    sp = (
        f"; the set point carries it ({cycle.setpoint_share:.2f} of pv's spread at the cycle)"
        if cycle.setpoint_carries
        else ""
    )
    return f"limit cycle in {cycle.signal} ({per}{reg}{n}){sp}"


def atypical_text(reading: CauseReading) -> str | None:
    """The caveat of a call that extrapolates (:attr:`CauseReading.atypical`), None
    for a typical one."""
    if not reading.atypical:
        return None
    first = reading.ranked()[0].value
    return (
        f"the evidence lies outside 99 % of the simulated loops whose cycle"
        f" {CAUSE_WORDS[first]} causes ({reading.atypicality:.1f} times their 99th"
        " percentile of squared distance): the cause model extrapolates here, so its"
        " call is a lead to check, not a finding"
    )


def friction_text(p_friction: float) -> str:
    """The friction model's P beside stage 2's decision: whether the valve has any
    friction (:mod:`stictiondiag.stiction.probability`), a different question from
    whether it causes the cycle."""
    return (
        f"P that the valve has friction (friction model) = {p_friction:.2f}: whether it "
        "has any, not whether it causes the cycle"
    )
