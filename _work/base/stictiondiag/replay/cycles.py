"""The average shape of a cycle, and how alike two signals' cycles are.

The replay is compared with the data cycle by cycle
(:mod:`stictiondiag.replay.closed_loop`, "waveform agreement") and the closed-loop
refit matches the recorded cycle's shape (:mod:`stictiondiag.replay.refit`): both
read the cycles with these functions.  Cycles are cut at upward zero crossings with
hysteresis (a Schmitt trigger), each is resampled to :data:`CYCLE_BINS` points of
phase, and the average shape is their mean.  Cost O(n + n_bins n_cycles) time.
"""

from __future__ import annotations

import numpy as np

from stictiondiag.core.jit import jit

#: Points of phase per cycle in the average cycle shape.
CYCLE_BINS = 256
#: Hysteresis of the cycle cutter, as a fraction of the signal's standard deviation.
CYCLE_HYSTERESIS = 0.25
#: Cycles shorter or longer than this factor of the median cycle are left out.
CYCLE_LENGTH_FACTOR = 1.6
#: Cycles interpolated together by :func:`cycle_shape` (bounds its memory).
CYCLE_BLOCK = 64


@jit
def _up_crossings(x, h):
    """Indices where ``x`` rises through 0 after having been below ``-h`` and
    before reaching ``+h`` (hysteresis against noise); fractional by interpolation."""
    n = x.shape[0]
    out = np.empty(n)
    m = 0
    armed = False
    last_zero = -1.0
    for k in range(1, n):
        if x[k] < -h:
            armed = True
            last_zero = -1.0
        if armed and x[k - 1] < 0.0 <= x[k]:
            last_zero = (k - 1) + (-x[k - 1]) / (x[k] - x[k - 1])
        if armed and x[k] > h and last_zero >= 0.0:
            out[m] = last_zero
            m += 1
            armed = False
            last_zero = -1.0
    return out[:m]


def cycle_shape(x: np.ndarray, n_bins: int = CYCLE_BINS) -> np.ndarray | None:
    """Average cycle of an oscillating signal on a normalised phase axis [-].

    The signal is linearly detrended, cut at its upward mean crossings (hysteresis
    :data:`CYCLE_HYSTERESIS` standard deviations), every cycle resampled to
    ``n_bins`` phase points, cycles of unusual length (beyond
    :data:`CYCLE_LENGTH_FACTOR` of the median) dropped, the rest averaged.  Returns
    the average cycle scaled to zero mean and unit norm, or None with fewer than two
    cycles.

    Cost O(n + n_bins n_cycles) time, O(n + n_bins) memory besides the signal: each
    block of :data:`CYCLE_BLOCK` cycles is interpolated on its own slice of the
    record (interpolating every cycle against the whole record cost O(n) per cycle,
    quadratic in the record), and the cycles are summed as they come.
    """
    x = np.asarray(x, dtype=float)
    if x.size < 4 * n_bins // 8 or not np.all(np.isfinite(x)):
        return None
    k = np.arange(x.size)
    xd = x - np.polyval(np.polyfit(k, x, 1), k)
    sd = float(xd.std())
    if sd == 0.0:
        return None
    ups = _up_crossings(xd, CYCLE_HYSTERESIS * sd)
    if ups.size < 3:
        return None
    lengths = np.diff(ups)
    med = float(np.median(lengths))
    keep = (lengths <= CYCLE_LENGTH_FACTOR * med) & (lengths >= med / CYCLE_LENGTH_FACTOR)
    if keep.sum() < 2:
        return None
    phase = np.arange(n_bins) / n_bins
    kept = np.flatnonzero(keep)
    total = np.zeros(n_bins)
    for b in range(0, kept.size, CYCLE_BLOCK):
        i = kept[b : b + CYCLE_BLOCK]
        t = ups[i, None] + lengths[i, None] * phase  # within [ups[i], ups[i + 1])
        lo = int(t[0, 0])
        hi = min(x.size, int(t[-1, -1]) + 2)  # the samples either side of every t
        cycles = np.interp(t, k[lo:hi], xd[lo:hi])
        for row in cycles:  # in order: the sum np.mean(cycles, axis=0) forms
            total += row
    shape = total / kept.size
    shape = shape - shape.mean()
    norm = float(np.linalg.norm(shape))
    if norm == 0.0:
        return None
    return shape / norm


def waveform_similarity(data: np.ndarray, model: np.ndarray) -> float | None:
    """Phase-insensitive waveform similarity of two oscillating signals [-].

    Correlation of their average cycle shapes (:func:`cycle_shape`) at the best
    circular shift, in [-1, 1]; None when either has fewer than two cycles.
    """
    a = cycle_shape(data)
    b = cycle_shape(model)
    if a is None or b is None:
        return None
    corr = np.fft.irfft(np.fft.rfft(a) * np.conj(np.fft.rfft(b)), a.size)
    return float(np.clip(corr.max(), -1.0, 1.0))
