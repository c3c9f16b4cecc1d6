"""He et al.'s two-parameter stick model and the band-hold valve
(stictiondiag.models.stick_models), open loop and in the closed-loop simulator."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag import UsageError
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI
from stictiondiag.models.stick_models import stick_model
from stictiondiag.signals.oscillation import detect_oscillation

#: A slow triangle between 40 and 60 % in steps of 0.01 %: the stick band and the
#: slip are resolved to one step.
STEP = 0.01
TRI = np.concatenate([np.arange(50, 60, STEP), np.arange(60, 40, -STEP), np.arange(40, 60, STEP)])


def _moves(y):
    return np.flatnonzero(np.diff(y) != 0) + 1


def test_he_model_staircase_and_reversal():
    # S = 4, J = 1: f_s = 2.5, f_d = 1.5.  Moving one way, each slip leaves u_r = f_d,
    # so the valve sticks again and slips each time the demand has gone f_s - f_d = J
    # further (steps of J, within one 0.01 step), landing f_d behind its demand.  After
    # the reversal at 60 % the residual force at the peak (between f_d and f_d + J)
    # must be undone and f_s built the other way: the first slip comes after a fall of
    # between S and S + J.
    y = stick_model(TRI, 4.0, 1.0, model="he")
    down = slice(1000, 3000)
    x, yd = TRI[down], y[down]
    k = _moves(yd)
    fall = 60.0 - x[k[0]]
    assert 4.0 - STEP <= fall <= 5.0 + STEP
    assert np.allclose(yd[k] - x[k], 1.5, atol=1e-9)
    assert np.allclose(-np.diff(yd[k[:15]]), 1.0 + STEP, atol=STEP)


def test_band_model_staircase_of_S():
    # S = 3: the valve holds until the demand is more than 3 from it, then jumps to the
    # demand, so it moves in steps of S (plus the 0.01 step that crosses the band) and
    # sits on its demand after each.
    y = stick_model(TRI, 3.0, 0.0, model="band")
    k = _moves(y)
    assert np.array_equal(y[k], TRI[k])
    assert np.allclose(np.abs(np.diff(y[k[:10]])), 3.0 + STEP, atol=STEP / 2)


def test_bad_parameters():
    with pytest.raises(UsageError):
        stick_model(TRI, 1.0, 2.0, model="he")  # J > S: f_d < 0
    with pytest.raises(UsageError):
        stick_model(TRI, 1.0, 0.0, model="karnopp")


@pytest.mark.parametrize("valve", ["he", "band"])
def test_closed_loop_kernel_runs_the_same_valve_and_cycles(valve):
    # The closed-loop kernel calls the same step as the open-loop model: from the
    # first movement on (the two start from different rest states) the recorded valve
    # position is the model run on the recorded op, to rounding.  In the
    # concentration loop (Eq. 3) a valve that sticks and slips makes a sustained,
    # regular limit cycle (Section 6.4: any slip jump does; He's valve sticks for
    # long stretches before its cycle settles, so the record is 8000 s).
    sim = simulate_loop(
        FOPTD(3.0, 10.0, 10.0), PI(0.2, 10.0), valve=valve, S=4.0, J=2.0, duration=8000.0, dt=1.0
    )
    mv = stick_model(sim.op, 4.0, 2.0, model=valve, initial_position=float(sim.mv[0]))
    k0 = max(_moves(mv)[0], _moves(sim.mv)[0]) + 1
    assert np.allclose(mv[k0:], sim.mv[k0:], atol=1e-9)
    osc = detect_oscillation(sim.pv[1000:], 1.0)
    assert osc.present and osc.regularity > 3.0
