"""Findings in words for one loop: what was found, what it means, what to do.

:func:`findings_of` reads the typed result of one loop
(:class:`stictiondiag.result.Analysis`, as run or as read back with
:meth:`~stictiondiag.result.Analysis.from_json`) and writes, for a maintenance planner:

* the verdict with the probability it decided on and its decision levels
  (:mod:`stictiondiag.stiction.verdict`): P(the valve causes the cycle), with the most
  likely cause and the runner-up, for a loop with a cycle and without mv, else the
  calibrated ``P(stiction)`` (Section 5.3); never a bare "confidence";
* S and J in % of valve travel (Section 5.1: "stiction is generally measured as a %
  of the valve travel"), each marked when the data determine it poorly
  (:func:`param_text`);
* what that means (the Fig. 11 cases: deadband, undershoot, no offset, overshoot)
  and what to do: a valve inspection, and meanwhile the variable-integral band of
  Section 6.4 with the offset it costs, both from the compensation simulated on the
  fitted loop (:mod:`stictiondiag.replay.compensation`);
* what the sim-to-real gap diagnosis found (:mod:`stictiondiag.gap`);
* what the data cannot tell.

Everything is read from the typed parts (:class:`~stictiondiag.stiction.fit_result.StictionFit`,
:class:`~stictiondiag.stiction.verdict.Verdict`, ...), never from text or string keys of
the JSON, so a field added to a result is a field of its class here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from stictiondiag.core.serialize import plain_float
from stictiondiag.stiction.cause import ACTIONS, CAUSE_WORDS, Cause
from stictiondiag.stiction.fit_result import Determinacy, StictionFit
from stictiondiag.stiction.verdict_result import Verdict

if TYPE_CHECKING:
    import pandas as pd

    from stictiondiag.replay.compensation import Compensation
    from stictiondiag.result import Analysis

#: Relative difference of J and S within which the valve counts as "no offset" (J = S,
#: Fig. 11c): below it the slip lands on the demand within a tenth of the jump.
NO_OFFSET_TOLERANCE = 0.1


@dataclass(frozen=True)
class Findings:
    """A loop's findings in plain words.

    Attributes
    ----------
    loop : str
        Loop name.
    verdict : str
        ``stiction``, ``no_stiction``, ``inconclusive`` (or ``unknown``).
    probability : float or None
        The probability the verdict decided on [-] (P(the valve causes the cycle) or
        P(stiction), :attr:`stictiondiag.stiction.verdict.Verdict.levels`).
    levels : tuple of float
        Decision levels on it: at or below the first no stiction, at or above the second
        stiction [-].
    S, J : float or None
        Deadband plus stickband and slip jump [% of valve travel].
    S_text, J_text : str
        ``S = 5.0 % of travel`` with the interval, or the note that it is poorly
        determined.
    poorly_determined : tuple of str
        The parameters (``"S"``, ``"J"``) the data determine poorly.
    headline : str
        The verdict with its probability, one line.
    meaning : str
        What the verdict and S, J mean for the valve.
    action : str
        What to do.
    compensation : str
        The variable-integral band and its offset (simulated), or why not given.
    gap : str
        What the sim-to-real gap diagnosis found.
    limits : tuple of str
        What the data cannot tell.
    """

    loop: str
    verdict: str
    probability: float | None
    levels: tuple[float, float]
    S: float | None
    J: float | None
    S_text: str
    J_text: str
    poorly_determined: tuple[str, ...]
    headline: str
    meaning: str
    action: str
    compensation: str
    gap: str
    limits: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return {
            "loop": self.loop,
            "verdict": self.verdict,
            "probability": self.probability,
            "decision_levels": list(self.levels),
            "S_pct_travel": self.S,
            "J_pct_travel": self.J,
            "S_text": self.S_text,
            "J_text": self.J_text,
            "poorly_determined": list(self.poorly_determined),
            "headline": self.headline,
            "meaning": self.meaning,
            "action": self.action,
            "compensation": self.compensation,
            "gap": self.gap,
            "limits": list(self.limits),
        }

    def items(self) -> list[tuple[str, str]]:
        """(topic, text) pairs in reading order."""
        out = [
            ("verdict", self.headline),
            ("valve", f"{self.S_text}; {self.J_text}"),
            ("meaning", self.meaning),
            ("action", self.action),
        ]
        if self.compensation:
            out.append(("compensation", self.compensation))
        out.append(("gap", self.gap))
        out += [("cannot tell", text) for text in self.limits]
        return out

    def to_pandas(self) -> pd.DataFrame:
        """One row per finding: columns ``loop``, ``topic``, ``text``."""
        import pandas as pd

        rows = [{"loop": self.loop, "topic": t, "text": x} for t, x in self.items()]
        return pd.DataFrame(rows, columns=["loop", "topic", "text"])

    def text(self, width: int = 12) -> str:
        """Plain-text rendering, one finding a line, topic in a column of ``width``."""
        return "\n".join(f"{topic:<{width}}{text}" for topic, text in self.items())


# --------------------------------------------------------------------------- parameters


def _num(v: float | None, spec: str = ".2g") -> str:
    if v is None:
        return "n/a"
    text = format(float(v), spec)
    return text


def _fmt(v: float | None) -> str:
    """A value in % of travel to 3 significant digits."""
    if v is None:
        return "n/a"
    return format(float(v), ".3g")


def estimate(fit: StictionFit, sym: str) -> float | None:
    """The estimate of ``sym`` (``"S"`` or ``"J"``) [% of op span], None when not finite."""
    return plain_float(fit.S if sym == "S" else fit.J)


def interval(fit: StictionFit, sym: str) -> tuple[float, float] | None:
    """The interval of ``sym`` [% of op span], None unless both ends are finite."""
    iv = fit.S_interval if sym == "S" else fit.J_interval
    ends = [plain_float(v) for v in (iv or ())]
    if len(ends) != 2 or ends[0] is None or ends[1] is None:
        return None
    return (ends[0], ends[1])


def determinacy(fit: StictionFit, sym: str) -> str:
    """The estimator's words on how well ``sym`` is determined ('' when none)."""
    member = fit.determinacy_of(sym)
    return "" if member is None else member.value


def param_note(fit: StictionFit, sym: str) -> str:
    """How well ``sym`` is known, in words: ``interval 4.98-5.01``,
    ``moderately determined: interval ...`` or ``poorly determined: interval
    2.89-5.78 at the search edge`` ('' without an interval)."""
    iv = interval(fit, sym)
    iv_text = f"interval {_fmt(iv[0])}\u2013{_fmt(iv[1])}" if iv else "no interval"
    member = fit.determinacy_of(sym)
    if fit.poorly_determined(sym):
        edge = " at the search edge" if member is not None and member.open else ""
        return f"poorly determined: {iv_text}{edge}"
    if member is Determinacy.MODERATE:
        return f"moderately determined: {iv_text}"
    return iv_text if iv else ""


def param_text(fit: StictionFit, sym: str, *, unit: str = " %") -> str:
    """``J = 5.8 % (poorly determined: interval 2.9-5.8 at the search edge)``.

    A well or moderately determined value carries its interval; a poorly determined
    one says so, with the interval and whether it ends at the edge of the search
    (the data bound it on one side only).
    """
    note = param_note(fit, sym)
    text = f"{sym} = {_fmt(estimate(fit, sym))}{unit}"
    return f"{text} ({note})" if note else text


def short_of_cycles(verdict: Verdict) -> bool:
    """An undecided stage-2 loop whose record is too short to clear the valve: P(valve)
    at or below the lower level, left undecided for want of three cycles
    (:func:`stictiondiag.stiction.verdict.stiction_verdict`)."""
    probs, cycle = verdict.cause_probabilities, verdict.cycle
    return bool(
        verdict.by_cause
        and verdict.cause is None
        and probs is not None
        and cycle is not None
        and cycle.short_record
        and probs.valve <= verdict.levels[0]
    )


def probability_text(verdict: Verdict) -> str:
    """``P(the valve causes the cycle) = 0.72 (decision levels 0.4 and 0.6); cause:
    the valve (P 0.72), runner-up: the controller's tuning (P 0.15)`` where stage 2
    decided (a cycle, no mv; an undecided loop: ``undecided between the valve (P 0.5)
    and ...``), ``P(stiction) = 0.55 (decision levels 0.3 and 0.7)`` otherwise, or
    ``no limit cycle`` for a loop without one."""
    probs = verdict.cause_probabilities
    if verdict.cause == Cause.NONE:
        pf = plain_float(verdict.evidence.p_friction)
        return "no limit cycle" + (
            f"; P(the valve has friction) = {pf:.2f}" if pf is not None else ""
        )
    lo, hi = verdict.levels
    p = plain_float(verdict.probability)
    p_text = "n/a" if p is None else f"{p:.2f}"
    if probs is None or not verdict.by_cause:
        return f"P(stiction) = {p_text} (decision levels {lo:g} and {hi:g})"
    # The verdict's own cause and runner-up, so the line cannot name a cause the
    # verdict did not (an undecided loop names none; its runner-up is the other cause).
    head = f"P(the valve causes the cycle) = {p_text} (decision levels {lo:g} and {hi:g}); "
    runner = verdict.runner_up
    other = f"{CAUSE_WORDS[runner]} (P {probs.p(runner):.2f})" if runner is not None else "-"
    if short_of_cycles(verdict):
        return head + (
            f"too few cycles to clear the valve (P {probs.valve:.2f}); most likely: {other}"
        )
    # A call that extrapolates says so (the verdict's reasons say how far).
    far = (
        "; the record is unlike the simulated loops of its most likely cause: an extrapolation"
        if probs.atypical
        else ""
    )
    if verdict.cause is None:
        return head + f"undecided between the valve (P {probs.valve:.2f}) and {other}" + far
    return (
        head + f"cause: {CAUSE_WORDS[verdict.cause]} (P {probs.p(verdict.cause):.2f}), "
        f"runner-up: {other}" + far
    )


# --------------------------------------------------------------------------- sentences


def _shape(S: float, J: float) -> str:
    """The Fig. 11 case of (S, J)."""
    if J <= 0:
        return "pure deadband, no slip jump (Fig. 11a)"
    if abs(J - S) <= NO_OFFSET_TOLERANCE * max(S, J):
        return "the slip lands on the demand (no offset, Fig. 11c)"
    if J < S:
        return "each slip stops short of the demand (undershoot, Fig. 11b)"
    return "each slip overshoots the demand (overshoot, Fig. 11d)"


def _meaning(status: str, a: Analysis, oscillating: bool) -> str:
    S, J = estimate(a.fit, "S"), estimate(a.fit, "J")
    if status == "stiction" and S is not None and J is not None:
        return (
            f"valve sticky, about {_fmt(S)} % of travel: the demand must move "
            f"{_fmt(S)} % before the valve moves after a reversal, and it then jumps "
            f"{_fmt(J)} %; {_shape(S, J)}"
        )
    if status == "inconclusive":
        v = a.verdict
        probs = v.cause_probabilities
        if short_of_cycles(v):
            return (
                "the record holds fewer than three cycles of the loop's oscillation: too"
                " few to tell whether the valve causes it"
            )
        if v.by_cause and probs is not None and v.runner_up is not None:
            return (
                f"the loop cycles, and the valve (P {probs.valve:.2f}) and "
                f"{CAUSE_WORDS[v.runner_up]} (P {probs.p(v.runner_up):.2f}) are too close "
                "to tell which causes it"
            )
        return (
            "the data neither confirm nor rule out a sticky valve: the evidence falls "
            "between the decision levels"
        )
    if status == "no_stiction":
        cause = a.verdict.cause
        if cause in ("tuning", "external", "other"):
            text = (
                f"the loop cycles, and the cause is most likely {CAUSE_WORDS[cause]}, not the valve"
            )
            cycle = a.verdict.cycle
            if cause == "external" and cycle is not None and cycle.setpoint_carries:
                text += (
                    f"; it reaches this loop through its set point, which carries"
                    f" {cycle.setpoint_share:.2f} of pv's spread at the cycle"
                )
            return text
        if cause == "none":
            return "the loop has no limit cycle: the valve is not driving an oscillation"
        if oscillating:
            return (
                "the oscillation is not explained by a sticky valve: look for its cause "
                "in the tuning or in a disturbance from another loop"
            )
        return "no sign of a sticky valve, and the loop does not oscillate"
    return "no verdict"


#: Unit of S and J when op's scale is unknown.
OWN_UNITS = " in op's own units (scale unknown, not % of span)"


def _action(
    status: str,
    cause: str | None,
    oscillating: bool,
    unknown_scale: bool,
    short: bool = False,
    setpoint: bool = False,
) -> str:
    if status == "stiction" and unknown_scale:
        # A size in unknown units cannot schedule work: S of 0.002 may be 0.2 % of span
        # or nothing at all.
        return (
            "size the stiction before any valve work: give op's values at 0 and 100 % of "
            "span (--op-range LO HI, or op_range in the loops manifest), or test the "
            "valve directly in manual"
        )
    if status != "inconclusive" and cause == "external" and setpoint:
        return (
            "look at the loop that writes this set point (a cascade master, or whatever"
            " moves it): the set point carries the cycle"
        )
    if status != "inconclusive" and cause in ACTIONS:
        return ACTIONS[cause]
    if status == "stiction":
        return "schedule a valve inspection (packing, actuator, positioner)"
    if status == "inconclusive" and short:
        return (
            "export a record of at least three cycles of the oscillation and analyse it"
            " again, or test the valve directly in manual"
        )
    if status == "inconclusive":
        return (
            "test the valve directly: in manual, step op by about the S found (or 1 % of "
            "travel) a few times each way and watch the valve position or the flow; "
            "record mv if it is available"
        )
    if status == "no_stiction" and oscillating:
        return "no valve work indicated; review the controller tuning and upstream loops"
    return "nothing to do for the valve"


def _compensation(status: str, comp: Compensation | None) -> str:
    if status != "stiction":
        return ""
    if comp is None:
        return "no compensation tried (it needs the closed-loop replay)"
    if not comp.applicable:
        return f"no compensation tried: {comp.reason}"
    band = plain_float(comp.band)
    if band is None:
        return (
            "a variable-integral PI (Section 6.4) does not stop the cycle of the fitted "
            f"loop: {comp.reason}"
        )
    offset, amplitude = plain_float(comp.offset), plain_float(comp.amplitude)
    share = (
        f", {100 * offset / amplitude:.0f} % of the cycle's amplitude"
        if offset is not None and amplitude is not None and amplitude > 0
        else ""
    )
    return (
        f"meanwhile a variable-integral band of {_num(band, '.3g')} pv units "
        f"({_num(plain_float(comp.band_pct_of_amplitude), '.0f')} % of the cycle's pv "
        f"amplitude) stops the cycle at an offset of {_num(offset, '.3g')} pv units"
        f"{share} (at most the band), simulated on the fitted loop (Section 6.4)"
    )


def _gap(a: Analysis) -> str:
    """The gap in words: how much of the departure is the fitted loop's (the
    closed-loop refit) and how much an unmodelled effect's
    (:func:`stictiondiag.gap.attribution.attribute_gap`)."""
    # Imported here: the gap's effects bring numba, which reading a result does not need.
    from stictiondiag.gap.attribution import attribute_gap

    why = attribute_gap(None if a.replay is None else a.replay.settings.refit, a.gap)
    if a.gap is None:
        text = f"no gap diagnosis: {a.gap_skipped or 'it needs the closed-loop replay'}"
        return f"{text}; {why.text}" if why.identification.refit_accepted else text
    head = (
        f"the replay departs from the data by {_num(plain_float(a.gap.before), '.3g')} % "
        f"({a.gap.metric})"
    )
    return f"{head}; {why.text}" if why.text else head


def _limits(a: Analysis, poorly: list[str]) -> list[str]:
    tags = a.tags
    out = []
    if tags.mv is None:
        out.append(
            "mv is not recorded: S and J come from pv through a fitted process, so "
            "valve and process cannot be told apart with certainty (Section 5.3.1)"
        )
    for sym in poorly:
        out.append(
            f"{sym} is poorly determined: values across its interval fit the data "
            "about equally well"
        )
    if not tags.loop_type_source and tags.loop_type in (None, "other"):
        out.append("the loop type was not given: the replay chose the process structure by fit")
    if a.verdict.evidence.short_record:
        out.append("the record is short: a missing cycle is not taken as evidence")
    out.append(
        "the cause of the friction (packing, actuator, positioner) and the valve's "
        "behaviour outside the travel seen in the record"
    )
    if a.compensation is not None and plain_float(a.compensation.band) is not None:
        out.append(
            "how the plant itself responds to the band: the figures come from the "
            "fitted model of the loop"
        )
    return out


def findings_of(a: Analysis, *, loop: str | None = None) -> Findings:
    """The findings of one analysis; ``loop`` names the loop (default :attr:`Analysis.loop`)."""
    fit, verdict = a.fit, a.verdict
    status = str(verdict.status or "unknown")
    oscillating = bool(a.oscillation.present)
    poorly = [sym for sym in ("S", "J") if fit.poorly_determined(sym)]
    word = status.upper().replace("_", " ")
    unknown = a.tags.op_scale == "unknown"
    unit = OWN_UNITS if unknown else " % of travel"
    meaning = _meaning(status, a, oscillating)
    if unknown and status == "stiction":
        meaning = (
            f"a sticky valve's pattern, S = {_fmt(estimate(fit, 'S'))} and J = "
            f"{_fmt(estimate(fit, 'J'))}{OWN_UNITS}: op is not in % of span, so its size in "
            "travel is not known"
        )
    return Findings(
        loop=str(a.loop if loop is None else loop),
        verdict=status,
        probability=plain_float(verdict.probability),
        levels=verdict.levels,
        S=estimate(fit, "S"),
        J=estimate(fit, "J"),
        S_text=param_text(fit, "S", unit=unit),
        J_text=param_text(fit, "J", unit=unit),
        poorly_determined=tuple(poorly),
        headline=f"{word}, {probability_text(verdict)}",
        meaning=meaning,
        action=_action(
            status,
            verdict.cause,
            oscillating,
            unknown,
            short_of_cycles(verdict),
            verdict.cycle is not None and verdict.cycle.setpoint_carries,
        ),
        compensation=_compensation(status, a.compensation),
        gap=_gap(a),
        limits=tuple(_limits(a, poorly)),
    )


def analysis_json(a: Analysis, *, loop: str | None = None) -> dict[str, Any]:
    """The analysis's JSON (:meth:`Analysis.to_dict`, the loop named ``loop`` when
    given) with its findings in words under ``"findings"``."""
    d = a.to_dict()
    if loop is not None:
        d["loop"] = loop
    return {**d, "findings": findings_of(a, loop=loop).to_dict()}
