"""Tests of the effect catalogue and the driven replays (stictiondiag.gap.effects)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stictiondiag.gap.context import LoopSignals, SlowLoad, build_context, measure_slips
from stictiondiag.gap.effects import EFFECTS, assessable_effects
from stictiondiag.gap.effects.base import BaseFit, fit_base, fit_process
from stictiondiag.gap.effects.kernels import valve_replay
from stictiondiag.gap.effects.miscalibration import slip_slope_test
from stictiondiag.gap.effects.quantization import detect_quantization, fit_quantization, quantize
from stictiondiag.gap.effects.search import needle_search
from stictiondiag.gap.effects.signatures import SIGNATURE_P, one_sided, signature_test
from stictiondiag.gap.effects.time_varying_stiction import change_sides
from stictiondiag.gap.effects.valve import fit_valve
from stictiondiag.gap.effects.valve_characteristic import characteristic_curve, gain_change_test
from stictiondiag.identification.controller import filtered_pv, fit_controller_replay
from stictiondiag.identification.numerics import fractional_delay_wls, wls
from stictiondiag.identification.predictor_kernels import prediction_variance_ratio
from stictiondiag.models.valve import (
    PHASE_MOVING,
    PHASE_REVERSAL,
    PHASE_SLIP,
    PHASE_STUCK,
    choudhury_model,
    kano_model,
)


def _noisy_ramp_op(n=3000, seed=0):
    """A triangular demand with noise: the kind of op a sticky loop produces."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    tri = 50.0 + 6.0 * (2.0 * np.abs((t / 150.0) % 2.0 - 1.0) - 1.0)
    return tri + 0.05 * rng.standard_normal(n)


@pytest.mark.parametrize("S, J", [(5.0, 0.0), (5.0, 2.0), (5.0, 5.0), (5.0, 7.0)])
def test_valve_replay_reproduces_the_paper_models(S, J):
    # Same state machine with equal up/down values: the outputs must agree to the
    # last bit (tolerance only for floating-point summation order, none here).
    op = _noisy_ramp_op()
    for kano, ref in ((False, choudhury_model), (True, kano_model)):
        mv, _ = valve_replay(op, S, J, kano=kano)
        np.testing.assert_allclose(mv, ref(op, S, J), atol=1e-12)


@pytest.mark.parametrize(
    "S, J, hi, lo", [(5, 0, 57.5, 42.5), (5, 2, 58.5, 41.5), (5, 7, 61.0, 39.0)]
)
def test_fig11_extremes(S, J, hi, lo):
    # REFERENCE.md, Fig. 11: op = 50 + 10 sin(2 pi t / 50) at 0.1 s.  The moving
    # phase is exactly op - sign(slope)(S - J)/2 (Eq. 4), so the extremes match to
    # the sampling of the sine (0.01 % of span).
    t = np.arange(0, 200, 0.1)
    op = 50 + 10 * np.sin(2 * np.pi * t / 50)
    mv, phase = valve_replay(op, S, J)
    assert mv.max() == pytest.approx(hi, abs=0.01)
    assert mv.min() == pytest.approx(lo, abs=0.01)
    assert set(np.unique(phase)) <= {
        PHASE_MOVING,
        PHASE_STUCK,
        PHASE_SLIP,
        PHASE_REVERSAL,
    }


def test_asymmetric_thresholds_act_by_direction():
    # A slow ramp up, then down: the valve must break away after S_open of rise and
    # after S_close of fall (whole samples of 0.01 % each, so exact to one sample).
    up = np.linspace(50, 60, 1001)
    down = np.linspace(60, 40, 2001)[1:]
    op = np.concatenate([up, down])
    mv, phase = valve_replay(op, 2.0, 1.0, S_down=6.0, J_down=1.0)
    slips = np.where(phase == PHASE_SLIP)[0]
    assert slips.size == 2
    assert op[slips[0]] - op[0] == pytest.approx(2.0, abs=0.011)
    assert 60.0 - op[slips[1]] == pytest.approx(6.0, abs=0.011)


def test_time_varying_arrays_equal_scalars_when_constant():
    op = _noisy_ramp_op(seed=1)
    n = op.size
    a, _ = valve_replay(op, 3.0, 1.5)
    b, _ = valve_replay(op, np.full(n, 3.0), np.full(n, 1.5))
    np.testing.assert_array_equal(a, b)


def test_lag_is_exact_first_order():
    # Zero-order-hold discretisation: after one time constant the step response is
    # 1 - 1/e exactly (floating point only).
    x = np.ones(101)
    x[0] = 0.0
    y = filtered_pv(x, 10.0, 1.0)
    assert y[10] == pytest.approx(1.0 - math.exp(-1.0), rel=1e-12)


def test_detect_quantization():
    rng = np.random.default_rng(2)
    x = 50 + np.cumsum(rng.standard_normal(5000)) * 0.1
    assert detect_quantization(x) is None
    # The decimals of a CSV file (6 significant digits) are not a resolution effect.
    assert detect_quantization(np.round(x, 4)) is None
    step, offset = detect_quantization(np.round(x / 0.5) * 0.5)
    assert step == pytest.approx(0.5, rel=1e-9)
    assert abs(offset) < 1e-9


def test_characteristic_curves():
    x = np.array([0.0, 25.0, 50.0, 100.0])
    for family in ("exponential", "power"):
        np.testing.assert_allclose(characteristic_curve(x, 0.0, family), x, atol=1e-12)
        y = characteristic_curve(x, 1.0, family)
        assert y[0] == pytest.approx(0.0, abs=1e-12) and y[-1] == pytest.approx(100.0)
        assert y[1] < x[1]  # positive curvature: equal-percentage-like, below the diagonal
    # ln(R) curvature: the equal-percentage flow ratio over the travel is R (to the
    # normalisation 1/(R-1), exact).
    R = 50.0
    y = characteristic_curve(np.array([50.0, 100.0]), math.log(R), "exponential")
    assert (y[1] + 100 / (R - 1)) / (y[0] + 100 / (R - 1)) == pytest.approx(math.sqrt(R))


def test_prediction_variance_grows_with_horizon():
    s1, m1 = prediction_variance_ratio(0.9, 0.01, 1)
    assert m1 == pytest.approx(s1, rel=1e-12)
    _, m5 = prediction_variance_ratio(0.9, 0.01, 5)
    _, m20 = prediction_variance_ratio(0.9, 0.01, 20)
    assert s1 < m5 < m20


def test_slow_load_removes_piecewise_linear_drift():
    n = 2000
    load = SlowLoad(n, 125)
    knots = np.linspace(0, n - 1, load.m)
    drift = np.interp(np.arange(n), knots, np.sin(knots / 300.0) * 5.0)
    r = load.residualize(drift, np.ones(n))
    # A curve on the knots is in the basis: removed up to the tiny ridge (1e-6).
    assert np.max(np.abs(r)) < 1e-4


def _foptd_data(n=4000, K=2.0, tau=12.0, delay=5, noise=0.05, seed=3):
    """Open-loop FOPTD response to a random sequence of valve steps, with noise."""
    rng = np.random.default_rng(seed)
    steps = np.repeat(rng.uniform(40, 60, n // 80 + 1), 80)[:n]
    a = math.exp(-1.0 / tau)
    y = np.zeros(n)
    for k in range(1, n):
        u = steps[k - 1 - delay] if k - 1 - delay >= 0 else steps[0]
        y[k] = a * y[k - 1] + K * (1 - a) * (u - 50.0)
    return steps, 20.0 + y + noise * rng.standard_normal(n)


def test_fit_process_recovers_foptd():
    u, pv = _foptd_data()
    sig = LoopSignals(op=u, pv=pv, dt=1.0, mv=u)
    ctx = build_context(sig)
    fit = fit_process(u, ctx, ctx.w_eval)
    # Gain and time constant within 10 %: the fit tracks a random-walk load too, and
    # the grid of poles is refined by a short golden search; dead time within one
    # sample (a fractional dead time shares the two input taps).
    assert fit.process.gain == pytest.approx(2.0, rel=0.1)
    assert fit.process.time_constant == pytest.approx(12.0, rel=0.1)
    assert abs(fit.process.dead_time - 5.0) <= 1.0


def test_fit_controller_recovers_pi():
    rng = np.random.default_rng(4)
    n = 2000
    pv = np.cumsum(rng.standard_normal(n)) * 0.1
    sp = np.zeros(n)
    e = sp - pv
    Kc, Ti = 0.8, 25.0
    op = 50 + Kc * (e + np.cumsum(e) / Ti)
    sig = LoopSignals(op=op, pv=pv, dt=1.0, sp=sp)
    pred, params = fit_controller_replay(sig.sp, sig.pv, sig.op, sig.dt, np.ones(n))
    # Noise-free PI data in the fitted form: exact to rounding.
    assert params.gain == pytest.approx(Kc, rel=1e-6)
    assert params.integral_time_s == pytest.approx(Ti, rel=1e-6)
    np.testing.assert_allclose(pred, np.clip(op, 0, 100), atol=1e-6)


def test_needle_search_finds_a_narrow_minimum():
    # A cost that is flat except within 0.5 % of the minimum, like a stiction replay
    # that is only in step with the data near the true J.
    target = np.array([3.0, 1.7])

    def cost(X, bound):
        d = np.abs(X - target) / target
        return np.where(
            np.all(d < 0.005, axis=1), np.sum(d, axis=1), 1.0 + 0.01 * np.sum(d, axis=1)
        )

    x, c = needle_search(
        cost, np.array([3.3, 1.5]), (0, 1), np.zeros(2), np.full(2, 10.0), rel=0.15
    )
    np.testing.assert_allclose(x, target, rtol=0.005)
    assert c < 0.01


def test_fit_valve_recovers_S_and_J():
    op = _noisy_ramp_op(n=3000, seed=5)
    mv, _ = valve_replay(op, 3.0, 2.0, kano=True, initial_direction=1.0)
    rng = np.random.default_rng(6)
    mv = mv + 0.02 * rng.standard_normal(mv.size)
    sig = LoopSignals(op=op, pv=mv.copy(), dt=1.0, mv=mv)
    ctx = build_context(sig)
    fit = fit_valve(ctx, ctx.w_eval)
    # The replay is in step with the data only near the true values: S and J within
    # 2 % (the noisy demand moves by about 0.05 % of span per sample).
    assert fit.S == pytest.approx(3.0, rel=0.02)
    assert fit.J == pytest.approx(2.0, rel=0.02)


def test_assessable_effects_without_mv():
    ok, missing = assessable_effects(False)
    assert "actuator_lag" in missing and "external_disturbance" in ok
    assert set(ok) | set(missing) == set(EFFECTS) - {"none"}


def test_fractional_delay_pair_keeps_one_sign():
    # y = u(t - d) - u(t - d - 1) plus noise: the free least-squares solution is the
    # differentiator (+1, -1); a dead time between d and d + 1 cannot have weights of
    # opposite sign, so the constrained fit keeps one column, the other weight is 0.
    rng = np.random.default_rng(7)
    n = 3000
    u = np.cumsum(rng.standard_normal(n))
    X = np.column_stack([u, np.concatenate([[u[0]], u[:-1]])])
    y = X[:, 0] - X[:, 1] + 0.01 * rng.standard_normal(n)
    w = np.ones(n)
    free = wls(X, y, w)
    assert free[0] * free[1] < 0.0
    coef = fractional_delay_wls(X, y, w)
    assert coef[0] * coef[1] == 0.0
    # With same-sign weights the free solution is kept (to 1e-5: the two columns are
    # nearly collinear and _wls adds a ridge of 1e-10 to the scaled normal equations).
    y2 = 0.3 * X[:, 0] + 0.7 * X[:, 1]
    np.testing.assert_allclose(fractional_delay_wls(X, y2, w), [0.3, 0.7], atol=1e-5)


def _pi_loop_signals(n=4000, dt=1.0, Kc=1.5, Ti=30.0, seed=8):
    """pv a slow wander, op a PI controller on it; the controller read pv unrounded."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    pv = 50.0 + 3.0 * np.sin(2 * np.pi * t / 400.0) + 0.5 * np.sin(2 * np.pi * t / 97.0)
    pv = pv + 0.02 * rng.standard_normal(n)
    sp = np.full(n, 50.0)
    e = sp - pv
    op = 50.0 + Kc * (e + np.cumsum(e) * dt / Ti)
    return pv, op, sp


@pytest.mark.parametrize("rounded_by", ["historian", "instrument"])
def test_quantization_explains_the_controller_error_of_a_historian_rounding(rounded_by):
    pv, op, sp = _pi_loop_signals()
    q = 0.25
    pv_rec = quantize(pv, q)
    if rounded_by == "instrument":
        # The controller read the rounded pv: op follows it exactly.
        e = sp - pv_rec
        op = 50.0 + 1.5 * (e + np.cumsum(e) / 30.0)
    sig = LoopSignals(op=op, pv=pv_rec, dt=1.0, mv=op.copy(), sp=sp)
    ctx = build_context(sig)
    base = fit_base(ctx, ctx.w_eval)
    ef = fit_quantization(ctx, ctx.w_eval, base)
    assert ef is not None and ef.params.pv.step == pytest.approx(q, rel=1e-6)
    # One step read off the data: one parameter, whatever signals it explains.
    assert ef.n_params == 1
    w = ctx.w_eval
    r = base.op - sig.op
    op_mse = float(np.dot(w, r * r) / w.sum())
    if rounded_by == "historian":
        # The replay answers the rounding error the controller never saw: the effect
        # accounts for most of the controller replay's error (the stand-in rounding
        # of the process replay is not the true one: at least half, never more).
        assert 0.5 * op_mse <= ef.explained["op"] <= op_mse * (1 + 1e-12)
    else:
        # The controller replay is exact up to its fit (op error ~0): nothing to
        # explain beyond it (capped by the replay's own error).
        assert ef.explained.get("op", 0.0) <= op_mse * (1 + 1e-12)


def test_signature_test_recovers_a_coefficient_and_keeps_its_level():
    # Replay errors are correlated (AR(1), phi = 0.95) and so is the regressor (a
    # slow sinusoid plus its own AR(1) part): the textbook standard error would be
    # about six times too small and reject far more often than 1 %.
    rng = np.random.default_rng(11)
    n, phi = 2400, 0.95

    def ar1(size):
        e = rng.standard_normal(size)
        out = np.empty(size)
        out[0] = e[0]
        for k in range(1, size):
            out[k] = phi * out[k - 1] + e[k]
        return out

    k = np.arange(n)
    rejections = 0
    n_rep = 300
    for _ in range(n_rep):
        x = np.sin(k / 90.0) + 0.3 * ar1(n)
        _, p = signature_test(x, ar1(n), np.ones(n))
        rejections += p < 0.01
    # Level 1 %: 3 of 300 expected; binomial sd 1.7.  The batch-means variance with
    # twelve blocks of 200 samples (correlation time about 40) is slightly
    # optimistic, so allow up to 4 % (12 of 300), still far below what ignoring the
    # correlation gives.
    assert rejections <= 12
    x = np.sin(k / 90.0) + 0.3 * ar1(n)
    beta, p = signature_test(x, 2.0 * x + ar1(n), np.ones(n))
    # Signal 2 x against AR(1) noise of sd 3.2 correlated over ~40 samples: a standard
    # error of about 0.35, so the estimate is within 1.0 (three standard errors) and
    # clear at the 1 % level.
    assert beta == pytest.approx(2.0, abs=1.0)
    assert p < 0.01


def test_signature_test_partials_out_other_columns():
    rng = np.random.default_rng(12)
    n = 1200
    z = rng.standard_normal(n)
    x = z + 0.1 * rng.standard_normal(n)
    y = 3.0 * z + 0.05 * rng.standard_normal(n)
    # y depends on z only; x is nearly a copy of z: with z partialled out x adds
    # nothing (p well above 1 %); without, it would look highly significant.
    beta, p = signature_test(x, y, np.ones(n), others=z[:, None])
    assert abs(beta) < 0.05
    assert p > 0.01
    # A column that is a copy of another carries nothing: (0, 1).
    assert signature_test(z, y, np.ones(n), others=z[:, None]) == (0.0, 1.0)


def _wandering_stickslip_op(n=8000, seed=7):
    """A noisy triangular demand whose centre wanders: slips at many positions."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    tri = 6.0 * (2.0 * np.abs((t / 150.0) % 2.0 - 1.0) - 1.0)
    return 50.0 + 15.0 * np.sin(t / 1300.0) + tri + 0.05 * rng.standard_normal(n)


@pytest.mark.parametrize("slope", [1.0, 0.8, 1.25])
def test_slip_slope_test_sees_a_miscalibrated_positioner(slope):
    op = _wandering_stickslip_op()
    v, _ = valve_replay(op, 3.0, 1.5, initial_direction=1.0)
    rng = np.random.default_rng(8)
    mv = 4.0 + slope * v + 0.03 * rng.standard_normal(op.size)
    slips = measure_slips(op, mv, 1.0)
    s, p = slip_slope_test(slips)
    # About 50 slips spread over 30 % of span: the slope is read to within 0.02
    # (mv noise 0.03 %, the one-sample resolution of the breakaway demand, and the
    # noisy demand's direction at the breakaway setting each slip's offset).
    assert s == pytest.approx(slope, abs=0.02)
    if slope == 1.0:
        # A correct positioner: no signature at the 1 % level (a fixed seed; the
        # test's level is checked on noise above).
        assert p > SIGNATURE_P
    else:
        assert p < 1e-4


def test_slip_slope_test_needs_slips():
    # Fewer than twelve slips: nothing to tell (nan, 1).
    assert slip_slope_test(None) == (pytest.approx(math.nan, nan_ok=True), 1.0)
    few = {
        "op_break": np.arange(8.0),
        "mv_after": np.arange(8.0),
        "op_direction": np.tile([1.0, -1.0], 4),
    }
    s, p = slip_slope_test(few)
    assert math.isnan(s) and p == 1.0


def _levels_loop(curvature, family="power", n=6000, seed=9):
    """Open-loop steps of a valve across its range into a lag with dead time, through
    an installed characteristic (curvature 0: linear)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(15.0, 85.0, n // 60 + 1), 60)[:n]
    u = u + 0.2 * rng.standard_normal(n)
    flow = characteristic_curve(u, curvature, family)
    a = math.exp(-1.0 / 10.0)
    y = np.zeros(n)
    for k in range(4, n):
        y[k] = a * y[k - 1] + 0.8 * (1 - a) * flow[k - 4]
    pv = y + 0.1 * rng.standard_normal(n)
    sig = LoopSignals(op=u, pv=pv, dt=1.0, mv=u)
    ctx = build_context(sig)
    proc = fit_process(u, ctx, ctx.w_eval)
    base = BaseFit(valve=None, process=proc, op=u, controller={}, mv_model=u)
    return ctx, base


@pytest.mark.parametrize("curvature", [math.log(2.0), math.log(0.5)])
def test_gain_change_test_sees_an_installed_characteristic(curvature):
    ctx, base = _levels_loop(curvature)
    change, p = gain_change_test(ctx, ctx.w_eval, base, "process")
    # Power 2 (convex): the gain at 70 % is about three times that at 30 %, so the
    # hinge at the median finds a gain higher above the middle; power 1/2 (concave)
    # the other way.  Strong and clear: p far below 1 %.
    assert change * curvature > 0.0
    assert abs(change) > 0.3
    assert p < 1e-4


def test_gain_change_test_is_quiet_on_a_linear_process():
    ctx, base = _levels_loop(0.0)
    change, p = gain_change_test(ctx, ctx.w_eval, base, "process")
    # A linear valve: no gain change beyond noise (a fixed seed; the test's level is
    # checked on noise above), and a small estimate.
    assert p > SIGNATURE_P
    assert abs(change) < 0.1


def test_one_sided_signature_p_follows_the_fitted_direction():
    # Half the two-sided p-value when the signature points the way the fitted effect
    # does, at least 1/2 when it points the other way (exact arithmetic).
    assert one_sided(0.02, True) == pytest.approx(0.01, abs=1e-15)
    assert one_sided(0.02, False) == pytest.approx(0.99, abs=1e-15)
    assert one_sided(1.0, True) == 0.5


def test_change_sides_never_leave_a_side_without_slips():
    # Slips every 10 samples over 1000.  A step at 400: slips before and after it.
    times = np.arange(5.0, 1000.0, 10.0)
    early, late = change_sides(times, 400.0, 400.0, 1000)
    assert early.sum() == 40 and late.sum() == 60
    # A ramp from the start of the record to sample 900 has no slip before it: the
    # sides are split at the middle of the ramp (450) instead, 45 and 55 slips.
    early, late = change_sides(times, 0.0, 900.0, 1000)
    assert early.sum() == 45 and late.sum() == 55
    # A drift over the whole record: its two halves.
    early, late = change_sides(times, 0.0, 999.0, 1000)
    assert early.sum() == 50 and late.sum() == 50


def test_slip_rate_differs_sees_slips_that_stop_and_keeps_a_steady_rate_quiet():
    """Issue 27: a change of stiction can leave slips after it too small to measure
    one by one; their number still tests it."""
    from stictiondiag.gap.effects.signatures import slip_rate_differs

    times = np.arange(5.0, 1000.0, 10.0)
    # A steady rate (40 before sample 400, 60 after it, the sides' share of the
    # record): no difference, p = 1 to rounding.
    assert slip_rate_differs(times, 400.0, 400.0, 1000) == pytest.approx(1.0, abs=1e-9)
    # Slips only before 400: 40 of 40 where 40 % are expected, p = 2 * 0.4004^40.
    p = slip_rate_differs(times[times < 400], 400.0, 400.0, 1000)
    assert p == pytest.approx(2.0 * (400.0 / 999.0) ** 40, rel=1e-6)
    # A change placed at the start of the record leaves that side no time: no test.
    assert slip_rate_differs(times, 0.0, 900.0, 1000) == 1.0


def test_time_varying_slips_test_counts_slips_when_one_side_has_too_few():
    from stictiondiag.gap.effects.time_varying_stiction import _slips_test

    rng = np.random.default_rng(2)
    n = 6000
    before = np.arange(20.0, 2000.0, 30.0)  # 66 slips before the change at 2000
    size = 2.0 + 0.2 * rng.standard_normal(before.size)
    slips = {
        "time": before,
        "travel": size,
        "J": size,
        "reversal": np.ones(before.size, dtype=bool),
    }
    # No slip measured after the step: the sizes cannot be compared, the rate can
    # (66 of 66 in a third of the record): p far below the 1 % the effect needs.
    assert _slips_test(slips, 2000.0, 2000.0, n) < 1e-10
    # The same slips, and as many after the step at the same rate and size: neither
    # test sees a change (p well above 1 %).
    after = before + 2000.0
    both = {
        "time": np.concatenate([before, after, after + 2000.0]),
        "travel": np.tile(size, 3),
        "J": np.tile(size, 3),
        "reversal": np.ones(3 * before.size, dtype=bool),
    }
    assert _slips_test(both, 2000.0, 2000.0, n) > 0.05
