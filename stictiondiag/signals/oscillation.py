"""Oscillation detection by the autocorrelation zero-crossing method.

Thornhill, Huang & Zhang (2003), "Detection of multiple oscillations in control
loops", Journal of Process Control 13, 91-100 (cited in Section 1 of Choudhury,
Thornhill & Shah 2005).  The autocorrelation function (ACF) of an oscillating signal
is itself oscillating with the same period, and it is much less noisy than the
signal: the ACF averages the noise away.  The intervals between zero crossings of the
ACF give the period ``Tp`` and its spread gives the regularity

    r = mean(Tp) / (3 std(Tp)),

and the signal is called oscillating when ``r > 1`` (the period spread is less than a
third of the mean period).

Decisions this implementation makes (and tests):

* Periods are taken between *alternate* zero crossings (crossing ``i`` to ``i + 2``),
  so a cycle whose two halves differ in length (an asymmetric square wave, an
  overshooting stiction cycle) gives a constant full period.
* Up to :data:`MAX_ZERO_CROSSINGS` crossings are used, as in Thornhill et al. (2003),
  and at least :data:`MIN_PERIOD_ESTIMATES` period estimates are required.
* The record must hold at least :data:`MIN_CYCLES` periods.
* A decaying transient has a regular ACF too, so the oscillation must also be
  sustained: the typical peak-to-peak range of the cycles in the last third of the
  record must be at least :data:`MIN_SUSTAIN_RATIO` of that in the first third.
* A zero crossing counts only when the ACF lobe before it is significant (above
  :data:`ACF_SIGNIFICANCE` standard errors of a white-noise ACF), so the random
  crossings of a white-noise ACF give no period.
* Drift is removed in passes: a least-squares line, then a running mean over
  :data:`DETREND_PERIODS` periods of the period found so far, repeated until the
  period settles.  A record whose op wanders or steps with the loads (a level loop's
  op follows the inflow) has a drift-dominated ACF after the line alone (issue 18:
  regularity 0.19 for the sawtooth op of ``sample_data/level_undershoot.csv``).
  The mean over three whole periods is flat for a periodic signal, a running median
  is not for a two-level one (it flips with the count of samples on either level).
  Checked on noise (3000 and 10 000 samples, 100 seeds each): random walks are
  called oscillating 17 times in 200 as with the straight line alone (17),
  AR(1) noise with pole 0.99 35 times (37), white noise never.
* A drift can hide the cycle from the straight line's ACF altogether: a slow wander
  or a level shift lifts the ACF so that it oscillates about a decaying positive
  offset and barely crosses zero, and the refinement above has no period to start
  from.  Thornhill et al. (2003) isolate each oscillation from such trends by
  filtering before the ACF.  Here, when the straight line leaves too few crossings
  or an irregular ACF, the period is *seeded* from the ACF itself: each of its first
  :data:`SEED_PEAKS` local peaks that stands out by :data:`ACF_SIGNIFICANCE`
  standard errors is a candidate period; the running mean over
  :data:`DETREND_PERIODS` candidate periods is removed and the ACF measured again,
  and a candidate counts only when the period found there, and after the
  refinement, is within :data:`SEED_CONSISTENCY` of it (the most regular one
  wins).  The self-consistency is the guard against noise: removing a running mean
  is a high-pass filter, and red noise filtered so takes a period set by the
  window, not by the candidate (AR(1) noise with pole 0.99, 3000 samples, 40
  seeds: a median of 2.4 to 2.8 candidate periods for candidates of 20 to 100
  samples).  Checked on noise (1441 and 3000 samples, 60 seeds each;
  ``python scripts/oscillation_false_cycles.py``): white noise and random walks
  under white noise are never called oscillating; the seeds add 0 to 5 calls in 60
  on AR(1) noise with poles 0.9 and 0.99, random walks and random steps, where the
  straight line and its refinement already make 2 to 21.  On the ISDB's unlabelled
  records it finds the cycles a level shift or a wander hides, for example CHEM6's
  (57 samples, pv and op) and CHEM61's (9 samples, pv).
* The ACF is smoothed by a centred moving average about a tenth of its first
  zero-crossing lag wide.  A symmetric smoother does not move the zero crossings of
  a periodic ACF; it removes the spurious double crossings that estimation noise
  causes where the ACF is small.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from stictiondiag.core.checks import check_dt
from stictiondiag.core.filters import (
    detrend_linear,
    savgol_smooth,
)
from stictiondiag.core.robust import second_difference_noise_std
from stictiondiag.core.serialize import plain_float

#: Regularity above which a signal is called oscillating (Thornhill et al. 2003).
REGULARITY_THRESHOLD = 1.0
#: Minimum number of periods the record must hold.
MIN_CYCLES = 3.0
#: Maximum number of ACF zero crossings used (Thornhill et al. 2003 use about ten).
MAX_ZERO_CROSSINGS = 11
#: Minimum number of full-period estimates from the ACF zero crossings.
MIN_PERIOD_ESTIMATES = 3
#: Minimum ratio of late to early cycle amplitude for a sustained oscillation.
MIN_SUSTAIN_RATIO = 0.3
#: Height of an ACF lobe, in standard errors of a white-noise ACF (1/sqrt(n)), for the
#: zero crossing that ends it to count (rejects the random crossings of noise).
ACF_SIGNIFICANCE = 3.0
#: Shortest series analysed [samples]; shorter series are reported as not oscillating.
MIN_SAMPLES = 16
#: Width of the running mean removed as drift, in periods of the oscillation [-].
DETREND_PERIODS = 3.0
#: Passes of detrending and period estimation, at most, and the relative change of
#: the period [-] at which they stop.
DETREND_PASSES = 4
DETREND_CONVERGED = 0.05
#: Peaks of the straight line's ACF tried as seeds of the period, at most [-], and the
#: largest relative difference between a seed and the period measured after the
#: running mean over its cycles is removed [-] (module doc).
SEED_PEAKS = 3
SEED_CONSISTENCY = 0.25
#: Upper bound of the reported regularity: a perfectly periodic simulated signal has
#: zero spread, and the regularity must stay a finite JSON number.
MAX_REGULARITY = 1.0e6


class Absence(StrEnum):
    """Why :func:`detect_oscillation` reports no oscillation: code compares the
    member, never the words of ``Oscillation.reason``."""

    FEW_SAMPLES = "few_samples"
    CONSTANT = "constant"
    RAMP = "ramp"
    FEW_CROSSINGS = "few_crossings"
    IRREGULAR = "irregular"
    FEW_CYCLES = "few_cycles"
    DECAYING = "decaying"


@dataclass(frozen=True)
class Oscillation:
    """Result of :func:`detect_oscillation`.

    Attributes
    ----------
    present : bool
        A regular, sustained oscillation was found.
    period_s : float or None
        Mean oscillation period [s]; None when no oscillation is present.
    amplitude : float or None
        Half the typical (median over cycles) peak-to-peak range of one cycle
        [units of x]; None when no oscillation is present.
    regularity : float or None
        Thornhill et al. (2003) regularity ``r = mean(Tp) / (3 std(Tp))`` [-], also
        reported when it is too low (that is why no oscillation is present); None when
        the ACF has too few zero crossings to compute it.
    n_cycles : float or None
        Record length divided by the period [-]; None when no oscillation is present.
    reason : str or None
        Why no oscillation is reported, in words (None when one is present).
    absence : Absence or None
        The same as a category (None when one is present).
    """

    present: bool
    period_s: float | None
    amplitude: float | None
    regularity: float | None
    n_cycles: float | None
    reason: str | None = None
    absence: Absence | None = None

    def to_dict(self) -> dict:
        """JSON-able dict (plain floats or None)."""
        return {
            "present": bool(self.present),
            "period_s": plain_float(self.period_s),
            "amplitude": plain_float(self.amplitude),
            "regularity": plain_float(self.regularity),
            "n_cycles": plain_float(self.n_cycles),
            "reason": self.reason,
        }


def _absent(absence: Absence, reason: str, regularity: float | None = None) -> Oscillation:
    return Oscillation(False, None, None, regularity, None, reason, absence)


def _interpolate_nans(x: np.ndarray) -> np.ndarray:
    """1-D float copy with interior NaNs interpolated and leading/trailing NaNs dropped."""
    x = np.asarray(x, dtype=float).ravel()
    ok = np.isfinite(x)
    if ok.all():
        return x.copy()
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return idx.astype(float)
    x = x[idx[0] : idx[-1] + 1]
    ok = np.isfinite(x)
    k = np.arange(x.size)
    x[~ok] = np.interp(k[~ok], k[ok], x[ok])
    return x


def autocorrelation(x: np.ndarray) -> np.ndarray:
    """Biased autocorrelation of a mean-centred signal, normalised to 1 at lag 0 [-].

    Computed by FFT with zero padding (no circular wrap-around).  Returns zeros for a
    constant signal.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    xc = x - x.mean()
    nfft = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(xc, nfft)
    acf = np.fft.irfft(spec * np.conj(spec), nfft)[:n]
    if acf[0] <= 0:
        return np.zeros(n)
    return acf / acf[0]


def _moving_average(a: np.ndarray, width: int) -> np.ndarray:
    if width <= 1:
        return a
    kernel = np.ones(width) / width
    return np.convolve(a, kernel, mode="same")


def _zero_crossings(acf: np.ndarray, max_lag: int) -> np.ndarray:
    """Lags [samples, fractional] where ``acf`` changes sign, linearly interpolated."""
    a = acf[: max_lag + 1]
    s = np.sign(a)
    # Exact zeros take the sign of the previous sample so they count once.
    for z in np.flatnonzero(s == 0):
        s[z] = s[z - 1] if z > 0 else 1.0
    k = np.flatnonzero(s[1:] != s[:-1])
    return k + a[k] / (a[k] - a[k + 1])


def _significant_crossings(acf: np.ndarray, crossings: np.ndarray, n: int) -> int:
    """Number of leading zero crossings that bound significant ACF lobes.

    The ACF of white noise wanders around zero with standard error ``1/sqrt(n)``
    (Bartlett), so its zero crossings are random.  A crossing counts only if the
    lobe before it (between the previous crossing and this one) reaches
    :data:`ACF_SIGNIFICANCE` standard errors; counting stops at the first lobe that
    does not.
    """
    threshold = ACF_SIGNIFICANCE / math.sqrt(n)
    for i in range(1, crossings.size):
        lo = int(math.ceil(crossings[i - 1]))
        hi = int(math.floor(crossings[i])) + 1
        if hi <= lo or np.max(np.abs(acf[lo:hi])) < threshold:
            return i
    return crossings.size


def _acf_periods(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero crossings [samples] of the smoothed ACF and full-period estimates [samples]."""
    return _periods_of_acf(autocorrelation(x))


def _periods_of_acf(acf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_acf_periods` of a signal whose autocorrelation ``acf`` is known."""
    n = acf.size
    max_lag = int(0.9 * n)
    first = _zero_crossings(acf, max_lag)
    if first.size == 0:
        return first, first
    width = int(round(first[0] / 10.0))
    if width >= 2:
        acf = _moving_average(acf, width | 1)
    crossings = _zero_crossings(acf, max_lag)[:MAX_ZERO_CROSSINGS]
    crossings = crossings[: _significant_crossings(acf, crossings, n)]
    periods = crossings[2:] - crossings[:-2]
    return crossings, periods


def acf_period_samples(x: np.ndarray) -> float | None:
    """Period [samples] of the dominant oscillation from the ACF zero crossings.

    Mean of the full-period estimates between alternate zero crossings of the
    autocorrelation (Thornhill et al. 2003) of the linearly detrended signal; None
    when the ACF has fewer than three zero crossings.  No regularity check: use
    :func:`detect_oscillation` to decide whether an oscillation is present.  The
    period in seconds is :func:`dominant_period`.
    """
    x = _interpolate_nans(x)
    if x.size < MIN_SAMPLES or np.ptp(x) == 0:
        return None
    _, periods = _acf_periods(detrend_linear(x))
    if periods.size == 0:
        return None
    return float(periods.mean())


def dominant_period(x: np.ndarray, dt: float) -> float | None:
    """Period [s] of the dominant oscillation from the ACF zero crossings
    (:func:`acf_period_samples` times the checked sample time ``dt``), or None."""
    dt = check_dt(dt)
    period = acf_period_samples(x)
    return None if period is None else period * dt


def _detrend_by_cycles(x: np.ndarray, period_samples: float) -> np.ndarray:
    """Remove the running mean over :data:`DETREND_PERIODS` periods.

    The mean over a window of whole periods of a periodic signal is constant
    whatever its phase, so it follows only the drift (ramps, wandering, the steps of
    load changes smeared over the window).  The window is ``DETREND_PERIODS *
    period_samples`` long exactly, not rounded to whole samples: the sums come from
    the cumulative sum interpolated at fractional positions, so a period that is not
    a whole number of samples leaves no ripple at the period.  Within half a window
    of either end the window stops at the end (the trend there is the first or last
    whole window's).  O(n).
    """
    n = x.size
    width = min(DETREND_PERIODS * period_samples, float(n - 1))
    if width < 2.0:
        return x - x.mean()
    grid = np.arange(n + 1, dtype=float)  # cumsum[j] = sum of x[:j]
    csum = np.concatenate([[0.0], np.cumsum(x)])
    half = width / 2.0
    centre = np.clip(np.arange(n) + 0.5, half, n - half)
    lo = np.interp(centre - half, grid, csum)
    hi = np.interp(centre + half, grid, csum)
    return x - (hi - lo) / width


def _refine_detrend(
    x: np.ndarray, xd: np.ndarray, crossings: np.ndarray, periods: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Detrend over a few periods and measure again, until the period settles.

    The first pass (a least-squares line) leaves any drift that is not a straight
    line: a wandering or stepping op dominates its autocorrelation, whose zero
    crossings are then irregular.  Its period, even rough, sets the width of a
    running mean (:func:`_detrend_by_cycles`) that removes the drift and leaves
    the cycle; the period measured on that signal sets the next width, up to
    :data:`DETREND_PASSES` times or until it changes by less than
    :data:`DETREND_CONVERGED`.  A pass that loses the period keeps the previous
    one.  Runs when the first pass gives :data:`MIN_PERIOD_ESTIMATES` periods and
    the record holds two of them (as the straight line through the cycle means
    that this replaces).  Each pass is O(n log n) (the autocorrelation).
    """
    if periods.size < MIN_PERIOD_ESTIMATES or x.size < 2 * periods.mean():
        return xd, crossings, periods
    period = float(periods.mean())
    for _ in range(DETREND_PASSES):
        xr = _detrend_by_cycles(x, period)
        cr, pr = _acf_periods(xr)
        if pr.size < MIN_PERIOD_ESTIMATES:
            break
        xd, crossings, periods = xr, cr, pr
        settled = abs(float(pr.mean()) - period) < DETREND_CONVERGED * period
        period = float(pr.mean())
        if settled:
            break
    return xd, crossings, periods


def _regularity(periods: np.ndarray) -> float:
    """Thornhill et al.'s ``mean(Tp) / (3 std(Tp))`` [-], bounded by
    :data:`MAX_REGULARITY`."""
    std_tp = float(periods.std(ddof=1))
    mean_tp = float(periods.mean())
    return min(MAX_REGULARITY, mean_tp / (3.0 * std_tp) if std_tp > 0 else math.inf)


def _side_dips(a: np.ndarray, peak: int, floor: float, step: int) -> bool:
    """Whether ``a``, walked from ``peak`` by ``step`` (-1 or +1) to its end, falls to
    ``floor`` or below before it rises above ``a[peak]``.  Walked in windows that
    double, so the cost is that of the walk."""
    top = a[peak]
    i, width = peak + step, 16
    while 0 <= i < a.size:
        j = max(i - width + 1, 0) if step < 0 else min(i + width, a.size)
        w = a[j : i + 1][::-1] if step < 0 else a[i:j]
        stop = np.flatnonzero((w > top) | (w <= floor))
        if stop.size:
            return bool(w[stop[0]] <= floor)
        i, width = (j - 1 if step < 0 else j), 2 * width
    return False


def _prominent_peaks(a: np.ndarray, height: float, first: int, count: int) -> list[int]:
    """The first ``count`` peaks of ``a`` at index ``first`` or later whose
    prominence is at least ``height``: what ``scipy.signal.find_peaks(a,
    prominence=height)`` keeps (a local maximum, a plateau's middle sample; its
    prominence the height above the higher of the lowest points on either side
    before a higher sample), without loading ``scipy.signal`` on the analysis path.
    O(n) for the maxima, and each peak's walk stops at its first dip or rise."""
    new = np.r_[True, a[1:] != a[:-1]]
    start = np.flatnonzero(new)
    end = np.r_[start[1:] - 1, a.size - 1]
    u = a[start]
    j = np.flatnonzero((u[1:-1] > u[:-2]) & (u[1:-1] > u[2:])) + 1
    found: list[int] = []
    for peak in (start[j] + end[j]) // 2:
        if len(found) == count:
            break
        floor = a[peak] - height
        if peak >= first and _side_dips(a, peak, floor, -1) and _side_dips(a, peak, floor, 1):
            found.append(int(peak))
    return found


def _seeded_detrend(
    x: np.ndarray, acf: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The cycle a drift hides from the straight line's ACF ``acf``, seeded by its
    peaks (module doc): the most regular detrended signal, its crossings and
    periods, or None when no seed holds.  O(n log n) per seed, at most
    :data:`SEED_PEAKS` seeds."""
    n = x.size
    top = int(n / MIN_CYCLES)
    peaks = _prominent_peaks(acf[: top + 1], ACF_SIGNIFICANCE / math.sqrt(n), 4, SEED_PEAKS)
    best: tuple[float, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None
    for seed in map(float, peaks):
        xr = _detrend_by_cycles(x, seed)
        cr, pr = _acf_periods(xr)
        if pr.size < MIN_PERIOD_ESTIMATES or abs(pr.mean() - seed) > SEED_CONSISTENCY * seed:
            continue
        found = _refine_detrend(x, xr, cr, pr)
        if abs(found[2].mean() - seed) > SEED_CONSISTENCY * seed:
            continue  # the refinement walked away from the seed: not the seed's cycle
        r = _regularity(found[2])
        if best is None or r > best[0]:
            best = (r, found)
    return None if best is None else best[1]


def _cycle_ranges(x: np.ndarray, period_samples: float) -> np.ndarray:
    """Peak-to-peak range of consecutive windows one period long [units of x]."""
    m = max(2, int(round(period_samples)))
    n_win = x.size // m
    if n_win == 0:
        return np.array([np.ptp(x)])
    w = x[: n_win * m].reshape(n_win, m)
    return w.max(axis=1) - w.min(axis=1)


def detect_oscillation(x: np.ndarray, dt: float) -> Oscillation:
    """Detect a regular, sustained oscillation and measure its period and amplitude.

    Autocorrelation zero-crossing method of Thornhill, Huang & Zhang (2003); see the
    module docstring for the thresholds.  Drift is removed first (a least-squares
    line, then, once the period is known, a running mean over a few periods,
    which the oscillation does not move, :func:`_refine_detrend`), so a drifting
    or stepping signal does not mask the oscillation.  O(n log n) in the record
    length n (autocorrelations by FFT; the running means are O(n)).

    Parameters
    ----------
    x : ndarray
        Uniformly sampled signal (pv, op or mv) [any units].  Interior NaNs are
        linearly interpolated, leading and trailing NaNs dropped.
    dt : float
        Sample time [s], > 0.

    Returns
    -------
    Oscillation
        ``present`` with period [s], amplitude (half peak-to-peak, units of x),
        regularity and number of cycles; or ``present=False`` with a reason for a
        short, constant, irregular (noise) or decaying signal.

    Notes
    -----
    The amplitude is the median over one-period windows of the window's peak-to-peak
    range, halved.  When the signal carries measurable white noise (robust noise
    estimate above 1 % of the signal's standard deviation) the ranges are taken on a
    Savitzky-Golay smoothed copy (cubic, window a tenth of a period) so noise spikes
    do not inflate them; the cubic fit keeps the peaks of sines and of the triangular
    stiction cycles within a few percent.
    """
    dt = check_dt(dt)
    x = _interpolate_nans(x)
    n = x.size
    if n < MIN_SAMPLES:
        return _absent(Absence.FEW_SAMPLES, f"too few samples ({n} < {MIN_SAMPLES})")
    if np.ptp(x) == 0:
        return _absent(Absence.CONSTANT, "constant signal")
    xd = detrend_linear(x)
    if np.ptp(xd) <= 1e-12 * max(1.0, float(np.max(np.abs(x)))):
        return _absent(Absence.RAMP, "signal is a pure ramp")
    line_acf = autocorrelation(xd)
    crossings, periods = _periods_of_acf(line_acf)
    xd, crossings, periods = _refine_detrend(x, xd, crossings, periods)
    if periods.size < MIN_PERIOD_ESTIMATES or _regularity(periods) <= REGULARITY_THRESHOLD:
        seeded = _seeded_detrend(x, line_acf)
        if seeded is not None and (
            periods.size < MIN_PERIOD_ESTIMATES or _regularity(seeded[2]) > _regularity(periods)
        ):
            xd, crossings, periods = seeded
    if periods.size < MIN_PERIOD_ESTIMATES:
        return _absent(
            Absence.FEW_CROSSINGS,
            f"autocorrelation has {crossings.size} zero crossings, "
            f"need {MIN_PERIOD_ESTIMATES + 2} for a regular oscillation",
        )
    mean_tp = float(periods.mean())
    regularity = _regularity(periods)
    n_cycles = n / mean_tp
    if regularity <= REGULARITY_THRESHOLD:
        return _absent(
            Absence.IRREGULAR,
            f"irregular: regularity {regularity:.2f} <= {REGULARITY_THRESHOLD}",
            regularity,
        )
    if n_cycles < MIN_CYCLES:
        return _absent(
            Absence.FEW_CYCLES,
            f"only {n_cycles:.1f} cycles in the record (< {MIN_CYCLES})",
            regularity,
        )

    xs = xd
    sigma = second_difference_noise_std(xd, min_samples=5)
    win = int(round(mean_tp / 10.0)) | 1
    if sigma > 0.01 * float(np.std(xd)) and win >= 5:
        xs = savgol_smooth(xd, win, 3)
    ranges = _cycle_ranges(xs, mean_tp)
    third = max(1, ranges.size // 3)
    early = float(np.median(ranges[:third]))
    late = float(np.median(ranges[-third:]))
    if early > 0 and late < MIN_SUSTAIN_RATIO * early:
        return _absent(
            Absence.DECAYING,
            f"decaying: late cycles are {late / early:.2f} of the early ones "
            f"(< {MIN_SUSTAIN_RATIO})",
            regularity,
        )
    amplitude = float(np.median(ranges)) / 2.0
    return Oscillation(
        present=True,
        period_s=mean_tp * dt,
        amplitude=amplitude,
        regularity=float(regularity),
        n_cycles=float(n_cycles),
        reason=None,
    )


def fundamental_amplitude(x: np.ndarray, period_samples: float) -> float | None:
    """Amplitude of the cycle's fundamental [units of x]: the median, over
    consecutive windows one period long, of ``|2/P sum x[k] exp(-2 pi i k / P)|``.

    This is the amplitude a describing function speaks of (the first Fourier
    coefficient of the signal, Choudhury, Thornhill & Shah 2005, Eq. 6), not the half
    peak-to-peak range of :func:`detect_oscillation`: a triangle's fundamental is
    8/pi^2 of its peak, a square wave's 4/pi.  Drift is removed first by the running
    mean over whole periods (:func:`_detrend_by_cycles`); each window's own
    fundamental is taken, so a period that wanders a little between cycles does not
    cancel the sum as one projection over the record would.  O(n).  None for a
    period shorter than 4 samples or a record shorter than one period.
    """
    x = _interpolate_nans(np.asarray(x, dtype=float))
    m = int(round(period_samples)) if math.isfinite(period_samples) else 0
    if m < 4 or x.size < m:
        return None
    xd = _detrend_by_cycles(x, float(period_samples))
    n_win = xd.size // m
    w = xd[: n_win * m].reshape(n_win, m)
    kernel = np.exp(-2j * np.pi * np.arange(m) / m)
    return float(np.median(np.abs(w @ kernel)) * 2.0 / m)
