"""Findings in words (stictiondiag.apps.findings), from analysis dicts."""

from __future__ import annotations

import pytest

from stictiondiag.apps.findings import findings_from_dict, param_text


def _dict(status="stiction", p=0.97, S=5.0, J=2.0, compensation=None, gap=None, **tags):
    return {
        "loop": "LIC200",
        "tags": {"loop_type": "level", "has_mv": True, **tags},
        "oscillation": {"pv": {"present": True, "period_s": 1000.0}},
        "stiction": {
            "status": status,
            "probability": p,
            "confidence": p if status != "no_stiction" else 1 - p,
            "S": S,
            "J": J,
            "S_interval": [S * 0.95, S * 1.05],
            "J_interval": [J * 0.95, J * 1.05],
            "details": {"determinacy": {"S": "well determined", "J": "well determined"}},
            "evidence": {"stiction_level": 0.7, "no_stiction_level": 0.3},
        },
        "compensation": compensation,
        "gap": gap,
    }


COMPENSATION = {
    "applicable": True,
    "reason": "a band of 0.8 pv units stops the cycle",
    "band_pv": 0.8,
    "band_pct_of_amplitude": 95.0,
    "offset_pv": 0.79,
}


def test_sticky_valve_says_what_to_do_with_the_simulated_band():
    f = findings_from_dict(
        _dict(
            compensation=COMPENSATION,
            gap={"effect": "quantization", "before": 27.6, "shrink_pct": 96, "metric": "x"},
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
    f = findings_from_dict(_dict(status, p))
    assert f"P(stiction) = {p:.2f} (decision levels 0.3 and 0.7)" in f.headline
    assert "confidence" not in f.text()
    assert words in f.meaning
    assert f.compensation == ""  # a band is offered only for a sticky valve


def test_poorly_determined_parameter_is_marked():
    d = _dict(J=5.78)
    d["stiction"]["J_interval"] = [2.89, 5.78]
    d["stiction"]["details"]["determinacy"]["J"] = (
        "poorly determined (interval reaches the search limit)"
    )
    f = findings_from_dict(d)
    assert f.poorly_determined == ("J",)
    assert f.J_text == (
        "J = 5.78 % of travel (poorly determined: interval 2.89\u20135.78 at the search edge)"
    )
    assert any("J is poorly determined" in x for x in f.limits)
    assert param_text(d["stiction"], "S") == "S = 5 % (interval 4.75\u20135.25)"


def test_zero_estimate_pinned_at_zero_is_not_poorly_determined():
    d = _dict("no_stiction", 0.02, S=0.0, J=0.0)
    d["stiction"]["details"]["determinacy"] = {"S": "poorly determined", "J": "poorly determined"}
    assert findings_from_dict(d).poorly_determined == ()


def test_what_the_data_cannot_tell():
    d = _dict(has_mv=False, loop_type="other")
    limits = findings_from_dict(d).limits
    assert any("mv is not recorded" in x for x in limits)
    assert any("loop type was not given" in x for x in limits)
    d = _dict(loop_type="level", loop_type_source="tag prefix LIC")
    assert not any("loop type" in x for x in findings_from_dict(d).limits)
