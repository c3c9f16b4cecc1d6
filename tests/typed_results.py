"""Small typed results for the renderer tests: an :class:`Analysis` built field by field.

The renderers (findings, the loop page, the terminal summary) take the typed result;
these builders give them one with exactly the values a test sets, without running an
analysis.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from stictiondiag.gap.effects.base import EffectParams
from stictiondiag.gap.result import Candidate, GapDiagnosis
from stictiondiag.io.tags import Tags
from stictiondiag.result import Analysis
from stictiondiag.signals.oscillation import Oscillation
from stictiondiag.stiction.cause import Cause, CauseReading, Cycle
from stictiondiag.stiction.fit_result import Determinacy, StictionFit
from stictiondiag.stiction.verdict_result import Verdict, VerdictEvidence, VerdictStatus

#: The decision levels the tests' verdicts carry in their evidence [-].
LEVELS = {"stiction_level": 0.7, "no_stiction_level": 0.3}


def make_evidence(p=0.97, *, has_mv=True, oscillating=True, **fields) -> VerdictEvidence:
    """A verdict's evidence with P(friction) ``p``, the :data:`LEVELS` and a cycle when
    ``oscillating``; any other field as given."""
    cycle = Cycle(oscillating, "pv" if oscillating else None, 1000.0, 1.0, 10.0)
    evidence = VerdictEvidence(
        p_friction=p,
        cause_probabilities=None,
        features={},
        contributions={},
        improvement=0.5,
        improvement_interval=(0.4, 0.6),
        support=1.0,
        min_improvement=0.1,
        n_blocks=10,
        has_mv=has_mv,
        short_record=False,
        cycle=cycle,
        direct_stick_slip=None,
        classic={},
        valve_level=0.6,
        **LEVELS,
    )
    return dataclasses.replace(evidence, **fields)


def make_gap(effect="quantization", before=0.5, after=0.2, shrink_pct=60.0, candidates=()):
    """A gap diagnosis with the given figures [%] and candidate effects."""
    return GapDiagnosis(
        metric="nrmse",
        definition="test",
        before=before,
        after=after,
        shrink_pct=shrink_pct,
        effect=effect,
        runner_up="none",
        margin=10.0,
        candidates=tuple(candidates),
    )


def make_candidate(effect, after=0.3, shrink_pct=40.0, params: EffectParams | None = None):
    """One candidate effect of a gap diagnosis (parameters none unless given)."""
    return Candidate(
        effect=effect,
        variant="",
        after=after,
        shrink_pct=shrink_pct,
        params=params or EffectParams(),
        n_params=1,
        heldout=after,
        penalised_score=after,
        accepted=True,
    )


def make_analysis(
    loop="LIC200",
    *,
    status="stiction",
    p=0.97,
    S=5.0,
    J=2.0,
    S_interval=None,
    J_interval=None,
    determinacy=("well determined", "well determined"),
    method="mv_segments",
    reasons=(),
    evidence: dict | None = None,
    has_mv=True,
    loop_type="level",
    loop_type_source="",
    names=None,
    n=1000,
    ts=1.0,
    oscillating=True,
    compensation=None,
    gap=None,
    warnings=(),
    op_scale="percent",
    causes: dict | None = None,
    cause=None,
    runner_up=None,
    short_record=False,
    setpoint_share=None,
) -> Analysis:
    """An :class:`Analysis` whose parts hold the values given (intervals default to
    +-5 % of the estimate; ``determinacy`` is the words for S and J, None for none).
    ``causes``: stage 2's ``{cause: P}``, with the verdict's ``cause`` and
    ``runner_up`` (the verdict then has a cycle, from a record of fewer than three
    cycles with ``short_record``, its set point carrying ``setpoint_share`` of it)."""
    zeros = np.zeros(n)
    tags = Tags(
        time=np.arange(n) * ts,
        pv=zeros,
        op=zeros,
        mv=zeros if has_mv else None,
        sp=None,
        ts=ts,
        names=dict(names or {"pv": "pv", "op": "op"}),
        source=f"/data/{loop}.csv",
        loop_type=loop_type,
        loop_type_source=loop_type_source,
        op_scale=op_scale,
    )
    fit = StictionFit(
        S=S,
        J=J,
        S_scaled=S / 10,
        J_scaled=J / 10,
        S_interval=S_interval if S_interval is not None else (S * 0.95, S * 1.05),
        J_interval=J_interval if J_interval is not None else (J * 0.95, J * 1.05),
        method=method,
        mv_model=zeros,
        n_slips=4,
        cost=1.0,
        linear_cost=2.0,
        S_determinacy=Determinacy.of(determinacy[0]),
        J_determinacy=Determinacy.of(determinacy[1]),
    )
    verdict = Verdict(
        status=VerdictStatus(status),
        detected={"stiction": True, "no_stiction": False}.get(status),
        confidence=p if status != "no_stiction" else 1 - p,
        reasons=tuple(reasons),
        evidence=make_evidence(p, has_mv=has_mv, oscillating=oscillating, **(evidence or {})),
        probability=p,
        cause=None if cause is None else Cause(cause),
        cycle=(
            Cycle(True, "pv", 1000.0, 1.0, 10.0, short_record, setpoint_share)
            if causes is not None
            else None
        ),
        cause_probabilities=None if causes is None else CauseReading.of(causes),
        runner_up=None if runner_up is None else Cause(runner_up),
    )
    osc = Oscillation(oscillating, 1000.0 if oscillating else None, 1.0, 5.0, 10.0)
    return Analysis(
        tags=tags,
        oscillation=osc,
        oscillation_op=osc,
        fit=fit,
        verdict=verdict,
        gap=gap,
        warnings=tuple(warnings),
        compensation=compensation,
    )
