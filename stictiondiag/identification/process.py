"""Identification of the process of a loop from closed-loop data (Eq. 3, Table 3).

The replay of a sticky loop (Choudhury, Thornhill & Shah 2005, Sections 4.2.2 and
5.3) needs the process ``G(s)`` that maps the valve position ``mv`` to ``pv``: first
order plus dead time ``K e^{-theta s} / (tau s + 1)`` (the concentration loop) or
integrating ``K e^{-theta s} / s`` (the level loop, Table 3).

Output-error fit (:func:`identify_process`): the model is *simulated* from ``u`` and
the squared simulation error minimised.  Gain, initial state and balance input enter
linearly and are solved by least squares; the dead time (whole samples) is scanned
over all delays at once (normal equations from prefix sums and correlations), on a
coarse grid of time constants for the FOPTD, followed by a scalar search of the time
constant and a local walk along the dead time.  A one-step ARX fit would be biased by
measurement noise on pv (the regressor ``pv[k]`` is noisy); the output-error fit is
not, and it is the simulated response that the replay needs (the ARX R^2 is reported
for reference).

Model and data are compared after a first-order high-pass (time constant a few
oscillation periods, :func:`drift_pole`): plant pv drifts with unmeasured
disturbances, which an integrator or a slow lag would otherwise chase.  The samples
within the first dead time are left out (pv there answers to inputs from before the
record); free-response regressors absorb what those unknown inputs leave behind, so
the fit is exact on noise-free data from the model.  Operating point and initial
state are then fitted on the raw data with the dynamics fixed.

With ``integrating=None`` the integrating model is chosen when its fit is within
:data:`INTEGRATING_R2_MARGIN` of the FOPTD's: an integrator is the limit of an FOPTD
with a long time constant, so the FOPTD always fits at least about as well and the
simpler model wins ties.

A limit cycle is (nearly) periodic, so a dead time ``d`` and ``d + P`` (``P`` the
period in samples) explain the data about equally well; the scan takes the shortest
dead time whose fit is close to the best (:data:`DEAD_TIME_TOLERANCE`).

The fits (:func:`fit_foptd`, :func:`fit_integrating`,
:func:`fit_integrating_differenced`) simulate the model with the first-order
responses of :mod:`stictiondiag.core.filters`; every dead time is scanned at once
(:func:`delay_scan`: normal equations from prefix sums and correlations).  The
result is one :class:`~stictiondiag.identification.process_result.ProcessFit`,
whose ``simulate`` replays the fitted process.

The prediction-error fit of the same process structures, with the unmeasured load
tracked by a Kalman filter and pv predicted ``h`` samples ahead, is
:func:`stictiondiag.identification.predictor.fit_predictor` (the gap diagnosis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from stictiondiag.core.checks import as_signal, check_dt
from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.core.filters import (
    correlate_lags,
    delayed,
    highpass,
    integrating_regressors,
    lag_response,
    lfilter1,
    powers,
)
from stictiondiag.core.optimize import minimize_scalar_bounded
from stictiondiag.identification.numerics import MIN_SAMPLES, r_squared
from stictiondiag.identification.process_result import Objective, OutputErrorFit, ProcessFit
from stictiondiag.models.processes import FOPTD, Integrating
from stictiondiag.signals.oscillation import acf_period_samples

#: Integrating model chosen when its simulation R^2 is at most this much below the FOPTD's.
INTEGRATING_R2_MARGIN = 0.01


#: Drift high-pass of the process fit: time constant in periods of pv's dominant
#: oscillation, or as a fraction of the record when pv has no dominant period.
DRIFT_PERIODS = 1.0


DRIFT_RECORD_FRACTION = 0.2


#: Longest dead time searched, as a fraction of the search span [-] (the record, or
#: :data:`SPAN_PERIODS` periods of pv's oscillation when that is shorter).
MAX_DEAD_TIME_FRACTION = 0.25


#: Longest FOPTD time constant searched, in search spans [-].
MAX_TIME_CONSTANT_SPANS = 20.0


#: The search ranges of the dead time and of the time constant are those of a record
#: of at most this many periods of pv's dominant oscillation [-] (see
#: :func:`search_span`) ...
SPAN_PERIODS = 80.0


#: ... and of at least this many samples [samples].
MIN_SPAN_SAMPLES = 10_000


#: The integrator's differenced fit smooths pv's differences with a first-order lag of
#: a period over this number (at least one sample) [-], and high-passes them with a
#: time constant of this many periods [-]: in closed loop the controller moves the
#: valve's mean with the wandering load, so the slow part of the valve position is
#: confounded with the disturbance; the slips and jumps within a cycle are not.
SMOOTH_PER_PERIOD = 100.0


#: Below this filtered R^2 of the integrator's level fit the differenced fit is used [-].
LEVEL_FIT_R2_MIN = 0.5


DIFFERENCED_DRIFT_PERIODS = 0.25


#: ... and the operating point is then fitted on the first this many periods [-].
START_WINDOW_PERIODS = 2.0


def _period_s(pv: np.ndarray, dt: float) -> float | None:
    """pv's dominant period [s] (:func:`~stictiondiag.signals.oscillation.dominant_period`
    of a checked ``dt``), or None.  O(n log n) (the autocorrelation by FFT)."""
    period = acf_period_samples(pv)
    return None if period is None else period * dt


def drift_pole(pv: np.ndarray, dt: float, drift_time_constant: float | None):
    """Pole ``b`` of the drift high-pass and its time constant [s] (None: no filter)."""
    period = _period_s(pv, dt) if drift_time_constant is None else None
    return _drift_pole(period, pv.size, dt, drift_time_constant)


def _drift_pole(period: float | None, n: int, dt: float, drift_time_constant: float | None):
    """:func:`drift_pole` given pv's dominant period [s] (None: none)."""
    if drift_time_constant is None:
        if period is not None:
            drift_time_constant = DRIFT_PERIODS * period
        else:
            drift_time_constant = DRIFT_RECORD_FRACTION * n * dt
    T = float(drift_time_constant)
    if math.isnan(T) or T <= 0.0:
        raise UsageError(f"drift_time_constant must be > 0 s (inf: no filter), got {T}")
    if math.isinf(T):
        return 1.0, None
    return math.exp(-dt / T), T


def search_span(n: int, period_samples: float | None) -> int:
    """Samples the identification's search ranges are scaled on: the record's ``n``,
    or :data:`SPAN_PERIODS` periods of pv's oscillation when that is shorter, but
    not less than :data:`MIN_SPAN_SAMPLES`.

    The dead time is searched up to :data:`MAX_DEAD_TIME_FRACTION` of the span and
    the FOPTD time constant up to :data:`MAX_TIME_CONSTANT_SPANS` spans.  Both are
    time scales of the loop, not of the record: when a loop's own feedback makes it
    cycle, the cycle sits where ``G0(i w) = -1/N(X_m)`` (Choudhury, Thornhill & Shah
    2005, Section 6.1, Eq. 5: ``G0`` the process with the PI controller, ``N`` the sticky
    valve's describing function, whose output lags its input), so the phase lag of
    ``G0`` at the cycle is below 180 degrees, and the dead time's share ``w theta``
    of it keeps the dead time below half a period; a dead time ``d + P`` is an alias
    of ``d`` on periodic data (the module docstring); 20 periods leave room for an oscillation
    from outside the loop and for a period detected at a harmonic.  A time
    constant of many periods (1600 at the cap) acts as an integrator on everything
    the drift-filtered data carry (the high-pass keeps periods up to a few of the
    cycle's): the fit's cost is flat beyond, and its gain over time constant is what
    the data determine.  A longer record adds cycles, not longer time scales: with
    the span capped the search takes a number of O(n) cost evaluations that does
    not grow with the record.  Without a dominant period the record is the only
    time scale and the span is ``n``.  The floor of :data:`MIN_SPAN_SAMPLES`
    guards against a period found on noise or at a harmonic of a loop that does
    not cycle (the period is not checked for regularity here): records of up to
    that length, the length the identification was designed and tested on (plant
    records of hours to days, the accuracy benchmark's 3000-10 000 samples), are
    searched over the record's ranges, as before the cap.  O(1).
    """
    if period_samples is None or not math.isfinite(period_samples) or period_samples <= 0:
        return int(n)
    return int(min(n, max(SPAN_PERIODS * period_samples, MIN_SPAN_SAMPLES)))


def longest_time_constant(pv: np.ndarray, dt: float) -> float:
    """Longest FOPTD time constant :func:`identify_process` searches for ``pv`` [s]:
    :data:`MAX_TIME_CONSTANT_SPANS` search spans (:func:`search_span`).  O(n log n)."""
    period = _period_s(pv, dt)
    span = search_span(pv.size, None if period is None else period / dt)
    return MAX_TIME_CONSTANT_SPANS * span * dt


# --------------------------------------------------------------------------------------
# The filtered output-error fits of the FOPTD and the integrator
# --------------------------------------------------------------------------------------


#: Dead-time scan: shortest delay whose cost is within this fraction of the range
#: between the best and the median cost (periodic data make d and d + P ambiguous).
DEAD_TIME_TOLERANCE = 0.02


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


def solve_normal(A: np.ndarray, g: np.ndarray, yy: np.ndarray | float, rows: np.ndarray | int):
    """Batched least squares from normal equations; mean squared error per batch.

    A singular system in the batch (regressors that coincide: a dead time or pole at
    which the lag response equals the free response, on a record that barely moves)
    is solved by the pseudo-inverse, its least-norm solution, instead of failing the
    whole batch: numpy's batched solve raises for the batch when any one of its
    systems is singular.  The regular systems get the same solution either way.
    """
    try:
        beta = np.linalg.solve(A, g[..., None])[..., 0]
    except np.linalg.LinAlgError:
        beta = (np.linalg.pinv(A) @ g[..., None])[..., 0]
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
    """:func:`foptd_oe` for every dead time 0..d_max at a fixed pole (vectorised):
    the high-passed lag response without dead time and the high-passed free
    response scanned by :func:`delay_scan`."""
    w = highpass(lag_response(u, 0, a), b)
    r = highpass(powers(a, 0, u.size), b)
    return delay_scan(w, r, y_f, b, d_max, sums)


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


# --------------------------------------------------------------------------------------
# identify_process: checks, the structures fitted and chosen, operating point
# --------------------------------------------------------------------------------------


def _checked_inputs(u, pv, dt, integrating, max_dead_time):
    """The arguments of :func:`identify_process` checked: ``(dt, u, pv, d_max)`` with
    ``d_max`` the longest dead time asked for [samples] (None: no limit asked).  Bad
    input raises :class:`UsageError` or :class:`DataError` with a one-line
    message."""
    dt = check_dt(dt)
    u = as_signal(u, "u")
    pv = as_signal(pv, "pv")
    if u.size != pv.size:
        raise UsageError(f"u and pv must have the same length, got {u.size} and {pv.size}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(pv))):
        raise DataError("u and pv must be finite for process identification: fill or drop gaps")
    n = u.size
    if n < MIN_SAMPLES:
        raise DataError(f"{n} samples are too few for process identification (need {MIN_SAMPLES})")
    if np.ptp(u) == 0.0:
        raise DataError("the process input is constant: the process cannot be identified")
    if integrating not in (None, True, False):
        raise UsageError(f"integrating must be True, False or None, got {integrating!r}")
    d_max = None
    if max_dead_time is not None:
        if not (math.isfinite(max_dead_time) and max_dead_time >= 0):
            raise UsageError(f"max_dead_time must be >= 0 s, got {max_dead_time}")
        d_max = max(int(max_dead_time / dt), 0)
    return dt, u, pv, d_max


def _chosen_structure(results: dict, integrating: bool | None) -> str:
    """``"integrating"`` or ``"foptd"``: the forced structure, or by fit (the
    integrator wins unless the lag explains :data:`INTEGRATING_R2_MARGIN` more)."""
    if integrating is None:
        return (
            "integrating"
            if results["integrating"]["r2"] >= results["foptd"]["r2"] - INTEGRATING_R2_MARGIN
            else "foptd"
        )
    return "integrating" if integrating else "foptd"


def _refit_integrating_differenced(result, uc, pc, period, dt, b, d_max, drift_time_constant):
    """Replace the integrator's fit in ``result`` by the fit to pv's differences
    (:func:`fit_integrating_differenced`) where that fit finds a response; the
    replay then starts from the operating point of the record's first cycles
    (``window`` [samples]).  ``period``: pv's dominant period [samples] or None."""
    n = pc.size
    smooth = math.exp(-1.0 / max(1.0, (period or 100.0) / SMOOTH_PER_PERIOD))
    b_diff = b
    if drift_time_constant is None and period is not None:
        b_diff = math.exp(-1.0 / max(2.0, DIFFERENCED_DRIFT_PERIODS * period))
    d, gain, r2_diff = fit_integrating_differenced(uc, pc, dt, b_diff, d_max, smooth)
    if math.isfinite(gain) and gain != 0.0:
        window = int(START_WINDOW_PERIODS * (period or n / START_WINDOW_PERIODS))
        result.update(d=d, gain=gain, u_bias=None, r2=r2_diff, window=max(window, MIN_SAMPLES))


def _chosen_process(chosen: str, p: dict, u, pv, dt):
    """The process of the chosen structure's parameters ``p`` and its biases and
    initial state from the unfiltered data, dynamics fixed (:func:`_biases`)."""
    if p["gain"] == 0.0 or not math.isfinite(p["gain"]):
        raise DataError(f"pv does not respond to the process input: no {chosen} model")
    d = p["d"]
    process: FOPTD | Integrating
    if chosen == "integrating":
        process = Integrating(gain=p["gain"], dead_time=d * dt)
    else:
        process = FOPTD(gain=p["gain"], time_constant=p["tau"], dead_time=d * dt)
    if "window" in p:
        # A wandering balance input: the operating point of the record's start, from
        # its first cycles, is where a replay from the recorded start begins.
        m = min(u.size, p["window"] + d + 1)
        return process, _biases(process, u[:m], pv[:m], dt, d)
    return process, _biases(process, u, pv, dt, d, u_bias=p.get("u_bias"))


def identify_process(
    u: np.ndarray,
    pv: np.ndarray,
    dt: float,
    *,
    integrating: bool | None = None,
    max_dead_time: float | None = None,
    drift_time_constant: float | None = None,
) -> ProcessFit:
    """Identify an FOPTD or integrating process from ``u`` to ``pv`` (Eq. 3, Table 3).

    Parameters
    ----------
    u : ndarray
        Process input: recorded valve position mv, or the fitted valve output
        ``mv_model`` of the stiction fit [% of span].
    pv : ndarray
        Process output [pv units].
    dt : float
        Sample time [s].
    integrating : bool or None
        Force the integrating (True) or FOPTD (False) structure; None chooses by fit.
    max_dead_time : float, optional
        Longest dead time searched [s]; default a quarter of the search span
        (:func:`search_span`: the record, or :data:`SPAN_PERIODS` periods of pv's
        oscillation when that is shorter).
    drift_time_constant : float, optional
        Time constant of the high-pass applied to model and data before they are
        compared [s]: slow drifts of plant data (unmeasured disturbances) then do not
        pull the fit, while the loop's oscillation passes.  Default
        :data:`DRIFT_PERIODS` periods of pv's dominant oscillation, or
        :data:`DRIFT_RECORD_FRACTION` of the record when pv has none; ``math.inf``
        compares the signals unfiltered.

    Returns
    -------
    ProcessFit
        The process, biases and fit measures.  Dead time is a whole number of
        samples; the FOPTD time constant is searched in [0.2 dt, 20 x span].

    Notes
    -----
    Cost O(n log n) for pv's period, then O(n) per cost evaluation: 25 delay scans
    (each O(n log d_max), :func:`stictiondiag.core.filters.correlate_lags` in
    blocks) and a few tens of output-error fits (:func:`foptd_oe`, O(n) each).  The
    number of evaluations depends on the search ranges, which :func:`search_span`
    bounds by the loop's period: for a cycling loop it does not grow with the record,
    so the fit is O(n log n) (the FFTs), in practice linear.  Memory O(n).
    """
    dt, u, pv, d_asked = _checked_inputs(u, pv, dt, integrating, max_dead_time)
    n = u.size
    period_s = _period_s(pv, dt)
    period = None if period_s is None else period_s / dt
    span = search_span(n, period)
    d_max = int(MAX_DEAD_TIME_FRACTION * span)
    if d_asked is not None:
        d_max = min(d_max, d_asked)
    b, drift_T = _drift_pole(period_s, n, dt, drift_time_constant)
    # Centre the signals: the normal equations are then well conditioned.
    uc = u - u.mean()
    pc = pv - pv.mean()
    y_f = highpass(pc, b)
    sst_dy = float(np.sum((np.diff(pc) - np.diff(pc).mean()) ** 2)) or 1e-300

    def r2_of(mse: float, d: int) -> float:
        return 1.0 - mse / (float(np.mean(y_f[d + 1 :] ** 2)) or 1e-300)

    results: dict[str, dict] = {}
    if integrating in (None, False):
        tau_max = MAX_TIME_CONSTANT_SPANS * span * dt
        d, tau, gain, mse = fit_foptd(uc, y_f, dt, b, d_max, tau_max)
        results["foptd"] = dict(d=d, tau=tau, gain=gain, r2=r2_of(mse, d))
    if integrating in (None, True):
        d, gain, ub_c, mse = fit_integrating(uc, y_f, dt, b, d_max)
        results["integrating"] = dict(d=d, gain=gain, u_bias=ub_c + u.mean(), r2=r2_of(mse, d))
    chosen = _chosen_structure(results, integrating)
    if chosen == "integrating" and results["integrating"]["r2"] < LEVEL_FIT_R2_MIN:
        # The level of pv is not explained (a wandering balance input integrated into
        # it): the integrator's parameters come from pv's differences instead, which
        # that wander does not bias.  Where the level fit holds it is kept: it is the
        # more efficient of the two under measurement noise.
        _refit_integrating_differenced(
            results["integrating"], uc, pc, period, dt, b, d_max, drift_time_constant
        )
    p = results[chosen]
    d = p["d"]
    process, fit = _chosen_process(chosen, p, u, pv, dt)
    oe = replace(
        fit.output_error,
        fit_r2=p["r2"],
        arx_r2=_arx_r2_at(uc, pc, d, chosen == "integrating", sst_dy),
        foptd_r2=results["foptd"]["r2"] if "foptd" in results else None,
        integrating_r2=results["integrating"]["r2"] if "integrating" in results else None,
        unfiltered_r2=r_squared(pv[d + 1 :], fit.simulate(u, dt)[d + 1 :]),
        drift_time_constant=drift_T,
    )
    return replace(fit, detail=oe)


def _biases(process, u, pv, dt, d, *, u_bias=None) -> ProcessFit:
    """Operating point and initial state for given dynamics (rows ``k > d``).

    FOPTD: ``pv_bias`` at ``u_bias = mean(u)`` and the initial deviation.
    Integrating: the balance input (``u_bias`` when given, else fitted) and the pv
    the simulated response starts from.
    """
    gain = float(process.gain)
    k = np.arange(d + 1, u.size)
    if isinstance(process, Integrating):
        X = integrating_regressors(u, d, dt)[k]
        target = pv[k] - gain * X[:, 1]
        if u_bias is None:
            coef, *_ = np.linalg.lstsq(X[:, [0, 2]], target, rcond=None)
            pv0, u_bias = float(coef[0]), -float(coef[1]) / gain
        else:
            pv0 = float(np.mean(target + gain * u_bias * X[:, 2]))
        oe = OutputErrorFit(u_bias=float(u_bias), pv_bias=pv0, initial_deviation=0.0)
        return ProcessFit(Objective.OUTPUT_ERROR, process, d, oe)
    a = math.exp(-dt / float(process.time_constant))
    u_bias = float(u.mean())
    target = pv[k] - gain * (lag_response(u, d, a)[k] - u_bias)
    free = powers(a, d + 1, u.size)
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones(k.size), free]), target, rcond=None)
    oe = OutputErrorFit(u_bias=u_bias, pv_bias=float(coef[0]), initial_deviation=float(coef[1]))
    return ProcessFit(Objective.OUTPUT_ERROR, process, d, oe)


def _arx_r2_at(u, pv, d, integrating, sst_dy) -> float:
    """R^2 of the one-step ARX prediction at dead time d, on pv differences."""
    x = delayed(u, d)[:-1]
    y_now, y_next = pv[:-1], pv[1:]
    if integrating:
        X = np.column_stack([x, np.ones(x.size)])
        target = y_next - y_now
    else:
        X = np.column_stack([y_now, x, np.ones(x.size)])
        target = y_next
    coef, *_ = np.linalg.lstsq(X, target, rcond=None)
    resid = target - X @ coef
    return 1.0 - float(resid @ resid) / sst_dy


def process_fit(
    process: FOPTD | Integrating, u: np.ndarray, pv: np.ndarray, dt: float
) -> ProcessFit:
    """Biases and fit measures of a *given* process on recorded data.

    The dynamics (gain, time constant, dead time) are kept; the dead time is rounded
    to whole samples.  FOPTD: ``pv_bias`` and the initial deviation are fitted with
    ``u_bias = mean(u)``; integrating: the initial pv and the balance input.
    """
    if not isinstance(process, FOPTD | Integrating):
        raise UsageError(
            "process must be a FOPTD or Integrating model (stictiondiag.models.processes)"
        )
    dt = check_dt(dt)
    u = as_signal(u, "u")
    pv = as_signal(pv, "pv")
    if u.size != pv.size or u.size < 2:
        raise UsageError(f"u and pv must be equally long signals, got {u.size} and {pv.size}")
    gain = float(process.gain)
    if gain == 0.0 or not math.isfinite(gain):
        raise UsageError(f"process gain must be finite and non-zero, got {gain}")
    d = int(round(float(process.dead_time) / dt))
    if u.size < d + 1 + MIN_SAMPLES:
        raise DataError(
            f"{u.size} samples are too few for a process with a dead time of {d} samples"
        )
    fit = _biases(process, u, pv, dt, d)
    # Rows within the first dead time are left out, as in identify_process.
    r2 = r_squared(pv[d + 1 :], fit.simulate(u, dt)[d + 1 :])
    oe = replace(
        fit.output_error,
        fit_r2=r2,
        arx_r2=_arx_r2_at(
            u, pv, d, fit.integrating, float(np.var(np.diff(pv))) * (u.size - 1) or 1e-300
        ),
        foptd_r2=None if fit.integrating else r2,
        integrating_r2=r2 if fit.integrating else None,
        unfiltered_r2=r2,
    )
    return replace(fit, detail=oe)
