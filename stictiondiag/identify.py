"""Identification of the linear parts of a control loop from closed-loop data.

The replay of a sticky loop (Choudhury, Thornhill & Shah 2005, Sections 4.2.2 and
5.3) needs the two linear blocks of Eq. 3 besides the valve: the PI controller
``C(s) = Kc (Ti s + 1) / (Ti s)`` that maps the control error ``e = sp - pv`` to the
valve demand ``op``, and the process ``G(s)`` that maps the valve position ``mv`` to
``pv``: first order plus dead time ``K e^{-theta s} / (tau s + 1)`` (the
concentration loop) or integrating ``K e^{-theta s} / s`` (the level loop, Table 3).

Controller (:func:`identify_controller`)
    Velocity form of the discrete PI law (backward-Euler integral),
    ``op[k] - op[k-1] = Kc (e[k] - e[k-1]) + Kc dt / Ti e[k]``, fitted by least
    squares.  Differencing removes the unknown bias (manual reset or integral state),
    so the fit needs no initial condition.  ``Kc`` may be negative (a reverse-acting
    controller in the paper's sign convention ``e = sp - pv``).  When the integral
    term is not significant the controller is proportional only (``Ti = inf``).
    Differences that touch a saturated ``op`` (at 0 or 100 %, or held at one value,
    see :func:`saturated_samples`) are excluded: there the controller's law does not
    hold.
    Without a recorded setpoint the setpoint is taken as constant at the mean of pv
    (an integrating controller holds pv at its setpoint on average).

Process (:func:`identify_process`)
    1. A scan over integer dead times ``d`` [samples] of the one-step ARX models
       ``pv[k+1] = a pv[k] + b u[k-d] + c`` (FOPTD) and
       ``pv[k+1] - pv[k] = b u[k-d] + c`` (integrating), all delays at once from
       normal equations built with correlations (vectorised, no loop over delays).
    2. Output-error refinement: the model is *simulated* from ``u`` and the squared
       simulation error minimised, over the time constant (a scalar search; gain,
       bias and initial state enter linearly and are solved by least squares at each
       step) and over the dead time near the ARX choice.  The one-step ARX fit is
       biased by measurement noise on pv (the regressor ``pv[k]`` is noisy); the
       output-error fit is not, and it is the simulated response that the replay
       needs.
    3. With ``integrating=None`` the integrating model is chosen when its simulation
       fit is within :data:`INTEGRATING_R2_MARGIN` of the FOPTD's: an integrator is
       the limit of an FOPTD with a long time constant, so the FOPTD always fits at
       least about as well and the simpler model wins ties.

A limit cycle is (nearly) periodic, so a dead time ``d`` and ``d + P`` (``P`` the
period in samples) explain the data about equally well; the scan takes the shortest
dead time whose fit is close to the best (:data:`DEAD_TIME_TOLERANCE`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import correlate, lfilter

from .errors import DataError, UsageError
from .processes import FOPTD, PI, Integrating

#: t-statistic of the integral term below which the controller is called P-only [-].
INTEGRAL_T_THRESHOLD = 3.0
#: op within this distance of 0 or 100 % counts as saturated [% of span].  Wider than
#: rounding: anti-windup schemes act next to the limit (conditional integration lets op
#: chatter just below it, integrating on some samples and not on others).
SATURATION_TOLERANCE = 1.0
#: op held at one value this long or longer counts as saturated [samples].
SATURATION_PLATEAU = 3
#: Integrating model chosen when its simulation R^2 is at most this much below the FOPTD's.
INTEGRATING_R2_MARGIN = 0.01
#: Dead-time scan: shortest delay whose ARX cost is within this fraction of the range
#: between the best and the median cost (periodic data make d and d + P ambiguous).
DEAD_TIME_TOLERANCE = 0.02
#: Longest dead time searched, as a fraction of the record [-].
MAX_DEAD_TIME_FRACTION = 0.25
#: Fewest usable samples for an identification.
MIN_SAMPLES = 20


@dataclass(frozen=True)
class ControllerFit:
    """PI controller identified from ``sp``, ``pv`` and ``op`` (Eq. 3 form).

    Attributes
    ----------
    controller : PI
        ``Kc`` [% of span / pv units] and ``Ti`` [s]; ``Ti = inf`` for a P-only law.
    op_bias : float
        op at zero error with the integral started at zero on the first sample
        [% of span]: ``op[k] = op_bias + Kc (e[k] + dt/Ti sum_{j<=k} e[j])``, the sum
        frozen while op is saturated.  For P-only, the manual reset.
    fit_r2 : float
        R^2 of the velocity-form regression on ``op`` differences [-].
    op_fit_r2 : float
        R^2 of the reconstructed op level on unsaturated samples [-].
    p_only : bool
        The integral term was not significant.
    reverse_acting : bool
        ``Kc < 0`` in the convention ``e = sp - pv``.
    sp_assumed : bool
        No setpoint was given; it was taken as constant at mean(pv).
    n_used, n_saturated : int
        Differences used in the fit; samples flagged as saturated.
    integral_t_stat : float
        t-statistic of the integral coefficient [-].
    """

    controller: PI
    op_bias: float
    fit_r2: float
    op_fit_r2: float
    p_only: bool
    reverse_acting: bool
    sp_assumed: bool
    n_used: int
    n_saturated: int
    integral_t_stat: float

    def to_dict(self) -> dict:
        """JSON-able dict (``integral_time_s`` is None for a P-only controller)."""
        ti = self.controller.integral_time
        return {
            "type": "p" if self.p_only else "pi",
            "gain": _plain(self.controller.gain),
            "integral_time_s": _plain(ti),
            "op_bias": _plain(self.op_bias),
            "fit_r2": _plain(self.fit_r2),
            "op_fit_r2": _plain(self.op_fit_r2),
            "p_only": bool(self.p_only),
            "reverse_acting": bool(self.reverse_acting),
            "sp_assumed": bool(self.sp_assumed),
            "n_used": int(self.n_used),
            "n_saturated": int(self.n_saturated),
            "integral_t_stat": _plain(self.integral_t_stat),
        }


@dataclass(frozen=True)
class ProcessFit:
    """Process from valve position (or any input ``u``) to pv.

    Attributes
    ----------
    process : FOPTD or Integrating
        Gain [pv units / % of span] (integrating: [pv units / (% of span s)]), time
        constant [s], dead time [s] (a whole number of samples).
    u_bias : float
        Input reference [% of span].  FOPTD: mean of ``u``; integrating: the balance
        input at which pv does not move.
    pv_bias : float
        FOPTD: steady-state pv at ``u = u_bias`` [pv units].  Integrating: pv at the
        first sample of the simulated response [pv units].
    initial_deviation : float
        FOPTD: pv[0] minus the steady state of ``u[0]`` (a decaying free response with
        the time constant) [pv units]; 0 for the integrating model.
    fit_r2 : float
        R^2 of the simulated (output-error) response against pv [-], over the samples
        after the first dead time (before it pv answers to inputs from before the
        record).
    arx_r2 : float
        R^2 of the one-step ARX model at the chosen dead time, on pv differences [-].
    integrating : bool
        The integrating model was chosen.
    dead_time_samples : int
        Dead time [samples].
    candidates : dict
        Simulation R^2 of each structure that was fitted (``foptd``, ``integrating``).
    """

    process: FOPTD | Integrating
    u_bias: float
    pv_bias: float
    initial_deviation: float
    fit_r2: float
    arx_r2: float
    integrating: bool
    dead_time_samples: int
    candidates: dict = field(default_factory=dict)

    def simulate(self, u: np.ndarray, dt: float) -> np.ndarray:
        """Open-loop response of the fitted model to ``u`` [pv units] (same length)."""
        u = np.asarray(u, dtype=float)
        d = self.dead_time_samples
        if self.integrating:
            return _integrating_regressors(u, d, dt) @ np.array(
                [self.pv_bias, self.process.gain, -self.process.gain * self.u_bias]
            )
        a = math.exp(-dt / self.process.time_constant)
        z = _lag_response(u, d, a)
        k = np.arange(u.size)
        return self.pv_bias + self.process.gain * (z - self.u_bias) + self.initial_deviation * a**k

    def to_dict(self) -> dict:
        """JSON-able dict: the process parameters plus biases and fit measures."""
        out = {
            k: _plain(v) if isinstance(v, float) else v for k, v in self.process.to_dict().items()
        }
        out.update(
            {
                "u_bias": _plain(self.u_bias),
                "pv_bias": _plain(self.pv_bias),
                "fit_r2": _plain(self.fit_r2),
                "arx_r2": _plain(self.arx_r2),
                "dead_time_samples": int(self.dead_time_samples),
                "candidates": {k: _plain(v) for k, v in self.candidates.items()},
            }
        )
        return out


def _plain(v) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _as_signal(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise UsageError(f"{name} must be a one-dimensional signal")
    return a


def _check_dt(dt) -> float:
    try:
        dt_ = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"sample time dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt_) and dt_ > 0):
        raise UsageError(f"sample time dt must be a positive number of seconds, got {dt_}")
    return dt_


def _r2(y: np.ndarray, y_hat: np.ndarray) -> float:
    sst = float(np.sum((y - y.mean()) ** 2))
    if sst <= 0.0:
        return 0.0
    return 1.0 - float(np.sum((y - y_hat) ** 2)) / sst


# --------------------------------------------------------------------------- controller


def saturated_samples(op: np.ndarray) -> np.ndarray:
    """Boolean mask of samples where the PI law cannot be seen in op.

    op at 0 or 100 % of span (within :data:`SATURATION_TOLERANCE`), or held at one
    value for at least :data:`SATURATION_PLATEAU` samples.  A PI controller with a
    non-zero error always moves its output, so a held op is a clamp (limits other
    than 0-100 %, or conditional-integration anti-windup holding op just below the
    limit), a manual or tracking mode, or a historian repeating old values: in each
    case the law does not hold there.  With zero error a held op carries no
    information, so leaving it out costs nothing.
    """
    op = np.asarray(op, dtype=float)
    sat = (op <= SATURATION_TOLERANCE) | (op >= 100.0 - SATURATION_TOLERANCE)
    if op.size < SATURATION_PLATEAU:
        return sat
    span = float(np.nanmax(op) - np.nanmin(op))
    tol = 1e-12 * max(1.0, span)
    same = np.abs(np.diff(op)) <= tol  # op[k+1] equals op[k]
    # Runs of equal consecutive differences; a run of m equal steps is m + 1 samples.
    edges = np.diff(np.concatenate(([0], same.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    for s0, e0 in zip(starts, ends, strict=True):
        if e0 - s0 + 1 >= SATURATION_PLATEAU:
            sat[s0 : e0 + 1] = True
    return sat


def identify_controller(
    sp: np.ndarray | None, pv: np.ndarray, op: np.ndarray, dt: float
) -> ControllerFit:
    """Identify the PI controller ``C(s) = Kc (Ti s + 1) / (Ti s)`` (Eq. 3).

    Parameters
    ----------
    sp : ndarray or None
        Setpoint [pv units]; None means constant at mean(pv).
    pv : ndarray
        Controlled variable [pv units].
    op : ndarray
        Controller output [% of span].
    dt : float
        Sample time [s].

    Returns
    -------
    ControllerFit
        ``Kc`` [% of span / pv units] (negative for a reverse-acting controller),
        ``Ti`` [s] (inf for P-only), op bias and fit measures.

    Notes
    -----
    Least squares on the velocity form
    ``op[k] - op[k-1] = Kc (e[k] - e[k-1]) + (Kc dt / Ti) e[k]``, which is free of
    the unknown bias.  The discretisation of the integral (backward or forward
    Euler) changes ``Kc`` by ``Kc dt / Ti`` (relative error ``dt / Ti``).
    """
    data = _ControllerData.build(sp, pv, op, dt)
    de, ek, dop = data.de, data.ek, data.dop
    if np.ptp(ek) == 0.0 and np.ptp(de) == 0.0:
        raise DataError("the control error is constant: pv and sp carry no information")
    coef, t_int, _ = _lstsq_t(np.column_stack([de, ek]), dop)
    kc, ki_dt = float(coef[0]), float(coef[1])
    record = data.e.size * data.dt
    ti = math.inf
    if abs(t_int) >= INTEGRAL_T_THRESHOLD and kc != 0.0 and ki_dt != 0.0:
        ti_candidate = kc * data.dt / ki_dt
        # A negative Ti means the "integral" has the wrong sign for a PI law: the
        # differences are explained by something else (noise, a P-only law with drift).
        if 0.0 < ti_candidate < 100.0 * record:
            ti = ti_candidate
    if math.isinf(ti):
        coef1, *_ = np.linalg.lstsq(de[:, None], dop, rcond=None)
        kc = float(coef1[0])
    if kc == 0.0 or not math.isfinite(kc):
        raise DataError("op does not respond to the control error: no PI law found")
    return data.result(kc, ti, float(t_int))


def controller_fit(
    controller: PI, sp: np.ndarray | None, pv: np.ndarray, op: np.ndarray, dt: float
) -> ControllerFit:
    """Fit measures and op bias of a *given* PI controller on recorded data.

    Same conventions as :func:`identify_controller` (``integral_time = inf`` for a
    P-only law); ``Kc`` and ``Ti`` are kept, only ``op_bias`` is estimated.
    """
    if not isinstance(controller, PI):
        raise UsageError("controller must be a PI model (stictiondiag.processes.PI)")
    kc, ti = float(controller.gain), float(controller.integral_time)
    if kc == 0.0 or not math.isfinite(kc) or not ti > 0.0:
        raise UsageError(f"controller needs a non-zero gain and Ti > 0, got Kc={kc}, Ti={ti}")
    return _ControllerData.build(sp, pv, op, dt).result(kc, ti, math.nan)


@dataclass(frozen=True, eq=False)
class _ControllerData:
    """Error, saturation mask and velocity-form regressors shared by the fits."""

    dt: float
    e: np.ndarray
    op: np.ndarray
    good: np.ndarray
    use: np.ndarray
    sp_assumed: bool
    n_saturated: int

    @classmethod
    def build(cls, sp, pv, op, dt) -> _ControllerData:
        dt = _check_dt(dt)
        pv = _as_signal(pv, "pv")
        op = _as_signal(op, "op")
        if pv.size != op.size:
            raise UsageError(f"pv and op must have the same length, got {pv.size} and {op.size}")
        sp_assumed = sp is None
        if sp_assumed:
            sp_arr = np.full(pv.size, float(np.nanmean(pv)))
        else:
            sp_arr = _as_signal(sp, "sp")
            if sp_arr.size != pv.size:
                raise UsageError(
                    f"sp and pv must have the same length, got {sp_arr.size} and {pv.size}"
                )
        e = sp_arr - pv
        sat = saturated_samples(op)
        good = np.isfinite(e) & np.isfinite(op) & ~sat
        use = good[1:] & good[:-1]
        n_used = int(use.sum())
        if n_used < MIN_SAMPLES:
            raise DataError(
                f"only {n_used} unsaturated samples for controller identification: "
                "use a record where op moves inside its range"
            )
        return cls(dt, e, op, good, use, sp_assumed, int(sat.sum()))

    @property
    def dop(self) -> np.ndarray:
        return np.diff(self.op)[self.use]

    @property
    def de(self) -> np.ndarray:
        return np.diff(self.e)[self.use]

    @property
    def ek(self) -> np.ndarray:
        return self.e[1:][self.use]

    def result(self, kc: float, ti: float, t_int: float) -> ControllerFit:
        dop = self.dop
        p_only = math.isinf(ti)
        ki_dt = 0.0 if p_only else kc * self.dt / ti
        resid = dop - kc * self.de - ki_dt * self.ek
        fit_r2 = 1.0 - float(resid @ resid) / max(float(np.sum((dop - dop.mean()) ** 2)), 1e-300)
        # op level: integral frozen while saturated (conditional-integration anti-windup).
        e, good = self.e, self.good
        law = kc * e
        if not p_only:
            law = law + ki_dt * np.cumsum(np.where(good, e, 0.0))
        op_bias = float(np.mean((self.op - law)[good]))
        return ControllerFit(
            controller=PI(gain=kc, integral_time=ti),
            op_bias=op_bias,
            fit_r2=fit_r2,
            op_fit_r2=_r2(self.op[good], law[good] + op_bias),
            p_only=p_only,
            reverse_acting=kc < 0.0,
            sp_assumed=self.sp_assumed,
            n_used=int(self.use.sum()),
            n_saturated=self.n_saturated,
            integral_t_stat=t_int,
        )


def _lstsq_t(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Least squares with the t-statistic of the last coefficient."""
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    dof = max(y.size - X.shape[1], 1)
    s2 = float(resid @ resid) / dof
    try:
        cov = s2 * np.linalg.inv(X.T @ X)
        se = math.sqrt(max(float(cov[-1, -1]), 0.0))
    except np.linalg.LinAlgError:
        se = math.inf
    t = abs(float(coef[-1])) / se if se > 0 else math.inf
    return coef, t, resid


# --------------------------------------------------------------------------- process


def _delayed(u: np.ndarray, shift: int) -> np.ndarray:
    """``u[k - shift]``, held at ``u[0]`` before the record starts."""
    if shift <= 0:
        return u
    out = np.empty_like(u)
    out[:shift] = u[0]
    out[shift:] = u[: u.size - shift]
    return out


def _lag_response(u: np.ndarray, d: int, a: float) -> np.ndarray:
    """``z[k+1] = a z[k] + (1 - a) u[k - d]``, ``z[0] = u[0]``: first-order lag with
    dead time ``d`` samples (exact zero-order-hold discretisation of the FOPTD)."""
    x = _delayed(u, d + 1)
    z, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * u[0]])
    return z


def _integrating_regressors(u: np.ndarray, d: int, dt: float) -> np.ndarray:
    """Columns [1, dt sum_{j<k} u[j-d], dt k] of the simulated integrator response."""
    x = _delayed(u, d + 1)
    x[0] = 0.0
    k = np.arange(u.size)
    return np.column_stack([np.ones(u.size), dt * np.cumsum(x), dt * k])


def _window_sums(x: np.ndarray, start: np.ndarray, length: int) -> np.ndarray:
    c = np.concatenate(([0.0], np.cumsum(x)))
    return c[start + length] - c[start]


def _arx_scan(u: np.ndarray, pv: np.ndarray, d_max: int, integrating: bool) -> np.ndarray:
    """Residual sum of squares of the one-step ARX model for every dead time 0..d_max.

    Rows ``k = d_max .. n-2`` are common to all delays so the costs compare.  The
    normal equations need, per delay, window sums of ``u`` and ``u^2`` and the
    correlations of ``u`` with ``pv[k]`` and ``pv[k+1]``, all computed at once.
    """
    n = u.size
    m = n - 1 - d_max
    k0 = d_max
    y_next = pv[k0 + 1 : n]
    y_now = pv[k0 : n - 1]
    starts = k0 - np.arange(d_max + 1)  # u[k-d] for k in [k0, n-2] starts at k0 - d
    su = _window_sums(u, starts, m)
    suu = _window_sums(u * u, starts, m)
    # corr[d] = sum_k y[k] u[k - d]; scipy's correlate picks FFT for long signals.
    full_next = correlate(y_next, u, mode="full", method="auto")
    full_now = correlate(y_now, u, mode="full", method="auto")
    # correlate(a, b)[j] = sum_i a[i] b[i + (len(b) - 1) - j]... index for shift s:
    # sum_i y[i] u[i + k0 - d]  -> lag index = (len(u) - 1) - (k0 - d)
    idx = (n - 1) - starts
    syu = full_next[idx]
    if integrating:
        dy = y_next - y_now
        sdu = syu - full_now[idx]
        A = np.empty((d_max + 1, 2, 2))
        A[:, 0, 0] = suu
        A[:, 0, 1] = su
        A[:, 1, 0] = su
        A[:, 1, 1] = m
        g = np.stack([sdu, np.full(d_max + 1, dy.sum())], axis=1)
        syy = float(dy @ dy)
    else:
        spu = full_now[idx]
        sp = float(y_now.sum())
        spp = float(y_now @ y_now)
        A = np.empty((d_max + 1, 3, 3))
        A[:, 0, 0] = spp
        A[:, 0, 1] = spu
        A[:, 0, 2] = sp
        A[:, 1, 0] = spu
        A[:, 1, 1] = suu
        A[:, 1, 2] = su
        A[:, 2, 0] = sp
        A[:, 2, 1] = su
        A[:, 2, 2] = m
        g = np.stack(
            [np.full(d_max + 1, float(y_next @ y_now)), syu, np.full(d_max + 1, y_next.sum())],
            axis=1,
        )
        syy = float(y_next @ y_next)
    # Tiny ridge keeps a constant-input window (singular) from failing the batch.
    A = A + 1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(A.shape[1])
    beta = np.linalg.solve(A, g[..., None])[..., 0]
    return syy - np.einsum("di,di->d", beta, g)


def _pick_dead_time(cost: np.ndarray) -> int:
    """Shortest delay whose ARX cost is close to the best (see module docstring)."""
    best = float(cost.min())
    spread = float(np.median(cost)) - best
    ok = np.flatnonzero(cost <= best + DEAD_TIME_TOLERANCE * max(spread, 0.0))
    d = int(ok[0])
    # Walk down into the local minimum of the run that starts at d.
    while d + 1 < cost.size and cost[d + 1] < cost[d]:
        d += 1
    return d


def _foptd_oe(u: np.ndarray, pv: np.ndarray, d: int, a: float, u_bias: float):
    """Linear part of the FOPTD output-error fit for fixed dead time and pole.

    Rows ``k <= d`` are left out: there pv depends on inputs from before the record,
    and from ``k = d + 1`` on any error in those shows only as a free response
    ``a^k``, which the third regressor absorbs.  Returns the mean squared error and
    the coefficients (gain, pv bias, initial deviation).
    """
    z = _lag_response(u, d, a)
    k = np.arange(d + 1, u.size)
    X = np.column_stack([z[k] - u_bias, np.ones(k.size), a**k])
    y = pv[k]
    # Normal equations (3 x 3) are several times faster than an SVD solve here; the
    # tiny ridge on the free-response column keeps them regular when a^k vanishes.
    A = X.T @ X
    A[2, 2] += 1e-12 * k.size
    coef = np.linalg.solve(A, X.T @ y)
    resid = y - X @ coef
    return float(resid @ resid) / k.size, coef


def _prefix(x: np.ndarray) -> np.ndarray:
    return np.concatenate(([0.0], np.cumsum(x)))


def _oe_delay_scan(z0: np.ndarray, pv: np.ndarray, a: float, d_max: int) -> np.ndarray:
    """Output-error mean squared error of the FOPTD for every dead time 0..d_max at a
    fixed pole (rows ``k > d`` as in :func:`_foptd_oe`).

    ``z0`` is the lag response without dead time; delaying the input delays it, so the
    regressors for dead time ``d`` are ``[z0[k - d], 1, a^k]`` for ``k > d``.  Their
    normal equations come from prefix sums and one correlation, for all delays at once.
    """
    n = z0.size
    dd = np.arange(d_max + 1)
    r = a ** np.arange(n)
    cz, czz, czr = _prefix(z0), _prefix(z0 * z0), _prefix(z0 * r)
    cr, crr, cp = _prefix(r), _prefix(r * r), _prefix(pv)
    crp, cpp = _prefix(r * pv), _prefix(pv * pv)
    top = n - dd  # z0[1 .. n-1-d] appear
    first = dd + 1  # rows k = d+1 .. n-1
    # sum_{k>=d} pv[k] z0[k-d] is the correlation of pv with z0 at lag d.
    full = correlate(pv, z0, mode="full", method="auto")
    A = np.empty((d_max + 1, 3, 3))
    A[:, 0, 0] = czz[top] - czz[1]
    A[:, 0, 1] = A[:, 1, 0] = cz[top] - cz[1]
    A[:, 0, 2] = A[:, 2, 0] = (a**dd) * (czr[top] - czr[1])
    A[:, 1, 1] = n - first
    A[:, 1, 2] = A[:, 2, 1] = cr[n] - cr[first]
    A[:, 2, 2] = crr[n] - crr[first]
    g = np.stack(
        [full[(n - 1) + dd] - z0[0] * pv[dd], cp[n] - cp[first], crp[n] - crp[first]], axis=1
    )
    # The free-response column vanishes for a fast pole (a^k -> 0); a tiny ridge on
    # it (the column is bounded by 1, like the constant) keeps the solve regular.
    A[:, 2, 2] += 1e-12 * n
    beta = np.linalg.solve(A, g[..., None])[..., 0]
    sse = (cpp[n] - cpp[first]) - np.einsum("di,di->d", beta, g)
    return sse / (n - first)


def _fit_foptd(u, pv, dt, d_max, tau_max):
    """Output-error FOPTD fit: a coarse grid over time constant and every dead time
    (vectorised), then a walk along the dead time with the time constant refined
    at each step."""
    u_bias = float(u.mean())
    log_lo, log_hi = math.log(0.2 * dt), math.log(tau_max)

    def sse(d: int, log_tau: float) -> float:
        return _foptd_oe(u, pv, d, math.exp(-dt / math.exp(log_tau)), u_bias)[0]

    grid = np.linspace(log_lo, log_hi, 25)
    spacing = float(grid[1] - grid[0])

    def best_tau(d: int, centre: float) -> tuple[float, float]:
        """Bounded search of log(tau) within a grid spacing of ``centre``; the
        bracket moves while the optimum sits on its edge."""
        lo, hi = max(centre - spacing, log_lo), min(centre + spacing, log_hi)
        for _ in range(8):
            res = minimize_scalar(
                lambda g: sse(d, g), bounds=(lo, hi), method="bounded", options={"xatol": 1e-4}
            )
            x = float(res.x)
            if x - lo < 0.05 * spacing and lo > log_lo:
                lo, hi = max(lo - spacing, log_lo), lo + 0.1 * spacing
            elif hi - x < 0.05 * spacing and hi < log_hi:
                lo, hi = hi - 0.1 * spacing, min(hi + spacing, log_hi)
            else:
                break
        return x, float(res.fun)

    # Coarse joint grid: every dead time for each time constant of the grid.  The
    # time constant and the dead time trade off along a ridge, so the two are
    # searched together rather than one after the other.
    profile = np.full(d_max + 1, np.inf)
    tau_at = np.zeros(d_max + 1)
    for g in grid:
        a = math.exp(-dt / math.exp(g))
        costs = _oe_delay_scan(_lag_response(u, 0, a), pv, a, d_max)
        better = costs < profile
        profile[better] = costs[better]
        tau_at[better] = g
    d = _pick_dead_time(profile)
    cache: dict[int, tuple[float, float]] = {d: best_tau(d, float(tau_at[d]))}

    def cost(dd: int, centre: float) -> float:
        if dd not in cache:
            cache[dd] = best_tau(dd, centre)
        return cache[dd][1]

    # Local refinement along the ridge with the time constant optimised at each step.
    for step in (1, -1):
        while 0 <= d + step <= d_max and cost(d + step, cache[d][0]) < cache[d][1]:
            d += step
    log_tau = cache[d][0]
    tau = math.exp(log_tau)
    sse_, coef = _foptd_oe(u, pv, d, math.exp(-dt / tau), u_bias)
    gain, pv_bias, x0 = (float(c) for c in coef)
    return d, tau, gain, pv_bias, x0, u_bias, sse_


def _fit_integrating(u, pv, dt, d0):
    n = u.size

    def fit(d: int):
        # Rows k <= d depend on inputs from before the record; from k = d + 1 on an
        # error in those is a constant offset, which the first regressor absorbs.
        X = _integrating_regressors(u, d, dt)[d + 1 :]
        coef, *_ = np.linalg.lstsq(X, pv[d + 1 :], rcond=None)
        r = pv[d + 1 :] - X @ coef
        return float(r @ r) / r.size, coef

    cache: dict[int, tuple[float, np.ndarray]] = {}

    def cost(d: int) -> float:
        if d not in cache:
            cache[d] = fit(d)
        return cache[d][0]

    d = d0
    for step in (1, -1):
        while 0 <= d + step < n // 2 and cost(d + step) < cost(d):
            d += step
    sse, coef = cache[d] if d in cache else fit(d)
    pv0, gain, slope = (float(c) for c in coef)
    u_bias = -slope / gain if gain != 0.0 else float(u.mean())
    return d, gain, pv0, u_bias, sse


def identify_process(
    u: np.ndarray,
    pv: np.ndarray,
    dt: float,
    *,
    integrating: bool | None = None,
    max_dead_time: float | None = None,
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
        Longest dead time searched [s]; default a quarter of the record.

    Returns
    -------
    ProcessFit
        The process, biases and fit measures.  Dead time is a whole number of
        samples; the FOPTD time constant is searched in [0.2 dt, 20 x record].
    """
    dt = _check_dt(dt)
    u = _as_signal(u, "u")
    pv = _as_signal(pv, "pv")
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
    d_max = int(MAX_DEAD_TIME_FRACTION * n)
    if max_dead_time is not None:
        if not (math.isfinite(max_dead_time) and max_dead_time >= 0):
            raise UsageError(f"max_dead_time must be >= 0 s, got {max_dead_time}")
        d_max = min(d_max, int(max_dead_time / dt))
    d_max = max(d_max, 0)
    # Centre the signals: the normal equations are then well conditioned.
    uc = u - u.mean()
    pc = pv - pv.mean()
    record = n * dt
    sst_dy = float(np.sum((np.diff(pc) - np.diff(pc).mean()) ** 2)) or 1e-300

    results: dict[str, tuple] = {}
    if integrating in (None, False):
        d, tau, gain, pv_bias_c, x0, ub_c, sse = _fit_foptd(uc, pc, dt, d_max, 20.0 * record)
        results["foptd"] = (
            1.0 - sse / (float(np.var(pc[d + 1 :])) or 1e-300),
            _arx_r2_at(uc, pc, d, False, sst_dy),
            dict(
                d=d,
                tau=tau,
                gain=gain,
                pv_bias=pv_bias_c + pv.mean(),
                x0=x0,
                u_bias=ub_c + u.mean(),
            ),
        )
    if integrating in (None, True):
        cost = _arx_scan(uc, pc, d_max, integrating=True)
        d0 = _pick_dead_time(cost)
        d, gain, pv0_c, ub_c, sse = _fit_integrating(uc, pc, dt, d0)
        results["integrating"] = (
            1.0 - sse / (float(np.var(pc[d + 1 :])) or 1e-300),
            _arx_r2_at(uc, pc, d, True, sst_dy),
            dict(d=d, gain=gain, pv_bias=pv0_c + pv.mean(), u_bias=ub_c + u.mean()),
        )
    if integrating is None:
        chosen = (
            "integrating"
            if results["integrating"][0] >= results["foptd"][0] - INTEGRATING_R2_MARGIN
            else "foptd"
        )
    else:
        chosen = "integrating" if integrating else "foptd"
    r2, arx_r2, p = results[chosen]
    candidates = {k: v[0] for k, v in results.items()}
    if chosen == "integrating":
        if p["gain"] == 0.0:
            raise DataError("pv does not respond to the process input: no integrating model")
        return ProcessFit(
            process=Integrating(gain=p["gain"], dead_time=p["d"] * dt),
            u_bias=p["u_bias"],
            pv_bias=p["pv_bias"],
            initial_deviation=0.0,
            fit_r2=r2,
            arx_r2=arx_r2,
            integrating=True,
            dead_time_samples=p["d"],
            candidates=candidates,
        )
    if p["gain"] == 0.0:
        raise DataError("pv does not respond to the process input: no FOPTD model")
    return ProcessFit(
        process=FOPTD(gain=p["gain"], time_constant=p["tau"], dead_time=p["d"] * dt),
        u_bias=p["u_bias"],
        pv_bias=p["pv_bias"],
        initial_deviation=p["x0"],
        fit_r2=r2,
        arx_r2=arx_r2,
        integrating=False,
        dead_time_samples=p["d"],
        candidates=candidates,
    )


def _arx_r2_at(u, pv, d, integrating, sst_dy) -> float:
    """R^2 of the one-step ARX prediction at dead time d, on pv differences."""
    x = _delayed(u, d)[:-1]
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
        raise UsageError("process must be a FOPTD or Integrating model (stictiondiag.processes)")
    dt = _check_dt(dt)
    u = _as_signal(u, "u")
    pv = _as_signal(pv, "pv")
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
    k = np.arange(u.size)
    if isinstance(process, Integrating):
        X = _integrating_regressors(u, d, dt)[d + 1 :]
        target = pv[d + 1 :] - gain * X[:, 1]
        coef, *_ = np.linalg.lstsq(X[:, [0, 2]], target, rcond=None)
        pv0, slope = float(coef[0]), float(coef[1])
        fit = ProcessFit(process, -slope / gain, pv0, 0.0, math.nan, math.nan, True, d)
    else:
        a = math.exp(-dt / float(process.time_constant))
        u_bias = float(u.mean())
        k = k[d + 1 :]
        target = pv[k] - gain * (_lag_response(u, d, a)[k] - u_bias)
        coef, *_ = np.linalg.lstsq(np.column_stack([np.ones(k.size), a**k]), target, rcond=None)
        fit = ProcessFit(
            process, u_bias, float(coef[0]), float(coef[1]), math.nan, math.nan, False, d
        )
    # Rows within the first dead time are left out, as in identify_process.
    r2 = _r2(pv[d + 1 :], fit.simulate(u, dt)[d + 1 :])
    kind = "integrating" if fit.integrating else "foptd"
    return ProcessFit(
        process=process,
        u_bias=fit.u_bias,
        pv_bias=fit.pv_bias,
        initial_deviation=fit.initial_deviation,
        fit_r2=r2,
        arx_r2=_arx_r2_at(
            u, pv, d, fit.integrating, float(np.var(np.diff(pv))) * (u.size - 1) or 1e-300
        ),
        integrating=fit.integrating,
        dead_time_samples=d,
        candidates={kind: r2},
    )
