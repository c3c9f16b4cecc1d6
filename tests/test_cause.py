"""Stage 1 of the verdict (stictiondiag.stiction.cause): a loop without a limit cycle
gets a definite answer, unless the valve's own movement shows stick-slip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stictiondiag.stiction.cause import (
    CAUSE_WORDS,
    CAUSES,
    NO_CYCLE_REASON,
    SETPOINT_CARRIES,
    cycle_text,
    direct_stick_slip,
    find_cycle,
    setpoint_share,
)
from stictiondiag.stiction.fit_result import BlockCosts, StictionFit
from stictiondiag.stiction.probability import FEATURES
from stictiondiag.stiction.verdict import stiction_verdict


class _Osc:
    def __init__(self, present, period_s=None, regularity=None, n_cycles=None):
        self.present = present
        self.period_s = period_s
        self.regularity = regularity
        self.n_cycles = n_cycles
        self.reason = None if present else "irregular"


def _fit():
    return StictionFit(
        S=1.0,
        J=0.5,
        S_scaled=0.5,
        J_scaled=0.25,
        S_interval=(0.5, 1.5),
        J_interval=(0.0, 1.0),
        method="hammerstein",
        mv_model=np.linspace(0.0, 10.0, 50),
        n_slips=6,
        cost=6.0,
        linear_cost=8.0,
        block_costs=BlockCosts(10, np.ones(6), 8.0 / 6.0 * np.ones(6)),
    )


def _constant_model(p: float) -> dict:
    # P(friction) = p whatever the features (zero coefficients).
    part = {
        "mean": [0.0] * len(FEATURES),
        "scale": [1.0] * len(FEATURES),
        "coef": [0.0] * len(FEATURES),
        "intercept": math.log(p / (1 - p)),
    }
    return {"features": list(FEATURES), "parts": {"op_pv": part, "mv": part}}


def test_cycle_found_in_pv_first_then_op():
    c = find_cycle(_Osc(True, 100.0, 3.0, 12.0), _Osc(True, 50.0, 2.0, 24.0), short_record=False)
    assert (c.present, c.signal, c.period_s, c.n_cycles) == (True, "pv", 100.0, 12.0)
    c = find_cycle(_Osc(False), _Osc(True, 50.0, 2.0, 24.0), short_record=False)
    assert (c.present, c.signal, c.period_s) == (True, "op", 50.0)


def test_short_record_counts_as_a_cycle_to_explain():
    # Two to three periods of a regular pattern: too few for the test, not a "no".
    c = find_cycle(_Osc(False), _Osc(False), short_record=True)
    assert c.present and c.short_record and c.signal is None


def test_no_cycle_is_a_definite_no_stiction_with_its_reason():
    # Even with P(friction) = 0.9 from the fit, no cycle and no direct evidence
    # (support 1.0 but the split halves could not be fitted) means the valve
    # drives no oscillation.
    flat = _Osc(False)
    v = stiction_verdict(
        _fit(),
        flat,
        oscillation_op=flat,
        cycle=find_cycle(flat, flat, short_record=False),
        model=_constant_model(0.9),
    )
    assert v.status == "no_stiction" and v.detected is False
    assert v.cause == "none"
    assert v.reasons[0].startswith(NO_CYCLE_REASON)
    # S and J are still reported.
    assert any(r.startswith("S = 1 %") for r in v.reasons)
    assert 0.5 <= v.confidence <= 1.0
    assert v.to_dict()["cycle"]["present"] is False


def _constant_cause_model(probs: dict[str, float]) -> dict:
    # P of each cause whatever the features (zero coefficients, log-P intercepts).
    return {
        "classes": list(CAUSES),
        "features": ["improvement"],
        "mean": [0.0],
        "scale": [1.0],
        "coef": [[0.0] * len(CAUSES)],
        "intercept": [math.log(probs[c]) for c in CAUSES],
    }


def _cycling_verdict(
    p_friction: float, probs: dict[str, float], *, has_mv: bool, short_record: bool = False
):
    # The verdict of a loop with a cycle in pv, under constant friction and cause models.
    osc, osc_op = _Osc(True, 100.0, 3.0, 12.0), _Osc(False)
    return stiction_verdict(
        _fit(),
        osc,
        oscillation_op=osc_op,
        cycle=find_cycle(osc, osc_op, short_record=short_record),
        has_mv=has_mv,
        model=_constant_model(p_friction),
        cause_model=_constant_cause_model(probs),
    )


@pytest.mark.parametrize(
    ("p_friction", "probs", "status", "cause", "runner"),
    [
        # P(valve) above the level: stiction, whatever the friction model says.
        (0.1, {"valve": 0.65, "tuning": 0.1, "external": 0.2, "other": 0.05}, "stiction",
         "valve", "external"),
        # P(valve) below 1 - level: no stiction, the most likely other cause named.
        (0.9, {"valve": 0.35, "tuning": 0.5, "external": 0.1, "other": 0.05}, "no_stiction",
         "tuning", "valve"),
        # Below 1 - level while still the single most likely cause: the cause named
        # is the most likely other one, and said to be.
        (0.9, {"valve": 0.38, "tuning": 0.32, "external": 0.2, "other": 0.1}, "no_stiction",
         "tuning", "valve"),
        # Between the levels: undecided, no cause named, the two leading ones reported.
        (0.9, {"valve": 0.5, "tuning": 0.1, "external": 0.3, "other": 0.1}, "inconclusive",
         None, "external"),
    ],
)  # fmt: skip
def test_a_cycle_without_mv_is_decided_by_its_cause(p_friction, probs, status, cause, runner):
    # Stage 2 decides by P(the valve causes the cycle) against VALVE_LEVEL (0.6);
    # P(stiction) of the friction model stays in the evidence and the reasons.
    v = _cycling_verdict(p_friction, probs, has_mv=False)
    assert (v.status, v.cause, v.runner_up) == (status, cause, runner)
    assert v.by_cause and v.levels == pytest.approx((0.4, 0.6), abs=1e-12)
    assert v.probability == pytest.approx(probs["valve"], abs=1e-9)
    assert sum(v.cause_probabilities.to_dict().values()) == pytest.approx(1.0, abs=1e-9)
    assert v.evidence.p_friction == pytest.approx(p_friction, abs=1e-9)
    assert v.reasons[0].startswith(f"P(the valve causes the cycle) = {probs['valve']:.2f}")
    top = max(probs, key=probs.get)
    named = cause or top
    which = "most likely cause" if named == top else "most likely other cause"
    assert f"{which}: {CAUSE_WORDS[named]} ({probs[named]:.2f})" in v.reasons[0]
    assert any(r.startswith(f"P that the valve has friction (friction model) = {p_friction:.2f}")
               for r in v.reasons)  # fmt: skip


@pytest.mark.parametrize(("p_valve", "status"), [(0.35, "inconclusive"), (0.65, "stiction")])
def test_a_short_record_does_not_clear_the_valve(p_valve, status):
    # Fewer periods than the oscillation test needs: the shape statistics are neutral,
    # so a low P(valve) is missing evidence and the loop stays undecided, saying why
    # (with a full record the same P(valve) 0.35 is no_stiction, test above); a high
    # one still calls stiction.
    probs = {"valve": p_valve, "tuning": 1.0 - p_valve - 0.02, "external": 0.01, "other": 0.01}
    v = _cycling_verdict(0.5, probs, has_mv=False, short_record=True)
    assert v.status == status
    assert v.probability == pytest.approx(p_valve, abs=1e-9)
    assert ("too few to clear the valve" in v.reasons[0]) is (status == "inconclusive")


@pytest.mark.parametrize(("p_friction", "status"), [(0.9, "stiction"), (0.5, "inconclusive")])
def test_a_cycle_with_mv_is_decided_by_P(p_friction, status):
    # With the valve position recorded the friction model's P decides (the cause model
    # is trained on loops without mv), against its own levels 0.3 and 0.7.
    probs = {"valve": 0.1, "tuning": 0.3, "external": 0.5, "other": 0.1}
    v = _cycling_verdict(p_friction, probs, has_mv=True)
    assert v.status == status and not v.by_cause
    assert v.levels == pytest.approx((0.3, 0.7), abs=1e-12)
    assert v.probability == pytest.approx(p_friction, abs=1e-9)


@pytest.mark.parametrize(
    ("features", "has_mv", "p", "called"),
    [
        ({}, True, 0.9, True),  # recorded mv: direct
        ({}, True, 0.6, False),  # recorded mv, but friction not favoured 7 to 3
        ({"kano": 1.0}, False, 0.8, True),  # stuck sections
        ({"kano": 0.0}, False, 0.8, False),
        (
            {"support": 0.97, "halves_missing": 0.0, "halves_improvement": 0.3},
            False,
            0.8,
            True,
        ),
        (  # one half does not improve: not over the whole record
            {"support": 0.97, "halves_missing": 0.0, "halves_improvement": 0.05},
            False,
            0.8,
            False,
        ),
    ],
)
def test_direct_stick_slip_rules(features, has_mv, p, called):
    got = direct_stick_slip(features, has_mv, p, min_improvement=0.1)
    assert (got is not None) is called


def test_setpoint_share_measures_how_much_of_the_cycle_the_set_point_carries():
    # Band-limited around the cycle, a set point that is pv's own cycle carries all of
    # it (1), one at half its amplitude half (the band-pass is linear, so the ratio is
    # exact up to round-off; 1e-6); a set point that holds still carries none (None:
    # nothing moves), and a step change outside the band little.
    t = np.arange(3000.0)
    pv = np.sin(2 * np.pi * t / 100.0)
    assert setpoint_share(pv, pv, 1.0, 100.0) == pytest.approx(1.0, abs=1e-6)
    assert setpoint_share(0.5 * pv, pv, 1.0, 100.0) == pytest.approx(0.5, abs=1e-6)
    assert setpoint_share(np.zeros_like(pv), pv, 1.0, 100.0) is None
    assert setpoint_share(None, pv, 1.0, 100.0) is None
    assert setpoint_share(pv, pv, 1.0, None) is None
    step = np.where(t < 1500, 0.0, 1.0)
    assert setpoint_share(step, pv, 1.0, 100.0) < SETPOINT_CARRIES
    cycle = find_cycle(_Osc(True, 100.0, 3.0, 30.0), _Osc(False), short_record=False,
                       setpoint_share=0.9)  # fmt: skip
    assert cycle.setpoint_carries and "the set point carries it (0.90" in cycle_text(cycle)
