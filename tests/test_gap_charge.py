"""The charge per parameter of a candidate that acts on several signals."""

from __future__ import annotations

import math

import pytest

from stictiondiag.gap.context import build_context, signals_of
from stictiondiag.gap.diagnose import diagnose_gap
from stictiondiag.gap.selection import bic_gain, signals_charge
from stictiondiag.models.synthetic import generate_case


def test_one_signal_is_charged_its_own_share():
    # One signal: the charge is that signal's, whatever it gains.
    assert signals_charge({"mv": 3.0}, {"mv": 5.0}) == pytest.approx(5.0)
    assert signals_charge({"mv": 30.0}, {"mv": 5.0}) == pytest.approx(5.0)


def test_each_signal_is_charged_in_the_units_of_its_own_error():
    # op's error 46 with a share of 0.11 (charge 4.8), pv's 4940 with 0.034 (charge
    # 165): a step that takes 36 off op and 100 off pv pays for itself on op alone
    # (ratio 36/4.8 + 100/165 = 8.1 >= 1), so the least total gain is 136/8.1 = 16.8,
    # not the charges' sum 170.  Tolerance: the rounding of the figures here.
    charges = {"op": bic_gain(46.0, 1, 0.11), "pv": bic_gain(4940.0, 1, 0.034)}
    gains = {"op": 36.0, "pv": 100.0}
    ratio = sum(gains[s] / charges[s] for s in gains)
    assert ratio == pytest.approx(8.1, abs=0.05)
    assert signals_charge(gains, charges) == pytest.approx(136.0 / ratio)
    assert signals_charge(gains, charges) == pytest.approx(16.8, abs=0.1)
    # Gains that do not pay on either signal: the charges' sum (the candidate fails).
    small = {"op": 1.0, "pv": 10.0}
    assert signals_charge(small, charges) == pytest.approx(sum(charges.values()))
    # A signal made worse counts against the others.
    assert signals_charge({"op": 6.0, "pv": -200.0}, charges) == pytest.approx(
        sum(charges.values())
    )
    assert math.isfinite(signals_charge({"op": 6.0, "pv": 0.0}, charges))


def test_historian_rounding_of_pv_is_named_on_an_integrating_loop():
    """Development seed 3, case 18: pv of an integrating loop rounded by the historian
    to 0.035 (the controller read it unrounded).  The rounding explains 75 % of the
    controller replay's held-out op error, consistently in every block, and 0.3 % of
    pv's, which is mostly load no replay foresees.  Charged the BIC share of pv's
    error for the step as well (168 against a held-out gain of 136), it lost to
    ``none``; charged on each signal in its own units it is named.  The gap falls by
    the op error the rounding explains alone, 10^4 op_from_pv_rounding / V_op (17.0 to
    15.1 %, by hand to the rounding of floats): pv's own rounding variance (1.7 % of
    V_pv) is held by pv's noise floor (78 % of V_pv), measured on the rounded pv, and
    counts once (7.6 % when it counted twice)."""
    case = generate_case("quantization", 2748678367)
    truth = case.truth["effect_parameters"]
    assert truth["quantised"] == "pv" and truth["pv_resolution"] == "historian"
    tags = case.tags()
    g = diagnose_gap(tags)
    assert g.effect == "quantization"
    q = next(c for c in g.candidates if c.effect == "quantization")
    assert q.params.pv.step == pytest.approx(truth["pv_quantum"], rel=1e-3)
    v_op = build_context(signals_of(tags)).norm["op"]
    by_hand = 1e4 * q.params.op_from_pv_rounding / v_op
    assert g.before**2 - g.after**2 == pytest.approx(by_hand, rel=1e-9)
    assert 15.0 < g.after < 16.0 and 16.5 < g.before < 17.5


def test_mv_missed_by_its_rounding_alone_is_evidence_for_quantization():
    """mv rounded to 1.0 % of span (and pv at the instrument) on a loop whose base
    replay misses mv by its rounding almost alone: the quantization takes mv's held-out
    error from 470 to 11 (normalised), which a floor holding the rounding variance a
    second time (459) counted as no evidence, so a miscalibration that takes it to 188
    was named (gap 28.9 to 19.3 %).  The rounding accounted for, the floor of what is
    left is the rounding variance's own sampling error over mv's 19 effectively
    independent errors (a fifth of it): quantization is named and the gap falls below
    10 % (measured 4.0 %)."""
    case = generate_case("quantization", 8005)
    truth = case.truth["effect_parameters"]
    assert truth["quantised"] == "both" and truth["pv_resolution"] == "instrument"
    tags = case.tags()
    g = diagnose_gap(tags)
    assert g.effect == "quantization"
    q = next(c for c in g.candidates if c.effect == "quantization")
    assert q.params.mv.step == pytest.approx(truth["mv_quantum_pct"], rel=1e-3)
    assert g.after < 10.0 and g.before > 20.0


def test_untested_slip_signature_on_a_quantised_mv():
    """Too few measured slips leave a valve-side signature untested: the replay decides
    alone (p 0), except on a quantised mv (p 1), whose rounding a more flexible valve
    follows on held-out blocks too."""
    import numpy as np

    from stictiondiag.gap.effects.signatures import slips_differ, untested_p

    t = np.arange(2000.0)
    smooth = 50.0 + 5.0 * np.sin(t / 50.0)
    assert untested_p(smooth) == 0.0
    assert untested_p(np.round(smooth)) == 1.0  # on a grid of 1 % of span
    assert untested_p(None) == 0.0
    slips = {
        "travel": np.array([1.0, 2.0]),
        "J": np.array([0.5, 0.6]),
        "reversal": np.array([True, True]),
    }
    a, b = np.array([True, False]), np.array([False, True])
    assert slips_differ(slips, a, b) == 0.0
    assert slips_differ(slips, a, b, untested=1.0) == 1.0
    assert slips_differ(None, a, b, untested=1.0) == 1.0


def test_quantised_mv_without_measured_slips_is_not_a_time_varying_valve():
    """mv rounded to 1.4 % of span on a valve of S 2 %: the segmentation measures no
    slip, so the change of stiction could not be tested, and the replay alone named
    ``time_varying_stiction`` (a drift over the record, gap 34 to 23 %) against the
    quantization (34 to 25 %).  On a quantised mv the slips must show the change:
    quantization is named, its step the hidden one."""
    case = generate_case("quantization", 8032)
    truth = case.truth["effect_parameters"]
    assert truth["quantised"] == "mv"
    tags = case.tags()
    g = diagnose_gap(tags)
    assert g.effect == "quantization"
    tvs = next(c for c in g.candidates if c.effect == "time_varying_stiction")
    assert tvs.params.slips_differ_p == 1.0 and not tvs.accepted
    q = next(c for c in g.candidates if c.effect == "quantization")
    assert q.params.mv.step == pytest.approx(truth["mv_quantum_pct"], rel=1e-3)
