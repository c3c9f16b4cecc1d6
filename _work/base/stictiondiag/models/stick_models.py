"""Two more stick models for simulated loops: He et al.'s and a band-hold valve.

The stiction family randomises the stick model itself, not only its parameters, so
that what the cause model learns is not one flowchart's signature (issue 26).
Besides Choudhury's and Kano's data-driven models (:mod:`stictiondiag.models.valve`)
and Karnopp's physical valve (:mod:`stictiondiag.models.physical`):

He, Wang, Pottmann & Qin (2007), two-parameter model
    A residual force ``u_r`` carries the demand the valve has not followed.  With
    ``temp = u[k] - u[k-1] + u_r``: when ``|temp| > f_s`` the valve moves,
    ``x[k] = u[k] - sign(temp) f_d`` and ``u_r = sign(temp) f_d``; otherwise it holds,
    ``x[k] = x[k-1]`` and ``u_r = temp``.  With ``f_s = (S + J)/2`` and
    ``f_d = (S - J)/2`` a reversal must travel ``f_s + f_d = S`` before the valve
    slips, the slip is ``f_s - f_d = J`` and the moving valve lags its demand by
    ``(S - J)/2``, as in Choudhury's Eq. 4; unlike Choudhury's flowchart, small
    reversals of the demand while stuck add up instead of re-arming the band.
Band-hold valve (the one-parameter model of Stenman, Gustafsson & Forsman 2003)
    The valve holds its position until the demand moves more than ``S`` away from it,
    then jumps to the demand: ``x[k] = x[k-1]`` if ``|u[k] - x[k-1]| <= S``, else
    ``u[k]``.  Stick band and slip are both ``S`` (``J`` plays no part).

Both are per-sample state machines on the state vector of
:func:`stictiondiag.models.valve.valve_state` (slot 0 the position, slot 1 He's
residual force, slot 5 the previous demand), called by the closed-loop kernel of
:mod:`stictiondiag.models.loops`; the open-loop runs here use the same steps.
"""

from __future__ import annotations

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import jit
from stictiondiag.models.valve import valve_state


@jit
def he_step(x, st, S, J):
    """Advance He et al.'s model by one sample (module doc); ``st`` updated in place,
    the position [% of span] returned."""
    fs = 0.5 * (S + J)
    fd = 0.5 * (S - J)
    temp = x - st[5] + st[1]
    if abs(temp) > fs:
        sgn = 1.0 if temp > 0.0 else -1.0
        st[0] = x - sgn * fd
        st[1] = sgn * fd
    else:
        st[1] = temp
    st[5] = x
    return st[0]


@jit
def band_step(x, st, S):
    """Advance the band-hold valve by one sample (module doc)."""
    if abs(x - st[0]) > S:
        st[0] = x
    st[5] = x
    return st[0]


@jit
def _run(x, S, J, kind, y0):
    n = x.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    st = valve_state(x[0], True)
    st[0] = y0
    st[1] = 0.0  # no residual force at rest
    out[0] = y0
    for k in range(1, n):
        out[k] = he_step(x[k], st, S, J) if kind == 0 else band_step(x[k], st, S)
    return out


def stick_model(
    op: np.ndarray, S: float, J: float, *, model: str, initial_position: float | None = None
) -> np.ndarray:
    """Valve position [% of span] from valve demand ``op`` [% of span] with He et
    al.'s model (``model="he"``) or the band-hold valve (``"band"``), started at rest
    at ``initial_position`` (default ``op[0]``) with no residual force.  ``S``, ``J``
    >= 0 [% of span], ``J <= S`` for He's model."""
    kinds = {"he": 0, "band": 1}
    if model not in kinds:
        raise UsageError(f"unknown stick model {model!r}: use he or band")
    S, J = float(S), float(J)
    if not (S >= 0 and J >= 0) or (model == "he" and J > S):
        raise UsageError(f"need S >= 0 and 0 <= J (<= S for he), got S={S}, J={J}")
    x = np.ascontiguousarray(op, dtype=float)
    if x.ndim != 1:
        raise UsageError("op must be a one-dimensional signal")
    if x.size == 0:
        return x.copy()
    y0 = float(x[0]) if initial_position is None else float(initial_position)
    return _run(x, S, J, kinds[model], y0)
