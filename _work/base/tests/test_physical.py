"""Physical valve model (Section 4, Eqs. 1-2, Tables 1-2) in open loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stictiondiag.core.errors import UsageError
from stictiondiag.models.physical import (
    VALVE_PARAMETERS,
    PhysicalValve,
    karnopp,
    karnopp_step,
)
from stictiondiag.models.valve import choudhury_model

DT = 0.1
T = np.arange(0.0, 200.0, DT)
#: Fig. 8 / Fig. 11 style input: 10 cm (= 10 %) amplitude, 50 s period, around 50 %.
OP_SINE = 50.0 + 10.0 * np.sin(2 * np.pi * T / 50.0)
#: Largest stem speed of OP_SINE [% of span / s].
SINE_SPEED = 10.0 * 2 * np.pi / 50.0


def test_table_values():
    # Table 1 nominal case and the Table 2 friction cases, verbatim.
    nominal = PhysicalValve.from_case("nominal")
    assert (nominal.mass, nominal.spring_constant, nominal.diaphragm_area) == (
        1.36,
        52500.0,
        0.0645,
    )
    assert (nominal.Fs, nominal.Fc, nominal.Fv) == (1750.0, 1250.0, 612.0)
    # Table 1 prints k/A = 807,692 Pa/m, which is 52,500 / 0.065: the area rounded to
    # 0.065 m^2.  With A = 0.0645 m^2 it is 813,953 Pa/m (0.8 % apart).
    assert nominal.calibration_factor == pytest.approx(807_692, rel=0.01)
    expected = {
        "linear": (45, 45),
        "deadband": (1250, 1250),
        "undershoot_open_loop": (2250, 1250),
        "undershoot_closed_loop": (1000, 400),
        "no_offset": (1750, 0),
        "miscalibrated": (1750, 0),
    }
    for name, (fs, fc) in expected.items():
        v = PhysicalValve.from_case(name)
        assert (v.Fs, v.Fc, v.Fv) == (fs, fc, 612.0)
    assert PhysicalValve.from_case("miscalibrated").calibration == 1.25
    assert set(VALVE_PARAMETERS) == {"nominal", *expected}


def test_valve_is_fast_and_overdamped():
    # Module docstring: natural frequency ~200 rad/s, overdamped with Fv = 612 N s/m.
    v = PhysicalValve()
    assert v.natural_frequency == pytest.approx(196.5, abs=0.1)
    assert v.damping_ratio == pytest.approx(1.145, abs=0.001)


@pytest.mark.parametrize(
    "case",
    [
        "linear",
        "deadband",
        "nominal",
        "undershoot_open_loop",
        "undershoot_closed_loop",
        "no_offset",
    ],
)
def test_quasi_static_equivalence_with_data_driven_model(case):
    """Slow input: the physical model is the data-driven one with S=(Fs+Fc)/k, J=(Fs-Fc)/k."""
    valve = PhysicalValve.from_case(case)
    eq = valve.data_driven_equivalent()
    assert eq["S"] == pytest.approx((valve.Fs + valve.Fc) / valve.spring_constant / 0.01)
    assert eq["J"] == pytest.approx((valve.Fs - valve.Fc) / valve.spring_constant / 0.01)
    mv = karnopp(OP_SINE, valve, DT)
    ref = choudhury_model(OP_SINE, eq["S"], eq["J"])
    settled = slice(len(T) // 4, None)
    # Extremes are stuck positions: exact up to the viscous lag, Fv/k * speed
    # (0.015 % of span at the sine's top speed) -- 0.02 % covers it.
    assert mv[settled].max() == pytest.approx(ref[settled].max(), abs=0.02)
    assert mv[settled].min() == pytest.approx(ref[settled].min(), abs=0.02)
    # Away from the slips the two agree to the viscous lag; a slip takes ~30 ms, so
    # it can land one 0.1-s sample apart in the two models: allow 2 % of samples.
    close = np.abs(mv - ref)[settled] < 0.02 + 1e-3 * SINE_SPEED
    assert close.mean() > 0.98


def test_slip_jump_and_moving_offset():
    # Undershoot (open loop, Table 2) on a slow ramp: the valve breaks away when
    # op - mv reaches Fs/k (4.29 %), slips to op - mv = Fc/k (2.38 %, the data-driven
    # (S - J)/2 of Eq. 4) -- a slip of J = (Fs - Fc)/k = 1.90 % -- and then follows
    # the ramp without sticking again.
    valve = PhysicalValve.from_case("undershoot_open_loop")
    k_pct = valve.spring_constant * 0.01  # N per % of span
    dt, speed = 0.01, 0.5  # [s], [% of span / s]
    t = np.arange(0.0, 60.0, dt)
    op = 50.0 + speed * t
    mv = karnopp(op, valve, dt)
    stuck = np.flatnonzero(np.diff(mv) == 0.0) + 1  # samples still at rest
    # Still stuck at Fs/k, broken away within one more sample of op travel (0.005 %).
    band = np.max(op[stuck] - mv[stuck])
    assert valve.Fs / k_pct - speed * dt <= band <= valve.Fs / k_pct
    assert stuck.max() < 1000  # one stick phase at the start only
    # Moving: offset Fc/k plus the viscous lag Fv/k * speed (0.006 %), to 1e-4 %.
    lag = valve.Fv / valve.spring_constant * speed
    assert np.allclose(op[-2000:] - mv[-2000:], valve.Fc / k_pct + lag, atol=1e-4)
    assert valve.data_driven_equivalent()["J"] == pytest.approx((2250 - 1250) / k_pct)


def test_no_offset_case_catches_up():
    # Fig. 8, fourth row: with Fc = 0 there is no deadband and the slip brings mv back
    # to op (no offset while moving); a slip is J = Fs/k = 3.33 %.
    valve = PhysicalValve.from_case("no_offset")
    mv = karnopp(OP_SINE, valve, DT)
    settled = slice(len(T) // 4, None)
    assert mv[settled].max() == pytest.approx(60.0, abs=0.02)  # viscous lag only
    assert mv[settled].min() == pytest.approx(40.0, abs=0.02)
    assert np.diff(mv).max() == pytest.approx(valve.Fs / valve.spring_constant / 0.01, abs=0.4)


def test_miscalibration_gives_larger_mv_swings():
    # Fig. 8, bottom row: calibration 25 % too large -> mv swings 1.25 x op swings and
    # the op-mv slope while moving is 1.25 (> 1).
    valve = PhysicalValve.from_case("miscalibrated")
    op = 40.0 + 10.0 * np.sin(2 * np.pi * T / 50.0)
    mv = karnopp(op, valve, DT)
    settled = slice(len(T) // 4, None)
    assert np.ptp(mv[settled]) == pytest.approx(1.25 * np.ptp(op[settled]), rel=0.01)
    moving = np.abs(np.diff(mv)) > 0.0
    moving[:-1] &= moving[1:]  # interior of moving stretches (no slip samples)
    slope = np.diff(mv)[moving] / np.diff(op)[moving]
    assert np.median(slope) == pytest.approx(1.25, abs=0.01)  # slip samples excluded


def test_linear_valve_follows_op():
    # Table 2 "linear": viscous friction dominates, input and output in phase
    # (first row of Fig. 8); the stick band (Fs + Fc)/k is 0.17 %.
    mv = karnopp(OP_SINE, PhysicalValve.from_case("linear"), DT)
    assert np.max(np.abs(mv[20:] - OP_SINE[20:])) < 0.1 + 0.02


def test_stuck_valve_holds_position_and_end_stops():
    valve = PhysicalValve.from_case("nominal")
    op = np.full(50, 30.0)
    op[10:] = 32.0  # below the breakaway step (Fs/k = 3.3 %)
    mv = karnopp(op, valve, DT)
    assert np.all(mv == 30.0)  # stuck: position exactly unchanged
    # Miscalibrated valve at full demand: the stem stops at the end of its travel.
    mv = karnopp(np.linspace(50, 100, 200), PhysicalValve.from_case("miscalibrated"), DT)
    assert mv.max() == 100.0


def test_integration_step_convergence():
    # The sub-step is an accuracy choice: halving it must not move the result by
    # more than the O(h) event-location error (a few 1e-3 % of span).
    coarse = karnopp(OP_SINE, PhysicalValve.from_case("nominal"), DT)
    fine = karnopp(OP_SINE, PhysicalValve.from_case("nominal", time_step=2.5e-5), DT)
    settled = slice(len(T) // 4, None)
    assert np.max(np.abs(coarse - fine)[settled]) < 0.01


def test_stribeck_friction():
    # Olsson (1996) Stribeck term: friction falls from Fs at rest to Fc with speed.
    # A very small Stribeck velocity is Karnopp's model (Eq. 2) again; a realistic one
    # raises the friction as the input slows near its turning points, so the valve
    # stops earlier (lower peaks) and still sticks for long stretches.
    base = karnopp(OP_SINE, PhysicalValve.from_case("nominal"), DT)
    tiny = karnopp(OP_SINE, PhysicalValve.from_case("nominal", stribeck_velocity=1e-8), DT)
    strib = karnopp(OP_SINE, PhysicalValve.from_case("nominal", stribeck_velocity=1e-3), DT)
    settled = slice(len(T) // 4, None)
    assert np.max(np.abs(tiny - base)[settled]) < 0.01  # sub-step resolution
    assert strib[settled].max() < base[settled].max() - 0.1
    assert np.mean(np.diff(strib) == 0.0) > 0.2


def test_zoh_staircase_makes_valve_stick_between_steps():
    # A 0.1-s staircase on a valve with Fs > Fc: after each step the valve comes to
    # rest in ~30 ms and needs Fs to move again, so it sticks for several steps.
    valve = PhysicalValve.from_case("nominal")
    op = 50.0 + 0.05 * np.arange(400)  # 0.05 % per 0.1-s step
    smooth = karnopp(op, valve, DT, hold="linear")
    stair = karnopp(op, valve, DT, hold="zoh")
    assert np.mean(np.diff(smooth[100:]) == 0) < 0.05
    assert np.mean(np.diff(stair[100:]) == 0) > 0.5


def test_karnopp_step_at_rest_obeys_eq2():
    p = PhysicalValve().kernel_parameters(1e-4)
    k = 52500.0
    # |Fa + Fr| <= Fs: stays stuck (Eq. 2, line 2).
    x, v = karnopp_step(0.5 + 1700.0 / k, 0.5, 0.0, p)
    assert (x, v) == (0.5, 0.0)
    # |Fa + Fr| > Fs: breaks away in the direction of the net force (line 3).
    x, v = karnopp_step(0.5 - 1800.0 / k, 0.5, 0.0, p)
    assert v < 0.0 and x < 0.5


@pytest.mark.parametrize(
    "kwargs",
    [
        {"Fs": 100.0, "Fc": 200.0},
        {"mass": 0.0},
        {"Fv": -1.0},
        {"calibration": float("nan")},
        {"stribeck_velocity": 0.0},
        {"time_step": "1e-4"},
    ],
)
def test_invalid_parameters(kwargs):
    with pytest.raises(UsageError):
        PhysicalValve(**kwargs)


def test_invalid_calls():
    with pytest.raises(UsageError, match="unknown physical valve case"):
        PhysicalValve.from_case("sticky")
    with pytest.raises(UsageError):
        karnopp(OP_SINE, PhysicalValve(), 0.0)
    with pytest.raises(UsageError):
        karnopp(OP_SINE, PhysicalValve(), DT, hold="cubic")
    with pytest.raises(UsageError):
        karnopp(np.array([1.0, math.nan]), PhysicalValve(), DT)
    with pytest.raises(UsageError):
        karnopp(OP_SINE, {"Fs": 1.0}, DT)
    assert karnopp(np.array([]), PhysicalValve(), DT).size == 0


def test_to_dict_is_json_ready():
    import json

    d = PhysicalValve.from_case("miscalibrated").to_dict()
    assert json.loads(json.dumps(d, allow_nan=False))["calibration"] == 1.25
    assert d["stribeck_velocity"] is None
