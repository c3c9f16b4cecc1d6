"""Tests of the data-driven valve models (Section 5, Fig. 10, Eq. 4, Fig. 11)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

from stictiondiag import (
    STICTION_MODEL_PARAMETERS,
    UsageError,
    choudhury_model,
    ewma,
    kano_model,
    ma_to_percent,
    percent_to_ma,
    valve_characteristic,
)
from stictiondiag.models.valve import EQUAL_PERCENTAGE_RANGEABILITY

DT = 0.1  # [s], Section 5.2
TIME = np.arange(0.0, 500.0, DT)  # ten periods of the Fig. 11 input
OP_FIG11 = 50.0 + 10.0 * np.sin(2 * np.pi * TIME / 50.0)
STEADY = TIME >= 100.0  # after two periods: the start-up from rest is over
MAX_OP_STEP = float(np.max(np.abs(np.diff(OP_FIG11))))  # 2 pi 10 dt / 50 = 0.126 %

# REFERENCE.md, "Data-driven model, open loop": (case, S, J, max mv, min mv).
FIG11 = [
    ("linear", 0, 0, 60.0, 40.0),
    ("deadband", 5, 0, 57.5, 42.5),
    ("undershoot", 5, 2, 58.5, 41.5),
    ("no_offset", 5, 5, 60.0, 40.0),
    ("overshoot", 5, 7, 61.0, 39.0),
]


@pytest.mark.parametrize(("case", "S", "J", "mv_max", "mv_min"), FIG11)
def test_fig11_table(case, S, J, mv_max, mv_min):
    assert STICTION_MODEL_PARAMETERS[case] == {"S": S, "J": J}
    mv = choudhury_model(OP_FIG11, S, J)[STEADY]
    # 500 samples per period put a sample exactly on each peak of op, where the
    # valve sticks (Fig. 10), so the extremes are exact up to rounding.
    assert mv.max() == pytest.approx(mv_max, abs=1e-9)
    assert mv.min() == pytest.approx(mv_min, abs=1e-9)


@pytest.mark.parametrize(("case", "S", "J", "mv_max", "mv_min"), FIG11)
def test_moving_phase_is_eq4_and_stuck_phase_is_constant(case, S, J, mv_max, mv_min):
    mv = choudhury_model(OP_FIG11, S, J)
    slope = np.sign(np.diff(OP_FIG11))
    moved = np.diff(mv) != 0
    # Eq. 4 is evaluated, not integrated: exact up to one rounding.
    eq4 = OP_FIG11[1:] - slope * (S - J) / 2.0
    np.testing.assert_allclose(mv[1:][moved], eq4[moved], rtol=0, atol=1e-12)
    if S > 0:
        # The valve sticks at every reversal: two stuck stretches per period.
        stuck_starts = np.flatnonzero(~moved[1:] & moved[:-1])
        assert len(stuck_starts) >= 2 * 9


@pytest.mark.parametrize(("S", "J"), [(5, 2), (5, 5), (5, 7), (3, 4.5), (2, 1)])
def test_each_slip_is_a_jump_of_J(S, J):
    mv = choudhury_model(OP_FIG11, S, J)
    jumps = np.abs(np.diff(mv))[STEADY[1:]]
    big = jumps[jumps > 2 * MAX_OP_STEP]
    # Two slips per period in the eight steady periods.
    assert len(big) == 16
    # The slip is detected at the first sample past the threshold S, so the jump is
    # J plus the overshoot of that sample: within one sample's op change.
    assert (big > J - 1e-12).all()
    assert (big <= J + MAX_OP_STEP + 1e-12).all()


def test_deadband_has_no_jump_in_steady_state():
    mv = choudhury_model(OP_FIG11, 5, 0)
    # J = 0: the valve starts moving with at most one sample's overshoot of S.
    assert np.abs(np.diff(mv))[STEADY[1:]].max() <= MAX_OP_STEP + 1e-12


def test_start_stuck_and_initial_position():
    mv = choudhury_model(OP_FIG11, 5, 2)
    # At rest and stuck at op[0] until op has moved by S from it.
    first_move = np.flatnonzero(np.diff(mv))[0] + 1
    assert np.all(mv[:first_move] == OP_FIG11[0])
    assert OP_FIG11[first_move] - OP_FIG11[0] > 5
    assert OP_FIG11[first_move - 1] - OP_FIG11[0] <= 5
    mv0 = choudhury_model(OP_FIG11, 5, 2, initial_position=47.0)
    assert mv0[0] == 47.0 and np.all(mv0[:first_move] == 47.0)


def test_saturation():
    op = 50.0 + 70.0 * np.sin(2 * np.pi * TIME / 50.0)
    for S, J in [(0, 0), (5, 2), (5, 7)]:
        mv = choudhury_model(op, S, J)
        assert mv.min() >= 0.0 and mv.max() <= 100.0
    # A linear valve is the saturated input.
    np.testing.assert_array_equal(choudhury_model(op, 0, 0), np.clip(op, 0, 100))
    # Overshoot (J > S) at the ends of travel still stops at the limits.
    mv = choudhury_model(op, 5, 7)
    assert mv.max() == 100.0 and mv.min() == 0.0


def test_ma_round_trip_and_ma_model():
    pct = np.array([0.0, 12.5, 50.0, 100.0])
    np.testing.assert_allclose(percent_to_ma(pct), [4.0, 6.0, 12.0, 20.0])
    np.testing.assert_allclose(ma_to_percent(percent_to_ma(OP_FIG11)), OP_FIG11, atol=1e-12)
    # Section 5.1: the 4-20 mA signal goes through the look-up table; the model in
    # mA is the percent model converted (rounding of the two conversions only).
    mv_ma = choudhury_model(percent_to_ma(OP_FIG11), 5, 2, op_units="mA")
    np.testing.assert_allclose(
        mv_ma, percent_to_ma(choudhury_model(OP_FIG11, 5, 2)), rtol=0, atol=1e-9
    )


def test_characteristics():
    x = np.linspace(0, 100, 1001)
    lin = valve_characteristic(x, "linear")
    eq = valve_characteristic(x, "equal_percentage")
    quick = valve_characteristic(x, "quick_opening")
    np.testing.assert_array_equal(lin, x)
    assert eq[0] == pytest.approx(100.0 / EQUAL_PERCENTAGE_RANGEABILITY)
    assert eq[-1] == pytest.approx(100.0)
    assert quick[0] == 0.0 and quick[-1] == pytest.approx(100.0)
    for flow in (lin, eq, quick):
        assert (np.diff(flow) > 0).all()
    # Equal percentage: equal increments of travel give equal ratios of flow.
    ratios = eq[100::100] / eq[:-100:100]
    np.testing.assert_allclose(ratios, ratios[0], rtol=1e-12)
    # Quick opening lies above linear inside the range; equal percentage below it,
    # except near closure where it keeps its 100/R minimum flow (2 % at R = 50).
    assert (quick[1:-1] > lin[1:-1]).all()
    assert (eq[100:-1] < lin[100:-1]).all()
    # Positions outside the travel are clipped.
    assert valve_characteristic(np.array([-5.0, 105.0]), "quick_opening").tolist() == [0.0, 100.0]
    # The model's output look-up.
    np.testing.assert_allclose(
        choudhury_model(OP_FIG11, 5, 2, characteristic="equal_percentage"),
        valve_characteristic(choudhury_model(OP_FIG11, 5, 2), "equal_percentage"),
    )


def test_ewma():
    step = np.r_[0.0, np.ones(50)]
    lam = 0.2
    f = ewma(step, lam)
    k = np.arange(51)
    # f[k] = 1 - (1 - lam)^k for a unit step after sample 0.
    np.testing.assert_allclose(f, np.where(k == 0, 0.0, 1 - (1 - lam) ** k), atol=1e-12)
    np.testing.assert_array_equal(ewma(OP_FIG11, 1.0), OP_FIG11)
    assert ewma(np.array([]), 0.5).size == 0


@pytest.mark.parametrize(
    ("S", "J"), [(-1, 0), (0, -0.5), ("x", 1), (None, 1), (float("nan"), 1), (1, float("inf"))]
)
def test_bad_parameters_raise_usage_error(S, J):
    for model in (choudhury_model, kano_model):
        with pytest.raises(UsageError):
            model(OP_FIG11, S, J)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"op_units": "volts"},
        {"characteristic": "butterfly"},
        {"ewma_lambda": 0.0},
        {"ewma_lambda": 1.5},
    ],
)
def test_bad_options_raise_usage_error(kwargs):
    with pytest.raises(UsageError):
        choudhury_model(OP_FIG11, 5, 2, **kwargs)


def test_two_dimensional_input_rejected():
    with pytest.raises(UsageError):
        choudhury_model(np.ones((3, 3)), 1, 1)


def test_empty_input():
    assert choudhury_model(np.array([]), 1, 1).size == 0


def _ramp_with_noise() -> np.ndarray:
    # 12.5 s at rest, a ramp of 10 % over 200 s, then flat; measurement noise with
    # a larger sample-to-sample change (0.07 %) than the ramp's (0.005 %).
    rng = np.random.default_rng(0)
    trend = np.r_[np.zeros(500), np.linspace(0.0, 10.0, 2000), np.full(1500, 10.0)]
    return 50.0 + trend + rng.normal(0.0, 0.05, trend.size)


def test_kano_breaks_away_where_noisy_choudhury_stays_stuck():
    op = _ramp_with_noise()
    S, J = 3.0, 1.0
    # Choudhury's model re-arms x_ss at every reversal of the slope, and noise
    # reverses it every other sample: the cumulative change never reaches S.
    stuck = choudhury_model(op, S, J)
    assert np.ptp(stuck) == 0.0
    # Kano's keeps x_ss while stuck: the ramp carries op past S and the valve
    # moves in stick-slip steps, ending within S of the input.
    kano = kano_model(op, S, J)
    assert kano[-1] - kano[0] > 10.0 - S
    assert len(np.unique(kano)) > 3
    # Section 5.1: with an EWMA pre-filter the noise reversals vanish and
    # Choudhury's model follows the ramp too (lags behind by at most (S - J)/2
    # plus the filter's lag).
    filtered = choudhury_model(op, S, J, ewma_lambda=0.01)
    assert filtered[-1] - filtered[0] > 10.0 - S


def test_kano_equals_choudhury_without_noise():
    # Both models differ only in how reversals inside the stuck band re-arm it; a
    # sine has none, so they agree sample by sample (Fig. 11 cases).
    for _, S, J, _, _ in FIG11:
        np.testing.assert_array_equal(kano_model(OP_FIG11, S, J), choudhury_model(OP_FIG11, S, J))


# ---------------------------------------------------------------------------
# Property tests.  Inputs are dyadic rationals (integers / 64) so that shifts,
# mirror images and scaling by powers of two are exact in floating point and the
# invariants can be asserted exactly.

_steps = st.lists(st.integers(-300, 300), min_size=2, max_size=200)
_param = st.integers(0, 640).map(lambda k: k / 64.0)
_models = st.sampled_from([choudhury_model, kano_model])


def _op_from(steps: list[int]) -> np.ndarray:
    # A random walk around 50 % in 1/64 % units, kept inside the span.
    return np.clip(50.0 + np.cumsum(steps) / 64.0, 0.0, 100.0)


@seed(20050101)
@settings(max_examples=150, deadline=None)
@given(
    op=st.lists(st.floats(-50, 150), min_size=1, max_size=200), S=_param, J=_param, model=_models
)
def test_output_within_span(op, S, J, model):
    mv = model(np.array(op), S, J)
    assert ((mv >= 0.0) & (mv <= 100.0)).all()


@seed(20050102)
@settings(max_examples=100, deadline=None)
@given(op=st.lists(st.floats(-50, 150), min_size=1, max_size=200), model=_models)
def test_no_stiction_is_identity(op, model):
    x = np.array(op)
    np.testing.assert_array_equal(model(x, 0.0, 0.0), np.clip(x, 0.0, 100.0))


@seed(20050103)
@settings(max_examples=150, deadline=None)
@given(steps=_steps, S=_param, J=_param, model=_models)
def test_stuck_inside_band(steps, S, J, model):
    # Started stuck, the valve moves only once the input has moved by more than S
    # (reversal) or J (same direction) from where it stuck; an input that stays
    # in a band no wider than min(S, J) never gets there.
    op = _op_from(steps)
    band = min(S, J)
    op = np.clip(op, op[0] - band / 2, op[0] + band / 2)
    mv = model(op, S, J)
    assert (mv == op[0]).all()


@seed(20050104)
@settings(max_examples=150, deadline=None)
@given(steps=_steps, S=_param, J=_param, shift=st.integers(-640, 640), model=_models)
def test_shift_invariance(steps, S, J, shift, model):
    # The model sees only differences of op: shifting op shifts mv (no saturation).
    op = np.clip(_op_from(steps), 20.0, 80.0)
    b = shift / 64.0
    np.testing.assert_array_equal(model(op + b, S, J), model(op, S, J) + b)


@seed(20050105)
@settings(max_examples=150, deadline=None)
@given(steps=_steps, S=_param, J=_param, c=st.sampled_from([0.25, 0.5, 2.0]), model=_models)
def test_scaling_invariance(steps, S, J, c, model):
    # Homogeneity: scaling the excursion of op and both S and J by c scales the
    # excursion of mv by c (the basis of describing_function_numeric's scaling).
    op = np.clip(_op_from(steps), 40.0, 60.0)
    mv = model(op, S, J)
    mv_c = model(50.0 + c * (op - 50.0), c * S, c * J)
    np.testing.assert_array_equal(mv_c, 50.0 + c * (mv - 50.0))


@seed(20050106)
@settings(max_examples=150, deadline=None)
@given(steps=_steps, S=_param, J=_param, model=_models)
def test_mirror_symmetry(steps, S, J, model):
    # Opening and closing behave alike: mirroring op about 50 % mirrors mv.
    op = _op_from(steps)
    np.testing.assert_array_equal(model(100.0 - op, S, J), 100.0 - model(op, S, J))
