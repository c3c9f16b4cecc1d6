"""Data-driven valve stiction models: Choudhury et al. (2005) and Kano et al. (2004).

Both models map the controller output ``op`` (valve demand) to the valve position
``mv`` with two parameters, in % of span:

* ``S``: deadband plus stickband, measured on the *input* axis;
* ``J``: slip jump, measured on the *output* axis.

Section 5.1 of Choudhury, Thornhill & Shah (2005), "Modelling valve stiction",
Control Engineering Practice 13, 641-658, and its Fig. 10 flowchart define the
algorithm implemented by :func:`choudhury_model`. In the moving phase the output is
Eq. 4, ``mv = op - sign(slope) (S - J) / 2``, which yields the four cases of
Section 5.1 and Fig. 11: deadband (``J = 0``), undershoot (``J < S``), no offset
(``J = S``) and overshoot (``J > S``).

The package has one data-driven valve: the per-sample state machine
:func:`valve_step` (Choudhury's flowchart or Kano's variant, S and J per direction of
travel).  The open-loop models here, the closed-loop simulators of
:mod:`stictiondiag.models.loops` (through :func:`choudhury_step`, :func:`kano_step`),
the stiction fit (:mod:`stictiondiag.stiction.valvefit`) and the gap's effect
catalogue (:mod:`stictiondiag.gap.effects.kernels`) all run it.  The withheld-effect
benchmark's oracle (:mod:`stictiondiag.models.synthetic_loop`) is written apart on
purpose and imports nothing from here.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import inline, jit

Characteristic = Literal["linear", "equal_percentage", "quick_opening"]
OpUnits = Literal["percent", "mA"]

#: Rangeability of the equal-percentage characteristic (typical globe valve, 50:1).
EQUAL_PERCENTAGE_RANGEABILITY = 50.0

#: Example (S, J) sets in % of span: the cases of Fig. 11 (Section 5.2) and Table 3.
STICTION_MODEL_PARAMETERS: dict[str, dict[str, float]] = {
    "linear": {"S": 0.0, "J": 0.0},
    "deadband": {"S": 5.0, "J": 0.0},
    "undershoot": {"S": 5.0, "J": 2.0},
    "no_offset": {"S": 5.0, "J": 5.0},
    "overshoot": {"S": 5.0, "J": 7.0},
}

# State vector layout shared by the step functions (float64 array of length 6).
_Y = 0  # last output [% of span]
_XSS = 1  # input at which the valve stuck [% of span]
_DIR = 2  # direction of the last movement (+1, -1, or 0 before any movement)
_VOLD = 3  # sign of the previous input slope
_STUCK = 4  # 1.0 while stuck, 0.0 while moving
_XPREV = 5  # previous input sample [% of span]
STATE_SIZE = 6


@jit
def valve_state(x0, stuck):
    """Initial state: valve at rest at ``x0`` (stuck or free). Compiled helper."""
    st = np.zeros(6)
    st[0] = x0
    st[1] = x0
    st[2] = 0.0
    st[3] = 0.0
    st[4] = 1.0 if stuck else 0.0
    st[5] = x0
    return st


@inline
def _sign(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


# Phase of a valve step (the gap diagnosis breaks its error down by phase).
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


@inline
def rest_state(x0, y0, d0, s_up, s_down, j_up, j_down):  # pragma: no cover - compiled
    """State ``(y, xss, dirn, v_old, stuck)`` of a valve at rest at ``y0`` after moving
    in direction ``d0``.

    By Eq. 4 the demand was ``y0 + d0 (S - J)/2`` when the valve stopped; with
    ``d0 = 0`` (unknown) the stop point is the first demand ``x0`` and the first
    breakaway needs S.
    """
    if d0 > 0.0:
        xss = y0 + (s_up - j_up) / 2.0
    elif d0 < 0.0:
        xss = y0 - (s_down - j_down) / 2.0
    else:
        xss = x0
    return y0, xss, d0, 0.0, 1.0


@inline
def valve_step(
    x, v_new, x_prev, y, xss, dirn, v_old, stuck, s_up, s_down, j_up, j_down, kano
):  # pragma: no cover - compiled
    """One sample of the data-driven valve family: the one state machine of this
    package (Section 5.1, Fig. 10, Eq. 4; Kano et al. 2004 with ``kano``).

    Choudhury's flowchart: the valve sticks when the input's slope changes sign or
    stays zero for two samples, ``xss`` being the input one sample before.  Kano's:
    a moving valve sticks when its input stops or reverses, and a stuck one keeps
    ``xss`` whatever the input does.  A stuck valve breaks away once the input is
    more than S from ``xss`` against its last movement (deadband plus stickband),
    or J along it (stickband; before any movement it counts as reversing), and
    jumps to ``x - d (S - J)/2``; moving, the output is Eq. 4.  S and J may differ
    by direction of travel (``s_up``, ``j_up`` opening; ``s_down``, ``j_down``
    closing): the gap's asymmetric valve; the paper's valve has them equal.

    Parameters are scalars: ``v_new`` the sign of ``x - x_prev``, ``v_old`` that of
    the previous step, ``stuck`` 1.0 or 0.0 (kept in registers by the compiler: an
    array state costs a memory round trip per field and sample).

    Returns
    -------
    (y, xss, dirn, stuck, phase)
        The new state, ``y`` unclipped, and the phase code (``PHASE_*``); the next
        sample's ``v_old`` is this ``v_new``.
    """
    if kano:
        if stuck == 0.0:
            if v_new == 0.0 or (dirn != 0.0 and v_new != dirn):
                stuck = 1.0
                xss = x_prev
            else:
                dirn = v_new
                if v_new > 0.0:
                    y = x - (s_up - j_up) / 2.0
                else:
                    y = x + (s_down - j_down) / 2.0
    else:
        if v_new != v_old and v_new != 0.0 and v_old != 0.0:
            stuck = 1.0
            xss = x_prev
        elif v_new == 0.0 and v_old == 0.0:
            if stuck == 0.0:
                stuck = 1.0
                xss = x_prev
    phase = PHASE_MOVING
    if stuck == 1.0:
        dx = x - xss
        d = _sign(dx)
        # Selections, not branches: while stuck the input wanders about x_ss with
        # the noise, and a branch on its side would be mispredicted half the time.
        s_d = s_up if d > 0.0 else s_down
        j_d = j_up if d > 0.0 else j_down
        reversal = (dirn == 0.0) | (d != dirn) | (d == 0.0)
        thr = s_d if reversal else j_d
        if d != 0.0 and abs(dx) > thr:
            stuck = 0.0
            dirn = d
            y = x - d * (s_d - j_d) / 2.0
            phase = PHASE_SLIP
        elif reversal and abs(dx) <= 0.5 * max(s_up, s_down):
            phase = PHASE_REVERSAL
        else:
            phase = PHASE_STUCK
    elif not kano and v_new != 0.0:
        dirn = v_new
        if v_new > 0.0:
            y = x - (s_up - j_up) / 2.0
        else:
            y = x + (s_down - j_down) / 2.0
    return y, xss, dirn, stuck, phase


@inline
def _choudhury_next(x, S, J, y, xss, dirn, v_old, stuck, x_prev):
    """One sample of the Fig. 10 flowchart on scalar state (Section 5.1):
    :func:`valve_step` with one S and J for both directions.

    Returns ``(y, xss, dirn, v_new, stuck)``: output, stuck input, direction of the
    last movement, input slope sign, stuck flag.  Shared by :func:`choudhury_step`
    and the open-loop kernels, where the state lives in local variables.
    """
    v_new = _sign(x - x_prev)
    y, xss, dirn, st, _ = valve_step(
        x, v_new, x_prev, y, xss, dirn, v_old, 1.0 if stuck else 0.0, S, S, J, J, False
    )
    return y, xss, dirn, v_new, st == 1.0


@inline
def _kano_next(x, S, J, y, xss, dirn, stuck, x_prev):
    """One sample of Kano et al. (2004) on scalar state; see :func:`kano_step`.

    Returns ``(y, xss, dirn, v_new, stuck)`` as :func:`_choudhury_next`.
    """
    v_new = _sign(x - x_prev)
    y, xss, dirn, st, _ = valve_step(
        x, v_new, x_prev, y, xss, dirn, 0.0, 1.0 if stuck else 0.0, S, S, J, J, True
    )
    return y, xss, dirn, v_new, st == 1.0


@jit
def choudhury_step(x, st, S, J):
    """Advance the Choudhury model by one sample (Fig. 10, Section 5.1).

    Parameters
    ----------
    x : float
        Valve demand at this sample, already in % of span and saturated to [0, 100].
    st : ndarray
        State vector from :func:`valve_state`, updated in place.
    S, J : float
        Deadband plus stickband [% of input span], slip jump [% of output span].

    Returns
    -------
    float
        Valve position [% of span].
    """
    y, xss, dirn, v_new, stuck = _choudhury_next(
        x, S, J, st[0], st[1], st[2], st[3], st[4] == 1.0, st[5]
    )
    st[0] = y
    st[1] = xss
    st[2] = dirn
    st[3] = v_new
    st[4] = 1.0 if stuck else 0.0
    st[5] = x
    return y


@jit
def kano_step(x, st, S, J):
    """Advance Kano et al. (2004) model by one sample.

    Kano's model keeps the input at which the valve stopped (``x_ss``) while stuck,
    whatever the input does, and only a movement of the input itself (not a reversal
    of its slope inside the stuck band) decides the breakaway: beyond ``S`` against
    the last direction of travel, beyond ``J`` in the same direction.  Noise
    reversals while stuck therefore do not reset the stuck band, unlike
    :func:`choudhury_step`, where every change of slope sign re-arms ``x_ss``.
    """
    y, xss, dirn, v_new, stuck = _kano_next(x, S, J, st[0], st[1], st[2], st[4] == 1.0, st[5])
    st[0] = y
    st[1] = xss
    st[2] = dirn
    st[3] = v_new
    st[4] = 1.0 if stuck else 0.0
    st[5] = x
    return y


@jit
def _saturate(v):
    """``v`` limited to [0, 100] % of span (NaN stays NaN, as with ``np.clip``)."""
    if v < 0.0:
        return 0.0
    if v > 100.0:
        return 100.0
    return v


@jit
def _choudhury_run(x, S, J, stuck0, y0):
    """Open-loop Choudhury model over ``x`` [% of span], input and output saturated.

    One pass, O(n) time, no temporary arrays: the state is in local variables and
    the saturation of the input (fully closed / fully open) and of the output is
    done per sample.  ``y0`` NaN: the valve starts at ``x[0]``.
    """
    n = x.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    x_prev = _saturate(x[0])
    y = x_prev if math.isnan(y0) else y0
    xss, dirn, v_old, stuck = x_prev, 0.0, 0.0, stuck0
    out[0] = _saturate(y)
    for k in range(1, n):
        xk = _saturate(x[k])
        y, xss, dirn, v_old, stuck = _choudhury_next(xk, S, J, y, xss, dirn, v_old, stuck, x_prev)
        x_prev = xk
        out[k] = _saturate(y)
    return out


@jit
def _kano_run(x, S, J, stuck0, y0):
    """Open-loop Kano model over ``x``; conventions of :func:`_choudhury_run`."""
    n = x.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    x_prev = _saturate(x[0])
    y = x_prev if math.isnan(y0) else y0
    xss, dirn, stuck = x_prev, 0.0, stuck0
    out[0] = _saturate(y)
    for k in range(1, n):
        xk = _saturate(x[k])
        y, xss, dirn, _, stuck = _kano_next(xk, S, J, y, xss, dirn, stuck, x_prev)
        x_prev = xk
        out[k] = _saturate(y)
    return out


@jit
def ewma(x, lam):
    """Exponentially weighted moving average, ``f[k] = lam x[k] + (1 - lam) f[k-1]``.

    Section 5.1 recommends such a filter in front of the stiction model for noisy
    inputs.  ``lam`` in (0, 1]; 1 means no filtering.
    """
    n = x.shape[0]
    f = np.empty(n)
    if n == 0:
        return f
    f[0] = x[0]
    for k in range(1, n):
        f[k] = lam * x[k] + (1.0 - lam) * f[k - 1]
    return f


def ma_to_percent(signal_mA: np.ndarray) -> np.ndarray:
    """Convert a 4-20 mA signal to % of span (Section 5.1 look-up table)."""
    return (np.asarray(signal_mA, dtype=float) - 4.0) / 16.0 * 100.0


def percent_to_ma(signal_pct: np.ndarray) -> np.ndarray:
    """Convert % of span to a 4-20 mA signal (inverse of :func:`ma_to_percent`)."""
    return np.asarray(signal_pct, dtype=float) / 100.0 * 16.0 + 4.0


def valve_characteristic(
    position: np.ndarray,
    kind: Characteristic = "linear",
    rangeability: float = EQUAL_PERCENTAGE_RANGEABILITY,
) -> np.ndarray:
    """Flow [% of max] through a valve at ``position`` [% of travel] (Section 5.1).

    ``linear``: flow = position; ``equal_percentage``: flow = 100 R^(x/100 - 1);
    ``quick_opening``: square-root characteristic, flow = 100 sqrt(x/100).
    """
    x = np.clip(np.asarray(position, dtype=float), 0.0, 100.0)
    if kind == "linear":
        return x
    if kind == "equal_percentage":
        return 100.0 * rangeability ** (x / 100.0 - 1.0)
    if kind == "quick_opening":
        return 100.0 * np.sqrt(x / 100.0)
    raise UsageError(
        f"unknown valve characteristic {kind!r}: use linear, equal_percentage or quick_opening"
    )


def _check_sj(S: float, J: float) -> tuple[float, float]:
    try:
        S_, J_ = float(S), float(J)
    except (TypeError, ValueError):
        raise UsageError(f"S and J must be numbers, got S={S!r}, J={J!r}") from None
    if not (math.isfinite(S_) and math.isfinite(J_)):
        raise UsageError(f"S and J must be finite, got S={S_}, J={J_}")
    if S_ < 0 or J_ < 0:
        raise UsageError(f"S and J must be >= 0 (% of span), got S={S_}, J={J_}")
    return S_, J_


def _model(op, S, J, *, kano, op_units, characteristic, ewma_lambda, start_stuck, initial_position):
    S, J = _check_sj(S, J)
    x = np.ascontiguousarray(op, dtype=float)
    if x.ndim != 1:
        raise UsageError("op must be a one-dimensional signal")
    if op_units == "mA":
        x = ma_to_percent(x)
    elif op_units != "percent":
        raise UsageError(f"unknown op units {op_units!r}: use percent or mA")
    if ewma_lambda is not None:
        if not 0.0 < ewma_lambda <= 1.0:
            raise UsageError(f"ewma_lambda must be in (0, 1], got {ewma_lambda}")
        x = ewma(x, float(ewma_lambda))
    y0 = math.nan if initial_position is None else float(initial_position)
    # Input and output saturated inside the kernel: fully closed / fully open.
    run = _kano_run if kano else _choudhury_run
    y = run(x, S, J, bool(start_stuck), y0)
    if characteristic != "linear":
        y = valve_characteristic(y, characteristic)
    if op_units == "mA":
        y = percent_to_ma(y)
    return y


def choudhury_model(
    op: np.ndarray,
    S: float,
    J: float,
    *,
    op_units: OpUnits = "percent",
    characteristic: Characteristic = "linear",
    ewma_lambda: float | None = None,
    start_stuck: bool = True,
    initial_position: float | None = None,
) -> np.ndarray:
    """Valve position from valve demand with the data-driven stiction model.

    Choudhury, Thornhill & Shah (2005), Section 5.1, Fig. 10 and Eq. 4.

    Parameters
    ----------
    op : ndarray
        Controller output / valve demand [% of span, or mA with ``op_units="mA"``].
    S : float
        Deadband plus stickband [% of input span], >= 0.
    J : float
        Slip jump [% of output span], >= 0.
    op_units : {"percent", "mA"}
        Units of ``op``; a 4-20 mA signal is converted to % and the output back to mA.
    characteristic : {"linear", "equal_percentage", "quick_opening"}
        Output look-up from valve position to flow (Section 5.1, last step of Fig. 10).
    ewma_lambda : float, optional
        Weight of an EWMA pre-filter on ``op`` for noisy inputs (Section 5.1).
    start_stuck : bool
        Start at rest and stuck at ``op[0]`` (as in Fig. 11).
    initial_position : float, optional
        Initial valve position [% of span]; default ``op[0]``.

    Returns
    -------
    ndarray
        Valve position ``mv`` (or flow, with a non-linear characteristic) in the units
        of ``op``.  Saturated to [0, 100] % of span.
    """
    return _model(
        op,
        S,
        J,
        kano=False,
        op_units=op_units,
        characteristic=characteristic,
        ewma_lambda=ewma_lambda,
        start_stuck=start_stuck,
        initial_position=initial_position,
    )


def kano_model(
    op: np.ndarray,
    S: float,
    J: float,
    *,
    op_units: OpUnits = "percent",
    characteristic: Characteristic = "linear",
    ewma_lambda: float | None = None,
    start_stuck: bool = True,
    initial_position: float | None = None,
) -> np.ndarray:
    """Valve position from valve demand with Kano et al. (2004)'s stiction model.

    Same parameters and units as :func:`choudhury_model`.  The difference is the
    stuck phase: Kano's model keeps the stuck position while the input wanders
    inside the band (noise reversals do not re-arm it), so a noisy input can break
    the valve away without the EWMA pre-filter Section 5.1 asks for.
    """
    return _model(
        op,
        S,
        J,
        kano=True,
        op_units=op_units,
        characteristic=characteristic,
        ewma_lambda=ewma_lambda,
        start_stuck=start_stuck,
        initial_position=initial_position,
    )
