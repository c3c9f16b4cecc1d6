"""Findings in words for one loop: what was found, what it means, what to do.

:func:`findings_from_dict` reads an analysis (:meth:`stictiondiag.analysis.Analysis.to_dict`,
or the JSON written from it) and writes, for a maintenance planner:

* the verdict with its calibrated ``P(stiction)`` and the decision levels (Section 5.3
  verdict, :mod:`stictiondiag.stiction.verdict`), never a bare "confidence";
* S and J in % of valve travel (Section 5.1: "stiction is generally measured as a %
  of the valve travel"), each marked when the data determine it poorly
  (:func:`param_text`);
* what that means (the Fig. 11 cases: deadband, undershoot, no offset, overshoot)
  and what to do: a valve inspection, and meanwhile the variable-integral band of
  Section 6.4 with the offset it costs, both from the compensation simulated on the
  fitted loop (:mod:`stictiondiag.replay.compensation`);
* what the sim-to-real gap diagnosis found (:mod:`stictiondiag.gap`);
* what the data cannot tell.

Everything is worked from the dict, so saved JSON files give the same findings.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from stictiondiag.stiction.cause import ACTIONS, CAUSE_WORDS
from stictiondiag.stiction.valvefit import Determinacy, poorly_determined
from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

if TYPE_CHECKING:
    import pandas as pd

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
        Calibrated P(stiction) [-].
    levels : tuple of float
        Decision levels on P: below the first no stiction, above the second stiction [-].
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


def determinacy_of(st: dict, sym: str) -> Determinacy | None:
    """How well ``sym`` is determined (``details.determinacy`` in the JSON), None
    when the estimator did not say."""
    details = st.get("details") or {}
    return Determinacy.of((details.get("determinacy") or {}).get(sym))


def determinacy(st: dict, sym: str) -> str:
    """The estimator's words on how well ``sym`` is determined ('' when none)."""
    member = determinacy_of(st, sym)
    return "" if member is None else member.value


def is_poorly_determined(st: dict, sym: str) -> bool:
    """The data determine ``sym`` poorly (:func:`stictiondiag.stiction.valvefit.
    poorly_determined`: the figures' rule too)."""
    return poorly_determined(determinacy_of(st, sym), st.get(sym), st.get(f"{sym}_interval"))


def param_note(st: dict, sym: str) -> str:
    """How well ``sym`` is known, in words: ``interval 4.98-5.01``,
    ``moderately determined: interval ...`` or ``poorly determined: interval
    2.89-5.78 at the search edge`` ('' without an interval)."""
    iv = list(st.get(f"{sym}_interval") or [])
    have_iv = len(iv) == 2 and None not in iv
    iv_text = f"interval {_fmt(iv[0])}\u2013{_fmt(iv[1])}" if have_iv else "no interval"
    member = determinacy_of(st, sym)
    if is_poorly_determined(st, sym):
        edge = " at the search edge" if member is not None and member.open else ""
        return f"poorly determined: {iv_text}{edge}"
    if member is Determinacy.MODERATE:
        return f"moderately determined: {iv_text}"
    return iv_text if have_iv else ""


def param_text(st: dict, sym: str, *, unit: str = " %") -> str:
    """``J = 5.8 % (poorly determined: interval 2.9-5.8 at the search edge)``.

    A well or moderately determined value carries its interval; a poorly determined
    one says so, with the interval and whether it ends at the edge of the search
    (the data bound it on one side only).
    """
    note = param_note(st, sym)
    text = f"{sym} = {_fmt(st.get(sym))}{unit}"
    return f"{text} ({note})" if note else text


def probability_text(st: dict) -> str:
    """``P(stiction) = 0.55 (decision levels 0.3 and 0.7)``, with the cause model's
    reading after it for a loop with a cycle and no mv (``; cause model: the valve
    (P 0.72), runner-up: the controller's tuning (P 0.15)``), or ``no limit
    cycle`` for a loop without one."""
    ev = st.get("evidence") or {}
    probs = st.get("cause_probabilities")
    cause = str(st.get("cause"))
    if cause == "none":
        pf = ev.get("p_friction")
        return "no limit cycle" + (
            f"; P(the valve has friction) = {float(pf):.2f}" if pf is not None else ""
        )
    lo = ev.get("no_stiction_level", NO_STICTION_LEVEL)
    hi = ev.get("stiction_level", STICTION_LEVEL)
    p = st.get("probability")
    p_text = "n/a" if p is None else f"{float(p):.2f}"
    text = f"P(stiction) = {p_text} (decision levels {lo:g} and {hi:g})"
    if probs and not ev.get("has_mv"):
        ranked = sorted(probs, key=lambda c: -float(probs[c]))
        top, second = ranked[0], ranked[1]
        text += (
            f"; cause model: {CAUSE_WORDS[top]} (P {float(probs[top]):.2f}), "
            f"runner-up: {CAUSE_WORDS[second]} (P {float(probs[second]):.2f})"
        )
    return text


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


def _meaning(status: str, st: dict, oscillating: bool) -> str:
    S, J = st.get("S"), st.get("J")
    if status == "stiction" and S is not None and J is not None:
        return (
            f"valve sticky, about {_fmt(S)} % of travel: the demand must move "
            f"{_fmt(S)} % before the valve moves after a reversal, and it then jumps "
            f"{_fmt(J)} %; {_shape(float(S), float(J))}"
        )
    if status == "inconclusive":
        return (
            "the data neither confirm nor rule out a sticky valve: the evidence falls "
            "between the decision levels"
        )
    if status == "no_stiction":
        cause = st.get("cause")
        if cause in ("tuning", "external", "other"):
            return (
                f"the loop cycles, and the cause is most likely {CAUSE_WORDS[cause]}, not the valve"
            )
        if cause == "none":
            return "the loop has no limit cycle: the valve is not driving an oscillation"
        if oscillating:
            return (
                "the oscillation is not explained by a sticky valve: look for its cause "
                "in the tuning or in a disturbance from another loop"
            )
        return "no sign of a sticky valve, and the loop does not oscillate"
    return "no verdict"


def _unknown_scale(d: dict) -> bool:
    """Whether op was not in % of span (:attr:`stictiondiag.io.tags.Tags.op_scale`)."""
    return (d.get("tags") or {}).get("op_scale") == "unknown"


#: Unit of S and J when op's scale is unknown.
OWN_UNITS = " in op's own units (scale unknown, not % of span)"


def _action(status: str, st: dict, oscillating: bool, unknown_scale: bool = False) -> str:
    if status == "stiction" and unknown_scale:
        # A size in unknown units cannot schedule work: S of 0.002 may be 0.2 % of span
        # or nothing at all.
        return (
            "size the stiction before any valve work: give op's values at 0 and 100 % of "
            "span (--op-range LO HI, or op_range in the loops manifest), or test the "
            "valve directly in manual"
        )
    cause = st.get("cause")
    if status != "inconclusive" and cause in ACTIONS:
        return ACTIONS[cause]
    if status == "stiction":
        return "schedule a valve inspection (packing, actuator, positioner)"
    if status == "inconclusive":
        return (
            "test the valve directly: in manual, step op by about the S found (or 1 % of "
            "travel) a few times each way and watch the valve position or the flow; "
            "record mv if it is available"
        )
    if status == "no_stiction" and oscillating:
        return "no valve work indicated; review the controller tuning and upstream loops"
    return "nothing to do for the valve"


def _compensation(status: str, d: dict) -> str:
    comp = d.get("compensation")
    if status != "stiction":
        return ""
    if not comp:
        return "no compensation tried (it needs the closed-loop replay)"
    if not comp.get("applicable"):
        return f"no compensation tried: {comp.get('reason')}"
    band = comp.get("band_pv")
    if band is None:
        return (
            "a variable-integral PI (Section 6.4) does not stop the cycle of the fitted "
            f"loop: {comp.get('reason')}"
        )
    offset, amplitude = comp.get("offset_pv"), comp.get("amplitude_pv")
    share = (
        f", {100 * offset / amplitude:.0f} % of the cycle's amplitude"
        if isinstance(offset, int | float) and isinstance(amplitude, int | float) and amplitude > 0
        else ""
    )
    return (
        f"meanwhile a variable-integral band of {_num(band, '.3g')} pv units "
        f"({_num(comp.get('band_pct_of_amplitude'), '.0f')} % of the cycle's pv "
        f"amplitude) stops the cycle at an offset of {_num(offset, '.3g')} pv units"
        f"{share} (at most the band), simulated on the fitted loop (Section 6.4)"
    )


def _gap(d: dict) -> str:
    """The gap in words: how much of the departure is the fitted loop's (the
    closed-loop refit) and how much an unmodelled effect's
    (:func:`stictiondiag.gap.attribution.attribute_gap`)."""
    # Imported here: the gap's effects bring numba, which reading a result does not need.
    from stictiondiag.gap.attribution import attribute_gap

    gap = d.get("gap")
    why = attribute_gap(d.get("replay"), gap)
    if not gap:
        text = "no gap diagnosis (it needs the closed-loop replay)"
        return f"{text}; {why['text']}" if why["identification"]["refit_accepted"] else text
    head = f"the replay departs from the data by {_num(gap.get('before'), '.3g')} % ({gap.get('metric')})"
    return f"{head}; {why['text']}" if why["text"] else head


def _limits(d: dict, st: dict, poorly: list[str]) -> list[str]:
    tg = d.get("tags") or {}
    out = []
    if not tg.get("has_mv", True):
        out.append(
            "mv is not recorded: S and J come from pv through a fitted process, so "
            "valve and process cannot be told apart with certainty (Section 5.3.1)"
        )
    for sym in poorly:
        out.append(
            f"{sym} is poorly determined: values across its interval fit the data "
            "about equally well"
        )
    if not tg.get("loop_type_source") and tg.get("loop_type") in (None, "other"):
        out.append("the loop type was not given: the replay chose the process structure by fit")
    ev = st.get("evidence") or {}
    if ev.get("short_record"):
        out.append("the record is short: a missing cycle is not taken as evidence")
    out.append(
        "the cause of the friction (packing, actuator, positioner) and the valve's "
        "behaviour outside the travel seen in the record"
    )
    if d.get("compensation") and (d["compensation"] or {}).get("band_pv") is not None:
        out.append(
            "how the plant itself responds to the band: the figures come from the "
            "fitted model of the loop"
        )
    return out


def findings_from_dict(d: dict) -> Findings:
    """The findings of one analysis dict (:meth:`Analysis.to_dict` or its JSON)."""
    st = d.get("stiction") or {}
    status = str(st.get("status") or "unknown")
    osc = (d.get("oscillation") or {}).get("pv") or {}
    oscillating = bool(osc.get("present"))
    poorly = [sym for sym in ("S", "J") if is_poorly_determined(st, sym)]
    ev = st.get("evidence") or {}
    levels = (
        float(ev.get("no_stiction_level", NO_STICTION_LEVEL)),
        float(ev.get("stiction_level", STICTION_LEVEL)),
    )
    word = status.upper().replace("_", " ")
    unknown = _unknown_scale(d)
    unit = OWN_UNITS if unknown else " % of travel"
    meaning = _meaning(status, st, oscillating)
    if unknown and status == "stiction":
        meaning = (
            f"a sticky valve's pattern, S = {_fmt(st.get('S'))} and J = {_fmt(st.get('J'))}"
            f"{OWN_UNITS}: op is not in % of span, so its size in travel is not known"
        )
    return Findings(
        loop=str(d.get("loop")),
        verdict=status,
        probability=st.get("probability"),
        levels=levels,
        S=st.get("S"),
        J=st.get("J"),
        S_text=param_text(st, "S", unit=unit),
        J_text=param_text(st, "J", unit=unit),
        poorly_determined=tuple(poorly),
        headline=f"{word}, {probability_text(st)}",
        meaning=meaning,
        action=_action(status, st, oscillating, unknown),
        compensation=_compensation(status, d),
        gap=_gap(d),
        limits=tuple(_limits(d, st, poorly)),
    )


def with_findings(d: dict) -> dict:
    """``d`` with its findings in words under ``"findings"`` (for the JSON files)."""
    return {**d, "findings": findings_from_dict(d).to_dict()}
