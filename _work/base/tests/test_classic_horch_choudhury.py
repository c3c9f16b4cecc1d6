"""Tests of Horch's CCF test and Choudhury's bicoherence test (stiction.classic).

The closed loops are simulated here with a small compiled loop around
:func:`stictiondiag.models.valve.choudhury_step`, so these tests do not depend on the project's
own loop simulator.  Each scenario is chosen so that the expected outcome follows from
an argument written beside it, not from a previous run.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stictiondiag.core.errors import (
    DataError,
    UsageError,
)
from stictiondiag.core.jit import jit
from stictiondiag.models.valve import (
    choudhury_step,
    valve_state,
)
from stictiondiag.stiction.classic import bicoherence as bic
from stictiondiag.stiction.classic import ellipse as el
from stictiondiag.stiction.classic import horch as ho

ISDB = Path(__file__).parents[1].parent / "shared" / "data" / "isdb"

# Paper's concentration loop (Eq. 3, Table 3): G = 3 e^{-10 s} / (10 s + 1),
# C = 0.2 (10 s + 1) / (10 s), simulated at 1 s; level loop G = 1/s,
# C = 0.4 (2 s + 1) / (2 s), simulated at 0.1 s.
CONC = dict(dt=1.0, gain=3.0, tau=10.0, delay=10.0, kc=0.2, ti=10.0, integrating=False)
LEVEL = dict(dt=0.1, gain=1.0, tau=1.0, delay=0.0, kc=0.4, ti=2.0, integrating=True)


@jit
def _closed_loop(
    n, dt, gain, tau, delay, kc, ti, S, J, integrating, equal_pct, sp, load_std, load_tau,
    dist_amp, dist_period, seed,
):  # fmt: skip
    """PI loop with a Choudhury valve; returns noise-free pv, op, mv.

    The process sees the valve output (optionally through an equal-percentage
    characteristic, rangeability 50, scaled to unit slope at the 50 % operating point)
    plus an output load: first-order filtered white noise (std ``load_std``, time
    constant ``load_tau``) and a sinusoid (``dist_amp``, ``dist_period``).
    """
    np.random.seed(seed)
    a = 1.0 if integrating else math.exp(-dt / tau)
    a_load = math.exp(-dt / load_tau)
    d = int(round(delay / dt))
    pv = np.empty(n)
    op = np.empty(n)
    mv = np.empty(n)
    line = np.zeros(d + 1)
    st = valve_state(50.0, True)
    slope = math.log(50.0) * 50.0**-0.5
    integral = 0.0
    x = 0.0
    load = 0.0
    for k in range(n):
        load = a_load * load + (1.0 - a_load) * load_std * np.random.randn()
        y = x + load + dist_amp * math.sin(2.0 * math.pi * k * dt / dist_period)
        pv[k] = y
        e = sp - y
        integral += e * dt / ti
        o = min(max(50.0 + kc * (e + integral), 0.0), 100.0)
        op[k] = o
        m = choudhury_step(o, st, S, J) if (S > 0.0 or J > 0.0) else o
        mv[k] = m
        u = m - 50.0
        if equal_pct:
            u = (100.0 * 50.0 ** (m / 100.0 - 1.0) - 100.0 * 50.0**-0.5) / slope
        for q in range(d):
            line[q] = line[q + 1]
        line[d] = u
        if integrating:
            x = x + gain * line[0] * dt
        else:
            x = a * x + (1.0 - a) * gain * line[0]
    return pv, op, mv


def simulate(
    loop: dict,
    *,
    n: int = 16000,
    skip: int = 4000,
    S: float = 0.0,
    J: float = 0.0,
    equal_pct: bool = False,
    sp: float = 0.0,
    load_std: float = 0.0,
    load_tau: float = 5.0,
    dist_amp: float = 0.0,
    dist_period: float = 1.0,
    noise: float = 0.0,
    seed: int = 1,
    kc: float | None = None,
    ti: float | None = None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Steady part of a closed loop: (pv with measurement noise, op, dt).

    Measurement noise is added to the recorded pv only: the Choudhury model re-arms
    its stuck band at every reversal of a noisy input (Section 5.1), so fed-back noise
    would freeze the valve; the paper's simulations are noise-free for that reason.
    """
    p = dict(loop)
    if kc is not None:
        p["kc"] = kc
    if ti is not None:
        p["ti"] = ti
    pv, op, _ = _closed_loop(
        n, p["dt"], p["gain"], p["tau"], p["delay"], p["kc"], p["ti"], S, J,
        p["integrating"], equal_pct, sp, load_std, load_tau, dist_amp, dist_period, seed,
    )  # fmt: skip
    rng = np.random.default_rng(seed + 1000)
    pv = pv[skip:] + noise * rng.standard_normal(n - skip)
    return pv, op[skip:], p["dt"]


def pi_phase_index(period_s: float, ti: float) -> float:
    """Horch's index predicted from the PI controller alone [rad].

    In a loop with a linear PI controller ``op = -Kc (pv + int(pv)/Ti)`` at every
    frequency, so at the cycle's fundamental ``op`` leads ``-pv`` by
    ``atan(1 / (w Ti))``; lag 0 of the CCF then sits that phase away from the CCF
    extremum and Horch's index is twice it.
    """
    w = 2.0 * math.pi / period_s
    return 2.0 * math.atan(1.0 / (w * ti))


# ======================================================================================
# Horch: cross-correlation test
# ======================================================================================


def test_cross_correlation_matches_direct_sum():
    rng = np.random.default_rng(0)
    a = rng.standard_normal(300)
    b = np.roll(a, 7) + 0.1 * rng.standard_normal(300)
    r = ho.cross_correlation(a, b, 20)
    from scipy.signal import detrend

    ad, bd = detrend(a), detrend(b)
    for lag in (-20, -3, 0, 7, 20):
        if lag >= 0:
            direct = np.sum(ad[: 300 - lag] * bd[lag:])
        else:
            direct = np.sum(ad[-lag:] * bd[: 300 + lag])
        direct /= 300 * ad.std() * bd.std()
        # FFT and direct sums agree to round-off.
        assert r[20 + lag] == pytest.approx(direct, abs=1e-12)
    # b is a delayed a: the CCF peaks at the delay.
    assert int(np.argmax(r)) - 20 == 7


@pytest.mark.parametrize(
    "shift, expected_deg, verdict",
    [
        (0.25, 180.0, "stiction"),  # pv a quarter cycle after op: odd CCF
        (0.5, 0.0, "no_stiction"),  # anti-phase: even CCF
        (0.0, 0.0, "no_stiction"),  # in phase: even CCF
        (0.2, 144.0, "stiction"),  # lag 0 is 72 deg from the CCF extremum
        (0.1, 72.0, "inconclusive"),  # 36 deg: the middle band
    ],
)
def test_horch_index_of_pure_sinusoids(shift, expected_deg, verdict):
    period, n = 50, 5000
    t = np.arange(n)
    op = np.sin(2 * np.pi * t / period)
    pv = np.sin(2 * np.pi * (t / period - shift))
    res = ho.horch_cross_correlation(op, pv, 1.0)
    # The zero crossings are interpolated linearly between samples of a 50-sample
    # cycle: 0.5 deg of index.
    assert math.degrees(res.delta_phi) == pytest.approx(expected_deg, abs=0.5)
    assert res.verdict == verdict
    assert res.oscillating
    assert res.period_s == pytest.approx(period, rel=0.01)


def test_horch_index_is_scale_and_sign_free():
    pv, op, dt = simulate(CONC, S=5.0, J=2.0, sp=1.0, noise=0.05)
    base = ho.horch_cross_correlation(op, pv, dt)
    other = ho.horch_cross_correlation(3.0 * op - 7.0, -0.5 * pv + 2.0, dt)
    # Affine changes of either signal and a sign flip leave the zero crossings where
    # they are (the CCF is normalised and only changes sign).
    assert other.delta_phi == pytest.approx(base.delta_phi, abs=1e-9)
    assert other.verdict == base.verdict


def test_horch_stiction_cycle_is_odd():
    # Table 3 case S = 5, J = 2 in the concentration loop: a 140 s limit cycle.
    pv, op, dt = simulate(CONC, S=5.0, J=2.0, sp=1.0, noise=0.05)
    res = ho.horch_cross_correlation(op, pv, dt)
    assert res.verdict == "stiction"
    assert res.period_s == pytest.approx(142.0, rel=0.03)  # REFERENCE.md, at 1 s: 140 s
    # The controller is linear, so the CCF phase is the PI phase at the fundamental;
    # harmonics of the square-ish pv bend the CCF a little: 5 deg.
    assert math.degrees(res.delta_phi) == pytest.approx(
        math.degrees(pi_phase_index(res.period_s, CONC["ti"])), abs=5.0
    )
    assert res.delta_phi >= ho.HORCH_ODD_MIN


def test_horch_aggressive_tuning_is_even():
    # Near the ultimate gain, with a long integral time: a noise-driven, lightly
    # damped linear oscillation at the crossover, where op is nearly -Kc pv.
    pv, op, dt = simulate(CONC, kc=0.45, ti=50.0, load_std=1.0, noise=0.02, seed=3)
    res = ho.horch_cross_correlation(op, pv, dt)
    assert res.verdict == "no_stiction"
    # Same PI-phase argument as above; a noise-driven cycle has a spread of
    # frequencies around the crossover: 5 deg.
    assert math.degrees(res.delta_phi) == pytest.approx(
        math.degrees(pi_phase_index(res.period_s, 50.0)), abs=5.0
    )
    assert abs(res.r0) > 0.5  # large |r(0)|: op and pv nearly in anti-phase


def test_horch_fast_external_disturbance_is_even():
    # A 15 s sinusoidal load on the concentration loop, faster than the loop can
    # follow: pv carries the disturbance, op = -C pv at 15 s.
    pv, op, dt = simulate(CONC, dist_amp=1.0, dist_period=15.0, noise=0.05)
    res = ho.horch_cross_correlation(op, pv, dt)
    assert res.verdict == "no_stiction"
    # A pure sinusoid through a linear controller: the CCF phase is exactly the PI
    # phase at 15 s; 2 deg for interpolation and the noise.
    assert math.degrees(res.delta_phi) == pytest.approx(
        math.degrees(pi_phase_index(15.0, CONC["ti"])), abs=2.0
    )


def test_horch_slow_external_disturbance_looks_like_stiction():
    # Known limitation of the CCF test, kept as published: under a disturbance much
    # slower than 1/Ti the integral action dominates C, op lags -pv by nearly 90 deg
    # and the CCF is odd although the loop is linear.
    pv, op, dt = simulate(CONC, dist_amp=1.0, dist_period=600.0, noise=0.05, n=20000)
    res = ho.horch_cross_correlation(op, pv, dt)
    predicted = pi_phase_index(600.0, CONC["ti"])
    assert predicted > ho.HORCH_ODD_MIN
    assert res.verdict == "stiction"
    assert math.degrees(res.delta_phi) == pytest.approx(math.degrees(predicted), abs=3.0)


def test_horch_no_oscillation_is_inconclusive():
    # Pure deadband in the self-regulating loop: no limit cycle (Section 6), only
    # measurement noise around the setpoint.
    pv, op, dt = simulate(CONC, S=5.0, J=0.0, sp=1.0, noise=0.05)
    res = ho.horch_cross_correlation(op, pv, dt)
    assert not res.oscillating
    assert res.verdict == "inconclusive"
    assert any("no oscillation" in r for r in res.reasons)


@pytest.mark.parametrize("S, J", [(3.0, 3.0), (3.0, 4.5)])
def test_horch_integrating_stiction_gives_spikes(S, J):
    # Level loop with stiction: pv is the integral of a square-ish valve position,
    # a triangle whose second derivative is a spike train.
    pv, op, dt = simulate(LEVEL, S=S, J=J, sp=1.0, noise=0.01)
    res = ho.horch_cross_correlation(op, pv, dt, integrating=True)
    assert res.method == "second_derivative"
    assert res.verdict == "stiction"
    # A pure triangle filtered to 10 harmonics gives a kurtosis of 8.3; the moving
    # phases of the valve round the corners and the noise pulls towards 3, so 4 is
    # asked for: clearly above Gaussian noise.
    assert res.kurtosis > 4.0


def test_horch_integrating_linear_oscillation_is_sinusoidal():
    # Linear level loop under a 5 s sinusoidal disturbance: pv is a sinusoid, so is
    # its second derivative (kurtosis 1.5, plus a little for the noise).
    pv, op, dt = simulate(LEVEL, dist_amp=1.0, dist_period=5.0, noise=0.01)
    res = ho.horch_cross_correlation(op, pv, dt, integrating=True)
    assert res.verdict == "no_stiction"
    assert res.kurtosis == pytest.approx(1.5, abs=0.4)


def test_horch_result_serialises():
    pv, op, dt = simulate(CONC, S=5.0, J=2.0, sp=1.0, noise=0.05)
    res = ho.horch_cross_correlation(op, pv, dt)
    d = json.loads(json.dumps(res.to_dict()))
    assert d["verdict"] == res.verdict
    assert d["delta_phi_deg"] == pytest.approx(math.degrees(res.delta_phi))
    df = res.to_pandas()
    assert list(df.columns) == ["lag_s", "ccf"]
    assert df["ccf"].iloc[len(df) // 2] == pytest.approx(res.r0)  # lag 0 in the middle
    assert df["lag_s"].iloc[len(df) // 2] == 0.0


# ======================================================================================
# Bicoherence
# ======================================================================================


def _reference_bic2(x, nfft, step, eps_percentile):
    """Bicoherence by explicit loops over segments and bifrequencies (slow, obvious)."""
    from scipy.signal import detrend, get_window

    x = detrend(np.asarray(x, float))
    w = get_window("hann", nfft)
    spectra = []
    for start in range(0, x.size - nfft + 1, step):
        seg = x[start : start + nfft]
        spectra.append(np.fft.rfft((seg - seg.mean()) * w))
    half = nfft // 2
    values = {}
    num, d12, d3 = {}, {}, {}
    for f1 in range(1, half + 1):
        for f2 in range(1, f1 + 1):
            if f1 + f2 > half:
                continue
            b = sum(s[f1] * s[f2] * np.conj(s[f1 + f2]) for s in spectra) / len(spectra)
            num[f1, f2] = abs(b) ** 2
            d12[f1, f2] = sum(abs(s[f1] * s[f2]) ** 2 for s in spectra) / len(spectra)
            d3[f1, f2] = sum(abs(s[f1 + f2]) ** 2 for s in spectra) / len(spectra)
    denom = {k: d12[k] * d3[k] for k in num}
    eps = np.percentile(list(denom.values()), eps_percentile)
    for k in num:
        values[k] = num[k] / (denom[k] + eps)
    return values


def test_bicoherence_matches_loop_reference():
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.standard_normal(700)) + rng.standard_normal(700) ** 2
    res = bic.bicoherence_indices(x, nfft=32, overlap=0.5)
    ref = _reference_bic2(x, 32, 16, 75.0)
    df = res.to_pandas()
    got = {
        (round(f1 * 32), round(f2 * 32)): v
        for f1, f2, v in zip(df.f1_hz, df.f2_hz, df.bic2, strict=True)
    }
    assert set(got) == set(ref)  # same principal domain, DC excluded
    for k, v in ref.items():
        # Same sums in a different order: round-off only.
        assert got[k] == pytest.approx(v, rel=1e-9, abs=1e-15)


def test_white_noise_is_gaussian():
    rng = np.random.default_rng(11)
    res = bic.bicoherence_indices(rng.standard_normal(4096))
    # Family-wise 5 % test over ~1000 bifrequencies: a Gaussian record shows no
    # significant value 95 % of the time, and NGI is then -threshold.
    assert res.n_significant == 0
    assert res.ngi <= bic.NGI_THRESHOLD
    assert not res.non_gaussian and not res.nonlinear
    assert res.n_segments == 63  # 4096 samples, nfft 128, 50 % overlap


def test_white_noise_nli_small_for_long_record():
    # The NLI of noise is the extreme of L chi-square values above their robust
    # spread, about 5 / (2 K) with the conditioning: below 0.01 once K is in the
    # thousands (2^16 samples give K = 1023).
    rng = np.random.default_rng(12)
    res = bic.bicoherence_indices(rng.standard_normal(2**16))
    assert res.nli < bic.NLI_THRESHOLD
    assert res.ngi <= bic.NGI_THRESHOLD
    assert res.n_segments == 1023


def test_per_bifrequency_test_flags_noise():
    # Why the default is family-wise: with the per-bifrequency 5 % level about 5 %
    # of the bifrequencies of pure noise are "significant" (a handful after the
    # conditioning), and the mean excess over the threshold is positive.
    rng = np.random.default_rng(11)
    x = rng.standard_normal(4096)
    res = bic.bicoherence_indices(x, correction="none", conditioning_percentile=None)
    expected = 0.05 * res.n_bifrequencies
    # Binomial count, n ~ 1000, p = 0.05: 4 standard deviations is 28.
    assert abs(res.n_significant - expected) < 28
    assert res.ngi > bic.NGI_THRESHOLD


def _qpc_record(coupled: bool, n_blocks: int = 64, nfft: int = 128, seed: int = 2):
    """Kim & Powers (1979) test signal: fresh random phases in every nfft block."""
    rng = np.random.default_rng(seed)
    k1, k2 = 24, 16  # FFT bins: f1 = 0.1875, f2 = 0.125 cycles/sample
    t = np.arange(nfft)
    blocks = []
    for _ in range(n_blocks):
        p1, p2, p3 = rng.uniform(0, 2 * np.pi, 3)
        p3 = p1 + p2 if coupled else p3
        w1, w2 = 2 * np.pi * k1 / nfft, 2 * np.pi * k2 / nfft
        blk = np.cos(w1 * t + p1) + np.cos(w2 * t + p2) + np.cos((w1 + w2) * t + p3)
        blocks.append(blk + 0.1 * rng.standard_normal(nfft))
    return np.concatenate(blocks), k1 / nfft, k2 / nfft


def test_quadratic_phase_coupling_peaks_at_f1_f2():
    x, f1, f2 = _qpc_record(coupled=True)
    res = bic.bicoherence_indices(x, nfft=128, overlap=0.0)
    # Phase-coupled triad: bic^2 -> 1 at (f1, f2) up to the noise (SNR 50 per
    # component); the conditioning term is tiny there because the three bins hold
    # most of the power.
    assert res.at(f1, f2) > 0.9
    assert (res.peak_f1_hz, res.peak_f2_hz) == pytest.approx((f1, f2))
    assert res.nonlinear


def test_uncoupled_triad_has_no_bicoherence():
    # Same three frequencies, independent phases: the triple products average out
    # over K = 64 segments; bic^2 is of order 1/K, below the family-wise threshold.
    x, f1, f2 = _qpc_record(coupled=False)
    res = bic.bicoherence_indices(x, nfft=128, overlap=0.0)
    assert res.at(f1, f2) < res.threshold
    assert not res.nonlinear


def test_bicoherence_is_scale_and_sign_free():
    x, _, _ = _qpc_record(coupled=True)
    a = bic.bicoherence_indices(x, nfft=128, overlap=0.0)
    b = bic.bicoherence_indices(-25.0 * x + 3.0, nfft=128, overlap=0.0)
    # |B|^2 and the denominator both scale with the sixth power; a sign flip changes
    # the sign of B only; the mean is removed.
    np.testing.assert_allclose(b.bic2, a.bic2, rtol=1e-9, atol=1e-15)


def test_stiction_cycle_through_equal_percentage_valve_is_nonlinear():
    # Overshoot case S = 5, J = 7 in the concentration loop: a square-ish pv.  The
    # equal-percentage characteristic makes the flow step up and down by different
    # amounts, so the cycle is not half-wave symmetric and its even harmonics are
    # phase-coupled to the odd ones.
    pv, op, dt = simulate(CONC, S=5.0, J=7.0, sp=1.0, equal_pct=True, noise=0.05)
    res = bic.bicoherence_indices(1.0 - pv, dt=dt)
    assert res.nonlinear
    # A sharp limit cycle puts most of the domain's significant values on its
    # harmonic grid: far above both thresholds, not marginally.
    assert res.ngi > 100 * bic.NGI_THRESHOLD
    assert res.nli > 10 * bic.NLI_THRESHOLD
    diag = bic.choudhury_hos(op, pv, np.full_like(pv, 1.0), dt)
    assert diag.verdict == "stiction"
    assert diag.signal == "control_error"
    assert diag.ellipse.axis_ratio >= el.ELLIPSE_MIN_AXIS_RATIO
    assert diag.ellipse.apparent_stiction > 0.0
    json.dumps(diag.to_dict(), allow_nan=False)


def test_level_loop_stiction_is_nonlinear():
    # Level loop, S = 3, J = 4.5 (overshoot): triangular pv.
    pv, op, dt = simulate(LEVEL, S=3.0, J=4.5, sp=1.0, noise=0.01)
    diag = bic.choudhury_hos(op, pv, np.full_like(pv, 1.0), dt)
    assert diag.nonlinear
    assert diag.verdict == "stiction"


def test_half_wave_symmetric_cycle_is_invisible():
    # Known limitation of the bicoherence test, kept as published: with a linear
    # valve characteristic the S = 5, J = 7 cycle is half-wave symmetric, so it has
    # odd harmonics only and f1 + f2 of two odd harmonics is an even one with no
    # power: the bispectrum is zero.  The conditioning term keeps the 0/0 at those
    # empty bifrequencies from producing spurious peaks.
    pv, op, dt = simulate(CONC, S=5.0, J=7.0, sp=1.0, noise=0.05)
    res = bic.bicoherence_indices(1.0 - pv, dt=dt)
    assert not res.non_gaussian
    assert res.max_bicoherence < res.threshold


def test_linear_loop_with_disturbance_is_not_stiction():
    pv, op, dt = simulate(CONC, dist_amp=1.0, dist_period=30.0, noise=0.05)
    diag = bic.choudhury_hos(op, pv, np.zeros_like(pv), dt)
    # A sinusoid in Gaussian noise through a linear loop: Gaussian-or-linear.
    assert not diag.nonlinear
    assert diag.verdict == "no_stiction"
    assert diag.ellipse is None


@pytest.mark.parametrize("n, verdict", [(600, "inconclusive"), (8000, "no_stiction")])
def test_hos_diagnosis_of_noise_depends_on_record_length(n, verdict):
    # Noise only: no significant bicoherence either way.  600 samples give 8
    # segments of 128, so the family-wise critical bic^2 is chi2 quantile
    # 2 ln(20 L) / 16 > 1 with L ~ 1000: the test could not have seen anything, and a
    # Gaussian finding is no evidence.  8000 samples give 124 segments, threshold 0.08.
    rng = np.random.default_rng(21)
    pv = rng.standard_normal(n)
    op = 50 - 0.3 * pv + 0.1 * rng.standard_normal(n)
    diag = bic.choudhury_hos(op, pv, None, 1.0)
    assert not diag.bicoherence.non_gaussian
    assert diag.verdict == verdict
    assert (diag.bicoherence.threshold > bic.HOS_MAX_THRESHOLD) == (verdict == "inconclusive")


def test_auto_decimation_targets_four_cycles_per_segment():
    # 140-sample period, nfft 128: 32 samples per cycle wanted, so q = 4.
    assert bic.auto_decimation(12000, 140.0, 128) == 4
    # Too short to keep 8 segments after decimating by 4: back off.
    assert bic.auto_decimation(2000, 140.0, 128) == 3
    assert bic.auto_decimation(12000, 20.0, 128) == 1
    assert bic.auto_decimation(12000, None, 128) == 1


def test_short_record_reduces_nfft():
    rng = np.random.default_rng(3)
    res = bic.bicoherence_indices(rng.standard_normal(500))
    # 500 samples give 6 segments of 128 and 14 of 64 (50 % overlap).
    assert res.nfft == 64
    assert res.n_segments == 14


# ======================================================================================
# Ellipse fit
# ======================================================================================


def test_fit_ellipse_recovers_geometry():
    t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    # Axes 3 and 1, rotated 30 deg, centred at (1, -2).
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    x = 1 + 3 * np.cos(t) * c - 1 * np.sin(t) * s
    y = -2 + 3 * np.cos(t) * s + 1 * np.sin(t) * c
    coef = el.fit_ellipse(x, y)
    ratio, half_chord = el._ellipse_geometry(coef)
    # Exact points on an ellipse: the fit is exact up to round-off.
    assert ratio == pytest.approx(1 / 3, rel=1e-8)
    # Half chord along x through the centre: 1/sqrt(M_xx) of the quadratic form,
    # M = R diag(1/9, 1) R^T.
    m_xx = c * c / 9 + s * s / 1
    assert half_chord == pytest.approx(1 / math.sqrt(m_xx), rel=1e-8)


@pytest.mark.parametrize("phase_deg", [90.0, 150.0, 170.0])
def test_pv_op_ellipse_axis_ratio_of_sinusoids(phase_deg):
    period, n = 40.0, 4000
    t = np.arange(n)
    op = 50 + 2 * np.sin(2 * np.pi * t / period)
    pv = 10 + 0.5 * np.sin(2 * np.pi * t / period - math.radians(phase_deg))
    out = el.pv_op_ellipse(op, pv, 1.0, period)
    c = abs(math.cos(math.radians(phase_deg)))
    # Two unit-variance sinusoids phi apart: covariance eigenvalues 1 +- |cos phi|.
    # The zero-phase band-pass keeps both amplitudes and the phase; the filter's
    # start-up transient at the ends costs 1e-2.
    assert out.axis_ratio == pytest.approx(math.sqrt((1 - c) / (1 + c)), abs=1e-2)
    assert out.elliptic == (out.axis_ratio >= el.ELLIPSE_MIN_AXIS_RATIO)
    # Width along op through the centre: 2 * 2 / sqrt(1 + cot^2 phi) for op amplitude 2
    # (the op-chord of the ellipse traced by (sin t, sin(t - phi))).
    width = 2 * 2 * abs(math.sin(math.radians(phase_deg)))
    assert out.apparent_stiction == pytest.approx(width, rel=2e-2)


# ======================================================================================
# Errors
# ======================================================================================


def test_errors():
    rng = np.random.default_rng(0)
    x = rng.standard_normal(1000)
    with pytest.raises(DataError, match="constant"):
        ho.horch_cross_correlation(np.ones(100), x[:100], 1.0)
    with pytest.raises(DataError, match="same length"):
        ho.horch_cross_correlation(x, x[:500], 1.0)
    with pytest.raises(DataError, match="NaN"):
        bic.bicoherence_indices(np.where(np.arange(1000) == 5, np.nan, x))
    with pytest.raises(DataError, match="segments"):
        bic.bicoherence_indices(x[:100])  # 5 segments of 32
    with pytest.raises(UsageError, match="power of two"):
        bic.bicoherence_indices(x, nfft=100)
    with pytest.raises(UsageError, match="dt"):
        ho.horch_cross_correlation(x, x, 0.0)
    with pytest.raises(UsageError, match="correction"):
        bic.bicoherence_indices(x, correction="holm")
    with pytest.raises(DataError, match="sp"):
        bic.choudhury_hos(x, x, sp=x[:10])


# ======================================================================================
# Real loops (ISDB)
# ======================================================================================


@pytest.mark.isdb
@pytest.mark.skipif(not ISDB.is_dir(), reason="ISDB data not available")
@pytest.mark.parametrize("loop", ["CHEM1", "CHEM4", "PAP3", "PAP9", "BAS6"])
def test_isdb_loops_run(loop):
    manifest = pd.read_csv(ISDB / "manifest.csv").set_index("loop")
    row = manifest.loc[loop]
    df = pd.read_csv(ISDB / "loops" / f"{loop}.csv")
    dt = float(row["ts_s"])
    h = ho.horch_cross_correlation(
        df.op.to_numpy(), df.pv.to_numpy(), dt, integrating=bool(row["integrating"])
    )
    d = bic.choudhury_hos(df.op.to_numpy(), df.pv.to_numpy(), df.sp.to_numpy(), dt)
    for verdict in (h.verdict, d.verdict):
        assert verdict in ("stiction", "no_stiction", "inconclusive")
    # Plain JSON, no NaN.
    text = json.dumps({"horch": h.to_dict(), "hos": d.to_dict()}, allow_nan=False)
    assert loop and text


def test_fdr_keeps_gaussian_records_gaussian():
    # Benjamini-Hochberg keeps the family-wise level alpha under the complete null
    # (no coupled bifrequency): white noise is rarely non-Gaussian, whatever K.  Ten
    # records at alpha = 0.05: at most two flagged allows a chance exceedance.
    rng = np.random.default_rng(11)
    flagged = sum(
        bic.bicoherence_indices(rng.standard_normal(2000), correction="fdr").non_gaussian
        for _ in range(10)
    )
    assert flagged <= 2
