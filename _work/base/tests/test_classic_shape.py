"""Tests of the shape tests of stiction.classic (He et al. 2007, Rossi & Scali 2005),
Kano et al. (2004), and of run_classic / classic_features.

Each closed-loop case is one of the paper loops of Choudhury, Thornhill & Shah (2005)
(Eq. 3, Table 3), simulated with :func:`stictiondiag.models.loops.simulate_paper_loop`:
the stiction cases are the Table 3 limit cycles; the linear cases replace the valve's
stiction by an external sinusoidal load, the classic confounder of every shape test.
Measurement noise (5 % of pv's spread) is added to the recorded pv only, so the valve
model sees the paper's noise-free loop.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.signal import sawtooth

from stictiondiag.core.errors import DataError
from stictiondiag.models.loops import simulate_paper_loop
from stictiondiag.stiction import classic
from stictiondiag.stiction.classic import he, kano, rossi_scali

#: (dt [s], duration [s], transient dropped [s]) per paper loop: the concentration
#: loop's 140 s cycle gets about 20 cycles, the level loop's 10 s cycle about 25.
LOOPS = {"concentration": (1.0, 4000.0, 1000.0), "level": (0.1, 300.0, 50.0)}


def loop(name: str, S: float = 0.0, J: float = 0.0, load_period: float | None = None):
    """(pv with measurement noise, op, mv, sp, dt) of a paper loop after its transient."""
    dt, duration, skip = LOOPS[name]
    n = int(round(duration / dt))
    load = None
    if load_period is not None:
        load = np.sin(2.0 * np.pi * np.arange(n) * dt / load_period)
    sim = simulate_paper_loop(name, S, J, duration=duration, dt=dt, load=load)
    k = int(skip / dt)
    pv = np.asarray(sim.pv)[k:]
    rng = np.random.default_rng(7)
    pv = pv + 0.05 * np.std(pv) * rng.standard_normal(pv.size)
    return pv, np.asarray(sim.op)[k:], np.asarray(sim.mv)[k:], np.asarray(sim.sp)[k:], dt


STICKY = {"concentration": (5.0, 2.0), "level": (3.0, 3.0)}  # Table 3 limit cycles
#: Load periods [s] about those of the stiction cycles (REFERENCE.md: 140 s, 9.6 s).
LOAD_PERIOD = {"concentration": 140.0, "level": 10.0}


# ======================================================================================
# He et al. (2007)
# ======================================================================================


def test_he_triangle_and_sine_limits():
    # He et al.'s argument: a triangle fits the triangle exactly (SI -> 1), a sine the
    # sine (SI -> 0).  The residual is the sampling of the zero crossings of a
    # 100-sample cycle (one sample in fifty per half cycle): 1 % of the index.
    t = np.arange(5000)
    tri = sawtooth(2 * np.pi * t / 100, 0.5)
    sine = np.sin(2 * np.pi * t / 100)
    r_tri = he.he_curve_fit(tri, tri, 1.0)
    r_sin = he.he_curve_fit(sine, sine, 1.0)
    assert r_tri.stiction_index == pytest.approx(1.0, abs=0.01)
    assert r_sin.stiction_index == pytest.approx(0.0, abs=0.01)
    assert (r_tri.verdict, r_sin.verdict) == ("stiction", "no_stiction")
    assert r_tri.n_half_cycles == 99  # 50 cycles, partial ends dropped


def test_he_triangle_fit_matches_brute_force():
    rng = np.random.default_rng(0)
    y = rng.standard_normal(40)
    t = np.arange(40)
    best = min(he._ls_sse(y, np.where(t <= c, t / c, (39 - t) / (39 - c))) for c in range(1, 39))
    # Cumulative-sum normal equations against explicit least squares: round-off.
    assert he._triangle_sse(y) == pytest.approx(best, rel=1e-9)


@pytest.mark.parametrize("name", ["concentration", "level"])
def test_he_signal_choice_follows_loop_type(name):
    # He et al. Section 3: the first integrator after the valve makes the triangle:
    # the PI's in the self-regulating loop (op), the process's in the level loop (pv).
    pv, op, _, _, dt = loop(name, *STICKY[name])
    res = he.he_curve_fit(op, pv, dt, integrating=name == "level")
    assert res.signal == ("pv" if name == "level" else "op")
    assert res.stiction_index >= he.HE_STICTION_MIN
    assert res.verdict == "stiction"


@pytest.mark.parametrize("name", ["concentration", "level"])
def test_he_sinusoidal_load_is_not_stiction(name):
    # A linear loop driven by a sinusoidal load: every signal is sinusoidal.
    pv, op, _, _, dt = loop(name, load_period=LOAD_PERIOD[name])
    res = he.he_curve_fit(op, pv, dt, integrating=name == "level")
    assert res.stiction_index <= he.HE_NO_STICTION_MAX
    assert res.verdict == "no_stiction"


def test_he_too_few_half_cycles():
    x = np.sin(np.linspace(0, 3 * np.pi, 300))
    res = he.he_curve_fit(x, x, 1.0)
    assert res.verdict == "inconclusive" and res.stiction_index is None


# ======================================================================================
# Rossi & Scali (2005)
# ======================================================================================


def test_rossi_scali_relay_response_and_sine_limits():
    # A relay (square wave, period 200) through a first-order lag (tau 15): between
    # switchings pv is exactly an exponential, Delta_E -> 1; a sine gives -> -1.  The
    # ten-harmonic low-pass in front of the fit rounds the relay response's corner at
    # each switching, which no exponential follows: about 0.1 of the index is lost
    # there (0.15 allowed); the sine has no corner to lose (0.05 allowed).
    n, period, tau = 6000, 200, 15.0
    u = np.sign(np.sin(2 * np.pi * (np.arange(n) + 0.5) / period))
    y = np.zeros(n)
    a = math.exp(-1.0 / tau)
    for k in range(1, n):
        y[k] = a * y[k - 1] + (1 - a) * u[k - 1]
    y = y[1000:]
    sine = np.sin(2 * np.pi * np.arange(5000) / period)
    r_relay = rossi_scali.rossi_scali_relay(y, 1.0, period)
    r_sin = rossi_scali.rossi_scali_relay(sine, 1.0, period)
    assert r_relay.delta_e == pytest.approx(1.0, abs=0.15)
    assert r_sin.delta_e == pytest.approx(-1.0, abs=0.05)
    assert (r_relay.verdict, r_sin.verdict) == ("stiction", "no_stiction")


@pytest.mark.parametrize("name", ["concentration", "level"])
def test_rossi_scali_paper_loops(name):
    pv, _, _, _, dt = loop(name, *STICKY[name])
    sticky = rossi_scali.rossi_scali_relay(pv, dt, LOAD_PERIOD[name])
    pv, _, _, _, dt = loop(name, load_period=LOAD_PERIOD[name])
    linear = rossi_scali.rossi_scali_relay(pv, dt, LOAD_PERIOD[name])
    assert sticky.verdict == "stiction"
    assert linear.verdict == "no_stiction"


# ======================================================================================
# Kano et al. (2004)
# ======================================================================================


def test_kano_stiction_cycle_sticks_most_of_the_time():
    # In the S = 5, J = 2 limit cycle the valve moves only at its slips and during the
    # short moving phase: it is stuck well over a quarter of every cycle.
    pv, op, mv, _, dt = loop("concentration", 5.0, 2.0)
    res = kano.kano_stick_sections(op, pv, dt, mv=mv)
    assert res.signal == "mv"
    assert res.rho >= kano.KANO_RHO_STICTION
    assert res.verdict == "stiction"


def test_kano_linear_valve_never_sticks():
    pv, op, mv, _, dt = loop("concentration", load_period=140.0)
    res = kano.kano_stick_sections(op, pv, dt, mv=mv)
    assert res.rho <= kano.KANO_RHO_NO_STICTION
    assert res.verdict == "no_stiction"


def test_kano_pv_proxy_only_for_flow_loops():
    pv, op, mv, _, dt = loop("concentration", 5.0, 2.0)
    # A flow follows the valve statically: pv = mv plus sensor noise stands in for mv.
    flow = mv + 0.01 * np.random.default_rng(3).standard_normal(mv.size)
    as_flow = kano.kano_stick_sections(op, flow, dt, loop_type="flow")
    assert as_flow.signal == "pv" and as_flow.verdict == "stiction"
    for lt in ("level", "temperature", None):
        res = kano.kano_stick_sections(op, pv, dt, loop_type=lt)
        assert res.verdict == "not_applicable" and res.rho is None


# ======================================================================================
# run_classic / classic_features
# ======================================================================================


def test_run_classic_level_loop():
    pv, op, mv, sp, dt = loop("level", 3.0, 3.0)
    res = classic.run_classic(pv, op, sp, dt, "level")
    assert res.integrating
    # Horch's integrating test, not the CCF rule, runs on a level loop.
    assert res.horch.method == "second_derivative"
    feats = classic.features_of(res)
    assert tuple(feats) == classic.FEATURE_NAMES
    assert math.isnan(feats["horch_phase_index"])
    assert math.isnan(feats["kano_rho"]) and math.isnan(feats["kano_call"])
    for name in ("he_call", "horch_call", "rossi_scali_call"):
        assert feats[name] == 1.0
    assert feats["oscillation_period_s"] == pytest.approx(9.6, rel=0.05)  # REFERENCE.md
    json.dumps(res.to_dict(), allow_nan=False)


def test_classic_features_with_mv_and_without_oscillation():
    pv, op, mv, sp, dt = loop("concentration", 5.0, 2.0)
    feats = classic.classic_features(pv, op, sp, dt, "composition", mv=mv)
    assert feats["kano_call"] == 1.0 and feats["he_call"] == 1.0
    assert 0.0 <= feats["horch_phase_index"] <= 1.0
    assert feats["ellipse_apparent_stiction"] > 0.0
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(3000)
    res = classic.run_classic(noise, rng.standard_normal(3000), None, 1.0, "flow")
    # No oscillation: the shape fits cannot run; they say so instead of guessing.
    assert res.he is None and res.rossi_scali is None
    assert {t for t, _ in res.errors} == {"he", "rossi_scali"}
    assert math.isnan(classic.features_of(res)["he_si"])


def test_run_classic_bad_input():
    x = np.sin(np.arange(500) / 10.0)
    with pytest.raises(DataError):
        classic.run_classic(x, x[:100], None, 1.0)
    with pytest.raises(DataError):
        classic.run_classic(np.full(500, np.nan), x, None, 1.0)
