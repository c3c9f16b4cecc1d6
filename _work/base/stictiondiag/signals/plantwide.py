"""Plant-wide oscillations: the loops of one plant that share a cycle.

One sticky valve rarely oscillates alone: its cycle travels downstream and every
loop it reaches oscillates at the same period (Thornhill & Horch 2007, "Advances
and new directions in plant-wide disturbance detection and diagnosis", Control
Engineering Practice 15, 1196-1206).  This module finds those groups in loops
recorded on one time grid and measures, per member, what the source ranking
(:mod:`stictiondiag.stiction.plantwide`) needs: the share of the group's power,
the harmonic content and the time lag of the cycle.

Method: common spectral peaks (:func:`plant_oscillations`, ``method="spectral"``)
-------------------------------------------------------------------------------
The spectral route of Thornhill, Shah, Huang & Vishnubhotla (2002), "Spectral
principal component analysis of dynamic process data", Control Engineering
Practice 10, 833-846: each loop's power spectrum (Welch, :func:`loop_spectra`),
detrended and normalised to unit power over the band analysed, so that loops of
any units and size weigh alike.  Where spectral PCA reads clusters off the
principal components of the normalised spectra, this implementation reads them
off the spectra directly, which gives the same clusters for the question asked
here (which loops share a spectral peak) without choosing a number of components:

1. every loop's significant peaks: a local maximum whose band (``f / (1 + w)`` to
   ``f (1 + w)``, :data:`BAND_WIDTH`) holds at least :data:`MIN_SHARE` of the
   loop's power and stands :data:`MIN_PROMINENCE` times above the median
   density of the octaves around it;
2. peaks of different loops within :data:`PEAK_TOLERANCE` of each other in
   frequency are one oscillation (strongest first); an oscillation with at least
   two loops is a group;
3. a group whose frequency is a harmonic (2 to 7 times) of a stronger group's,
   with at least half its loops among that group's members, is that group's
   harmonic and is dropped;
4. every loop is then tested at each group's frequency (the same share and
   prominence, and its largest density in the band within
   :data:`PEAK_TOLERANCE` of the frequency), so a member whose peak lost the
   clustering to a larger peak of its own still joins.

Step 2 alone would also group loops that merely cycle at similar periods (two
loops tuned tight, two slow wanders); the members kept are those whose cycle is
coherent with the group's strongest member's (:func:`_coherent`): loops reached
by one source are phase-locked to it.

Why this method and not the regularity-and-period clustering of Thornhill, Huang
& Zhang (2003) (``method="acf"``, kept for the comparison): measured on the 20
simulated plants of :mod:`stictiondiag.models.synthetic_plant` the method was
developed on (seeds 0-19, 233 loops; ``python
benchmarks/bench_plantwide_methods.py``), the spectral peaks put 231 loops (99.1 %)
in the right group, the autocorrelation periods 224 (96.1 %).  The
autocorrelation gives one period per loop, so a loop whose own tight tuning or a
second cycle dominates its ACF drops out of the group, and two loops whose
noisy-resonance periods the ACF measures alike join; a spectrum holds all the
peaks of a loop at once, and the coherence test tells a common cause from a
common period.

Costs: one FFT per loop and segment, O(n log n) per loop; grouping sorts the
peaks, O(P log P) for P peaks; testing every loop at every group's frequency is
O(loops x groups).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.core.filters import detrend_linear
from stictiondiag.signals.oscillation import detect_oscillation

__all__ = [
    "BAND_WIDTH",
    "LoopSpectra",
    "OscillationGroup",
    "PlantOscillations",
    "band_power",
    "cycle_lag",
    "harmonic_ratio",
    "loop_spectra",
    "plant_oscillations",
]

#: Half width of a peak's band, relative to its frequency [-]: ``f/(1+w)`` to ``f(1+w)``.
BAND_WIDTH = 0.10
#: Share of a loop's power in a peak's band for the peak to count [-].
MIN_SHARE = 0.10
#: Ratio of the band's mean density to the median density of the octaves around it [-].
MIN_PROMINENCE = 4.0
#: Peaks of two loops this close in frequency (relative) are one oscillation [-].
PEAK_TOLERANCE = 0.08
#: Segment length of the coherence test, in periods of the oscillation.
COHERENCE_PERIODS = 8.0
#: Magnitude-squared coherence with the group's strongest member for a loop to stay [-].
MIN_COHERENCE = 0.5
#: Fewest cycles a segment of the Welch estimate must hold for a peak to count.
MIN_SEGMENT_CYCLES = 3.0
#: Shortest period considered [samples]; shorter cycles are noise at this sampling.
MIN_PERIOD_SAMPLES = 3.0
#: Harmonics (multiples of a group's frequency) that do not make a group of their own.
HARMONICS = range(2, 8)
#: Shortest record [samples].
MIN_SAMPLES = 128
#: Methods of :func:`plant_oscillations`.
METHODS = ("spectral", "acf")


@dataclass(frozen=True)
class LoopSpectra:
    """Normalised power spectra of a plant's loops on one frequency grid.

    Attributes
    ----------
    loops : tuple of str
        Loop names, in the order of the rows.
    freq_hz : ndarray
        Frequencies of the band analysed [Hz].
    power : ndarray
        (loops, frequencies) power spectral density, each row normalised to sum 1
        over ``freq_hz`` [1/bin].
    dt : float
        Sample time [s].
    n_samples : int
        Record length [samples].
    signals : ndarray
        (loops, samples) detrended signals the spectra come from.
    """

    loops: tuple[str, ...]
    freq_hz: np.ndarray = field(repr=False)
    power: np.ndarray = field(repr=False)
    dt: float
    n_samples: int
    signals: np.ndarray = field(repr=False)

    def row(self, loop: str) -> np.ndarray:
        """One loop's normalised spectrum."""
        return self.power[self.loops.index(loop)]


@dataclass(frozen=True)
class OscillationGroup:
    """Loops that share one oscillation.

    Attributes
    ----------
    group : int
        Group number (1 for the group with the most power, then down).
    period_s : float
        Period of the common oscillation [s] (power-weighted over the members).
    members : tuple of str
        Member loops, largest share first.
    shares : tuple of float
        Each member's share of the group's power [-] (sums to 1): its power in
        the band, every loop normalised to unit power.
    power_fractions : tuple of float
        Fraction of each member's own power in the band [-].
    freq_hz : ndarray
        Frequency grid of ``spectra`` [Hz] (for the group's plot; not in to_dict).
    spectra : ndarray
        Members' normalised spectra, rows in the order of ``members`` (for the plot).
    """

    group: int
    period_s: float
    members: tuple[str, ...]
    shares: tuple[float, ...]
    power_fractions: tuple[float, ...]
    freq_hz: np.ndarray = field(repr=False, compare=False)
    spectra: np.ndarray = field(repr=False, compare=False)

    @property
    def frequency_hz(self) -> float:
        """Frequency of the oscillation [Hz]."""
        return 1.0 / self.period_s

    def to_dict(self) -> dict:
        """JSON-able dict (the spectra left out)."""
        return {
            "group": int(self.group),
            "period_s": float(self.period_s),
            "members": list(self.members),
            "shares": [float(v) for v in self.shares],
            "power_fractions": [float(v) for v in self.power_fractions],
        }


@dataclass(frozen=True)
class PlantOscillations:
    """Result of :func:`plant_oscillations`.

    Attributes
    ----------
    groups : tuple of OscillationGroup
        Oscillations shared by two loops or more, strongest first.
    loops : tuple of str
        Loops analysed.
    method : str
        ``"spectral"`` or ``"acf"``.
    dt : float
        Sample time [s].
    n_samples : int
        Common record length [samples].
    """

    groups: tuple[OscillationGroup, ...]
    loops: tuple[str, ...]
    method: str
    dt: float
    n_samples: int

    def groups_of(self, loop: str) -> list[OscillationGroup]:
        """The groups ``loop`` belongs to."""
        return [g for g in self.groups if loop in g.members]

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "dt_s": float(self.dt),
            "n_samples": int(self.n_samples),
            "loops": list(self.loops),
            "groups": [g.to_dict() for g in self.groups],
        }


def _prepare(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float).ravel()
    ok = np.isfinite(x)
    if not ok.all():
        if ok.sum() < 2:
            return np.zeros(x.size)
        k = np.arange(x.size)
        x = x.copy()
        x[~ok] = np.interp(k[~ok], k[ok], x[ok])
    return detrend_linear(x)


def _check(signals: Mapping[str, np.ndarray], dt: float) -> tuple[list[str], int, float]:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"sample time must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt) and dt > 0):
        raise UsageError(f"sample time must be a positive number of seconds, got {dt}")
    names = [str(k) for k in signals]
    sizes = {np.asarray(v).size for v in signals.values()}
    if len(sizes) > 1:
        raise DataError(
            f"the loops' records differ in length ({min(sizes)} to {max(sizes)} samples); "
            "plant-wide grouping needs one time grid"
        )
    n = sizes.pop() if sizes else 0
    if names and n < MIN_SAMPLES:
        raise DataError(f"{n} samples per loop; plant-wide grouping needs {MIN_SAMPLES}")
    return names, n, dt


def loop_spectra(signals: Mapping[str, np.ndarray], dt: float) -> LoopSpectra:
    """Welch power spectra of time-aligned loops, each normalised to unit power.

    Segments of half the record with half overlap (three segments, Hann taper),
    each linearly detrended; the band analysed runs from the frequency whose
    period fits :data:`MIN_SEGMENT_CYCLES` times in a segment up to a period of
    :data:`MIN_PERIOD_SAMPLES` samples, so drift and the loop's set-point moves
    below it do not enter the normalisation.  O(n log n) per loop.

    Parameters
    ----------
    signals : mapping of str to ndarray
        Loop -> signal (pv or control error) [any units], one grid for all.
    dt : float
        Sample time [s].
    """
    names, n, dt = _check(signals, dt)
    seg = max(MIN_SAMPLES // 2, n // 2)
    step = max(1, seg // 2)
    starts = range(0, n - seg + 1, step)
    taper = np.hanning(seg)
    freq = np.fft.rfftfreq(seg, dt)
    lo = int(math.ceil(MIN_SEGMENT_CYCLES))
    hi = int(math.floor(seg / MIN_PERIOD_SAMPLES))
    keep = slice(lo, hi + 1)
    power = np.zeros((len(names), hi + 1 - lo))
    prepared = np.zeros((len(names), n))
    for i, name in enumerate(names):
        x = prepared[i] = _prepare(signals[name])
        acc = np.zeros(freq.size)
        for s in starts:
            acc += np.abs(np.fft.rfft(detrend_linear(x[s : s + seg]) * taper)) ** 2
        band = acc[keep]
        total = float(band.sum())
        power[i] = band / total if total > 0 else 0.0
    return LoopSpectra(tuple(names), freq[keep], power, dt, n, prepared)


def band_power(power: np.ndarray, freq_hz: np.ndarray, f0: float, width: float = BAND_WIDTH):
    """Power in the band ``f0/(1+width)`` to ``f0 (1+width)`` (at least the nearest bin).

    ``power`` may be one spectrum or a (loops, frequencies) array; returns a float
    or one value per row.
    """
    sel = (freq_hz >= f0 / (1 + width)) & (freq_hz <= f0 * (1 + width))
    if not sel.any():
        sel = np.zeros(freq_hz.size, bool)
        sel[int(np.argmin(np.abs(freq_hz - f0)))] = True
    return power[..., sel].sum(axis=-1)


def _prominence(power: np.ndarray, freq_hz: np.ndarray, f0: float) -> np.ndarray:
    """Mean density in the band over the median density of ``f0/3 .. 3 f0`` outside it."""
    band = (freq_hz >= f0 / (1 + BAND_WIDTH)) & (freq_hz <= f0 * (1 + BAND_WIDTH))
    around = (freq_hz >= f0 / 3.0) & (freq_hz <= f0 * 3.0) & ~band
    if not band.any() or around.sum() < 3:
        return np.zeros(power.shape[:-1])
    inside = power[..., band].mean(axis=-1)
    floor = np.median(power[..., around], axis=-1)
    return inside / np.maximum(floor, 1e-300)


def _peaks(spec: LoopSpectra) -> list[tuple[float, int, float]]:
    """(share, loop index, frequency [Hz]) of every significant peak of every loop."""
    out = []
    f = spec.freq_hz
    for i, p in enumerate(spec.power):
        local = np.flatnonzero((p[1:-1] >= p[:-2]) & (p[1:-1] > p[2:])) + 1
        for k in local:
            band = (f >= f[k] / (1 + BAND_WIDTH)) & (f <= f[k] * (1 + BAND_WIDTH))
            if p[k] < p[band].max():
                continue  # a ripple on the flank of a larger peak
            share = float(band_power(p, f, f[k]))
            if share >= MIN_SHARE and float(_prominence(p, f, f[k])) >= MIN_PROMINENCE:
                out.append((share, i, float(f[k])))
    return out


def _cluster(peaks: list[tuple[float, int, float]]) -> list[dict]:
    """Peaks of different loops within :data:`PEAK_TOLERANCE` in frequency, strongest first."""
    clusters: list[dict] = []
    for share, i, f in sorted(peaks, reverse=True):
        for c in clusters:
            if abs(math.log(f / c["f"])) <= math.log1p(PEAK_TOLERANCE) and i not in c["loops"]:
                c["loops"].add(i)
                c["power"] += share
                break
        else:
            clusters.append({"f": f, "loops": {i}, "power": share})
    return [c for c in clusters if len(c["loops"]) >= 2]


def _is_harmonic(c: dict, stronger: list[dict]) -> bool:
    """``c`` lies at 2 to 7 times a stronger group's frequency, among that group's loops."""
    for s in stronger:
        ratio = c["f"] / s["f"]
        k = round(ratio)
        inside = len(c["loops"] & s["members"]) >= 0.5 * len(c["loops"])
        if k in HARMONICS and abs(ratio / k - 1) <= PEAK_TOLERANCE and inside:
            return True
    return False


def _member_test(spec: LoopSpectra, f0: float) -> np.ndarray:
    """Loops with a significant peak of their own within :data:`PEAK_TOLERANCE` of ``f0``.

    The peak is the largest density in the band around ``f0``; it must stand
    within the tolerance (not on the band's edge, the flank of a neighbouring
    peak), and the band must hold :data:`MIN_SHARE` of the loop's power with
    :data:`MIN_PROMINENCE`.
    """
    f = spec.freq_hz
    band = np.flatnonzero((f >= f0 / (1 + BAND_WIDTH)) & (f <= f0 * (1 + BAND_WIDTH)))
    if band.size == 0:
        return np.zeros(len(spec.loops), bool)
    top = f[band[np.argmax(spec.power[:, band], axis=1)]]
    centred = np.abs(np.log(top / f0)) <= math.log1p(PEAK_TOLERANCE)
    share = np.asarray(band_power(spec.power, f, f0))
    prom = _prominence(spec.power, f, f0)
    return centred & (share >= MIN_SHARE) & (prom >= MIN_PROMINENCE)


def _make_group(spec: LoopSpectra, f0: float, members: np.ndarray) -> OscillationGroup:
    idx = np.flatnonzero(members)
    band = (spec.freq_hz >= f0 / (1 + BAND_WIDTH)) & (spec.freq_hz <= f0 * (1 + BAND_WIDTH))
    p = spec.power[idx][:, band]
    f_centre = float((p.sum(axis=0) * spec.freq_hz[band]).sum() / max(p.sum(), 1e-300))
    fractions = p.sum(axis=1)
    order = np.argsort(-fractions, kind="mergesort")
    total = float(fractions.sum()) or 1.0
    return OscillationGroup(
        group=0,
        period_s=1.0 / f_centre,
        members=tuple(spec.loops[idx[k]] for k in order),
        shares=tuple(float(fractions[k] / total) for k in order),
        power_fractions=tuple(float(fractions[k]) for k in order),
        freq_hz=spec.freq_hz,
        spectra=spec.power[idx[order]],
    )


def _spectral_groups(spec: LoopSpectra) -> list[OscillationGroup]:
    kept: list[dict] = []
    groups = []
    for c in _cluster(_peaks(spec)):
        if _is_harmonic(c, kept):
            continue
        members = _member_test(spec, c["f"])
        members[list(c["loops"])] = True
        members &= _coherent(spec, c["f"], members)
        key = frozenset(int(i) for i in np.flatnonzero(members))
        if len(key) < 2 or any(key == k["members"] and _near(c["f"], k["f"]) for k in kept):
            continue
        kept.append({**c, "members": key})
        groups.append(_make_group(spec, c["f"], members))
    return groups


def _coherent(spec: LoopSpectra, f0: float, members: np.ndarray) -> np.ndarray:
    """Members whose cycle is coherent with the strongest member's (it is kept).

    Loops that share a cycle from one source are phase-locked; two loops that
    merely cycle at similar periods (two tight loops of their own, a slow wander)
    are not.  The magnitude-squared coherence at ``f0``, from cross spectra summed
    over the band of :data:`BAND_WIDTH` and averaged over segments of
    :data:`COHERENCE_PERIODS` periods (half overlap, Hann taper), must reach
    :data:`MIN_COHERENCE`.  One reference per group, so the cost is linear in
    the members.
    """
    idx = np.flatnonzero(members)
    if idx.size < 2:
        return members
    share = np.asarray(band_power(spec.power[idx], spec.freq_hz, f0))
    ref = idx[int(np.argmax(share))]
    n = spec.n_samples
    period = 1.0 / (f0 * spec.dt)
    seg = int(min(max(COHERENCE_PERIODS * period, 32), n // 4))
    step = max(1, seg // 2)
    taper = np.hanning(seg)
    f = np.fft.rfftfreq(seg, spec.dt)
    sel = (f >= f0 / (1 + BAND_WIDTH)) & (f <= f0 * (1 + BAND_WIDTH))
    if not sel.any():
        sel = np.abs(f - f0) == np.min(np.abs(f - f0))
    starts = range(0, n - seg + 1, step)

    def coefficients(x: np.ndarray) -> np.ndarray:
        segs = np.stack([x[s : s + seg] for s in starts])
        segs = segs - segs.mean(axis=1, keepdims=True)
        return np.fft.rfft(segs * taper, axis=1)[:, sel]

    xr = coefficients(spec.signals[ref])
    prr = float(np.sum(np.abs(xr) ** 2))
    out = members.copy()
    for i in idx:
        if i == ref:
            continue
        xi = coefficients(spec.signals[i])
        pxy = np.sum(xi * np.conj(xr), axis=0)
        coh = float(np.sum(np.abs(pxy)) ** 2 / max(float(np.sum(np.abs(xi) ** 2)) * prr, 1e-300))
        out[i] = coh >= MIN_COHERENCE
    return out


def _near(f1: float, f2: float) -> bool:
    return abs(math.log(f1 / f2)) <= math.log1p(2 * PEAK_TOLERANCE)


def _acf_groups(signals: Mapping[str, np.ndarray], spec: LoopSpectra) -> list[OscillationGroup]:
    """Regularity-and-period clustering (Thornhill, Huang & Zhang 2003), for comparison.

    Each loop's period and regularity from the autocorrelation zero crossings
    (:func:`stictiondiag.signals.oscillation.detect_oscillation`); two oscillating
    loops share an oscillation when their periods differ by less than the sum of
    their period spreads (``std Tp = Tp / (3 r)``), at most :data:`PEAK_TOLERANCE`.
    """
    found = []
    for i, name in enumerate(spec.loops):
        osc = detect_oscillation(np.asarray(signals[name], float), spec.dt)
        if osc.present and osc.period_s and osc.regularity:
            found.append((osc.regularity, i, osc.period_s))
    clusters: list[dict] = []
    for r, i, tp in sorted(found, reverse=True):
        for c in clusters:
            tol = min(PEAK_TOLERANCE * c["tp"], c["sd"] + tp / (3 * r))
            if abs(tp - c["tp"]) <= tol:
                c["loops"].add(i)
                break
        else:
            clusters.append({"tp": tp, "sd": tp / (3 * r), "loops": {i}})
    groups = []
    for c in clusters:
        if len(c["loops"]) >= 2:
            members = np.zeros(len(spec.loops), bool)
            members[list(c["loops"])] = True
            groups.append(_make_group(spec, 1.0 / c["tp"], members))
    return groups


def plant_oscillations(
    signals: Mapping[str, np.ndarray], dt: float, *, method: str = "spectral"
) -> PlantOscillations:
    """Groups of loops that share an oscillation (see the module docstring).

    Parameters
    ----------
    signals : mapping of str to ndarray
        Loop -> pv (or control error) [any units], all on one time grid, equally long.
    dt : float
        Sample time [s].
    method : {"spectral", "acf"}
        Common spectral peaks (default, chosen by measurement) or the
        autocorrelation periods of Thornhill, Huang & Zhang (2003).

    Returns
    -------
    PlantOscillations
        Groups ordered by total power, numbered from 1.

    Raises
    ------
    UsageError
        Unknown method, bad sample time.
    DataError
        Records of different lengths, or too short.
    """
    if method not in METHODS:
        raise UsageError(f"unknown grouping method {method!r}: use one of {', '.join(METHODS)}")
    spec = loop_spectra(signals, dt)
    if not spec.loops:
        return PlantOscillations((), (), method, spec.dt, spec.n_samples)
    found = _spectral_groups(spec) if method == "spectral" else _acf_groups(signals, spec)
    found.sort(key=lambda g: -sum(g.power_fractions))
    groups = tuple(
        OscillationGroup(
            k + 1, g.period_s, g.members, g.shares, g.power_fractions, g.freq_hz, g.spectra
        )
        for k, g in enumerate(found)
    )
    return PlantOscillations(groups, spec.loops, method, spec.dt, spec.n_samples)


def harmonic_ratio(x: np.ndarray, dt: float, period_s: float, n_harmonics: int = 5) -> float:
    """Power of the harmonics 2 to ``n_harmonics`` over the power of the fundamental [-].

    A cycle is most distorted (squarest, or most triangular) in the loop whose
    nonlinearity makes it; each process between it and a downstream loop is a
    low-pass filter that strips the harmonics first (Thornhill & Horch 2007,
    Section 4.2).  From the periodogram of the detrended record (Hann taper), in
    bands of half :data:`BAND_WIDTH` around each multiple of the frequency; each
    band counts only its excess over the noise floor (the median density of the
    half octave on either side times the band's bins), so broadband noise does
    not pass for harmonics.  Harmonics above the Nyquist frequency are left out.
    """
    x = _prepare(x)
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    f = np.fft.rfftfreq(x.size, dt)
    f0 = 1.0 / period_s
    half = BAND_WIDTH / 2

    def excess(fk: float) -> float:
        band = (f >= fk / (1 + half)) & (f <= fk * (1 + half))
        if not band.any():
            return 0.0
        around = (f >= fk / 1.4) & (f <= fk * 1.4) & ~band
        floor = float(np.median(p[around])) if around.sum() >= 3 else 0.0
        return max(0.0, float(p[band].sum()) - floor * int(band.sum()))

    fundamental = excess(f0)
    if fundamental <= 0:
        return float("nan")
    nyq = 0.5 / dt
    harm = sum(excess(k * f0) for k in range(2, n_harmonics + 1) if k * f0 * 1.4 < nyq)
    return harm / fundamental


#: Highest harmonic kept by :func:`cycle_lag`'s band-pass, in multiples of the frequency.
LAG_HARMONICS = 10.0


def _band_derivative(x: np.ndarray, dt: float, f0: float) -> np.ndarray:
    """First difference of ``x`` band-passed to ``f0 / 2 .. LAG_HARMONICS f0`` (by FFT)."""
    spectrum = np.fft.rfft(_prepare(x))
    f = np.fft.rfftfreq(x.size, dt)
    spectrum[(f < f0 / 2) | (f > LAG_HARMONICS * f0)] = 0.0
    return np.diff(np.fft.irfft(spectrum, x.size))


def cycle_lag(x: np.ndarray, reference: np.ndarray, dt: float, period_s: float) -> float:
    """Time [s] by which ``x`` lags ``reference`` in their common cycle (negative: leads).

    The lag of the largest absolute cross-correlation of the two signals'
    derivatives, band-passed from half the cycle's frequency to
    :data:`LAG_HARMONICS` times it, within half a period either side.  The
    derivative stresses the cycle's sharp changes (a sticky valve's slips), which
    reach each downstream loop after the transport and lags between them
    (Thornhill & Horch 2007, Section 5: time delays and the order in which a
    disturbance reaches the measurements), and which a periodogram's phase at
    the fundamental alone does not time as well: the receiving loop's own
    controller shifts the fundamental's phase.  A loop downstream of another lags
    it; a lag beyond half a period is not told apart from a lead.  O(n log n).
    """
    a = _band_derivative(np.asarray(x, float), dt, 1.0 / period_s)
    b = _band_derivative(np.asarray(reference, float), dt, 1.0 / period_s)
    n = a.size
    nfft = 1 << (2 * n).bit_length()
    c = np.fft.irfft(np.fft.rfft(a, nfft) * np.conj(np.fft.rfft(b, nfft)), nfft)
    m = max(1, min(n - 1, int(period_s / dt / 2)))
    lags = np.concatenate([np.arange(0, m + 1), np.arange(-m, 0)])
    values = np.concatenate([c[: m + 1], c[nfft - m :]])
    return float(lags[int(np.argmax(np.abs(values)))] * dt)
