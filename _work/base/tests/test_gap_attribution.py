"""Attribution of a replay's departure: the fitted loop (closed-loop refit) or an effect."""

from __future__ import annotations

import pytest

from stictiondiag.gap.attribution import LARGE_GAP_PCT, attribute_gap


def _replay(accepted, c0, c1, S0=2.0, J0=0.5, S1=3.0, J1=1.0):
    refit = {
        "accepted": accepted,
        "cost_open_loop": c0,
        "cost": c1,
        "S_open_loop": S0,
        "J_open_loop": J0,
        "S": S1 if accepted else S0,
        "J": J1 if accepted else J0,
        "reason": "no refit lowers the cycle mismatch",
    }
    return {"settings": {"refit": refit}}


def _gap(effect, before, after, not_assessed=(), candidates=()):
    return {
        "effect": effect,
        "before": before,
        "after": after,
        "shrink_pct": 100.0 * (1 - after / before) if before else 0.0,
        "not_assessed": list(not_assessed),
        "candidates": list(candidates),
    }


def test_fitted_loop_named_when_the_refit_removes_most_of_the_mismatch():
    a = attribute_gap(_replay(True, 2.0, 0.2), _gap("none", 10.0, 10.0))
    assert a["cause"] == "fitted_loop"
    # 1 - 0.2 / 2.0 = 90 % of the mismatch removed, exactly.
    assert a["identification"]["removed_pct"] == pytest.approx(90.0, abs=1e-9)
    assert "S 2.00 to 3.00" in a["text"] and "main cause" in a["text"]


def test_effect_named_when_the_loop_reproduces_the_cycle():
    a = attribute_gap(_replay(False, 0.001, 0.001), _gap("quantization", 20.0, 5.0))
    assert a["cause"] == "effect"
    assert "quantization" in a["text"] and "not the cause" in a["text"]


def test_large_gap_without_effect_says_why_and_what_is_left_open():
    cands = [{"effect": "actuator_lag", "after": 70.0}, {"effect": "quantization", "after": 60.0}]
    gap = _gap("none", LARGE_GAP_PCT + 30.0, LARGE_GAP_PCT + 30.0, ("asymmetry",), cands)
    a = attribute_gap(_replay(False, 3.0, 3.0), gap)
    assert a["cause"] == "unexplained"
    assert "quantization" in a["text"]  # the closest candidate, and why it is not named
    assert a["open_gap_pct"] == LARGE_GAP_PCT + 30.0
    assert "asymmetry" in a["text"] and "open to them" in a["text"]


def test_large_gap_without_effect_names_the_failed_test_and_where_it_lies():
    """Issue 27: a gap over 50 % left with 'none' says why in words: where the gap
    lies, the closest candidate and which of its tests failed."""
    sig = {"op": {"before": 5.0}, "pv": {"before": 70.0}, "mv": {"before": 1.0}}
    c = {
        "effect": "valve_characteristic",
        "after": 20.0,
        "heldout": 60.0,
        "n_params": 1,
        "params": {"gain_change_p": 0.2},
    }
    gap = _gap("none", 80.0, 80.0, candidates=[c])
    gap["breakdown"] = {"signal": sig}
    gap["heldout_before"] = 65.0
    text = attribute_gap(None, gap)["text"]
    assert "most of it is in pv" in text
    assert "gain_change: p = 0.2" in text
    # Signature passes, held-out worse than the base: that is the reason given.
    c["params"] = {"gain_change_p": 0.001}
    c["heldout"] = 70.0
    text = attribute_gap(None, gap)["text"]
    assert "does no better than the two-parameter replay (70 % against 65 %)" in text
    # No candidate lowers the record's gap, and the gap is in the controller's replay.
    sig["op"]["before"] = 90.0
    c["after"] = 85.0
    text = attribute_gap(None, gap)["text"]
    assert "in op, the controller's replay" in text and "no candidate lowers it" in text
