"""Tests of an effect's own signature in the data, beyond a smaller replay error.

An effect of the catalogue is named only when the data show its signature: slips
that differ by direction or by time (a rank test on the slips measured one by one,
Fig. 2 of Choudhury, Thornhill & Shah 2005), or a least-squares coefficient whose
standard error comes from the scatter between blocks of the record
(:func:`signature_test`).  The effect-specific tests live with their effects.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.stats import (
    mannwhitneyu,  # scipy.stats.mannwhitneyu, without importing scipy.stats
)

#: Significance the measured slips must show for a threshold-only effect (rank test).
SLIP_TEST_P = 0.01


#: Blocks of the record whose scatter gives a signature coefficient's standard error.
SIGNATURE_BLOCKS = 12


#: Significance an effect's own signature must show (t test, one-sided in the
#: direction of the fitted effect).
SIGNATURE_P = 0.01


def signature_test(
    x: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    others: np.ndarray | None = None,
    n_blocks: int = SIGNATURE_BLOCKS,
) -> tuple[float, float]:
    """Least-squares coefficient of ``x`` in ``y`` (``others`` partialled out) and the
    two-sided p-value that it is 0: ``(beta, p)``; ``(0, 1)`` when ``x`` carries nothing
    the other columns do not.

    Replay errors are correlated in time (a whole slip or cycle at a time), so the
    standard error is not the textbook one: the products ``x~ e`` (``x~`` the column
    with ``others`` partialled out, ``e`` the fit's residual) are summed over
    ``n_blocks`` consecutive blocks of the weighted samples and the coefficient's
    variance is taken from the scatter of those block sums (batch means), with a
    Student t distribution on ``n_blocks - 1`` degrees of freedom.  A coefficient that
    only some part of the record supports has a large scatter and fails.
    """
    from scipy.special import stdtr

    sel = w > 0
    xs = np.asarray(x, dtype=float)[sel]
    ys = np.asarray(y, dtype=float)[sel]
    n_blocks = int(n_blocks)
    if xs.size < 3 * n_blocks or n_blocks < 3:
        return 0.0, 1.0
    if others is not None:
        Z = np.asarray(others, dtype=float)[sel]
        Z = Z.reshape(xs.size, -1)
        coef_x = np.linalg.lstsq(Z, xs, rcond=None)[0]
        coef_y = np.linalg.lstsq(Z, ys, rcond=None)[0]
        xs = xs - Z @ coef_x
        ys = ys - Z @ coef_y
    sxx = float(np.dot(xs, xs))
    scale = float(np.dot(np.asarray(x, dtype=float)[sel], np.asarray(x, dtype=float)[sel]))
    if sxx <= 1e-12 * max(scale, 1e-300):
        return 0.0, 1.0
    beta = float(np.dot(xs, ys)) / sxx
    z = xs * (ys - beta * xs)
    sums = np.array([b.sum() for b in np.array_split(z, n_blocks)])
    var_sum = n_blocks * float(np.sum((sums - sums.mean()) ** 2)) / (n_blocks - 1)
    if var_sum <= 0.0:
        return beta, 0.0 if beta != 0.0 else 1.0
    t = beta * sxx / math.sqrt(var_sum)
    return beta, float(2.0 * stdtr(n_blocks - 1, -abs(t)))


def block_scale(r: np.ndarray, w: np.ndarray, n_blocks: int = SIGNATURE_BLOCKS) -> np.ndarray:
    """Per-sample factor ``1 / s_b`` that weights a regression by the inverse of its
    errors' variance in each block (feasible generalised least squares): ``s_b`` is the
    RMS of ``r`` over block ``b`` of the weighted samples, the blocks of
    :func:`signature_test`'s batch means; 0 outside the weighted samples.

    A replay's errors are not equally large along the record: a block with an
    unforeseen load step or set-point change carries errors many times those of the
    quiet blocks, and an unweighted least-squares coefficient is then decided by
    those few blocks, where the error is mostly the load.  Multiplying every column
    of the regression (and its response) by this factor gives each block a say in
    proportion to how precisely it measures the coefficient.
    """
    res = np.asarray(r, dtype=float)
    out = np.zeros(res.size)
    idx = np.flatnonzero(np.asarray(w) > 0)
    if idx.size == 0:
        return out
    total = float(np.mean(res[idx] ** 2))
    for b in np.array_split(idx, max(int(n_blocks), 1)):
        if b.size:
            ms = max(float(np.mean(res[b] ** 2)), 1e-12 * total, 1e-300)
            out[b] = 1.0 / math.sqrt(ms)
    return out


def one_sided(p_two_sided: float, agrees: bool) -> float:
    """p-value of the one-sided test in the direction of the fitted effect from that of
    the two-sided test: half of it when the estimate points that way, else 1 or more
    (``1 - p/2``)."""
    return 0.5 * p_two_sided if agrees else 1.0 - 0.5 * p_two_sided


def _slip_blocks(n_rows: int) -> int:
    """Blocks for :func:`signature_test` on per-slip values: three slips or more each."""
    return min(SIGNATURE_BLOCKS, n_rows // 3)


def testable_slips(slips: dict | None):
    """Demand at breakaway, position after the slip and demand direction of the
    measured slips, with the number of blocks to test them in; None when there are
    too few slips for a test (fewer than four blocks)."""
    if slips is None or "op_break" not in slips:
        return None
    x, y, d = slips["op_break"], slips["mv_after"], slips["op_direction"]
    ok = np.isfinite(x) & np.isfinite(y)
    x, y, d = x[ok], y[ok], d[ok]
    n_blocks = _slip_blocks(x.size)
    if n_blocks < 4:
        return None
    return x, y, d, n_blocks


def untested_p(mv: np.ndarray | None) -> float:
    """p-value of a valve-side signature that too few measured slips leave untested.

    0 as a rule: the replay decides alone (its held-out gain, the penalty and the
    block count of :mod:`stictiondiag.gap.selection`).  1 on a quantised mv
    (:func:`stictiondiag.gap.effects.quantization.detect_quantization`): there the
    rounding is most of the replay's mv error and persists from one sample to the
    next, so a more flexible valve (thresholds that change during the record or by
    direction, a slope, a curve) follows it on the held-out blocks as well, and the
    segmentation, which reads the rounding's steps, measures few slips or none.  The
    effect must then be shown by the slips measured.
    """
    # Imported here: quantization imports this module, a cycle at module level.
    from stictiondiag.gap.effects.quantization import detect_quantization

    return 1.0 if detect_quantization(mv) is not None else 0.0


def slips_comparable(slips: dict, a: np.ndarray, b: np.ndarray) -> bool:
    """Whether :func:`slips_differ` can compare the slips in ``a`` and ``b``: three or
    more measured on each side, in the demand travel at reversals or in the jump."""
    for mask in (slips["reversal"], np.ones(slips["J"].size, dtype=bool)):
        if int(np.sum(a & mask)) >= 3 and int(np.sum(b & mask)) >= 3:
            return True
    return False


def slips_differ(
    slips: dict | None,
    a: np.ndarray,
    b: np.ndarray,
    untested: float = 0.0,
    expect: dict | None = None,
) -> float:
    """Smallest p-value of two-sided rank tests that the slips in ``a`` and ``b`` differ,
    in the demand travel at reversals (S) or in the jump (J); ``untested`` when there
    are too few measured slips to test (fewer than three on a side; 0: the replay
    decides alone, see :func:`untested_p`).

    Thresholds are fitted on the whole record, where a replay that is more flexible
    can fall in step with a few more slips by chance; the slips measured one by one
    (:func:`measure_slips`) must show the difference too.

    ``expect`` (``travel`` and ``J``): the sign of the difference the fitted effect
    gives, the slips in ``b`` less those in ``a``; a test whose sign is not 0 is
    one-sided in that direction (:func:`one_sided`): slips that differ the other way
    do not show the fitted effect.
    """
    if slips is None:
        return untested
    p = 1.0
    tested = False
    for key, mask in (("travel", slips["reversal"]), ("J", np.ones(slips["J"].size, dtype=bool))):
        x, y = slips[key][a & mask], slips[key][b & mask]
        if x.size >= 3 and y.size >= 3:
            tested = True
            res = mannwhitneyu(x, y, alternative="two-sided")
            p_key = float(res.pvalue)
            sign = 0.0 if expect is None else float(np.sign(expect.get(key, 0.0)))
            if sign != 0.0:
                # b's slips larger than a's when a's U statistic is below its mean.
                b_larger = float(res.statistic) < 0.5 * x.size * y.size
                p_key = one_sided(p_key, b_larger == (sign > 0.0))
            p = min(p, p_key)
    return p if tested else untested


def slip_rate_differs(times: np.ndarray, t1: float, t2: float, n: int) -> float:
    """Two-sided p-value that slips are measured at a different rate before sample
    ``t1`` than after sample ``t2`` (of ``n``): the count before, of all counted on
    both sides, against the binomial whose share is the side's share of their
    duration; 1 when a side has no duration or no slip is counted on either side.

    When stiction changes, the slips after the change may be too small or too
    frequent for the segmentation to measure one by one, so their sizes cannot be
    compared (:func:`slips_differ` needs three on a side); their number can.  A
    change placed at an end of the record leaves that side no duration and so no
    test.
    """
    from scipy.special import bdtr, bdtrc

    t = np.asarray(times, dtype=float)
    d_early, d_late = max(float(t1), 0.0), max(float(n - 1) - float(t2), 0.0)
    k, m = int(np.sum(t < t1)), int(np.sum(t > t2))
    total = k + m
    if d_early <= 0.0 or d_late <= 0.0 or total == 0:
        return 1.0
    share = d_early / (d_early + d_late)
    lower = float(bdtr(k, total, share))  # P(X <= k)
    upper = float(bdtrc(k - 1, total, share)) if k > 0 else 1.0  # P(X >= k)
    return min(1.0, 2.0 * min(lower, upper))
