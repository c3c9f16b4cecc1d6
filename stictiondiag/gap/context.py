"""The shared signals one gap diagnosis works on.

The recorded signals of a loop (:class:`LoopSignals`), the basis of its unmeasured
slow load (:class:`SlowLoad`), the samples the replay is judged on, the normaliser of
each signal's error and the slips measured in the data (Fig. 2 of Choudhury,
Thornhill & Shah 2005): :func:`build_context` computes them once
(:class:`ReplayContext`) for the base replay, every effect of the catalogue and every
held-out fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.checks import span_offset
from stictiondiag.core.errors import DataError
from stictiondiag.stiction.segments import segment_valve

#: Shortest record analysed [samples].
MIN_SAMPLES = 400


def signals_of(tags) -> LoopSignals:
    try:
        op = np.asarray(tags.op, dtype=float)
        pv = np.asarray(tags.pv, dtype=float)
        ts = float(tags.ts)
    except (AttributeError, TypeError, ValueError):
        raise DataError("gap diagnosis needs tags with op, pv and a sample time ts") from None
    mv = getattr(tags, "mv", None)
    sp = getattr(tags, "sp", None)
    mv = None if mv is None else np.asarray(mv, dtype=float)
    sp = None if sp is None else np.asarray(sp, dtype=float)
    n = op.size
    for name, x in (("op", op), ("pv", pv), ("mv", mv), ("sp", sp)):
        if x is None:
            continue
        if x.size != n:
            raise DataError(f"{name} has {x.size} samples, op has {n}: pass equally long signals")
        if not np.all(np.isfinite(x)):
            raise DataError(f"{name} has gaps (NaN): fill or drop them before the gap diagnosis")
    if n < MIN_SAMPLES:
        raise DataError(
            f"{n} samples are too few for the gap diagnosis: need at least {MIN_SAMPLES}"
        )
    if not (math.isfinite(ts) and ts > 0):
        raise DataError(f"sample time must be a positive number of seconds, got {ts}")
    if np.ptp(op) == 0.0 or np.ptp(pv) == 0.0:
        raise DataError("op or pv is constant: there is no movement to replay")
    if mv is not None and np.ptp(mv) == 0.0:
        mv = None
    # The valve kernels work in 0-100 % of span and clip there; mean-centred or
    # normalised exports are shifted into it, and back for output.
    offset = span_offset(op, mv)
    if offset:
        op = op + offset
        mv = None if mv is None else mv + offset
    return LoopSignals(op=op, pv=pv, dt=ts, mv=mv, sp=sp, offset=offset)


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
    offset : float
        Shift added to the recorded op and mv to bring them into 0-100 %
        (:func:`stictiondiag.core.checks.span_offset`) [% of span]; 0 for a record
        in % of span.
    """

    op: np.ndarray
    pv: np.ndarray
    dt: float
    mv: np.ndarray | None = None
    sp: np.ndarray | None = None
    offset: float = 0.0

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


def measure_slips(op: np.ndarray, mv: np.ndarray, dt: float, segments=None) -> dict | None:
    """S and J of every slip read off the data (the stick and slip segments of Fig. 2).

    Uses :func:`stictiondiag.stiction.segments.segment_valve` (or ``segments``, its
    result for these op, mv and dt when the caller has it already); the values only
    seed the least-squares searches, so a failure there is not an error (None).
    """
    try:
        seg = segment_valve(op, mv, dt) if segments is None else segments
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


def starting_point(fit, sig: LoopSignals) -> dict:
    """S and J to start the searches from and, without a recorded mv, the modelled
    valve output that drives the process (from a stiction estimate, if any)."""
    start = None
    mv_model = None
    if fit is not None:
        S, J = getattr(fit, "S", None), getattr(fit, "J", None)
        if S is not None and J is not None and math.isfinite(S) and math.isfinite(J):
            start = (float(S), float(J))
        if sig.mv is None and getattr(fit, "mv_model", None) is not None:
            mv_model = np.asarray(fit.mv_model, dtype=float) + sig.offset
            if mv_model.size != sig.n:
                mv_model = None
    return {"start": start, "mv_model": mv_model}


def build_context(
    sig: LoopSignals,
    *,
    start: tuple[float, float] | None = None,
    mv_model: np.ndarray | None = None,
    load_spacing: float | None = None,
    segments=None,
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
    segments : Segments, optional
        ``segment_valve(sig.op, sig.mv, sig.dt)`` when the caller has it already
        (:func:`measure_slips`).

    Notes
    -----
    The replay cannot know the valve's state before the record starts, so it is
    judged from the first slip measured in the data on (at least the first 2 % of
    the record, at most the first 20 %).
    """
    n = sig.n
    spacing = max(n / 16.0, 40.0) if load_spacing is None else float(load_spacing)
    load = SlowLoad(n, min(spacing, max(n - 1, 2)))
    slips = measure_slips(sig.op, sig.mv, sig.dt, segments) if sig.mv is not None else None
    if slips is not None and sig.offset and segments is not None:
        # Segments measured on the record as read: positions into the shifted span.
        slips["op_break"] = slips["op_break"] + sig.offset
        slips["mv_after"] = slips["mv_after"] + sig.offset
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
