"""The continuous op/pv evidence of the stiction probability
(stictiondiag.stiction.probability_evidence): the classic tests' statistics and the
oscillation's shape, on the paper loops of Choudhury, Thornhill & Shah (2005) with a
sticky valve (Table 3 limit cycles) and with a linear valve under a sinusoidal load
of about the same period (the confounder of every op/pv test), as in
tests/test_classic_shape.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import sawtooth
from test_classic_shape import LOAD_PERIOD, STICKY, loop

from stictiondiag.stiction.probability import (
    CANDIDATES,
    FEATURES,
    classic_votes,
    load_model,
    stiction_probability,
)
from stictiondiag.stiction.probability_evidence import (
    CONTINUOUS,
    NEUTRAL,
    amplitude_lock,
    continuous_features,
    odd_harmonics,
    shape_statistics,
    slope_kurtosis,
)


def _features(name: str, sticky: bool) -> dict:
    if sticky:
        pv, op, _, sp, dt = loop(name, *STICKY[name])
    else:
        pv, op, _, sp, dt = loop(name, load_period=LOAD_PERIOD[name])
    classic = classic_votes(op, pv, sp, dt, name == "level", name)
    q5, q95 = np.percentile(op, [5.0, 95.0])
    return continuous_features(classic, float(q95 - q5))


def test_harmonics_of_pure_waveforms():
    # A square wave's 3rd and 5th harmonics hold 1/9 + 1/25 of the fundamental's
    # power (log10 -0.82), a triangle's 1/81 + 1/625 (-1.87), a sinusoid's none.
    # Tolerance 0.1 in log10 (26 %): the Welch window leaks a little power into the
    # bands, and the median noise floor of a noise-free signal is not exactly 0.
    t = np.arange(4000.0)
    period = 100.0
    square = np.sign(np.sin(2 * np.pi * t / period + 0.1))
    tri = sawtooth(2 * np.pi * t / period, 0.5)
    sine = np.sin(2 * np.pi * t / period)
    assert odd_harmonics(square, 1.0, period) == pytest.approx(-0.82, abs=0.1)
    assert odd_harmonics(tri, 1.0, period) == pytest.approx(-1.87, abs=0.1)
    assert odd_harmonics(sine, 1.0, period) < -3.0
    # Slope kurtosis: a sinusoid's slope is a sinusoid (kurtosis 1.5), a triangle's a
    # square (1.0, log 0; band-limiting to six harmonics rounds its corners, hence
    # the 0.15 tolerance), a square wave's spikes (far above 3).
    assert slope_kurtosis(sine, 1.0, period) == pytest.approx(math.log(1.5), abs=0.02)
    assert slope_kurtosis(tri, 1.0, period) == pytest.approx(0.0, abs=0.15)
    assert slope_kurtosis(square, 1.0, period) > math.log(4.0)


def _cycles(lengths: np.ndarray, amplitudes: np.ndarray, square: bool) -> np.ndarray:
    # One cycle of each length [samples] and amplitude, joined at upward zero crossings.
    parts = []
    for n, a in zip(lengths.astype(int), amplitudes, strict=True):
        s = np.sin(2 * np.pi * np.arange(n) / n)
        parts.append(a * (np.sign(s) if square else s))
    return np.concatenate(parts)


def test_amplitude_lock_tells_a_locked_swing_from_a_locked_clock():
    # A valve's cycle: the same swing each time (a stick band), lengths that wander
    # (100 +- 20 samples, CV 0.12): the swing varies far less than the length, lock > 1
    # (a ratio of CVs above e).  A driven cycle: the same length each time, swings that
    # wander (CV 0.17): lock < -1.  The margin of 1 leaves room for the band-limiting,
    # which rounds the square wave's swing a little differently in cycles of different
    # length: noise-free, the valve's comes out at 1.9 and the driven one at the bound
    # -3.
    rng = np.random.default_rng(3)
    n = 60
    valve = _cycles(rng.uniform(80, 120, n), np.ones(n), square=True)
    driven = _cycles(np.full(n, 100.0), rng.uniform(0.7, 1.3, n), square=False)
    assert amplitude_lock(valve, 1.0, 100.0) > 1.0
    assert amplitude_lock(driven, 1.0, 100.0) < -1.0
    # Fewer than five periods: no lock (two CVs need four whole cycles at least).
    assert amplitude_lock(valve[:450], 1.0, 100.0) is None


def test_shape_needs_a_period_and_cycles():
    x = np.sin(np.arange(200) / 10.0)
    assert all(v is None for v in shape_statistics(x, x, 1.0, None).values())
    # 200 samples of a 100-sample cycle: two cycles, fewer than the three needed.
    assert all(v is None for v in shape_statistics(x, x, 1.0, 100.0).values())


@pytest.mark.parametrize("name", ["concentration", "level"])
def test_continuous_features_separate_a_limit_cycle_from_a_sinusoidal_load(name):
    # The sticky loop's signal after the first integrator is a triangle (He et al.
    # 2007: SI >= 0.6, the paper's level), pv is relay-like (Rossi & Scali 2005:
    # delta_e >= 0.4) and holds odd harmonics; under a sinusoidal load through a
    # linear valve the same statistics are those of a sinusoid (SI <= 0.4,
    # delta_e <= 0, odd harmonics at the noise floor).  The margins asked (0.4 in SI,
    # 0.8 in delta_e, a factor 10 in harmonic power) are half or less of the
    # separations these noisy (5 % of pv) paper loops give, so the test fails only
    # if a statistic stops separating them.
    s = _features(name, sticky=True)
    h = _features(name, sticky=False)
    assert s["he_si"] >= 0.6 and h["he_si"] <= 0.4
    assert s["he_si"] - h["he_si"] > 0.4
    assert s["rossi_scali_delta_e"] - h["rossi_scali_delta_e"] > 0.8
    assert s["pv_odd_harmonics"] - h["pv_odd_harmonics"] > 1.0
    assert s["op_odd_harmonics"] - h["op_odd_harmonics"] > 1.0
    for f in (s, h):
        assert set(f) == set(CONTINUOUS)
        assert all(math.isfinite(v) for v in f.values())


def test_missing_statistics_take_neutral_values():
    f = continuous_features({}, 5.0)
    assert f == NEUTRAL
    f = continuous_features({"he_si": float("nan"), "ellipse_apparent_stiction": 20.0}, 5.0)
    assert f["he_si"] == NEUTRAL["he_si"]
    assert f["ellipse_share"] == 2.0  # clipped: 20 % of span over a 5 % spread


def test_packaged_model_predicts_probabilities():
    # The shipped model (the earlier features; the continuous statistics are candidates
    # only) loads, and any feature vector in the features' ranges gets a
    # probability strictly inside (0, 1).
    model = load_model()
    assert tuple(model["features"]) == FEATURES
    rng = np.random.default_rng(3)
    for _ in range(50):
        feats = {k: float(rng.uniform(-0.5, 2.0)) for k in CANDIDATES}
        for has_mv in (False, True):
            p = stiction_probability(feats, has_mv, model)
            assert 0.0 < p < 1.0
