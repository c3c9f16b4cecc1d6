"""S and J without the valve position: a Hammerstein fit to op and pv.

Most plant data have no valve position (Section 3: only loops 1 and 4 had one).  The
valve model of Fig. 10 is then fitted together with a linear process, the valve
output feeding the process (a Hammerstein model, op -> valve(S, J) -> G(q) -> pv):

* for fixed (S, J) the valve output ``u = valve(op; S, J)`` is computed by the
  compiled flowchart and the linear part is linear in its parameters, so it is
  fitted by least squares;
* S and J are found by a coarse-to-fine grid search over (S, J), every grid point
  evaluated in one compiled batch.

The linear part
---------------
A first-order process with dead time and a direct part, the first-order-plus-dead-time
form of Eq. 3 and Table 3 of the paper, with the high-pass ``H`` (corner at four
cycle periods) applied to both sides::

    H pv[k] = b0 (H u)[k - d] + b1 (H lag_tau u)[k - d] + c0 + c1 a^k + c2 e^(-k/tau)

``b0`` and ``b1`` have one sign (a monotone step response: a process, not the inverse
of the PI controller, which an unconstrained fit to closed-loop data would find: with
Eq. 3's controller pv is a high-pass of op); ``d >= 1`` samples (op at sample k is
computed from pv at sample k, so the valve acts from the next one); ``tau`` and ``d``
are searched; the last three terms are free and carry what the start of the record
leaves (the high-pass and the process responding to their unknown state there).  The
high-pass removes drifts and set-point moves without changing the valve-to-pv
relation.  It is an output-error fit: the residual is what the model cannot reproduce
from op alone, not a one-step-ahead prediction error (which the last pv sample would
dominate, hiding the valve).

* Integrating processes (``integrating=True``, a level loop, Table 3): the
  integrator is taken out of pv by differencing it, ``pv[k] - pv[k-1]``, which the
  valve output drives directly; an unknown inflow imbalance or a load step at the
  process input then shows as a step that the high-pass removes instead of a ramp
  that lasts.  Differencing amplifies white noise, so a lag of a twentieth of a cycle
  is put on both sides of the model (the same linear filter on both sides leaves
  the relation unchanged).  (The compiled kernels also hold the undifferenced form,
  the integral seen through the high-pass, ``integrating=True``; it left load steps
  as lasting misfits.)
* Flow loops (``flow_loop=True``) get the self-regulating structure too.  Section
  5.3.1 takes pv in a liquid flow loop to be proportional to the valve opening, so a
  structure with a lag and a dead time of a few samples would do for the process;
  but without mv pv also carries the loads the controller fights, and in closed
  loop these make pv lag op by a phase that such a structure cannot give.  The
  valve model then supplies it: a deadband lags its input (the phase of the
  describing function, Section 6), so a healthy valve under an external
  oscillation was fitted as a sticky one that beats the linear valve on every
  cycle (simulated flow loops with a linear valve and a sinusoidal load on pv:
  six of six called stiction).  The self-regulating structure, whose dead time
  reaches half a cycle, leaves the phase to the linear part, and its false-alarm
  rate is the one measured by ``benchmarks/calibration_nomv.py``.

The valve model
---------------
Each fit tries the published flowchart and Kano's variant, on op itself and, when op
carries white noise, behind a play operator of four noise deviations
(:class:`stictiondiag.stiction.valvefit.ValveVariant`).  A record starts at an arbitrary point
of the valve's history, so the model is started stuck at the first clear extreme of
op with its stop point a searched offset back from it (:data:`START_OFFSETS`).

How well S and J are determined
-------------------------------
From the cost profile: the 95 % interval holds the values whose best cost (other
parameters free) is within an F-test threshold of the minimum, counting as many
independent observations as the fitted valve has slips, and never less than
:data:`MODEL_ERROR_SHARE` of the best cost, for the model's own error
(:func:`stictiondiag.stiction.valvefit.cost_threshold`).  That share is measured, not
assumed: ``benchmarks/calibration_nomv.py`` simulates loops with known S (white
noise, coloured loads, healthy valves under external oscillations) and prints how
often the interval holds the true S.
Without mv the breakaway point S trades off against the process dead time, and J
against the process gain when the valve never moves smoothly (then J is reported
unbounded); ``details["determinacy"]`` says "poorly determined" when the interval is
wide or reaches the search limit.

Known limit: a noisy op fed to a valve that sticks at every noise reversal (Kano's
flowchart on raw noisy op, as in :func:`stictiondiag.models.loops.simulate_loop` with noise)
makes the valve's sequence of stop points depend on every noise sample; a model
started from a slightly different point never falls back in step, the cost has a
needle at the true (S, J), and the grid search can miss it.  Such fits show as weak
or poorly determined, not as wrong with confidence.

Speed
-----
The search runs on op in units of its cycle travel (so that a fit does not depend on
the units of op).  Least-squares sums use every ``r``-th row, at least 60 rows per
cycle and at most :data:`MAX_ROWS` rows; the valve and the filters still run at the
full rate, so the breakaway timing keeps the full resolution of op.  Records longer
than :data:`MAX_SAMPLES` are fitted on their central part.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.core.jit import jit
from stictiondiag.stiction.segments import _determinacy
from stictiondiag.stiction.valvefit import (
    StictionFit,
    ValveVariant,
    block_sse,
    cost_threshold,
    cycle_samples,
    effective_samples,
    profile_interval,
    valve_run,
    valve_variants,
    white_noise_std,
)

#: Range of the process time constant searched, in oscillation periods, and the
#: number of (log-spaced) values on the coarse grid.
TAU_PERIODS = (0.01, 2.0)
N_TAUS = 8

#: Corner of the high-pass applied to pv and the regressors, in oscillation periods.
HIGHPASS_PERIODS = 4.0

#: Fewest regression rows per oscillation period (sets the row stride).
ROWS_PER_PERIOD = 60

#: Share of the best cost by which a parameter value's profile cost may exceed it
#: and still be inside the S, J and dead-time intervals, whatever the record length
#: (:func:`stictiondiag.stiction.valvefit.cost_threshold`).  The F test alone assumes the
#: model is right; here the valve model and the first-order linear part meet a
#: real loop only approximately, and a band a little wider or narrower moves whole
#: slips by a sample, so the cost at the true S exceeds the best one by a share of
#: the residual that does not shrink as slips accumulate (measured on simulated
#: loops: its 90th percentile is 0.2 to 0.46 of the best cost, with no trend, from
#: 20 to over 150 slips).  The F test alone held the true S in 59 % of them.  The share is the smallest
#: tenth that gives the nominal 95 % coverage of S on the calibration draw of
#: ``benchmarks/calibration_nomv.py`` (four PI loops, self-regulating and
#: integrating, S of 1 to 5 % of span, white noise and coloured loads, records of
#: 2000 and 4000 samples; ``--seed 7 --reps 2``); other seeds check it.
MODEL_ERROR_SHARE = 0.6


#: Longest dead time searched, as a fraction of the oscillation period.
MAX_DELAY_PERIODS = 0.5

#: Starting states tried: the valve is started stuck at the first extreme of op, its
#: stop point this far back from the extreme, in cycle travels of op (see
#: :func:`first_extreme`).  With a noisy op a sticky valve sticks again right after
#: every slip, so the point it stopped at is not the extreme of op, and a model
#: started from the wrong point stays out of step with the valve.
START_OFFSETS = (0.0, 0.01, 0.03, 0.1, 0.2, 0.4)

#: Half-cycles whose residual energy exceeds this many times the median are left out
#: of the fit (set-point moves and load steps the model cannot know).
OUTLIER_FACTOR = 8.0

#: Longest record fitted [samples]; longer records are fitted on their central part.
MAX_SAMPLES = 12_000

#: Most regression rows used (the row stride grows for longer records).
MAX_ROWS = 1200

#: Cost evaluations of the final Nelder-Mead polish.
POLISH_EVALUATIONS = 150

#: Share of samples the fitted valve must spend moving smoothly with op (Eq. 4) for
#: J to be told apart from the process gain.
MIN_MOVING_FRACTION = 0.02


# --------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------


@jit
def _lag(x, T, k0):
    """First-order lag, unit gain, time constant ``T`` [samples] (T <= 0: a copy),
    started in steady state at sample ``k0``; zero before ``k0``."""
    n = x.shape[0]
    y = np.zeros(n)
    if T <= 0.0:
        for k in range(k0, n):
            y[k] = x[k]
        return y
    a = math.exp(-1.0 / T)
    y[k0] = x[k0]
    for k in range(k0 + 1, n):
        y[k] = a * y[k - 1] + (1.0 - a) * x[k]
    return y


@jit
def _highpass(x, a, k0):
    """``(1 - q^-1) / (1 - a q^-1)`` started at rest at sample ``k0``; zero before."""
    n = x.shape[0]
    y = np.zeros(n)
    for k in range(k0 + 1, n):
        y[k] = a * y[k - 1] + x[k] - x[k - 1]
    return y


@jit
def _leaky_integral(x, a, k0):
    """``(1 - a) / (1 - a q^-1)`` applied to ``x - x[k0]`` from rest at ``k0``: an
    integrator seen through the high-pass ``(1 - q^-1) / (1 - a q^-1)``, scaled to unit
    gain at zero frequency; zero before ``k0``."""
    n = x.shape[0]
    y = np.zeros(n)
    for k in range(k0 + 1, n):
        y[k] = a * y[k - 1] + (1.0 - a) * (x[k] - x[k0])
    return y


#: Columns of the linear part (see :func:`_regressors`).
NCOL = 5


@jit
def _regressors(u, tau, integrating, a_hp, k0):
    """Columns of the linear part for one process time constant ``tau`` [samples].

    ``[F u, F lag(u, tau), 1, a^(k - k0), b^(k - k0)]`` with ``F`` the high-pass
    (self-regulating) or the integrator seen through the high-pass (integrating),
    ``a`` the high-pass pole and ``b = exp(-1/tau)`` the process pole.  The first two
    are the process (a direct part and a first-order lag, gains of one sign); the
    last three are free: a constant, the high-pass response to a step at the start,
    and the process's own response to its unknown state at the start (together they
    also carry an integrating process's unknown inflow imbalance).  Everything starts
    at sample ``k0``, so no history from before the start (where the valve state is
    unknown) enters.
    """
    n = u.shape[0]
    phi = np.zeros((n, NCOL))
    if integrating:
        g0 = _leaky_integral(u, a_hp, k0)
        g1 = _leaky_integral(_lag(u, tau, k0), a_hp, k0)
    else:
        g0 = _highpass(u, a_hp, k0)
        g1 = _highpass(_lag(u, tau, k0), a_hp, k0)
    b = math.exp(-1.0 / tau) if tau > 0.0 else 0.0
    e = 1.0
    f = 1.0
    for k in range(k0, n):
        phi[k, 0] = g0[k]
        phi[k, 1] = g1[k]
        phi[k, 2] = 1.0
        phi[k, 3] = e
        phi[k, 4] = f
        e *= a_hp
        f *= b
    return phi


@jit
def _normal_equations(u, taus, integrating, a_hp, k0, j0, j1, stride, keep, Y):
    """Normal equations of the linear part for every time constant and delay, in one pass.

    The columns are those of :func:`_regressors`, computed on the fly and kept only at
    the regression rows ``j = j0, j0 + stride, ... < j1`` whose ``keep`` flag is set;
    ``Y[r, i]`` is the target ``yf[j_r + delays[i]]`` of the r-th kept row.  Returns
    ``A[t]`` (5 x 5) and ``B[t]`` (5 x delays).
    """
    nt = taus.shape[0]
    n = u.shape[0]
    nr = Y.shape[0]
    phi = np.empty((nt, nr, NCOL))
    bl = np.empty(nt)
    for t in range(nt):
        bl[t] = math.exp(-1.0 / taus[t]) if taus[t] > 0.0 else 0.0
    lag = np.full(nt, u[k0])
    g1 = np.zeros(nt)
    free = np.ones(nt)
    g0 = 0.0
    e = 1.0
    u0 = u[k0]
    c = 1.0 - a_hp
    r = 0
    row = 0
    next_row = j0
    for k in range(k0, n):
        if k > k0:
            uk = u[k]
            if integrating:
                g0 = a_hp * g0 + c * (uk - u0)
                for t in range(nt):
                    lag[t] = bl[t] * lag[t] + (1.0 - bl[t]) * uk
                    g1[t] = a_hp * g1[t] + c * (lag[t] - u0)
                    free[t] *= bl[t]
            else:
                g0 = a_hp * g0 + uk - u[k - 1]
                for t in range(nt):
                    prev = lag[t]
                    lag[t] = bl[t] * prev + (1.0 - bl[t]) * uk
                    g1[t] = a_hp * g1[t] + lag[t] - prev
                    free[t] *= bl[t]
            e *= a_hp
        if k == next_row:
            if r >= nr or k >= j1:
                break
            next_row += stride
            row += 1
            if not keep[row - 1]:
                continue
            for t in range(nt):
                phi[t, r, 0] = g0
                phi[t, r, 1] = g1[t]
                phi[t, r, 2] = 1.0
                phi[t, r, 3] = e
                phi[t, r, 4] = free[t]
            r += 1
    A = np.empty((nt, NCOL, NCOL))
    B = np.empty((nt, NCOL, Y.shape[1]))
    for t in range(nt):
        P = phi[t]
        At = P.T @ P
        tr = 0.0
        for p in range(NCOL):
            tr += At[p, p]
        ridge = 1e-10 * tr / NCOL + 1e-300
        for p in range(NCOL):
            At[p, p] += ridge
        A[t] = At
        B[t] = P.T @ Y
    return A, B


@jit
def _solve_subset(A, b, idx, k, theta):
    """Solve ``A[idx, idx] theta = b[idx]`` (symmetric positive definite, k <= 8) by
    Cholesky; returns ``theta . b[idx]`` (the explained sum of squares) or -1.0 when
    the subsystem is singular."""
    L = np.zeros((8, 8))
    for i in range(k):
        for j in range(i + 1):
            s = A[idx[i], idx[j]]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            if i == j:
                if s <= 0.0:
                    return -1.0
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    z = np.empty(8)
    for i in range(k):
        s = b[idx[i]]
        for p in range(i):
            s -= L[i, p] * z[p]
        z[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, k):
            s -= L[p, i] * theta[p]
        theta[i] = s / L[i, i]
    e = 0.0
    for i in range(k):
        e += theta[i] * b[idx[i]]
    return e


@jit
def _same_sign_fit(A, b, yy, nb):
    """Least squares with the first ``nb`` (basis) gains of one common sign.

    The remaining columns are free.  A combination of first-order lags with gains of
    one sign has a monotone step response: a process, and not the inverse of the
    controller, which an unconstrained fit to closed-loop data finds instead (through
    the PI law of Eq. 3, pv is a high-pass of op).  Solved exactly by enumerating the
    active sets (at most 2^4 small systems).  Returns the sum of squared residuals.
    """
    m = A.shape[0]
    idx = np.empty(8, dtype=np.int64)
    theta = np.empty(8)
    best = yy
    for mask in range(0, 1 << nb):
        k = 0
        for i in range(nb):
            if mask & (1 << i):
                idx[k] = i
                k += 1
        kb = k
        for i in range(nb, m):
            idx[k] = i
            k += 1
        e = _solve_subset(A, b, idx, k, theta)
        if e < 0.0:
            continue
        pos = True
        neg = True
        for i in range(kb):
            if theta[i] < 0.0:
                pos = False
            if theta[i] > 0.0:
                neg = False
        if (pos or neg) and yy - e < best:
            best = yy - e
    return max(best, 0.0)


@jit
def _batch_cost(
    x,
    S_arr,
    J_arr,
    offsets,
    taus,
    kano,
    k_start,
    d_start,
    integrating,
    a_hp,
    j0,
    j1,
    stride,
    keep,
    Y,
    yy,
    pre_lag,
):
    """Best cost over start offsets, process time constants and delays for every (S, J).

    ``Y[r, i]`` is the high-passed pv at regression row ``r`` shifted by delay ``i``
    and ``yy[i]`` its sum of squares; ``pre_lag`` [samples] a lag applied to the valve
    output first (the same lag the target went through; 0: none).  Returns the cost
    and, for each pair, the indices of the best delay, start offset and time
    constant.
    """
    m = S_arr.shape[0]
    cost = np.empty(m)
    best_d = np.zeros(m, dtype=np.int64)
    best_o = np.zeros(m, dtype=np.int64)
    best_t = np.zeros(m, dtype=np.int64)
    nt = taus.shape[0]
    nd = Y.shape[1]
    for i in range(m):
        cost[i] = np.inf
        for io in range(offsets.shape[0]):
            u, _ = valve_run(x, S_arr[i], J_arr[i], kano, k_start, d_start, offsets[io])
            if pre_lag > 0.0:
                u = _lag(u, pre_lag, k_start)
            A, B = _normal_equations(u, taus, integrating, a_hp, k_start, j0, j1, stride, keep, Y)
            for t in range(nt):
                for k in range(nd):
                    sse = _same_sign_fit(A[t], B[t, :, k], yy[k], 2)
                    if sse < cost[i]:
                        cost[i] = sse
                        best_d[i] = k
                        best_o[i] = io
                        best_t[i] = t
            if S_arr[i] == 0.0:
                break  # a linear valve has no stuck state to start from
    return cost, best_d, best_o, best_t


# --------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------


def _check(op, pv, dt) -> tuple[np.ndarray, np.ndarray, float]:
    op = np.asarray(op, dtype=float)
    pv = np.asarray(pv, dtype=float)
    if op.ndim != 1 or pv.ndim != 1 or op.shape != pv.shape:
        raise DataError(
            f"op and pv must be one-dimensional and of equal length, got {op.shape} and {pv.shape}"
        )
    if op.size < 50:
        raise DataError(f"only {op.size} samples of op and pv: need at least 50 for a fit")
    if not (np.all(np.isfinite(op)) and np.all(np.isfinite(pv))):
        raise DataError("op or pv contains NaN or inf: fill or drop the gaps first")
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise DataError(f"sampling time must be a number, got {dt!r}") from None
    if not (dt > 0 and math.isfinite(dt)):
        raise DataError(f"sampling time must be positive, got {dt}")
    if np.ptp(op) <= 0:
        raise DataError("op is constant: the valve demand never moves, nothing to fit")
    if np.ptp(pv) <= 0:
        raise DataError("pv is constant: nothing to fit")
    return op, pv, dt


def _moving_average(x: np.ndarray, width: int) -> np.ndarray:
    if width <= 1:
        return x.copy()
    k = np.ones(width) / width
    pad = width // 2
    xp = np.concatenate((np.full(pad, x[0]), x, np.full(width - 1 - pad, x[-1])))
    return np.convolve(xp, k, mode="valid")


def first_extreme(op: np.ndarray, period: int) -> tuple[int, float]:
    """Sample of the first clear extreme of op, and the direction of travel into it.

    A sticky valve in a limit cycle has slipped on the way to an extreme of op
    (Figs. 12 and 14) and is stuck when op turns, so the model is started there,
    stuck, its last movement in the direction of travel.  The extreme is taken on op
    smoothed over an eighth of a period; (0, 0.0) when op has none.
    """
    n = op.size
    win = min(n, max(3, int(1.5 * period)))
    s = _moving_average(op[:win], max(1, period // 8))
    edge = max(2, period // 16)
    cand = []
    for k, d in ((int(np.argmax(s)), 1.0), (int(np.argmin(s)), -1.0)):
        if edge <= k < win - edge:
            cand.append((k, d))
    if not cand:
        return 0, 0.0
    k, d = min(cand)
    # The recorded op at the extreme, not the smoothed one: the valve saw the former.
    lo, hi = max(0, k - edge), min(n, k + edge + 1)
    seg = op[lo:hi]
    k = lo + int(np.argmax(d * seg))
    return k, d


def _delay_grid(d_max: int, n_coarse: int = 14) -> np.ndarray:
    """Coarse dead times [samples], log-spaced from 1 to ``d_max``: the same relative
    resolution for a short dead time as for a long one."""
    d_max = max(1, int(d_max))
    if d_max <= n_coarse:
        return np.arange(1, d_max + 1, dtype=np.int64)
    return np.unique(np.round(np.geomspace(1, d_max, n_coarse)).astype(np.int64))


def _same_sign_lstsq(X: np.ndarray, y: np.ndarray, nb: int) -> np.ndarray:
    """Parameters of :func:`_same_sign_fit` (first ``nb`` gains of one sign)."""
    m = X.shape[1]
    best, best_theta = np.inf, np.zeros(m)
    for mask in range(0, 1 << nb):
        cols = [i for i in range(nb) if mask & (1 << i)] + list(range(nb, m))
        th, *_ = np.linalg.lstsq(X[:, cols], y, rcond=None)
        g = th[: len(cols) - (m - nb)]
        if g.size and not (np.all(g >= 0) or np.all(g <= 0)):
            continue
        sse = float(np.sum((y - X[:, cols] @ th) ** 2))
        if sse < best:
            best = sse
            best_theta = np.zeros(m)
            best_theta[cols] = th
    return best_theta


class _Problem:
    """Everything the cost of one (S, J) needs, fixed for one fit.

    Regression rows are ``j0, j0 + stride, ... < j1``; ``j1`` leaves room for the
    longest dead time, so every delay uses the same rows.
    """

    def __init__(self, x, yf, taus, integrating, a_hp, k_start, d_start, j0, j1, stride, delays):
        self.x, self.yf = x, yf
        self.taus = np.asarray(taus, dtype=float)
        self.integrating, self.a_hp = bool(integrating), float(a_hp)
        self.k_start, self.d_start = int(k_start), float(d_start)
        self.j0, self.j1, self.stride = int(j0), int(j1), int(stride)
        self.all_rows = np.arange(self.j0, self.j1, self.stride, dtype=np.int64)
        self.keep = np.ones(self.all_rows.size, dtype=np.bool_)
        self.rows = self.all_rows
        self.inputs: dict[str, np.ndarray] = {}
        self.pre_lag = 0.0
        self.set_delays(delays)

    def set_delays(self, delays):
        self.delays = np.asarray(delays, dtype=np.int64)
        self.Y = np.ascontiguousarray(self.yf[self.rows[:, None] + self.delays[None, :]])
        self.yy = np.sum(self.Y**2, axis=0)

    def set_keep(self, keep):
        """Leave out the regression rows whose flag is False."""
        self.keep = np.asarray(keep, dtype=np.bool_)
        self.rows = self.all_rows[self.keep]
        self.set_delays(self.delays)

    def cost(self, S, J, variant: ValveVariant, offsets):
        """Cost, best delay, start offset and time constant for every (S, J) pair.

        Pairs with a band narrower than the play operator are run without it
        (:meth:`stictiondiag.stiction.valvefit.ValveVariant.for_band`).
        """
        S = np.atleast_1d(np.asarray(S, dtype=float))
        J = np.atleast_1d(np.asarray(J, dtype=float))
        off = np.atleast_1d(np.asarray(offsets, dtype=float))
        parts = variant.band_parts(S)
        if len(parts) == 1:
            return self._cost(S, J, parts[0][1], off)
        out = [np.empty(S.size), np.empty(S.size, np.int64), np.empty(S.size), np.empty(S.size)]
        for mask, v in parts:
            part = self._cost(S[mask], J[mask], v, off)
            for o, p in zip(out, part, strict=True):
                o[mask] = p
        return out[0], out[1], out[2], out[3]

    def _input(self, variant: ValveVariant) -> np.ndarray:
        """The op that ``variant`` runs on (prepared once per variant)."""
        x = self.inputs.get(variant.name)
        if x is None:
            x = self.inputs[variant.name] = variant.prepare(self.x)
        return x

    def _cost(self, S, J, variant: ValveVariant, off):
        x = self._input(variant)
        c, bd, bo, bt = _batch_cost(
            x,
            variant.model_S(S),
            J,
            off,
            self.taus,
            variant.kano,
            self.k_start,
            self.d_start,
            self.integrating,
            self.a_hp,
            self.j0,
            self.j1,
            self.stride,
            self.keep,
            self.Y,
            self.yy,
            self.pre_lag,
        )
        return c, self.delays[bd], off[bo], self.taus[bt]

    def residual(self, S, J, variant: ValveVariant, delay, offset, tau):
        """Residual on the regression rows, fitted parameters and valve output."""
        variant = variant.for_band(float(S))
        x = self._input(variant)
        u, n_slips = valve_run(
            x,
            float(variant.model_S(S)),
            float(J),
            variant.kano,
            self.k_start,
            self.d_start,
            float(offset),
        )
        uf = _lag(u, self.pre_lag, self.k_start) if self.pre_lag > 0 else u
        phi = _regressors(uf, float(tau), self.integrating, self.a_hp, self.k_start)
        X = phi[self.rows]
        y = self.yf[self.rows + int(delay)]
        theta = _same_sign_lstsq(X, y, 2)
        return y - X @ theta, theta, u, n_slips


def _grid(S_lo, S_hi, J_lo, J_hi, n):
    Sg = np.linspace(S_lo, S_hi, n)
    Jg = np.linspace(J_lo, J_hi, n)
    SS, JJ = np.meshgrid(Sg, Jg, indexing="ij")
    return SS.ravel(), JJ.ravel(), Sg[1] - Sg[0], Jg[1] - Jg[0]


def cycle_travel(x: np.ndarray, period: int) -> float:
    """Typical peak-to-peak travel of ``x`` over a cycle [units of x].

    The 90th percentile of the ranges of windows two periods long of ``x`` detrended
    by a running median over three periods: a bound on the band S of a sticky valve
    that slips every cycle, without the load moves of op that a range of the whole
    record would include.
    """
    from stictiondiag.core.filters import median_filter_nearest

    xd = x - median_filter_nearest(x, max(3, int(3 * period) | 1))
    m = max(2, int(2 * period))
    nw = xd.size // m
    if nw < 1:
        return float(np.ptp(xd))
    w = xd[: nw * m].reshape(nw, m)
    return float(np.percentile(w.max(axis=1) - w.min(axis=1), 90))


def _ordinary_blocks(resid: np.ndarray, block: int) -> np.ndarray:
    """Rows to keep: those outside blocks whose residual energy exceeds
    :data:`OUTLIER_FACTOR` times the median block energy.  Keeps everything when that
    would leave out more than 10 % of the rows: set-point moves and load steps are
    isolated events, a misfit spread over many blocks is the model's own."""
    n = resid.size
    nb = max(1, n // block)
    e = np.array([np.sum(resid[i * block : (i + 1) * block] ** 2) for i in range(nb)])
    keep = np.ones(n, dtype=bool)
    med = float(np.median(e))
    if not med > 0:
        return keep
    for i in np.flatnonzero(e > OUTLIER_FACTOR * med):
        keep[i * block : n if i == nb - 1 else (i + 1) * block] = False
    return keep if keep.mean() >= 0.9 else np.ones(n, dtype=bool)


def _delay_window(d_best: int, d_max: int, half: int, most: int) -> np.ndarray:
    """Dead times within ``half`` of ``d_best`` (at most ``most``, evenly spread)."""
    d = np.arange(max(1, d_best - half), min(d_max, d_best + half) + 1, dtype=np.int64)
    if d.size > most:
        d = np.unique(np.round(np.linspace(d[0], d[-1], most)).astype(np.int64))
    return d


def _setup(op, pv, dt, integrating, period_s) -> dict:
    """Time scales, structure, start and the least-squares problem of a fit."""
    n = op.size
    op_mean = float(np.mean(op))
    x = op - op_mean  # the valve model is shift-equivariant; centring helps the sums
    y = (pv - np.mean(pv)) / np.std(pv)
    if period_s is not None and period_s > 0 and math.isfinite(period_s):
        period = int(max(4, min(round(period_s / dt), n // 3)))
    else:
        period = cycle_samples(op)
    stride = max(1, period // ROWS_PER_PERIOD, -(-n // MAX_ROWS))
    a_hp = math.exp(-1.0 / (HIGHPASS_PERIODS * period))

    # A flow loop gets the self-regulating structure (see "The linear part").
    structure = "integrating" if integrating else "self-regulating"
    taus = np.geomspace(max(0.3, period * TAU_PERIODS[0]), period * TAU_PERIODS[1], N_TAUS)
    d_max = max(1, min(int(MAX_DELAY_PERIODS * period), n // 4))
    coarse_delays = _delay_grid(d_max)

    k_start, d_start = first_extreme(x, period)
    # Both sides of the model start at k_start; the process's own response to its
    # unknown state there dies out within half a period or so.
    yf = _highpass(y, a_hp, k_start)
    j0 = k_start + max(1, period // 2)
    j1 = n - d_max
    if (j1 - j0) // stride < 30:
        raise DataError(
            f"record too short for a Hammerstein fit: {n} samples with a {period}-sample "
            "cycle; record at least three cycles"
        )
    # The search runs on op in units of its typical cycle travel, so that a fit is
    # exactly the same whatever the units of op (STYLE.md invariant); S and J are
    # scaled back at the end.
    scale = cycle_travel(x, period)
    if not scale > 0:
        scale = float(np.ptp(x))
    x = x / scale
    pre_lag = 0.0
    if integrating:
        # The integrator is taken out of pv (its increments are driven by the valve
        # directly), so an unknown inflow imbalance or a load step at the process
        # input no longer leaves a lasting ramp.  Differencing amplifies white noise;
        # a lag of a twentieth of a cycle on both sides of the model takes it back.
        pre_lag = max(0.0, period / 20.0)
        dy = np.diff(y, prepend=y[0])
        dy = _lag(dy, pre_lag, 0) if pre_lag > 0 else dy
        dy_std = float(dy.std())
        if not dy_std > 0:
            raise DataError("pv of the integrating loop never changes: nothing to fit")
        yf = _highpass((dy - dy.mean()) / dy_std, a_hp, k_start)
        # White noise on pv through the difference and the lag, in target units.
        impulse = np.zeros(int(20 * pre_lag) + 10)
        impulse[1] = 1.0
        h = _lag(np.diff(impulse, prepend=0.0), pre_lag, 0)
        noise_var = white_noise_std(y) ** 2 * float(np.sum(h**2)) / dy_std**2
    else:
        noise_var = white_noise_std(y) ** 2
    prob = _Problem(x, yf, taus, False, a_hp, k_start, d_start, j0, j1, stride, coarse_delays)
    prob.pre_lag = pre_lag
    S_max = float(min(1.25, np.ptp(x)))

    return {
        "problem": prob,
        "structure": structure,
        "period": period,
        "x": x,
        "n": n,
        "stride": stride,
        "d_max": d_max,
        "coarse_delays": coarse_delays,
        "taus": taus,
        "scale": scale,
        "noise_var": noise_var,
        "S_max": S_max,
        "a_hp": a_hp,
    }


def fit_hammerstein(
    op: np.ndarray,
    pv: np.ndarray,
    dt: float,
    *,
    integrating: bool,
    flow_loop: bool,
    period_s: float | None = None,
) -> StictionFit:
    """S and J from op and pv by fitting valve model and linear process together.

    Parameters
    ----------
    op : ndarray
        Controller output / valve demand [% of span].
    pv : ndarray
        Controlled variable [any units; scaled to unit variance inside].
    dt : float
        Sampling time [s].
    integrating : bool
        The process integrates (level loop): the linear part includes an integrator.
    flow_loop : bool
        The loop is a flow loop (Section 5.3.1).  It is fitted with the
        self-regulating structure, whose lags and dead times include a flow loop's
        (see "The linear part" in the module docstring); recorded in ``details``.
    period_s : float, optional
        Cycle period [s] that sets the time scales of the linear basis and the row
        stride; by default measured on op (:func:`stictiondiag.stiction.valvefit.cycle_samples`).

    Returns
    -------
    StictionFit
        ``method="hammerstein"``; costs are sums of squared residuals of the
        high-passed, unit-variance pv.  ``details`` holds the linear part (dead time,
        basis), the valve model variant, determinacy and per-cycle costs.

    Notes
    -----
    Search, every cost minimised over the dead times, process time constants and
    start offsets of the current sets:

    1. every valve variant and start offset on a 9 x 9 (S, J) grid with three time
       constants and log-spaced dead times up to half a cycle; the five best cells of
       each variant then with every time constant: this picks the variant, the start
       offset (kept from here on, with offset 0), the time constant and the dead
       time;
    2. an 11 x 11 grid with time constants and dead times around those, then two
       zooms of 7 x 7 around each of the three best cells;
    3. dead times at one-sample resolution and a finer time constant around the best,
       two more zooms; finally a Nelder-Mead polish of S, J and the time constant.

    S and J are searched up to 1.25 times the typical cycle travel of op.  The profile
    intervals use only the points of steps 2 and 3, whose dead times adapt to S.
    """
    op, pv, dt = _check(op, pv, dt)
    n_in = op.size
    # Very long records: the central MAX_SAMPLES samples (the fit's cost grows with
    # the record; tens of cycles are plenty).
    first = max(0, (n_in - MAX_SAMPLES) // 2)
    op_fit, pv_fit = op[first : first + MAX_SAMPLES], pv[first : first + MAX_SAMPLES]
    setup = _setup(op_fit, pv_fit, dt, integrating, period_s)
    prob, structure, period = setup["problem"], setup["structure"], setup["period"]
    x, stride, d_max = setup["x"], setup["stride"], setup["d_max"]
    coarse_delays, taus, scale = setup["coarse_delays"], setup["taus"], setup["scale"]
    S_max = J_max = setup["S_max"]  # in cycle travels of op, like every S and J below
    op_mean, op_std = float(np.mean(op_fit)), float(np.std(op))
    offsets_all = np.array(START_OFFSETS)

    # 1. Valve variant, start offset, process time constant and dead time on a coarse
    #    grid.
    SS, JJ, _, _ = _grid(0.0, S_max, 0.0, J_max, 9)
    variants = {v.name: v for v in valve_variants(x)}
    if any(v.play_width > 0 for v in variants.values()):
        # On a noisy op the published flowchart re-arms at every noise reversal and
        # never slips, and behind the play operator it differs from Kano's variant
        # only in rare partial reversals: not worth their evaluations.
        variants.pop("choudhury")
        variants.pop("choudhury+play")
    # 1a. Every variant and start offset on the coarse grid, with three process time
    #     constants and every second regression row.
    prob1 = _Problem(
        prob.x,
        prob.yf,
        np.geomspace(prob.taus[0], prob.taus[-1], 3),
        prob.integrating,
        prob.a_hp,
        prob.k_start,
        prob.d_start,
        prob.j0,
        prob.j1,
        2 * prob.stride,
        prob.delays,
    )
    prob1.pre_lag = prob.pre_lag
    coarse = {name: prob1.cost(SS, JJ, v, offsets_all) for name, v in variants.items()}
    n_eval = len(coarse) * SS.size * offsets_all.size
    # 1b. The five best cells of each variant with every time constant.
    prob1.taus = prob.taus
    best1 = (np.inf, None, 0, 0.0, 0.0, 0.0, 0.0)
    for name, (c1, _, o1, _) in coarse.items():
        top = np.argsort(c1)[:5]
        for k in top:
            c, d, o, t = prob1.cost(SS[k], JJ[k], variants[name], o1[k])
            n_eval += 1
            if c[0] < best1[0]:
                best1 = (float(c[0]), name, int(d[0]), float(o[0]), float(t[0]), SS[k], JJ[k])
    _, model, d_best, off_best, tau_best, S1, J1 = best1
    variant = variants[model]

    # Half-cycles the model cannot explain at all (set-point moves, load steps at
    # the process input) are left out from here on.
    resid1, *_ = prob.residual(S1, J1, variant, d_best, off_best, tau_best)
    keep = _ordinary_blocks(resid1, max(2, period // (2 * stride)))
    n_left_out = int(keep.size - keep.sum())
    if n_left_out:
        prob.set_keep(keep)

    # From here on: the best start offset and the plain one (stuck at the extreme).
    k_off = int(np.argmin(np.abs(offsets_all - off_best)))
    offsets = np.unique(offsets_all[[0, k_off]])

    pts: dict[str, list] = {k: [] for k in "SJCDOT"}

    def evaluate(S_arr, J_arr):
        nonlocal n_eval
        c, bd, bo, bt = prob.cost(S_arr, J_arr, variant, offsets)
        for k, v in zip("SJCDOT", (S_arr, J_arr, c, bd, bo, bt), strict=True):
            pts[k].append(v)
        n_eval += S_arr.size * offsets.size
        return c

    def zoom(sb, jb, ds, dj, levels):
        for _ in range(levels):
            Sz, Jz, zs, zj = _grid(
                max(0.0, sb - ds), min(S_max, sb + ds), max(0.0, jb - dj), min(J_max, jb + dj), 7
            )
            c = evaluate(Sz, Jz)
            k = int(np.argmin(c))
            sb, jb = Sz[k], Jz[k]
            ds, dj = 2 * zs, 2 * zj

    def best():
        k = int(np.argmin(np.concatenate(pts["C"])))
        return tuple(np.concatenate(pts[key])[k] for key in "SJDT")

    # 2. Time constants and dead times near the best ones; grid and zooms.
    delays = _delay_window(d_best, d_max, max(3, d_best // 2), 9)
    prob.taus = tau_best * np.array([0.5, 0.75, 1.0, 1.33, 2.0])
    prob.set_delays(delays)
    SS, JJ, step_s, step_j = _grid(0.0, S_max, 0.0, J_max, 11)
    c = evaluate(SS, JJ)
    for k in np.argsort(c)[:3]:
        zoom(SS[k], JJ[k], 2 * step_s, 2 * step_j, 2)

    # 3. Dead time at one-sample resolution and a finer time constant near the best
    #    pair, then zoom again.
    sb, jb, d_best, tau_best = best()
    spacing = int(np.max(np.diff(delays))) if delays.size > 1 else 1
    prob.set_delays(_delay_window(int(d_best), d_max, max(2, spacing), 9))
    prob.taus = float(tau_best) * np.array([0.9, 1.0, 1.11])
    zoom(sb, jb, 2 * step_s / 3, 2 * step_j / 3, 2)

    # 4. Local polish: Nelder-Mead over S, J and the time constant (continuous), the
    #    dead time free within two samples of the best and the start offset fixed.
    sb, jb, d_best, tau_best = best()
    k = int(np.argmin(np.concatenate(pts["C"])))
    offsets = np.array([np.concatenate(pts["O"])[k]])
    prob.set_delays(_delay_window(int(d_best), d_max, 2, 5))

    # The time constant stays inside the structure's range (TAU_PERIODS, or where
    # the grids of steps 2 and 3 took it): outside it the basis is no longer the
    # structure's process, and an unbounded polish found lags of hundreds of cycles, integrators
    # through which a deadband imitates a load on pv that op does not drive.
    tau_lo = min(float(taus.min()), float(tau_best))
    tau_hi = max(float(taus.max()), float(tau_best))

    def objective(v):
        S_v, J_v = min(max(v[0], 0.0), S_max), min(max(v[1], 0.0), J_max)
        prob.taus = np.array([min(max(float(tau_best) * math.exp(v[2]), tau_lo), tau_hi)])
        return float(evaluate(np.array([S_v]), np.array([J_v]))[0])

    from scipy.optimize import minimize

    zs = 2 * step_s / 27
    zj = 2 * step_j / 27
    simplex = np.array([[sb, jb, 0.0], [sb + zs, jb, 0.0], [sb, jb + zj, 0.0], [sb, jb, 0.05]])
    minimize(
        objective,
        simplex[0],
        method="Nelder-Mead",
        options={"initial_simplex": simplex, "maxfev": POLISH_EVALUATIONS, "xatol": 1e-4},
    )

    S_all, J_all, C_all, D_all, O_all, T_all = (np.concatenate(pts[k]) for k in "SJCDOT")
    i = int(np.argmin(C_all))
    S_hat, J_hat, cost = float(S_all[i]), float(J_all[i]), float(C_all[i])
    delay, offset, tau = int(D_all[i]), float(O_all[i]), float(T_all[i])

    # The linear valve gets every time constant and dead time searched, the stiction
    # fit's own, and the same continuous polish of the time constant, so it is not
    # handicapped: the improvement compares the two valves, not two searches.
    linear = ValveVariant("linear", False)
    prob.set_delays(np.union1d(coarse_delays, prob.delays))
    prob.taus = np.union1d(taus, [tau])
    lin_c, lin_d, _, lin_t = prob.cost(0.0, 0.0, linear, 0.0)
    lin_best = (float(lin_c[0]), int(lin_d[0]), float(lin_t[0]))

    def lin_objective(log_tau):
        nonlocal lin_best
        prob.taus = np.array([math.exp(log_tau)])
        c_l, d_l, _, t_l = prob.cost(0.0, 0.0, linear, 0.0)
        if c_l[0] < lin_best[0]:
            lin_best = (float(c_l[0]), int(d_l[0]), float(t_l[0]))
        return float(c_l[0])

    from scipy.optimize import minimize_scalar

    lt0 = math.log(lin_best[2])
    minimize_scalar(
        lin_objective,
        bounds=(
            max(lt0 - math.log(3.0), math.log(tau_lo)),
            min(lt0 + math.log(3.0), math.log(tau_hi)),
        ),
        method="bounded",
        options={"maxiter": 30, "xatol": 0.01},
    )
    linear_cost, lin_delay, lin_tau = lin_best
    lin_resid, *_ = prob.residual(0.0, 0.0, linear, lin_delay, 0.0, lin_tau)
    resid, theta, mv_model, n_slips = prob.residual(S_hat, J_hat, variant, delay, offset, tau)

    # Independent evidence on S and J comes from the breakaways: each slip is one
    # observation of the band.  Counting residual samples instead (even decorrelated
    # ones) would make the interval as narrow as the noise allows, while what limits
    # the fit is how well the slips are placed.
    n_eff_resid = effective_samples(resid)
    n_eff = float(min(n_eff_resid, max(n_slips, 1) + 3))
    # White measurement noise on pv, in the units of the cost (pv scaled to unit
    # variance; the slow high-pass leaves white noise as it is): a diagnostic only.
    noise_cost = setup["noise_var"] * resid.size
    thr = cost_threshold(cost, n_eff, 3, model_error=MODEL_ERROR_SHARE)
    S_iv, _, S_open = profile_interval(S_all, C_all, thr, 0.0, S_max)
    J_iv, _, J_open = profile_interval(J_all, C_all, thr, 0.0, J_max)
    d_iv, _, _ = profile_interval(D_all.astype(float), C_all, thr, 1.0, float(d_max))
    n_par = NCOL + 5  # linear columns; S, J, dead time, time constant, offset

    # The flowchart that ran at the estimate: a band narrower than the play
    # operator runs on the raw op (ValveVariant.for_band).
    variant = variant.for_band(S_hat)
    model = variant.name

    # Without a smooth moving phase the valve output is a square wave whose height
    # is J (Eq. 4): the process gain scales it, so J cannot be told apart from the
    # gain.  Then only its bounds are known.
    x_valve = variant.prepare(x)
    k_s = prob.k_start
    dmv, dx = np.diff(mv_model[k_s:]), np.diff(x_valve[k_s:])
    moving = np.abs(dmv - dx) <= 1e-9 * max(float(np.ptp(x)), 1e-300)
    moving &= np.abs(dmv) > 0
    moving_fraction = float(moving.mean()) if moving.size else 0.0
    J_confounded = moving_fraction < MIN_MOVING_FRACTION and S_hat > 0
    if J_confounded:
        J_iv, J_open = (0.0, J_max), True

    # Valve output over the whole record, from the same starting state.
    if first > 0 or op_fit.size < n_in:
        S_model = float(variant.model_S(S_hat))
        mv_model, _ = valve_run(
            variant.prepare((op - op_mean) / scale),
            S_model,
            J_hat,
            variant.kano,
            first + prob.k_start,
            prob.d_start,
            offset,
        )

    # Back from cycle travels to the units of op.
    S_hat, J_hat = S_hat * scale, J_hat * scale
    S_iv = (S_iv[0] * scale, S_iv[1] * scale)
    J_iv = (J_iv[0] * scale, J_iv[1] * scale)
    block = max(2, period // stride)
    details = {
        "valve_model": model,
        "play_width": variant.play_width * scale,
        "structure": structure,
        "period_samples": period,
        "row_stride": stride,
        "rows_left_out": n_left_out,
        "dead_time_s": delay * dt,
        "dead_time_interval_s": [d_iv[0] * dt, d_iv[1] * dt],
        "linear_valve_dead_time_s": float(lin_delay) * dt,
        "time_constant_s": tau * dt,
        "process_gains": {"direct": float(theta[0]), "lag": float(theta[1])},
        "highpass_corner_s": HIGHPASS_PERIODS * period * dt,
        "search_limit": S_max * scale,
        "start_sample": first + prob.k_start,
        "fitted_samples": [first, first + op_fit.size],
        "start_offset": offset * scale,
        "cost_by_valve_model_coarse": {k: float(v[0].min()) for k, v in coarse.items()},
        "determinacy": _determinacy(S_hat, S_iv, S_open, J_hat, J_iv, J_open),
        "interval_method": (
            "95 % profile-cost interval over the grid search (F test, as many independent "
            f"observations as slips, at least {MODEL_ERROR_SHARE:g} of the best cost for "
            "the model's own error, as measured on simulated loops); J unbounded when the "
            "valve never moves smoothly"
        ),
        "effective_samples": n_eff,
        "effective_samples_residual": n_eff_resid,
        "noise_cost": noise_cost,
        "explained": 1.0 - cost / max(float(np.sum(prob.yf[prob.rows + delay] ** 2)), 1e-300),
        "moving_fraction": moving_fraction,
        "J_confounded_with_gain": bool(J_confounded),
        "n_samples": int(resid.size),
        "n_parameters": {"stiction": n_par, "linear": n_par - 2},
        "block_samples": block,
        "block_sse": {
            "stiction": block_sse(resid, block).tolist(),
            "linear": block_sse(lin_resid, block).tolist(),
        },
        "n_evaluations": int(n_eval),
    }
    if integrating and flow_loop:
        details["note"] = "loop type flow but integrating: the integrating structure was used"
    elif flow_loop:
        details["note"] = (
            "flow loop: fitted with the self-regulating structure, whose dead time reaches "
            "half a cycle, so that a load the controller fights is not blamed on the valve"
        )
    return StictionFit(
        S=S_hat,
        J=J_hat,
        S_scaled=S_hat / op_std,
        J_scaled=J_hat / op_std,
        S_interval=S_iv,
        J_interval=J_iv,
        method="hammerstein",
        mv_model=mv_model * scale + op_mean,
        n_slips=int(n_slips),
        cost=cost,
        linear_cost=linear_cost,
        details=details,
    )
