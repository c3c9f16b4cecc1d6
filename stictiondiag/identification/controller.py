"""Identification of the PI controller of a loop from closed-loop data (Eq. 3).

The replay of a sticky loop (Choudhury, Thornhill & Shah 2005, Sections 4.2.2 and
5.3) needs the PI controller ``C(s) = Kc (Ti s + 1) / (Ti s)`` that maps the control
error ``e = sp - pv`` to the valve demand ``op``.  Two fits of the one law:

:func:`identify_controller`
    Velocity form of the discrete PI law (backward-Euler integral),
    ``op[k] - op[k-1] = Kc (e[k] - e[k-1]) + Kc dt / Ti e[k]``, fitted by least
    squares.  Differencing removes the unknown bias (manual reset or integral state),
    so the fit needs no initial condition.  ``Kc`` may be negative (a reverse-acting
    controller in the paper's sign convention ``e = sp - pv``).  When the integral
    term is not significant the controller is proportional only (``Ti = inf``).
    Differences that touch a saturated ``op`` (held at its recorded minimum or
    maximum, see :func:`saturated_samples`) are excluded: there the controller's law
    does not hold.  Differences the law does not explain elsewhere (anti-windup acting
    next to a limit, manual mode, historian glitches) are trimmed as outliers:
    residuals beyond :data:`TRIM_SIGMAS` robust standard deviations are left out and
    the fit repeated.  Without a recorded setpoint the setpoint is taken as constant
    at the mean of pv (an integrating controller holds pv at its setpoint on average).
    A first-order pv filter in front of the law is searched (``pv_filter``).

:func:`fit_controller_replay`
    Position form on a filtered pv with per-sample weights, for the driven replay of
    the gap diagnosis, which fits on some blocks of the record and judges on others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from stictiondiag.core.checks import as_signal, check_dt
from stictiondiag.core.errors import DataError, StictionError, UsageError
from stictiondiag.core.filters import lfilter1
from stictiondiag.core.robust import robust_std
from stictiondiag.core.serialize import to_plain
from stictiondiag.identification.numerics import MIN_SAMPLES, r_squared, wls
from stictiondiag.models.processes import PI

#: Outlier trimming of the velocity-form fit: residuals beyond this many robust
#: standard deviations are left out [-], for at most TRIM_ROUNDS refits.
TRIM_SIGMAS = 5.0


TRIM_ROUNDS = 4


#: t-statistic of the integral term below which the controller is called P-only [-].
INTEGRAL_T_THRESHOLD = 3.0


#: op within this fraction of its recorded range of the recorded minimum or maximum
#: counts as at the limit [-] (rounding of a clamped value).
SATURATION_TOLERANCE = 1e-6


#: op held at a limit this long or longer counts as saturated [samples].
SATURATION_PLATEAU = 3


#: pv filters tried by the controller identification [samples], and the share of the
#: unfiltered law's residual variance a filter must at most leave to be kept [-].
PV_FILTER_GRID = (0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.7, 8.0, 11.0, 16.0)


PV_FILTER_GAIN = 0.5


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
    n_used, n_saturated, n_outliers : int
        Differences used in the fit; samples flagged as saturated; differences left
        out as outliers of the PI law.
    integral_t_stat : float
        t-statistic of the integral coefficient [-].
    pv_filter_time : float
        Time constant of the first-order filter the controller applies to pv before
        forming the error [s]; 0 for none.  Distributed control systems filter the
        measurement; the PI law then holds for the filtered pv only.
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
    n_outliers: int = 0
    pv_filter_time: float = 0.0

    def to_dict(self) -> dict:
        """JSON-able dict (``integral_time_s`` is None for a P-only controller)."""
        ti = self.controller.integral_time
        return {
            "type": "p" if self.p_only else "pi",
            "gain": to_plain(self.controller.gain),
            "integral_time_s": to_plain(ti),
            "op_bias": to_plain(self.op_bias),
            "fit_r2": to_plain(self.fit_r2),
            "op_fit_r2": to_plain(self.op_fit_r2),
            "p_only": bool(self.p_only),
            "reverse_acting": bool(self.reverse_acting),
            "sp_assumed": bool(self.sp_assumed),
            "n_used": int(self.n_used),
            "n_saturated": int(self.n_saturated),
            "n_outliers": int(self.n_outliers),
            "pv_filter_time_s": to_plain(self.pv_filter_time),
            "integral_t_stat": to_plain(self.integral_t_stat),
        }


def saturated_samples(op: np.ndarray) -> np.ndarray:
    """Boolean mask of samples where op is pinned at a limit.

    op held for at least :data:`SATURATION_PLATEAU` samples at its recorded minimum
    or maximum (within :data:`SATURATION_TOLERANCE` of the op range): a clamp, at 0 or
    100 % or at other output limits.  The units of op are not assumed (plant data are
    often scaled), so the limits are taken from the record.  Other stretches where
    the PI law does not hold (anti-windup acting next to a limit, manual mode) are
    left to the outlier trimming of :func:`identify_controller`.
    """
    op = np.asarray(op, dtype=float)
    sat = np.zeros(op.size, dtype=bool)
    if op.size < SATURATION_PLATEAU:
        return sat
    lo, hi = float(np.nanmin(op)), float(np.nanmax(op))
    tol = SATURATION_TOLERANCE * (hi - lo)
    if hi - lo <= 0.0:
        return sat
    for at in (op <= lo + tol, op >= hi - tol):
        edges = np.diff(np.concatenate(([0], at.astype(np.int8), [0])))
        starts = np.flatnonzero(edges == 1)
        ends = np.flatnonzero(edges == -1)
        for s0, e0 in zip(starts, ends, strict=True):
            # Held, not passing through: the run must be flat, not a turning peak.
            if e0 - s0 >= SATURATION_PLATEAU and np.ptp(op[s0:e0]) <= tol:
                sat[s0:e0] = True
    return sat


def filtered_pv(pv: np.ndarray, time_constant: float, dt: float) -> np.ndarray:
    """First-order filter of pv as a controller applies it, ``f[k] = a f[k-1] + (1 - a)
    pv[k]`` with ``a = exp(-dt / T)``, started at ``pv[0]``; ``T = 0`` returns pv."""
    pv = np.asarray(pv, dtype=float)
    if not time_constant > 0.0:
        return pv
    a = math.exp(-dt / float(time_constant))
    return lfilter1((1.0 - a,), -a, pv, zi=a * pv[0])


def _checked_record(sp, pv, op, dt):
    """The arguments of the controller fits checked once, at their entrance:
    ``(dt, sp, pv, op)`` as a float and one-dimensional float arrays of one length
    (``sp`` None when not recorded); bad input raises a one-line
    :class:`UsageError`.  The fits' private steps take them as checked."""
    dt = check_dt(dt)
    pv = as_signal(pv, "pv")
    op = as_signal(op, "op")
    if pv.size != op.size:
        raise UsageError(f"pv and op must have the same length, got {pv.size} and {op.size}")
    if sp is not None:
        sp = as_signal(sp, "sp")
        if sp.size != pv.size:
            raise UsageError(f"sp and pv must have the same length, got {sp.size} and {pv.size}")
    return dt, sp, pv, op


def identify_controller(
    sp: np.ndarray | None,
    pv: np.ndarray,
    op: np.ndarray,
    dt: float,
    *,
    pv_filter: str | float | None = "auto",
) -> ControllerFit:
    """Identify the PI controller, with the pv filter in front of it (Eq. 3).

    ``pv_filter="auto"`` tries first-order pv filters of :data:`PV_FILTER_GRID`
    samples and keeps the one whose PI law fits op best, if it leaves at most
    :data:`PV_FILTER_GAIN` of the unfiltered law's residual variance; a number is
    the filter's time constant [s]; None or 0 means no filter.  A filter the
    controller applies and the fit ignores biases ``Kc`` and ``Ti`` badly (the
    filtered error lags the recorded one).  See :func:`_identify_pi` for the law.

    Cost O(n): one fit per filter of the grid (12 with ``"auto"``), each at most
    :data:`TRIM_ROUNDS` least-squares fits and medians of the record's residuals.
    """
    dt, sp, pv, op = _checked_record(sp, pv, op, dt)
    if pv_filter is None or (not isinstance(pv_filter, str) and not pv_filter > 0.0):
        return _identify_pi(sp, pv, op, dt)
    if not isinstance(pv_filter, str):
        if not math.isfinite(float(pv_filter)):
            raise UsageError(f"pv_filter must be 'auto', None or a time in s, got {pv_filter}")
        fit = _identify_pi(sp, filtered_pv(pv, float(pv_filter), dt), op, dt)
        return replace(fit, pv_filter_time=float(pv_filter))
    if pv_filter != "auto":
        raise UsageError(f"pv_filter must be 'auto', None or a time in s, got {pv_filter!r}")
    best = plain = _identify_pi(sp, pv, op, dt)
    plain_unexplained = 1.0 - best.fit_r2
    for samples in PV_FILTER_GRID:
        T = samples * dt
        try:
            fit = _identify_pi(sp, filtered_pv(pv, T, dt), op, dt)
        except DataError:
            continue
        # The law is judged on the samples it keeps; a filter must also not worsen
        # the reconstruction of op over the whole record.  On a quantised pv a long
        # filter fits the stretches between pv's steps exactly and leaves the steps
        # out as outliers (Kc and Ti a tenth of the truth).
        if (
            fit.fit_r2 > best.fit_r2
            and fit.n_used >= best.n_used * (1.0 - PV_FILTER_GAIN)
            and fit.op_fit_r2 >= plain.op_fit_r2
        ):
            best = replace(fit, pv_filter_time=T)
    if best.pv_filter_time > 0.0 and 1.0 - best.fit_r2 > PV_FILTER_GAIN * plain_unexplained:
        return _identify_pi(sp, pv, op, dt)
    return best


#: Trimming stops before it keeps less than this share of the rows where a
#: regressor is not zero.
TRIM_KEEP_REGRESSOR = 0.1


def _active_rows(X: np.ndarray) -> np.ndarray:
    """Rows where each column of ``X`` is not zero (beyond rounding), column-major
    (one contiguous row mask per column)."""
    magnitude = np.abs(X)
    return np.ascontiguousarray((magnitude > 1e-12 * np.max(magnitude, axis=0)).T)


def _loses_regressor(active: np.ndarray, keep: np.ndarray, inlier: np.ndarray) -> bool:
    """Whether going from the rows ``keep`` to ``inlier`` keeps less than
    :data:`TRIM_KEEP_REGRESSOR` of the rows where a column of ``X`` is not zero
    (``active``, :func:`_active_rows`; a quantised pv: the error changes at its steps
    only).  O(n) per column, no copies of ``X``."""
    total = np.array([np.count_nonzero(col & keep) for col in active])
    kept = np.array([np.count_nonzero(col & inlier) for col in active])
    return bool(np.any((total > 0) & (kept < TRIM_KEEP_REGRESSOR * total)))


def _identify_pi(sp: np.ndarray | None, pv: np.ndarray, op: np.ndarray, dt: float) -> ControllerFit:
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
    X = np.column_stack([de, ek])
    active = _active_rows(X)
    keep = np.ones(dop.size, dtype=bool)
    floor = 1e-9 * max(float(np.std(dop)), 1e-300)
    for _ in range(TRIM_ROUNDS):
        coef, *_ = np.linalg.lstsq(X[keep], dop[keep], rcond=None)
        resid = dop - X @ coef
        r_in = resid[keep]
        sigma = robust_std(r_in)
        inlier = np.abs(resid) <= max(TRIM_SIGMAS * sigma, floor)
        if inlier.sum() < max(MIN_SAMPLES, dop.size // 2) or np.array_equal(inlier, keep):
            break
        # A quantised pv changes at a few samples only, where a small pv filter of
        # the controller leaves the largest residuals: trimming them would leave
        # the proportional term nothing to be fitted on (Kc = 0, no PI law).
        if _loses_regressor(active, keep, inlier):
            break
        keep = inlier
    coef, t_int, _ = _lstsq_t(X[keep], dop[keep])
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
        coef1, *_ = np.linalg.lstsq(de[keep, None], dop[keep], rcond=None)
        kc = float(coef1[0])
    if kc == 0.0 or not math.isfinite(kc):
        raise DataError("op does not respond to the control error: no PI law found")
    return data.result(kc, ti, float(t_int), keep)


def controller_fit(
    controller: PI,
    sp: np.ndarray | None,
    pv: np.ndarray,
    op: np.ndarray,
    dt: float,
    *,
    pv_filter_time: float = 0.0,
) -> ControllerFit:
    """Fit measures and op bias of a *given* PI controller on recorded data.

    Same conventions as :func:`identify_controller` (``integral_time = inf`` for a
    P-only law); ``Kc``, ``Ti`` and the pv filter [s] are kept, only ``op_bias`` is
    estimated.
    """
    if not isinstance(controller, PI):
        raise UsageError("controller must be a PI model (stictiondiag.models.processes.PI)")
    kc, ti = float(controller.gain), float(controller.integral_time)
    if kc == 0.0 or not math.isfinite(kc) or not ti > 0.0:
        raise UsageError(f"controller needs a non-zero gain and Ti > 0, got Kc={kc}, Ti={ti}")
    dt, sp, pv, op = _checked_record(sp, pv, op, dt)
    pv_f = filtered_pv(pv, pv_filter_time, dt)
    fit = _ControllerData.build(sp, pv_f, op, dt).result(kc, ti, math.nan)
    return replace(fit, pv_filter_time=float(pv_filter_time))


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
        """The data of arguments checked by :func:`_checked_record` (``pv`` possibly
        filtered since)."""
        sp_assumed = sp is None
        sp_arr = np.full(pv.size, float(np.nanmean(pv))) if sp_assumed else sp
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

    def result(
        self, kc: float, ti: float, t_int: float, keep: np.ndarray | None = None
    ) -> ControllerFit:
        dop = self.dop
        if keep is None:
            keep = np.ones(dop.size, dtype=bool)
        p_only = math.isinf(ti)
        ki_dt = 0.0 if p_only else kc * self.dt / ti
        resid = (dop - kc * self.de - ki_dt * self.ek)[keep]
        dop = dop[keep]
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
            op_fit_r2=r_squared(self.op[good], law[good] + op_bias),
            p_only=p_only,
            reverse_acting=kc < 0.0,
            sp_assumed=self.sp_assumed,
            n_used=int(keep.sum()),
            n_saturated=self.n_saturated,
            n_outliers=int(keep.size - keep.sum()),
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


@dataclass(frozen=True)
class ControllerReplay:
    """The PI law that replays a recorded op (:func:`fit_controller_replay`).

    Attributes
    ----------
    gain : float
        Kc [% of span / pv units].
    integral_time_s : float or None
        Ti [s]; None without integral action.
    filter_time_s : float
        Time constant of the first-order filter on pv [s] (0: none).
    bias : float
        op at zero error and zero integral [% of span].
    """

    gain: float
    integral_time_s: float | None
    filter_time_s: float
    bias: float

    def to_dict(self) -> dict:
        return to_plain(
            {
                "gain": self.gain,
                "integral_time_s": self.integral_time_s,
                "filter_time_s": self.filter_time_s,
                "bias": self.bias,
            }
        )


def fit_controller_replay(
    sp: np.ndarray | None, pv: np.ndarray, op: np.ndarray, dt: float, w: np.ndarray
) -> tuple[np.ndarray, ControllerReplay]:
    """PI controller replay on a filtered measurement (Eq. 3).

    ``op = bias + Kc (e + (1/Ti) integral(e))``, ``e = sp - pv_f`` with ``pv_f`` a
    first-order filtered pv (a transmitter or DCS filter); linear least squares in
    (bias, Kc, Kc/Ti) for each filter time on a short grid.  Without a recorded set
    point a ramp column absorbs the constant set point in the integral.

    Parameters
    ----------
    sp : ndarray or None
        Set point [pv units], None when not recorded.
    pv : ndarray
        Process variable [pv units].
    op : ndarray
        Controller output [% of span].
    dt : float
        Sample time [s].
    w : ndarray
        Weights of the samples the law is fitted on (0 or 1).

    Returns
    -------
    op_hat : ndarray
        Replayed controller output [% of span].
    params : ControllerReplay
        Kc [% / pv units], Ti [s] (None without integral action), the pv filter's
        time constant [s] and the bias [% of span].
    """
    n = op.size
    sp_fixed = sp is None
    sp = np.zeros(n) if sp is None else sp
    best = None
    for tf in (0.0, 0.5, 1.0, 2.0, 3.0, 5.0):
        pvf = filtered_pv(pv, tf * dt, dt) if tf > 0 else pv
        e = sp - pvf
        cols = [np.ones(n), e, np.cumsum(e) * dt]
        if sp_fixed:
            cols.append(np.arange(n, dtype=float) * dt)
        X = np.column_stack(cols)
        coef = wls(X, op, w)
        pred = np.clip(X @ coef, 0.0, 100.0)
        sse = float(np.dot(w, (pred - op) ** 2))
        if best is None or sse < best[0]:
            best = (sse, pred, coef, tf)
    assert best is not None  # the loop over the filter times ran at least once
    _, pred, coef, tf = best
    kc, ki = float(coef[1]), float(coef[2])
    ti = kc / ki if abs(ki) > 1e-12 and kc / ki > 0 else None
    return pred, ControllerReplay(
        gain=kc, integral_time_s=ti, filter_time_s=tf * dt, bias=float(coef[0])
    )


#: R^2 of the velocity-form PI law (:attr:`ControllerFit.fit_r2`) from which the
#: controller's sign is taken as well determined [-].  Measured on simulated loops
#: only (``benchmarks/gain_sign_family.py``: 300 loops of the training family,
#: seeds 20000-20299, mv removed, every process gain and controller gain positive):
#: with the recorded set point one identified gain of 288 had the wrong sign, at R^2
#: -0.06; with the set point dropped (a cascade slave whose set point moves is then
#: read against a constant one) four had, all at R^2 <= 0.06.  Below about 0.2 the
#: law explains too little of op's moves for its sign to mean anything (op is then
#: not computed from this pv: a moving set point that is not recorded, a
#: compressed or quantised record); above it, no wrong sign in either case, and 98 %
#: (with sp) and 93 % (without) of the loops keep a sign.  The margin of about three
#: over the worst wrong sign is deliberate: a wrong sign held would force a
#: positive-feedback model on the loop.
SIGN_MIN_R2 = 0.2


def loop_gain_sign(
    sp: np.ndarray | None, pv: np.ndarray, op: np.ndarray, dt: float
) -> tuple[int, float]:
    """The sign a process gain (pv per op) needs to close a negative feedback loop
    with this loop's controller, and the R^2 of the controller's law [-].

    A loop that runs under control has ``Kc Kp > 0`` (``e = sp - pv``), so the
    process gain has the sign of ``Kc`` (:func:`identify_controller`).  Returns
    ``(sign(Kc), fit_r2)`` when the law's R^2 reaches :data:`SIGN_MIN_R2`, else
    ``(0, fit_r2)``: the sign is not well determined; ``(0, nan)`` when no law is
    found.  Cost O(n), that of :func:`identify_controller`.
    """
    try:
        cf = identify_controller(sp, pv, op, dt)
    except (StictionError, ValueError, FloatingPointError, np.linalg.LinAlgError):
        return 0, math.nan
    r2 = float(cf.fit_r2)
    kc = float(cf.controller.gain)
    if not (math.isfinite(r2) and r2 >= SIGN_MIN_R2 and math.isfinite(kc) and kc != 0.0):
        return 0, r2
    return (1 if kc > 0 else -1), r2
