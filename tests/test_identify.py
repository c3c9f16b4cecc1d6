"""Identification of the PI controller and the process from closed-loop data.

The data come from the paper's loops (Eq. 3, Table 3) simulated with the data-driven
valve (Section 5.1), so the true Kc, Ti, K, tau and dead time are known.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from stictiondiag.core.errors import (
    DataError,
    UsageError,
)
from stictiondiag.identification.controller import (
    controller_fit,
    identify_controller,
    saturated_samples,
)
from stictiondiag.identification.process import (
    MAX_DEAD_TIME_FRACTION,
    MIN_SPAN_SAMPLES,
    SPAN_PERIODS,
    identify_process,
    process_fit,
    search_span,
)
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import (
    FOPTD,
    LOOP_PARAMETERS,
    PI,
    Integrating,
)
from stictiondiag.models.valve import choudhury_model

N = 10_000
DT = 0.1
CONC = LOOP_PARAMETERS["concentration"]
LEVEL = LOOP_PARAMETERS["level"]


def setpoint_step(n: int = N, base: float = 10.0, step: float = 1.0, at: float = 5.0):
    """A setpoint step that makes the integral ramp and the stuck valve move."""
    return base + np.where(np.arange(n) * DT >= at, step, 0.0)


def run(loop, S, J, **kw):
    kw.setdefault("sp", setpoint_step())
    kw.setdefault("op_bias", 40.0)
    kw.setdefault("pv_bias", 10.0)
    return simulate_loop(
        loop["process"], loop["controller"], duration=N * DT, dt=DT, S=S, J=J, **kw
    )


@pytest.fixture(scope="module")
def conc_clean():
    return run(CONC, 5.0, 2.0)


@pytest.fixture(scope="module")
def level_clean():
    return run(LEVEL, 3.0, 3.0)


# --------------------------------------------------------------------------- controller


def test_controller_exact_on_simulated_loop(conc_clean):
    s = conc_clean
    c = identify_controller(s.sp, s.pv, s.op, DT)
    # The simulator's integral is the backward-Euler sum the velocity form assumes, so
    # the regression is exact: only rounding is left.
    assert c.controller.gain == pytest.approx(0.2, rel=1e-9)
    assert c.controller.integral_time == pytest.approx(10.0, rel=1e-9)
    assert not c.p_only and not c.reverse_acting and not c.sp_assumed
    # op_bias: the simulator starts with zero integral at op = op_bias = 40.
    assert c.op_bias == pytest.approx(40.0, abs=1e-6)
    assert c.fit_r2 > 1 - 1e-9
    assert c.op_fit_r2 > 1 - 1e-9


def test_controller_exact_with_measurement_noise():
    # op is computed from the noisy pv the controller saw, so noise does not bias
    # the velocity-form regression (no errors in variables): still exact.  The Kano
    # valve is used because Choudhury's re-arms its stuck band at every noise reversal.
    s = run(LEVEL, 3.0, 3.0, valve="kano", noise_std=0.2, seed=1)
    c = identify_controller(s.sp, s.pv, s.op, DT)
    assert c.controller.gain == pytest.approx(0.4, rel=1e-9)
    assert c.controller.integral_time == pytest.approx(2.0, rel=1e-9)


def test_controller_quantised_op():
    # A historian that stores op to 0.01 % adds +-0.005 % of noise to every op
    # difference; measured error 0.05 %, tolerance 1 % (twenty times that).
    s = run(CONC, 5.0, 5.0)
    c = identify_controller(s.sp, s.pv, np.round(s.op, 2), DT)
    assert c.controller.gain == pytest.approx(0.2, rel=0.01)
    assert c.controller.integral_time == pytest.approx(10.0, rel=0.01)


def test_controller_reverse_acting():
    # Negative process gain with a negative controller gain is a negative-feedback
    # loop; the identification must keep the sign (exact as above).
    s = simulate_loop(
        FOPTD(-3.0, 10.0, 10.0),
        PI(-0.2, 10.0),
        duration=N * DT,
        dt=DT,
        S=5.0,
        J=5.0,
        sp=setpoint_step(),
        op_bias=40.0,
        pv_bias=10.0,
    )
    c = identify_controller(s.sp, s.pv, s.op, DT)
    assert c.reverse_acting
    assert c.controller.gain == pytest.approx(-0.2, rel=1e-9)
    assert c.controller.integral_time == pytest.approx(10.0, rel=1e-9)
    p = identify_process(s.mv, s.pv, DT)
    assert p.process.gain == pytest.approx(-3.0, rel=1e-4)


def test_controller_proportional_only():
    # Ti = 1e12 s is no integral action over a 1000 s record; setpoint steps excite
    # the loop.  The gain is exact (see above), Ti is reported as infinite.
    rng = np.random.default_rng(0)
    sp = 10.0 + np.repeat(rng.normal(0.0, 2.0, N // 500), 500)
    s = simulate_loop(
        FOPTD(3.0, 10.0, 10.0),
        PI(0.2, 1e12),
        duration=N * DT,
        dt=DT,
        valve="linear",
        sp=sp,
        op_bias=40.0,
        pv_bias=10.0,
        noise_std=0.05,
        seed=1,
    )
    c = identify_controller(s.sp, s.pv, s.op, DT)
    assert c.p_only
    assert math.isinf(c.controller.integral_time)
    assert c.controller.gain == pytest.approx(0.2, rel=1e-9)
    # P-only: op = op_bias + Kc e exactly.  The simulator starts at op = 40 % at the
    # initial error sp[0] - pv_bias, so the manual reset is 40 - Kc e0.
    assert c.op_bias == pytest.approx(40.0 - 0.2 * (s.sp[0] - 10.0), abs=1e-6)
    assert c.to_dict()["integral_time_s"] is None


def test_controller_saturation_left_out():
    # Setpoints that need more than 100 % or less than 0 % valve opening.  The
    # simulator's anti-windup (conditional integration) holds op just below the
    # limit and chatters there, integrating on some samples and not on others, so
    # the PI law does not hold next to the limits.
    blocks = np.array([10.0, 200.0, 10.0, -200.0, 10.0, 150.0, 10.0, -100.0, 10.0, 10.0])
    sp = np.repeat(blocks, N // blocks.size)
    s = simulate_loop(
        FOPTD(3.0, 10.0, 10.0),
        PI(0.2, 10.0),
        duration=N * DT,
        dt=DT,
        valve="linear",
        sp=sp,
        op_bias=60.0,
        pv_bias=10.0,
    )
    near_limits = (s.op > 99.0) | (s.op < 1.0)
    assert near_limits.mean() > 0.1  # the case really saturates
    c = identify_controller(s.sp, s.pv, s.op, DT)
    # Exact once the stretches at the limits are trimmed (rounding only).
    assert c.controller.gain == pytest.approx(0.2, rel=1e-9)
    assert c.controller.integral_time == pytest.approx(10.0, rel=1e-9)
    assert c.n_outliers > 0.05 * N
    # Fitting through the saturated stretches would be wrong by more than 5 %.
    e = s.sp - s.pv
    X = np.column_stack([np.diff(e), e[1:]])
    kc, ki = np.linalg.lstsq(X, np.diff(s.op), rcond=None)[0]
    naive_ti = kc * DT / ki
    assert abs(kc / 0.2 - 1) > 0.05 or abs(naive_ti / 10.0 - 1) > 0.05


def test_saturated_samples_pinned_at_recorded_limits():
    # A clamp at 95 % (not 100 %) and one at the bottom, in op of any units; a
    # turning peak of a triangle that passes the maximum is not a clamp.
    tri = 50.0 + 45.0 * (2 * np.abs(((np.arange(400) / 100.0) % 1.0) - 0.5) * 2 - 1)
    op = np.concatenate([tri, np.full(20, 95.0), tri[::-1], np.full(10, 5.0)])
    sat = saturated_samples(op)
    assert sat[400:420].all() and sat[820:830].all()
    assert sat.sum() == 30
    # Scaled data (mean-centred, no 0-100 % limits) has no clamp.
    assert not saturated_samples(np.sin(np.arange(500) / 10.0)).any()


def test_controller_missing_setpoint():
    # Constant setpoint not recorded: taken as mean(pv).  The mean control error of
    # the limit cycle (0.011 here) shifts the error by a constant, which biases the
    # integral coefficient slightly (measured 2e-5); tolerance 0.1 %.
    s = run(CONC, 5.0, 5.0, sp=10.0)
    c = identify_controller(None, s.pv, s.op, DT)
    assert c.sp_assumed
    assert c.controller.gain == pytest.approx(0.2, rel=1e-3)
    assert c.controller.integral_time == pytest.approx(10.0, rel=1e-3)


def test_controller_fit_of_given_controller(conc_clean):
    s = conc_clean
    c = controller_fit(PI(0.2, 10.0), s.sp, s.pv, s.op, DT)
    assert c.op_bias == pytest.approx(40.0, abs=1e-6)  # exact law, as above
    assert c.fit_r2 > 1 - 1e-9
    wrong = controller_fit(PI(0.1, 10.0), s.sp, s.pv, s.op, DT)
    assert wrong.fit_r2 < 0.9  # a halved gain explains much less


def test_controller_errors():
    with pytest.raises(UsageError):
        identify_controller(None, np.zeros(50), np.zeros(40), DT)
    with pytest.raises(UsageError):
        identify_controller(None, np.zeros(50), np.zeros(50), -1.0)
    # op pinned at 100 % throughout: nothing to fit.
    with pytest.raises(DataError):
        identify_controller(None, np.arange(100.0), np.full(100, 100.0), DT)


# --------------------------------------------------------------------------- process


def test_process_open_loop_exact():
    # Analytic check: random steps through the exact ZOH discretisation of
    # K e^{-theta s}/(tau s + 1) are reproduced to rounding.
    rng = np.random.default_rng(2)
    n, dt = 3000, 0.5
    u = 50.0 + np.repeat(rng.normal(0.0, 5.0, n // 60), 60)
    K, tau, d = 1.7, 12.0, 14
    a = math.exp(-dt / tau)
    x = np.concatenate([np.full(d + 1, u[0]), u[: n - d - 1]])
    pv = 3.0 + K * (lfilter([1 - a], [1, -a], x, zi=[a * u[0]])[0] - 50.0)
    p = identify_process(u, pv, dt, integrating=False)
    assert p.process.gain == pytest.approx(K, rel=1e-6)
    assert p.process.time_constant == pytest.approx(tau, rel=1e-6)
    assert p.dead_time_samples == d
    # Response within 1e-4 on a range of about 30: the optimiser's tolerance on tau.
    np.testing.assert_allclose(p.simulate(u, dt), pv, atol=1e-4)


def test_process_foptd_closed_loop(conc_clean):
    s = conc_clean
    p = identify_process(s.mv, s.pv, DT, integrating=None)
    # The loop simulator uses the same exact ZOH model: exact to the optimiser's
    # tolerance (measured 4e-6 on tau).
    assert not p.integrating
    assert p.process.gain == pytest.approx(3.0, rel=1e-4)
    assert p.process.time_constant == pytest.approx(10.0, rel=1e-4)
    assert p.process.dead_time == pytest.approx(10.0, abs=1e-9)
    assert p.output_error.fit_r2 > 0.9999
    assert p.output_error.integrating_r2 < p.output_error.foptd_r2 - 0.1


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_process_foptd_noisy(seed):
    # White measurement noise (std 0.2 against a pv cycle of about +-5): the
    # output-error fit is unbiased but has variance; over seeds 0-4 the largest
    # errors were 0.2 % (gain), 1.1 % (tau) and one sample (dead time).
    # Tolerances: 2 %, 3 %, 2 samples.
    s = run(CONC, 5.0, 2.0, valve="kano", noise_std=0.2, seed=seed)
    p = identify_process(s.mv, s.pv, DT, integrating=None)
    assert not p.integrating
    assert p.process.gain == pytest.approx(3.0, rel=0.02)
    assert p.process.time_constant == pytest.approx(10.0, rel=0.03)
    assert abs(p.dead_time_samples - 100) <= 2


def test_process_drift_prefilter():
    # An unmeasured slow load (sine of period 700 s, about ten cycles, plus a ramp)
    # drifts pv.  The loop feeds the load back into mv, so no open-loop fit is
    # unbiased; the high-pass against drift keeps most of the bias out.  Measured
    # gain errors: 4.6 % filtered, 12.8 % unfiltered.  Tolerance 7 % filtered, and
    # the filter must help.
    t = np.arange(N) * DT
    load = 2.0 * np.sin(2 * np.pi * t / 700.0) + 2.0 * t / 1000.0
    s = run(CONC, 5.0, 5.0, load=load)
    filtered = identify_process(s.mv, s.pv, DT)
    raw = identify_process(s.mv, s.pv, DT, drift_time_constant=math.inf)
    assert (
        filtered.output_error.drift_time_constant is not None
        and raw.output_error.drift_time_constant is None
    )
    assert filtered.process.gain == pytest.approx(3.0, rel=0.07)
    assert abs(filtered.process.gain - 3.0) < abs(raw.process.gain - 3.0)


def test_process_integrating_closed_loop(level_clean):
    s = level_clean
    p = identify_process(s.mv, s.pv, DT, integrating=None)
    # An integrator is exact in the simulator: rounding only.  The FOPTD fits about
    # as well (long time constant), and the simpler model is chosen.
    assert p.integrating
    assert isinstance(p.process, Integrating)
    assert p.process.gain == pytest.approx(1.0, rel=1e-6)
    assert p.process.dead_time == 0.0
    assert p.output_error.u_bias == pytest.approx(40.0, abs=1e-6)  # the balance valve position
    assert p.output_error.foptd_r2 <= p.output_error.integrating_r2


def test_process_integrating_noisy():
    # Noise std 0.2 on a level cycle of about +-3.7: largest gain error over three
    # seeds 0.05 %; tolerance 1 %.
    s = run(LEVEL, 3.0, 3.0, valve="kano", noise_std=0.2, seed=0)
    p = identify_process(s.mv, s.pv, DT, integrating=None)
    assert p.integrating
    assert p.process.gain == pytest.approx(1.0, rel=0.01)
    assert p.output_error.u_bias == pytest.approx(40.0, abs=0.05)


def test_process_forced_structure(level_clean):
    s = level_clean
    p = identify_process(s.mv, s.pv, DT, integrating=False)
    # An FOPTD fitted to an integrator needs a time constant far beyond the cycle
    # (period 9.6 s) and K/tau close to the integrator gain.
    assert isinstance(p.process, FOPTD)
    assert p.process.time_constant > 100.0
    assert p.process.gain / p.process.time_constant == pytest.approx(1.0, rel=0.02)


def test_process_from_fitted_valve_output():
    # Without mv the process input is the stiction model's output for the recorded
    # op.  Started without a kick the model output equals the simulated valve
    # exactly, so the identification is as exact as from mv.
    s = run(CONC, 5.0, 2.0, kick=0.0)
    mv_model = choudhury_model(s.op, 5.0, 2.0)
    assert np.max(np.abs(mv_model - s.mv)) < 1e-9
    p = identify_process(mv_model, s.pv, DT)
    assert p.process.gain == pytest.approx(3.0, rel=1e-4)
    assert p.process.time_constant == pytest.approx(10.0, rel=1e-4)
    assert p.dead_time_samples == 100


def test_process_fit_of_given_process(conc_clean):
    s = conc_clean
    p = process_fit(CONC["process"], s.mv, s.pv, DT)
    # True dynamics: only the biases are fitted, the response is exact.
    assert p.output_error.fit_r2 > 1 - 1e-9
    np.testing.assert_allclose(p.simulate(s.mv, DT)[101:], s.pv[101:], atol=1e-6)
    d = p.to_dict()
    assert d["type"] == "foptd" and d["dead_time_samples"] == 100


def test_process_errors():
    with pytest.raises(DataError):
        identify_process(np.full(200, 50.0), np.arange(200.0), DT)
    with pytest.raises(UsageError):
        identify_process(np.arange(200.0), np.arange(100.0), DT)
    with pytest.raises(UsageError):
        identify_process(np.arange(200.0), np.arange(200.0), DT, integrating="yes")
    with pytest.raises(DataError):
        identify_process(np.arange(10.0), np.arange(10.0), DT)


def test_process_integrating_wandering_load():
    """A level loop whose outflow wanders (random walk plus two steps): the integrated
    wander swamps pv's level, so the integrator comes from pv's differences.

    ``sample_data/level_undershoot.csv`` is made by ``scripts/make_sample_data.py``
    with K = 0.004 /s and a dead time of 5 s (one sample).  The controller moves the
    valve's mean with the load, so part of the valve's slow motion is confounded with
    the disturbance: the gain comes out about 8 % low; 15 % allows for that bias,
    while the level fit alone gave a gain 70 times too small.
    """
    from pathlib import Path

    from stictiondiag.io.tags import read_tags

    tags = read_tags(Path(__file__).resolve().parents[1] / "sample_data" / "level_undershoot.csv")
    p = identify_process(tags.mv, tags.pv, tags.ts, integrating=True)
    assert p.process.gain == pytest.approx(0.004, rel=0.15)
    assert p.process.dead_time <= 2 * tags.ts  # one sample true; the lag adds at most one
    assert p.output_error.fit_r2 > 0.8  # of the filtered differences: the fit explains the slips


@pytest.mark.parametrize("filter_samples", [2.0, 6.0])
def test_controller_with_pv_filter(filter_samples):
    """A controller that filters pv (as distributed control systems do): the law holds
    for the filtered pv only.  Ignoring the filter biases Kc and Ti badly (on the
    sample loops by a factor of 2 to 10); the automatic search finds a filter on its
    grid and recovers the law.  Tolerances: the grid's spacing is a factor of about
    1.4 in the filter time, which moves Kc and Ti by a few % (measured: at most 6 %
    for Ti); 10 % allows for it.
    """
    T = filter_samples * DT
    sim = simulate_loop(
        LEVEL["process"],
        LEVEL["controller"],
        duration=N * DT,
        dt=DT,
        valve="choudhury",
        S=3.0,
        J=3.0,
        sp=setpoint_step(),
        op_bias=40.0,
        pv_filter_time=T,
    )
    plain = identify_controller(sim.sp, sim.pv, sim.op, DT, pv_filter=None)
    auto = identify_controller(sim.sp, sim.pv, sim.op, DT)
    exact = identify_controller(sim.sp, sim.pv, sim.op, DT, pv_filter=T)
    kc, ti = LEVEL["controller"].gain, LEVEL["controller"].integral_time
    assert exact.controller.gain == pytest.approx(kc, rel=0.01)  # the discretisation only
    assert exact.controller.integral_time == pytest.approx(ti, rel=0.01)
    assert auto.pv_filter_time == pytest.approx(T, rel=0.45)  # one grid step
    assert auto.controller.gain == pytest.approx(kc, rel=0.1)
    assert auto.controller.integral_time == pytest.approx(ti, rel=0.1)
    # What the search is for: the plain law leaves at least twice the residual.
    assert 1.0 - auto.fit_r2 < 0.5 * (1.0 - plain.fit_r2)


def test_controller_without_pv_filter_keeps_none():
    # No filter in the loop: the plain law explains op exactly, no filter is kept.
    sim = run(CONC, 5.0, 2.0)
    fit = identify_controller(sim.sp, sim.pv, sim.op, DT)
    assert fit.pv_filter_time == 0.0


def test_controller_quantised_pv_with_small_filter():
    """A pv read at a coarse instrument resolution (Loop 4 of Section 3) changes at
    a quarter of the samples only; a controller filter of a fraction of a sample
    leaves its largest residuals exactly there (the identification ignores a
    filter this small: the automatic search's grid starts at half a sample).  Trimming them as outliers left the
    proportional term no data (Kc = 0: "no PI law found", so no replay and no gap
    diagnosis), and a long pv filter then fitted the stretches between the steps
    exactly with Kc and Ti a tenth of the truth.  The law is found.  Tolerance: the
    filter the fit ignores moves Kc and Ti by less than 0.1 % here (4 % at a
    filter of 0.3 samples); 3 % allows for it.
    """
    rng = np.random.default_rng(6006)
    n, dt, kc, ti = 6000, 2.0, 0.67, 70.0
    # A cycling pv, rounded by the instrument to 0.45 units.
    t = np.arange(n) * dt
    pv_true = 50.0 + 1.5 * np.sin(2 * np.pi * t / 600.0) + np.cumsum(rng.normal(0, 0.02, n))
    pv = 0.45 * np.round(pv_true / 0.45)
    sp = np.full(n, 50.0)
    a = math.exp(-dt / 0.4)  # a fifth of a sample
    pv_f = lfilter([1.0 - a], [1.0, -a], pv, zi=[a * pv[0]])[0]
    e = sp - pv_f
    op = 40.0 + kc * (e + np.cumsum(e) * dt / ti)
    fit = identify_controller(sp, pv, op, dt)
    assert fit.controller.gain == pytest.approx(kc, rel=0.03)
    assert fit.controller.integral_time == pytest.approx(ti, rel=0.03)
    assert fit.pv_filter_time == 0.0


# ------------------------------------------------------------------ growth with length


def test_process_search_span_is_the_record_or_80_periods():
    assert search_span(15_000, 200.0) == 15_000  # 75 periods: the record
    assert search_span(50_000, 200.0) == int(SPAN_PERIODS * 200.0)
    assert search_span(50_000, None) == 50_000  # no cycle: no other time scale
    # A short period (noise, a harmonic) does not cut the ranges below 10 000 samples.
    assert search_span(50_000, 4.0) == MIN_SPAN_SAMPLES
    assert search_span(8000, 4.0) == 8000


def test_process_search_ranges_follow_the_cycle_not_the_record(monkeypatch):
    """Issue 19: on a record of many cycles the dead time and the time constant are
    searched over the ranges of 80 periods of the cycle, not of the record, so a
    record four times as long takes no more cost evaluations (each O(n)) and gives
    the same process.  The loop of benchmarks/scaling.py (concentration loop at
    1 s, period about 140 s: 20 000 samples are 140 periods).  Tolerances: the
    ranges are those of the detected period, which moves by well under 1 % between
    the two records (1 %); the fits of the two records differ by their noise
    (measured 2e-5 on the gain and 2.4e-4 on the time constant; 1e-3); evaluations: the walk along
    the dead time may take one more step (at most 10 more evaluations; the record's
    range took twice as many at 500 000 samples as at 50 000).
    """
    import stictiondiag.identification.process as proc

    sim = simulate_loop(
        CONC["process"],
        CONC["controller"],
        duration=80_500.0,
        dt=1.0,
        S=5.0,
        J=2.0,
        noise_std=0.05,
        seed=11,
    )
    ranges: list[tuple[int, float]] = []
    calls = [0]
    fit_foptd, foptd_oe = proc.fit_foptd, proc.foptd_oe

    def spy_fit(u, y_f, dt, b, d_max, tau_max):
        ranges.append((d_max, tau_max))
        return fit_foptd(u, y_f, dt, b, d_max, tau_max)

    def spy_oe(*args):
        calls[0] += 1
        return foptd_oe(*args)

    monkeypatch.setattr(proc, "fit_foptd", spy_fit)
    monkeypatch.setattr(proc, "foptd_oe", spy_oe)
    fits, counts = [], []
    for n in (20_000, 80_000):
        calls[0] = 0
        fits.append(
            identify_process(sim.mv[500 : 500 + n], sim.pv[500 : 500 + n], 1.0, integrating=False)
        )
        counts.append(calls[0])
    (d_short, tau_short), (d_long, tau_long) = ranges
    assert 100 < d_short / (MAX_DEAD_TIME_FRACTION * SPAN_PERIODS) < 200  # a period
    assert d_long == pytest.approx(d_short, rel=0.01)
    assert tau_long == pytest.approx(tau_short, rel=0.01)
    assert d_short < MAX_DEAD_TIME_FRACTION * 20_000 and tau_short < 20.0 * 20_000
    assert counts[1] <= counts[0] + 10
    short, long = fits
    assert long.dead_time_samples == short.dead_time_samples == 10
    assert long.process.gain == pytest.approx(short.process.gain, rel=1e-3)
    assert long.process.time_constant == pytest.approx(short.process.time_constant, rel=1e-3)


def test_loop_type_lag_at_the_top_of_the_range_is_an_integrator(monkeypatch):
    """The level loop (Table 3) with mv: the self-regulating fit's time constant runs
    past the record, so the process is integrating.  On a record of thousands of
    cycles the time constant is searched up to 1600 periods only, shorter than the
    record; a fit at the top of that range is read the same way.  Shown here with
    the span cut to 2 periods and no floor (time constants up to 40 periods, 320 s, against a
    record of 600 s): without the top-of-range rule the two fits are alike and the
    loop was left undecided."""
    import stictiondiag.identification.process as proc
    from stictiondiag.identification.looptype import infer_integrating
    from stictiondiag.io.tags import Tags

    sim = simulate_loop(
        LEVEL["process"],
        LEVEL["controller"],
        duration=650.0,
        dt=DT,
        S=3.0,
        J=3.0,
        noise_std=0.01,
        seed=3,
        op_bias=40.0,
        pv_bias=10.0,
    )
    k = slice(500, None)
    tags = Tags.from_arrays(sim.pv[k], sim.op[k], mv=sim.mv[k], sp=sim.sp[k], ts=DT)
    decided, why = infer_integrating(tags)
    assert decided is True and "exceeds the record" in why
    monkeypatch.setattr(proc, "SPAN_PERIODS", 2.0)
    monkeypatch.setattr(proc, "MIN_SPAN_SAMPLES", 0)
    decided, why = infer_integrating(tags)
    assert decided is True and "top of the range searched" in why


def test_solve_normal_survives_a_singular_system_in_its_batch():
    """A batch of normal equations with one singular system (two coinciding
    regressors) is solved, not refused: numpy's batched solve raises for the whole
    batch, which reached a user as a traceback from ``analyze``.  The regular system
    keeps its exact solution (to rounding, 1e-12), and the singular one gets the
    least-norm solution, whose fitted values are still the least-squares ones."""
    from stictiondiag.identification.process import solve_normal

    rng = np.random.default_rng(0)
    X = rng.normal(size=(50, 2))
    Xs = np.column_stack([X[:, 0], X[:, 0]])  # two identical columns: singular
    y = X @ np.array([1.5, -0.5]) + 0.01 * rng.normal(size=50)
    A = np.stack([X.T @ X, Xs.T @ Xs])
    g = np.stack([X.T @ y, Xs.T @ y])
    mse, beta = solve_normal(A, g, float(y @ y), 50)
    assert np.allclose(beta[0], np.linalg.solve(X.T @ X, X.T @ y), rtol=1e-12, atol=1e-12)
    # Least norm on the singular system: the two equal coefficients share the slope.
    b1 = float(X[:, 0] @ y / (X[:, 0] @ X[:, 0]))
    assert np.allclose(beta[1], [b1 / 2, b1 / 2], rtol=1e-9)
    assert np.all(np.isfinite(mse))


def test_r_squared_of_nothing_is_nan_without_a_warning():
    # An identification left with no samples to score (seen on a generated gap case)
    # printed numpy's "Mean of empty slice" on the user's terminal.
    import warnings

    from stictiondiag.identification.numerics import r_squared

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert math.isnan(r_squared(np.array([]), np.array([])))
    assert r_squared(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 3.0])) == 1.0
