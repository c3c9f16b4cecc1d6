"""Findings in words (stictiondiag.apps.findings), from typed analyses."""

from __future__ import annotations

import pytest
from typed_results import make_analysis, make_gap

from stictiondiag.apps.findings import findings_of, param_text
from stictiondiag.replay.compensation import Compensation
from stictiondiag.stiction.cause import CAUSE_WORDS
from stictiondiag.stiction.fit_result import Determinacy

COMPENSATION = Compensation(
    applicable=True,
    reason="a band of 0.8 pv units stops the cycle",
    band=0.8,
    band_pct_of_amplitude=95.0,
    offset=0.79,
)


def test_sticky_valve_says_what_to_do_with_the_simulated_band():
    f = findings_of(
        make_analysis(
            compensation=COMPENSATION,
            gap=make_gap(effect="quantization", before=27.6, after=1.1, shrink_pct=96),
        )
    )
    assert f.headline == "STICTION, P(stiction) = 0.97 (decision levels 0.3 and 0.7)"
    assert f.meaning.startswith("valve sticky, about 5 % of travel")
    assert "undershoot, Fig. 11b" in f.meaning  # J < S
    assert f.action.startswith("schedule a valve inspection")
    assert "variable-integral band of 0.8 pv units" in f.compensation
    assert "offset of 0.79 pv units" in f.compensation
    assert "quantization" in f.gap and "96 %" in f.gap
    frame = f.to_pandas()
    assert list(frame.columns) == ["loop", "topic", "text"]
    assert {"verdict", "valve", "action", "compensation", "gap", "cannot tell"} <= set(
        frame["topic"]
    )
    assert f.text().splitlines()[0].startswith("verdict")


@pytest.mark.parametrize(
    "status,p,words",
    [
        ("inconclusive", 0.55, "neither confirm nor rule out"),
        ("no_stiction", 0.02, "not explained by a sticky valve"),
    ],
)
def test_undecided_and_negative_verdicts_give_the_probability(status, p, words):
    """Issue 18: no "confidence 1.00" on an inconclusive or no-stiction verdict."""
    f = findings_of(make_analysis(status=status, p=p))
    assert f"P(stiction) = {p:.2f} (decision levels 0.3 and 0.7)" in f.headline
    assert "confidence" not in f.text()
    assert words in f.meaning
    assert f.compensation == ""  # a band is offered only for a sticky valve


def test_poorly_determined_parameter_is_marked():
    a = make_analysis(
        J=5.78, J_interval=(2.89, 5.78), determinacy=("well determined", Determinacy.OPEN.value)
    )
    f = findings_of(a)
    assert f.poorly_determined == ("J",)
    assert f.J_text == (
        "J = 5.78 % of travel (poorly determined: interval 2.89\u20135.78 at the search edge)"
    )
    assert any("J is poorly determined" in x for x in f.limits)
    assert param_text(a.fit, "S") == "S = 5 % (interval 4.75\u20135.25)"


def test_zero_estimate_pinned_at_zero_is_not_poorly_determined():
    a = make_analysis(
        status="no_stiction",
        p=0.02,
        S=0.0,
        J=0.0,
        determinacy=("poorly determined", "poorly determined"),
    )
    assert findings_of(a).poorly_determined == ()


def test_what_the_data_cannot_tell():
    limits = findings_of(make_analysis(has_mv=False, loop_type="other")).limits
    assert any("mv is not recorded" in x for x in limits)
    assert any("loop type was not given" in x for x in limits)
    a = make_analysis(loop_type="level", loop_type_source="tag prefix LIC")
    assert not any("loop type" in x for x in findings_of(a).limits)


def test_findings_of_a_result_read_back_are_the_same():
    """The findings of a result read back from its JSON (the typed round trip) are
    those of the result itself: nothing is read from text."""
    from stictiondiag.result import Analysis

    a = make_analysis(compensation=COMPENSATION, gap=make_gap())
    assert findings_of(Analysis.from_json(a.to_json())) == findings_of(a)


@pytest.mark.parametrize(
    ("status", "p_valve", "cause", "runner", "meaning", "action"),
    [
        ("stiction", 0.8, "valve", "tuning", "valve sticky", "inspect the valve"),
        ("no_stiction", 0.1, "external", "valve", "most likely an external oscillating",
         "look upstream"),
        ("inconclusive", 0.5, None, "tuning", "the valve (P 0.50) and the controller's tuning "
         "(P 0.30) are too close", "test the valve directly"),
    ],
)  # fmt: skip
def test_a_cycle_without_mv_is_read_by_its_cause(status, p_valve, cause, runner, meaning, action):
    # Stage 2 decided (a cycle, no mv): the headline gives P(the valve causes the
    # cycle) with its levels 0.4 and 0.6 and the two leading causes; the meaning and
    # the action follow the cause named (an undecided loop names the two candidates).
    rest = {"valve": p_valve, "tuning": 0.3, "external": 0.0, "other": 0.0}
    if cause == "external":
        rest = {"valve": p_valve, "tuning": 0.1, "external": 0.8, "other": 0.0}
    elif status == "stiction":
        rest = {"valve": p_valve, "tuning": 0.2, "external": 0.0, "other": 0.0}
    a = make_analysis(
        status=status, p=p_valve, has_mv=False, method="hammerstein", causes=rest,
        cause=cause, runner_up=runner,
    )  # fmt: skip
    f = findings_of(a)
    assert f"P(the valve causes the cycle) = {p_valve:.2f} (decision levels 0.4 and 0.6)" in (
        f.headline
    )
    assert meaning in f.meaning
    assert action in f.action
    # The headline names the verdict's own cause, never one it did not name.
    named = "undecided between the valve" if cause is None else f"cause: {CAUSE_WORDS[cause]}"
    assert named in f.headline and f"{CAUSE_WORDS[runner]} (P {rest[runner]:.2f})" in f.headline


def test_a_short_record_says_it_cannot_clear_the_valve():
    # Stage 2 left undecided a loop whose P(valve) is below the lower level because
    # its record holds fewer than three cycles: the findings say so and ask for a
    # longer record, not "too close to call".
    causes = {"valve": 0.3, "tuning": 0.7, "external": 0.0, "other": 0.0}
    a = make_analysis(
        status="inconclusive", p=0.3, has_mv=False, method="hammerstein", causes=causes,
        runner_up="tuning", short_record=True,
    )  # fmt: skip
    f = findings_of(a)
    assert "too few cycles to clear the valve (P 0.30)" in f.headline
    assert "fewer than three cycles" in f.meaning and "too close" not in f.meaning
    assert f.action.startswith("export a record of at least three cycles")
    # The same reading from a full record is the ordinary undecided one.
    a = make_analysis(
        status="inconclusive", p=0.3, has_mv=False, method="hammerstein", causes=causes,
        runner_up="tuning",
    )  # fmt: skip
    assert "undecided between the valve" in findings_of(a).headline


@pytest.mark.parametrize(("share", "upstream"), [(0.9, False), (0.2, True)])
def test_an_external_cycle_through_the_set_point_points_at_its_writer(share, upstream):
    # An external cycle that the set point carries (0.9 of pv's spread at the cycle,
    # at or above SETPOINT_CARRIES 0.5) comes from the loop that writes the set point
    # (a cascade master): the action says so. A still set point (0.2) keeps the
    # general "look upstream".
    causes = {"valve": 0.1, "tuning": 0.1, "external": 0.8, "other": 0.0}
    a = make_analysis(
        status="no_stiction", p=0.1, has_mv=False, method="hammerstein", causes=causes,
        cause="external", runner_up="valve", setpoint_share=share,
    )  # fmt: skip
    f = findings_of(a)
    assert f.action.startswith("look upstream") is upstream
    assert ("the loop that writes this set point" in f.action) is not upstream
    assert ("through its set point, which carries 0.90" in f.meaning) is not upstream
