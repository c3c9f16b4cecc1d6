"""The verdict's result types: :class:`Verdict` and the evidence behind it
(:class:`VerdictEvidence`), filled by :func:`stictiondiag.stiction.verdict.stiction_verdict`.

They live apart from the decision so that the renderers, the saved results and the
decision read one typed object (the verdict module is long enough on its own).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from stictiondiag.core.serialize import to_plain as _plain
from stictiondiag.stiction.cause import Cause, CauseReading, Cycle

#: How the verdict's confidence follows from P, as the evidence states it.
CONFIDENCE_FORMULA = (
    "P = the probability the verdict decides on, both fitted on simulated loops: "
    "P(the valve causes the cycle) of the cause model (stictiondiag.stiction."
    "cause_model) for a loop with a cycle and without mv, else P(stiction) of the "
    "friction model (stictiondiag.stiction.probability); confidence = P (stiction, "
    "inconclusive) or 1 - P (no stiction); without a limit cycle, "
    "max(1 - P(stiction), 0.5) for no stiction (stage 1 answers the question of the "
    "cycle, P(stiction) only whether the valve has friction)"
)


class VerdictStatus(StrEnum):
    """The verdict: the value is the word the JSON carries; code compares members."""

    STICTION = "stiction"
    NO_STICTION = "no_stiction"
    INCONCLUSIVE = "inconclusive"


@dataclass(frozen=True)
class VerdictEvidence:
    """The measured quantities behind a verdict, and the levels it was decided with.

    ``features``, ``contributions`` and ``classic`` stay mappings by name: they are
    the probability model's input vector and its terms, whose names the fitted model
    lists (:func:`stictiondiag.stiction.probability.part_features`), not a fixed set.

    Attributes
    ----------
    p_friction : float
        The friction model's P(stiction) [-] (:mod:`stictiondiag.stiction.probability`),
        in every case (the verdict's ``probability`` is 0 for a loop without a cycle
        and without direct stick-slip).  The JSON writes it as ``probability`` too.
    cause_probabilities : CauseReading or None
        Stage 2's P of each cause of the cycle [-]; None without a cycle or without
        the cause model.
    features : dict of str to float
        The probability model's features of the loop
        (:func:`stictiondiag.stiction.verdict.verdict_features`) [units per feature].
    contributions : dict of str to float
        Each feature's term in the log-odds relative to the training mean [-],
        largest first.
    improvement : float
        Share of the linear valve's residual the stiction model removes [-].
    improvement_interval : (float, float)
        2.5 and 97.5 percentiles of the improvement over the cycle resamples [-].
    support : float
        Share of resamples whose improvement exceeds ``min_improvement`` [-].
    min_improvement : float
        Improvement that counts as material [-].
    n_blocks : int
        Cycle blocks the support was measured over [-].
    has_mv : bool
        The valve position was recorded.
    short_record : bool
        The record holds fewer cycles than the oscillation test needs.
    cycle : Cycle
        Stage 1: the limit cycle found, if any.
    direct_stick_slip : str or None
        The direct evidence of stick-slip in a loop without a cycle, in words.
    classic : dict of str to float or None
        The classic tests' calls (+1, 0, -1) and statistics, by name
        (:func:`stictiondiag.stiction.probability.classic_votes`).
    stiction_level, no_stiction_level : float
        P(stiction) above which the verdict is ``stiction``, below which
        ``no_stiction`` [-], where the friction model decides (a loop with mv).
    valve_level : float
        P(the valve causes the cycle) at or above which stage 2 calls ``stiction``
        (at or below one minus it ``no_stiction``) [-], for a loop with a cycle and
        without mv.
    confidence_formula : str
        How the confidence follows from P.
    """

    p_friction: float
    cause_probabilities: CauseReading | None
    features: dict[str, float]
    contributions: dict[str, float]
    improvement: float
    improvement_interval: tuple[float, float]
    support: float
    min_improvement: float
    n_blocks: int
    has_mv: bool
    short_record: bool
    cycle: Cycle
    direct_stick_slip: str | None
    classic: dict[str, float | None]
    stiction_level: float
    no_stiction_level: float
    valve_level: float
    confidence_formula: str = CONFIDENCE_FORMULA

    def to_dict(self) -> dict:
        """JSON-able dict, under the keys the verdict's JSON has always had."""
        cause = self.cause_probabilities
        return _plain(
            {
                "probability": self.p_friction,
                "p_friction": self.p_friction,
                "cause_probabilities": None if cause is None else cause.to_dict(),
                "valve_level": self.valve_level,
                "features": self.features,
                "contributions": self.contributions,
                "stiction_level": self.stiction_level,
                "no_stiction_level": self.no_stiction_level,
                "improvement": self.improvement,
                "improvement_interval": list(self.improvement_interval),
                "support": self.support,
                "min_improvement": self.min_improvement,
                "n_blocks": int(self.n_blocks),
                "has_mv": self.has_mv,
                "short_record": bool(self.short_record),
                "cycle": self.cycle.to_dict(),
                "direct_stick_slip": self.direct_stick_slip,
                "classic": self.classic,
                "confidence_formula": self.confidence_formula,
            }
        )


@dataclass(frozen=True)
class Verdict:
    """Is the oscillation caused by valve stiction?

    Attributes
    ----------
    status : VerdictStatus
        ``stiction``, ``no_stiction`` or ``inconclusive``.
    detected : bool or None
        True for stiction, False for no stiction, None when inconclusive.
    confidence : float
        Support for ``status`` in [0, 1], measured from the data (see
        :func:`~stictiondiag.stiction.verdict.stiction_verdict` for the formula); for
        ``"inconclusive"`` it is the support for stiction, which fell between the
        decision levels.
    reasons : tuple of str
        Human-readable reasons, most important first.
    evidence : VerdictEvidence
        The measured quantities behind the decision.
    probability : float or None
        The probability the verdict decided on [-] (see below and :attr:`levels`).
    cause : Cause or None
        Why the loop oscillates (:mod:`stictiondiag.stiction.cause`): ``none`` (no
        limit cycle), ``valve``, ``tuning``, ``external``, ``other``; None when
        the verdict cannot name one.
    cycle : Cycle or None
        Stage 1: the limit cycle found, if any.
    cause_probabilities : CauseReading or None
        Stage 2: P of each cause of the cycle [-] (None without a cycle or without
        the cause model), and how typical the evidence is of the most likely cause
        (its ``atypicality``, in the JSON as ``cause_atypicality``; above 1 the
        reasons say that the call is an extrapolation).
    runner_up : Cause or None
        The most likely cause after ``cause``; for an undecided loop the most likely
        cause other than the valve (the alternative the verdict could not rule out).

    ``probability`` is P(the valve causes the cycle) when stage 2 decides (a cycle,
    no mv), 0 for a loop without a cycle and without direct stick-slip, else the
    friction model's P(stiction) (kept in ``evidence.p_friction`` in every case).
    """

    status: VerdictStatus
    detected: bool | None
    confidence: float
    reasons: tuple[str, ...]
    evidence: VerdictEvidence = field(repr=False)
    probability: float | None = None
    cause: Cause | None = None
    cycle: Cycle | None = None
    cause_probabilities: CauseReading | None = None
    runner_up: Cause | None = None

    @property
    def by_cause(self) -> bool:
        """Stage 2 decided: the loop has a cycle, no mv, and the cause model read it
        (:func:`stictiondiag.stiction.verdict.stiction_verdict`)."""
        return (
            self.cycle is not None
            and self.cycle.present
            and self.cause_probabilities is not None
            and not self.evidence.has_mv
        )

    @property
    def levels(self) -> tuple[float, float]:
        """The levels the verdict decided with on :attr:`probability`: at or below the
        first no stiction, at or above the second stiction [-] (P(the valve causes
        the cycle) where :attr:`by_cause`, else P(stiction))."""
        ev = self.evidence
        if self.by_cause:
            return 1.0 - ev.valve_level, ev.valve_level
        return ev.no_stiction_level, ev.stiction_level

    def to_dict(self) -> dict:
        probs = self.cause_probabilities
        return _plain(
            {
                "status": self.status,
                "verdict": self.status,
                "detected": self.detected,
                "confidence": self.confidence,
                "probability": self.probability,
                "cause": self.cause,
                "cause_probabilities": None if probs is None else probs.to_dict(),
                "cause_atypicality": None if probs is None else probs.atypicality,
                "runner_up": self.runner_up,
                "cycle": None if self.cycle is None else self.cycle.to_dict(),
                "reasons": list(self.reasons),
                "evidence": self.evidence.to_dict(),
            }
        )
