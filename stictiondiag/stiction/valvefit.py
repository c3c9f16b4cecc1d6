"""Stiction parameters S and J from plant data: the shared toolbox of the two estimators.

The data-driven valve model of Choudhury, Thornhill & Shah (2005), Section 5.1 and
Fig. 10, has two parameters, both in % of span: ``S`` (deadband plus stickband, on
the input axis) and ``J`` (slip jump, on the output axis).  They are estimated in one
of two ways:

* from the valve's own position ``mv`` when it is recorded
  (:func:`stictiondiag.stiction.segments.estimate_from_mv`): the stick and slip segments of the
  mv-op plot (Figs. 2-3 and 6), refined by a least-squares fit of the model to ``mv``;
* from ``op`` and ``pv`` alone (:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`): the
  valve model in series with a linear process (a Hammerstein model), fitted together.

Both return a :class:`~stictiondiag.stiction.fit_result.StictionFit`;
:func:`stictiondiag.stiction.verdict.stiction_verdict` then asks the question of
Section 5.3.

This module holds what the two estimators share: the compiled batch evaluation
of the valve model over many (S, J) pairs, the effective number of independent
samples of a residual, and the profile-cost intervals.
"""

from __future__ import annotations

import math
import multiprocessing
import os
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.filters import median_filter_nearest
from stictiondiag.core.jit import jit
from stictiondiag.core.robust import MAD_TO_STD, robust_std, second_difference_noise_std
from stictiondiag.models.valve import _choudhury_next, _kano_next
from stictiondiag.stiction.fit_result import Determinacy

#: Width of the play operator that keeps noise reversals of op away from the valve
#: model, in robust noise standard deviations of op (see :func:`valve_variants`).
PLAY_WIDTH_SIGMAS = 4.0

#: Coverage of the reported S and J intervals (profile-cost intervals, F test).
INTERVAL_LEVEL = 0.95


# --------------------------------------------------------------------------------------
# Valve model variants and compiled kernels shared by the estimators
# --------------------------------------------------------------------------------------


@jit
def play(x, width):
    """Play (backlash) operator of total ``width``: follows ``x`` at ``width/2`` behind,
    and holds while ``x`` turns back by less than ``width``."""
    n = x.shape[0]
    y = np.empty(n)
    if n == 0:
        return y
    h = 0.5 * width
    y[0] = x[0]
    for k in range(1, n):
        y[k] = min(max(y[k - 1], x[k] - h), x[k] + h)
    return y


@dataclass(frozen=True)
class ValveVariant:
    """One way of running the data-driven valve model on a recorded op.

    * ``choudhury``: the published flowchart (Fig. 10).  It re-arms the stuck band at
      every reversal of the input's slope, so on a noisy op it hardly ever slips
      (which is why Section 5.1 asks for a filter in front of it).
    * ``kano``: Kano et al. (2004), which keeps the stuck position while the input
      wanders inside the band.
    * ``+play``: op passes first through a play operator of width ``w`` (4 robust
      noise standard deviations of op), so that noise reversals neither re-arm nor
      stop the valve.  The play operator lags op by ``w/2`` in the direction of travel,
      so the model with ``S - w`` on the played op is the model with ``S`` on op
      itself (breakaway after a travel of ``S``, Eq. 4 offset ``(S - J)/2``); the
      variant is therefore parametrised by the ``S`` of the raw op.
    """

    name: str
    kano: bool
    play_width: float = 0.0

    def prepare(self, op: np.ndarray) -> np.ndarray:
        """The input the valve model sees [units of op]."""
        op = np.ascontiguousarray(op, dtype=float)
        return play(op, self.play_width) if self.play_width > 0 else op

    def model_S(self, S):
        """``S`` to give the model for a band ``S`` on the raw op."""
        return np.maximum(np.asarray(S, dtype=float) - self.play_width, 0.0)

    def for_band(self, S: float) -> ValveVariant:
        """The variant that represents a band ``S`` on the raw op.

        Behind the play operator every ``S <= w`` gives the same model, a valve
        stuck for a travel of ``w`` at each reversal (a deadband of ``w``, Fig. 11
        with ``J = 0``), not a valve with the smaller band: ``S = 0`` would not be
        the linear valve.  A band below ``w`` is therefore run on the raw op, by the
        same flowchart without the play operator, so that every ``S`` of the search
        is the model of Fig. 10 with that band and ``S = J = 0`` is a linear valve.
        """
        if self.play_width > 0 and S < self.play_width:
            return ValveVariant(self.name.removesuffix("+play"), self.kano)
        return self

    def band_parts(self, S: np.ndarray) -> list[tuple[np.ndarray, ValveVariant]]:
        """The bands ``S`` split by the variant that runs them (:meth:`for_band`):
        ``(mask, variant)`` pairs, each mask non-empty, together covering ``S``."""
        narrow = np.asarray(S, dtype=float) < self.play_width
        parts = [(~narrow, self), (narrow, self.for_band(0.0))]
        return [(mask, v) for mask, v in parts if mask.any()]

    def sse(self, op: np.ndarray, mv: np.ndarray, S: float, J: float, sync) -> float:
        """Squared error [% of span]^2 of the model with band ``S`` and jump ``J``
        against ``mv``, run by the variant that represents ``S`` (:meth:`for_band`):
        one pair of :func:`valve_sse_batch`.  ``sync``: ``(k0, k_start, d_start)``,
        the first sample counted and where and how the model starts moving."""
        v = self.for_band(S)
        k0, k_start, d_start = sync
        model_S = v.model_S(np.array([S]))
        return float(
            valve_sse_batch(
                v.prepare(op), mv, model_S, np.array([J]), v.kano, k0, k_start, d_start, -1.0
            )[0]
        )


def white_noise_std(x: np.ndarray) -> float:
    """Standard deviation of white noise on ``x`` [units of x]; 0 for a smooth signal.

    Second differences of white noise alternate in sign (lag-1 autocorrelation
    -2/3); those of a smooth signal with curvature do not (close to +1).  The noise
    is taken as present when the lag-1 autocorrelation of the second difference
    (winsorised at 5 robust deviations, so that slips do not dominate) is below
    -0.25, and its level is then
    :func:`~stictiondiag.core.robust.second_difference_noise_std`.
    """
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    if d2.size < 10:
        return 0.0
    med = float(np.median(d2))
    mad = float(np.median(np.abs(d2 - med)))
    if mad <= 0:
        return 0.0
    d = np.clip(d2 - med, -5 * MAD_TO_STD * mad, 5 * MAD_TO_STD * mad)
    d = d - d.mean()
    den = float(np.dot(d, d))
    rho1 = float(np.dot(d[1:], d[:-1])) / den if den > 0 else 1.0
    return second_difference_noise_std(x) if rho1 < -0.25 else 0.0


def valve_variants(op: np.ndarray) -> list[ValveVariant]:
    """The valve variants a fit tries on ``op``: both flowcharts, raw and, when op
    carries white noise, behind the play operator."""
    out = [ValveVariant("choudhury", False), ValveVariant("kano", True)]
    w = PLAY_WIDTH_SIGMAS * white_noise_std(op)
    if w > 1e-9 * max(float(np.ptp(op)), 1e-300):
        out += [ValveVariant("choudhury+play", False, w), ValveVariant("kano+play", True, w)]
    return out


@jit
def _start_state(op, S, J, k_start, d_start, offset):
    """Valve state at sample ``k_start`` as local scalars.

    ``offset < 0``: moving in direction ``d_start`` (Eq. 4 output).  ``offset >= 0``:
    stuck since the demand was ``op[k_start] - d_start * offset``, its last movement in
    direction ``d_start``.

    Returns ``(y, xss, dirn, v_old, stuck, x_prev)``, the state of
    :func:`stictiondiag.models.valve.choudhury_step` (kept in local variables by the
    kernels below, as in :func:`stictiondiag.models.valve._choudhury_run`).
    """
    x0 = op[k_start]
    if offset < 0.0:
        return x0 - d_start * (S - J) / 2.0, x0, d_start, d_start, False, x0
    x_ss = x0 - d_start * offset
    return x_ss - d_start * (S - J) / 2.0, x_ss, d_start, d_start, True, x0


@jit
def valve_run(op, S, J, kano, k_start, d_start, offset):
    """Valve position for a recorded ``op`` (Fig. 10), from a given state at ``k_start``.

    A record starts at an arbitrary point of the valve's history, and in a replay of
    recorded op a model out of step with the real valve may never slip at all (the
    recorded op stops ramping when the *real* valve slipped).  The model is therefore
    started in a stated state (see :func:`_start_state`): moving in direction
    ``d_start`` (+1/-1, 0 unknown) right after a recorded slip (``offset < 0``), or
    stuck at an extreme of op with its stop point ``offset`` back from it (a valve
    that slipped on the way to the extreme and stuck).  Output before ``k_start`` is
    held at the starting value; fits leave those samples out.

    Unlike :func:`stictiondiag.models.valve.choudhury_model` the input is not clipped to
    [0, 100]: a recorded op is already what the valve saw, and no clipping keeps the
    fit invariant to the units of op.

    Returns
    -------
    y : ndarray
        Valve position [units of op].
    n_slips : int
        Number of breakaways (stuck -> moving transitions) after ``k_start``.
    """
    n = op.shape[0]
    out = np.empty(n)
    if n == 0:
        return out, 0
    y, xss, dirn, v_old, stuck, x_prev = _start_state(op, S, J, k_start, d_start, offset)
    for k in range(k_start + 1):
        out[k] = y
    slips = 0
    # The model is chosen once, not at every sample (the same operations per sample).
    if kano:
        for k in range(k_start + 1, n):
            x = op[k]
            was_stuck = stuck
            y, xss, dirn, v_old, stuck = _kano_next(x, S, J, y, xss, dirn, stuck, x_prev)
            x_prev = x
            out[k] = y
            if was_stuck and not stuck:
                slips += 1
    else:
        for k in range(k_start + 1, n):
            x = op[k]
            was_stuck = stuck
            y, xss, dirn, v_old, stuck = _choudhury_next(
                x, S, J, y, xss, dirn, v_old, stuck, x_prev
            )
            x_prev = x
            out[k] = y
            if was_stuck and not stuck:
                slips += 1
    return out, slips


@jit
def valve_sse_batch(op, mv, S_arr, J_arr, kano, k0, k_start, d_start, offset):
    """Sum of squared residuals of ``mv - (valve(op; S, J) + bias)`` for many (S, J).

    The valve starts as in :func:`valve_run`.  The bias (a constant offset between
    recorded mv and the model, e.g. a positioner zero error) is fitted in closed form
    for every pair.  Samples before ``k0`` (> ``k_start``) are left out.
    """
    m = S_arr.shape[0]
    n = op.shape[0]
    out = np.empty(m)
    cnt = n - k0
    for i in range(m):
        S = S_arr[i]
        J = J_arr[i]
        y, xss, dirn, v_old, stuck, x_prev = _start_state(op, S, J, k_start, d_start, offset)
        s1 = 0.0
        s2 = 0.0
        for k in range(k_start + 1, n):
            x = op[k]
            if kano:
                y, xss, dirn, v_old, stuck = _kano_next(x, S, J, y, xss, dirn, stuck, x_prev)
            else:
                y, xss, dirn, v_old, stuck = _choudhury_next(
                    x, S, J, y, xss, dirn, v_old, stuck, x_prev
                )
            x_prev = x
            if k >= k0:
                r = mv[k] - y
                s1 += r
                s2 += r * r
        out[i] = s2 - s1 * s1 / cnt if cnt > 0 else 0.0
    return out


#: Fewest (S, J) pairs per thread in :func:`valve_sse_many`.
MIN_PAIRS_PER_THREAD = 60
#: Most threads of :func:`valve_sse_many`.
MAX_THREADS = 4


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


def valve_sse_many(op, mv, S_arr, J_arr, kano, k0, k_start, d_start, offset):
    """:func:`valve_sse_batch`, the pairs shared between threads.

    The compiled kernel releases the interpreter lock and every pair is computed on
    its own, so the threads run side by side on a multi-core machine and return the
    very numbers of one call.  Each thread takes at least
    :data:`MIN_PAIRS_PER_THREAD` pairs; the threads have ended when this returns.
    A worker process (of a scan or a report, local pool or Dask) keeps one thread:
    there one loop per core already keeps every core busy.
    """
    S_arr = np.ascontiguousarray(S_arr, dtype=float)
    J_arr = np.ascontiguousarray(J_arr, dtype=float)
    m = S_arr.shape[0]
    k = min(MAX_THREADS, _cpus(), m // MIN_PAIRS_PER_THREAD)
    if multiprocessing.parent_process() is not None:
        k = 1
    if k <= 1:
        return valve_sse_batch(op, mv, S_arr, J_arr, kano, k0, k_start, d_start, offset)
    import threading

    bounds = [m * i // k for i in range(k + 1)]
    out = np.empty(m)
    errors: dict[int, BaseException] = {}

    def part(a: int, b: int) -> None:
        try:
            out[a:b] = valve_sse_batch(
                op, mv, S_arr[a:b], J_arr[a:b], kano, k0, k_start, d_start, offset
            )
        except BaseException as exc:  # re-raised by the calling thread
            errors[a] = exc

    threads = [
        threading.Thread(target=part, args=(bounds[i], bounds[i + 1]), daemon=True)
        for i in range(1, k)
    ]
    for t in threads:
        t.start()
    try:
        part(bounds[0], bounds[1])
    finally:
        for t in threads:
            t.join()
    if errors:
        raise errors[min(errors)]
    return out


# --------------------------------------------------------------------------------------
# Statistics shared by the estimators
# --------------------------------------------------------------------------------------


def _schmitt_period(x: np.ndarray) -> float | None:
    """Mean period [samples] from crossings of a +-half-robust-std band around zero."""
    s = robust_std(x)
    if s <= 0:
        return None
    h = 0.5 * s
    up = x > h
    down = x < -h
    state = np.where(up, 1, np.where(down, -1, 0))
    state = state[state != 0]
    idx = np.flatnonzero(np.where(up, 1, np.where(down, -1, 0)) != 0)
    if state.size < 2:
        return None
    change = np.flatnonzero(state[1:] != state[:-1]) + 1
    if change.size < 3:
        return None
    k = idx[change]
    return float(2.0 * (k[-1] - k[0]) / (change.size - 1))


def cycle_samples(x: np.ndarray) -> int:
    """Time scale of the cycle of ``x`` [samples]: its mean period, measured robustly.

    Plant records carry load steps, set-point moves and drifts next to the cycle,
    which defeat an autocorrelation period.  Here ``x`` is detrended by a running
    median (which follows steps without smearing them) over three periods, and the
    period is twice the mean interval between crossings of a band of +-half the
    robust standard deviation (a Schmitt trigger, so noise does not add crossings);
    the window and the period are iterated to agreement.  Falls back to a tenth of
    the record.  The result sets time scales of the fits, not a reported period
    (that is :func:`stictiondiag.signals.oscillation.detect_oscillation`'s job).

    Cost O(n log n): at most six running medians of O(n log w) each
    (:func:`stictiondiag.core.filters.median_filter_nearest`; the first window is a
    quarter of the record) and O(n) crossings.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    fallback = max(2, n // 10)
    if n < 20 or np.ptp(x) <= 0:
        return fallback
    window = n / 4.0
    period = None
    for _ in range(6):
        xd = x - median_filter_nearest(x, max(3, int(window) | 1))
        p = _schmitt_period(xd)
        if p is None:
            break
        done = period is not None and abs(p - period) < 0.05 * period
        period = p
        if done:
            break
        window = 3.0 * period
    if period is None or not math.isfinite(period):
        return fallback
    return int(max(4, min(round(period), n // 3)))


def effective_samples(residual: np.ndarray) -> float:
    """Effective number of independent samples of a residual [-].

    ``N / tau`` with the integrated autocorrelation time ``tau = 1 + 2 sum rho_k``,
    summed over the initial positive sequence of the autocorrelation (Geyer 1992).
    Closed-loop residuals are coloured; counting every sample as independent would
    make intervals and tests far too confident.
    """
    r = np.asarray(residual, dtype=float)
    r = r[np.isfinite(r)]
    n = r.size
    if n < 4:
        return float(max(n, 1))
    r = r - r.mean()
    var = float(np.dot(r, r))
    if var <= 0.0:
        return float(n)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[: n // 2] / var
    tau = 1.0
    for k in range(1, acf.size):
        if acf[k] <= 0.0:
            break
        tau += 2.0 * acf[k]
    return float(max(2.0, n / tau))


def cost_threshold(cost_min: float, n_eff: float, n_params: int, model_error: float = 0.0) -> float:
    """Cost below which a parameter value cannot be told apart from the optimum.

    Profile-likelihood F test for one parameter (Seber & Wild 1989, Section 5.9):
    ``C <= C_min (1 + F_{0.95}(1, nu) / nu)`` with ``nu = N_eff - p``.

    The F test assumes the model is right and only noise is left, so that the
    allowed increase shrinks as the record grows.  Where the model itself is known
    to be off by a share of the residual that no record length removes,
    ``model_error`` (a share of ``C_min``) is the smallest increase allowed:
    ``C <= C_min (1 + max(F_{0.95}(1, nu) / nu, model_error))``.  The Hammerstein
    fit measures its share on simulated loops
    (:data:`stictiondiag.stiction.hammerstein.MODEL_ERROR_SHARE`).
    """
    from scipy.special import fdtri  # = scipy.stats.f.ppf, without importing scipy.stats

    nu = max(1.0, n_eff - n_params)
    return float(cost_min * (1.0 + max(fdtri(1, nu, INTERVAL_LEVEL) / nu, model_error)))


def profile_interval(
    values: np.ndarray, costs: np.ndarray, threshold: float, lo: float, hi: float
) -> tuple[tuple[float, float], bool, bool]:
    """Interval of one parameter from evaluated (value, cost) pairs of a grid search.

    The profile cost at a value is the smallest cost evaluated there (the other
    parameters free).  The interval spans the values whose profile cost is within
    ``threshold``, widened to the neighbouring evaluated values (the true edge lies
    between them) and clipped to the searched range [lo, hi].  Where that neighbour
    is the end of the searched range itself, evaluated and outside the threshold (S
    = 0, the linear valve, tested and rejected), the edge is where the profile,
    interpolated linearly between the two values, crosses the threshold: widening
    to the end would put back a value the data reject, and an interval of S that
    reaches 0 reads as "S cannot be told apart from 0".

    Returns
    -------
    interval : (float, float)
    reaches_lo, reaches_hi : bool
        Whether the interval reaches the lowest / highest searched value (then the data
        do not bound the parameter on that side).
    """
    v = np.asarray(values, dtype=float)
    c = np.asarray(costs, dtype=float)
    ok = np.isfinite(c)
    v, c = v[ok], c[ok]
    uv, inv = np.unique(v, return_inverse=True)
    prof = np.full(uv.size, np.inf)
    np.minimum.at(prof, inv, c)
    inside = np.flatnonzero(prof <= threshold)
    if inside.size == 0:
        inside = np.array([int(np.argmin(prof))])
    i0, i1 = int(inside[0]), int(inside[-1])

    def crossing(j_out: int, j_in: int) -> float:
        # Where the profile, linear between an evaluated value outside the threshold
        # and its neighbour inside, crosses the threshold.
        c_out, c_in = float(prof[j_out]), float(prof[j_in])
        t = (c_out - threshold) / (c_out - c_in) if c_out > c_in else 1.0
        return float(uv[j_out] + min(max(t, 0.0), 1.0) * (uv[j_in] - uv[j_out]))

    if i0 == 0:
        a = float(lo)
    elif uv[i0 - 1] <= lo and prof[i0] <= threshold:
        a = crossing(i0 - 1, i0)
    else:
        a = float(uv[i0 - 1])
    if i1 + 1 >= uv.size:
        b = float(hi)
    elif uv[i1 + 1] >= hi and prof[i1] <= threshold:
        b = crossing(i1 + 1, i1)
    else:
        b = float(uv[i1 + 1])
    return (max(float(lo), a), min(float(hi), b)), i0 == 0, i1 == uv.size - 1


def block_sse(residual: np.ndarray, block: int, start: int = 0) -> np.ndarray:
    """Sum of squared residuals per consecutive block of ``block`` samples."""
    r = np.asarray(residual, dtype=float)[start:]
    block = max(1, int(block))
    nb = r.size // block
    if nb == 0:
        return np.array([float(np.sum(r * r))])
    return (r[: nb * block] ** 2).reshape(nb, block).sum(axis=1)


#: Interval width [% of span] that determines S or J whatever its size: about the
#: resolution of a valve positioner, below which no maintenance decision changes.
RESOLUTION_PCT = 0.1


def determinacy(S, S_iv, S_open, J, J_iv, J_open) -> dict[str, Determinacy]:
    """How well S and J are determined: interval width relative to the estimate.

    An interval narrower than :data:`RESOLUTION_PCT` determines the value even when
    the estimate is at or near zero (a healthy valve: S = 0 within 0.004 % is well
    determined, not poorly).
    """

    def one(v, iv, open_hi) -> Determinacy:
        width = iv[1] - iv[0]
        if open_hi:
            return Determinacy.OPEN
        if width <= RESOLUTION_PCT or (v > 0 and width <= 0.5 * v):
            return Determinacy.WELL
        if v > 0 and width <= 1.5 * v:
            return Determinacy.MODERATE
        return Determinacy.POOR

    return {"S": one(S, S_iv, S_open), "J": one(J, J_iv, J_open)}
