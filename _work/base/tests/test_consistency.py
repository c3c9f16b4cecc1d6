"""Describing-function consistency of an identified loop (Section 6): the sampled
process of the Hammerstein fit, the linear loop's margins, op's fundamental amplitude
and the features built from them."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from stictiondiag.models.describing import predict_limit_cycle, stability_margins
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI, Integrating, SampledLag
from stictiondiag.signals.oscillation import detect_oscillation, fundamental_amplitude
from stictiondiag.stiction.consistency import FILL, LOG_CAP, describing_features
from stictiondiag.stiction.hammerstein import fit_hammerstein


def test_sampled_lag_tends_to_the_continuous_foptd_at_low_frequency():
    # z = exp(i w dt) -> 1 + i w dt: at w dt = 1e-3 the sampled lag and dead time differ
    # from K e^{-theta s}/(tau s + 1) by about w dt / 2 in phase (the zero-order
    # hold's half sample), so 1e-3 relative.
    dt = 0.1
    p = SampledLag(0.0, 3.0, 10.0, 10.0, dt)
    w = np.array([1e-3, 1e-2])
    ref = FOPTD(3.0, 10.0, 10.0).frequency_response(w)
    got = p.frequency_response(w)
    assert np.allclose(np.abs(got), np.abs(ref), rtol=2e-3)
    assert np.allclose(np.angle(got), np.angle(ref), atol=1e-3)


def test_sampled_integrator_has_gain_per_sample():
    # b0 per sample = K dt, so b0 / (1 - z^-1) -> K / s as w dt -> 0 (relative 1e-3).
    dt = 0.1
    p = SampledLag(1.0 * dt, 0.0, 0.0, 0.0, dt, integrating=True)
    w = np.array([1e-2])
    assert np.allclose(p.frequency_response(w), Integrating(1.0).frequency_response(w), rtol=1e-3)


def test_margins_of_the_concentration_loop_are_the_analytic_ones():
    # C G = 0.2 (10 s + 1)/(10 s) 3 e^{-10 s}/(10 s + 1) = 0.06 e^{-10 s} / s (the PI's
    # zero cancels the lag): phase -pi at w = pi/20, GM = (pi/20)/0.06 = 2.618;
    # |G0| = 1 at w = 0.06, PM = 90 - 0.6 rad = 55.62 deg.  Grid interpolation: 1e-3.
    m = stability_margins(FOPTD(3.0, 10.0, 10.0), PI(0.2, 10.0))
    assert m.gain_margin == pytest.approx(math.pi / 20 / 0.06, rel=1e-3)
    assert m.phase_margin_deg == pytest.approx(90.0 - math.degrees(0.6), abs=0.05)


def test_margins_fall_below_one_for_an_unstable_loop():
    # Three times the gain of a loop with GM 2.618: GM 0.873, the linear loop is unstable.
    m = stability_margins(FOPTD(3.0, 10.0, 10.0), PI(0.6, 10.0))
    assert m.gain_margin == pytest.approx(math.pi / 20 / 0.18, rel=1e-3)
    assert m.phase_margin_deg < 0


def test_df_on_the_sampled_level_loop_matches_the_reference():
    # REFERENCE.md, closed loops: level loop G = 1/s, C = 0.4 (2 s + 1)/(2 s), S = J = 3:
    # DF period 9.8 s, op amplitude 1.69 (rounded).  Sampled at 0.1 s with the one-
    # sample dead time the simulator has, it stays within 3 %.
    p = SampledLag(0.1, 0.0, 0.0, 0.1, 0.1, integrating=True)
    pred = predict_limit_cycle(p, PI(0.4, 2.0), 3.0, 3.0, n_amplitudes=120, n_frequencies=3000)
    assert pred.limit_cycle and pred.stable
    assert pred.period_s == pytest.approx(9.8, rel=0.03)
    assert pred.amplitude_op == pytest.approx(1.69, rel=0.03)


def test_fundamental_amplitude_of_sine_and_triangle():
    # A sine's fundamental is its amplitude; a triangle's 8/pi^2 of its peak (Fourier
    # series).  40.5-sample period: the per-window sums leak about 1 % at most.
    k = np.arange(4000)
    period = 40.5
    sine = 2.0 * np.sin(2 * np.pi * k / period) + 0.001 * k  # a ramp: drift removed
    tri = 4.0 * np.abs((k / period) % 1.0 - 0.5) - 1.0
    assert fundamental_amplitude(sine, period) == pytest.approx(2.0, rel=0.015)
    assert fundamental_amplitude(tri, period) == pytest.approx(8 / np.pi**2, rel=0.015)
    assert fundamental_amplitude(sine[:30], period) is None


def _loop(S, J, load=None, seed=1):
    """The paper's concentration loop at 1 s, 2000 samples after a 1000-sample start."""
    sim = simulate_loop(
        FOPTD(3.0, 10.0, 10.0),
        PI(0.2, 10.0),
        duration=3000.0,
        dt=1.0,
        valve="choudhury" if S > 0 else "linear",
        S=S,
        J=J,
        load=load,
        seed=seed,
    )
    pv, op, sp = sim.pv[1000:], sim.op[1000:], sim.sp[1000:]
    data = SimpleNamespace(op=op, pv=pv, sp=sp, ts=1.0, integrating=False, mv=None)
    fit = fit_hammerstein(op, pv, 1.0, integrating=False, flow_loop=False)
    return fit, data, detect_oscillation(pv, 1.0).period_s


def test_a_sticky_loop_is_consistent_with_its_describing_function():
    # Concentration loop, S = J = 5 (REFERENCE.md: DF period 82.9 s against 72.5 s
    # simulated, the describing function's own error, 13 %; op amplitude 2.95).  The
    # identified loop and fitted S, J must predict a stable cycle within that error plus
    # the fit's (a factor 1.35 in period, 1.25 in op amplitude), and the linear loop
    # is stable (analytic GM 2.618, log 0.96; the fitted process within 10 %).
    fit, data, period = _loop(5.0, 5.0)
    f = describing_features(fit, data, period)
    assert f["df_available"] == 1.0 and f["df_cycle"] == 1.0
    assert f["df_period_miss"] < math.log(1.35)
    assert abs(f["df_amplitude_ratio"]) < math.log(1.25)
    assert f["linear_gain_margin"] == pytest.approx(math.log(2.618), abs=0.1)


def test_a_linear_valve_under_an_external_cycle_predicts_no_valve_cycle():
    # A linear valve and a 100-s sinusoidal load: the fit finds no friction, so the
    # describing function predicts no cycle and the features say so (their fill
    # values for a missing prediction).
    k = np.arange(3000)
    fit, data, period = _loop(0.0, 0.0, load=2.0 * np.sin(2 * np.pi * k / 100.0))
    assert period == pytest.approx(100.0, rel=0.05)
    f = describing_features(fit, data, period)
    assert f["df_cycle"] == 0.0
    assert f["df_period_miss"] == pytest.approx(LOG_CAP)
    assert f["df_amplitude_ratio"] == pytest.approx(-LOG_CAP)


def test_no_hammerstein_fit_gives_the_fill_values():
    fit, data, period = _loop(5.0, 5.0)
    from dataclasses import replace

    assert describing_features(replace(fit, method="mv_segments"), data, period) == FILL
    assert describing_features(fit, None, period) == FILL
