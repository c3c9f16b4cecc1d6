"""Catalogue of unmodelled effects: augmentations of the driven replay of a loop.

The two-parameter model of Choudhury, Thornhill & Shah (2005) (Section 5.1, Fig. 10,
Eq. 4) never matches a real valve exactly.  Each entry of :data:`EFFECT_MODELS` adds
one named effect to the replay, with its own parameters fitted by least squares, so
:mod:`stictiondiag.gap.diagnose` can ask which effect explains the departure of the replay from
the data.

The *driven replay* feeds every element of the loop with its recorded input, so a
departure is located in the element that causes it:

* valve: ``mv_hat = valve(op)`` (the stiction model, Section 5.1), replayed freely
  from the recorded op;
* process: ``pv_hat = G(mv)`` (first order with dead time, or an integrator; Section
  4.2.2, Eq. 3), driven by the recorded mv (or the modelled mv when mv is not
  recorded) and predicted a dead time plus a time constant ahead, with the unmeasured
  load tracked by a steady-state Kalman filter (:func:`fit_process`);
* controller: ``op_hat = C(sp - pv)`` (a PI controller on a filtered pv, Eq. 3).

The effects and where they act:

=====================  ======  =====================================================
effect                 signal  augmentation (extra parameters)
=====================  ======  =====================================================
actuator_lag           mv      first-order positioner/actuator lag after the friction
                               element (time constant)
miscalibration         mv      moving-phase slope of mv against op not 1 and an offset
                               (Section 4.2.1, Fig. 8 bottom row) (slope, offset); the
                               slips measured in the data must show the slope
                               (:func:`slip_slope_test`)
asymmetry              mv      S and J differ opening and closing (Loop 1, Section 3)
                               (S and J of the second direction)
valve_characteristic   pv, mv  installed characteristic between valve position and
                               flow (Section 5.1, last step of Fig. 10): curvature of an
                               exponential (equal-percentage-like) or power
                               (quick-opening-like) curve, on the process input or on mv;
                               the loop's gain must change with the operating point
                               (:func:`gain_change_test`)
quantization           any     historian or instrument resolution (Loop 4, Section 3):
                               the rounding error ``q^2/12`` of each signal whose values
                               lie on a grid of step ``q`` (one step per signal)
external_disturbance   pv      an oscillation entering the loop that the valve did not
                               cause: a sinusoid and its second harmonic added to pv
                               (frequency, amplitudes, phases); it must keep its phase
                               along the record (:func:`phase_coherence`)
time_varying_stiction  mv      S and J changing during the record: a step, a ramp
                               between two instants or a drift over the record (end
                               values and instants)
=====================  ======  =====================================================

Every fitter takes per-sample weights (0 or 1) so the same code fits on a training
part of the record and is validated on the held-back part (:mod:`stictiondiag.gap.diagnose`).

Searching the thresholds
------------------------
With a noisy demand each breakaway happens at the first noisy sample beyond the
threshold, so a replay is in step with the data only in a narrow region of S and J
(about 1 % of J) and off by whole slips elsewhere; the error is a rugged function
that defeats descent methods.  The searches therefore start from the demand travel
of the slips measured in the data (:func:`measure_slips`), lay dense product grids
over the coupled thresholds (:func:`grid_search_nd`, :func:`needle_search`) and
evaluate thousands of parameter sets per compiled call, abandoning each as soon as
its error exceeds the best so far.  The process fits are vectorised linear least
squares over a grid of poles, dead times and load-to-noise ratios.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.filters import lfilter1
from stictiondiag.core.jit import jit

#: Effect names in the order they are reported; ``none`` is the base two-parameter model.
EFFECTS: tuple[str, ...] = (
    "none",
    "actuator_lag",
    "miscalibration",
    "asymmetry",
    "valve_characteristic",
    "quantization",
    "external_disturbance",
    "time_varying_stiction",
)

#: One-line description of each effect (used in reports and ``--help`` texts).
EFFECT_DESCRIPTIONS: dict[str, str] = {
    "none": "the two-parameter model explains the data to within its noise",
    "actuator_lag": "positioner or actuator dynamics after the friction element",
    "miscalibration": "moving-phase slope of mv against op not 1 (Fig. 8, bottom row)",
    "asymmetry": "different S and J opening and closing (Loop 1, Section 3)",
    "valve_characteristic": "non-linear installed characteristic between position and flow",
    "quantization": "historian or instrument resolution (Loop 4, Section 3)",
    "external_disturbance": "an oscillation entering the loop that the valve did not cause",
    "time_varying_stiction": "S or J changing during the record",
}

#: Effects that act on the valve and need a recorded mv to be assessed.
VALVE_SIDE_EFFECTS: frozenset[str] = frozenset(
    {"actuator_lag", "miscalibration", "asymmetry", "time_varying_stiction"}
)

# Phase codes written by the valve kernel (used by the gap breakdown).
PHASE_MOVING = 0
PHASE_STUCK = 1
PHASE_SLIP = 2
PHASE_REVERSAL = 3
PHASE_NAMES = {
    PHASE_STUCK: "stuck",
    PHASE_SLIP: "slip",
    PHASE_MOVING: "moving",
    PHASE_REVERSAL: "reversal",
}


# --------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------

# Per-sample helpers are inlined into the compiled loops: a call per sample would
# cost more than the state machine itself.
_inline = numba.njit(inline="always", cache=True, nogil=True)

# Layout of the valve state vector used by the compiled step.
_Y, _XSS, _DIR, _VOLD, _STUCK, _XPREV = 0, 1, 2, 3, 4, 5

# Columns of a parameter row of :func:`_valve_sse_batch`.
_P_COLUMNS = (
    "S_open",
    "S_open_end",
    "S_close",
    "S_close_end",
    "J_open",
    "J_open_end",
    "J_close",
    "J_close_end",
    "lag_weight",
)

_FAMILY_CODES = {"linear": 0, "exponential": 1, "power": 2}


@_inline
def _sgn(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@_inline
def _valve_init(x0, y0, d0, s_u, s_d, j_u, j_d):  # pragma: no cover - compiled
    """State ``(y, xss, dir, vold, stuck)`` of a valve at rest at ``y0`` after moving
    in direction ``d0``.

    By Eq. 4 the demand was ``y0 + d0 (S - J)/2`` when the valve stopped; with
    ``d0 = 0`` (unknown) the stop point is the first demand and the first breakaway
    needs S.
    """
    if d0 > 0.0:
        xss = y0 + (s_u - j_u) / 2.0
    elif d0 < 0.0:
        xss = y0 - (s_d - j_d) / 2.0
    else:
        xss = x0
    return y0, xss, d0, 0.0, 1.0


@_inline
def _valve_step(
    x, vnew, xprev, y, xss, dr, vold, stuck, s_u, s_d, j_u, j_d, kano
):  # pragma: no cover - compiled
    """One sample of the data-driven valve with direction-dependent S and J.

    The state machine of :func:`stictiondiag.models.valve.choudhury_step` (Fig. 10) or,
    with ``kano``, of :func:`stictiondiag.models.valve.kano_step`; the breakaway threshold
    and the moving-phase offset of Eq. 4 use the values of the direction of travel.
    ``vnew`` is the sign of ``x - xprev``; the state is held in scalars (kept in
    registers by the compiler: an array state costs a memory round trip per field and
    sample).  Returns the new state ``(y, xss, dir, stuck)``, ``y`` unclipped, and
    the phase code; ``vold`` of the next sample is this ``vnew``.
    """
    if kano:
        if stuck == 0.0:
            if vnew == 0.0 or (dr != 0.0 and vnew != dr):
                stuck = 1.0
                xss = xprev
            else:
                dr = vnew
                if vnew > 0.0:
                    y = x - (s_u - j_u) / 2.0
                else:
                    y = x + (s_d - j_d) / 2.0
    else:
        if vnew != vold and vnew != 0.0 and vold != 0.0:
            stuck = 1.0
            xss = xprev
        elif vnew == 0.0 and vold == 0.0:
            if stuck == 0.0:
                stuck = 1.0
                xss = xprev
    phase = PHASE_MOVING
    if stuck == 1.0:
        dx = x - xss
        d = _sgn(dx)
        reversal = True
        slipped = False
        if d != 0.0:
            if d > 0.0:
                s_dd = s_u
                j_dd = j_u
            else:
                s_dd = s_d
                j_dd = j_d
            reversal = dr == 0.0 or d != dr
            thr = s_dd if reversal else j_dd
            if abs(dx) > thr:
                stuck = 0.0
                slipped = True
                dr = d
                y = x - d * (s_dd - j_dd) / 2.0
        if slipped:
            phase = PHASE_SLIP
        elif reversal and abs(dx) <= 0.5 * max(s_u, s_d):
            phase = PHASE_REVERSAL
        else:
            phase = PHASE_STUCK
    elif not kano and vnew != 0.0:
        dr = vnew
        if vnew > 0.0:
            y = x - (s_u - j_u) / 2.0
        else:
            y = x + (s_d - j_d) / 2.0
    return y, xss, dr, stuck, phase


@jit
def _clipped_moves(op):  # pragma: no cover - compiled
    """Demand clipped to 0-100 % and the sign of its change (0 at the first sample)."""
    n = op.shape[0]
    xs = np.empty(n)
    vs = np.empty(n)
    for k in range(n):
        xs[k] = min(max(op[k], 0.0), 100.0)
        vs[k] = _sgn(xs[k] - xs[k - 1]) if k > 0 else 0.0
    return xs, vs


@_inline
def _characteristic(z, curvature, family):  # pragma: no cover - compiled
    if family == 0:
        return z
    zz = min(max(z, 0.0), 100.0) / 100.0
    if family == 1:
        if abs(curvature) < 1e-9:
            return 100.0 * zz
        return 100.0 * math.expm1(curvature * zz) / math.expm1(curvature)
    return 100.0 * zz ** math.exp(curvature)


@jit
def _valve_series(op, s_up, s_dn, j_up, j_dn, kano, y0, d0, lag):  # pragma: no cover - compiled
    """Valve position (after an optional first-order lag) and phase for one parameter set.

    ``s_up`` etc. have length 1 (constant) or ``len(op)``; ``lag`` is the weight of
    the previous lagged value (0: no lag).
    """
    n = op.shape[0]
    out = np.empty(n)
    phase = np.zeros(n, dtype=np.int8)
    if n == 0:
        return out, phase
    tv = s_up.shape[0] > 1
    xs, vs = _clipped_moves(op)
    y, xss, dr, vold, stuck = _valve_init(xs[0], y0, d0, s_up[0], s_dn[0], j_up[0], j_dn[0])
    yl = y0
    out[0] = y0
    phase[0] = PHASE_STUCK
    for k in range(1, n):
        i = k if tv else 0
        y, xss, dr, stuck, ph = _valve_step(
            xs[k],
            vs[k],
            xs[k - 1],
            y,
            xss,
            dr,
            vold,
            stuck,
            s_up[i],
            s_dn[i],
            j_up[i],
            j_dn[i],
            kano,
        )
        vold = vs[k]
        yc = min(max(y, 0.0), 100.0)
        yl = lag * yl + (1.0 - lag) * yc
        out[k] = yl
        phase[k] = ph
    return out, phase


#: Samples between the checks of an affine row's partial error (a power of two).
_CHECK_EVERY = 128


@jit
def _affine_prefix(mv, w):  # pragma: no cover - compiled
    """Running sums ``(sum w, sum w mv, sum w mv^2)`` of the closed-form map, at the end
    of every block of ``_CHECK_EVERY`` samples and (last row) over the whole record.

    Summed in the order of the row loop of :func:`_valve_sse_row`, so the totals are
    the very numbers a row would accumulate itself: they depend on mv and the
    weights only, and are summed once per batch instead of once per row.
    """
    n = mv.shape[0]
    nck = n // _CHECK_EVERY
    pre = np.empty((nck + 1, 3))
    sw = 0.0
    sm = 0.0
    smm = 0.0
    for k in range(n):
        wk = w[k]
        if wk != 0.0:
            sw += wk
            sm += wk * mv[k]
            smm += wk * mv[k] * mv[k]
        if (k & (_CHECK_EVERY - 1)) == _CHECK_EVERY - 1:
            c = k // _CHECK_EVERY
            pre[c, 0] = sw
            pre[c, 1] = sm
            pre[c, 2] = smm
    pre[nck, 0] = sw
    pre[nck, 1] = sm
    pre[nck, 2] = smm
    return pre


@_inline
def _valve_sse_row(
    xs, vs, mv, w, P, r, h, kano, y0, d0, affine, curvature, family, limit, tv, pre, check
):  # pragma: no cover - compiled
    """Error of row ``r`` of :func:`_valve_sse_batch` (``xs``, ``vs``: :func:`_clipped_moves`).

    With ``affine`` the sums over mv come from ``pre`` (:func:`_affine_prefix`); with
    ``check`` the partial error, minimised over slope and offset, is compared with
    ``limit`` every ``_CHECK_EVERY`` samples and returned once above it (the least
    squares error of a map can only grow as samples are added).
    """
    n = xs.shape[0]
    x0 = xs[0]
    su0, su1, sd0, sd1 = P[r, 0], P[r, 1], P[r, 2], P[r, 3]
    ju0, ju1, jd0, jd1 = P[r, 4], P[r, 5], P[r, 6], P[r, 7]
    lag = P[r, 8]
    h0 = h[0]
    y, xss, dr, vold, stuck = _valve_init(
        x0,
        y0,
        d0,
        su0 + (su1 - su0) * h0,
        sd0 + (sd1 - sd0) * h0,
        ju0 + (ju1 - ju0) * h0,
        jd0 + (jd1 - jd0) * h0,
    )
    yl = y0
    sz = 0.0
    szz = 0.0
    szm = 0.0
    sse = 0.0
    su, sd, ju, jd = su0, sd0, ju0, jd0
    if not tv:
        su = max(su0 + (su1 - su0) * h0, 0.0)
        sd = max(sd0 + (sd1 - sd0) * h0, 0.0)
        ju = max(ju0 + (ju1 - ju0) * h0, 0.0)
        jd = max(jd0 + (jd1 - jd0) * h0, 0.0)
    hprev = np.nan
    for k in range(n):
        if k > 0:
            if tv:
                hk = h[k]
                # The profile is flat before and after the change: the thresholds
                # are recomputed only where it moves.
                if hk != hprev:
                    su = max(su0 + (su1 - su0) * hk, 0.0)
                    sd = max(sd0 + (sd1 - sd0) * hk, 0.0)
                    ju = max(ju0 + (ju1 - ju0) * hk, 0.0)
                    jd = max(jd0 + (jd1 - jd0) * hk, 0.0)
                    hprev = hk
            y, xss, dr, stuck, _ = _valve_step(
                xs[k], vs[k], xs[k - 1], y, xss, dr, vold, stuck, su, sd, ju, jd, kano
            )
            vold = vs[k]
            yc = min(max(y, 0.0), 100.0)
            if lag > 0.0:
                yl = lag * yl + (1.0 - lag) * yc
            else:
                yl = yc
        wk = w[k]
        if affine:
            if wk != 0.0:
                z = yl if family == 0 else _characteristic(yl, curvature, family)
                sz += wk * z
                szz += wk * z * z
                szm += wk * z * mv[k]
            if check and (k & (_CHECK_EVERY - 1)) == _CHECK_EVERY - 1:
                c = k // _CHECK_EVERY
                pw = pre[c, 0]
                if pw > 0.0:
                    vz = szz - sz * sz / pw
                    # Only where the slope is well determined: a lower bound then.
                    if vz > 1e-4 * szz:
                        pm = pre[c, 1]
                        vm = pre[c, 2] - pm * pm / pw
                        cz = szm - sz * pm / pw
                        part = vm - cz * cz / vz
                        if part > limit:
                            return part
        else:
            if wk == 0.0:
                continue
            z = yl if family == 0 else _characteristic(yl, curvature, family)
            e = z - mv[k]
            sse += wk * e * e
            if sse > limit:
                break
    if affine:
        nck = pre.shape[0] - 1
        sw, sm, smm = pre[nck, 0], pre[nck, 1], pre[nck, 2]
        if sw <= 0.0:
            return 0.0
        vz = szz - sz * sz / sw
        vm = smm - sm * sm / sw
        cz = szm - sz * sm / sw
        return vm - cz * cz / vz if vz > 1e-12 * max(vm, 1e-300) else vm
    return sse


@jit
def _valve_sse_batch(
    op, mv, w, P, h, kano, y0, d0, affine, curvature, family, bound, keep, order
):  # pragma: no cover
    """Weighted sum of squared mv errors for many parameter rows at once.

    Each row of ``P`` holds S and J opening and closing at the start and end of the
    profile ``h`` (length 1: constant) and the lag weight (columns as
    ``_P_COLUMNS``).  The valve output goes through the lag and the characteristic
    (``family`` 0: none); with ``affine`` the best ``mv = b + k z`` is solved in
    closed form from running sums, so the returned error is already minimised over
    slope and offset.  Without ``affine`` a row is abandoned (its partial error,
    already above, is returned) as soon as its error exceeds ``bound`` or the best
    complete row so far: most rows of a search grid are far from the minimum.

    With ``affine`` and ``keep > 0`` only the ``keep`` lowest errors are needed
    exactly: a row is abandoned once its partial error exceeds the ``keep``-th lowest
    complete error so far by more than a rounding margin, and that partial error
    (above every error kept) is returned.  The complete rows' errors are the same
    numbers as without abandoning.  ``order`` is the order the rows are evaluated in
    (the rows near the expected minimum first give a low limit early); only with
    ``keep``, as it changes the limit of the rows without it.
    """
    # The stuck-phase logic, the closed-form map and the time profile are passed as
    # constants at separate call sites, so that each inlined copy of the row loop is
    # compiled without their tests per sample (20 % faster).
    m = P.shape[0]
    costs = np.empty(m)
    limit = bound
    tv = h.shape[0] > 1
    xs, vs = _clipped_moves(op)
    pre = _affine_prefix(mv, w) if affine else np.zeros((1, 3))
    nck = pre.shape[0] - 1
    # Rounding margin: far above the error of the running sums (n eps times their
    # size; z and mv lie within 0-100 %), far below a slip's share of the error.
    margin = 1e-9 * (pre[nck, 2] + 1e4 * pre[nck, 0])
    kk = max(keep, 1)
    kept = np.full(kk, np.inf)
    check = affine and keep > 0
    for t in range(m):
        r = order[t] if check else t
        if affine:
            lim = kept[kk - 1] + margin if check else limit
            if kano:
                c = _valve_sse_row(
                    xs,
                    vs,
                    mv,
                    w,
                    P,
                    r,
                    h,
                    True,
                    y0,
                    d0,
                    True,
                    curvature,
                    family,
                    lim,
                    tv,
                    pre,
                    check,
                )
            else:
                c = _valve_sse_row(
                    xs,
                    vs,
                    mv,
                    w,
                    P,
                    r,
                    h,
                    False,
                    y0,
                    d0,
                    True,
                    curvature,
                    family,
                    lim,
                    tv,
                    pre,
                    check,
                )
        elif kano:
            if tv:
                c = _valve_sse_row(
                    xs,
                    vs,
                    mv,
                    w,
                    P,
                    r,
                    h,
                    True,
                    y0,
                    d0,
                    False,
                    curvature,
                    family,
                    limit,
                    True,
                    pre,
                    False,
                )
            else:
                c = _valve_sse_row(
                    xs,
                    vs,
                    mv,
                    w,
                    P,
                    r,
                    h,
                    True,
                    y0,
                    d0,
                    False,
                    curvature,
                    family,
                    limit,
                    False,
                    pre,
                    False,
                )
        elif tv:
            c = _valve_sse_row(
                xs,
                vs,
                mv,
                w,
                P,
                r,
                h,
                False,
                y0,
                d0,
                False,
                curvature,
                family,
                limit,
                True,
                pre,
                False,
            )
        else:
            c = _valve_sse_row(
                xs,
                vs,
                mv,
                w,
                P,
                r,
                h,
                False,
                y0,
                d0,
                False,
                curvature,
                family,
                limit,
                False,
                pre,
                False,
            )
        costs[r] = c
        if affine:
            # Insert a complete error among the lowest ``keep`` (an abandoned row's
            # partial error lies above them all).
            if c < kept[kk - 1]:
                i = kk - 1
                while i > 0 and kept[i - 1] > c:
                    kept[i] = kept[i - 1]
                    i -= 1
                kept[i] = c
        elif c < limit:
            limit = c
    return costs


def valve_replay(
    op: np.ndarray,
    S: float | np.ndarray,
    J: float | np.ndarray,
    *,
    S_down: float | np.ndarray | None = None,
    J_down: float | np.ndarray | None = None,
    kano: bool = False,
    initial_position: float | None = None,
    initial_direction: float = 0.0,
    lag_time_constant: float = 0.0,
    dt: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Valve position from the demand with direction- and time-dependent S and J.

    Generalises :func:`stictiondiag.models.valve.choudhury_model` (Section 5.1, Fig. 10,
    Eq. 4) for the effects of the catalogue: ``S`` and ``J`` apply to opening
    (rising mv), ``S_down`` and ``J_down`` to closing, each may be one value per
    sample, and a first-order actuator lag may follow the friction element.

    Parameters
    ----------
    op : ndarray
        Valve demand [% of span].
    S, J : float or ndarray
        Deadband plus stickband [% of input span] and slip jump [% of output span]
        opening (and closing when ``S_down``/``J_down`` are not given).
    S_down, J_down : float or ndarray, optional
        The same for closing.
    kano : bool
        Stuck-phase logic of Kano et al. (2004) instead of Fig. 10: noise reversals
        while stuck do not move the point the breakaway is measured from.
    initial_position : float, optional
        Valve position at the first sample [% of span]; default ``op[0]``.
    initial_direction : {-1, 0, 1}
        Direction of the movement that brought the valve to rest before the record
        starts (0: unknown; the first breakaway then needs S).  A record starts in
        the middle of the valve's history; with the right direction the replay is in
        step with the valve from the first sample on.
    lag_time_constant : float
        Time constant of a first-order lag after the friction element [s] (0: none).
    dt : float
        Sample time [s] (only used with a lag).

    Returns
    -------
    mv : ndarray
        Valve position [% of span].
    phase : ndarray of int8
        Valve phase per sample: 0 moving, 1 stuck, 2 breakaway (slip), 3 stuck after
        a reversal while the demand is within S/2 of where the valve stopped.
    """
    x = np.ascontiguousarray(op, dtype=float)
    arrays = [
        np.atleast_1d(np.asarray(v, dtype=float)) for v in (S, S_down, J, J_down) if v is not None
    ]
    s_up = np.atleast_1d(np.asarray(S, dtype=float))
    j_up = np.atleast_1d(np.asarray(J, dtype=float))
    s_dn = s_up if S_down is None else np.atleast_1d(np.asarray(S_down, dtype=float))
    j_dn = j_up if J_down is None else np.atleast_1d(np.asarray(J_down, dtype=float))
    size = max(a.size for a in arrays)
    if size not in (1, x.size):
        raise UsageError(f"S and J must be scalars or one value per sample ({x.size}), got {size}")
    s_up, s_dn, j_up, j_dn = (
        np.ascontiguousarray(np.broadcast_to(a, (size,)), dtype=float)
        for a in (s_up, s_dn, j_up, j_dn)
    )
    y0 = float(x[0]) if initial_position is None else float(initial_position)
    lag = math.exp(-dt / lag_time_constant) if lag_time_constant > 0.0 else 0.0
    return _valve_series(
        x,
        np.maximum(s_up, 0.0),
        np.maximum(s_dn, 0.0),
        np.maximum(j_up, 0.0),
        np.maximum(j_dn, 0.0),
        bool(kano),
        min(max(y0, 0.0), 100.0),
        float(np.sign(initial_direction)),
        lag,
    )


def characteristic_curve(x: np.ndarray, curvature: float, family: str) -> np.ndarray:
    """Normalised installed characteristic, flow [% of max] at position x [% of travel].

    ``exponential``: ``100 (e^{c x/100} - 1)/(e^c - 1)`` (equal-percentage-like for
    c > 0, c = ln R for rangeability R; quick-opening-like for c < 0);
    ``power``: ``100 (x/100)^p`` with ``p = e^{curvature}`` (quick-opening for p < 1,
    ``p = 1/2`` the square root of Section 5.1).  Both are the identity at curvature
    0 (the look-up table in the last step of Fig. 10).
    """
    z = np.clip(np.asarray(x, dtype=float), 0.0, 100.0) / 100.0
    if family == "power":
        return 100.0 * z ** math.exp(curvature)
    if family == "linear" or abs(curvature) < 1e-9:
        return 100.0 * z
    return 100.0 * np.expm1(curvature * z) / math.expm1(curvature)


def first_order_lag(x: np.ndarray, time_constant: float, dt: float) -> np.ndarray:
    """First-order lag ``tau dy/dt = x - y`` sampled exactly (zero-order hold), started at rest.

    Parameters
    ----------
    x : ndarray
        Input [any units].
    time_constant : float
        tau [s], >= 0 (0 returns ``x``).
    dt : float
        Sample time [s].
    """
    if time_constant <= 0.0:
        return np.asarray(x, dtype=float)
    a = math.exp(-dt / time_constant)
    return lfilter1((1.0 - a,), -a, x, zi=a * x[0])


def quantize(x: np.ndarray, step: float, offset: float = 0.0) -> np.ndarray:
    """Round ``x`` to the grid ``offset + step * integer`` (instrument or historian resolution)."""
    return offset + step * np.round((np.asarray(x, dtype=float) - offset) / step)


def detect_quantization(x: np.ndarray | None) -> tuple[float, float] | None:
    """Resolution of a recorded signal: the step and offset of the grid its values lie on.

    A signal counts as quantised when all its distinct values are whole multiples of
    the smallest difference between them (to 1 % of that step), that step is at least
    1/1000 of the signal's standard deviation (a coarser grid than the decimals of a
    CSV file), and there are at least two levels.

    Returns
    -------
    (step, offset) or None
        Step [units of x] and the level nearest zero, or None when not quantised.
    """
    if x is None:
        return None
    values = np.unique(np.asarray(x, dtype=float)[np.isfinite(x)])
    if values.size < 2:
        return None
    sd = float(np.std(x))
    if not sd > 0.0:
        return None
    diffs = np.diff(values)
    step = float(np.min(diffs))
    if step < 1e-3 * sd:
        return None
    rel = (values - values[0]) / step
    if float(np.max(np.abs(rel - np.round(rel)))) > 0.01:
        return None
    offset = float(values[0] - step * np.round(values[0] / step))
    return step, offset


# --------------------------------------------------------------------------------------
# Fitting helpers
# --------------------------------------------------------------------------------------


def needle_search(
    batch_cost: Callable[[np.ndarray, float], np.ndarray],
    x0: np.ndarray,
    pair: tuple[int, int],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    rel: float = 0.15,
    n_grid: int = 31,
    beam: int = 3,
    zooms: int = 2,
    floor: float | None = None,
) -> tuple[np.ndarray, float]:
    """Dense grid over two parameters, then zooming grids around the best few points.

    The replay error of a stiction model with a noisy demand is a rugged function of
    S and J: each breakaway happens at the first noisy sample beyond the threshold,
    so the replay matches the data only in a narrow region (about 1 % of J) and is
    off by whole slips elsewhere.  A descent method stalls on the steps; this search
    lays an ``n_grid x n_grid`` grid over ``+-rel`` of the starting values (at least
    ``+-rel floor``), keeps the ``beam`` best points and zooms around each to two of
    the previous steps either side, ``zooms`` times.  ``batch_cost(X, bound)``
    evaluates all rows of X in one compiled call and may abandon rows above
    ``bound``.  A pair ``(i, i)`` is a one-dimensional scan.

    Returns the best point and its cost.
    """
    i, j = pair
    x0 = np.clip(np.asarray(x0, dtype=float), lower, upper)
    best_c = float(batch_cost(x0[None, :], np.inf)[0])
    best_x = x0
    fl = max(abs(x0[i]), abs(x0[j])) if floor is None else floor

    def grid(x, hw_i, hw_j, m):
        gi = np.clip(np.linspace(x[i] - hw_i, x[i] + hw_i, m), lower[i], upper[i])
        if i == j:
            X = np.repeat(x[None, :], gi.size, axis=0)
            X[:, i] = gi
            return X
        gj = np.clip(np.linspace(x[j] - hw_j, x[j] + hw_j, m), lower[j], upper[j])
        GI, GJ = np.meshgrid(gi, gj, indexing="ij")
        X = np.repeat(x[None, :], GI.size, axis=0)
        X[:, i] = GI.ravel()
        X[:, j] = GJ.ravel()
        return X

    m0 = 4 * n_grid if i == j else n_grid
    hw_i = rel * max(abs(x0[i]), 0.5 * fl, 1e-6)
    hw_j = rel * max(abs(x0[j]), 0.5 * fl, 1e-6)
    X = grid(x0, hw_i, hw_j, m0 if i == j else n_grid)
    c = batch_cost(X, best_c)
    order = np.argsort(c)[:beam]
    if c[order[0]] < best_c:
        best_c, best_x = float(c[order[0]]), X[order[0]].copy()
    starts = [X[k].copy() for k in order]
    step_i = 2 * hw_i / max((m0 if i == j else n_grid) - 1, 1)
    step_j = 2 * hw_j / max(n_grid - 1, 1)
    for x in starts:
        si, sj = step_i, step_j
        for _ in range(zooms):
            m = 21 if i == j else 11
            Z = grid(x, 2 * si, 2 * sj, m)
            cz = batch_cost(Z, best_c)
            k = int(np.argmin(cz))
            x = Z[k].copy()
            if cz[k] < best_c:
                best_c, best_x = float(cz[k]), x
            si, sj = 4 * si / (m - 1), 4 * sj / (m - 1)
    return best_x, best_c


def _golden(cost: Callable[[float], float], lo: float, hi: float, n_iter: int = 30) -> float:
    """Minimise a unimodal scalar function on [lo, hi] by golden-section search."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    for _ in range(n_iter):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
    return c if fc < fd else d


def _wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted linear least squares (weights 0/1) by the normal equations.

    Columns are scaled to unit norm and a tiny ridge keeps collinear columns
    solvable; far faster than an SVD for the few columns used here.
    """
    Xw = X * w[:, None]
    A = Xw.T @ X
    b = Xw.T @ y
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    As = A / np.outer(d, d)
    As[np.diag_indices_from(As)] += 1e-10
    try:
        return np.linalg.solve(As, b / d) / d
    except np.linalg.LinAlgError:
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
        return coef


def _fractional_delay_wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`_wls` with the first two columns (the input at dead times d and d + 1)
    weighted with one sign.

    The two columns stand for one gain and a dead time between d and d + 1 samples:
    ``b ((1 - f) u(t - d) + f u(t - d - 1))`` with ``0 <= f <= 1``.  Unconstrained,
    the pair can take large weights of opposite sign, ``b (u(t - d) - u(t - d - 1))``:
    a differentiator that answers the valve's slips instead of its position, fits a
    part of the record and fails elsewhere.  When the free solution has opposite
    signs, the constrained optimum lies on the boundary ``f = 0`` or ``f = 1``: the
    better fit with one of the two columns alone.
    """
    coef = _wls(X, y, w)
    if X.shape[1] < 2 or coef[0] * coef[1] >= 0.0:
        return coef
    best = None
    for drop in (1, 0):
        keep = [j for j in range(X.shape[1]) if j != drop]
        c = np.zeros(X.shape[1])
        c[keep] = _wls(X[:, keep], y, w)
        r = y - X @ c
        sse = float(np.dot(w, r * r))
        if best is None or sse < best[0]:
            best = (sse, c)
    return best[1]


def dominant_period_samples(x: np.ndarray) -> float | None:
    """Period of the largest spectral peak of ``x`` [samples], or None.

    Slow drift (fewer than four cycles in the record) is excluded, so a load change
    does not pass for the oscillation; the periodogram is smoothed over three bins.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 16 or not np.std(x) > 0:
        return None
    xd = x - np.mean(x)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.abs(np.fft.rfft(xd * np.hanning(n), nfft)) ** 2
    spec = np.convolve(spec, np.ones(3) / 3.0, mode="same")
    f = np.arange(spec.size) / nfft  # [cycles/sample]
    ok = (f >= 4.0 / n) & (f <= 0.25)
    if not np.any(ok):
        return None
    i = int(np.argmax(np.where(ok, spec, -1.0)))
    return float(1.0 / f[i])


class SlowLoad:
    """Unmeasured slow load on pv: a piecewise-linear curve with knots every ``spacing`` samples.

    Plant loops carry load changes the replay cannot know: the controller moves the
    valve to cancel them, so the driven process replay ``G(mv)`` departs from pv by
    ``G(load)``.  The replay compares pv after removing this slow part; the knot
    spacing is twice the longest oscillation period of the loop, so a
    piecewise-linear curve cannot follow the oscillations themselves (a sinusoid
    needs knots at most a quarter period apart).

    Parameters
    ----------
    n : int
        Record length [samples].
    spacing : float
        Knot spacing [samples].
    """

    def __init__(self, n: int, spacing: float):
        spacing = max(float(spacing), 2.0)
        self.n = int(n)
        self.m = max(int(math.ceil((n - 1) / spacing)) + 1, 2)
        self.spacing = (n - 1) / (self.m - 1)
        pos = np.arange(n) / self.spacing
        self.j = np.minimum(np.floor(pos).astype(np.int64), self.m - 2)
        self.t = pos - self.j

    def _ht(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``H^T diag(w) x`` for a matrix x (n x c)."""
        out = np.empty((self.m, x.shape[1]))
        a, b = w * (1.0 - self.t), w * self.t
        for c in range(x.shape[1]):
            out[:, c] = np.bincount(self.j, a * x[:, c], minlength=self.m) + np.bincount(
                self.j + 1, b * x[:, c], minlength=self.m
            )
        return out

    def solve(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """Knot values of the weighted least-squares fit of each column of ``x``."""
        from scipy.linalg import solveh_banded

        x2 = x[:, None] if x.ndim == 1 else x
        a, b = w * (1.0 - self.t), w * self.t
        diag = np.bincount(self.j, a * (1.0 - self.t), minlength=self.m) + np.bincount(
            self.j + 1, b * self.t, minlength=self.m
        )
        off = np.bincount(self.j, a * self.t, minlength=self.m)[: self.m - 1]
        ridge = 1e-6 * max(float(diag.max()), 1e-12)
        ab = np.zeros((2, self.m))
        ab[0, 1:] = off
        ab[1] = diag + ridge
        beta = solveh_banded(ab, self._ht(x2, w))
        return beta if x.ndim > 1 else beta[:, 0]

    def evaluate(self, beta: np.ndarray) -> np.ndarray:
        """The curve(s) at every sample."""
        if beta.ndim == 1:
            return beta[self.j] * (1.0 - self.t) + beta[self.j + 1] * self.t
        return beta[self.j] * (1.0 - self.t)[:, None] + beta[self.j + 1] * self.t[:, None]

    def residualize(self, x: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``x`` minus its weighted least-squares slow part."""
        return x - self.evaluate(self.solve(x, w))


# --------------------------------------------------------------------------------------
# Loop data and fitted replays
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LoopSignals:
    """Recorded signals of one loop, uniformly sampled.

    Attributes
    ----------
    op : ndarray
        Controller output [% of span].
    pv : ndarray
        Process variable [pv units].
    dt : float
        Sample time [s].
    mv : ndarray or None
        Valve position [% of span], None when not recorded.
    sp : ndarray or None
        Set point [pv units], None when not recorded.
    """

    op: np.ndarray
    pv: np.ndarray
    dt: float
    mv: np.ndarray | None = None
    sp: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.op.size)

    def variance(self, signal: str) -> float:
        """Variance of a recorded signal [units^2], floored so a constant signal is usable."""
        x = getattr(self, signal)
        v = float(np.var(x))
        scale = max(float(np.mean(np.abs(x))), 1.0)
        return max(v, (1e-6 * scale) ** 2)


@dataclass(frozen=True)
class ReplayContext:
    """What every fitter needs besides the weights.

    Attributes
    ----------
    sig : LoopSignals
        Recorded signals.
    load : SlowLoad
        Basis of the unmeasured slow load on pv.
    w_eval : ndarray
        Weights of the samples the replay is judged on (all but the first few, whose
        initial state the replay cannot know); the slow load is fitted on these.
    start : (S, J) or None
        Stiction estimate to start the search from [% of span].
    mv_model : ndarray or None
        Valve output that drives the process when mv is not recorded [% of span].
    slips : dict or None
        Slips measured in the data (:func:`measure_slips`): per slip the time
        [samples], direction, S and J [% of span]; seeds the searches.
    norm : dict
        Normaliser of each signal's squared error: the variance of its cycle-scale
        part (the signal minus its slow part) [units^2].
    """

    sig: LoopSignals
    load: SlowLoad
    w_eval: np.ndarray
    start: tuple[float, float] | None = None
    mv_model: np.ndarray | None = None
    slips: dict | None = None
    norm: dict = field(default_factory=dict)
    #: Terms of the process fits that several fits share (:func:`fit_process`), by the
    #: identity of their input and the filter; the inputs are held, so their identity
    #: stays theirs.
    cache: dict = field(default_factory=dict, compare=False, repr=False)


def measure_slips(op: np.ndarray, mv: np.ndarray, dt: float) -> dict | None:
    """S and J of every slip read off the data (the stick and slip segments of Fig. 2).

    Uses :func:`stictiondiag.stiction.segments.segment_valve`; the values only seed the
    least-squares searches, so a failure there is not an error (None).
    """
    try:
        from stictiondiag.stiction.segments import segment_valve

        seg = segment_valve(op, mv, dt)
    except Exception:  # noqa: BLE001 - seeds are optional; the searches have grids too
        return None
    if seg.n_slips == 0:
        return None
    # The demand's direction at the breakaway (the sample that crossed the threshold):
    # the side of the deadband the valve moves on afterwards (Eq. 4).
    op = np.asarray(op, dtype=float)
    e = np.clip(np.asarray(seg.slip[:, 0], dtype=int), 1, op.size - 1)
    op_dir = np.sign(op[e] - op[e - 1])
    op_dir = np.where(op_dir == 0.0, np.asarray(seg.direction, dtype=float), op_dir)
    return {
        "time": np.asarray(seg.slip[:, 0], dtype=float),
        "direction": np.asarray(seg.direction, dtype=float),
        "S": np.asarray(seg.band, dtype=float),
        "J": np.asarray(seg.jump, dtype=float),
        "travel": np.asarray(seg.travel, dtype=float),
        "reversal": np.asarray(seg.reversal, dtype=bool),
        "op_break": np.asarray(seg.op_break, dtype=float),
        "mv_after": np.asarray(seg.mv_after, dtype=float),
        "op_direction": op_dir,
    }


def build_context(
    sig: LoopSignals,
    *,
    start: tuple[float, float] | None = None,
    mv_model: np.ndarray | None = None,
    load_spacing: float | None = None,
) -> ReplayContext:
    """Everything the fits share: slow-load basis, judged samples, normalisers, slips.

    Parameters
    ----------
    sig : LoopSignals
        Recorded signals.
    start : (S, J), optional
        Stiction estimate [% of span] to start the valve searches from.
    mv_model : ndarray, optional
        Valve output driving the process when mv is not recorded [% of span].
    load_spacing : float, optional
        Knot spacing of the slow load [samples]; default a sixteenth of the record
        (at least 40 samples), so the eight validation blocks of
        :mod:`stictiondiag.gap.diagnose` hold two knots each.

    Notes
    -----
    The replay cannot know the valve's state before the record starts, so it is
    judged from the first slip measured in the data on (at least the first 2 % of
    the record, at most the first 20 %).
    """
    n = sig.n
    spacing = max(n / 16.0, 40.0) if load_spacing is None else float(load_spacing)
    load = SlowLoad(n, min(spacing, max(n - 1, 2)))
    slips = measure_slips(sig.op, sig.mv, sig.dt) if sig.mv is not None else None
    warm = max(n // 50, 20)
    if slips is not None and slips["time"].size:
        warm = max(warm, min(int(slips["time"][0]) + 10, n // 5))
    w_eval = np.ones(n)
    w_eval[: min(warm, n // 2)] = 0.0
    norm = {}
    for name in ("op", "mv", "pv"):
        x = getattr(sig, name)
        if x is None:
            continue
        r = load.residualize(np.asarray(x, dtype=float), w_eval)
        v = float(np.dot(w_eval, r * r) / max(w_eval.sum(), 1.0))
        norm[name] = max(v, 1e-6 * sig.variance(name), 1e-18)
    return ReplayContext(
        sig=sig, load=load, w_eval=w_eval, start=start, mv_model=mv_model, slips=slips, norm=norm
    )


@dataclass(frozen=True)
class ValveFit:
    """The fitted two-parameter valve replay.

    Attributes
    ----------
    mv : ndarray
        Replayed valve position [% of span].
    phase : ndarray
        Valve phase codes of the stiction element (see :func:`valve_replay`).
    params : dict
        S and J [% of span].
    kano : bool
        Stuck-phase logic of Kano et al. (2004) instead of Fig. 10.
    initial_direction : float
        Direction of travel before the record (+1 opening, -1 closing).
    """

    mv: np.ndarray
    phase: np.ndarray
    params: dict
    kano: bool = False
    initial_direction: float = 0.0


@dataclass(frozen=True)
class ProcessFit:
    """A fitted process replay: pv predicted one sample ahead (Section 4.2.2, Eq. 3).

    Attributes
    ----------
    pv : ndarray
        One-step-ahead prediction of pv [pv units].
    model : ProcessModel
        Pole (1 for an integrating process), dead time [samples] and the load-to-noise
        variance ratio of the load tracking.
    coef : ndarray
        Linear coefficients (input gains at two adjacent dead times, then any extra
        columns).
    params : dict
        Readable parameters: gain, time constant [s], dead time [s], integrating.
    """

    pv: np.ndarray
    model: ProcessModel
    coef: np.ndarray
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class EffectFit:
    """One fitted candidate: the base replay with one effect added.

    Attributes
    ----------
    effect : str
        Effect name (one of :data:`EFFECTS`).
    variant : str
        Which form of the effect fitted best (e.g. ``step`` or ``ramp`` for
        ``time_varying_stiction``).
    n_params : int
        Parameters beyond the base model's.
    params : dict
        Fitted parameters, units in the key names (``_s`` seconds, ``_pct`` % of
        span; S and J always in % of span).
    predictions : dict
        Replayed signals this effect changes (``mv``, ``pv`` or ``op``) [their units].
    x : tuple
        The searched parameter vector (starts the search on a part of the record).
    process : ProcessFit or None
        For effects on the process side, the process replay with the effect in it.
    pv_floor : float or None
        For effects on the process side, the pv noise floor of that replay
        (:func:`process_noise_floor`) [pv units^2].
    supported : bool
        False when a check of the effect's own signature fails (an external
        oscillation without a steady phase): it then cannot be named.
    explained : dict
        Variance per sample the effect accounts for as a known measurement error
        (the rounding of a quantised signal), by signal [units^2].
    """

    effect: str
    variant: str
    n_params: int
    params: dict
    predictions: dict
    x: tuple = ()
    process: ProcessFit | None = None
    pv_floor: float | None = None
    supported: bool = True
    explained: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BaseFit:
    """The base replay on one set of weights: two-parameter valve, process, controller.

    Attributes
    ----------
    valve : ValveFit or None
        None when mv is not recorded.
    process : ProcessFit
        Process replay driven by the recorded mv (or ``mv_model``).
    op : ndarray
        Controller replay [% of span].
    controller : dict
        Controller parameters (see :func:`fit_controller`).
    mv_model : ndarray
        Valve output of the two-parameter model [% of span].
    """

    valve: ValveFit | None
    process: ProcessFit
    op: np.ndarray
    controller: dict
    mv_model: np.ndarray

    def predictions(self) -> dict:
        """Replayed signals by name [their units]."""
        out = {"op": self.op, "pv": self.process.pv}
        if self.valve is not None:
            out["mv"] = self.valve.mv
        return out


# --------------------------------------------------------------------------------------
# Valve fitting
# --------------------------------------------------------------------------------------

_CONSTANT = np.zeros(1)


def _rows_order(m: int, order=None) -> np.ndarray:
    """Evaluation order of ``m`` rows for :func:`_valve_sse_batch` (default: as given)."""
    if order is None:
        return np.arange(m, dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if order.shape != (m,):
        raise ValueError(f"order must be a permutation of the {m} rows")
    return order


def _centre_first(X: np.ndarray) -> np.ndarray:
    """Rows of a search grid nearest its centre first (each column by its spread)."""
    if X.shape[0] < 3:
        return np.arange(X.shape[0])
    lo, hi = X.min(axis=0), X.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.argsort(np.abs((X - 0.5 * (lo + hi)) / span).sum(axis=1), kind="stable")


class _ValveProblem:
    """Recorded op and mv with the weights and the fixed valve settings of one fit.

    Attributes
    ----------
    op, mv, w : ndarray
        Demand and position [% of span], sample weights.
    var : float
        Normaliser of the squared error [(% of span)^2].
    kano : bool
        Stuck-phase logic of Kano et al. (2004).
    d0, y0 : float
        Direction of travel before the first sample and the position then.
    """

    def __init__(self, op, mv, w, var, kano, d0, y0):
        self.op = np.ascontiguousarray(op, dtype=float)
        self.mv = np.ascontiguousarray(mv, dtype=float)
        self.w = np.ascontiguousarray(w, dtype=float)
        self.var = float(var)
        self.kano = bool(kano)
        self.d0 = float(d0)
        self.y0 = min(max(float(y0), 0.0), 100.0)
        self.y0_data = self.y0

    @classmethod
    def of(cls, ctx: ReplayContext, w: np.ndarray, kano: bool, d0: float) -> _ValveProblem:
        mv = ctx.sig.mv
        y0 = _rest_level_before_first_slip(ctx)
        return cls(ctx.sig.op, mv, w, ctx.norm["mv"], kano, d0, y0)

    def with_output_map(self, slope: float, offset: float) -> _ValveProblem:
        """The same problem for a model ``mv = offset + slope * element``: the element
        starts at the recorded rest level mapped back to its own units."""
        other = copy.copy(self)
        if abs(slope) > 1e-9:
            other.y0 = min(max((self.y0_data - offset) / slope, 0.0), 100.0)
        return other

    def costs(
        self,
        P,
        h=_CONSTANT,
        *,
        affine=False,
        curvature=0.0,
        family="linear",
        bound=np.inf,
        keep=0,
        order=None,
    ):
        """Normalised weighted squared mv error for every row of P (see ``_P_COLUMNS``).

        Rows whose error exceeds ``bound`` (normalised) or the best row so far are
        abandoned early; their returned error is then only a lower bound.  With
        ``affine`` (no ``bound``) and ``keep > 0`` only the ``keep`` lowest errors are
        exact (enough for the ``keep`` best rows); the others may be lower bounds that
        lie above them.  ``order``: the order to evaluate the rows in with ``keep``
        (likely best first makes the abandoning effective).
        """
        c = _valve_sse_batch(
            self.op,
            self.mv,
            self.w,
            np.ascontiguousarray(P, dtype=float),
            np.ascontiguousarray(h, dtype=float),
            self.kano,
            self.y0,
            self.d0,
            bool(affine),
            float(curvature),
            _FAMILY_CODES[family],
            float(bound) * self.var,
            int(keep),
            _rows_order(len(P), order if keep else None),
        )
        return c / self.var

    def series(self, row, h=_CONSTANT):
        """Valve position and phase for one parameter row [% of span]."""
        row = np.asarray(row, dtype=float)
        h = np.asarray(h, dtype=float)

        def prof(a, b):
            return np.maximum(a + (b - a) * h, 0.0) if h.size > 1 else np.array([max(a, 0.0)])

        return _valve_series(
            self.op,
            prof(row[0], row[1]),
            prof(row[2], row[3]),
            prof(row[4], row[5]),
            prof(row[6], row[7]),
            self.kano,
            self.y0,
            self.d0,
            float(row[8]),
        )


def _rest_level_before_first_slip(ctx: ReplayContext) -> float:
    """Valve position at the start of the replay [% of span].

    The recorded level while the valve rests before its first measured slip: there
    the position has settled (after any actuator lag) and the valve is stuck, as the
    replay starts.  Without measured slips, the first few samples.
    """
    mv = ctx.sig.mv
    if ctx.slips is not None and ctx.slips["time"].size:
        k = int(ctx.slips["time"][0])
        if k >= 4:
            return float(np.median(mv[max(k - 10, 0) : k - 1]))
    return float(np.median(mv[: max(min(3, mv.size // 100), 1)]))


def _rows(
    S_open,
    J_open,
    S_close=None,
    J_close=None,
    S_open_end=None,
    J_open_end=None,
    S_close_end=None,
    J_close_end=None,
    lag=None,
):
    """Parameter rows (``_P_COLUMNS``) from columns; missing ones default to symmetric,
    constant in time and without lag."""
    S_close = S_open if S_close is None else S_close
    J_close = J_open if J_close is None else J_close
    cols = [
        S_open,
        S_open if S_open_end is None else S_open_end,
        S_close,
        S_close if S_close_end is None else S_close_end,
        J_open,
        J_open if J_open_end is None else J_open_end,
        J_close,
        J_close if J_close_end is None else J_close_end,
        0.0 if lag is None else lag,
    ]
    m = max(np.size(c) for c in cols)
    return np.column_stack([np.broadcast_to(np.asarray(c, dtype=float), (m,)) for c in cols])


def _travel(op: np.ndarray) -> float:
    return max(float(np.percentile(op, 99) - np.percentile(op, 1)), 0.2)


def _slip_medians(slips: dict | None, mask=None) -> tuple[float, float] | None:
    """Median S and J [% of span] of the measured slips (all, or those in ``mask``)."""
    if slips is None:
        return None
    sel = np.ones(slips["S"].size, dtype=bool) if mask is None else mask
    if sel.sum() < 2:
        return None
    S = float(np.median(slips["S"][sel]))
    J = float(np.median(slips["J"][sel]))
    if not (math.isfinite(S) and math.isfinite(J)):
        return None
    return max(S, 0.0), max(J, 0.0)


def _travel_seeds(
    slips: dict | None, direction: float = 0.0, mask=None
) -> list[tuple[float, float]]:
    """(S, J) starting points from the demand travel of the measured slips.

    A valve breaks away once its demand has travelled S from where it stopped
    after a reversal, J after a stop in the same direction (Fig. 2); the first
    sample beyond the threshold overshoots it, so the lower quartile of the travels
    is taken.  J is also read from the slip jumps (Eq. 4), which hold when S - J is
    the same both ways.  ``direction`` selects opening (+1) or closing (-1) slips.
    """
    if slips is None or "travel" not in slips:
        return []
    sel = np.ones(slips["travel"].size, dtype=bool) if mask is None else mask.copy()
    if direction != 0.0:
        sel &= slips["direction"] == direction
    rev = sel & slips["reversal"]
    same = sel & ~slips["reversal"]
    if rev.sum() < 2:
        return []
    S = float(np.percentile(slips["travel"][rev], 25))
    Js = []
    if same.sum() >= 3:
        Js.append(float(np.percentile(slips["travel"][same], 25)))
    Js.append(float(np.median(slips["J"][sel])))
    return [(max(S, 0.0), max(J, 0.0)) for J in Js if math.isfinite(J)]


#: Stages of :func:`grid_search_nd` when starting from the measured slips, whose
#: S and J can be 30 % off for an asymmetric or time-varying valve (relative span,
#: values per parameter).
_WIDE_STAGES = ((0.35, 15), (0.06, 7), (0.015, 5), (0.004, 5))
#: The same from the windowed fits of a time-varying valve, which start closer.
_TVS_STAGES = ((0.25, 9), (0.06, 7), (0.015, 5), (0.004, 5))


def grid_search_nd(
    batch_cost: Callable[[np.ndarray, float], np.ndarray],
    x0: np.ndarray,
    dims: tuple[int, ...],
    *,
    stages: tuple[tuple[float, int], ...] = ((0.12, 9), (0.03, 7), (0.008, 5)),
) -> tuple[np.ndarray, float]:
    """Coarse-to-fine product grid over several parameters at once, relative to x0.

    Stiction parameters of an augmented valve are coupled: with the closing S a
    little off, the replay misses the closing slips and the opening S and J cannot
    be found either.  Each stage lays a grid of ``steps`` values per parameter over
    ``+-span`` (relative) around the current point, all combinations at once (the
    compiled cost abandons the bad ones early), and recentres on the best.
    """
    x = np.asarray(x0, dtype=float).copy()
    best = float(batch_cost(x[None, :], np.inf)[0])
    dims = tuple(dims)
    for span, steps in stages:
        g = np.linspace(1.0 - span, 1.0 + span, steps)
        mesh = np.meshgrid(*([g] * len(dims)), indexing="ij")
        F = np.column_stack([m.ravel() for m in mesh])
        X = np.repeat(x[None, :], F.shape[0], axis=0)
        # Offsets relative to each value, but at least to a third of the largest one
        # (a J near zero still moves).
        xd = np.abs(x[list(dims)])
        scale = np.maximum(xd, max(0.3 * float(xd.max()), 1e-3))
        X[:, list(dims)] = x[list(dims)] + (F - 1.0) * scale
        X = np.maximum(X, 0.0)
        # Nearest points first: a good early bound makes the rest cheap.
        X = X[np.argsort(np.abs(F - 1.0).sum(axis=1))]
        c = batch_cost(X, best)
        k = int(np.argmin(c))
        if c[k] < best:
            best, x = float(c[k]), X[k].copy()
    return x, best


def _sj_wide(cost2, seeds) -> np.ndarray:
    """Best (S, J) on a grid of S around each seed (+-30 %) and J over [0, 1.4 S].

    J has no reliable seed when slips are smeared (a lag) or mixed (asymmetry), and
    the replay's error is a needle in J: it must be scanned over its whole range.
    """
    pts = []
    for S0, _ in seeds:
        for S in S0 * np.linspace(0.7, 1.3, 13):
            for fj in np.linspace(0.0, 1.4, 36):
                pts.append((S, S * fj))
    X = np.array(pts + [tuple(s) for s in seeds])
    c = cost2(X, np.inf)
    return X[int(np.argmin(c))]


def _sj_bounds(travel: float) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(2), np.array([travel, 1.5 * travel])


def _needle_sj(
    prob: _ValveProblem,
    seeds,
    travel: float,
    *,
    rel: float = 0.15,
    zooms: int = 2,
    n_grid: int = 31,
    **row_kw,
):
    """Best (S, J) from each seed by :func:`needle_search`; returns (x, cost)."""
    lower, upper = _sj_bounds(travel)

    def cost(X, bound):
        return prob.costs(_rows(X[:, 0], X[:, 1], **row_kw), bound=bound)

    best = None
    for s in seeds:
        x, c = needle_search(
            cost, np.asarray(s, dtype=float), (0, 1), lower, upper, rel=rel, zooms=zooms
        )
        if best is None or c < best[1]:
            best = (x, c)
    return best


def fit_valve(ctx: ReplayContext, w: np.ndarray, *, like: ValveFit | None = None) -> ValveFit:
    """Least-squares S and J of the two-parameter model on the recorded mv.

    A coarse grid (S geometric, J in proportion to S) for Fig. 10 and for Kano's
    stuck-phase logic, then :func:`needle_search` around its best points, the
    stiction estimate and the medians of the slips measured in the data; then the
    direction of travel before the record.

    Parameters
    ----------
    ctx : ReplayContext
        Needs a recorded mv.
    w : ndarray
        Sample weights (0 or 1): samples that count in the fit.
    like : ValveFit, optional
        A fit on the whole record: keep its logic and initial direction and search
        near its S and J (fits on parts of the record for validation).
    """
    travel = _travel(ctx.sig.op)
    if like is not None:
        # Thresholds are not refitted on part of the record: a replay is in step with
        # the data only at the exact thresholds, and a refit on half the record finds
        # a slightly different one that throws the other half out of step.
        return like

    S_grid = travel * np.geomspace(0.003, 0.6, 36)
    SS, RR = np.meshgrid(S_grid, np.linspace(0.0, 1.6, 9), indexing="ij")
    coarse = np.column_stack([SS.ravel(), (SS * RR).ravel()])
    extra = []
    if ctx.start is not None and all(math.isfinite(v) for v in ctx.start):
        extra.append((max(float(ctx.start[0]), 0.0), max(float(ctx.start[1]), 0.0)))
    med = _slip_medians(ctx.slips)
    if med is not None:
        extra.append(med)
    extra += _travel_seeds(ctx.slips)
    # The stuck-phase logic from the coarse grid and the seeds (the two differ only
    # in how noise reversals re-arm a stuck valve), then the fine search.
    best = None
    for kano in (False, True):
        prob = _ValveProblem.of(ctx, w, kano, 1.0)
        X = np.vstack([coarse, np.array(extra).reshape(-1, 2)])
        c = prob.costs(_rows(X[:, 0], X[:, 1]))
        i = int(np.argmin(c))
        if best is None or c[i] < best[0]:
            best = (float(c[i]), kano, tuple(X[i]))
    _, kano, top = best
    prob = _ValveProblem.of(ctx, w, kano, 1.0)
    seeds = list(dict.fromkeys([top, *extra]))
    # J scanned over its whole range around each seed, as the augmented valves do
    # (:func:`_sj_wide`): the error is a needle in J, and a base that misses it would
    # credit any augmentation that re-searches S and J with the base's own shortfall.
    wide = _sj_wide(lambda X, bound: prob.costs(_rows(X[:, 0], X[:, 1]), bound=bound), seeds)
    x, c = _needle_sj(prob, list(dict.fromkeys([*seeds, tuple(wide)])), travel)
    # The direction of travel before the record only matters until the first slip.
    prob_neg = _ValveProblem.of(ctx, w, kano, -1.0)
    d0 = -1.0 if prob_neg.costs(_rows(x[0], x[1]))[0] < c else 1.0
    prob = _ValveProblem.of(ctx, w, kano, d0)
    v, ph = prob.series(_rows(x[0], x[1])[0])
    return ValveFit(v, ph, {"S": float(x[0]), "J": float(x[1])}, kano, d0)


def _delayed(u: np.ndarray, d: int) -> np.ndarray:
    if d <= 0:
        return u
    out = np.empty_like(u)
    out[:d] = u[0]
    out[d:] = u[:-d]
    return out


@jit
def _riccati_gains(pole, load_ratio):  # pragma: no cover - compiled
    p11, p12, p22 = 1.0 + load_ratio, 0.0, 1.0 + load_ratio
    k1 = k2 = 0.0
    for _ in range(2000):
        s = p11 + 1.0
        n1, n2 = p11 / s, p12 / s
        f11 = p11 - n1 * p11
        f12 = p12 - n1 * p12
        f22 = p22 - n2 * p12
        # P = F Pf F' + Q with F = [[a, 1], [0, 1]].
        q11 = pole * pole * f11 + 2.0 * pole * f12 + f22
        q12 = pole * f12 + f22
        q22 = f22 + load_ratio
        done = abs(n1 - k1) < 1e-13 and abs(n2 - k2) < 1e-13
        k1, k2 = n1, n2
        p11, p12, p22 = q11, q12, q22
        if done:
            break
    return k1, k2, p11, p12, p22


def kalman_gains(pole: float, load_ratio: float) -> tuple[float, float]:
    """Steady-state Kalman gains of the process-with-load model.

    States: the process output ``y`` and an unmeasured load ``l`` (a random walk)
    entering with the valve: ``y[k+1] = a y[k] + b u[k-d] + l[k]``, ``l[k+1] = l[k] +
    v[k]``, measured ``pv = y + e``; ``load_ratio`` is var(v)/var(e).  Returns the
    gains of the filtered estimates of ``y`` and ``l`` on the innovation.
    """
    k1, k2, *_ = _riccati_gains(float(pole), float(load_ratio))
    return float(k1), float(k2)


def prediction_variance_ratio(pole: float, load_ratio: float, horizon: int) -> tuple[float, float]:
    """Variances of the one-step innovation and of the ``horizon``-step prediction error,
    in units of the measurement-noise variance, for the process-with-load model.

    A correct model's ``horizon``-step error variance is the second value times the
    measurement noise variance: measurement noise plus the load the filter could not
    foresee.
    """
    k1, k2, p11, p12, p22 = _riccati_gains(float(pole), float(load_ratio))
    s1 = p11 + 1.0
    # Filtered covariance.
    f11, f12, f22 = p11 - k1 * p11, p12 - k1 * p12, p22 - k2 * p12
    P = np.array([[f11, f12], [f12, f22]])
    F = np.array([[pole, 1.0], [0.0, 1.0]])
    Q = np.array([[0.0, 0.0], [0.0, load_ratio]])
    acc = np.zeros((2, 2))
    Fj = np.eye(2)
    for _ in range(max(int(horizon), 1)):
        acc += Fj @ Q @ Fj.T
        Fj = F @ Fj
    Pm = Fj @ P @ Fj.T + acc
    return float(s1), float(Pm[0, 0] + 1.0)


@jit
def _prediction_errors(z, drive, pole, k1, k2, y0, horizon):  # pragma: no cover - compiled
    """Errors of the ``horizon``-step-ahead predictions of the steady-state filter.

    ``z`` are the measurements, ``drive`` the known input term added to the next
    process output.  The filter runs on every sample; the prediction of ``z[k]`` is
    made at ``k - horizon`` from the filtered state then, with the known inputs in
    between and the load held (samples before the horizon get the one-step error).
    """
    n = z.shape[0]
    yf = np.empty(n)
    lf = np.empty(n)
    err = np.empty(n)
    yh = y0
    lh = 0.0
    for k in range(n):
        e = z[k] - yh
        err[k] = e
        yf[k] = yh + k1 * e
        lf[k] = lh + k2 * e
        yh = pole * yf[k] + lf[k] + drive[k]
        lh = lf[k]
    if horizon > 1 and n > horizon:
        # The prediction of z[j0 + horizon] made at j0, for every j0 at once: the same
        # operations per prediction as a loop over it, but the inner loop runs over
        # contiguous samples and is vectorised by the compiler.
        m = n - horizon
        y = yf[:m].copy()
        for i in range(horizon):
            for j0 in range(m):
                y[j0] = pole * y[j0] + lf[j0] + drive[j0 + i]
        for j0 in range(m):
            err[j0 + horizon] = z[j0 + horizon] - y[j0]
    return err


@jit
def _prediction_errors_many(Z, D, y0, pole, k1, k2, horizon):  # pragma: no cover - compiled
    """:func:`_prediction_errors` of every row of ``Z`` (driven by the row of ``D``,
    started at ``y0``) with one filter: the same operations per row, but the rows'
    filters run side by side, so one's latency hides behind the others'."""
    m, n = Z.shape
    yf = np.empty((m, n))
    lf = np.empty((m, n))
    err = np.empty((m, n))
    yh = y0.copy()
    lh = np.zeros(m)
    for k in range(n):
        for c in range(m):
            e = Z[c, k] - yh[c]
            err[c, k] = e
            yf[c, k] = yh[c] + k1 * e
            lf[c, k] = lh[c] + k2 * e
            yh[c] = pole * yf[c, k] + lf[c, k] + D[c, k]
            lh[c] = lf[c, k]
    if horizon > 1 and n > horizon:
        q = n - horizon
        y = np.empty(q)
        for c in range(m):
            for j0 in range(q):
                y[j0] = yf[c, j0]
            for i in range(horizon):
                for j0 in range(q):
                    y[j0] = pole * y[j0] + lf[c, j0] + D[c, j0 + i]
            for j0 in range(q):
                err[c, j0 + horizon] = Z[c, j0 + horizon] - y[j0]
    return err


@dataclass(frozen=True)
class ProcessModel:
    """Structure of the process replay.

    Attributes
    ----------
    pole : float
        Discrete pole of the lag (1: integrating).
    delay : int
        Dead time [samples].
    load_ratio : float
        Load-to-noise variance ratio of the load tracking.
    horizon : int
        Prediction horizon [samples]: pv is predicted this far ahead.
    """

    pole: float
    delay: int
    load_ratio: float
    horizon: int = 1

    @property
    def gains(self) -> tuple[float, float]:
        return kalman_gains(self.pole, self.load_ratio)


def _input_response(u: np.ndarray, model: ProcessModel, k1: float, k2: float) -> np.ndarray:
    """Innovation response to a unit gain on the input without dead time."""
    u0 = u - u[0]
    return _prediction_errors(
        np.zeros(u.size), np.ascontiguousarray(u0), model.pole, k1, k2, 0.0, model.horizon
    )


def _shifted_pair(base: np.ndarray, delay: int) -> np.ndarray:
    """``base`` delayed by ``delay`` and ``delay + 1`` samples, as two columns."""
    X = np.empty((base.size, 2))
    X[:, 0] = _delayed(base, delay)
    X[:, 1] = _delayed(base, delay + 1)
    return X


def _process_regressors(u: np.ndarray, model: ProcessModel, k1: float, k2: float) -> np.ndarray:
    """Innovation responses to a unit gain on the input at two adjacent dead times."""
    return _shifted_pair(_input_response(u, model, k1, k2), model.delay)


#: Entries kept per kind in a context's cache of process terms.
_CACHE_ENTRIES = 24


def _cache_get(cache: dict | None, kind: str, key):
    """The value remembered under ``key`` (see :func:`_cached`), or None."""
    if cache is None:
        return None
    hit = cache.get(kind, {}).get(key)
    return None if hit is None else hit[-1]


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


def _structure_grid(u: np.ndarray, pv: np.ndarray, w: np.ndarray):
    """The one-step prediction-error fit on a grid of poles, dead times and load ratios.

    Returns the best ``(sse, ProcessModel)``, the best per pole and the dead-time grid
    (see :func:`fit_process`).
    """
    n = u.size
    zeros = np.zeros(n)
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
    for pole in pole_grid:
        for lr in ratios:
            k1, k2 = kalman_gains(pole, lr)
            e0 = _prediction_errors(pv, zeros, pole, k1, k2, float(pv[0]), 1)
            base_reg = _prediction_errors(
                zeros, np.ascontiguousarray(u - u[0]), pole, k1, k2, 0.0, 1
            )
            # All dead times at once: Gram matrix of the shifted regressors.
            Xs = np.stack([_delayed(base_reg, int(d)) for d in shifts])
            Xw = Xs * w
            G = Xw @ Xs.T
            g = Xw @ e0
            ee = float(np.dot(w * e0, e0))
            for d in d_grid:
                i, j = where[int(d)], where[int(d) + 1]
                A = np.array([[G[i, i], G[i, j]], [G[j, i], G[j, j]]])
                rhs = -np.array([g[i], g[j]])
                A[0, 0] += 1e-12 * (A[0, 0] + 1e-300)
                A[1, 1] += 1e-12 * (A[1, 1] + 1e-300)
                try:
                    coef = np.linalg.solve(A, rhs)
                except np.linalg.LinAlgError:
                    continue
                if coef[0] * coef[1] < 0.0:
                    # A dead time between d and d + 1 weighs both with one sign: on
                    # the boundary, the better single column (see _fractional_delay_wls).
                    coef = max(
                        (np.array([rhs[0] / A[0, 0], 0.0]), np.array([0.0, rhs[1] / A[1, 1]])),
                        key=lambda c: float(rhs @ c),
                    )
                sse = ee + float(rhs @ coef) * -1.0
                if best is None or sse < best[0]:
                    best = (sse, ProcessModel(float(pole), int(d), float(lr)))
                if pole not in per_pole or sse < per_pole[pole][0]:
                    per_pole[pole] = (sse, ProcessModel(float(pole), int(d), float(lr)))
    return best, per_pole, d_grid


def fit_process(
    u: np.ndarray,
    ctx: ReplayContext,
    w: np.ndarray,
    *,
    extra: np.ndarray | None = None,
    model: ProcessModel | None = None,
    retune: bool = False,
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
    ctx : ReplayContext
        pv and the evaluation weights.
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
    """
    pv, dt = ctx.sig.pv, ctx.sig.dt
    n = u.size
    u = np.ascontiguousarray(u, dtype=float)
    pv = np.ascontiguousarray(pv, dtype=float)
    zeros = np.zeros(n)
    extra_cols = None if extra is None else np.atleast_2d(extra.T).T
    # Terms that depend on the structure only (the innovations of pv, the input's
    # response) are shared with the other fits of this context: the searches over an
    # effect's parameter refit the linear coefficients many times with one structure.
    # Keys hold the arrays they name (an identity stays unique while it is held).
    cache = ctx.cache if isinstance(getattr(ctx, "cache", None), dict) else None
    u_key = (id(u), id(pv))
    memo: dict = {}

    extra_rows = None if extra_cols is None else np.ascontiguousarray(extra_cols.T)
    u0 = np.ascontiguousarray(u - u[0])

    def terms(m: ProcessModel):
        """Innovations of pv, the input's response and the extra columns' responses
        for the filter of ``m``: whatever is not shared yet, in one compiled call."""
        k1, k2 = kalman_gains(m.pole, m.load_ratio)
        fkey = (m.pole, m.load_ratio, m.horizon)
        e_key, b_key = (id(pv), *fkey), (*u_key, *fkey)
        e0 = _cache_get(cache, "innovations", e_key)
        base = _cache_get(cache, "input_response", b_key)
        rows, drives, starts = [], [], []
        if e0 is None:
            rows.append(pv)
            drives.append(zeros)
            starts.append(float(pv[0]))
        if base is None:
            rows.append(zeros)
            drives.append(u0)
            starts.append(0.0)
        n_extra = 0 if extra_rows is None else extra_rows.shape[0]
        E = None
        if rows or n_extra:
            Z = np.empty((len(rows) + n_extra, n))
            D = np.zeros((len(rows) + n_extra, n))
            for i, (z_, d_) in enumerate(zip(rows, drives, strict=True)):
                Z[i] = z_
                D[i] = d_
            if n_extra:
                Z[len(rows) :] = extra_rows
            y0 = np.zeros(Z.shape[0])
            y0[: len(starts)] = starts
            R = _prediction_errors_many(Z, D, y0, m.pole, k1, k2, m.horizon)
            i = 0
            if e0 is None:
                e0 = R[i].copy()
                _cache_put(cache, "innovations", e_key, (pv, e0))
                i += 1
            if base is None:
                base = R[i].copy()
                _cache_put(cache, "input_response", b_key, (u, pv, base))
                i += 1
            E = R[i:]
        X = np.empty((n, 2 + n_extra))
        X[:, 0] = _delayed(base, m.delay)
        X[:, 1] = _delayed(base, m.delay + 1)
        if n_extra:
            # pv = y + d + e: the disturbance enters like a measurement offset.
            X[:, 2:] = -E.T
        return e0, X

    def solve(m: ProcessModel):
        # The searches come back to points already solved (a golden section's last
        # point, the chosen structure): the same model, the same numbers.
        hit = memo.get(m)
        if hit is None:
            hit = memo[m] = _solve(m)
        return hit

    def _solve(m: ProcessModel):
        e0, X = terms(m)
        coef = _fractional_delay_wls(X, -e0, w)
        r = e0 + X @ coef
        return float(np.dot(w, r * r)), coef, r

    if model is None:
        # The grid of structures fits the input alone: shared by every fit of this
        # context with the same input and weights (the extra columns come after).
        best, per_pole, d_grid = _cached(
            cache,
            "structure_grid",
            (*u_key, id(w)),
            lambda: (u, pv, w, _structure_grid(u, pv, w)),
        )
        per_pole = dict(per_pole)
        m = best[1]
        # Refine the dead time to the sample, then the pole and the load ratio.
        i = int(np.searchsorted(d_grid, m.delay))
        for d in range(int(d_grid[max(i - 1, 0)]), int(d_grid[min(i + 1, d_grid.size - 1)]) + 1):
            cand = ProcessModel(m.pole, d, m.load_ratio)
            sse = solve(cand)[0]
            if sse < best[0]:
                best = (sse, cand)
        m = best[1]
        if m.pole < 1.0:
            lt0 = math.log(-1.0 / math.log(m.pole))
            lt = _golden(
                lambda v: solve(ProcessModel(math.exp(-1.0 / math.exp(v)), m.delay, m.load_ratio))[
                    0
                ],
                lt0 - 0.6,
                lt0 + 0.6,
                12,
            )
            cand = ProcessModel(math.exp(-1.0 / math.exp(lt)), m.delay, m.load_ratio)
            sse = solve(cand)[0]
            if sse < best[0]:
                best = (sse, cand)
        m = best[1]
        # Predict as far ahead as the process takes to answer a valve step (dead time
        # plus one time constant): one step ahead, the load tracking hides most of a
        # wrong gain or a slow disturbance.
        # Predict as far ahead as the process takes to answer a valve step: dead time
        # plus one time constant (an integrator answers with a ramp at once; a few
        # samples show its slope).
        tau = 5.0 if m.pole >= 1.0 else min(-1.0 / math.log(max(m.pole, 1e-12)), 40.0)
        horizon = int(min(max(round(m.delay + tau), 2), 60, max(n // 20, 2)))

        def tune(cm: ProcessModel) -> tuple[float, ProcessModel]:
            """Load ratio (coarse grid, then golden) and dead time (+-2) at the horizon."""
            grid = [ProcessModel(cm.pole, cm.delay, 10.0**e, horizon) for e in range(-9, 1)]
            sse, cm = min(((solve(g)[0], g) for g in grid), key=lambda v: v[0])
            c0 = math.log10(cm.load_ratio)
            ll = _golden(
                lambda v: solve(ProcessModel(cm.pole, cm.delay, 10.0**v, horizon))[0],
                c0 - 1.0,
                c0 + 1.0,
                10,
            )
            cand = ProcessModel(cm.pole, cm.delay, 10.0**ll, horizon)
            c = solve(cand)[0]
            if c < sse:
                sse, cm = c, cand
            for dd in (-2, -1, 1, 2):
                if cm.delay + dd < 0:
                    continue
                cand = ProcessModel(cm.pole, cm.delay + dd, cm.load_ratio, horizon)
                c = solve(cand)[0]
                if c < sse:
                    sse, cm = c, cand
            return sse, cm

        # The structure is judged where the replay is: the best lags of the one-step
        # grid and the integrator, each tuned at the horizon (a lag and an integrator
        # can predict one step ahead equally well, not further).
        best_h = tune(m)
        others = sorted(per_pole.values(), key=lambda v: v[0])[:3]
        if 1.0 in per_pole:
            others.append(per_pole[1.0])
        for _, cm in others:
            if cm.pole == m.pole:
                continue
            cand = tune(cm)
            if cand[0] < best_h[0]:
                best_h = cand
        model = best_h[1]
    elif retune:
        m0 = model
        lo, hi = math.log10(m0.load_ratio) - 2.0, math.log10(m0.load_ratio) + 1.0
        ll = _golden(
            lambda v: solve(ProcessModel(m0.pole, m0.delay, 10.0**v, m0.horizon))[0], lo, hi, 12
        )
        cand = ProcessModel(m0.pole, m0.delay, 10.0**ll, m0.horizon)
        if solve(cand)[0] < solve(m0)[0]:
            model = cand
    _, coef, r = solve(model)
    params = _process_params(model, coef, dt)
    return ProcessFit(pv=pv - r, model=model, coef=coef, params=params)


def _process_params(model: ProcessModel, coef: np.ndarray, dt: float) -> dict:
    pole = model.pole
    integrating = pole >= 1.0
    b = float(coef[0] + coef[1])
    frac = float(coef[1] / b) if abs(b) > 1e-12 else 0.0
    frac = min(max(frac, 0.0), 1.0)
    if integrating:
        gain, tau = b / dt, None
    else:
        gain = b / (1.0 - pole)
        tau = -dt / math.log(pole) if pole > 0.0 else 0.0
    return {
        "integrating": integrating,
        "gain": gain,
        "time_constant_s": tau,
        "dead_time_s": (model.delay + frac) * dt,
        "load_to_noise_ratio": model.load_ratio,
    }


def process_noise_floor(
    u: np.ndarray, ctx: ReplayContext, fit: ProcessFit, extra: np.ndarray | None = None
) -> float:
    """Variance of the pv prediction error that a correct process replay still makes [pv^2].

    The measurement-noise variance is read from the one-step innovations of the fitted
    replay (their variance is a known multiple of it for the fitted load-to-noise
    ratio), and the horizon's error is that multiple of it again
    (:func:`prediction_variance_ratio`): measurement noise plus the load the filter
    could not foresee.
    """
    m = fit.model
    k1, k2 = kalman_gains(m.pole, m.load_ratio)
    pv = np.ascontiguousarray(ctx.sig.pv, dtype=float)
    zeros = np.zeros(pv.size)
    one = ProcessModel(m.pole, m.delay, m.load_ratio, 1)
    e0 = _prediction_errors(pv, zeros, m.pole, k1, k2, float(pv[0]), 1)
    X = _process_regressors(np.ascontiguousarray(u, dtype=float), one, k1, k2)
    if extra is not None and fit.coef.size > 2:
        E = np.column_stack(
            [
                -_prediction_errors(np.ascontiguousarray(c), zeros, m.pole, k1, k2, 0.0, 1)
                for c in np.atleast_2d(extra.T)
            ]
        )
        X = np.column_stack([X, E])
    e1 = e0 + X @ fit.coef[: X.shape[1]]
    w = ctx.w_eval
    s1 = float(np.dot(w, e1 * e1)) / max(float(w.sum()), 1.0)
    r1, rm = prediction_variance_ratio(m.pole, m.load_ratio, m.horizon)
    return s1 / r1 * rm


def fit_controller(sig: LoopSignals, w: np.ndarray) -> tuple[np.ndarray, dict]:
    """PI controller replay on a filtered measurement (Eq. 3).

    ``op = bias + Kc (e + (1/Ti) integral(e))``, ``e = sp - pv_f`` with ``pv_f`` a
    first-order filtered pv (a transmitter or DCS filter); linear least squares in
    (bias, Kc, Kc/Ti) for each filter time on a short grid.  Without a recorded set
    point a ramp column absorbs the constant set point in the integral.

    Returns
    -------
    op_hat : ndarray
        Replayed controller output [% of span].
    params : dict
        ``gain`` Kc [% / pv units], ``integral_time_s`` Ti [s] (None without integral
        action), ``filter_time_s`` [s], ``bias`` [% of span].
    """
    n = sig.n
    sp = sig.sp if sig.sp is not None else np.zeros(n)
    best = None
    for tf in (0.0, 0.5, 1.0, 2.0, 3.0, 5.0):
        pvf = first_order_lag(sig.pv, tf * sig.dt, sig.dt) if tf > 0 else sig.pv
        e = sp - pvf
        cols = [np.ones(n), e, np.cumsum(e) * sig.dt]
        if sig.sp is None:
            cols.append(np.arange(n, dtype=float) * sig.dt)
        X = np.column_stack(cols)
        coef = _wls(X, sig.op, w)
        pred = np.clip(X @ coef, 0.0, 100.0)
        sse = float(np.dot(w, (pred - sig.op) ** 2))
        if best is None or sse < best[0]:
            best = (sse, pred, coef, tf)
    _, pred, coef, tf = best
    kc, ki = float(coef[1]), float(coef[2])
    ti = kc / ki if abs(ki) > 1e-12 and kc / ki > 0 else None
    return pred, {
        "gain": kc,
        "integral_time_s": ti,
        "filter_time_s": tf * sig.dt,
        "bias": float(coef[0]),
    }


# --------------------------------------------------------------------------------------
# Base replay and candidate effects
# --------------------------------------------------------------------------------------


def _process_input(ctx: ReplayContext, base: BaseFit | None = None) -> np.ndarray:
    if ctx.sig.mv is not None:
        return ctx.sig.mv
    if base is not None:
        return base.mv_model
    return ctx.mv_model


def fit_base(ctx: ReplayContext, w: np.ndarray, *, like: BaseFit | None = None) -> BaseFit:
    """Fit the base replay: the two-parameter valve, the process and the controller.

    Parameters
    ----------
    ctx : ReplayContext
        Signals, slow-load basis, starting S and J.
    w : ndarray
        Sample weights (0 or 1).
    like : BaseFit, optional
        The fit on the whole record, to start from (fits on parts of the record).
    """
    sig = ctx.sig
    valve = None
    if sig.mv is not None:
        valve = fit_valve(ctx, w, like=None if like is None else like.valve)
        mvm = valve.mv
    else:
        mvm = ctx.mv_model
        if mvm is None:
            S, J = ctx.start if ctx.start is not None else (0.0, 0.0)
            mvm, _ = valve_replay(sig.op, S, J)
    u = sig.mv if sig.mv is not None else mvm
    process = fit_process(u, ctx, w, model=None if like is None else like.process.model)
    op_hat, ctrl = fit_controller(sig, w)
    return BaseFit(valve=valve, process=process, op=op_hat, controller=ctrl, mv_model=mvm)


def _problem(ctx: ReplayContext, w: np.ndarray, base: BaseFit) -> _ValveProblem:
    return _ValveProblem.of(ctx, w, base.valve.kano, base.valve.initial_direction)


def _pick_problem(ctx, w, base, init, evaluate) -> _ValveProblem:
    """The stuck-phase logic for an augmented valve: the one of the whole-record fit
    ``init``, else whichever makes ``evaluate(problem)`` (the error at the starting
    points) lower.  The base fit's logic is not enough: an effect can make the other
    logic the better reading of the same data."""
    d0 = base.valve.initial_direction
    if init is not None:
        return _ValveProblem.of(ctx, w, init.params.get("logic") == "kano", d0)
    probs = [_ValveProblem.of(ctx, w, k, d0) for k in (False, True)]
    return min(probs, key=evaluate)


def _logic(prob: _ValveProblem) -> str:
    return "kano" if prob.kano else "choudhury"


def _scale(*values: float) -> float:
    return max(max(values), 0.05)


def _lag_weight(tau_samples: float) -> float:
    return math.exp(-1.0 / tau_samples) if tau_samples > 1e-6 else 0.0


def fit_actuator_lag(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """Positioner/actuator dynamics after the friction element: ``mv = lag(valve(op))``.

    The stiction element of Fig. 10 is followed by a first-order lag with time
    constant tau [s].  The breakaways of the element do not depend on the lag, so S
    and J are searched with a provisional lag, then tau by golden-section search,
    then S and J again.
    """
    seeds = [(base.valve.params["S"], base.valve.params["J"])]
    med = _slip_medians(ctx.slips)
    if med is not None:
        seeds.append(med)
    seeds += _travel_seeds(ctx.slips)
    prob = _pick_problem(
        ctx,
        w,
        base,
        init,
        lambda pr: float(np.min(pr.costs(_rows(*np.array(seeds).T, lag=_lag_weight(2.0))))),
    )
    travel = _travel(ctx.sig.op)
    dt = ctx.sig.dt
    tau_max = max(ctx.sig.n / 20.0, 2.0)

    def cost_tau(S, J):
        return lambda t: float(prob.costs(_rows(S, J, lag=_lag_weight(t)))[0])

    if init is not None:
        # Thresholds from the whole record; the lag is refitted here.
        S, J, tau = init.x
    else:
        # The breakaways do not depend on the lag: S and J with a few provisional lags
        # (a lag hides the size of the slips, so J can be far from the base fit's).
        best = None
        for tau in (1.0, 3.0, 6.0):

            def cost2(X, bound, tau=tau):
                return prob.costs(_rows(X[:, 0], X[:, 1], lag=_lag_weight(tau)), bound=bound)

            x = _sj_wide(cost2, seeds)
            x, c = grid_search_nd(cost2, x, (0, 1), stages=_WIDE_STAGES[1:])
            if best is None or c < best[0]:
                best = (c, x, tau)
        _, (S, J), tau = best
        (S, J), _ = _needle_sj(prob, [(S, J)], travel, rel=0.05, n_grid=15, lag=_lag_weight(tau))
        lt = _golden(lambda v: cost_tau(S, J)(math.exp(v)), math.log(0.1), math.log(tau_max), 24)
        tau = math.exp(lt)
        (S, J), _ = _needle_sj(prob, [(S, J)], travel, rel=0.05, n_grid=15, lag=_lag_weight(tau))
    lt = _golden(
        lambda v: cost_tau(S, J)(math.exp(v)),
        math.log(max(tau / 3, 0.05)),
        math.log(min(3 * tau + 0.1, tau_max)),
        16,
    )
    tau = math.exp(lt)
    mv_hat, _ = prob.series(_rows(S, J, lag=_lag_weight(tau))[0])
    return EffectFit(
        # A lag shorter than half a sample cannot be told from the timing jitter of
        # the replayed slips: it smooths every mistimed jump a little.
        supported=tau >= 0.5,
        effect="actuator_lag",
        variant="first_order",
        n_params=1,
        params={
            "S": float(S),
            "J": float(J),
            "time_constant_s": float(tau * dt),
            "logic": _logic(prob),
        },
        predictions={"mv": mv_hat},
        x=(float(S), float(J), float(tau)),
    )


def _affine(v: np.ndarray, mv: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Least-squares ``mv = b + k v`` on the weighted samples: (k, b)."""
    sw = w > 0
    vv, mm = v[sw], mv[sw]
    vm = vv.mean()
    den = float(np.dot(vv - vm, vv - vm))
    if den <= 0.0:
        return 1.0, float(mm.mean() - vm)
    k = float(np.dot(vv - vm, mm - mm.mean()) / den)
    return k, float(mm.mean() - k * vm)


def fit_miscalibration(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """Miscalibrated positioner: ``mv = offset + slope * valve(op)`` (Section 4.2.1, Fig. 8).

    A calibration factor that is too large makes the moving-phase slope of mv
    against op greater than 1.  The data-driven model scales exactly with its input,
    so a span error before the friction element (``demand = pivot + slope (op -
    pivot)``) is this model with S and J divided by the slope; S and J on the op
    axis are searched, slope and offset solved in closed form for every trial.
    """
    travel = _travel(ctx.sig.op)
    S0, J0 = base.valve.params["S"], base.valve.params["J"]
    slopes = np.geomspace(0.4, 2.5, 41)
    prob = _pick_problem(
        ctx,
        w,
        base,
        init,
        lambda pr: float(np.min(pr.costs(_rows(S0 / slopes, J0 / slopes), affine=True))),
    )
    if init is not None:
        # Thresholds from the whole record; slope and offset are solved on the samples
        # of ``w`` below.
        prob = prob.with_output_map(init.params["slope"], init.params["offset_pct"])
        x = np.array(init.x)
    else:
        c = prob.costs(_rows(S0 / slopes, J0 / slopes), affine=True)
        i = int(np.argmin(c))
        # The element starts at the recorded rest level in its own units: map it back
        # with the slope and offset of the best scanned point before the search.
        v, _ = prob.series(_rows(S0 / slopes[i], J0 / slopes[i])[0])
        prob = prob.with_output_map(*_affine(v, ctx.sig.mv, w))
        c = prob.costs(_rows(S0 / slopes, J0 / slopes), affine=True)
        seeds = [(S0 / slopes[i], J0 / slopes[i]) for i in np.argsort(c)[:2]]
        # The demand travel of the slips is on the op axis already.
        seeds += _travel_seeds(ctx.slips)
        # Only the best point of the wide grid is used: the others need not be exact.
        wide = _sj_wide(
            lambda X, bound: prob.costs(_rows(X[:, 0], X[:, 1]), affine=True, keep=1), seeds
        )
        x, _ = _needle_sj_affine(prob, [*seeds, tuple(wide)], travel * 3)
    v, _ = prob.series(_rows(x[0], x[1])[0])
    slope, offset = _affine(v, ctx.sig.mv, w)
    for _ in range(2 if init is None else 0):
        prob = prob.with_output_map(slope, offset)
        x, _ = _needle_sj_affine(prob, [x], travel * 3, rel=0.03, zooms=1, n_grid=11)
        v, _ = prob.series(_rows(x[0], x[1])[0])
        slope, offset = _affine(v, ctx.sig.mv, w)
    # The signature (whole-record fit only): the slope of the position after each
    # slip against the demand at its breakaway, measured in the data, differs from 1
    # in the fitted direction (:func:`slip_slope_test`, one-sided).
    slip_slope, p_slope = math.nan, 0.0
    if init is None:
        slip_slope, p_slope = slip_slope_test(ctx.slips)
        if math.isfinite(slip_slope):
            p_slope = _one_sided(p_slope, (slip_slope - 1.0) * (slope - 1.0) > 0.0)
        else:
            # Too few measured slips to test (as for :func:`_slips_differ`): the
            # replay decides alone.
            p_slope = 0.0
    return EffectFit(
        effect="miscalibration",
        variant="slope_offset",
        n_params=2,
        supported=p_slope < SIGNATURE_P,
        params={
            "S": float(x[0] * slope),
            "J": float(x[1] * slope),
            "S_on_op_axis": float(x[0]),
            "J_on_op_axis": float(x[1]),
            "slope": slope,
            "offset_pct": offset,
            "logic": _logic(prob),
            "slip_slope": slip_slope,
            "slip_slope_p": p_slope,
        },
        predictions={"mv": offset + slope * v},
        x=(float(x[0]), float(x[1])),
    )


def _needle_sj_affine(prob: _ValveProblem, seeds, travel: float, *, rel=0.15, zooms=2, n_grid=31):
    lower, upper = _sj_bounds(travel)

    def cost(X, bound):
        # needle_search uses the order of the ``beam`` (3) best rows of a grid only;
        # its grids are centred on the best point so far.
        return prob.costs(_rows(X[:, 0], X[:, 1]), affine=True, keep=3, order=_centre_first(X))

    best = None
    for s in seeds:
        x, c = needle_search(
            cost, np.asarray(s, dtype=float), (0, 1), lower, upper, rel=rel, zooms=zooms
        )
        if best is None or c < best[1]:
            best = (x, c)
    return best


def fit_asymmetry(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """Different S and J opening and closing (Loop 1 of Section 3, Fig. 3).

    Fig. 10 and Eq. 4 with S and J taken from the direction of travel: four
    parameters instead of two, searched a direction at a time (the other held) from
    the base fit and from the slips measured in each direction.
    """
    travel = _travel(ctx.sig.op)
    lower, upper = np.zeros(4), np.array([travel, 1.5 * travel] * 2)
    S0, J0 = base.valve.params["S"], base.valve.params["J"]
    seeds = [np.array([S0, J0, S0, J0])]
    ups = _travel_seeds(ctx.slips, 1.0) or [(S0, J0)]
    dns = _travel_seeds(ctx.slips, -1.0) or [(S0, J0)]
    for up in ups:
        for dn in dns:
            seeds.append(np.array([up[0], up[1], dn[0], dn[1]]))
    S4 = np.array(seeds)
    prob = _pick_problem(ctx, w, base, init, lambda pr: float(np.min(pr.costs(_rows(*S4.T)))))

    def cost(X, bound):
        return prob.costs(_rows(X[:, 0], X[:, 1], X[:, 2], X[:, 3]), bound=bound)

    if init is not None:
        # Thresholds only: kept from the whole record (judged there with a penalty per
        # parameter and the block consistency of :mod:`stictiondiag.gap.diagnose`).
        x = np.array(init.x)
    else:
        c = cost(S4, np.inf)
        x = seeds[int(np.argmin(c))]
        # All four together: the two directions' slips are coupled through where the
        # valve stops.
        x, _ = grid_search_nd(cost, x, (0, 1, 2, 3), stages=_WIDE_STAGES)
        for pair in ((0, 1), (2, 3)):
            x, _ = needle_search(cost, x, pair, lower, upper, rel=0.03, zooms=1, n_grid=11)
    mv_hat, _ = prob.series(_rows(x[0], x[1], x[2], x[3])[0])
    p_slips = (
        _slips_differ(ctx.slips, ctx.slips["direction"] > 0, ctx.slips["direction"] < 0)
        if ctx.slips is not None
        else 0.0
    )
    return EffectFit(
        supported=p_slips < SLIP_TEST_P,
        effect="asymmetry",
        variant="open_close",
        n_params=2,
        params={
            "S_open": float(x[0]),
            "J_open": float(x[1]),
            "S_close": float(x[2]),
            "J_close": float(x[3]),
            "logic": _logic(prob),
            "slips_differ_p": p_slips,
        },
        predictions={"mv": mv_hat},
        x=tuple(float(v) for v in x),
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


def _one_sided(p_two_sided: float, agrees: bool) -> float:
    """p-value of the one-sided test in the direction of the fitted effect from that of
    the two-sided test: half of it when the estimate points that way, else 1 or more
    (``1 - p/2``)."""
    return 0.5 * p_two_sided if agrees else 1.0 - 0.5 * p_two_sided


def _slip_blocks(n_rows: int) -> int:
    """Blocks for :func:`signature_test` on per-slip values: three slips or more each."""
    return min(SIGNATURE_BLOCKS, n_rows // 3)


def _testable_slips(slips: dict | None):
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


def slip_slope_test(slips: dict | None) -> tuple[float, float]:
    """Slope of the valve position after each slip against the demand it broke away at,
    and the two-sided p-value that it is 1: ``(slope, p)``.

    After a slip the two-parameter valve rests at (or, moving on, follows) the demand
    less ``d (S - J)/2`` (Section 5.1, Eq. 4, ``d`` the direction the demand moves
    in at the breakaway): the position after each slip, measured in the data
    (:func:`measure_slips`), against the demand at the breakaway is a line of slope 1
    with one offset per direction, wherever along
    its travel the valve slips.  A miscalibrated positioner gives another slope
    (Section 4.2.1, Fig. 8, bottom row).  The slope's uncertainty comes from the
    scatter between blocks of consecutive slips (:func:`signature_test`); ``(nan, 1)``
    with fewer than twelve slips (too few to test: :func:`fit_miscalibration` then
    leaves the decision to the replay, as :func:`_slips_differ` does).
    """
    measured = _testable_slips(slips)
    if measured is None:
        return math.nan, 1.0
    x, y, d, n_blocks = measured
    others = np.column_stack([(d > 0).astype(float), (d < 0).astype(float)])
    beta, p = signature_test(x, y - x, np.ones(x.size), others=others, n_blocks=n_blocks)
    if p >= 1.0 and beta == 0.0:
        return math.nan, 1.0
    return 1.0 + beta, p


def _slips_differ(slips: dict | None, a: np.ndarray, b: np.ndarray) -> float:
    """Smallest p-value of two-sided rank tests that the slips in ``a`` and ``b`` differ,
    in the demand travel at reversals (S) or in the jump (J); 0 when there are too
    few measured slips to test (fewer than three on a side: the replay decides alone).

    Thresholds are fitted on the whole record, where a replay that is more flexible
    can fall in step with a few more slips by chance; the slips measured one by one
    (:func:`measure_slips`) must show the difference too.
    """
    from stictiondiag.core.stats import (
        mannwhitneyu,  # scipy.stats.mannwhitneyu, without importing scipy.stats
    )

    if slips is None:
        return 0.0
    p = 1.0
    tested = False
    for key, mask in (("travel", slips["reversal"]), ("J", np.ones(slips["J"].size, dtype=bool))):
        x, y = slips[key][a & mask], slips[key][b & mask]
        if x.size >= 3 and y.size >= 3:
            tested = True
            p = min(p, float(mannwhitneyu(x, y, alternative="two-sided").pvalue))
    return p if tested else 0.0


def _change_sides(times: np.ndarray, t1: float, t2: float, n: int) -> tuple:
    """Slips before and after a change of stiction between samples t1 and t2 (masks
    of ``times``): those before t1 and after t2; for a drift over the whole record,
    those in its first and second half.  A change placed at an end of the record
    leaves (almost) no slips on that side: then those before and after the middle of
    the change, so that the fit cannot place a change where the slips cannot test it
    (fewer than three on a side leave the decision to the replay,
    :func:`_slips_differ`)."""
    if t1 <= 0.0 and t2 >= n - 1:
        return times < n / 2, times >= n / 2
    early, late = times < t1, times > t2
    if min(int(early.sum()), int(late.sum())) < 3:
        mid = 0.5 * (t1 + t2)
        early, late = times < mid, times >= mid
    return early, late


def _profile(n: int, t1: float, t2: float) -> np.ndarray:
    """0 before sample t1, 1 after t2, linear between (a step when t2 <= t1)."""
    k = np.arange(n, dtype=float)
    if t2 <= t1 + 1e-9:
        return (k >= t1).astype(float)
    return np.clip((k - t1) / (t2 - t1), 0.0, 1.0)


def _window_fits(ctx: ReplayContext, w: np.ndarray, base: BaseFit, n_win: int) -> list:
    """S and J fitted on each of ``n_win`` windows of the record on its own.

    Each window is replayed from the data: it starts at the window's first sample
    and is judged from its first measured slip on (the valve state before is
    unknown), so a window costs a fraction of a whole-record replay.
    """
    sig = ctx.sig
    n = sig.n
    travel = _travel(sig.op)
    S0, J0 = base.valve.params["S"], base.valve.params["J"]
    edges = np.linspace(0, n, n_win + 1).astype(int)
    slip_t = ctx.slips["time"] if ctx.slips is not None else np.zeros(0)
    slip_d = ctx.slips["direction"] if ctx.slips is not None else np.zeros(0)
    out = []
    for i in range(n_win):
        a, b = edges[i], edges[i + 1]
        ww = w[a:b].copy()
        inside = (slip_t >= a) & (slip_t < b)
        first = int(slip_t[inside][0]) - a if inside.any() else (b - a) // 10
        ww[: first + 2] = 0.0
        if ww.sum() < 0.25 * (b - a):
            out.append(None)
            continue
        before = slip_d[slip_t < a]
        d0 = float(before[-1]) if before.size else base.valve.initial_direction
        prob = _ValveProblem(
            sig.op[a:b],
            sig.mv[a:b],
            ww,
            ctx.norm["mv"],
            base.valve.kano,
            d0,
            float(np.median(sig.mv[a : a + 3])),
        )
        seeds = [(S0, J0)]
        med = _slip_medians(ctx.slips, inside)
        if med is not None:
            seeds.append(med)
        seeds += _travel_seeds(ctx.slips, mask=inside)
        ratios = np.geomspace(1 / 3, 3.0, 13)
        RR, JJ = np.meshgrid(ratios, np.linspace(0.0, 1.5, 7), indexing="ij")
        sc = _scale(S0, J0)
        coarse = np.column_stack([(sc * RR).ravel(), (sc * RR * JJ).ravel()])
        c = prob.costs(_rows(coarse[:, 0], coarse[:, 1]))
        seeds += [tuple(coarse[k]) for k in np.argsort(c)[:2]]
        x, _ = _needle_sj(prob, seeds, travel, rel=0.15, zooms=1)
        out.append((0.5 * (a + b), float(x[0]), float(x[1]), float(ww.sum())))
    return out


def fit_time_varying_stiction(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """S and J changing during the record: a step, a ramp between two instants, or a drift.

    ``S(t) = S0 + (S1 - S0) h(t)``, the same for J, with ``h`` rising from 0 to 1
    between t1 and t2 (a step when t1 = t2; a drift over the record when t1 = 0 and
    t2 = T).  S and J are first fitted on six windows of the record; the profile
    that best matches those values starts the joint search.
    """
    n = ctx.sig.n
    travel = _travel(ctx.sig.op)
    lower, upper = np.zeros(4), np.array([travel, 1.5 * travel] * 2)
    prob = _problem(ctx, w, base) if init is None else _pick_problem(ctx, w, base, init, None)

    def cost_h(h):
        def cost(X, bound):
            return prob.costs(
                _rows(
                    X[:, 0],
                    X[:, 1],
                    S_open_end=X[:, 2],
                    J_open_end=X[:, 3],
                    S_close_end=X[:, 2],
                    J_close_end=X[:, 3],
                ),
                h,
                bound=bound,
            )

        return cost

    def search(t1, t2, x, rel, zooms):
        cost = cost_h(_profile(n, t1, t2))
        # Start and end values together (coupled through where the valve stops),
        # then each pair finely.
        stages = _TVS_STAGES if rel > 0.1 else ((0.02, 5), (0.005, 5))
        x, _ = grid_search_nd(cost, x, (0, 1, 2, 3), stages=stages)
        for pair in ((0, 1), (2, 3)):
            x, c = needle_search(
                cost, x, pair, lower, upper, rel=rel, zooms=zooms, n_grid=11 if rel < 0.1 else 31
            )
        return x, c

    S0, J0 = base.valve.params["S"], base.valve.params["J"]
    win = []
    if init is not None:
        t1, t2 = (
            init.params["change_start_s"] / ctx.sig.dt,
            init.params["change_end_s"] / ctx.sig.dt,
        )
        # Thresholds and instants only: kept from the whole record.
        x = np.array(init.x)
        results = [(0.0, x, t1, t2, prob)]
    else:
        win = _window_fits(ctx, w, base, 6)
        pts = [v for v in win if v is not None]
        shapes = [(0.0, float(n - 1))]
        if len(pts) >= 3:
            centers = np.array([p[0] for p in pts])
            vals = np.array([[p[1], p[2]] for p in pts])
            best_shape = None
            for t1 in np.linspace(0.1, 0.9, 17) * n:
                for width in (0.0, 0.15 * n, 0.3 * n):
                    if width > 0:
                        h = np.clip((centers - t1) / width, 0.0, 1.0)
                    else:
                        h = (centers >= t1).astype(float)
                    A = np.column_stack([1.0 - h, h])
                    coef, *_ = np.linalg.lstsq(A, vals, rcond=None)
                    c = float(np.sum((A @ coef - vals) ** 2))
                    if best_shape is None or c < best_shape[0]:
                        best_shape = (c, t1, t1 + width)
            shapes.append((best_shape[1], best_shape[2]))
        results = []
        for t1, t2 in shapes:
            # Either stuck-phase logic, whichever reads the profile's start better.
            early = [p for p in pts if p[0] < t1] or pts[:1]
            late = [p for p in pts if p[0] > t2] or pts[-1:]
            if early and late:
                x = np.array(
                    [
                        np.median([p[1] for p in early]),
                        np.median([p[2] for p in early]),
                        np.median([p[1] for p in late]),
                        np.median([p[2] for p in late]),
                    ]
                )
            else:
                x = np.array([S0, J0, S0, J0])
            h0 = _profile(n, t1, t2)
            row0 = _rows(
                x[0], x[1], S_open_end=x[2], J_open_end=x[3], S_close_end=x[2], J_close_end=x[3]
            )
            prob = _pick_problem(
                ctx, w, base, None, lambda pr, h0=h0, row0=row0: float(pr.costs(row0, h0)[0])
            )
            x, c = search(t1, t2, x, 0.15, 2)
            # Move the instants by a few percent of the record while that helps.
            for _ in range(4):
                moved = False
                for d1, d2 in ((-1, -1), (1, 1), (-1, 0), (1, 0), (0, -1), (0, 1)):
                    a, b = t1 + d1 * 0.02 * n, t2 + d2 * 0.02 * n
                    if a < 0 or b > n - 1 or b < a:
                        continue
                    cc = float(cost_h(_profile(n, a, b))(x[None, :], np.inf)[0])
                    if cc < c:
                        c, t1, t2, moved = cc, a, b, True
                if not moved:
                    break
            x, c = search(t1, t2, x, 0.05, 1)
            results.append((c, x, t1, t2, prob))
    c, x, t1, t2, prob = min(results, key=lambda r: r[0])
    h = _profile(n, t1, t2)
    row = _rows(x[0], x[1], S_open_end=x[2], J_open_end=x[3], S_close_end=x[2], J_close_end=x[3])[0]
    mv_hat, _ = prob.series(row, h)
    if ctx.slips is not None:
        early, late = _change_sides(ctx.slips["time"], t1, t2, n)
        p_slips = _slips_differ(ctx.slips, early, late)
    else:
        p_slips = 0.0
    if t1 <= 0.0 and t2 >= n - 1:
        variant, n_params = "drift", 2
    elif t2 - t1 < 1.0:
        variant, n_params = "step", 3
    else:
        variant, n_params = "ramp", 4
    params = {
        "S_start": float(x[0]),
        "J_start": float(x[1]),
        "S_end": float(x[2]),
        "J_end": float(x[3]),
        "change_start_s": float(t1) * ctx.sig.dt,
        "change_end_s": float(t2) * ctx.sig.dt,
        "logic": _logic(prob),
        "slips_differ_p": p_slips,
    }
    if win:
        params["windows"] = [
            None if v is None else {"time_s": v[0] * ctx.sig.dt, "S": v[1], "J": v[2]} for v in win
        ]
    return EffectFit(
        supported=p_slips < SLIP_TEST_P,
        effect="time_varying_stiction",
        variant=variant,
        n_params=n_params,
        params=params,
        predictions={"mv": mv_hat},
        x=tuple(float(v) for v in x),
    )


_CURVATURE_GRIDS = {
    "exponential": (np.linspace(-6.0, 6.0, 13), (-10.0, 10.0)),
    "power": (np.linspace(-1.5, 1.5, 13), (-2.5, 2.5)),
}


def _search_curvature(cost: Callable[[float], float], family: str) -> tuple[float, float]:
    grid, bounds = _CURVATURE_GRIDS[family]
    costs = [cost(float(c)) for c in grid]
    i = int(np.argmin(costs))
    c = _golden(cost, float(grid[max(i - 1, 0)]), float(grid[min(i + 1, grid.size - 1)]), 14)
    c = float(np.clip(c, *bounds))
    cc = cost(c)
    return (c, cc) if cc < costs[i] else (float(grid[i]), costs[i])


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    v = np.asarray(x, dtype=float)[w > 0]
    return float(np.median(v)) if v.size else float(np.median(x))


def gain_change_test(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, side: str
) -> tuple[float, float]:
    """The signature of an installed characteristic: a gain that changes with the
    operating point, which no linear process gives (Section 5.1, last step of Fig. 10).

    The base replay's input ``u`` is joined by a hinge ``max(u - u_50, 0)`` at its
    median: its coefficient is the relative change of the gain above the middle of
    the range travelled against below it, whatever the shape of the curve.
    Process side (``u`` the process input): the hinge passes through the base
    process's dynamics, load tracking and prediction horizon, and its coefficient is
    fitted to the base pv replay's errors.  Valve side (mv itself flow-like): the
    position after each slip against the demand at its breakaway and the hinge of it,
    with an offset per direction (as :func:`slip_slope_test`).  Returns the
    relative gain change and the two-sided p-value of :func:`signature_test` (the
    block-to-block scatter of the record decides, so a change that only part of the
    record shows does not pass).  An operating point that never moves (a cycle
    between two fixed positions) leaves the hinge a copy of ``u``: p = 1.  On the
    valve side with fewer than twelve measured slips: ``(nan, 1)``, too few to test.
    """
    sig = ctx.sig
    if side == "process":
        u = _process_input(ctx, base)
        model = base.process.model
        k1, k2 = model.gains
        h = np.maximum(u - _weighted_median(u, w), 0.0)
        X_u = _process_regressors(u, model, k1, k2)
        x_h = _process_regressors(h, model, k1, k2) @ base.process.coef[:2]
        r = sig.pv - base.process.pv
        others = np.column_stack([np.ones(sig.n), X_u])
        return signature_test(x_h, -r, w, others=others)
    measured = _testable_slips(ctx.slips)
    if measured is None:
        return math.nan, 1.0
    x, y, d, n_blocks = measured
    others = np.column_stack([(d > 0).astype(float), (d < 0).astype(float), x])
    h = np.maximum(x - float(np.median(x)), 0.0)
    beta, p = signature_test(h, y, np.ones(x.size), others=others, n_blocks=n_blocks)
    b = float(np.linalg.lstsq(others, y, rcond=None)[0][2])
    return (beta / b if b != 0.0 else 0.0), p


def fit_valve_characteristic(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """A non-linear installed characteristic between valve position and flow.

    Process side: ``pv = G(f(mv))``, the curvature of ``f`` searched with the process
    dynamics of the base fit and its gain, initial state and slow load refitted.
    Valve side (mv itself flow-like): ``mv = a + b f(valve(op))``.  Two families,
    exponential and power; the form with the lower error on mv and pv together is
    kept.
    """
    sig = ctx.sig
    u = _process_input(ctx, base)
    model = base.process.model
    pv, var_pv = sig.pv, ctx.norm["pv"]
    base_pv_cost = float(np.dot(w, (base.process.pv - pv) ** 2)) / var_pv
    forms = ["process_exponential", "process_power"]
    if sig.mv is not None:
        forms += ["valve_exponential", "valve_power"]
        prob = _problem(ctx, w, base)
        row = _rows(base.valve.params["S"], base.valve.params["J"])
        base_mv_cost = float(prob.costs(row)[0])
    if init is not None:
        forms = [init.variant]
    results = []
    for form in forms:
        side, family = form.split("_")
        if side == "process":

            def cost_pv(c, family=family):
                f = fit_process(characteristic_curve(u, c, family), ctx, w, model=model)
                return float(np.dot(w, (f.pv - pv) ** 2)) / var_pv

            if init is not None:
                c = float(init.params["curvature"])
                cc = cost_pv(c)
            else:
                c, cc = _search_curvature(cost_pv, family)
            ue = characteristic_curve(u, c, family)
            if init is None:
                f = fit_process(ue, ctx, w, model=model, retune=True)
            else:
                f = fit_process(ue, ctx, w, model=init.process.model if init.process else model)
            cc = float(np.dot(w, (f.pv - pv) ** 2)) / var_pv
            results.append(
                (cc, form, 1, {"curvature": c, "family": family, "side": side}, {"pv": f.pv}, f, ue)
            )
        else:

            def cost_mv(c, family=family):
                return float(prob.costs(row, affine=True, curvature=c, family=family)[0])

            if init is not None:
                c = float(init.params["curvature"])
                cc = cost_mv(c)
            else:
                c, cc = _search_curvature(cost_mv, family)
            g = characteristic_curve(base.valve.mv, c, family)
            k, b = _affine(g, sig.mv, w)
            # On the same footing as the process side: error on mv and pv together.
            results.append(
                (
                    cc + base_pv_cost - base_mv_cost,
                    form,
                    3,
                    {"curvature": c, "family": family, "side": side},
                    {"mv": b + k * g},
                    None,
                    None,
                )
            )
    _, variant, n_params, params, preds, proc, ue = min(results, key=lambda r: r[0])
    supported = True
    if init is None:
        gain_change, p_gain = gain_change_test(ctx, w, base, params["side"])
        if math.isfinite(gain_change):
            # Convex (curvature > 0, both families) means more gain above the middle.
            p_gain = _one_sided(p_gain, gain_change * params["curvature"] > 0.0)
        else:
            # Too few measured slips to test: the replay decides alone.
            p_gain = 0.0
        params = {**params, "gain_change": gain_change, "gain_change_p": p_gain}
        supported = p_gain < SIGNATURE_P
    return EffectFit(
        effect="valve_characteristic",
        variant=variant,
        n_params=n_params,
        supported=supported,
        params=params,
        predictions=preds,
        x=(params["curvature"],),
        process=proc,
        pv_floor=None if proc is None or init is not None else process_noise_floor(ue, ctx, proc),
    )


def fit_quantization(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit | None:
    """Historian or instrument resolution (Loop 4 of Section 3, Fig. 6).

    The resolution (step ``q``) of each recorded signal is read from the data
    (:func:`detect_quantization`).  A continuous replay cannot reproduce the rounding:
    the recorded value departs from the true one by a rounding error of variance
    ``q^2/12``, which the augmented replay accounts for as a known measurement error
    (one parameter per quantised signal, the step).  The replay itself is unchanged.
    None when no signal is quantised.
    """
    preds, params, explained = {}, {}, {}
    base_preds = base.predictions()
    for name in ("op", "mv", "pv"):
        x = getattr(ctx.sig, name)
        q = detect_quantization(x)
        if q is None or name not in base_preds:
            continue
        step, offset = q
        preds[name] = base_preds[name]
        explained[name] = step * step / 12.0
        params[f"{name}_step"] = step
        params[f"{name}_offset"] = offset
    if not preds:
        return None
    if "pv_step" in params:
        # A pv rounded by the historian (not by the instrument the controller reads)
        # also throws the controller replay off: it is driven by the rounded pv.
        extra = _rounding_in_op(ctx, w, base, params["pv_step"], params["pv_offset"])
        if extra > 0.0:
            preds["op"] = base_preds["op"]
            explained["op"] = explained.get("op", 0.0) + extra
            params["op_from_pv_rounding"] = extra
    return EffectFit(
        effect="quantization",
        variant="+".join(preds),
        n_params=sum(k.endswith("_step") for k in params),
        params=params,
        predictions=preds,
        explained=explained,
    )


def quantized_signals(ef: EffectFit) -> tuple[str, ...]:
    """The signals whose resolution a quantization fit reads from the data (``op``,
    ``mv``, ``pv``, in that order)."""
    return tuple(name for name in ("op", "mv", "pv") if f"{name}_step" in ef.params)


def restrict_quantization(ef: EffectFit, signals: tuple[str, ...]) -> EffectFit:
    """The quantization fit ``ef`` with the resolution of ``signals`` only.

    Each step is one parameter and acts on its own signal (a historian-rounded pv also
    on the controller replay, ``op_from_pv_rounding``), so a loop whose mv is rounded
    and whose pv is rounded too finely to matter is explained by mv's step alone; the
    gap diagnosis keeps the subset that pays for its parameters
    (:func:`stictiondiag.gap.diagnose.diagnose_gap`).
    """
    params, explained, preds = {}, {}, {}
    for name in ("op", "mv", "pv"):
        if name not in signals or f"{name}_step" not in ef.params:
            continue
        step = float(ef.params[f"{name}_step"])
        params[f"{name}_step"] = step
        params[f"{name}_offset"] = ef.params[f"{name}_offset"]
        explained[name] = step * step / 12.0
        preds[name] = ef.predictions[name]
    extra = ef.params.get("op_from_pv_rounding")
    if "pv_step" in params and extra is not None:
        params["op_from_pv_rounding"] = extra
        explained["op"] = explained.get("op", 0.0) + float(extra)
        preds["op"] = ef.predictions["op"]
    preds = {k: v for k, v in ef.predictions.items() if k in preds}
    return replace(
        ef,
        variant="+".join(preds),
        n_params=sum(k.endswith("_step") for k in params),
        params=params,
        predictions=preds,
        explained=explained,
    )


def _rounding_in_op(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, step: float, offset: float
) -> float:
    """Variance per sample of the controller replay's error that a rounded pv causes
    [(% of span)^2].

    The replayed controller (:func:`fit_controller`) is driven by the recorded pv; if
    the historian rounded pv after the controller read it, the replay answers the
    rounding error ``e`` that the controller never saw, by ``Kc (e_f + (1/Ti) int e_f)``
    (``e_f`` the filtered ``e``).  ``e`` is unobserved; its stand-in is the rounding of
    the continuous process replay (same step and grid), which moves like pv and so has
    the rounding error's own correlation.  The value is capped by the controller
    replay's error on ``w``: when the instrument rounds (the controller reads the
    rounded pv), the replay has no such error and nothing is explained.
    """
    ctrl = base.controller
    kc = float(ctrl.get("gain") or 0.0)
    if kc == 0.0 or step <= 0.0:
        return 0.0
    dt = ctx.sig.dt
    smooth = np.asarray(base.process.pv, dtype=float)
    e = quantize(smooth, step, offset) - smooth
    tf = float(ctrl.get("filter_time_s") or 0.0)
    ef = first_order_lag(e, tf, dt) if tf > 0.0 else e
    ti = ctrl.get("integral_time_s")
    d_op = kc * ef
    if ti:
        d_op = d_op + kc / float(ti) * np.cumsum(ef) * dt
    wsum = max(float(w.sum()), 1.0)
    d_op = d_op - float(np.dot(w, d_op)) / wsum
    predicted = float(np.dot(w, d_op * d_op)) / wsum
    r = base.op - ctx.sig.op
    observed = float(np.dot(w, r * r)) / wsum
    return min(predicted, observed)


def _sinusoids(n: int, omega: float, harmonics: int) -> np.ndarray:
    k = np.arange(n, dtype=float)
    cols = []
    for h in range(1, harmonics + 1):
        cols += [np.cos(h * omega * k), np.sin(h * omega * k)]
    return np.column_stack(cols)


#: Significance of the phase coherence an external oscillation must show (Rayleigh test).
COHERENCE_P = 0.01


def phase_coherence(r: np.ndarray, omega: float, w: np.ndarray) -> tuple[float, float]:
    """Phase coherence of a sinusoid of ``omega`` [rad/sample] in ``r`` along the record.

    An oscillation from outside the loop keeps its own clock: its phase, measured
    in consecutive blocks of one period, stays put.  A loop's own stick-slip cycle
    drifts in phase from cycle to cycle (noise and load change each cycle's
    length), and a sinusoid fitted to broadband residual has random phases.  Returns
    the mean resultant length R of the block phases (1: one phase) and the Rayleigh
    test's p-value ``exp(-B R^2)`` for B blocks.
    """
    n = r.size
    period = 2.0 * math.pi / max(omega, 1e-9)
    L = int(max(period, 16))
    B = n // L
    if B < 3:
        return 0.0, 1.0
    k = np.arange(n)
    z = (r * w) * np.exp(-1j * omega * k)
    ph = []
    for b in range(B):
        c = z[b * L : (b + 1) * L].sum()
        if abs(c) > 0:
            ph.append(c / abs(c))
    if len(ph) < 3:
        return 0.0, 1.0
    R = float(abs(np.mean(ph)))
    return R, float(math.exp(-len(ph) * R * R))


def fit_external_disturbance(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit | None = None
) -> EffectFit:
    """An oscillation entering the loop that the valve did not cause.

    ``pv = G(mv) + A1 sin(w t + p1) [+ A2 sin(2 w t + p2)]``: the frequency starts at
    one of the largest peaks of the spectrum of the process-replay residual, is
    refined by golden-section search, and the process is refitted together with the
    sinusoids (a disturbance biases the process fit, so they are fitted together).
    Periods longer than the slow load's knot spacing belong to the load.
    """
    sig = ctx.sig
    u = _process_input(ctx, base)
    pv, n = sig.pv, sig.n
    var_pv = ctx.norm["pv"]
    model = base.process.model

    def cost(om, harmonics, model=model, retune=False):
        f = fit_process(u, ctx, w, extra=_sinusoids(n, om, harmonics), model=model, retune=retune)
        return float(np.dot(w, (f.pv - pv) ** 2)) / var_pv, f

    if init is not None:
        om = 2.0 * math.pi * sig.dt / init.params["period_s"]
        harmonics = 1 if init.variant == "fundamental" else 2
        c, f = cost(om, harmonics, model=init.process.model if init.process else model)
    else:
        r = (pv - base.process.pv) * w
        nfft = 1 << int(math.ceil(math.log2(4 * n)))
        spec = np.abs(np.fft.rfft(r, nfft)) ** 2
        omega = 2.0 * math.pi * np.arange(spec.size) / nfft  # [rad/sample]
        lo = max(2.0 * math.pi * 2.0 / n, 2.0 * math.pi / ctx.load.spacing)
        ok = (omega >= lo) & (omega <= 2.0 * math.pi / 3.0)
        cand = np.where(ok)[0]
        if cand.size < 3:
            cand = np.arange(1, spec.size)

        def top_peaks(spec_x, k):
            sx = spec_x[cand]
            pk = [
                cand[i] for i in range(1, sx.size - 1) if sx[i] >= sx[i - 1] and sx[i] >= sx[i + 1]
            ]
            return sorted(pk, key=lambda i: -spec_x[i])[:k] or [cand[int(np.argmax(sx))]]

        # Candidate frequencies: the largest peaks of the replay's residual and of pv
        # itself (the load tracking follows part of a slow disturbance, so its peak
        # can be small in the residual while it dominates pv).
        pvc = (pv - np.sum(pv * w) / max(np.sum(w), 1.0)) * w
        spec_pv = np.abs(np.fft.rfft(pvc, nfft)) ** 2
        peaks = list(dict.fromkeys(top_peaks(spec, 3) + top_peaks(spec_pv, 3)))
        best = None
        width = 2.0 * math.pi / nfft * 4.0
        for i in peaks:
            om0 = omega[i]
            om = _golden(lambda o: cost(o, 1)[0], max(om0 - width, 1e-6), om0 + width, n_iter=14)
            for harmonics in (1, 2):
                # Judged with the load tracking retuned: with the oscillation in the
                # model there is less load to follow.
                c, f = cost(om, harmonics, retune=True)
                if best is None or c < best[0]:
                    best = (c, om, harmonics, f)
        c, om, harmonics, f = best
        # The process dynamics refitted with the disturbance in the model, and the
        # load tracking retuned: the disturbance is no longer load to follow.
        c2, f2 = cost(om, harmonics, model=None)
        if c2 < c:
            c, f = c2, f2
        c3, f3 = cost(om, harmonics, model=f.model, retune=True)
        if c3 < c:
            f = f3
    amp = f.coef[-2 * harmonics :]
    amplitudes = [float(math.hypot(amp[2 * h], amp[2 * h + 1])) for h in range(harmonics)]
    coherence, p_value = (
        phase_coherence(pv - base.process.pv, om, ctx.w_eval) if init is None else (None, 0.0)
    )
    return EffectFit(
        effect="external_disturbance",
        variant="fundamental" if harmonics == 1 else "fundamental_and_second_harmonic",
        n_params=1 + 2 * harmonics,
        params={
            "period_s": float(2.0 * math.pi / om * sig.dt),
            "amplitude": amplitudes[0],
            "amplitude_second_harmonic": amplitudes[1] if harmonics > 1 else 0.0,
            "phase_coherence": coherence,
            "phase_coherence_p": p_value,
        },
        predictions={"pv": f.pv},
        supported=p_value < COHERENCE_P,
        x=(float(om),),
        process=f,
        pv_floor=None
        if init is not None
        else process_noise_floor(u, ctx, f, _sinusoids(n, om, harmonics)),
    )


#: The catalogue: effect name -> fitter ``f(context, weights, base, init=None)``
#: returning an :class:`EffectFit` (None when the effect does not apply, e.g. no
#: signal is quantised).  ``init`` is the fit on the whole record, to start from.
EFFECT_MODELS: dict[str, Callable[..., EffectFit | None]] = {
    "actuator_lag": fit_actuator_lag,
    "miscalibration": fit_miscalibration,
    "asymmetry": fit_asymmetry,
    "valve_characteristic": fit_valve_characteristic,
    "quantization": fit_quantization,
    "external_disturbance": fit_external_disturbance,
    "time_varying_stiction": fit_time_varying_stiction,
}


def assessable_effects(has_mv: bool) -> tuple[list[str], list[str]]:
    """Effects that can and cannot be assessed with or without a recorded mv.

    Without mv the valve-side effects (lag, miscalibration, asymmetry, time-varying
    S and J) are confounded with the process dynamics and gain in pv; the
    process-side ones remain.
    """
    names = [e for e in EFFECTS if e != "none"]
    if has_mv:
        return names, []
    return [e for e in names if e not in VALVE_SIDE_EFFECTS], [
        e for e in names if e in VALVE_SIDE_EFFECTS
    ]
