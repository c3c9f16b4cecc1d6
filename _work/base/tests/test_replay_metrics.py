"""Replay figures read by period, amplitude and waveform (stictiondiag.replay.metrics)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from stictiondiag.replay.metrics import cycle_amplitude, render_metrics, replay_metrics


def _saw(n: int, period: int, amplitude: float) -> np.ndarray:
    """Triangle wave of half peak-to-peak ``amplitude``, period in samples."""
    phase = (np.arange(n) % period) / period
    return amplitude * (4 * np.abs(phase - 0.5) - 1)


def test_amplitude_of_a_drifting_cycle_is_the_cycle_not_the_drift():
    """Issue 18: op drifting under a clean sawtooth was measured by its whole range.
    Per one-period window the drift adds at most half its change over one period."""
    n, period, amplitude = 4000, 200, 5.0
    drift = np.linspace(0.0, 20.0, n)  # 1 % per period
    a = cycle_amplitude(_saw(n, period, amplitude) + drift, period)
    assert abs(a - amplitude) <= 0.5 * 20.0 * period / n + 1e-9
    # Without a period the percentile range takes the drift in: far off.
    assert cycle_amplitude(_saw(n, period, amplitude) + drift, None) > 1.8 * amplitude


def _replay(pv_data, pv_rep, op_data, op_rep, period_data, period_rep):
    return SimpleNamespace(
        period_s={"data": period_data, "replay": period_rep},
        period_signal="pv",
        dt=1.0,
        data={"pv": pv_data, "op": op_data, "mv": None},
        pv=pv_rep,
        op=op_rep,
        waveform={"pv": 0.97, "op": 0.95},
        nrmse={"pv": 1.4, "op": 1.2},
    )


def test_period_amplitude_and_waveform_of_a_replay():
    n = 3000
    t = np.arange(n)
    pv_data = np.sin(2 * np.pi * t / 100)
    pv_rep = 0.8 * np.sin(2 * np.pi * t / 110 + 1.0)  # 10 % slower, 20 % smaller
    op_data = _saw(n, 100, 5.0) + np.linspace(0, 30, n)  # drifts 1 %/period
    op_rep = _saw(n, 110, 5.0)
    m = replay_metrics(_replay(pv_data, pv_rep, op_data, op_rep, 100.0, 110.0))
    assert m.period_error_pct == pytest.approx(10.0, abs=1e-9)
    # One-period windows of the data's period (100 samples) hold both extremes of
    # the 110-sample replay cycle in more than half of the windows: the median is
    # the full amplitude, to the 1 s sampling of the sine peaks (< 0.1 %).
    assert m.amplitude_error_pct["pv"] == pytest.approx(-20.0, abs=0.1)
    # Same measure for both: the drifting op and the clean replay agree to the drift
    # over one period (1 % of span, half of it on the half range: 10 % of 5).
    assert abs(m.amplitude_error_pct["op"]) <= 10.0 + 1e-9
    assert m.waveform == {"pv": 0.97, "op": 0.95} and m.nrmse["pv"] == 1.4
    d = m.to_dict()
    assert d["amplitude"]["pv"]["data"] == pytest.approx(1.0, abs=1e-3)
    line = render_metrics(d)
    assert line.startswith("period +10 % (110 s against 100 s); amplitude pv -20 %")
    assert "waveform agreement [1 = same] pv 0.97, op 0.95" in line
    assert set(m.to_pandas()["signal"]) == {"pv", "op"}


def test_replay_that_does_not_cycle():
    n = 1000
    flat = np.zeros(n)
    cyc = np.sin(2 * np.pi * np.arange(n) / 100)
    m = replay_metrics(_replay(cyc, flat, cyc, flat, 100.0, None))
    assert m.period_error_pct is None
    assert m.amplitude_error_pct["pv"] == pytest.approx(-100.0)
    assert render_metrics(m.to_dict()).startswith("period: the replay does not cycle")


def test_sample_level_loop_amplitudes_are_compared_by_one_measure():
    """Issue 18: on level_undershoot the op lines read "data 5.47, replay 2.73": the
    drifting data op (not detected as oscillating) was measured by its whole range,
    the replay's by its cycle.  By one measure the replay of the same valve (S = 5,
    J = 2.5 in the file's generator) in the identified integrating loop matches op's
    cycle within 10 % (its period is within 10 % too)."""
    from pathlib import Path

    from stictiondiag.analysis import AnalysisConfig, analyze_file

    sample = Path(__file__).resolve().parents[1] / "sample_data" / "level_undershoot.csv"
    a = analyze_file(
        sample, config=AnalysisConfig(gap=False, compensation=False), loop_type="level"
    )
    m = replay_metrics(a.replay)
    assert abs(m.period_error_pct) < 10.0
    for name in ("pv", "op", "mv"):
        assert abs(m.amplitude_error_pct[name]) < 10.0, (name, m.amplitude[name])
    window = int(round(m.period_data_s / a.replay.dt))
    assert m.amplitude["op"]["data"] == cycle_amplitude(a.replay.data["op"], window)


# ------------------------------------------------------------------ cycle reproduction


def _sine(period: float, amplitude: float, n: int = 2000) -> np.ndarray:
    return amplitude * np.sin(2 * np.pi * np.arange(n) / period)


def test_spread_amplitude_of_a_square_wave_is_its_amplitude():
    # 5-95 % spread of a +-2 square wave is 4 exactly (both levels hold 50 % each).
    x = np.where(np.arange(1000) % 100 < 50, 2.0, -2.0)
    from stictiondiag.replay.metrics import spread_amplitude

    assert spread_amplitude(x) == pytest.approx(2.0, abs=1e-12)


def test_cycle_reproduction_within_and_outside_tolerance():
    from stictiondiag.replay.metrics import cycle_reproduction

    data = _sine(100.0, 1.0)
    # 10 % longer period, 20 % larger: within 20 % / 35 %.
    ok = cycle_reproduction(data, _sine(110.0, 1.2), 1.0)
    assert ok.reproduced, ok.reason
    assert ok.period_error_pct == pytest.approx(10.0, abs=2.0)  # ACF period estimate
    assert ok.amplitude_error_pct == pytest.approx(20.0, abs=2.0)  # percentile grid
    long = cycle_reproduction(data, _sine(130.0, 1.0), 1.0)
    assert not long.reproduced and "period" in long.reason
    small = cycle_reproduction(data, _sine(100.0, 0.5), 1.0)
    assert not small.reproduced and "amplitude" in small.reason
    decay = cycle_reproduction(data, _sine(100.0, 1.0) * np.exp(-np.arange(2000) / 300.0), 1.0)
    assert not decay.reproduced and "does not cycle" in decay.reason
