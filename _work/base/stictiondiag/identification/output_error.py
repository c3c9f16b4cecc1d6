"""Filtered output-error fits of the FOPTD and the integrator (Eq. 3, Table 3).

The fits behind :func:`stictiondiag.identification.process.identify_process` (see
its module docstring): the model is simulated from the input and compared with pv
after the same first-order high-pass; gain, initial state and balance input enter
linearly and are solved by least squares; every dead time is scanned at once
(:func:`delay_scan`: normal equations from prefix sums and correlations), on a grid
of time constants for the FOPTD, followed by a scalar search of the time constant
and a walk along the dead time (:func:`fit_foptd`).  A limit cycle is (nearly)
periodic, so a dead time ``d`` and ``d + P`` (``P`` the period in samples) explain
the data about equally well; the scan takes the shortest dead time whose fit is
close to the best (:data:`DEAD_TIME_TOLERANCE`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.filters import correlate_lags, lfilter1
from stictiondiag.core.optimize import minimize_scalar_bounded
from stictiondiag.identification.numerics import MIN_SAMPLES, delayed

#: Dead-time scan: shortest delay whose cost is within this fraction of the range
#: between the best and the median cost (periodic data make d and d + P ambiguous).
DEAD_TIME_TOLERANCE = 0.02


#: ``a^k`` with ``k ln a < UNDERFLOW_LOG`` is below 2^-1080, a 64th of the smallest
#: subnormal double: it rounds to 0 [-].
UNDERFLOW_LOG = -1080.0 * math.log(2.0)


def powers(a: float, start: int, stop: int) -> np.ndarray:
    """``a ** np.arange(start, stop)``, the same numbers, for a pole ``0 <= a <= 1``.

    Powers far below the smallest subnormal are zero whatever the rounding and are
    not computed: pow's underflow path costs ten times its normal one, and the
    free responses of a fast pole (``a^k`` for a time constant of a few samples)
    underflow after a few thousand samples, so on a long record almost every
    power took that path.  O(n), about 5 ns per computed power.
    """
    k = np.arange(start, stop)
    if not 0.0 < a < 1.0:
        return a**k
    last = math.ceil(UNDERFLOW_LOG / math.log(a))  # a^k == 0 from k = last on
    m = min(max(last - start, 0), k.size)
    out = np.zeros(k.size)
    out[:m] = a ** k[:m]
    return out


def lag_response(u: np.ndarray, d: int, a: float) -> np.ndarray:
    """``z[k+1] = a z[k] + (1 - a) u[k - d]``, ``z[0] = u[0]``: first-order lag with
    dead time ``d`` samples (exact zero-order-hold discretisation of the FOPTD)."""
    x = delayed(u, d + 1)
    return lfilter1((1.0 - a,), -a, x, zi=a * u[0])


def integrating_regressors(u: np.ndarray, d: int, dt: float) -> np.ndarray:
    """Columns [1, dt sum_{j<k} u[j-d], dt k] of the simulated integrator response."""
    x = delayed(u, d + 1)
    x[0] = 0.0
    k = np.arange(u.size)
    return np.column_stack([np.ones(u.size), dt * np.cumsum(x), dt * k])


def pick_dead_time(cost: np.ndarray) -> int:
    """Shortest delay whose cost is close to the best (see module docstring)."""
    best = float(cost.min())
    spread = float(np.median(cost)) - best
    ok = np.flatnonzero(cost <= best + DEAD_TIME_TOLERANCE * max(spread, 0.0))
    d = int(ok[0])
    # Walk down into the local minimum of the run that starts at d.
    while d + 1 < cost.size and cost[d + 1] < cost[d]:
        d += 1
    return d


def highpass(x: np.ndarray, b: float) -> np.ndarray:
    """First-order high-pass ``y[k] = b (y[k-1] + x[k] - x[k-1])`` with pole ``b``,
    started at rest at ``x[0]`` (``y[0] = 0``); ``b = 1`` only removes ``x[0]``."""
    x = np.asarray(x, dtype=float) - x[0]
    if b >= 1.0:
        return x
    return lfilter1((b, -b), -b, x)


def solve_normal(A: np.ndarray, g: np.ndarray, yy: np.ndarray | float, rows: np.ndarray | int):
    """Batched least squares from normal equations; mean squared error per batch."""
    beta = np.linalg.solve(A, g[..., None])[..., 0]
    return (yy - np.einsum("...i,...i->...", beta, g)) / rows, beta


def foptd_oe(
    u: np.ndarray, y_f: np.ndarray, d: int, a: float, b: float, qb: np.ndarray | None = None
):
    """Filtered output-error fit of the FOPTD for fixed dead time and pole.

    Regressors, high-passed like ``y_f``: the lag response ``z`` (coefficient: the
    gain) and the free response ``a^k`` (the initial state); plus ``b^k``, the
    filter's own free response, which carries whatever the rows ``k <= d`` (where pv
    answers to inputs from before the record) leave in the filter.  Rows ``k > d``.
    ``qb``: ``powers(b, 0, n)`` when the caller has it (a fit evaluates many dead
    times and poles with one filter).  Returns the mean squared error and the
    coefficients.  O(n): a few passes over the record.
    """
    n = u.size
    rows = slice(d + 1, n)
    X = np.column_stack(
        [
            highpass(lag_response(u, d, a), b)[rows],
            highpass(powers(a, 0, n), b)[rows],
            powers(b, d + 1, n) if qb is None else qb[rows],
        ]
    )
    A = X.T @ X
    m = n - d - 1
    # Free responses vanish for fast poles: a tiny ridge keeps the solve regular.
    A[1, 1] += 1e-12 * m
    A[2, 2] += 1e-12 * m
    y = y_f[rows]
    mse, coef = solve_normal(A, X.T @ y, float(y @ y), m)
    return float(mse), coef


def _prefix(x: np.ndarray) -> np.ndarray:
    return np.concatenate(([0.0], np.cumsum(x)))


@dataclass(frozen=True)
class FilterSums:
    """What the delay scans of one fit share: the filter's free response ``b^k`` and
    the prefix sums of its square, of its product with ``y_f`` and of ``y_f``'s
    square (they do not depend on the input's pole or dead time)."""

    q: np.ndarray
    cqq: np.ndarray
    cqy: np.ndarray
    cyy: np.ndarray

    @classmethod
    def of(cls, y_f: np.ndarray, b: float) -> FilterSums:
        q = powers(b, 0, y_f.size)
        return cls(q, _prefix(q * q), _prefix(q * y_f), _prefix(y_f * y_f))


def delay_scan(
    w: np.ndarray,
    r: np.ndarray,
    y_f: np.ndarray,
    b: float,
    d_max: int,
    sums: FilterSums | None = None,
):
    """Mean squared error of a filtered output-error fit for every dead time 0..d_max.

    Regressors for dead time ``d``, rows ``k > d``: ``w[k - d]`` (the high-passed
    response to the input without dead time, ``w[0] = 0``: delaying the input delays
    the response, and the high-pass started at rest keeps the shift), ``r[k]`` (a
    delay-free column) and ``b^k`` (the filter's free response).  The normal
    equations come from prefix sums and two correlations for all delays at once;
    ``sums`` are the ones that depend on ``y_f`` and ``b`` only, when the caller
    scans more than once (:class:`FilterSums`).  O(n log d_max) (the correlations,
    :func:`correlate_lags`) plus O(d_max) 3 x 3 solves; O(n) memory.
    """
    n = w.size
    dd = np.arange(d_max + 1)
    if sums is None:
        sums = FilterSums.of(y_f, b)
    q, cqq, cqy, cyy = sums.q, sums.cqq, sums.cqy, sums.cyy
    first = dd + 1  # rows k = d+1 .. n-1
    top = n - dd  # w[1 .. n-1-d] appear
    cww, cwq = _prefix(w * w), _prefix(w * q)
    crr, crq = _prefix(r * r), _prefix(r * q)
    cry = _prefix(r * y_f)
    # sum_{k>=d} v[k] w[k-d]: correlation of v with w at lag d (w[0] = 0 drops k = d).
    wr = correlate_lags(r, w, d_max)
    wy = correlate_lags(y_f, w, d_max)
    A = np.empty((d_max + 1, 3, 3))
    A[:, 0, 0] = cww[top] - cww[1]
    A[:, 0, 1] = A[:, 1, 0] = wr
    A[:, 0, 2] = A[:, 2, 0] = (b**dd) * (cwq[top] - cwq[1])
    A[:, 1, 1] = crr[n] - crr[first] + 1e-12 * n * max(float(np.max(np.abs(r))), 1.0) ** 2
    A[:, 1, 2] = A[:, 2, 1] = crq[n] - crq[first]
    A[:, 2, 2] = cqq[n] - cqq[first] + 1e-12 * n
    g = np.stack([wy, cry[n] - cry[first], cqy[n] - cqy[first]], axis=1)
    mse, _ = solve_normal(A, g, cyy[n] - cyy[first], n - first)
    return mse


def oe_delay_scan(
    u: np.ndarray,
    y_f: np.ndarray,
    a: float,
    b: float,
    d_max: int,
    sums: FilterSums | None = None,
):
    """:func:`foptd_oe` for every dead time 0..d_max at a fixed pole (vectorised)."""
    w = highpass(lag_response(u, 0, a), b)
    return delay_scan(w, highpass(powers(a, 0, u.size), b), y_f, b, d_max, sums)


def fit_foptd(u, y_f, dt, b, d_max, tau_max):
    """Filtered output-error FOPTD fit: a coarse grid over the time constant with every
    dead time (vectorised), then a walk along the dead time with the time constant
    refined at each step.  Returns (dead time [samples], tau [s], gain, mse).

    Cost: 25 delay scans (:func:`delay_scan`, O(n log d_max) each) and about ten
    O(n) output-error fits per bounded search of the time constant, one search per
    step of the walk.  With ``d_max`` and ``tau_max`` from :func:`search_span` (the
    loop's period, not the record) the grid's spacing and so the walk's length do
    not grow with the record: O(n log d_max) in all.
    """
    log_lo, log_hi = math.log(0.2 * dt), math.log(tau_max)
    sums = FilterSums.of(y_f, b)  # shared by every scan and fit below: one filter

    def mse(d: int, log_tau: float) -> float:
        return foptd_oe(u, y_f, d, math.exp(-dt / math.exp(log_tau)), b, sums.q)[0]

    grid = np.linspace(log_lo, log_hi, 25)
    spacing = float(grid[1] - grid[0])

    def best_tau(d: int, centre: float) -> tuple[float, float]:
        """Bounded search of log(tau) within a grid spacing of ``centre``; the
        bracket moves while the optimum sits on its edge."""
        lo, hi = max(centre - spacing, log_lo), min(centre + spacing, log_hi)
        for _ in range(8):
            res_x, res_fun = minimize_scalar_bounded(lambda g: mse(d, g), (lo, hi), xatol=1e-4)
            x = float(res_x)
            if x - lo < 0.05 * spacing and lo > log_lo:
                lo, hi = max(lo - spacing, log_lo), lo + 0.1 * spacing
            elif hi - x < 0.05 * spacing and hi < log_hi:
                lo, hi = hi - 0.1 * spacing, min(hi + spacing, log_hi)
            else:
                break
        return x, float(res_fun)

    # Coarse joint grid: every dead time for each time constant of the grid.  The
    # time constant and the dead time trade off along a ridge, so the two are
    # searched together rather than one after the other.
    profile = np.full(d_max + 1, np.inf)
    tau_at = np.zeros(d_max + 1)
    for g in grid:
        costs = oe_delay_scan(u, y_f, math.exp(-dt / math.exp(g)), b, d_max, sums)
        better = costs < profile
        profile[better] = costs[better]
        tau_at[better] = g
    d = pick_dead_time(profile)
    cache: dict[int, tuple[float, float]] = {d: best_tau(d, float(tau_at[d]))}

    def cost(dd: int, centre: float) -> float:
        if dd not in cache:
            cache[dd] = best_tau(dd, centre)
        return cache[dd][1]

    # Local refinement along the ridge with the time constant optimised at each step.
    for step in (1, -1):
        while 0 <= d + step <= d_max and cost(d + step, cache[d][0]) < cache[d][1]:
            d += step
    tau = math.exp(cache[d][0])
    mse_, coef = foptd_oe(u, y_f, d, math.exp(-dt / tau), b, sums.q)
    return d, tau, float(coef[0]), mse_


def integrating_oe(u, y_f, dt, d, b):
    """Filtered output-error fit of the integrator for a fixed dead time: regressors
    (high-passed) ``dt sum u`` (gain) and ``dt k`` (minus gain x balance input), and
    the filter's free response ``b^k``; rows ``k > d``."""
    n = u.size
    rows = slice(d + 1, n)
    cols = integrating_regressors(u, d, dt)
    X = np.column_stack(
        [highpass(cols[:, 1], b)[rows], highpass(cols[:, 2], b)[rows], powers(b, d + 1, n)]
    )
    A = X.T @ X
    m = n - d - 1
    A[2, 2] += 1e-12 * m
    y = y_f[rows]
    mse, coef = solve_normal(A, X.T @ y, float(y @ y), m)
    return float(mse), coef


def fit_integrating(u, y_f, dt, b, d_max):
    """Filtered output-error integrator fit; every dead time at once (the model is
    linear in its parameters, so the scan is exact).  Returns (dead time, gain,
    balance input, mse).  O(n log d_max): one delay scan and one fit."""
    # With the input shifted to start at zero the integrated input for dead time d is
    # the one for no dead time shifted by d; the shift moves into the balance input.
    cols = integrating_regressors(u - u[0], 0, dt)
    costs = delay_scan(highpass(cols[:, 1], b), highpass(cols[:, 2], b), y_f, b, d_max)
    d = pick_dead_time(costs)
    mse, coef = integrating_oe(u, y_f, dt, d, b)
    gain = float(coef[0])
    u_bias = -float(coef[1]) / gain if gain != 0.0 else float(u.mean())
    return d, gain, u_bias, mse


def fit_integrating_differenced(u, pv, dt, b, d_max, smooth):
    """Integrator fit on pv's differences: ``pv[k+1] - pv[k] = K dt (u[k - d] - u_b)``.

    The balance input ``u_b`` of a real level loop wanders with the unmeasured
    outflow; integrated, that wander swamps pv's level, so a fit of pv itself is
    pulled far off.  In the differences it is a slow offset that the drift
    high-pass removes.  Both sides pass the same high-pass and the same first-order
    lag ``smooth`` (against the noise that differencing amplifies): the relation is
    linear, so the filters leave the gain unchanged.  Every dead time is scanned at
    once.  Returns (dead time, gain, R^2 of the filtered differences).
    O(n log d_max).
    """
    dy = np.diff(pv)
    x = u[:-1] - u[0]
    y_f = highpass(lfilter1((1.0 - smooth,), -smooth, dy - dy[0]), b)
    w = highpass(lfilter1((1.0 - smooth,), -smooth, x), b)
    zero = np.zeros_like(w)
    d_max = min(d_max, w.size - MIN_SAMPLES)
    costs = delay_scan(w, zero, y_f, b, max(d_max, 0))
    d = pick_dead_time(costs)
    k = np.arange(d + 1, w.size)
    wd = w[k - d]
    gain = float(wd @ y_f[k]) / (float(wd @ wd) or 1e-300) / dt
    resid = y_f[k] - gain * dt * wd
    r2 = 1.0 - float(resid @ resid) / (float(y_f[k] @ y_f[k]) or 1e-300)
    return d, gain, r2
