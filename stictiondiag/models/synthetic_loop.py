"""Compiled closed loop of the withheld-effect benchmark (:mod:`stictiondiag.models.synthetic`).

The benchmark's own simulator, kept apart from the diagnosis code so that a
benchmark result cannot come from both sides sharing one mistake: a stick-slip valve
written from the description in Section 5.1 of Choudhury, Thornhill & Shah (2005)
(open and close directions with their own S and J), the Karnopp valve of Section 4.1
(Eqs. 1-2, Table 1) over one sample, the valve characteristic, and the PI loop of
Eq. 3 that drives them.  It imports nothing from the valve, loop or physical-model
modules of :mod:`stictiondiag`.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.jit import inline, jit


@jit
def _sgn(v):
    """Sign of ``v`` as a float (0 at 0): the oracle's own, shared with no valve model."""
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


# Stick-slip state layout (float64 array).
_POS, _XSTICK, _STUCK, _LASTDIR, _PREVX, _PREVSLOPE = range(6)


@jit
def stick_slip_state(position):
    """State of a stick-slip element at rest at ``position`` [% of span]."""
    st = np.zeros(6)
    st[_POS] = position
    st[_XSTICK] = position
    st[_STUCK] = 1.0
    st[_LASTDIR] = 0.0
    st[_PREVX] = position
    st[_PREVSLOPE] = 0.0
    return st


@jit
def stick_slip_step(x, st, S_open, J_open, S_close, J_close):
    """One sample of the two-parameter stick-slip element (Section 5.1, Fig. 2).

    Written from the paper's text: the valve sticks when the slope of its input
    changes sign, or stays zero for two consecutive samples; ``x_ss``, the input
    at which it stuck, "is kept in memory and does not change until the valve gets
    stuck again", so input noise while stuck does not reset it. A stuck valve
    slips once the input has moved from ``x_ss`` by more than ``S`` against its
    last direction of travel (deadband plus stickband) or ``J`` along it
    (stickband); moving, the output is ``x - d (S - J) / 2`` (Eq. 4). S and J may
    differ by direction (``d = +1`` opening, ``-1`` closing).

    Parameters
    ----------
    x : float
        Valve demand [% of span], already in [0, 100].
    st : ndarray
        State from :func:`stick_slip_state`, updated in place.
    S_open, J_open, S_close, J_close : float
        Deadband plus stickband [% of input span] and slip jump [% of output span]
        for opening and closing movements.

    Returns
    -------
    float
        Valve position [% of span].
    """
    slope = _sgn(x - st[_PREVX])
    if st[_STUCK] == 0.0:
        if slope == 0.0 and st[_PREVSLOPE] == 0.0:
            st[_STUCK] = 1.0
            st[_XSTICK] = st[_PREVX]
        elif slope != 0.0 and st[_LASTDIR] != 0.0 and slope != st[_LASTDIR]:
            st[_STUCK] = 1.0
            st[_XSTICK] = st[_PREVX]
        elif slope != 0.0:
            S = S_open if slope > 0.0 else S_close
            J = J_open if slope > 0.0 else J_close
            st[_LASTDIR] = slope
            st[_POS] = x - slope * (S - J) / 2.0
    if st[_STUCK] == 1.0:
        dev = x - st[_XSTICK]
        d = _sgn(dev)
        if d != 0.0:
            S = S_open if d > 0.0 else S_close
            J = J_open if d > 0.0 else J_close
            band = J if d == st[_LASTDIR] else S
            if abs(dev) > band:
                st[_STUCK] = 0.0
                st[_LASTDIR] = d
                st[_POS] = x - d * (S - J) / 2.0
    st[_PREVX] = x
    st[_PREVSLOPE] = slope
    pos = st[_POS]
    if pos < 0.0:
        pos = 0.0
    elif pos > 100.0:
        pos = 100.0
    st[_POS] = pos
    return pos


@jit
def karnopp_interval(
    phys,
    xr0,
    xr1,
    duration,
    mass,
    spring,
    viscous,
    Fs_open,
    Fc_open,
    Fs_close,
    Fc_close,
    h,
    v_eps,
    travel,
):
    """Advance the Karnopp valve over one controller interval (Section 4.1, Eq. 2).

    Newton's law ``M x'' = k (x_r - x) + F_f`` (Eq. 1 with ``F_a = k x_r`` through
    the calibration ``k/A`` and ``F_p = F_i = 0``), integrated with a semi-implicit
    Euler sub-step ``h``. The required stem position ``x_r`` moves linearly from
    ``xr0`` to ``xr1`` over the interval (the current-to-pressure converter and
    actuator volume do not pass a step). While stuck the valve does not move and the
    breakaway instant, where the applied force leaves the static band, is solved
    exactly (the force is linear in time), so stuck intervals cost nothing.

    Parameters
    ----------
    phys : ndarray
        State ``[x [m], v [m/s], stuck (1/0)]``, updated in place.
    xr0, xr1 : float
        Required stem position at the start and end of the interval [m].
    duration : float
        Interval [s].
    mass, spring, viscous : float
        M [kg], k [N/m], Fv [N s/m].
    Fs_open, Fc_open, Fs_close, Fc_close : float
        Static and Coulomb friction [N] for opening (positive) and closing moves.
    h, v_eps : float
        Sub-step [s]; stick velocity window [m/s].
    travel : float
        Full stem travel [m]; the valve rests against its stops at 0 and ``travel``.

    Returns
    -------
    float
        Stem position at the end of the interval [m].
    """
    x = phys[0]
    v = phys[1]
    stuck = phys[2]
    n_sub = int(round(duration / h))
    if n_sub < 1:
        n_sub = 1
    h = duration / n_sub
    rate = (xr1 - xr0) / duration
    i = 0
    while i < n_sub:
        t = i * h
        if stuck == 1.0:
            F0 = spring * (xr0 + rate * t - x)
            F1 = spring * (xr1 - x)
            if -Fs_close <= F0 <= Fs_open and -Fs_close <= F1 <= Fs_open:
                break
            if -Fs_close <= F0 <= Fs_open:
                # Breakaway inside the interval: time at which F leaves the band.
                dF = F1 - F0
                limit = Fs_open if dF > 0.0 else -Fs_close
                t_break = t + (limit - F0) / dF * (duration - t)
                i = int(math.ceil(t_break / h))
                if i >= n_sub:
                    break
                t = i * h
            stuck = 0.0
            v = 0.0
        F = spring * (xr0 + rate * t - x)
        if v == 0.0:
            # Eq. 2, third line: at the breakaway instant friction is -Fs sgn(F).
            if F > 0.0:
                friction = -Fs_open
            else:
                friction = Fs_close
            if abs(F) <= (Fs_open if F > 0.0 else Fs_close):
                stuck = 1.0
                i += 1
                continue
        else:
            Fc = Fc_open if v > 0.0 else Fc_close
            friction = -Fc * _sgn(v) - viscous * v
        v_new = v + h * (F + friction) / mass
        x = x + h * v_new
        if x <= 0.0 or x >= travel:
            x = min(max(x, 0.0), travel)
            v_new = 0.0
            stuck = 1.0
        elif v_new * v < 0.0 or (v != 0.0 and abs(v_new) < v_eps):
            F_next = spring * (xr0 + rate * (t + h) - x)
            if -Fs_close <= F_next <= Fs_open:
                stuck = 1.0
            v_new = 0.0
        v = v_new
        i += 1
    phys[0] = x
    phys[1] = v
    phys[2] = stuck
    return x


@jit
def flow_characteristic(position, kind, rangeability, authority):
    """Installed flow [fraction of max] at ``position`` [% of travel].

    Inherent characteristic ``f``: equal percentage ``R^(p - 1)`` (``kind`` 1,
    rangeability ``R``) or quick opening ``1 - (1 - p)^m`` (``kind`` 2, exponent
    ``m`` passed as ``rangeability``); installed with valve authority ``a`` as
    ``f / sqrt(a + (1 - a) f^2)`` (Section 5.1 names the look-up; the installed
    form is the usual one for a valve in series with line resistance).
    """
    p = min(max(position / 100.0, 0.0), 1.0)
    if kind == 1:
        f = rangeability ** (p - 1.0)
    elif kind == 2:
        f = 1.0 - (1.0 - p) ** rangeability
    else:
        return p
    # Installed characteristic with valve authority a (share of the system
    # pressure drop taken by the fully open valve).
    return f / math.sqrt(authority + (1.0 - authority) * f * f)


@inline
def _pi_step(meas, sp, pvf, integral, filter_weight, ts, Kc, Ti, op_bias):
    """One sample of the PI controller ``Kc (1 + 1/(Ti s))`` (Eq. 3) on the first-order
    filtered measurement, with conditional integration against windup: the integral
    [pv units * s] is kept only while the output stays inside the span.

    Returns the controller output [% of span, within 0-100], the filtered
    measurement [pv units] and the integral.
    """
    pvf = pvf + filter_weight * (meas - pvf)
    e = sp - pvf
    trial = integral + e * ts
    u_pi = op_bias + Kc * (e + trial / Ti)
    if 0.0 <= u_pi <= 100.0:
        integral = trial
    else:
        u_pi = op_bias + Kc * (e + integral / Ti)
    return min(max(u_pi, 0.0), 100.0), pvf, integral


@inline
def _karnopp_sample(
    phys,
    prev_demand,
    demand,
    S_open,
    J_open,
    S_close,
    J_close,
    ts,
    mass,
    spring,
    viscous,
    stem_m_per_pct,
    h,
    v_eps,
):
    """Valve position [% of span] after one sample of the Karnopp valve
    (:func:`karnopp_interval`) driven from ``prev_demand`` to ``demand`` [% of span].

    This sample's S and J [% of span] per direction become the forces of Eq. 1 through
    the spring: ``Fs = k (S + J) / 2``, ``Fc = k (S - J) / 2`` (Section 4.1).
    """
    Fs_o = spring * stem_m_per_pct * (S_open + J_open) / 2.0
    Fc_o = spring * stem_m_per_pct * (S_open - J_open) / 2.0
    Fs_c = spring * stem_m_per_pct * (S_close + J_close) / 2.0
    Fc_c = spring * stem_m_per_pct * (S_close - J_close) / 2.0
    xm = karnopp_interval(
        phys,
        prev_demand * stem_m_per_pct,
        demand * stem_m_per_pct,
        ts,
        mass,
        spring,
        viscous,
        Fs_o,
        Fc_o,
        Fs_c,
        Fc_c,
        h,
        v_eps,
        100.0 * stem_m_per_pct,
    )
    return xm / stem_m_per_pct


@jit
def closed_loop(
    ts,
    integrating,
    gain,
    time_constant,
    delay,
    Kc,
    Ti,
    filter_weight,
    op_bias,
    pv0,
    pv_quantum,
    sp,
    load_in,
    load_out,
    noise,
    physical,
    S_open,
    J_open,
    S_close,
    J_close,
    cal_gain,
    cal_pivot,
    lag_weight,
    char_kind,
    rangeability,
    authority,
    flow0,
    dflow0,
    mass,
    spring,
    viscous,
    stem_m_per_pct,
    h,
    v_eps,
):
    """Sampled closed loop: PI -> calibration -> friction -> lag -> characteristic -> process.

    All signals one value per sample ``ts`` [s]. The process is discretised
    exactly for a zero-order-hold input (FOPTD ``K e^{-theta s}/(tau s + 1)`` or
    integrating ``K e^{-theta s}/s``), dead time ``delay`` whole samples. The PI
    controller is the paper's ``Kc (1 + 1/(Ti s))`` on a first-order filtered
    measurement, with conditional integration against windup.
    """
    n = sp.shape[0]
    pv = np.empty(n)
    op = np.empty(n)
    valve_out = np.empty(n)
    position = np.empty(n)
    flow = np.empty(n)
    pv_clean = np.empty(n)
    a = math.exp(-ts / time_constant) if not integrating else 1.0
    b = gain * (1.0 - a) if not integrating else gain * ts
    ubuf = np.zeros(delay + 1)
    y = 0.0
    pvf = sp[0]
    integral = 0.0
    demand0 = cal_pivot + cal_gain * (op_bias - cal_pivot)
    st = stick_slip_state(demand0)
    phys = np.zeros(3)
    phys[0] = demand0 * stem_m_per_pct
    phys[2] = 1.0
    lagged = demand0
    prev_demand = demand0
    for k in range(n):
        clean = pv0 + y + load_out[k]
        pv_clean[k] = clean
        meas = clean + noise[k]
        if pv_quantum > 0.0:
            meas = pv_quantum * math.floor(meas / pv_quantum + 0.5)
        pv[k] = meas
        u_pi, pvf, integral = _pi_step(
            meas, sp[k], pvf, integral, filter_weight, ts, Kc, Ti, op_bias
        )
        op[k] = u_pi
        demand = min(max(cal_pivot + cal_gain * (u_pi - cal_pivot), 0.0), 100.0)
        if physical:
            vo = _karnopp_sample(
                phys,
                prev_demand,
                demand,
                S_open[k],
                J_open[k],
                S_close[k],
                J_close[k],
                ts,
                mass,
                spring,
                viscous,
                stem_m_per_pct,
                h,
                v_eps,
            )
        else:
            vo = stick_slip_step(demand, st, S_open[k], J_open[k], S_close[k], J_close[k])
        prev_demand = demand
        valve_out[k] = vo
        lagged = lagged + lag_weight * (vo - lagged)
        position[k] = lagged
        # Deviation from the valve position at the operating point, where the
        # process is at pv0 (a miscalibrated valve sits elsewhere for op_bias).
        if char_kind == 0:
            u = lagged - demand0
        else:
            u = (flow_characteristic(lagged, char_kind, rangeability, authority) - flow0) / dflow0
        flow[k] = u + op_bias
        u += load_in[k]
        # Dead-time buffer: ubuf[0] is the input applied now, delayed by `delay`.
        for j in range(delay):
            ubuf[j] = ubuf[j + 1]
        ubuf[delay] = u
        y = a * y + b * ubuf[0]
    return pv, op, valve_out, position, flow, pv_clean
