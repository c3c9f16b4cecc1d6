"""Small statistics: the Mann-Whitney U test of :mod:`scipy.stats` without importing
:mod:`scipy.stats`, and the bootstrap interval of a median.

Importing :mod:`scipy.stats` takes about a second, more than the rest of a
``stiction analyze`` run imports; the gap diagnosis needs one rank test from it.
:func:`mannwhitneyu` repeats scipy's computation (scipy 1.17,
``scipy/stats/_mannwhitneyu.py``, BSD licence) step by step for 1-D samples, so the
p-values are the same numbers; ``tests/test_filters.py`` checks that against scipy.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.special import binom, ndtr


class MannWhitneyResult(NamedTuple):
    statistic: float
    pvalue: float


def _rank_average(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Average ranks (1-based) and tie counts, as ``scipy.stats._stats_py._rankdata``."""
    n = xy.size
    j = np.argsort(xy, kind="stable")
    y = xy[j]
    first = np.concatenate(([True], y[:-1] != y[1:]))
    indices = np.arange(n)[first]
    counts = np.diff(indices, append=np.asarray([n], dtype=indices.dtype))
    ranks = np.arange(1, n + 1, dtype=float)[first] + (counts.astype(float) - 1) / 2
    ranks_sorted = np.repeat(ranks, counts)
    out = np.empty(n)
    np.put_along_axis(out, j, ranks_sorted, axis=-1)
    t = np.zeros(n)
    t[first] = counts
    return out, t


def _exact_sf(u: int, n1: int, n2: int) -> float:
    """P(U >= u) of the null distribution of U, for ``u >= n1 n2 / 2`` (scipy's
    ``_MWU.sf`` via the frequency recursion, which it then reads off the lower tail)."""
    n1, n2 = min(n1, n2), max(n1, n2)
    k = n1 * n2 - u  # complement, <= u
    # build_sigma_array(k)
    s_array = np.zeros(k + 1, dtype=int)
    for d in np.arange(1, n1 + 1):
        s_array[np.arange(d, k + 1, d)] += d
    for d in np.arange(n2 + 1, n2 + n1 + 1):
        s_array[np.arange(d, k + 1, d)] -= d
    s_array = s_array[1:]
    # build_u_freqs_array(k)
    total = binom(n1 + n2, n1)
    configurations = np.zeros(k + 1, dtype=np.uint64)
    configurations_is_uint = True
    uint_max = np.iinfo(np.uint64).max
    configurations[0] = 1
    for v in np.arange(1, k + 1):
        coeffs = s_array[v - 1 :: -1]
        new_val = np.dot(configurations[:v], coeffs) / v
        if new_val > uint_max and configurations_is_uint:
            configurations = configurations.astype(float)
            configurations_is_uint = False
        configurations[v] = new_val
    pmfs = configurations / total
    return np.cumsum(pmfs)[k]


def mannwhitneyu(x, y, alternative: str = "two-sided") -> MannWhitneyResult:
    """``scipy.stats.mannwhitneyu(x, y, alternative="two-sided")`` for 1-D samples
    (default ``use_continuity=True``, ``method="auto"``: the exact distribution when
    one sample has at most 8 values and there are no ties, else the normal
    approximation with tie correction).  NaN in either sample gives NaN results."""
    if alternative != "two-sided":
        raise ValueError("only the two-sided test is implemented")
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.size == 0 or y.size == 0:
        raise ValueError("`x` and `y` must be of nonzero size.")
    if np.isnan(x).any() or np.isnan(y).any():
        return MannWhitneyResult(np.float64(np.nan), np.float64(np.nan))
    n1, n2 = x.size, y.size
    ranks, t = _rank_average(np.concatenate((x, y)))
    r1 = np.sum(ranks[:n1])
    u1 = r1 - n1 * (n1 + 1) / 2
    u2 = n1 * n2 - u1
    u = np.maximum(u1, u2)
    if n1 > 8 and n2 > 8 or np.any(t > 1):
        mu = n1 * n2 / 2
        n = n1 + n2
        tie_term = np.sum(t**3 - t, axis=-1)
        s = np.sqrt(n1 * n2 / 12 * ((n + 1) - tie_term / (n * (n - 1))))
        numerator = u - mu
        numerator -= 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            z = numerator / s
        p = ndtr(-z)
    else:
        p = np.asarray(_exact_sf(int(np.int64(u)), n1, n2), dtype=float)
    p = p * 2
    p = np.clip(p, 0.0, 1.0)
    return MannWhitneyResult(np.float64(u1), np.float64(p))


#: The bootstrap of :func:`bootstrap_median_ci` draws its resamples in chunks of
#: about this many values (half a MiB of float64: the chunk stays in the core's cache).
BOOTSTRAP_CHUNK_VALUES = 1 << 16


def bootstrap_median_ci(
    x: np.ndarray, seed: int = 0, n_boot: int = 2000, min_count: int = 3
) -> tuple[float, float] | None:
    """95 % bootstrap interval of the median of ``x`` (percentile method, fixed seed);
    None for fewer than ``min_count`` values.

    Cost O(n_boot m) time for ``m`` values (one selection per resample) and
    O(:data:`BOOTSTRAP_CHUNK_VALUES` + n_boot + m) memory: the resamples are drawn
    chunk by chunk from the one generator, which gives the same draws as drawing
    them all at once (the generator's stream is consumed in the same order), so the
    interval is the same to the bit; the ``n_boot x m`` index array of one draw
    left the cache at long records and made the step grow faster than the record.
    """
    x = np.asarray(x, dtype=float)
    m = x.size
    if m < min_count:
        return None
    rng = np.random.default_rng(seed)
    rows = max(1, BOOTSTRAP_CHUNK_VALUES // m)
    med = np.empty(n_boot)
    for start in range(0, n_boot, rows):
        stop = min(start + rows, n_boot)
        idx = rng.integers(0, m, size=(stop - start, m))
        med[start:stop] = np.median(x[idx], axis=1)
    lo, hi = np.percentile(med, [2.5, 97.5])
    return float(lo), float(hi)
