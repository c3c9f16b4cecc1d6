"""Continuous op/pv evidence for the stiction probability: the classic tests' own
statistics and the oscillation's shape.

The classic tests (:mod:`stictiondiag.stiction.classic`) each reduce a continuous
statistic to a ternary call.  Their calls keep their published meaning; for the
calibrated combination (:mod:`stictiondiag.stiction.probability`) the statistics
themselves are passed on, because a call throws away how far the statistic is from
its thresholds.  Each statistic is mapped to a bounded number; where a test could not
run or does not apply it takes a fixed *neutral* value (that of a sinusoidal, linear
oscillation, or of no evidence), listed in :data:`NEUTRAL`.

The shape of the oscillation
----------------------------
A sticky valve in a limit cycle moves in jumps (Choudhury, Thornhill & Shah 2005,
Section 5.2 and Fig. 9-10): the valve's flow is a square-ish wave, the first
integrator after the valve makes a triangle of it (the controller's integral action
in a self-regulating loop, so op; the process in an integrating loop, so pv), and a
self-regulating process passes the square-ish wave on to pv (He et al. 2007, Section
3).  A square wave holds odd harmonics (amplitude 1/k of the fundamental at k = 3, 5,
...), a triangle weaker ones (1/k^2); a linear loop driven by a periodic load passes
on the load's harmonics only, and a sinusoidal load has none.  Two families of
statistics measure this on pv and on op, and a third how steady the cycle's swing
is against its period:

``*_odd_harmonics``
    ``log10`` of the power of the 3rd and 5th harmonics of the oscillation over that
    of the fundamental (Welch spectrum, bands of +-0.2 f0, the median spectral level
    above the fundamental subtracted as the noise floor), clipped to [-4, 0] [-].  A
    square wave gives log10(1/9 + 1/25) = -0.82, a triangle -1.87, a sinusoid the
    noise floor.
``*_slope_kurtosis``
    ``log`` of the kurtosis of the first difference of the signal, band-limited to
    six harmonics of the oscillation and to above a third of its frequency, clipped
    to [0, 3] [-].  A sinusoid's slope is a sinusoid (kurtosis 1.5), a triangle's a
    square (1.0), a square wave's a train of spikes (large); white noise gives 3.
``*_amplitude_lock``
    What holds the cycle steady, its swing or its clock: ``log`` of the coefficient
    of variation of the cycle lengths over that of the cycle swings (peak to peak),
    cycles taken between upward zero crossings of the band-limited signal (those of
    0.4 to 2.5 periods), clipped to [-3, 3] [-].  A sticky valve's limit cycle is
    locked in amplitude: each half-cycle ends when op has travelled the stick band S
    from where the valve stuck, and the slip moves the valve by about the same amount
    each time (Section 5.2, Fig. 10), while noise and load changes make the travel
    take more or less time; so the swing varies less than the period (positive).  A
    cycle driven from outside keeps the disturbance's clock, and a linear loop near
    its stability limit rings at its own frequency with the random amplitude of
    filtered noise: the period varies less than the swing (negative).  On the cause
    family's held-out loops (seeds 12 and 13) the area under the ROC curve of op's
    lock for the valve's cycles against all others is 0.79 (`docs/history.md`,
    "The cycle's amplitude lock").
"""

from __future__ import annotations

import math

import numpy as np

#: Harmonics of the oscillation kept before the slope statistic [-]: the 3rd and 5th
#: harmonics of a square wave (its jumps), with the measurement noise above cut.
SHAPE_HARMONICS = 6.0
#: Half width of a harmonic's band in the spectrum, in units of the fundamental [-]
#: (a limit cycle's period wanders by a few per cent from cycle to cycle).
HARMONIC_BAND = 0.2
#: Smallest log10 harmonic ratio reported [-] (a pure sinusoid in noise).
MIN_LOG_RATIO = -4.0
#: Fewest cycles in the record for the shape statistics [-].
SHAPE_MIN_CYCLES = 3.0
#: Fewest whole cycles for the amplitude lock (two coefficients of variation) [-].
LOCK_MIN_CYCLES = 4
#: Cycle lengths the amplitude lock counts, in periods [-] (shorter ones are noise
#: crossing zero, longer ones a lost cycle).
LOCK_LENGTHS = (0.4, 2.5)
#: Bound of the amplitude lock [-], and the smallest coefficient of variation it
#: divides by [-] (a noise-free cycle).
LOCK_BOUND = 3.0
LOCK_MIN_CV = 1e-3

#: Continuous features computed here, and their neutral value where a statistic could
#: not be computed (a sinusoidal or absent oscillation; no evidence either way).
NEUTRAL: dict[str, float] = {
    "he_si": 0.5,
    "horch_phase": 0.5,
    "horch_d2_kurtosis": math.log(3.0),
    "choudhury_nli": 0.0,
    "choudhury_ngi": 0.0,
    "ellipse_axis_ratio": 0.0,
    "ellipse_share": 0.0,
    "kano_rho": 0.0,
    "rossi_scali_delta_e": 0.0,
    "pv_odd_harmonics": MIN_LOG_RATIO,
    "op_odd_harmonics": MIN_LOG_RATIO,
    "pv_slope_kurtosis": math.log(1.5),
    "op_slope_kurtosis": math.log(1.5),
    "pv_amplitude_lock": 0.0,
    "op_amplitude_lock": 0.0,
}

#: The continuous features, in a stable order.
CONTINUOUS: tuple[str, ...] = tuple(NEUTRAL)

#: Those of them that measure the oscillation's shape (the rest are the classic
#: tests' statistics).
SHAPE_FEATURES: tuple[str, ...] = (
    "pv_odd_harmonics",
    "op_odd_harmonics",
    "pv_slope_kurtosis",
    "op_slope_kurtosis",
    "pv_amplitude_lock",
    "op_amplitude_lock",
)


def _finite(v) -> float | None:
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def band_limited(x: np.ndarray, dt: float, period_s: float) -> np.ndarray:
    """x band-passed to [f0 / 3, SHAPE_HARMONICS f0] (zero-phase Butterworth)."""
    from scipy import signal as sps  # imported here: scipy.signal is slow to import

    nyq = 0.5 / dt
    f0 = 1.0 / period_s
    lo = f0 / 3.0 / nyq
    hi = SHAPE_HARMONICS * f0 / nyq
    y = x - float(np.mean(x))
    if hi < 0.9:
        b, a = sps.butter(2, hi)
        y = sps.filtfilt(b, a, y, padlen=min(6, y.size - 1))
    if lo > 1e-4:
        b, a = sps.butter(2, lo, btype="high")
        y = sps.filtfilt(b, a, y, padlen=min(6, y.size - 1))
    return y


def odd_harmonics(x: np.ndarray, dt: float, period_s: float) -> float | None:
    """log10 of (power of the 3rd and 5th harmonics) / (power of the fundamental)
    of ``x`` oscillating with ``period_s`` (module doc), or None."""
    from scipy import signal as sps

    n = x.size
    period = period_s / dt
    if not period > 4 or n < SHAPE_MIN_CYCLES * period:
        return None
    nper = int(min(n, max(64, round(8 * period))))
    f, P = sps.welch(x, fs=1.0 / dt, nperseg=nper, detrend="linear")
    f0 = 1.0 / period_s
    near = (f > 0.7 * f0) & (f < 1.3 * f0)
    if not near.any():
        return None
    f0 = float(f[near][np.argmax(P[near])])
    df = float(f[1] - f[0])
    above = f > 1.5 * f0
    floor = float(np.median(P[above])) if above.any() else 0.0

    def band(k: float) -> float | None:
        if (k + HARMONIC_BAND) * f0 >= f[-1]:
            return None
        m = np.abs(f - k * f0) <= max(HARMONIC_BAND * f0, df)
        return max(float(np.sum(P[m] - floor)), 0.0)

    p1 = band(1.0)
    if not p1:
        return None
    odd = sum(v for v in (band(3.0), band(5.0)) if v is not None)
    return float(np.clip(math.log10(max(odd / p1, 10.0**MIN_LOG_RATIO)), MIN_LOG_RATIO, 0.0))


def slope_kurtosis(x: np.ndarray, dt: float, period_s: float) -> float | None:
    """log of the kurtosis of the band-limited first difference of ``x`` (module
    doc), clipped to [0, 3], or None."""
    period = period_s / dt
    if not period > 4 or x.size < SHAPE_MIN_CYCLES * period:
        return None
    d = np.diff(band_limited(np.asarray(x, dtype=float), dt, period_s))
    d = d - float(np.mean(d))
    v = float(np.mean(d * d))
    if not v > 0:
        return None
    k = float(np.mean(d**4)) / (v * v)
    return float(np.clip(math.log(k), 0.0, 3.0))


def amplitude_lock(x: np.ndarray, dt: float, period_s: float) -> float | None:
    """log(CV of the cycle lengths / CV of the cycle swings) of ``x`` oscillating
    with ``period_s`` (module doc), or None (fewer than :data:`LOCK_MIN_CYCLES`
    cycles).  Cost linear in the record's length."""
    period = period_s / dt
    if not period > 4 or x.size < (LOCK_MIN_CYCLES + 1) * period:
        return None
    y = band_limited(np.asarray(x, dtype=float), dt, period_s)
    neg = np.signbit(y)
    up = np.nonzero(neg[:-1] & ~neg[1:])[0]
    if up.size < LOCK_MIN_CYCLES + 1:
        return None
    seg = y[up[0] : up[-1] + 1]
    starts = up[:-1] - up[0]
    swing = np.maximum.reduceat(seg, starts) - np.minimum.reduceat(seg, starts)
    length = np.diff(up).astype(float)
    keep = (length > LOCK_LENGTHS[0] * period) & (length < LOCK_LENGTHS[1] * period)
    if int(keep.sum()) < LOCK_MIN_CYCLES:
        return None
    length, swing = length[keep], swing[keep]
    cv_length = float(length.std() / length.mean())
    cv_swing = float(swing.std() / swing.mean()) if swing.mean() > 0 else 0.0
    ratio = max(cv_length, LOCK_MIN_CV) / max(cv_swing, LOCK_MIN_CV)
    return float(np.clip(math.log(ratio), -LOCK_BOUND, LOCK_BOUND))


def shape_statistics(pv, op, dt: float, period_s: float | None) -> dict[str, float | None]:
    """The oscillation's shape in pv and op (module doc); None where it cannot be
    measured (no oscillation period, or fewer than :data:`SHAPE_MIN_CYCLES` cycles)."""
    out: dict[str, float | None] = {
        f"{s}_{k}": None
        for s in ("pv", "op")
        for k in ("odd_harmonics", "slope_kurtosis", "amplitude_lock")
    }
    if period_s is None or not math.isfinite(period_s) or period_s <= 0:
        return out
    for name, x in (("pv", pv), ("op", op)):
        x = np.asarray(x, dtype=float)
        if x.size < 32 or not np.all(np.isfinite(x)) or float(np.ptp(x)) == 0.0:
            continue
        try:
            out[f"{name}_odd_harmonics"] = odd_harmonics(x, dt, period_s)
            out[f"{name}_slope_kurtosis"] = slope_kurtosis(x, dt, period_s)
            out[f"{name}_amplitude_lock"] = amplitude_lock(x, dt, period_s)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError):
            continue
    return out


def continuous_features(classic: dict, op_spread: float) -> dict[str, float]:
    """The features of :data:`CONTINUOUS` from the classic tests' statistics and the
    shape statistics (``classic``, as returned by
    :func:`stictiondiag.stiction.probability.classic_votes`) and the spread of op
    (5 to 95 % quantiles) [% of span].

    ``he_si`` He et al.'s stiction index [0, 1]; ``horch_phase`` Horch's phase index
    delta_phi / pi [0, 1]; ``horch_d2_kurtosis`` log of Horch's (2000) kurtosis of pv's
    second derivative, clipped to [0, 3]; ``choudhury_nli``, ``choudhury_ngi`` the
    bicoherence indices clipped to [-0.2, 1]; ``ellipse_axis_ratio`` [0, 1];
    ``ellipse_share`` the ellipse's apparent stiction over op's spread, clipped to
    [0, 2]; ``kano_rho`` [0, 1]; ``rossi_scali_delta_e`` [-1, 1]; the shape
    statistics as in the module doc.  Missing ones take :data:`NEUTRAL`.
    """
    g = classic.get

    def clip(v, lo, hi):
        v = _finite(v)
        return None if v is None else float(np.clip(v, lo, hi))

    k2 = _finite(g("horch_d2_kurtosis"))
    app = _finite(g("ellipse_apparent_stiction"))
    raw = {
        "he_si": clip(g("he_si"), 0.0, 1.0),
        "horch_phase": clip(g("horch_phase_index"), 0.0, 1.0),
        "horch_d2_kurtosis": (
            float(np.clip(math.log(k2), 0.0, 3.0)) if k2 is not None and k2 > 0 else None
        ),
        "choudhury_nli": clip(g("choudhury_nli"), -0.2, 1.0),
        "choudhury_ngi": clip(g("choudhury_ngi"), -0.2, 1.0),
        "ellipse_axis_ratio": clip(g("ellipse_axis_ratio"), 0.0, 1.0),
        "ellipse_share": (
            float(np.clip(app / op_spread, 0.0, 2.0)) if app is not None and op_spread > 0 else None
        ),
        "kano_rho": clip(g("kano_rho"), 0.0, 1.0),
        "rossi_scali_delta_e": clip(g("rossi_scali_delta_e"), -1.0, 1.0),
        **{k: clip(g(k), -10.0, 10.0) for k in SHAPE_FEATURES},
    }
    return {k: (NEUTRAL[k] if raw[k] is None else raw[k]) for k in CONTINUOUS}
