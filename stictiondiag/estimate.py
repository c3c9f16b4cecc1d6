"""Stiction parameters S and J from plant data, and the stiction verdict.

The data-driven valve model of Choudhury, Thornhill & Shah (2005), Section 5.1 and
Fig. 10, has two parameters, both in % of span: ``S`` (deadband plus stickband, on
the input axis) and ``J`` (slip jump, on the output axis).  They are estimated in one
of two ways:

* from the valve's own position ``mv`` when it is recorded
  (:func:`stictiondiag.segments.estimate_from_mv`): the stick and slip segments of the
  mv-op plot (Figs. 2-3 and 6), refined by a least-squares fit of the model to ``mv``;
* from ``op`` and ``pv`` alone (:func:`stictiondiag.hammerstein.fit_hammerstein`): the
  valve model in series with a linear process (a Hammerstein model), fitted together.

Both return a :class:`StictionFit`.  :func:`stiction_verdict` then asks the question of
Section 5.3: is there an oscillation, and does the stiction model explain it better
than a linear valve, by how much, and how consistently over the cycles.

This module also holds what the two estimators share: the compiled batch evaluation
of the valve model over many (S, J) pairs, the effective number of independent
samples of a residual, and the profile-cost intervals.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._jit import jit
from .valve import choudhury_step, kano_step, valve_state

#: Width of the play operator that keeps noise reversals of op away from the valve
#: model, in robust noise standard deviations of op (see :func:`valve_variants`).
PLAY_WIDTH_SIGMAS = 4.0

#: Coverage of the reported S and J intervals (profile-cost intervals, F test).
INTERVAL_LEVEL = 0.95


# --------------------------------------------------------------------------------------
# Result dataclasses
# --------------------------------------------------------------------------------------


def _plain(v: Any) -> Any:
    """JSON-able copy: numpy scalars -> float/int, NaN/inf -> None, arrays -> lists."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray):
        return [_plain(x) for x in v.tolist()]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f if math.isfinite(f) else None
    return v


@dataclass(frozen=True)
class StictionFit:
    """Estimated stiction parameters of the data-driven model (Section 5.1).

    Attributes
    ----------
    S : float
        Deadband plus stickband [% of op span].
    J : float
        Slip jump [% of op span] (the model's output axis is in the units of op).
    S_scaled, J_scaled : float
        S and J divided by the standard deviation of op [units of scaled op, as in the
        mean-centred unit-variance plots of Section 3].
    S_interval, J_interval : tuple of float, or None
        Interval [% of op span] of the values the data cannot tell apart from the
        estimate (see ``details["interval_method"]``); None when not determined.
    method : str
        ``"mv_segments"`` (valve position recorded) or ``"hammerstein"`` (op and pv).
    mv_model : ndarray
        Fitted valve position for the recorded op [% of span].
    n_slips : int
        Number of slips (breakaways) of the fitted valve over the record [-].
    cost : float
        Sum of squared residuals of the stiction model (mv fit: [% of span]^2;
        Hammerstein fit: [scaled pv]^2, pv scaled to unit variance).
    linear_cost : float
        The same cost with a linear valve (S = J = 0), fitted the same way.
    details : dict
        Method-specific, JSON-able diagnostics: both estimates of the mv method,
        determinacy, the valve model variant, per-cycle costs used by the verdict.
    """

    S: float
    J: float
    S_scaled: float
    J_scaled: float
    S_interval: tuple[float, float] | None
    J_interval: tuple[float, float] | None
    method: str
    mv_model: np.ndarray = field(repr=False)
    n_slips: int
    cost: float
    linear_cost: float
    details: dict = field(default_factory=dict, repr=False)

    @property
    def improvement(self) -> float | None:
        """Fraction of the linear valve's residual removed by the stiction model [-]."""
        if not (self.linear_cost > 0 and math.isfinite(self.linear_cost)):
            return None
        return 1.0 - self.cost / self.linear_cost

    def to_dict(self) -> dict:
        """JSON-able summary (no time series; ``mv_model`` is left out)."""
        return _plain(
            {
                "S": self.S,
                "J": self.J,
                "S_scaled": self.S_scaled,
                "J_scaled": self.J_scaled,
                "S_interval": None if self.S_interval is None else list(self.S_interval),
                "J_interval": None if self.J_interval is None else list(self.J_interval),
                "method": self.method,
                "n_slips": self.n_slips,
                "cost": self.cost,
                "linear_cost": self.linear_cost,
                "improvement": self.improvement,
                "details": self.details,
            }
        )


@dataclass(frozen=True)
class Verdict:
    """Is the oscillation caused by valve stiction?

    Attributes
    ----------
    status : str
        ``"stiction"``, ``"no_stiction"`` or ``"inconclusive"``.
    detected : bool or None
        True for stiction, False for no stiction, None when inconclusive.
    confidence : float
        Support for ``status`` in [0, 1], measured from the data (see
        :func:`stiction_verdict` for the formula); for ``"inconclusive"`` it is the
        support for stiction, which fell between the decision levels.
    reasons : tuple of str
        Human-readable reasons, most important first.
    evidence : dict
        The measured quantities behind the decision (JSON-able).
    """

    status: str
    detected: bool | None
    confidence: float
    reasons: tuple[str, ...]
    evidence: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        return _plain(
            {
                "status": self.status,
                "verdict": self.status,
                "detected": self.detected,
                "confidence": self.confidence,
                "reasons": list(self.reasons),
                "evidence": self.evidence,
            }
        )


# --------------------------------------------------------------------------------------
# Valve model variants and compiled kernels shared by the estimators
# --------------------------------------------------------------------------------------


def noise_std(x: np.ndarray) -> float:
    """Robust standard deviation of white measurement noise on ``x`` [units of x].

    From the second difference (insensitive to ramps) with the median absolute
    deviation (insensitive to slips): ``1.4826 MAD(diff2 x) / sqrt(6)``.
    """
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    if d2.size == 0:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


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


def white_noise_std(x: np.ndarray) -> float:
    """Standard deviation of white noise on ``x`` [units of x]; 0 for a smooth signal.

    Second differences of white noise alternate in sign (lag-1 autocorrelation
    -2/3); those of a smooth signal with curvature do not (close to +1).  The noise
    is taken as present when the lag-1 autocorrelation of the second difference
    (winsorised at 5 robust deviations, so that slips do not dominate) is below
    -0.25, and its level is then :func:`noise_std`.
    """
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    if d2.size < 10:
        return 0.0
    med = float(np.median(d2))
    mad = float(np.median(np.abs(d2 - med)))
    if mad <= 0:
        return 0.0
    d = np.clip(d2 - med, -5 * 1.4826 * mad, 5 * 1.4826 * mad)
    d = d - d.mean()
    den = float(np.dot(d, d))
    rho1 = float(np.dot(d[1:], d[:-1])) / den if den > 0 else 1.0
    return noise_std(x) if rho1 < -0.25 else 0.0


def valve_variants(op: np.ndarray) -> list[ValveVariant]:
    """The valve variants a fit tries on ``op``: both flowcharts, raw and, when op
    carries white noise, behind the play operator."""
    out = [ValveVariant("choudhury", False), ValveVariant("kano", True)]
    w = PLAY_WIDTH_SIGMAS * white_noise_std(op)
    if w > 1e-9 * max(float(np.ptp(op)), 1e-300):
        out += [ValveVariant("choudhury+play", False, w), ValveVariant("kano+play", True, w)]
    return out


@jit
def _valve_step(x, st, S, J, kano):
    if kano:
        return kano_step(x, st, S, J)
    return choudhury_step(x, st, S, J)


@jit
def _start_state(op, S, J, k_start, d_start, offset):
    """Valve state at sample ``k_start``.

    ``offset < 0``: moving in direction ``d_start`` (Eq. 4 output).  ``offset >= 0``:
    stuck since the demand was ``op[k_start] - d_start * offset``, its last movement in
    direction ``d_start``.
    """
    st = valve_state(op[k_start], False)
    st[2] = d_start
    st[3] = d_start
    if offset < 0.0:
        st[0] = op[k_start] - d_start * (S - J) / 2.0
    else:
        x_ss = op[k_start] - d_start * offset
        st[1] = x_ss
        st[4] = 1.0
        st[0] = x_ss - d_start * (S - J) / 2.0
    return st


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

    Unlike :func:`stictiondiag.valve.choudhury_model` the input is not clipped to
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
    y = np.empty(n)
    if n == 0:
        return y, 0
    st = _start_state(op, S, J, k_start, d_start, offset)
    for k in range(k_start + 1):
        y[k] = st[0]
    slips = 0
    for k in range(k_start + 1, n):
        was_stuck = st[4] == 1.0
        y[k] = _valve_step(op[k], st, S, J, kano)
        if was_stuck and st[4] == 0.0:
            slips += 1
    return y, slips


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
        st = _start_state(op, S_arr[i], J_arr[i], k_start, d_start, offset)
        s1 = 0.0
        s2 = 0.0
        for k in range(k_start + 1, n):
            y = _valve_step(op[k], st, S_arr[i], J_arr[i], kano)
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
    """
    S_arr = np.ascontiguousarray(S_arr, dtype=float)
    J_arr = np.ascontiguousarray(J_arr, dtype=float)
    m = S_arr.shape[0]
    k = min(MAX_THREADS, _cpus(), m // MIN_PAIRS_PER_THREAD)
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
    s = 1.4826 * float(np.median(np.abs(x - np.median(x))))
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
    (that is :func:`stictiondiag.oscillation.detect_oscillation`'s job).
    """
    from ._filters import median_filter_nearest

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
    (:data:`stictiondiag.hammerstein.MODEL_ERROR_SHARE`).
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


# --------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------

#: Smallest share of the linear valve's residual the stiction model must remove for
#: the improvement to count as material [-].
MIN_IMPROVEMENT = 0.1

#: Bootstrap support needed to call stiction (and 1 minus it to call no stiction).
DECISION_LEVEL = 0.95

#: "No stiction" is said only when the record bounds S below this [% of span]: a
#: linear valve that explains the data as well as a sticky one is no evidence of a
#: healthy valve when the fit leaves S anywhere up to several % (a record without
#: clear cycles, disturbed by loads and set-point changes).  Stiction of a few % of
#: span is what the paper's industrial loops show (Section 3).
RULE_OUT_S = 2.0

#: Bootstrap resamples of the per-cycle costs.
N_BOOTSTRAP = 2000


def improvement_support(
    block_stiction: np.ndarray,
    block_linear: np.ndarray,
    min_improvement: float = MIN_IMPROVEMENT,
    n_boot: int = N_BOOTSTRAP,
    seed: int = 0,
) -> tuple[float, float, tuple[float, float]]:
    """Bootstrap support that the stiction model beats the linear valve materially.

    The residual sums of squares of both models are cut into blocks about one cycle
    long; blocks are resampled with replacement (a block bootstrap, so the
    correlation within a cycle is kept) and for each resample the improvement
    ``1 - sum(SSE_stiction) / sum(SSE_linear)`` is recomputed.

    Returns
    -------
    support : float
        Share of resamples with an improvement above ``min_improvement`` [-].
    improvement : float
        Improvement on the whole record [-].
    interval : (float, float)
        2.5 and 97.5 percentiles of the resampled improvement [-].
    """
    bs = np.asarray(block_stiction, dtype=float)
    bl = np.asarray(block_linear, dtype=float)
    tot = float(bl.sum())
    if bs.size == 0 or bs.size != bl.size or not tot > 0:
        return 0.0, 0.0, (0.0, 0.0)
    f = 1.0 - float(bs.sum()) / tot
    if bs.size < 2:
        return float(f > min_improvement), f, (f, f)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, bs.size, size=(n_boot, bs.size))
    num = bs[idx].sum(axis=1)
    den = bl[idx].sum(axis=1)
    fb = 1.0 - num / np.where(den > 0, den, np.inf)
    lo, hi = np.percentile(fb, [2.5, 97.5])
    return float(np.mean(fb > min_improvement)), f, (float(lo), float(hi))


def _osc_text(name: str, osc) -> str:
    if osc is None:
        return f"{name}: not analysed"
    if getattr(osc, "present", False):
        per = getattr(osc, "period_s", None)
        reg = getattr(osc, "regularity", None)
        per_s = f"period {per:.4g} s" if per is not None else "period unknown"
        reg_s = f", regularity {reg:.2g}" if reg is not None else ""
        return f"{name} oscillates ({per_s}{reg_s})"
    why = getattr(osc, "reason", None)
    return f"no oscillation in {name}" + (f" ({why})" if why else "")


def stiction_verdict(
    fit: StictionFit,
    oscillation,
    *,
    oscillation_op=None,
    has_mv: bool | None = None,
    short_record: bool = False,
    min_improvement: float = MIN_IMPROVEMENT,
    decision_level: float = DECISION_LEVEL,
    seed: int = 0,
) -> Verdict:
    """Does valve stiction explain the loop's oscillation?

    The question of Section 5.3 of Choudhury, Thornhill & Shah (2005), asked of
    the data: is there an oscillation at all (Sections 4.2.2 and 5.3: stiction shows
    as a limit cycle), does the stiction model explain the data better than a linear
    valve, by how much, consistently over the cycles, and are S and J determined.

    Parameters
    ----------
    fit : StictionFit
        From :func:`stictiondiag.segments.estimate_from_mv` or
        :func:`stictiondiag.hammerstein.fit_hammerstein`.
    oscillation : Oscillation
        :func:`stictiondiag.oscillation.detect_oscillation` of pv.
    oscillation_op : Oscillation, optional
        The same for op; an oscillation in either counts.
    has_mv : bool, optional
        Whether the valve position was recorded; default from ``fit.method``.
    short_record : bool
        The record shows a regular cycle but holds fewer periods of it than the
        oscillation test needs (:func:`stictiondiag.analysis.check_record_length`):
        the missing oscillation is then no evidence against stiction.
    min_improvement : float
        Share of the linear valve's residual the stiction model must remove to count
        as a material improvement [-].
    decision_level : float
        Support needed for a decision [-].
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    Verdict

    Notes
    -----
    The evidence is the bootstrap support ``P`` of :func:`improvement_support`: the
    share of block resamples (blocks about one cycle long) in which the stiction
    model removes more than ``min_improvement`` of the residual the linear valve
    leaves.  It measures at once *how much* (the threshold) and *how consistently*
    (the resampling over cycles) the stiction model does better.

    * An oscillation, ``P >= decision_level`` and S determined (its interval excludes
      0 and stays inside the search range): **stiction**, confidence ``P``.
    * An oscillation and ``P <= 1 - decision_level``, or ``P < 0.5`` with a linear
      valve (S = 0) inside the S interval: **no stiction**, confidence ``1 - P``.
    * No regular oscillation in pv or op: **no stiction**, confidence ``1 - P``,
      unless the valve evidence itself shows repeated stick-slip
      (``P >= decision_level``, at least three slips, S determined; on a short
      record the support over at least three blocks): then
      **stiction**, confidence ``P`` (or **inconclusive** when ``P`` is that high
      but S is not determined).  With mv recorded that is the valve seen
      sticking; without, a valve model that explains pv by its slips.  When the
      record is merely too short to confirm its cycle (``short_record``), the
      missing oscillation proves nothing: **no stiction** then needs
      ``P <= 1 - decision_level`` (a linear valve explains pv as well), and
      anything between is **inconclusive**.  Plant
      stiction cycles are often too irregular for the regularity test of
      :func:`stictiondiag.oscillation.detect_oscillation` (its r > 1), and a fit
      whose band excludes zero and beats a linear valve in 95 % of the cycle
      resamples is evidence of its own.
    * Otherwise **inconclusive** (weak or inconsistent improvement, or S poorly
      determined), confidence ``P`` (the support for stiction).
    * Every **no stiction** above also needs the S interval to end below
      :data:`RULE_OUT_S`; where the record leaves a larger S open the verdict is
      **inconclusive** and says how much stiction is not ruled out.

    The confidence is therefore never set by hand: it is a bootstrap share computed
    from the fit's residuals.
    """
    if has_mv is None:
        has_mv = fit.method == "mv_segments"
    d = fit.details or {}
    blocks = d.get("block_sse") or {}
    bs = np.asarray(blocks.get("stiction", []), dtype=float)
    bl = np.asarray(blocks.get("linear", []), dtype=float)
    if bs.size == 0:
        bs, bl = np.array([fit.cost]), np.array([fit.linear_cost])
    P, f, f_iv = improvement_support(bs, bl, min_improvement, seed=seed)

    osc_pv = bool(getattr(oscillation, "present", False))
    osc_op = bool(getattr(oscillation_op, "present", False)) if oscillation_op else False
    oscillating = osc_pv or osc_op

    S_iv = fit.S_interval
    S_open = "reaches the search limit" in str((d.get("determinacy") or {}).get("S", ""))
    S_excludes_zero = S_iv is not None and S_iv[0] > 0.0
    S_determined = S_excludes_zero and not S_open
    n_slips = int((d.get("segments") or {}).get("n_slips", fit.n_slips))

    fit_text = (
        f"S = {fit.S:.3g} %"
        + (f" [{S_iv[0]:.3g}, {S_iv[1]:.3g}]" if S_iv else "")
        + f", J = {fit.J:.3g} %"
        + (f" [{fit.J_interval[0]:.3g}, {fit.J_interval[1]:.3g}]" if fit.J_interval else "")
        + f" of span ({'valve position' if has_mv else 'op and pv'})"
    )
    improve_text = (
        f"the stiction model removes {100 * f:.0f} % of the linear valve's residual "
        f"(95 % interval over cycles {100 * f_iv[0]:.0f} to {100 * f_iv[1]:.0f} %; "
        f"support {P:.2f} for more than {100 * min_improvement:.0f} %"
        + (
            f"; only {bs.size} cycle block(s), too few to measure consistency"
            if bs.size < 3
            else ""
        )
        + ")"
    )
    osc_texts = [_osc_text("pv", oscillation)]
    if oscillation_op is not None:
        osc_texts.append(_osc_text("op", oscillation_op))
    det_texts = []
    if not S_excludes_zero:
        det_texts.append("S cannot be told apart from 0 (no stick band)")
    elif S_open:
        det_texts.append("S poorly determined: its interval reaches the search limit")
    if d.get("J_confounded_with_gain"):
        det_texts.append(
            "J not determined without mv: the fitted valve never moves smoothly, so its "
            "jump trades off against the process gain"
        )

    evidence = {
        "oscillation_pv": osc_pv,
        "oscillation_op": osc_op,
        "improvement": f,
        "improvement_interval": list(f_iv),
        "support": P,
        "min_improvement": min_improvement,
        "decision_level": decision_level,
        "n_blocks": int(bs.size),
        "S_determined": bool(S_determined),
        "n_slips": n_slips,
        "has_mv": bool(has_mv),
        "short_record": bool(short_record),
        "confidence_formula": (
            "support = share of block-bootstrap resamples (one-cycle blocks) in which the "
            "stiction model removes more than min_improvement of the linear valve's "
            "residual; confidence = support (stiction, inconclusive) or 1 - support "
            "(no stiction)"
        ),
    }

    if not oscillating:
        # A record too short to confirm its cycle must show the improvement over at
        # least three blocks: a bootstrap over fewer measures no consistency.
        enough_blocks = bs.size >= 3 or not short_record
        if P >= decision_level and n_slips >= 3 and S_determined and enough_blocks:
            source = (
                "the recorded valve position sticks and slips"
                if has_mv
                else "the valve model explains pv by repeated slips"
            )
            return Verdict(
                "stiction",
                True,
                P,
                (
                    f"{source} ({n_slips} slips) although the cycle is not regular",
                    *osc_texts,
                    improve_text,
                    fit_text,
                ),
                evidence,
            )
        if P >= decision_level:
            return Verdict(
                "inconclusive",
                None,
                P,
                (
                    "no regular oscillation, but the valve model fits better than a linear "
                    "valve: " + improve_text,
                    *det_texts,
                    *osc_texts,
                    fit_text,
                ),
                evidence,
            )
        if short_record and P > 1.0 - decision_level:
            return Verdict(
                "inconclusive",
                None,
                P,
                (
                    "the record is too short to confirm or rule out a limit cycle, and the "
                    "valve model's evidence is not decisive: " + improve_text,
                    *det_texts,
                    *osc_texts,
                    fit_text,
                ),
                evidence,
            )
        if short_record:
            reasons = (
                "a linear valve explains pv as well (the record is too short to confirm "
                "its cycle): " + improve_text,
                *osc_texts,
                fit_text,
            )
        else:
            reasons = (*osc_texts, "nothing for stiction to explain", improve_text)
        return _no_stiction_unless_open(P, reasons, S_iv, fit_text, evidence)

    if P >= decision_level and S_determined:
        return Verdict(
            "stiction", True, P, (improve_text, fit_text, *osc_texts, *det_texts), evidence
        )
    if P <= 1.0 - decision_level or (not S_excludes_zero and P < 0.5):
        return _no_stiction_unless_open(
            P,
            ("a linear valve explains the oscillation as well: " + improve_text, *osc_texts),
            S_iv,
            fit_text,
            evidence,
        )
    why = (
        "the improvement over a linear valve is weak or not consistent over the cycles"
        if P < decision_level
        else "the stiction parameters are poorly determined"
    )
    return Verdict(
        "inconclusive", None, P, (why, improve_text, *det_texts, fit_text, *osc_texts), evidence
    )


def _no_stiction_unless_open(P, reasons, S_iv, fit_text, evidence) -> Verdict:
    """**No stiction** (confidence ``1 - P``) when the S interval's upper end is below
    :data:`RULE_OUT_S`; otherwise **inconclusive** (confidence ``P``): the record does
    not rule out a sticky valve of that size."""
    upper = None if S_iv is None else float(S_iv[1])
    evidence = {**evidence, "S_upper": upper, "rule_out_S": RULE_OUT_S}
    if upper is not None and upper >= RULE_OUT_S:
        return Verdict(
            "inconclusive",
            None,
            P,
            (
                f"stiction up to S = {upper:.3g} % of span is not ruled out by the record "
                f"(no stiction needs S bounded below {RULE_OUT_S:g} %)",
                *reasons,
                fit_text,
            ),
            evidence,
        )
    return Verdict("no_stiction", False, 1.0 - P, (*reasons, fit_text), evidence)


# --------------------------------------------------------------------------------------
# The two estimators (implemented in their own modules)
# --------------------------------------------------------------------------------------


def estimate_from_mv(op: np.ndarray, mv: np.ndarray, dt: float) -> StictionFit:
    """S and J from the recorded valve position: see :func:`stictiondiag.segments.estimate_from_mv`."""
    from .segments import estimate_from_mv as _impl

    return _impl(op, mv, dt)


def fit_hammerstein(
    op: np.ndarray,
    pv: np.ndarray,
    dt: float,
    *,
    integrating: bool,
    flow_loop: bool,
    period_s: float | None = None,
) -> StictionFit:
    """S and J from op and pv: see :func:`stictiondiag.hammerstein.fit_hammerstein`."""
    from .hammerstein import fit_hammerstein as _impl

    return _impl(op, pv, dt, integrating=integrating, flow_loop=flow_loop, period_s=period_s)
