"""Compiled valve kernels of the effect catalogue.

The data-driven valve of Choudhury, Thornhill & Shah (2005) (Section 5.1, Fig. 10,
Eq. 4), the family's one state machine :func:`stictiondiag.models.valve.valve_step`,
run for the effects: S and J per direction of travel and per sample,
an actuator lag after the friction element, an installed characteristic, and the
batch evaluation of many parameter sets per compiled call (:func:`valve_sse_batch`).
A parameter row holds, in this order: S opening at the start and end of the time
profile, S closing at start and end, J opening at start and end, J closing at start
and end, and the weight of the lag.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import inline, jit
from stictiondiag.models.valve import PHASE_STUCK
from stictiondiag.models.valve import _sign as _sgn
from stictiondiag.models.valve import rest_state as _valve_init
from stictiondiag.models.valve import valve_step as _valve_step

FAMILY_CODES = {"linear": 0, "exponential": 1, "power": 2}


def valve_rows(
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
    """Parameter rows of :func:`valve_sse_batch` (the column order of the module
    docstring) from columns; missing ones default to symmetric, constant in time and
    without lag."""
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


def _rows_order(m: int, order=None) -> np.ndarray:
    """Evaluation order of ``m`` rows for :func:`valve_sse_batch` (default: as given)."""
    if order is None:
        return np.arange(m, dtype=np.int64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    if order.shape != (m,):
        raise ValueError(f"order must be a permutation of the {m} rows")
    return order


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


@inline
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
def valve_series(op, s_up, s_dn, j_up, j_dn, kano, y0, d0, lag):  # pragma: no cover - compiled
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


@inline
def _valve_sse_row(
    xs, vs, mv, w, P, r, h, kano, y0, d0, affine, curvature, family, limit, tv, pre, check
):  # pragma: no cover - compiled
    """Error of row ``r`` of :func:`valve_sse_batch` (``xs``, ``vs``: :func:`_clipped_moves`).

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


@inline
def _affine_row(
    xs, vs, mv, w, P, r, h, kano, y0, d0, curvature, family, limit, tv, pre, check
):  # pragma: no cover - compiled
    """Row ``r``'s error minimised over the map ``mv = b + k z`` (:func:`valve_sse_batch`
    with ``affine``): one copy of the row loop per valve, Kano's or Choudhury's."""
    if kano:
        return _valve_sse_row(
            xs, vs, mv, w, P, r, h, True, y0, d0, True, curvature, family, limit, tv, pre, check
        )
    return _valve_sse_row(
        xs, vs, mv, w, P, r, h, False, y0, d0, True, curvature, family, limit, tv, pre, check
    )


@inline
def _plain_row(
    xs, vs, mv, w, P, r, h, kano, y0, d0, curvature, family, limit, tv, pre
):  # pragma: no cover - compiled
    """Row ``r``'s error of ``mv = z`` (:func:`valve_sse_batch` without ``affine``): one
    copy of the row loop per valve and per profile, constant or time-varying."""
    if kano:
        if tv:
            return _valve_sse_row(
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
        return _valve_sse_row(
            xs, vs, mv, w, P, r, h, True, y0, d0, False, curvature, family, limit, False, pre, False
        )
    if tv:
        return _valve_sse_row(
            xs, vs, mv, w, P, r, h, False, y0, d0, False, curvature, family, limit, True, pre, False
        )
    return _valve_sse_row(
        xs, vs, mv, w, P, r, h, False, y0, d0, False, curvature, family, limit, False, pre, False
    )


@inline
def _keep_lowest(kept, c):  # pragma: no cover - compiled
    """Insert the error ``c`` among the lowest errors ``kept`` (sorted, rising) if it is
    below the highest of them (an abandoned row's partial error lies above them all)."""
    kk = kept.shape[0]
    if c < kept[kk - 1]:
        i = kk - 1
        while i > 0 and kept[i - 1] > c:
            kept[i] = kept[i - 1]
            i -= 1
        kept[i] = c


@jit
def valve_sse_batch(
    op, mv, w, P, h, kano, y0, d0, affine, curvature, family, bound, keep, order
):  # pragma: no cover
    """Weighted sum of squared mv errors for many parameter rows at once.

    Each row of ``P`` holds S and J opening and closing at the start and end of the
    profile ``h`` (length 1: constant) and the lag weight (columns as
    :func:`valve_rows` builds them).  The valve output goes through the lag and the characteristic
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
    # constants at separate call sites (_affine_row, _plain_row), so that each inlined
    # copy of the row loop is compiled without their tests per sample (20 % faster).
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
            c = _affine_row(
                xs, vs, mv, w, P, r, h, kano, y0, d0, curvature, family, lim, tv, pre, check
            )
            costs[r] = c
            _keep_lowest(kept, c)
        else:
            c = _plain_row(xs, vs, mv, w, P, r, h, kano, y0, d0, curvature, family, limit, tv, pre)
            costs[r] = c
            if c < limit:
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
    return valve_series(
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
