"""Classic data-driven stiction tests, as baselines for the model-based verdict.

Two families of published tests are implemented so that they can be run side by side
with :mod:`stictiondiag.analysis` on the same loops:

* **Horch's cross-correlation test** (Horch 1999, "A simple method for detection of
  stiction in control valves", Control Engineering Practice 7, 1221-1231; Horch 2000,
  PhD thesis, KTH, cited in Section 2 of Choudhury, Thornhill & Shah 2005).  In a
  self-regulating loop a stiction limit cycle makes the controller output ``op`` a
  triangle (it integrates a square-ish control error), a quarter of a cycle out of
  phase with the process output ``pv``: the cross-correlation function (CCF) of
  ``op`` and ``pv`` is *odd* around lag 0.  A linear oscillation (aggressive tuning,
  or an external disturbance the controller fights) puts ``op`` and ``pv`` near
  anti-phase: the CCF is *even*, with a large ``|r(0)|``.  For integrating processes
  (level loops) the integrator adds its own quarter cycle and the CCF rule fails;
  Horch's extension (Horch 2002; Horch & Isaksson) looks at the *second derivative*
  of ``pv`` instead (see :func:`horch_cross_correlation`).

* **The bicoherence test** of Choudhury, Shah & Thornhill (2004), "Diagnosis of poor
  control-loop performance using higher-order statistics", Automatica 40, 1719-1728
  (cited in Section 5.3 of Choudhury, Thornhill & Shah 2005), with the Total
  Nonlinearity Index of Choudhury, Shook & Shah (2006), "Linear or nonlinear?  A
  bicoherence based metric of nonlinearity measure", IFAC SAFEPROCESS.  A linear loop
  driven by Gaussian noise gives a Gaussian control error whose squared bicoherence
  is zero at every bifrequency; a valve nonlinearity couples the phases of the
  harmonics of the limit cycle and raises the bicoherence at a few bifrequencies.
  The test asks "non-Gaussian?" (NGI) and then "nonlinear?" (NLI); for a nonlinear
  loop an elliptic ``pv``-``op`` pattern points to stiction
  (:func:`choudhury_hos_diagnosis`).

Both tests return a verdict ``"stiction"``, ``"no_stiction"`` or ``"inconclusive"``
in the same vocabulary as :class:`stictiondiag.stiction.valvefit.Verdict`.

Decisions this implementation makes (documented per function, tested in
``tests/test_baselines.py``):

* Horch's phase index and its three bands (:data:`HORCH_EVEN_MAX`,
  :data:`HORCH_ODD_MIN`).  With a linear PI controller ``op = -C(pv)`` holds at every
  frequency, so the index is twice the controller's phase lead ``atan(1 / (w Ti))``
  at the cycle frequency ``w``, stiction or not: the CCF is odd only for cycles
  slower than about ``11 Ti``, and a linear loop under a slow external disturbance
  has an odd CCF too.  Both are properties of the published test, kept and tested.
* The bicoherence significance test is applied at a *family-wise* level over the
  principal domain (Bonferroni) by default; ``correction="none"`` gives the
  per-bifrequency test of Choudhury et al. (2004).  The reason is measured, not
  assumed: see :func:`bicoherence_indices`, Notes.
* Half-wave-symmetric limit cycles (odd harmonics only) have a bispectrum that is
  identically zero, so the bicoherence test cannot see them whatever their shape; a
  symmetric stiction cycle in a self-regulating loop is such a cycle.  This is a
  property of the published test, kept as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from stictiondiag.core.errors import (
    DataError,
    UsageError,
)
from stictiondiag.core.filters import detrend_linear
from stictiondiag.signals.oscillation import detect_oscillation

if TYPE_CHECKING:
    import pandas as pd

VerdictLabel = Literal["stiction", "no_stiction", "inconclusive"]

# --------------------------------------------------------------------------------------
# Horch's test: thresholds
# --------------------------------------------------------------------------------------

#: Upper bound of Horch's phase index for an *even* CCF (no stiction) [rad].  The index
#: ``delta_phi = pi |tau_r - tau_l| / (tau_r + tau_l)`` is 0 for a perfectly even CCF and
#: pi for a perfectly odd one; the middle third of [0, pi] is left undecided (Horch
#: 1999, 2000).
HORCH_EVEN_MAX = math.pi / 3.0
#: Lower bound of Horch's phase index for an *odd* CCF (stiction) [rad].
HORCH_ODD_MIN = 2.0 * math.pi / 3.0
#: Cut-off of the low-pass filter in front of the second difference of ``pv`` in the
#: integrating-process test, in multiples of the oscillation frequency.  Ten harmonics
#: keep the corners of a triangular ``pv`` sharp (the spikes of its second derivative
#: stay narrow: a pure triangle filtered this way gives a kurtosis of 8.3) while the
#: white measurement noise, which differencing twice amplifies by sqrt(6) per sample
#: and more at high frequency, is cut.
HORCH_FILTER_HARMONICS = 10.0
#: Kurtosis of the filtered second difference of ``pv`` above which it is a spike train
#: (stiction: a triangular ``pv`` in an integrating loop) [-].  A Gaussian has 3, a
#: sinusoid 1.5, a sinusoid in noise lies between.
HORCH_SPIKE_KURTOSIS = 3.5
#: Kurtosis below which the filtered second difference is a sinusoid (no stiction) [-].
HORCH_SINE_KURTOSIS = 2.5
#: Smallest peak |CCF| (normalised) in the window between the zero crossings, in
#: multiples of the white-noise standard error 1/sqrt(n), for the zero crossings to
#: be those of a real oscillation rather than of estimation noise.
HORCH_CCF_SIGNIFICANCE = 3.0

# --------------------------------------------------------------------------------------
# Bicoherence test: thresholds and estimator settings
# --------------------------------------------------------------------------------------

#: NGI above which the signal is non-Gaussian (Choudhury et al. 2004; the small
#: positive margin is theirs, to absorb estimation error).
NGI_THRESHOLD = 0.001
#: NLI above which a non-Gaussian signal is nonlinear (Choudhury et al. 2004).
NLI_THRESHOLD = 0.01
#: Significance level of the chi-square test of zero bicoherence.
BICOHERENCE_ALPHA = 0.05
#: Default FFT (segment) length [samples] (Choudhury et al. 2004 use 128).
BICOHERENCE_NFFT = 128
#: Default overlap of consecutive segments [fraction of nfft].
BICOHERENCE_OVERLAP = 0.5
#: Percentile of the bicoherence denominator used as the conditioning term epsilon
#: (Choudhury, Shah & Thornhill 2008, Diagnosis of Process Nonlinearities and Valve
#: Stiction, Springer, Section 3; it damps the spurious 0/0 peaks at bifrequencies
#: without power).
BICOHERENCE_CONDITIONING_PERCENTILE = 75.0
#: Fraction of the smallest and of the largest squared bicoherence values left out of
#: the robust mean and standard deviation in the NLI (Choudhury et al. 2004).
NLI_TRIM = 0.10
#: Fewest segments for a bicoherence estimate; below it the chi-square approximation
#: of the estimator's distribution is meaningless.
MIN_SEGMENTS = 8
#: Shortest FFT length the automatic reduction for short records goes down to.
MIN_NFFT = 32
#: Target oscillation period after automatic decimation, in samples per ``nfft``
#: (a quarter of the segment: four cycles per segment, the fundamental at bin 4, and
#: harmonics up to the 16th below the Nyquist frequency for nfft = 128).
CYCLES_PER_SEGMENT = 4.0

#: Largest critical squared bicoherence at which a Gaussian finding still counts as
#: evidence of a linear loop in :func:`choudhury_hos_diagnosis`.  Above it the record
#: has too few segments for the test to see anything but near-perfect phase coupling
#: (with the family-wise test about K < 20 segments), and "Gaussian" only means "too
#: short to tell".
HOS_MAX_THRESHOLD = 0.5

# --------------------------------------------------------------------------------------
# pv-op ellipse (Choudhury et al. 2004, 2006)
# --------------------------------------------------------------------------------------

#: Minor-to-major axis ratio above which the filtered pv-op plot is an open ellipse.
#: Two unit-variance sinusoids with phase difference phi give the ratio
#: sqrt((1 - |cos phi|) / (1 + |cos phi|)); 0.2 means phi at least 22.6 degrees away
#: from in-phase or anti-phase.
ELLIPSE_MIN_AXIS_RATIO = 0.2
#: Band of the pv-op band-pass filter around the oscillation frequency [multiples of
#: the oscillation frequency] (the oscillation band Choudhury et al. 2006 keep).
ELLIPSE_BAND = (0.5, 2.0)


# ======================================================================================
# helpers
# ======================================================================================


def _plain(v) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _signal(x, name: str, min_samples: int = 16) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"{name} must be numeric") from None
    if a.ndim != 1:
        raise DataError(f"{name} must be a one-dimensional signal, got shape {a.shape}")
    if a.size < min_samples:
        raise DataError(f"{name} has {a.size} samples; the test needs at least {min_samples}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{name} contains NaN or infinite values; fill or drop them first")
    if np.ptp(a) == 0:
        raise DataError(f"{name} is constant; the test needs a varying signal")
    return a


def _check_dt(dt) -> float:
    try:
        dt_ = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"sample time dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt_) and dt_ > 0):
        raise UsageError(f"sample time dt must be a positive number of seconds, got {dt_}")
    return dt_


def _first_crossing(r: np.ndarray) -> float | None:
    """Position [samples, fractional] of the first sign change of ``r`` from index 0.

    ``r[0]`` is the value at lag 0.  An exact zero at lag 0 is a crossing at 0.
    Linear interpolation between the two samples that bracket the change.
    """
    if r[0] == 0.0:
        return 0.0
    s = np.sign(r)
    # An exact zero later on takes the sign of the sample before it (counted once).
    for k in np.flatnonzero(s == 0):
        s[k] = s[k - 1]
    k = np.flatnonzero(s[1:] != s[0])
    if k.size == 0:
        return None
    k0 = int(k[0])
    return k0 + r[k0] / (r[k0] - r[k0 + 1])


def cross_correlation(op: np.ndarray, pv: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ``r(tau) = E[op(t) pv(t + tau)] / (s_op s_pv)``.

    Biased estimator (divided by n at every lag) of the linearly detrended signals,
    computed by FFT with zero padding; returned for lags ``-max_lag .. max_lag``
    (index ``max_lag`` is lag 0) [-].
    """
    a = detrend_linear(np.asarray(op, dtype=float))
    b = detrend_linear(np.asarray(pv, dtype=float))
    n = a.size
    nfft = 1 << (2 * n - 1).bit_length()
    spec = np.conj(np.fft.rfft(a, nfft)) * np.fft.rfft(b, nfft)
    full = np.fft.irfft(spec, nfft)
    # full[k] = sum_t a[t] b[t + k] for k >= 0; negative lags wrap to the end.
    r = np.concatenate([full[nfft - max_lag :], full[: max_lag + 1]])
    scale = n * a.std() * b.std()
    return r / scale


# ======================================================================================
# Horch (1999, 2000, 2002)
# ======================================================================================


@dataclass(frozen=True)
class HorchResult:
    """Result of :func:`horch_cross_correlation`.

    Attributes
    ----------
    verdict : {"stiction", "no_stiction", "inconclusive"}
        Horch's classification.
    method : {"cross_correlation", "second_derivative"}
        The self-regulating test (CCF odd or even) or the integrating-process test
        (distribution of the second derivative of pv).
    oscillating : bool
        An oscillation was detected in pv or op (:func:`detect_oscillation`); both of
        Horch's tests presuppose one.
    period_s : float or None
        Oscillation period [s] (of pv, else of op); None when no oscillation.
    delta_phi : float or None
        Horch's phase index ``pi |tau_r - tau_l| / (tau_r + tau_l)`` [rad], 0 for an
        even CCF, pi for an odd one; None for the integrating test or when the CCF has
        no zero crossing on one side.
    tau_left_s, tau_right_s : float or None
        Distance from lag 0 to the first zero crossing of the CCF on the negative and
        on the positive side [s].
    r0 : float or None
        Normalised CCF at lag 0 [-].
    r_peak : float or None
        Largest |CCF| between one half-cycle before the left and after the right zero
        crossing [-]; the crossings count only when it is significant.
    kurtosis : float or None
        Kurtosis of the filtered second difference of pv [-] (integrating test only):
        about 1.5 for a sinusoidal pv, 3 for noise, above 3 for the spike train of a
        triangular pv.
    reasons : tuple of str
        Why the verdict was reached, in words.
    lags_s, ccf : ndarray or None
        The CCF [-] against lag [s] over the searched window (self-regulating test);
        kept for plotting, left out of :meth:`to_dict`.
    """

    verdict: VerdictLabel
    method: str
    oscillating: bool
    period_s: float | None
    delta_phi: float | None
    tau_left_s: float | None
    tau_right_s: float | None
    r0: float | None
    r_peak: float | None
    kurtosis: float | None
    reasons: tuple[str, ...]
    lags_s: np.ndarray | None = field(default=None, repr=False, compare=False)
    ccf: np.ndarray | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-able dict of the scalar fields (plain floats, None for missing)."""
        return {
            "verdict": self.verdict,
            "method": self.method,
            "oscillating": bool(self.oscillating),
            "period_s": _plain(self.period_s),
            "delta_phi": _plain(self.delta_phi),
            "delta_phi_deg": (
                None if self.delta_phi is None else _plain(math.degrees(self.delta_phi))
            ),
            "tau_left_s": _plain(self.tau_left_s),
            "tau_right_s": _plain(self.tau_right_s),
            "r0": _plain(self.r0),
            "r_peak": _plain(self.r_peak),
            "kurtosis": _plain(self.kurtosis),
            "reasons": list(self.reasons),
        }

    def to_pandas(self) -> pd.DataFrame:
        """The CCF as a DataFrame with columns ``lag_s`` [s] and ``ccf`` [-]."""
        import pandas as pd

        if self.ccf is None or self.lags_s is None:
            return pd.DataFrame({"lag_s": [], "ccf": []})
        return pd.DataFrame({"lag_s": self.lags_s, "ccf": self.ccf})


def _oscillation_of(pv: np.ndarray, op: np.ndarray, dt: float):
    osc_pv = detect_oscillation(pv, dt)
    if osc_pv.present:
        return True, osc_pv.period_s
    osc_op = detect_oscillation(op, dt)
    if osc_op.present:
        return True, osc_op.period_s
    return False, None


def horch_cross_correlation(
    op: np.ndarray,
    pv: np.ndarray,
    dt: float,
    *,
    integrating: bool = False,
) -> HorchResult:
    """Horch's stiction test: odd or even cross-correlation of op and pv.

    Parameters
    ----------
    op : ndarray
        Controller output [% of span] (any affine scale: the test is scale-free).
    pv : ndarray
        Process output (controlled variable) [pv units]; the control error may be
        passed instead, the CCF only changes sign.
    dt : float
        Sample time [s].
    integrating : bool
        The process integrates (level loop): use Horch's second-derivative test.

    Returns
    -------
    HorchResult
        Verdict, Horch's phase index and the CCF.

    Notes
    -----
    *Self-regulating processes* (Horch 1999).  The CCF
    ``r(tau) = E[op(t) pv(t + tau)]`` of the linearly detrended signals is computed
    for lags up to half the record.  Let ``tau_l`` and ``tau_r`` be the distances
    from lag 0 to the first zero crossing on the negative and positive side (linear
    interpolation).  For a CCF ``cos(w (tau - tau_m))`` they sit a quarter cycle
    either side of its extremum ``tau_m``, so the position of lag 0 between them,

        delta_phi = pi |tau_r - tau_l| / (tau_r + tau_l)    [rad],

    is twice the phase of lag 0 measured from the extremum: 0 when lag 0 is the
    extremum (even CCF, op and pv in anti-phase or in phase: no stiction), pi when
    lag 0 is itself a zero crossing (odd CCF, a quarter-cycle shift: stiction).
    ``delta_phi <= pi/3`` gives "no_stiction", ``delta_phi >= 2 pi/3`` gives
    "stiction", the middle third "inconclusive".  The crossings count only when the
    CCF between them reaches :data:`HORCH_CCF_SIGNIFICANCE` white-noise standard
    errors.

    *Integrating processes* (Horch's extension, Horch 2002; Horch & Isaksson).  The
    integrator turns the square-ish valve position of a stiction cycle into a
    triangular pv, and shifts the phase so that the CCF rule no longer holds.  A
    triangle's second derivative is a train of spikes at its corners, a sinusoid's is
    a sinusoid; Horch distinguishes them by the distribution of the filtered second
    derivative of pv (a spike train in noise is Gaussian-like with heavy tails, a
    sinusoid is bimodal).  Horch compares least-squares fits of the two candidate
    distributions to the histogram; here the comparison is made with the kurtosis
    ``E[z^4] / E[z^2]^2`` of the standardised signal, which orders the same three
    shapes (sinusoid 1.5, Gaussian noise 3, spike train above 3) without fitting the
    noise level, and whose thresholds (:data:`HORCH_SINE_KURTOSIS`,
    :data:`HORCH_SPIKE_KURTOSIS`) leave pure noise undecided.  pv is detrended and
    low-pass filtered (zero-phase Butterworth, order 4) at
    :data:`HORCH_FILTER_HARMONICS` times the oscillation frequency before the second
    difference is taken.

    Both tests presuppose an oscillating loop: when neither pv nor op oscillates
    (:func:`stictiondiag.signals.oscillation.detect_oscillation`) the verdict is
    "inconclusive"; the CCF index is still reported for the self-regulating test.
    """
    dt = _check_dt(dt)
    op = _signal(op, "op")
    pv = _signal(pv, "pv")
    if op.size != pv.size:
        raise DataError(f"op and pv must have the same length, got {op.size} and {pv.size}")
    oscillating, period_s = _oscillation_of(pv, op, dt)
    if integrating:
        return _horch_integrating(pv, dt, oscillating, period_s)

    n = pv.size
    max_lag = n // 2
    r = cross_correlation(op, pv, max_lag)
    lags = np.arange(-max_lag, max_lag + 1)
    right = _first_crossing(r[max_lag:])
    left = _first_crossing(r[max_lag::-1])
    r0 = float(r[max_lag])
    reasons: list[str] = []
    delta_phi = r_peak = None
    if right is None or left is None:
        reasons.append("the CCF has no zero crossing on one side of lag 0")
    elif left + right == 0.0:
        reasons.append("the CCF is zero at lag 0 and has no other crossing")
    else:
        delta_phi = math.pi * abs(right - left) / (right + left)
        half = 0.5 * (right + left)
        lo = max(0, int(math.floor(max_lag - left - half)))
        hi = min(r.size, int(math.ceil(max_lag + right + half)) + 1)
        r_peak = float(np.max(np.abs(r[lo:hi])))
    significant = r_peak is not None and r_peak >= HORCH_CCF_SIGNIFICANCE / math.sqrt(n)
    if r_peak is not None and not significant:
        reasons.append(
            f"the CCF peak {r_peak:.3f} is within {HORCH_CCF_SIGNIFICANCE:g} standard "
            f"errors of zero: its zero crossings are noise"
        )
    if not oscillating:
        reasons.append("no oscillation in pv or op: Horch's test applies to oscillating loops")

    verdict: VerdictLabel = "inconclusive"
    if delta_phi is not None and significant:
        deg = math.degrees(delta_phi)
        if delta_phi >= HORCH_ODD_MIN:
            shape = f"odd CCF (delta_phi {deg:.0f} deg >= 120 deg): stiction likely"
            if oscillating:
                verdict = "stiction"
            reasons.insert(0, shape)
        elif delta_phi <= HORCH_EVEN_MAX:
            shape = f"even CCF (delta_phi {deg:.0f} deg <= 60 deg): no stiction"
            if oscillating:
                verdict = "no_stiction"
            reasons.insert(0, shape)
        else:
            reasons.insert(0, f"CCF neither odd nor even (delta_phi {deg:.0f} deg)")
    return HorchResult(
        verdict=verdict,
        method="cross_correlation",
        oscillating=oscillating,
        period_s=period_s,
        delta_phi=delta_phi,
        tau_left_s=None if left is None else left * dt,
        tau_right_s=None if right is None else right * dt,
        r0=r0,
        r_peak=r_peak,
        kurtosis=None,
        reasons=tuple(reasons),
        lags_s=lags * dt,
        ccf=r,
    )


def _horch_integrating(
    pv: np.ndarray, dt: float, oscillating: bool, period_s: float | None
) -> HorchResult:
    common = dict(
        method="second_derivative",
        oscillating=oscillating,
        period_s=period_s,
        delta_phi=None,
        tau_left_s=None,
        tau_right_s=None,
        r0=None,
        r_peak=None,
    )
    if not oscillating or period_s is None:
        return HorchResult(
            verdict="inconclusive",
            kurtosis=None,
            reasons=("no oscillation in pv or op: Horch's test applies to oscillating loops",),
            **common,
        )
    nyquist = 0.5 / dt
    wn = HORCH_FILTER_HARMONICS / period_s / nyquist
    y = detrend_linear(pv)
    if wn < 0.9:
        from scipy import signal as sps  # imported here: scipy.signal is slow to import

        b, a = sps.butter(4, wn)
        y = sps.filtfilt(b, a, y)
    d2 = np.diff(y, 2)
    z = d2 - d2.mean()
    var = float(np.mean(z**2))
    if var <= 0:
        return HorchResult(
            verdict="inconclusive",
            kurtosis=None,
            reasons=("second difference of pv is zero",),
            **common,
        )
    kurt = float(np.mean(z**4) / var**2)
    if kurt >= HORCH_SPIKE_KURTOSIS:
        verdict: VerdictLabel = "stiction"
        why = (
            f"second derivative of pv is a spike train (kurtosis {kurt:.2f} >= "
            f"{HORCH_SPIKE_KURTOSIS:g}): triangular pv, stiction likely"
        )
    elif kurt <= HORCH_SINE_KURTOSIS:
        verdict = "no_stiction"
        why = (
            f"second derivative of pv is sinusoidal (kurtosis {kurt:.2f} <= "
            f"{HORCH_SINE_KURTOSIS:g}): no stiction"
        )
    else:
        verdict = "inconclusive"
        why = f"second derivative of pv is Gaussian-like (kurtosis {kurt:.2f})"
    return HorchResult(verdict=verdict, kurtosis=kurt, reasons=(why,), **common)


# ======================================================================================
# Bicoherence (Choudhury, Shah & Thornhill 2004)
# ======================================================================================


@dataclass(frozen=True)
class BicoherenceResult:
    """Result of :func:`bicoherence_indices`.

    Attributes
    ----------
    ngi : float
        Non-Gaussianity index [-]: mean squared bicoherence of the significant
        bifrequencies minus the significance threshold (``-threshold`` when none is
        significant).  Non-Gaussian when above :data:`NGI_THRESHOLD`.
    nli : float
        Nonlinearity index [-]: ``|max bic^2 - (robust mean + 2 robust std)|``.
        Nonlinear (given non-Gaussian) when above :data:`NLI_THRESHOLD`.
    tnli : float
        Total nonlinearity index [-]: sum of the significant squared bicoherence
        values (Choudhury, Shook & Shah 2006).
    non_gaussian, nonlinear : bool
        ``ngi > NGI_THRESHOLD``; ``non_gaussian and nli > NLI_THRESHOLD``.
    threshold : float
        Critical squared bicoherence ``chi2_2(1 - alpha') / (2 K)`` [-], with
        ``alpha'`` the per-bifrequency level.
    alpha : float
        Significance level (family-wise with ``correction="bonferroni"``).
    correction : {"bonferroni", "none"}
        Multiple-comparison correction of the per-bifrequency test.
    n_segments : int
        Number K of (overlapping) segments averaged.
    nfft : int
        Segment / FFT length actually used [samples of the decimated signal].
    decimation : int
        Decimation factor applied before the estimate.
    n_bifrequencies, n_significant : int
        Size of the principal domain searched, and how many values were significant.
    max_bicoherence : float
        Largest squared bicoherence [-].
    peak_f1_hz, peak_f2_hz : float
        Bifrequency of the largest squared bicoherence [Hz].
    f1_hz, f2_hz, bic2 : ndarray
        The principal domain (``f1 >= f2 > 0``, ``f1 + f2 <= fs/2``) [Hz] and its
        squared bicoherence [-]; left out of :meth:`to_dict`.
    """

    ngi: float
    nli: float
    tnli: float
    non_gaussian: bool
    nonlinear: bool
    threshold: float
    alpha: float
    correction: str
    n_segments: int
    nfft: int
    decimation: int
    n_bifrequencies: int
    n_significant: int
    max_bicoherence: float
    peak_f1_hz: float
    peak_f2_hz: float
    f1_hz: np.ndarray = field(repr=False, compare=False)
    f2_hz: np.ndarray = field(repr=False, compare=False)
    bic2: np.ndarray = field(repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-able dict of the scalar fields."""
        return {
            "ngi": _plain(self.ngi),
            "nli": _plain(self.nli),
            "tnli": _plain(self.tnli),
            "non_gaussian": bool(self.non_gaussian),
            "nonlinear": bool(self.nonlinear),
            "threshold": _plain(self.threshold),
            "alpha": _plain(self.alpha),
            "correction": self.correction,
            "n_segments": int(self.n_segments),
            "nfft": int(self.nfft),
            "decimation": int(self.decimation),
            "n_bifrequencies": int(self.n_bifrequencies),
            "n_significant": int(self.n_significant),
            "max_bicoherence": _plain(self.max_bicoherence),
            "peak_f1_hz": _plain(self.peak_f1_hz),
            "peak_f2_hz": _plain(self.peak_f2_hz),
        }

    def to_pandas(self) -> pd.DataFrame:
        """Principal domain as a DataFrame: ``f1_hz``, ``f2_hz``, ``bic2``, ``significant``."""
        import pandas as pd

        return pd.DataFrame(
            {
                "f1_hz": self.f1_hz,
                "f2_hz": self.f2_hz,
                "bic2": self.bic2,
                "significant": self.bic2 > self.threshold,
            }
        )

    def at(self, f1_hz: float, f2_hz: float) -> float:
        """Squared bicoherence at the grid bifrequency nearest to (f1, f2) [-].

        The pair is put in the principal domain first (``f1 >= f2``).
        """
        a, b = max(f1_hz, f2_hz), min(f1_hz, f2_hz)
        k = int(np.argmin((self.f1_hz - a) ** 2 + (self.f2_hz - b) ** 2))
        return float(self.bic2[k])


def _segments_count(n: int, nfft: int, overlap: float) -> int:
    step = max(1, int(round(nfft * (1.0 - overlap))))
    return 0 if n < nfft else 1 + (n - nfft) // step


def bicoherence_indices(
    x: np.ndarray,
    *,
    dt: float = 1.0,
    nfft: int = BICOHERENCE_NFFT,
    overlap: float = BICOHERENCE_OVERLAP,
    window: str = "hann",
    decimation: int = 1,
    alpha: float = BICOHERENCE_ALPHA,
    correction: Literal["bonferroni", "none"] = "bonferroni",
    conditioning_percentile: float | None = BICOHERENCE_CONDITIONING_PERCENTILE,
) -> BicoherenceResult:
    """Squared bicoherence and the NGI, NLI and TNLI of Choudhury et al. (2004, 2006).

    Parameters
    ----------
    x : ndarray
        Signal [any units]: the control error ``sp - pv`` (or pv) of a loop.
    dt : float
        Sample time [s] (only scales the reported frequencies).
    nfft : int
        Segment and FFT length [samples, after decimation]; halved (down to
        :data:`MIN_NFFT`) while the record gives fewer than :data:`MIN_SEGMENTS`
        segments.
    overlap : float
        Overlap of consecutive segments [fraction of nfft], in [0, 0.9].
    window : str
        Taper applied to each segment (any :func:`scipy.signal.get_window` name);
        Hann by default.
    decimation : int
        Decimate by this factor first (zero-phase FIR anti-alias filter), so that a
        slow oscillation spans several cycles per segment.
    alpha : float
        Significance level of the test of zero bicoherence.
    correction : {"bonferroni", "none"}
        ``"bonferroni"``: ``alpha`` is family-wise over the principal domain (each
        bifrequency is tested at ``alpha / L``); ``"none"``: each bifrequency at
        ``alpha``, as in Choudhury et al. (2004).
    conditioning_percentile : float or None
        Percentile of the denominator over the principal domain added to it as the
        conditioning term epsilon (None: no conditioning).

    Returns
    -------
    BicoherenceResult

    Notes
    -----
    *Estimator* (direct method, Kim & Powers normalisation).  The record is linearly
    detrended, cut into K segments of ``nfft`` samples with the given overlap, each
    made zero-mean and tapered, and Fourier transformed (``X_k(f)``).  For every
    bifrequency of the principal domain (``f1 >= f2 > 0``, ``f1 + f2 <= fs/2``; the
    inner triangle, DC left out)

        B(f1, f2)     = 1/K sum_k X_k(f1) X_k(f2) X_k*(f1 + f2)
        bic^2(f1, f2) = |B|^2 / (1/K sum_k |X_k(f1) X_k(f2)|^2 * 1/K sum_k |X_k(f1+f2)|^2
                                + epsilon)

    all at once by fancy indexing of the (K, nfft/2 + 1) array of segment spectra.

    *Test.*  For a Gaussian signal ``2 K bic^2`` is asymptotically chi-square with 2
    degrees of freedom at each bifrequency (Hinich; Elgar & Guza), so a value is
    significant when ``bic^2 > c / (2 K)`` with ``c`` the ``1 - alpha'`` quantile of
    chi2(2).  Then (Choudhury et al. 2004; TNLI from Choudhury, Shook & Shah 2006)

        NGI  = mean(bic^2 over significant bifrequencies) - c / (2 K)
        NLI  = |max bic^2 - (robust mean bic^2 + 2 robust std bic^2)|
        TNLI = sum(bic^2 over significant bifrequencies)

    with the robust statistics over the values left after dropping the smallest and
    the largest :data:`NLI_TRIM` of them.  Non-Gaussian: ``NGI > 0.001``; nonlinear:
    non-Gaussian and ``NLI > 0.01``.

    *Why family-wise by default.*  Averaged over the significant values only, the NGI
    of a Gaussian signal is the mean excess of a chi-square tail over its threshold,
    about ``1 / (2 K)`` per unit of conditioning, not zero: with the per-bifrequency
    test (``correction="none"``) white noise of 4096 samples (K = 63) has NGI > 0.001
    in about nine records out of ten, and then NLI (the extreme of about 1000
    chi-square values, about ``5 / K``) above 0.01 as well, i.e. white noise is called
    nonlinear.  The fixed thresholds 0.001 and 0.01 only work for K of the order of
    1000 segments.  Testing the L bifrequencies at a family-wise level keeps the
    indices' definitions and thresholds and makes a Gaussian record rarely show any
    significant value (NGI = -threshold), whatever its length.
    """
    dt = _check_dt(dt)
    x = _signal(x, "signal")
    if not 0.0 <= overlap <= 0.9:
        raise UsageError(f"overlap must be a fraction in [0, 0.9], got {overlap}")
    if not 0.0 < alpha < 1.0:
        raise UsageError(f"alpha must be in (0, 1), got {alpha}")
    if correction not in ("bonferroni", "none"):
        raise UsageError(f"correction must be 'bonferroni' or 'none', got {correction!r}")
    try:
        nfft = int(nfft)
        decimation = int(decimation)
    except (TypeError, ValueError):
        raise UsageError("nfft and decimation must be integers") from None
    if nfft < MIN_NFFT or nfft & (nfft - 1):
        raise UsageError(f"nfft must be a power of two >= {MIN_NFFT}, got {nfft}")
    if decimation < 1:
        raise UsageError(f"decimation must be an integer >= 1, got {decimation}")
    if conditioning_percentile is not None and not 0.0 <= conditioning_percentile <= 100.0:
        raise UsageError(
            f"conditioning_percentile must be in [0, 100] or None, got {conditioning_percentile}"
        )

    from scipy import signal as sps  # imported here: scipy.signal is slow to import
    from scipy.special import chdtri

    x = detrend_linear(x)
    if decimation > 1:
        if x.size // decimation < MIN_NFFT * 2:
            raise DataError(
                f"decimating {x.size} samples by {decimation} leaves too few samples; "
                f"use a smaller decimation"
            )
        x = sps.decimate(x, decimation, ftype="fir", zero_phase=True)
    while nfft > MIN_NFFT and _segments_count(x.size, nfft, overlap) < MIN_SEGMENTS:
        nfft //= 2
    k_seg = _segments_count(x.size, nfft, overlap)
    if k_seg < MIN_SEGMENTS:
        raise DataError(
            f"{x.size} samples give {k_seg} segments of {nfft}; the bicoherence needs at "
            f"least {MIN_SEGMENTS} (a longer record or less decimation)"
        )
    step = max(1, int(round(nfft * (1.0 - overlap))))
    segs = sliding_window_view(x, nfft)[::step][:k_seg]
    segs = segs - segs.mean(axis=1, keepdims=True)
    try:
        taper = sps.get_window(window, nfft)
    except ValueError as exc:
        raise UsageError(f"unknown window {window!r}: {exc}") from None
    spec = np.fft.rfft(segs * taper, axis=1)

    half = nfft // 2
    i1, i2 = np.tril_indices(half + 1)
    keep = (i2 >= 1) & (i1 + i2 <= half)
    i1, i2 = i1[keep], i2[keep]
    x1x2 = spec[:, i1] * spec[:, i2]
    x3 = spec[:, i1 + i2]
    bispec = np.mean(x1x2 * np.conj(x3), axis=0)
    denom = np.mean(np.abs(x1x2) ** 2, axis=0) * np.mean(np.abs(x3) ** 2, axis=0)
    eps = 0.0
    if conditioning_percentile is not None:
        eps = float(np.percentile(denom, conditioning_percentile))
    scale = float(np.max(denom)) if denom.size else 0.0
    if scale <= 0.0:
        raise DataError("the signal has no power at any bifrequency; nothing to test")
    bic2 = np.abs(bispec) ** 2 / (denom + eps + 1e-300 * scale)
    bic2 = np.clip(bic2, 0.0, 1.0)  # Cauchy-Schwarz bound, guards round-off

    n_bif = int(bic2.size)
    alpha_point = alpha / n_bif if correction == "bonferroni" else alpha
    threshold = float(chdtri(2, alpha_point) / (2.0 * k_seg))  # = scipy.stats.chi2.isf
    significant = bic2 > threshold
    n_sig = int(np.count_nonzero(significant))
    mean_sig = float(bic2[significant].mean()) if n_sig else 0.0
    ngi = mean_sig - threshold
    tnli = float(bic2[significant].sum())
    ordered = np.sort(bic2)
    cut = int(NLI_TRIM * n_bif)
    core = ordered[cut : n_bif - cut] if n_bif - 2 * cut >= 2 else ordered
    nli = abs(float(ordered[-1]) - (float(core.mean()) + 2.0 * float(core.std())))
    non_gaussian = ngi > NGI_THRESHOLD
    nonlinear = bool(non_gaussian and nli > NLI_THRESHOLD)

    dt_eff = dt * decimation
    df = 1.0 / (nfft * dt_eff)
    f1 = i1 * df
    f2 = i2 * df
    kmax = int(np.argmax(bic2))
    return BicoherenceResult(
        ngi=ngi,
        nli=nli,
        tnli=tnli,
        non_gaussian=bool(non_gaussian),
        nonlinear=nonlinear,
        threshold=threshold,
        alpha=float(alpha),
        correction=correction,
        n_segments=int(k_seg),
        nfft=int(nfft),
        decimation=int(decimation),
        n_bifrequencies=n_bif,
        n_significant=n_sig,
        max_bicoherence=float(bic2[kmax]),
        peak_f1_hz=float(f1[kmax]),
        peak_f2_hz=float(f2[kmax]),
        f1_hz=f1,
        f2_hz=f2,
        bic2=bic2,
    )


def auto_decimation(
    n: int, period_samples: float | None, nfft: int = BICOHERENCE_NFFT, overlap: float = 0.5
) -> int:
    """Decimation factor that puts :data:`CYCLES_PER_SEGMENT` cycles in a segment.

    ``q = floor(period / (nfft / CYCLES_PER_SEGMENT))``, lowered until the decimated
    record still gives :data:`MIN_SEGMENTS` segments of ``nfft``; 1 when the period
    is unknown or already short.
    """
    if period_samples is None or not math.isfinite(period_samples):
        return 1
    q = int(period_samples // (nfft / CYCLES_PER_SEGMENT))
    while q > 1 and _segments_count(n // q, nfft, overlap) < MIN_SEGMENTS:
        q -= 1
    return max(1, q)


# ======================================================================================
# pv-op ellipse and the HOS diagnosis procedure
# ======================================================================================


def fit_ellipse(x: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """Direct least-squares ellipse fit (Fitzgibbon, Pilu & Fisher 1999).

    Numerically stable form of Halir & Flusser (1998).  Returns the conic
    coefficients ``(a, b, c, d, e, f)`` of ``a x^2 + b x y + c y^2 + d x + e y + f = 0``
    (an ellipse: ``4 a c - b^2 > 0``), or None when no ellipse fits.
    """
    d1 = np.column_stack([x * x, x * y, y * y])
    d2 = np.column_stack([x, y, np.ones_like(x)])
    s1 = d1.T @ d1
    s2 = d1.T @ d2
    s3 = d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    # Premultiply by the inverse of the constraint matrix [[0,0,2],[0,-1,0],[2,0,0]].
    m = np.array([m[2] / 2.0, -m[1], m[0] / 2.0])
    try:
        _, vecs = np.linalg.eig(m)
    except np.linalg.LinAlgError:
        return None
    vecs = np.real(vecs)
    cond = 4.0 * vecs[0] * vecs[2] - vecs[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        return None
    a1 = vecs[:, ok[0]]
    return np.concatenate([a1, t @ a1])


def _ellipse_geometry(coef: np.ndarray) -> tuple[float, float] | None:
    """(minor/major axis ratio, half chord along x through the centre) of a conic."""
    a, b, c, d, e, f = coef
    q = np.array([[a, b / 2.0], [b / 2.0, c]])
    try:
        centre = np.linalg.solve(2.0 * q, -np.array([d, e]))
    except np.linalg.LinAlgError:
        return None
    f0 = float(centre @ q @ centre + d * centre[0] + e * centre[1] + f)
    if f0 == 0.0:
        return None
    m = q / -f0
    lam = np.linalg.eigvalsh(m)
    if lam[0] <= 0:
        return None
    ratio = math.sqrt(lam[0] / lam[1])
    half_chord_x = 1.0 / math.sqrt(m[0, 0])
    return ratio, half_chord_x


def pv_op_ellipse(op: np.ndarray, pv: np.ndarray, dt: float, period_s: float) -> dict:
    """Ellipse fitted to the band-pass filtered pv-op plot (Choudhury et al. 2004, 2006).

    Both signals are detrended and band-pass filtered (zero-phase Butterworth, order
    2) over :data:`ELLIPSE_BAND` times the oscillation frequency, scaled to unit
    variance, and an ellipse is fitted by direct least squares.

    Returns
    -------
    dict
        ``fitted`` (bool), ``axis_ratio`` (minor/major in the scaled plane [-]),
        ``elliptic`` (``axis_ratio >= ELLIPSE_MIN_AXIS_RATIO``) and
        ``apparent_stiction`` (the width of the ellipse along op through its centre,
        Choudhury et al. 2006's apparent stiction [units of op, % of span]).
    """
    nyquist = 0.5 / dt
    f0 = 1.0 / period_s
    lo = ELLIPSE_BAND[0] * f0 / nyquist
    hi = ELLIPSE_BAND[1] * f0 / nyquist
    out = {"fitted": False, "axis_ratio": None, "elliptic": False, "apparent_stiction": None}
    if not 0.0 < lo < hi < 1.0:
        return out
    from scipy import signal as sps  # imported here: scipy.signal is slow to import

    b, a = sps.butter(2, [lo, hi], btype="band")
    padlen = min(3 * max(len(a), len(b)), op.size - 1)
    opf = sps.filtfilt(b, a, detrend_linear(op), padlen=padlen)
    pvf = sps.filtfilt(b, a, detrend_linear(pv), padlen=padlen)
    s_op, s_pv = float(opf.std()), float(pvf.std())
    if s_op <= 0 or s_pv <= 0:
        return out
    coef = fit_ellipse(opf / s_op, pvf / s_pv)
    geom = None if coef is None else _ellipse_geometry(coef)
    if geom is None:
        return out
    ratio, half_chord = geom
    return {
        "fitted": True,
        "axis_ratio": _plain(ratio),
        "elliptic": bool(ratio >= ELLIPSE_MIN_AXIS_RATIO),
        "apparent_stiction": _plain(2.0 * half_chord * s_op),
    }


def choudhury_hos_diagnosis(
    op: np.ndarray,
    pv: np.ndarray,
    sp: np.ndarray | None = None,
    dt: float = 1.0,
    *,
    nfft: int = BICOHERENCE_NFFT,
    correction: Literal["bonferroni", "none"] = "bonferroni",
) -> dict:
    """Choudhury, Shah & Thornhill (2004)'s higher-order-statistics stiction diagnosis.

    Procedure:

    1. Take the control error ``sp - pv`` (pv when no setpoint is given).
    2. Detect its oscillation (:func:`detect_oscillation`) and decimate so that a
       segment holds :data:`CYCLES_PER_SEGMENT` cycles (:func:`auto_decimation`).
    3. Bicoherence test (:func:`bicoherence_indices`).  Gaussian, or non-Gaussian but
       linear: the loop's poor performance is not caused by a nonlinearity
       ("no_stiction": tuning or disturbances).  A Gaussian finding from a record so
       short that the critical squared bicoherence exceeds :data:`HOS_MAX_THRESHOLD`
       is "inconclusive" instead: the test had no power.
    4. Nonlinear: fit an ellipse to the band-pass filtered pv-op plot
       (:func:`pv_op_ellipse`).  An open ellipse gives "stiction", with Choudhury et
       al. (2006)'s apparent stiction (width of the ellipse along op); a collapsed
       one, or no oscillation to filter around, gives "inconclusive" (a nonlinearity
       other than the valve's is possible).

    Parameters
    ----------
    op : ndarray
        Controller output [% of span].
    pv : ndarray
        Process output [pv units].
    sp : ndarray, optional
        Setpoint [pv units].
    dt : float
        Sample time [s].
    nfft : int
        FFT length of the bicoherence estimate [samples].
    correction : {"bonferroni", "none"}
        See :func:`bicoherence_indices`.

    Returns
    -------
    dict
        JSON-able: ``verdict``, ``signal`` ("control_error" or "pv"), ``nonlinear``,
        ``bicoherence`` (:meth:`BicoherenceResult.to_dict`), ``oscillation``
        (:meth:`Oscillation.to_dict`), ``ellipse`` (see :func:`pv_op_ellipse`, None when
        not reached) and ``reasons``.
    """
    dt = _check_dt(dt)
    op = _signal(op, "op")
    pv = _signal(pv, "pv")
    if op.size != pv.size:
        raise DataError(f"op and pv must have the same length, got {op.size} and {pv.size}")
    if sp is not None:
        sp_ = np.asarray(sp, dtype=float)
        if sp_.shape != pv.shape:
            raise DataError(f"sp must have the same length as pv, got {sp_.size} and {pv.size}")
        if not np.all(np.isfinite(sp_)):
            raise DataError("sp contains NaN or infinite values; fill or drop them first")
        x = sp_ - pv
        name = "control_error"
        if np.ptp(x) == 0:
            raise DataError("the control error sp - pv is constant; nothing to test")
    else:
        x = pv
        name = "pv"
    osc = detect_oscillation(x, dt)
    period_samples = osc.period_s / dt if osc.present and osc.period_s else None
    q = auto_decimation(x.size, period_samples, nfft)
    bic = bicoherence_indices(x, dt=dt, nfft=nfft, decimation=q, correction=correction)
    reasons: list[str] = []
    ellipse = None
    if not bic.non_gaussian and bic.threshold > HOS_MAX_THRESHOLD:
        verdict: VerdictLabel = "inconclusive"
        reasons.append(
            f"{name} shows no significant bicoherence, but with {bic.n_segments} segments "
            f"only values above {bic.threshold:.2f} would be significant: record too "
            f"short for the test"
        )
    elif not bic.non_gaussian:
        verdict = "no_stiction"
        reasons.append(
            f"{name} is Gaussian (NGI {bic.ngi:.4f} <= {NGI_THRESHOLD}): linear loop, "
            f"poor performance from tuning or disturbances"
        )
    elif not bic.nonlinear:
        verdict = "no_stiction"
        reasons.append(f"{name} is non-Gaussian but linear (NLI {bic.nli:.4f} <= {NLI_THRESHOLD})")
    else:
        reasons.append(
            f"{name} is nonlinear (NGI {bic.ngi:.4f} > {NGI_THRESHOLD}, "
            f"NLI {bic.nli:.4f} > {NLI_THRESHOLD})"
        )
        if not osc.present or osc.period_s is None:
            verdict = "inconclusive"
            reasons.append("no regular oscillation to filter the pv-op plot around")
        else:
            ellipse = pv_op_ellipse(op, pv, dt, osc.period_s)
            if ellipse["elliptic"]:
                verdict = "stiction"
                reasons.append(
                    f"pv-op plot is elliptic (axis ratio {ellipse['axis_ratio']:.2f}): "
                    f"stiction, apparent size {ellipse['apparent_stiction']:.3g} % of op"
                )
            else:
                verdict = "inconclusive"
                ratio = ellipse["axis_ratio"]
                shape = "no ellipse fits" if ratio is None else f"axis ratio {ratio:.2f}"
                reasons.append(
                    f"pv-op plot is not an open ellipse ({shape}): a nonlinearity other "
                    f"than valve stiction is possible"
                )
    return {
        "verdict": verdict,
        "signal": name,
        "nonlinear": bool(bic.nonlinear),
        "bicoherence": bic.to_dict(),
        "oscillation": osc.to_dict(),
        "ellipse": ellipse,
        "reasons": reasons,
    }
