"""Prediction-error fit of the process with the unmeasured load tracked (Section 4.2.2, Eq. 3).

The process is a first-order lag with dead time (or an integrator, pole 1), as in
Eq. 3 and Table 3 of Choudhury, Thornhill & Shah (2005).  Plant loops carry load
changes that the controller answers with the valve: a replay that drives the process
with the recorded mv alone departs from pv by the whole load, which is as large as
the cycle itself.  :func:`fit_predictor` therefore tracks the load with a steady-state
Kalman filter (a random-walk load entering with the valve, white measurement noise)
and predicts pv ``h`` samples ahead (``h`` = dead time + time constant); the
innovations are linear in the gain (and in a fractional dead time), solved by least
squares on a grid of poles, dead times and load-to-noise ratios.

The filter itself (its gains, prediction errors and variances, the innovation
responses to the input, the pv noise floor of a fitted replay) and the compiled parts
(the grid's sums, the linear solve) are in
:mod:`stictiondiag.identification.predictor_kernels`.

This is the process fit of the gap diagnosis (:mod:`stictiondiag.gap`), which fits on
some blocks of the record and judges on others (per-sample weights).  The closed-loop
replay uses the output-error fit of the same structures
(:func:`stictiondiag.identification.process.identify_process`): it simulates the
loop freely, without a filter to track the load.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.identification.numerics import (
    fractional_delay_wls,
    golden_section,
)
from stictiondiag.identification.predictor_kernels import (
    _prediction_errors_rows,
    extra_start,
    kalman_gains,
    shifted_grams,
    shifted_pair_wls,
)
from stictiondiag.identification.process_result import (
    Objective,
    PredictionFit,
    ProcessFit,
    ProcessModel,
)
from stictiondiag.models.processes import FOPTD, Integrating

#: Entries kept per kind in a cache of process terms (:func:`fit_predictor`).
_CACHE_ENTRIES = 24


def _cache_put(cache: dict | None, kind: str, key, value: tuple) -> None:
    """Remember ``value`` (the arrays the key names, then the value) under ``key``."""
    if cache is None:
        return
    store = cache.setdefault(kind, {})
    if len(store) >= _CACHE_ENTRIES:
        try:
            del store[next(iter(store))]
        except (KeyError, StopIteration, RuntimeError):  # pragma: no cover - a race
            pass
    store[key] = value


def _cached(cache: dict | None, kind: str, key, compute):
    """The last item of ``compute()`` (the arrays its key names, then the value),
    remembered in ``cache[kind]`` under ``key`` (bounded, oldest out)."""
    if cache is None:
        return compute()[-1]
    store = cache.setdefault(kind, {})
    hit = store.get(key)
    if hit is not None:
        return hit[-1]
    value = compute()
    if len(store) >= _CACHE_ENTRIES:
        try:
            del store[next(iter(store))]
        except (KeyError, StopIteration, RuntimeError):  # pragma: no cover - a race
            pass
    store[key] = value
    return value[-1]


def _pair_sse(G, g, ee, ii, jj) -> np.ndarray:
    """Error left by the input at dead times ``d`` and ``d + 1`` for every dead time of
    the grid at once (rows ``ii`` and ``jj`` of the Gram matrix ``G`` of the shifted
    regressors, ``g`` their products with the innovations, ``ee`` the innovations' sum
    of squares); inf where the 2 x 2 system is singular.

    The two gains are solved in closed form (Cramer's rule) with a tiny ridge; a pair
    of opposite signs (a dead time between d and d + 1 weighs both with one sign) is
    replaced by the better single column, as in :func:`fractional_delay_wls`.
    O(number of dead times).
    """
    a00 = G[ii, ii] + 1e-12 * (G[ii, ii] + 1e-300)
    a11 = G[jj, jj] + 1e-12 * (G[jj, jj] + 1e-300)
    a01, a10 = G[ii, jj], G[jj, ii]
    r0, r1 = -g[ii], -g[jj]
    det = a00 * a11 - a01 * a10
    with np.errstate(divide="ignore", invalid="ignore"):
        c0 = (r0 * a11 - a01 * r1) / det
        c1 = (a00 * r1 - a10 * r0) / det
        explained = r0 * c0 + r1 * c1
        # On the boundary: the better single column (the first on a tie).
        e0, e1 = r0 * r0 / a00, r1 * r1 / a11
    single = np.where(e1 > e0, e1, e0)
    explained = np.where(c0 * c1 < 0.0, single, explained)
    sse = ee - explained
    return np.where((det != 0.0) & np.isfinite(sse), sse, np.inf)


def _structure_grid(u: np.ndarray, pv: np.ndarray, w: np.ndarray):
    """The one-step prediction-error fit on a grid of poles, dead times and load ratios.

    Returns the best ``(sse, ProcessModel)``, the best per pole and the dead-time grid
    (see :func:`fit_predictor`).  Per pole, the filters of its load ratios run side by
    side in one compiled call; per filter, the about three Gram entries per dead time
    that :func:`_pair_sse` uses (:func:`shifted_grams`).  O(n) per pole, load ratio
    and dead time.
    """
    n = u.size
    taus = np.geomspace(0.5, max(n / 8.0, 2.0), 14)
    pole_grid = np.concatenate([np.exp(-1.0 / taus), [1.0]])
    ratios = (1e-6, 1e-4, 1e-3, 1e-2, 1e-1)
    d_max = int(min(max(n // 10, 5), 200))
    d_grid = np.unique(
        np.concatenate(
            [np.arange(0, min(d_max, 8)), np.geomspace(8, max(d_max, 9), 10).astype(int)]
        )
    )
    best = None
    per_pole: dict = {}
    shifts = np.unique(np.concatenate([d_grid, d_grid + 1]))
    where = {int(d): i for i, d in enumerate(shifts)}
    ii = np.array([where[int(d)] for d in d_grid])
    jj = np.array([where[int(d) + 1] for d in d_grid])
    u0 = np.ascontiguousarray(u - u[0])
    nr = len(ratios)
    # The filters of one pole's load ratios side by side: pv's innovations (rows
    # 0..nr-1, undriven, from pv[0]) and the input's response (rows nr.., driven by
    # u - u[0], from 0), each row with the numbers of its own filter alone.
    Zs, Ds = np.stack([pv, np.zeros(n)]), np.stack([np.zeros(n), u0])
    rows = np.repeat(np.arange(2), nr)
    y0 = np.zeros(2 * nr)
    y0[:nr] = float(pv[0])
    unused = np.empty((0, n))  # no extra rows
    for pole in pole_grid:
        gains = [kalman_gains(pole, lr) for lr in ratios]
        k1 = np.array([g[0] for g in gains] * 2)
        k2 = np.array([g[1] for g in gains] * 2)
        R = _prediction_errors_rows(
            Zs, unused, rows, Ds, rows, y0, np.full(2 * nr, pole), k1, k2, 1
        )
        for r, lr in enumerate(ratios):
            # All dead times at once: the entries of the Gram matrix of the shifted
            # regressors (row i: ``delayed(base_reg, shifts[i])``) that the pairs use.
            G, g, ee = shifted_grams(R[nr + r], R[r], w, shifts, ii, jj)
            sse = _pair_sse(G, g, ee, ii, jj)
            k = int(np.argmin(sse))
            if not math.isfinite(sse[k]):
                continue
            cand = (float(sse[k]), ProcessModel(float(pole), int(d_grid[k]), float(lr)))
            if best is None or cand[0] < best[0]:
                best = cand
            if pole not in per_pole or cand[0] < per_pole[pole][0]:
                per_pole[pole] = cand
    return best, per_pole, d_grid


def _put_delayed(out: np.ndarray, u: np.ndarray, shift: int) -> None:
    """Write :func:`delayed` ``(u, shift)`` into ``out`` (the same values, no temporary)."""
    shift = max(shift, 0)
    out[:shift] = u[0]
    out[shift:] = u[: u.size - shift]


class _Replay:
    """The linear part of :func:`fit_predictor` for one record: for a given structure,
    the filter's innovations of pv and the responses of the input (and of any extra
    columns), then the weighted least-squares coefficients (Section 4.2.2, Eq. 3).

    Terms that depend on the structure only (the innovations of pv, the input's
    response) are shared with the other fits of this context through ``cache``: the
    searches over an effect's parameter refit the linear coefficients many times with
    one structure.  Keys hold the arrays they name (an identity stays unique while it
    is held).  The three terms of each filter are remembered for this fit
    (:meth:`filtered`), and so are the solved structures (:meth:`solve`); a grid's
    filters are computed in one compiled call (:meth:`prefetch`).  A structure costs
    O(n p^2) for ``p`` columns once its filter's terms are there, and O(n) per
    filtered row before.
    """

    def __init__(self, u, pv, w, extra, cache):
        self.n = n = u.size
        self.u = u = np.ascontiguousarray(u, dtype=float)
        self.pv = pv = np.ascontiguousarray(pv, dtype=float)
        self.w = w
        # Without a shared cache, one of this fit's own.
        self.cache = {} if cache is None else cache
        self.zeros = np.zeros(n)
        extra_cols = None if extra is None else np.atleast_2d(extra.T).T
        self.u_key = (id(u), id(pv))
        self.memo: dict = {}
        self.extra_rows = None if extra_cols is None else np.ascontiguousarray(extra_cols.T)
        self.n_extra = 0 if self.extra_rows is None else self.extra_rows.shape[0]
        # The terms of the filters used, by filter (:meth:`filtered`; bounded).
        self.filter_memo: dict = {}
        self.no_extra = np.empty((0, n))
        # Signals the filter rows read: pv and zeros (rows 0, 1), the extra columns
        # (rows 2..), and their drives: zeros and u - u[0] (shared by the fits of the
        # context).
        self.src_z = _cached(
            self.cache, "signals", id(pv), lambda: (pv, np.stack([pv, self.zeros]))
        )
        self.src_d = _cached(
            self.cache,
            "drives",
            self.u_key,
            lambda: (u, pv, np.stack([self.zeros, u - u[0]])),
        )
        self.u0 = self.src_d[1]

    def prefetch(self, models) -> None:
        """Filter whatever the structures ``models`` (one horizon) still lack, in one
        compiled call: their rows run side by side (a grid's filters cost little more
        than one), each with its own filter's numbers (:func:`_prediction_errors_rows`).
        The innovations and the input's response go to the shared cache, and the
        three terms of each filter to this fit's memo (:meth:`filtered`)."""
        cache, pv, memo = self.cache, self.pv, self.filter_memo
        innovations = cache.setdefault("innovations", {})
        responses = cache.setdefault("input_response", {})
        todo = []
        zi: list = []  # per row: row of src_z then extra_rows, row of src_d
        di: list = []
        par: list = []  # per row: start, pole, k1, k2
        for m in models:
            fkey = (m.pole, m.load_ratio, m.horizon)
            if fkey in memo:
                continue
            e_key, b_key = (id(pv), *fkey), (*self.u_key, *fkey)
            e0, base = innovations.get(e_key), responses.get(b_key)
            k1, k2 = kalman_gains(m.pole, m.load_ratio)
            first = len(zi)
            if e0 is None:
                zi.append(0)
                di.append(0)
                par.append((float(pv[0]), m.pole, k1, k2))
            if base is None:
                zi.append(1)
                di.append(1)
                par.append((0.0, m.pole, k1, k2))
            for i in range(self.n_extra):
                zi.append(2 + i)
                di.append(0)
                # The filter of an extra column starts at the column's first value,
                # as pv's starts at pv[0] (:func:`~stictiondiag.identification.predictor_kernels.extra_start`).
                par.append((extra_start(self.extra_rows[i]), m.pole, k1, k2))
            todo.append((fkey, e_key, b_key, e0, base, first))
        if not todo:
            return
        R = None
        if zi:
            P = np.array(par)
            R = _prediction_errors_rows(
                self.src_z,
                self.extra_rows if self.n_extra else self.no_extra,
                np.array(zi),
                self.src_d,
                np.array(di),
                P[:, 0],
                P[:, 1],
                P[:, 2],
                P[:, 3],
                models[0].horizon,
            )
        for fkey, e_key, b_key, e0, base, i in todo:
            if e0 is None:
                assert R is not None
                e0 = R[i]
                _cache_put(cache, "innovations", e_key, (pv, e0))
                i += 1
            else:
                e0 = e0[-1]
            if base is None:
                assert R is not None
                base = R[i]
                _cache_put(cache, "input_response", b_key, (self.u, pv, base))
                i += 1
            else:
                base = base[-1]
            # A structure's extra rows are consecutive: a view of them.
            E = R[i : i + self.n_extra] if self.n_extra and R is not None else self.no_extra
            if len(memo) >= _CACHE_ENTRIES:
                del memo[next(iter(memo))]
            memo[fkey] = (e0, base, E)

    def filtered(self, m: ProcessModel):
        """Innovations of pv, the input's response (both shared through the cache) and
        the extra columns' responses (rows) for the filter of ``m``."""
        fkey = (m.pole, m.load_ratio, m.horizon)
        hit = self.filter_memo.get(fkey)
        if hit is None:
            self.prefetch([m])
            hit = self.filter_memo[fkey]
        return hit

    def terms(self, m: ProcessModel):
        """Innovations of pv and the regressors ``X`` of the structure ``m``: the input's
        response at the dead times d and d + 1, then the extra columns' responses."""
        e0, base, E = self.filtered(m)
        X = np.empty((self.n, 2 + E.shape[0]))
        for j, shift in enumerate((m.delay, m.delay + 1)):
            _put_delayed(X[:, j], base, shift)
        # pv = y + d + e: the disturbance enters like a measurement offset.
        X[:, 2:] = -E.T
        return e0, X

    def solve(self, m: ProcessModel):
        """``(sse, coef, residual)`` of the structure ``m``.

        The searches come back to points already solved (a golden section's last
        point, the chosen structure): the same model, the same numbers.
        """
        hit = self.memo.get(m)
        if hit is None:
            hit = self.memo[m] = self._solve(m)
        return hit

    def _solve(self, m: ProcessModel):
        e0, base, E = self.filtered(m)
        try:
            sse, coef, r = shifted_pair_wls(e0, base, m.delay, E, self.w)
        except np.linalg.LinAlgError:
            # A singular or non-finite system: numpy's path, with its lstsq fallback.
            X = np.empty((self.n, 2 + E.shape[0]))
            for j, shift in enumerate((m.delay, m.delay + 1)):
                _put_delayed(X[:, j], base, shift)
            X[:, 2:] = -E.T
            coef = fractional_delay_wls(X, -e0, self.w)
            r = e0 + X @ coef
            sse = np.dot(self.w, r * r)
        return float(sse), coef, r

    def sse(self, m: ProcessModel) -> float:
        """Weighted sum of squared errors of the structure ``m`` [pv^2]."""
        return self.solve(m)[0]


def _refine_one_step(rep: _Replay, best: tuple, d_grid: np.ndarray) -> tuple:
    """The best one-step structure of the grid refined: the dead time to the sample,
    then the pole (golden section on the log time constant).  Returns ``(sse, model)``.
    """
    m = best[1]
    i = int(np.searchsorted(d_grid, m.delay))
    for d in range(int(d_grid[max(i - 1, 0)]), int(d_grid[min(i + 1, d_grid.size - 1)]) + 1):
        cand = ProcessModel(m.pole, d, m.load_ratio)
        sse = rep.sse(cand)
        if sse < best[0]:
            best = (sse, cand)
    m = best[1]
    if m.pole < 1.0:
        lt0 = math.log(-1.0 / math.log(m.pole))
        lt = golden_section(
            lambda v: rep.sse(ProcessModel(math.exp(-1.0 / math.exp(v)), m.delay, m.load_ratio)),
            lt0 - 0.6,
            lt0 + 0.6,
            12,
        )
        cand = ProcessModel(math.exp(-1.0 / math.exp(lt)), m.delay, m.load_ratio)
        sse = rep.sse(cand)
        if sse < best[0]:
            best = (sse, cand)
    return best


def _prediction_horizon(m: ProcessModel, n: int) -> int:
    """Samples pv is predicted ahead: as far as the process takes to answer a valve
    step, dead time plus one time constant (an integrator answers with a ramp at once;
    a few samples show its slope).  One step ahead, the load tracking hides most of a
    wrong gain or a slow disturbance."""
    tau = 5.0 if m.pole >= 1.0 else min(-1.0 / math.log(max(m.pole, 1e-12)), 40.0)
    return int(min(max(round(m.delay + tau), 2), 60, max(n // 20, 2)))


#: Smallest load-to-noise ratio of an integrating replay (the one-step grid's smallest,
#: :func:`_structure_grid`); see :func:`_lowest_load_exponent`.
INTEGRATOR_MIN_LOAD_RATIO = 1e-6


def _lowest_load_exponent(pole: float) -> float:
    """log10 of the smallest load-to-noise ratio searched for a structure of ``pole``.

    An integrator must track its load.  With the tracking nearly off (ratios near
    1e-10), its filter hardly reads pv, and the replay integrates the valve open
    loop from the record's start: the load offset the controller answers in mv then
    drifts it off without bound, so least squares drives the gain to zero and the
    replay predicts pv at its level, a flat forecast that in a loop held at its set
    point can beat every physical replay at the horizon.  It is not a process: on a
    first-order process of gain 1.6 (time constant 25 s) with a miscalibrated valve it
    was chosen with a gain of 2.3e-4 /s, 270 times below the lag's 0.06 /s, and the gap
    then had no valve to act through.  A lag's open-loop replay is stable and keeps the
    whole range.
    """
    return math.log10(INTEGRATOR_MIN_LOAD_RATIO) if pole >= 1.0 else -math.inf


def _tune_at_horizon(rep: _Replay, cm: ProcessModel, horizon: int) -> tuple[float, ProcessModel]:
    """Load ratio (coarse grid, then golden) and dead time (+-2) at the horizon; an
    integrator's ratio not below :data:`INTEGRATOR_MIN_LOAD_RATIO`
    (:func:`_lowest_load_exponent`)."""
    lowest = _lowest_load_exponent(cm.pole)
    grid = [ProcessModel(cm.pole, cm.delay, 10.0**e, horizon) for e in range(-9, 1) if e >= lowest]
    rep.prefetch(grid)
    sse, cm = min(((rep.sse(g), g) for g in grid), key=lambda v: v[0])
    c0 = math.log10(cm.load_ratio)
    ll = golden_section(
        lambda v: rep.sse(ProcessModel(cm.pole, cm.delay, 10.0**v, horizon)),
        max(c0 - 1.0, lowest),
        c0 + 1.0,
        10,
    )
    cand = ProcessModel(cm.pole, cm.delay, 10.0**ll, horizon)
    c = rep.sse(cand)
    if c < sse:
        sse, cm = c, cand
    for dd in (-2, -1, 1, 2):
        if cm.delay + dd < 0:
            continue
        cand = ProcessModel(cm.pole, cm.delay + dd, cm.load_ratio, horizon)
        c = rep.sse(cand)
        if c < sse:
            sse, cm = c, cand
    return sse, cm


def _judge_at_horizon(rep: _Replay, m: ProcessModel, per_pole: dict, horizon: int) -> ProcessModel:
    """The structure is judged where the replay is: the refined structure ``m``, the
    best lags of the one-step grid and the integrator, each tuned at the horizon (a
    lag and an integrator can predict one step ahead equally well, not further)."""
    best_h = _tune_at_horizon(rep, m, horizon)
    others = sorted(per_pole.values(), key=lambda v: v[0])[:3]
    if 1.0 in per_pole:
        others.append(per_pole[1.0])
    for _, cm in others:
        if cm.pole == m.pole:
            continue
        cand = _tune_at_horizon(rep, cm, horizon)
        if cand[0] < best_h[0]:
            best_h = cand
    return best_h[1]


def _search_structure(rep: _Replay, cache: dict | None) -> ProcessModel:
    """The structure of the replay: the one-step grid (:func:`_structure_grid`),
    refined (:func:`_refine_one_step`), then judged at the prediction horizon
    (:func:`_judge_at_horizon`)."""
    u, pv, w = rep.u, rep.pv, rep.w
    # The grid of structures fits the input alone: shared by every fit of this
    # context with the same input and weights (the extra columns come after).
    best, per_pole, d_grid = _cached(
        cache,
        "structure_grid",
        (*rep.u_key, id(w)),
        lambda: (u, pv, w, _structure_grid(u, pv, w)),
    )
    per_pole = dict(per_pole)
    m = _refine_one_step(rep, best, d_grid)[1]
    horizon = _prediction_horizon(m, rep.n)
    return _judge_at_horizon(rep, m, per_pole, horizon)


def _retune_load(rep: _Replay, m0: ProcessModel) -> ProcessModel:
    """``m0`` with its load-to-noise ratio searched again (golden section over two
    decades below and one above, an integrator's not below
    :data:`INTEGRATOR_MIN_LOAD_RATIO`), kept only where it lowers the error."""
    lo = max(math.log10(m0.load_ratio) - 2.0, _lowest_load_exponent(m0.pole))
    hi = math.log10(m0.load_ratio) + 1.0
    ll = golden_section(
        lambda v: rep.sse(ProcessModel(m0.pole, m0.delay, 10.0**v, m0.horizon)), lo, hi, 12
    )
    cand = ProcessModel(m0.pole, m0.delay, 10.0**ll, m0.horizon)
    if rep.sse(cand) < rep.sse(m0):
        return cand
    return m0


def fit_predictor(
    u: np.ndarray,
    pv: np.ndarray,
    dt: float,
    w: np.ndarray,
    *,
    extra: np.ndarray | None = None,
    model: ProcessModel | None = None,
    retune: bool = False,
    cache: dict | None = None,
) -> ProcessFit:
    """One-step-ahead process replay with the unmeasured load tracked (Section 4.2.2, Eq. 3).

    The process is a first-order lag with dead time (or an integrator, pole 1), as
    in Eq. 3 and Table 3.  Plant loops carry load changes that the controller
    answers with the valve: a replay that drives the process with the recorded mv
    alone departs from pv by the whole load, which is as large as the cycle itself.
    The replay therefore tracks the load with a steady-state Kalman filter (a
    random-walk load entering with the valve, white measurement noise) and predicts
    pv one sample ahead; what it cannot predict is the pv gap.  The innovations are
    linear in the gain (and in a fractional dead time), solved by least squares on a
    grid of poles, dead times and load-to-noise ratios (the prediction-error fit,
    which unlike a plain output-error fit is not biased by the load the controller
    answers).

    Parameters
    ----------
    u : ndarray
        Process input (valve position or flow) [% of span].
    pv : ndarray
        Process variable [pv units].
    dt : float
        Sample time [s].
    w : ndarray
        Weights of the samples the process is fitted on (0 or 1).
    extra : ndarray, optional
        Extra columns (n x m) added to pv (an output disturbance), fitted with the
        process.
    model : ProcessModel, optional
        Keep this structure and fit only the linear coefficients.
    retune : bool
        With ``model``: search the load-to-noise ratio again (an effect in the model
        leaves less for the load tracking to follow).
    cache : dict, optional
        Terms that depend on the structure only (the innovations of pv, the input's
        response), shared by the fits of one record: keyed by the identity of the
        arrays they come from, which the cache holds (see :func:`_cached`).
    """
    rep = _Replay(u, pv, w, extra, cache)
    if model is None:
        model = _search_structure(rep, cache)
    elif retune:
        model = _retune_load(rep, model)
    _, coef, r = rep.solve(model)
    return ProcessFit(
        Objective.PREDICTION_ERROR,
        _process_of(model, coef, dt),
        model.delay,
        PredictionFit(pv=rep.pv - r, model=model, coef=coef),
    )


def _process_of(model: ProcessModel, coef: np.ndarray, dt: float) -> FOPTD | Integrating:
    """The process of a fitted structure: the input's gains at the dead times d and
    d + 1 summed, and the fraction of the second taken as a fractional dead time."""
    pole = model.pole
    integrating = pole >= 1.0
    b = float(coef[0] + coef[1])
    frac = float(coef[1] / b) if abs(b) > 1e-12 else 0.0
    frac = min(max(frac, 0.0), 1.0)
    dead_time = (model.delay + frac) * dt
    if integrating:
        return Integrating(gain=b / dt, dead_time=dead_time)
    tau = -dt / math.log(pole) if pole > 0.0 else 0.0
    return FOPTD(gain=b / (1.0 - pole), time_constant=tau, dead_time=dead_time)
