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

The per-sample state machine is a compiled function (:func:`choudhury_step`,
:func:`kano_step`) so the closed-loop simulators in :mod:`stictiondiag.models.loops` call
exactly the same code as the open-loop models here.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import jit

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


@jit
def _sign(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@jit
def _breakaway(x, S, J, y, xss, dirn):
    """A stuck valve at input ``x``, stuck since input ``xss``: ``(y, dirn, stuck)``.

    Shared by both data-driven models.  A reversal against the last movement must
    overcome deadband + stickband (S); the same direction after a stop, the
    stickband only (J); before the first movement the valve is treated as
    reversing (S).  On breakaway the output jumps to ``x - d (S - J)/2`` (Eq. 4).
    """
    dx = x - xss
    d = _sign(dx)
    if d != 0.0:
        thr = S if (dirn == 0.0 or d != dirn) else J
        if abs(dx) > thr:
            return x - d * (S - J) / 2.0, d, False
    return y, dirn, True


@jit
def _choudhury_next(x, S, J, y, xss, dirn, v_old, stuck, x_prev):
    """One sample of the Fig. 10 flowchart on scalar state (Section 5.1).

    Returns ``(y, xss, dirn, v_new, stuck)``: output, stuck input, direction of the
    last movement, input slope sign, stuck flag.  Shared by :func:`choudhury_step`
    and the open-loop kernel, where the state lives in local variables.
    """
    v_new = _sign(x - x_prev)
    # Fig. 10: the valve sticks when the slope changes sign or stays zero for two
    # consecutive samples.  x_ss is the input one sample before the change.
    if (v_new != v_old and v_new != 0.0 and v_old != 0.0) or (
        v_new == 0.0 and v_old == 0.0 and not stuck
    ):
        stuck = True
        xss = x_prev
    if stuck:
        y, dirn, stuck = _breakaway(x, S, J, y, xss, dirn)
    elif v_new != 0.0:
        dirn = v_new
        y = x - v_new * (S - J) / 2.0  # Eq. 4
    return y, xss, dirn, v_new, stuck


@jit
def _kano_next(x, S, J, y, xss, dirn, stuck, x_prev):
    """One sample of Kano et al. (2004) on scalar state; see :func:`kano_step`.

    Returns ``(y, xss, dirn, v_new, stuck)`` as :func:`_choudhury_next`.
    """
    v_new = _sign(x - x_prev)
    if not stuck:
        # Moving: the valve stops when the input reverses or stops changing.
        if v_new == 0.0 or (dirn != 0.0 and v_new != dirn):
            stuck = True
            xss = x_prev
        else:
            dirn = v_new
            y = x - v_new * (S - J) / 2.0
    if stuck:
        y, dirn, stuck = _breakaway(x, S, J, y, xss, dirn)
    return y, xss, dirn, v_new, stuck


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
