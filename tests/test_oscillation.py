"""Tests of the ACF zero-crossing oscillation detector (Thornhill et al. 2003)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import sawtooth, square

from stictiondiag import UsageError, choudhury_model
from stictiondiag.signals import oscillation
from stictiondiag.signals.oscillation import (
    MIN_CYCLES,
    REGULARITY_THRESHOLD,
    Absence,
    acf_period_samples,
    autocorrelation,
    detect_oscillation,
    dominant_period,
)

DT = 0.1  # [s]
T = np.arange(0.0, 1000.0, DT)  # 10 000 samples, like a plant record


def _acf_tolerance(n_cycles: float) -> float:
    """Relative period tolerance from the finite-record term of the ACF (see below)."""
    return max(2e-3, 1.0 / (4 * np.pi**2 * n_cycles))


@pytest.mark.parametrize("period", [7.3, 50.0, 180.0])
def test_clean_sine_period_and_amplitude(period):
    x = 3.0 + 2.0 * np.sin(2 * np.pi * T / period + 0.4)
    osc = detect_oscillation(x, DT)
    assert osc.present
    # The ACF of a finite record is the tapered cosine plus an end term of relative
    # size ~ 1/(2 pi n_cycles) that shifts the zero crossings by up to about
    # 1/(4 pi^2 n_cycles) of a period (0.5 % at 5.5 cycles, 0.06 % at 137).
    assert osc.period_s == pytest.approx(period, rel=_acf_tolerance(T[-1] / period))
    # The window maximum misses the true peak by at most half a sample of phase:
    # 2 (1 - cos(pi dt / T)) is below 1e-3 for these periods.
    assert osc.amplitude == pytest.approx(2.0, rel=1e-3)
    assert osc.regularity > REGULARITY_THRESHOLD
    assert osc.n_cycles == pytest.approx(T[-1] / period, rel=5e-3)


@pytest.mark.parametrize("noise_std", [0.3, 1.0])
def test_noisy_sine(noise_std):
    rng = np.random.default_rng(1)
    x = np.sin(2 * np.pi * T / 40.0) + rng.normal(0.0, noise_std, T.size)
    osc = detect_oscillation(x, DT)
    assert osc.present
    # ACF averaging over 10 000 samples keeps the zero crossings within about 1 %
    # of the period even at unit signal-to-noise ratio.
    assert osc.period_s == pytest.approx(40.0, rel=0.01)
    # Noise widens the per-cycle range even after smoothing; the amplitude is
    # within 25 % at a noise std of a third of the amplitude, and at most doubled
    # at unit noise (the estimator is a half range, not a fitted sine).
    upper = 1.25 if noise_std < 0.5 else 2.0
    assert 0.9 <= osc.amplitude <= upper


def test_square_and_triangular_limit_cycles():
    tri = 1.5 * sawtooth(2 * np.pi * T / 73.0, 0.5)
    sq = 4.0 * square(2 * np.pi * T / 37.0, duty=0.3)  # asymmetric halves
    o_tri = detect_oscillation(tri, DT)
    o_sq = detect_oscillation(sq, DT)
    assert o_tri.present and o_sq.present
    # Periods from alternate zero crossings: an asymmetric square wave still gives
    # the full period; interpolation error well below one sample (0.1 s).
    assert o_tri.period_s == pytest.approx(73.0, abs=0.05)
    assert o_sq.period_s == pytest.approx(37.0, abs=0.05)
    # Triangle: the sample nearest a corner is within one sample slope of the peak
    # (4 A dt / T = 0.8 %).  Square wave: plateau values, up to the drift line
    # through the cycle means, which the one-sample quantisation of each cycle's
    # duty tilts by < 1e-4 of the amplitude.
    assert o_tri.amplitude == pytest.approx(1.5, rel=0.01)
    assert o_sq.amplitude == pytest.approx(4.0, rel=1e-4)


def test_simulated_stiction_output_open_loop():
    # mv of the Fig. 11 undershoot valve: a stick-slip staircase-like wave.
    op = 50.0 + 10.0 * np.sin(2 * np.pi * T / 50.0)
    mv = choudhury_model(op, 5.0, 2.0)
    osc = detect_oscillation(mv, DT)
    assert osc.present
    # Same period as the input; ACF crossing interpolation error < 1 sample.
    assert osc.period_s == pytest.approx(50.0, abs=0.1)
    # Table for Fig. 11 (REFERENCE.md): mv between 41.5 and 58.5 -> half range 8.5,
    # to one sample's change of op (2 pi 10 dt / 50 = 0.13).
    assert osc.amplitude == pytest.approx(8.5, abs=0.13)


def test_decaying_transient_is_not_an_oscillation():
    x = 5.0 * np.exp(-T / 150.0) * np.sin(2 * np.pi * T / 50.0)
    osc = detect_oscillation(x, DT)
    assert not osc.present
    assert "decaying" in osc.reason and osc.absence is Absence.DECAYING
    assert osc.period_s is None and osc.amplitude is None


def test_sustained_but_growing_cycle_is_an_oscillation():
    # A limit cycle building up from a kick grows before it settles.
    env = 1.0 - np.exp(-T / 100.0)
    osc = detect_oscillation(env * np.sin(2 * np.pi * T / 50.0), DT)
    assert osc.present
    assert osc.period_s == pytest.approx(50.0, rel=0.01)


@pytest.mark.parametrize("seed", range(5))
def test_white_noise_is_not_an_oscillation(seed):
    x = np.random.default_rng(seed).normal(size=5000)
    assert not detect_oscillation(x, 1.0).present


def test_random_walk_is_not_an_oscillation():
    x = np.cumsum(np.random.default_rng(3).normal(size=5000))
    assert not detect_oscillation(x, 1.0).present


def test_too_few_cycles():
    x = np.sin(2 * np.pi * T / 400.0)  # 2.5 cycles
    osc = detect_oscillation(x, DT)
    assert not osc.present
    assert MIN_CYCLES == 3.0
    # Each reason comes with its category, which code reads (not the reason's words):
    # 2.5 cycles leave the autocorrelation 4 zero crossings, 2.8 enough for a period.
    assert osc.absence is Absence.FEW_CROSSINGS
    osc = detect_oscillation(np.sin(2 * np.pi * T / (1000.0 / 2.8)), DT)
    assert osc.absence is Absence.FEW_CYCLES and osc.reason.startswith("only 2.8 cycles")


def test_trend_does_not_mask_oscillation():
    x = 0.05 * T + np.sin(2 * np.pi * T / 25.0)
    osc = detect_oscillation(x, DT)
    assert osc.present
    # A linear drift is removed exactly by detrending.
    assert osc.period_s == pytest.approx(25.0, rel=2e-3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_level_shift_does_not_hide_a_stick_slip_cycle(seed, monkeypatch):
    # A triangular cycle (57 samples) under a level shift of 1.5 peak-to-peaks halfway:
    # the straight line's ACF barely crosses zero (1 crossing), so without the seeded
    # periods no cycle is found; seeded from the ACF's peak, the running mean over
    # three periods removes the shift and the cycle's period comes back.  The
    # tolerance is the smoothing of the step by that running mean (measured 56.7).
    k = np.arange(1000)
    rng = np.random.default_rng(seed)
    x = sawtooth(2 * np.pi * k / 57.0, 0.5) + 3.0 * (k >= 500) + 0.2 * rng.standard_normal(k.size)
    osc = detect_oscillation(x, 1.0)
    assert osc.present
    assert osc.period_s == pytest.approx(57.0, rel=0.02)
    monkeypatch.setattr(oscillation, "SEED_PEAKS", 0)
    line = detect_oscillation(x, 1.0)
    assert not line.present and line.absence is Absence.FEW_CROSSINGS


@pytest.mark.parametrize("walk", [0.0, 0.1], ids=["white", "walk + white"])
def test_seeded_periods_find_no_cycle_in_white_noise_or_a_walk_under_it(walk):
    # scripts/oscillation_false_cycles.py measures 0 of 60 for both at 1441 samples
    # (and the coloured noises the seeds do call, beside the straight line's calls).
    def draw(s):
        e = np.random.default_rng(s).standard_normal(1441)
        return walk * np.cumsum(e) + np.random.default_rng(1000 + s).standard_normal(1441)

    assert sum(detect_oscillation(draw(s), 1.0).present for s in range(20)) == 0


@pytest.mark.parametrize(
    "x",
    [np.full(500, 3.0), np.zeros(1), np.array([]), np.arange(10.0), np.linspace(0, 1, 300)],
    ids=["constant", "one", "empty", "short", "ramp"],
)
def test_degenerate_signals_do_not_crash(x):
    osc = detect_oscillation(x, 1.0)
    assert not osc.present
    assert osc.reason and osc.absence in (Absence.FEW_SAMPLES, Absence.CONSTANT, Absence.RAMP)
    json.dumps(osc.to_dict())


def test_nan_are_interpolated():
    x = np.sin(2 * np.pi * T / 50.0)
    x[[0, 100, 5000, 5001]] = np.nan
    osc = detect_oscillation(x, DT)
    assert osc.present
    # Four samples bridged by interpolation move the ACF negligibly.
    assert osc.period_s == pytest.approx(50.0, rel=2e-3)


def test_all_nan_is_not_an_oscillation():
    assert not detect_oscillation(np.full(100, np.nan), 1.0).present


@pytest.mark.parametrize("dt", [0.0, -1.0, float("nan"), "abc"])
def test_bad_dt_raises_usage_error(dt):
    with pytest.raises(UsageError):
        detect_oscillation(np.sin(np.arange(100.0)), dt)


def test_to_dict_is_json_with_plain_types():
    d = detect_oscillation(np.sin(2 * np.pi * T / 50.0), DT).to_dict()
    text = json.dumps(d)
    assert "NaN" not in text and "Infinity" not in text
    assert all(type(v) in (bool, float, type(None)) for k, v in d.items() if k != "reason")
    assert set(d) >= {"present", "period_s", "amplitude", "regularity", "n_cycles"}


def test_regularity_is_finite_for_a_perfect_cycle():
    # A perfectly periodic square wave has identical ACF intervals; the
    # regularity is capped so that it stays a finite JSON number.
    x = np.tile(np.r_[np.ones(50), -np.ones(50)], 30)
    osc = detect_oscillation(x, 1.0)
    assert osc.present and math.isfinite(osc.regularity)
    # Finite-record ACF term, as for the sines above (30 cycles).
    assert osc.period_s == pytest.approx(100.0, rel=_acf_tolerance(30))


def test_dominant_period_and_acf():
    x = np.sin(2 * np.pi * T / 30.0)
    # Same estimate as detect_oscillation, without the decision.
    assert dominant_period(x, DT) == pytest.approx(30.0, rel=2e-3)
    assert dominant_period(np.ones(100), 1.0) is None
    # The period in samples is the same estimate before the sample time scales it:
    # 300 samples within the tolerance above, and equal to the last bit once scaled.
    assert acf_period_samples(x) == pytest.approx(300.0, rel=2e-3)
    assert acf_period_samples(x) * DT == dominant_period(x, DT)
    assert acf_period_samples(np.ones(100)) is None
    with pytest.raises(UsageError):
        dominant_period(x, 0.0)
    acf = autocorrelation(x)
    assert acf[0] == pytest.approx(1.0)
    # Half a period later a sine's ACF is about -1, tapered by the biased
    # estimator's (1 - k/n) factor.
    k = 150
    assert acf[k] == pytest.approx(-(1 - k / T.size), abs=0.01)


def test_dt_scales_the_period_only():
    x = np.sin(2 * np.pi * np.arange(3000) / 60.0)
    a = detect_oscillation(x, 1.0)
    b = detect_oscillation(x, 0.5)
    # Same samples, half the sample time: exactly half the period, same rest.
    assert b.period_s == pytest.approx(a.period_s / 2, rel=1e-12)
    assert b.amplitude == a.amplitude and b.regularity == a.regularity


SAMPLE_DATA = Path(__file__).resolve().parents[1] / "sample_data"
#: Periods [s] the detector found in the sample loops before drift was removed over
#: a few periods (sample_data/README.md lists the pv periods).
SAMPLE_PERIODS = {
    ("level_undershoot.csv", "pv"): 1011.23,
    ("level_no_mv.csv", "pv"): 266.42,
    ("slave_flow_stickslip.csv", "pv"): 183.24,
    ("slave_flow_stickslip.csv", "op"): 183.23,
    ("slave_flow_stickslip.csv", "mv"): 183.24,
    ("temperature_quantised.csv", "pv"): 7687.29,
}


def test_drifting_sawtooth_op_of_level_undershoot_is_regular():
    # Issue 18: op of the level loop is a clean sawtooth on steps and a wander (it
    # follows the inflow); the ACF after a straight line alone is the drift's, with
    # regularity 0.19.  Detrended over three periods it is the cycle's: measured
    # 26.7 (the issue found about 23 by hand).  > 10 asks for a cycle an order of
    # magnitude more regular than Thornhill's threshold of 1.  Its period is pv's
    # (the same limit cycle): within 1 %, measured 0.1 %.
    from stictiondiag.io.tags import read_tags

    tags = read_tags(SAMPLE_DATA / "level_undershoot.csv")
    op = detect_oscillation(tags.op, tags.ts)
    pv = detect_oscillation(tags.pv, tags.ts)
    assert op.present and pv.present
    assert op.regularity > 10.0
    assert op.period_s == pytest.approx(pv.period_s, rel=0.01)


@pytest.mark.parametrize(("name", "signal"), sorted(SAMPLE_PERIODS))
def test_sample_loops_keep_their_periods(name, signal):
    # The detrend changes which drift is removed, not the cycle, so the ACF zero
    # crossings move by a small part of their own scatter: the mean of m period
    # estimates has a standard error of mean / (3 r sqrt(m)), 0.01-4 % for these
    # loops (regularity r from 2.5 to thousands, m = 9).  1 % holds the most
    # regular ones close and still lets the least regular (temperature, r = 2.5)
    # pass; measured changes at most 0.15 %.
    from stictiondiag.io.tags import read_tags

    tags = read_tags(SAMPLE_DATA / name)
    osc = detect_oscillation(getattr(tags, signal), tags.ts)
    assert osc.present
    assert osc.period_s == pytest.approx(SAMPLE_PERIODS[(name, signal)], rel=0.01)
