"""Attribution of a replay's departure: the fitted loop (closed-loop refit) or an effect."""

from __future__ import annotations

import pytest

from stictiondiag.gap.attribution import LARGE_GAP_PCT, GapCause, attribute_gap
from stictiondiag.gap.breakdown import Breakdown, PerSignal, SignalGap
from stictiondiag.gap.effects.base import EffectParams
from stictiondiag.gap.effects.valve_characteristic import (
    CharacteristicParams,
    CharacteristicSide,
    CurveFamily,
)
from stictiondiag.gap.result import Candidate, GapDiagnosis
from stictiondiag.models.processes import FOPTD
from stictiondiag.replay.refit import ClosedLoopRefit


def _refit(accepted, c0, c1, S0=2.0, J0=0.5, S1=3.0, J1=1.0):
    return ClosedLoopRefit(
        S_open_loop=S0,
        J_open_loop=J0,
        S=S1 if accepted else S0,
        J=J1 if accepted else J0,
        process_open_loop=FOPTD(1.0, 10.0),
        process=FOPTD(1.0, 10.0),
        cost_open_loop=c0,
        cost=c1,
        accepted=accepted,
        simulations=10,
        reason="no refit lowers the cycle mismatch",
    )


def _candidate(effect, after, heldout=float("nan"), n_params=1, params=None):
    return Candidate(
        effect=effect,
        variant="",
        after=after,
        shrink_pct=0.0,
        params=params or EffectParams(),
        n_params=n_params,
        heldout=heldout,
        penalised_score=after,
        accepted=False,
    )


def _gap(effect, before, after, not_assessed=(), candidates=(), breakdown=None, heldout=0.0):
    return GapDiagnosis(
        metric="nrmse",
        definition="test",
        before=before,
        after=after,
        shrink_pct=100.0 * (1 - after / before) if before else 0.0,
        effect=effect,
        runner_up=None,
        margin=0.0,
        candidates=tuple(candidates),
        breakdown=breakdown,
        not_assessed=tuple(not_assessed),
        heldout_before=heldout,
    )


def test_fitted_loop_named_when_the_refit_removes_most_of_the_mismatch():
    a = attribute_gap(_refit(True, 2.0, 0.2), _gap("none", 10.0, 10.0))
    assert a.cause is GapCause.FITTED_LOOP
    # 1 - 0.2 / 2.0 = 90 % of the mismatch removed, exactly.
    assert a.identification.removed_pct == pytest.approx(90.0, abs=1e-9)
    assert "S 2.00 to 3.00" in a.text and "main cause" in a.text


def test_effect_named_when_the_loop_reproduces_the_cycle():
    a = attribute_gap(_refit(False, 0.001, 0.001), _gap("quantization", 20.0, 5.0))
    assert a.cause is GapCause.EFFECT
    assert "quantization" in a.text and "not the cause" in a.text


def test_large_gap_without_effect_says_why_and_what_is_left_open():
    cands = [_candidate("actuator_lag", 70.0), _candidate("quantization", 60.0)]
    gap = _gap("none", LARGE_GAP_PCT + 30.0, LARGE_GAP_PCT + 30.0, ("asymmetry",), cands)
    a = attribute_gap(_refit(False, 3.0, 3.0), gap)
    assert a.cause is GapCause.UNEXPLAINED
    assert "quantization" in a.text  # the closest candidate, and why it is not named
    assert a.open_gap_pct == LARGE_GAP_PCT + 30.0
    assert "asymmetry" in a.text and "open to them" in a.text


def test_large_gap_without_effect_names_the_failed_test_and_where_it_lies():
    """Issue 27: a gap over 50 % left with 'none' says why in words: where the gap
    lies, the closest candidate and which of its tests failed."""
    before = {"op": 5.0, "pv": 70.0, "mv": 1.0}

    def text_of(after, heldout, p):
        params = CharacteristicParams(
            0.5, CurveFamily.EXPONENTIAL, CharacteristicSide.PROCESS, 0.1, gain_change_p=p
        )
        c = _candidate("valve_characteristic", after, heldout, 1, params)
        sig = PerSignal.of({s: SignalGap(v, v, 0.0) for s, v in before.items()})
        breakdown = Breakdown(signal=sig)
        gap = _gap("none", 80.0, 80.0, candidates=[c], breakdown=breakdown, heldout=65.0)
        return attribute_gap(None, gap).text

    text = text_of(20.0, 60.0, 0.2)
    assert "most of it is in pv" in text
    assert "gain_change: p = 0.2" in text
    # Signature passes, held-out worse than the base: that is the reason given.
    text = text_of(20.0, 70.0, 0.001)
    assert "does no better than the two-parameter replay (70 % against 65 %)" in text
    # No candidate lowers the record's gap, and the gap is in the controller's replay.
    before["op"] = 90.0
    text = text_of(85.0, 70.0, 0.001)
    assert "in op, the controller's replay" in text and "no candidate lowers it" in text
