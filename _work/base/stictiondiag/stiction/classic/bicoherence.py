"""Choudhury, Shah & Thornhill (2004): bicoherence NGI/NLI, then the pv-op ellipse.

Choudhury, M. A. A. S., Shah, S. L. & Thornhill, N. F. (2004), "Diagnosis of poor
control-loop performance using higher-order statistics", Automatica 40, 1719-1728
(cited in Section 5.3 of Choudhury, Thornhill & Shah 2005); the Total Nonlinearity
Index of Choudhury, Shook & Shah (2006), "Linear or nonlinear?  A bicoherence based
metric of nonlinearity measure", IFAC SAFEPROCESS; the quantification of Choudhury,
Shah, Thornhill & Shook (2006), Control Engineering Practice 14, 1395-1412.

A linear loop driven by Gaussian noise gives a Gaussian control error whose squared
bicoherence is zero at every bifrequency; a valve nonlinearity couples the phases of
the harmonics of the limit cycle and raises the bicoherence at a few bifrequencies.
The test asks "non-Gaussian?" (NGI > 0.001) and then "nonlinear?" (NLI > 0.01); for a
nonlinear loop an elliptic pv-op pattern points to stiction
(:mod:`stictiondiag.stiction.classic.ellipse`).

What was verified and what was not
----------------------------------
* Verified (re-derived from the definitions, tested in
  ``tests/test_classic_horch_choudhury.py``): the estimator (direct method, Kim & Powers
  normalisation), the chi-square significance of ``2 K bic^2``, NGI, NLI, TNLI and the
  thresholds 0.001 and 0.01; a stiction limit cycle of the data-driven model through
  a nonlinear valve characteristic, and in the level loop, gives NGI > 0 and
  NLI > 0.01 (the published signs) while a linear loop with a sinusoidal disturbance
  does not.
* Not verified: the papers' segment length and overlap for short records, and the
  precise percentile of the conditioning term epsilon (Choudhury, Shah & Thornhill
  2008, Section 3, say only "a small constant"; 75 % of the denominator is this
  implementation's choice).
* Decisions of this implementation: the significance test is family-wise over the
  principal domain (Bonferroni) by default, because with the per-bifrequency test the
  NGI of Gaussian data is about ``1 / K`` (see :func:`bicoherence_indices`, Notes);
  ``correction="none"`` is the paper's.  Half-wave-symmetric limit cycles (odd
  harmonics only) have a bispectrum that is identically zero, so the test cannot see
  them whatever their shape; a property of the published test, kept.

Why the test rarely calls stiction on short plant records (measured)
--------------------------------------------------------------------
The weakness is the method's, at the record lengths of plant data, not a bug found
in this estimator.  The published thresholds (NGI > 0.001, NLI > 0.01) are fixed,
but under a Gaussian record the per-bifrequency NGI is about ``1 / K`` and the NLI
about ``ln(L) / K`` (K segments, L bifrequencies), so they only separate Gaussian
from non-Gaussian for K of the order of 1000 segments.  On simulated paper loops
(6 seeds each; 1000 samples, i.e. K = 14) the per-bifrequency test
(``correction="none"``) called every linear loop nonlinear (sinusoidal load, or
noise load: 6/6), and the family-wise tests (Bonferroni, or Benjamini-Hochberg,
which gave identical calls) called none of them, but found only 2/6 stiction cycles
through an equal-percentage valve and 0/6 of the others; at 3000 samples the
family-wise tests found 6/6 of the self-regulating stiction cycles with no false call
(the level loop's symmetric cycle stays invisible).  Decimating to the oscillation
band helped only slightly (6/6 against 4/6 for one case at 3000 samples), because it
lowers K.  On the ISDB loops with a stated stiction label (records of 200 to 4700
samples, K = 9 to 72), 11 of the 16 stop at "record too short for the test"
(critical squared bicoherence 0.53 to 1.1), one is Gaussian, one has no regular
oscillation for the ellipse, one has a collapsed ellipse and two are called stiction.
The per-bifrequency test would call 10 of 16, but since it calls noise-driven
linear loops nonlinear at the same K, those calls come from the oscillation and the
ellipse, not from the bicoherence.  The family-wise default is kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from stictiondiag.core.checks import check_dt
from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.core.filters import detrend_linear
from stictiondiag.core.serialize import plain_float
from stictiondiag.signals.oscillation import Oscillation, detect_oscillation
from stictiondiag.stiction.classic._common import (
    VerdictLabel,
    same_length,
    signal,
)
from stictiondiag.stiction.classic.ellipse import EllipseResult, pv_op_ellipse

if TYPE_CHECKING:
    import pandas as pd

Correction = Literal["bonferroni", "fdr", "none"]
CORRECTIONS = ("bonferroni", "fdr", "none")

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
#: evidence of a linear loop in :func:`choudhury_hos`.  Above it the record
#: has too few segments for the test to see anything but near-perfect phase coupling
#: (with the family-wise test about K < 20 segments), and "Gaussian" only means "too
#: short to tell".
HOS_MAX_THRESHOLD = 0.5


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
            "ngi": plain_float(self.ngi),
            "nli": plain_float(self.nli),
            "tnli": plain_float(self.tnli),
            "non_gaussian": bool(self.non_gaussian),
            "nonlinear": bool(self.nonlinear),
            "threshold": plain_float(self.threshold),
            "alpha": plain_float(self.alpha),
            "correction": self.correction,
            "n_segments": int(self.n_segments),
            "nfft": int(self.nfft),
            "decimation": int(self.decimation),
            "n_bifrequencies": int(self.n_bifrequencies),
            "n_significant": int(self.n_significant),
            "max_bicoherence": plain_float(self.max_bicoherence),
            "peak_f1_hz": plain_float(self.peak_f1_hz),
            "peak_f2_hz": plain_float(self.peak_f2_hz),
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


def _point_level(bic2: np.ndarray, k_seg: int, alpha: float, correction: str) -> float:
    """Per-bifrequency significance level for the chosen multiple-test correction.

    Under zero bicoherence ``P(bic^2 > b) = exp(-K b)`` (chi-square, 2 dof, of
    ``2 K bic^2``).  ``"fdr"`` is the step-up rule of Benjamini & Hochberg (1995): the
    largest ``j`` with ``p_(j) <= j alpha / L``; it keeps the family-wise level
    ``alpha`` when no bifrequency is coupled (a Gaussian record) and rejects more
    than Bonferroni when many are (the harmonics of a limit cycle).  With no
    rejection it falls back to the Bonferroni level.
    """
    n_bif = bic2.size
    if correction == "none":
        return alpha
    if correction == "fdr" and n_bif:
        p = np.sort(np.exp(-k_seg * bic2))
        ok = np.flatnonzero(p <= alpha * np.arange(1, n_bif + 1) / n_bif)
        if ok.size:
            return float(alpha * (ok[-1] + 1) / n_bif)
    return alpha / max(n_bif, 1)


def _segments_count(n: int, nfft: int, overlap: float) -> int:
    step = max(1, int(round(nfft * (1.0 - overlap))))
    return 0 if n < nfft else 1 + (n - nfft) // step


def _check_options(
    overlap: float,
    alpha: float,
    correction: str,
    nfft: int,
    decimation: int,
    conditioning_percentile: float | None,
) -> tuple[int, int]:
    """Check :func:`bicoherence_indices`' options; ``nfft`` and ``decimation`` as ints."""
    if not 0.0 <= overlap <= 0.9:
        raise UsageError(f"overlap must be a fraction in [0, 0.9], got {overlap}")
    if not 0.0 < alpha < 1.0:
        raise UsageError(f"alpha must be in (0, 1), got {alpha}")
    if correction not in CORRECTIONS:
        raise UsageError(f"correction must be one of {', '.join(CORRECTIONS)}, got {correction!r}")
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
    return nfft, decimation


def _segment_spectra(
    x: np.ndarray, nfft: int, overlap: float, window: str, decimation: int
) -> tuple[np.ndarray, int, int]:
    """The spectra ``X_k(f)`` of the detrended, decimated record's tapered segments.

    Returns the (K, nfft/2 + 1) spectra, the segment length used (``nfft`` halved
    while the record gives fewer than :data:`MIN_SEGMENTS` segments) and K.
    """
    from scipy import signal as sps  # imported here: scipy.signal is slow to import

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
    return np.fft.rfft(segs * taper, axis=1), nfft, k_seg


def _squared_bicoherence(
    spec: np.ndarray, nfft: int, conditioning_percentile: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``bic^2`` over the principal domain, with the bin indices ``i1 >= i2`` of each
    bifrequency (see the Notes of :func:`bicoherence_indices`)."""
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
    return np.clip(bic2, 0.0, 1.0), i1, i2  # Cauchy-Schwarz bound, guards round-off


def _gaussianity_indices(
    bic2: np.ndarray, k_seg: int, alpha: float, correction: str
) -> tuple[float, int, float, float, float]:
    """The test of zero bicoherence and the indices: threshold, number of significant
    bifrequencies, NGI, NLI and TNLI (see the Notes of :func:`bicoherence_indices`)."""
    from scipy.special import chdtri

    n_bif = int(bic2.size)
    alpha_point = _point_level(bic2, k_seg, alpha, correction)
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
    return threshold, n_sig, ngi, nli, tnli


def bicoherence_indices(
    x: np.ndarray,
    *,
    dt: float = 1.0,
    nfft: int = BICOHERENCE_NFFT,
    overlap: float = BICOHERENCE_OVERLAP,
    window: str = "hann",
    decimation: int = 1,
    alpha: float = BICOHERENCE_ALPHA,
    correction: Correction = "bonferroni",
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
    dt = check_dt(dt)
    x = signal(x, "signal")
    nfft, decimation = _check_options(
        overlap, alpha, correction, nfft, decimation, conditioning_percentile
    )
    spec, nfft, k_seg = _segment_spectra(x, nfft, overlap, window, decimation)
    bic2, i1, i2 = _squared_bicoherence(spec, nfft, conditioning_percentile)
    threshold, n_sig, ngi, nli, tnli = _gaussianity_indices(bic2, k_seg, alpha, correction)
    non_gaussian = ngi > NGI_THRESHOLD
    nonlinear = bool(non_gaussian and nli > NLI_THRESHOLD)

    df = 1.0 / (nfft * (dt * decimation))  # bin width after decimation [Hz]
    f1, f2 = i1 * df, i2 * df
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
        n_bifrequencies=int(bic2.size),
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
# The procedure: bicoherence, then the ellipse
# ======================================================================================


@dataclass(frozen=True)
class ChoudhuryResult:
    """Result of :func:`choudhury_hos`.

    Attributes
    ----------
    verdict : {"stiction", "no_stiction", "inconclusive"}
    signal : {"control_error", "pv"}
        The signal tested: ``sp - pv``, or pv when no setpoint was given.
    bicoherence : BicoherenceResult
        NGI, NLI, TNLI and the estimator's settings.
    oscillation : Oscillation
        Oscillation of the tested signal (sets the decimation and the ellipse band).
    ellipse : EllipseResult or None
        The pv-op ellipse; None when the loop was not found nonlinear.
    reasons : tuple of str
    """

    verdict: VerdictLabel
    signal: str
    bicoherence: BicoherenceResult
    oscillation: Oscillation
    ellipse: EllipseResult | None
    reasons: tuple[str, ...]

    @property
    def nonlinear(self) -> bool:
        """The bicoherence test found a nonlinear loop."""
        return bool(self.bicoherence.nonlinear)

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "verdict": self.verdict,
            "signal": self.signal,
            "nonlinear": self.nonlinear,
            "bicoherence": self.bicoherence.to_dict(),
            "oscillation": self.oscillation.to_dict(),
            "ellipse": None if self.ellipse is None else self.ellipse.to_dict(),
            "reasons": list(self.reasons),
        }


def _tested_signal(pv: np.ndarray, sp) -> tuple[np.ndarray, str]:
    if sp is None:
        return pv, "pv"
    sp_ = np.asarray(sp, dtype=float)
    if sp_.shape != pv.shape:
        raise DataError(f"sp must have the same length as pv, got {sp_.size} and {pv.size}")
    if not np.all(np.isfinite(sp_)):
        raise DataError("sp contains NaN or infinite values; fill or drop them first")
    x = sp_ - pv
    if np.ptp(x) == 0:
        raise DataError("the control error sp - pv is constant; nothing to test")
    return x, "control_error"


def _hos_decision(name: str, bic: BicoherenceResult) -> tuple[VerdictLabel | None, str]:
    """Verdict from the indices alone (None: nonlinear, go on to the ellipse)."""
    if not bic.non_gaussian and bic.threshold > HOS_MAX_THRESHOLD:
        return "inconclusive", (
            f"{name} shows no significant bicoherence, but with {bic.n_segments} segments "
            f"only values above {bic.threshold:.2f} would be significant: record too "
            f"short for the test"
        )
    if not bic.non_gaussian:
        return "no_stiction", (
            f"{name} is Gaussian (NGI {bic.ngi:.4f} <= {NGI_THRESHOLD}): linear loop, "
            f"poor performance from tuning or disturbances"
        )
    if not bic.nonlinear:
        return (
            "no_stiction",
            f"{name} is non-Gaussian but linear (NLI {bic.nli:.4f} <= {NLI_THRESHOLD})",
        )
    return None, (
        f"{name} is nonlinear (NGI {bic.ngi:.4f} > {NGI_THRESHOLD}, "
        f"NLI {bic.nli:.4f} > {NLI_THRESHOLD})"
    )


def choudhury_hos(
    op,
    pv,
    sp=None,
    dt: float = 1.0,
    *,
    nfft: int = BICOHERENCE_NFFT,
    correction: Correction = "bonferroni",
    oscillation: Oscillation | None = None,
) -> ChoudhuryResult:
    """Choudhury, Shah & Thornhill (2004)'s higher-order-statistics stiction diagnosis.

    Procedure:

    1. Take the control error ``sp - pv`` (pv when no setpoint is given).
    2. Detect its oscillation (:func:`detect_oscillation`) and decimate so that a
       segment holds :data:`CYCLES_PER_SEGMENT` cycles (:func:`auto_decimation`).
    3. Bicoherence test (:func:`bicoherence_indices`).  Gaussian, or non-Gaussian but
       linear: the loop's poor performance is not caused by a nonlinearity
       ("no_stiction").  A Gaussian finding from a record so short that the critical
       squared bicoherence exceeds :data:`HOS_MAX_THRESHOLD` is "inconclusive": the
       test had no power.
    4. Nonlinear: fit an ellipse to the band-pass filtered pv-op plot
       (:func:`pv_op_ellipse`).  An open ellipse gives "stiction", with the apparent
       stiction; a collapsed one, or no oscillation to filter around, gives
       "inconclusive" (a nonlinearity other than the valve's is possible).

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
    oscillation : Oscillation, optional
        Oscillation of the tested signal, when the caller has it already.

    Returns
    -------
    ChoudhuryResult
    """
    dt = check_dt(dt)
    op = signal(op, "op")
    pv = signal(pv, "pv")
    same_length(("op", op), ("pv", pv))
    x, name = _tested_signal(pv, sp)
    osc = detect_oscillation(x, dt) if oscillation is None else oscillation
    period_samples = osc.period_s / dt if osc.present and osc.period_s else None
    q = auto_decimation(x.size, period_samples, nfft)
    bic = bicoherence_indices(x, dt=dt, nfft=nfft, decimation=q, correction=correction)
    verdict, why = _hos_decision(name, bic)
    reasons = [why]
    ellipse = None
    if verdict is None:
        if not osc.present or osc.period_s is None:
            verdict = "inconclusive"
            reasons.append("no regular oscillation to filter the pv-op plot around")
        else:
            ellipse = pv_op_ellipse(op, pv, dt, osc.period_s)
            if ellipse.elliptic:
                verdict = "stiction"
                reasons.append(
                    f"pv-op plot is elliptic (axis ratio {ellipse.axis_ratio:.2f}): "
                    f"stiction, apparent size {ellipse.apparent_stiction:.3g} % of op"
                )
            else:
                verdict = "inconclusive"
                ratio = ellipse.axis_ratio
                shape = "no ellipse fits" if ratio is None else f"axis ratio {ratio:.2f}"
                reasons.append(
                    f"pv-op plot is not an open ellipse ({shape}): a nonlinearity other "
                    f"than valve stiction is possible"
                )
    return ChoudhuryResult(verdict, name, bic, osc, ellipse, tuple(reasons))
