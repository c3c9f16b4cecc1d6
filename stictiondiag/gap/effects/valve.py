"""The valve replay fitted to a recorded mv: the two-parameter model and its searches.

:class:`ValveProblem` holds the recorded op and mv, the weights and the fixed settings
of one fit and evaluates many parameter rows per compiled call; :func:`fit_valve` fits
the base model (Section 5.1, Fig. 10, Eq. 4 of Choudhury, Thornhill & Shah 2005);
the seeds from the slips measured in the data and the S-J searches are shared by the
valve-side effects.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.kernels import (
    FAMILY_CODES,
    _rows_order,
    valve_rows,
    valve_series,
    valve_sse_batch,
)
from stictiondiag.gap.effects.search import needle_from_seeds

_CONSTANT = np.zeros(1)


class ValveProblem:
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
    def of(cls, ctx: ReplayContext, w: np.ndarray, kano: bool, d0: float) -> ValveProblem:
        mv = recorded_mv(ctx)
        y0 = _rest_level_before_first_slip(ctx)
        return cls(ctx.sig.op, mv, w, ctx.norm["mv"], kano, d0, y0)

    def with_output_map(self, slope: float, offset: float) -> ValveProblem:
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
        """Normalised weighted squared mv error for every row of P (the columns of :func:`valve_rows`).

        Rows whose error exceeds ``bound`` (normalised) or the best row so far are
        abandoned early; their returned error is then only a lower bound.  With
        ``affine`` (no ``bound``) and ``keep > 0`` only the ``keep`` lowest errors are
        exact (enough for the ``keep`` best rows); the others may be lower bounds that
        lie above them.  ``order``: the order to evaluate the rows in with ``keep``
        (likely best first makes the abandoning effective).
        """
        c = valve_sse_batch(
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
            FAMILY_CODES[family],
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

        return valve_series(
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


def recorded_mv(ctx: ReplayContext) -> np.ndarray:
    """The recorded mv of ``ctx`` [% of span]: the valve replay is fitted only on loops
    that have one."""
    mv = ctx.sig.mv
    if mv is None:
        raise ValueError("the valve replay needs a recorded mv")
    return mv


def _rest_level_before_first_slip(ctx: ReplayContext) -> float:
    """Valve position at the start of the replay [% of span].

    The recorded level while the valve rests before its first measured slip: there
    the position has settled (after any actuator lag) and the valve is stuck, as the
    replay starts.  Without measured slips, the first few samples.
    """
    mv = recorded_mv(ctx)
    if ctx.slips is not None and ctx.slips["time"].size:
        k = int(ctx.slips["time"][0])
        if k >= 4:
            return float(np.median(mv[max(k - 10, 0) : k - 1]))
    return float(np.median(mv[: max(min(3, mv.size // 100), 1)]))


def demand_travel(op: np.ndarray) -> float:
    return max(float(np.percentile(op, 99) - np.percentile(op, 1)), 0.2)


def slip_medians(slips: dict | None, mask=None) -> tuple[float, float] | None:
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


def travel_seeds(
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


def sj_wide(cost2, seeds) -> np.ndarray:
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


def sj_bounds(travel: float) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(2), np.array([travel, 1.5 * travel])


def needle_sj(
    prob: ValveProblem,
    seeds,
    travel: float,
    *,
    rel: float = 0.15,
    zooms: int = 2,
    **row_kw,
):
    """Best (S, J) from each seed by :func:`needle_search` (its default grid); returns
    (x, cost)."""
    lower, upper = sj_bounds(travel)

    def cost(X, bound):
        return prob.costs(valve_rows(X[:, 0], X[:, 1], **row_kw), bound=bound)

    return needle_from_seeds(cost, seeds, (0, 1), lower, upper, rel=rel, zooms=zooms)


class ValveLogic(StrEnum):
    """The stuck-phase logic of a replayed valve: the flowchart of Fig. 10
    (Choudhury, Thornhill & Shah 2005) or Kano et al.'s (2004), which re-arms a stuck
    valve on a reversal of the demand."""

    CHOUDHURY = "choudhury"
    KANO = "kano"


@dataclass(frozen=True)
class ValveFit:
    """The fitted two-parameter valve replay.

    Attributes
    ----------
    mv : ndarray
        Replayed valve position [% of span].
    phase : ndarray
        Valve phase codes of the stiction element (see :func:`valve_replay`).
    S, J : float
        Deadband plus stickband and slip jump [% of span].
    kano : bool
        Stuck-phase logic of Kano et al. (2004) instead of Fig. 10.
    initial_direction : float
        Direction of travel before the record (+1 opening, -1 closing).
    """

    mv: np.ndarray
    phase: np.ndarray
    S: float
    J: float
    kano: bool = False
    initial_direction: float = 0.0

    @property
    def logic(self) -> ValveLogic:
        """The stuck-phase logic replayed."""
        return ValveLogic.KANO if self.kano else ValveLogic.CHOUDHURY


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
    travel = demand_travel(ctx.sig.op)
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
    med = slip_medians(ctx.slips)
    if med is not None:
        extra.append(med)
    extra += travel_seeds(ctx.slips)
    # The stuck-phase logic from the coarse grid and the seeds (the two differ only
    # in how noise reversals re-arm a stuck valve), then the fine search.
    best: tuple[float, bool, tuple] | None = None
    for kano in (False, True):
        prob = ValveProblem.of(ctx, w, kano, 1.0)
        X = np.vstack([coarse, np.array(extra).reshape(-1, 2)])
        c = prob.costs(valve_rows(X[:, 0], X[:, 1]))
        i = int(np.argmin(c))
        if best is None or c[i] < best[0]:
            best = (float(c[i]), kano, tuple(X[i]))
    assert best is not None  # the loop above scored both logics
    _, kano, top = best
    prob = ValveProblem.of(ctx, w, kano, 1.0)
    seeds = list(dict.fromkeys([top, *extra]))
    # J scanned over its whole range around each seed, as the augmented valves do
    # (:func:`sj_wide`): the error is a needle in J, and a base that misses it would
    # credit any augmentation that re-searches S and J with the base's own shortfall.
    wide = sj_wide(lambda X, bound: prob.costs(valve_rows(X[:, 0], X[:, 1]), bound=bound), seeds)
    x, c = needle_sj(prob, list(dict.fromkeys([*seeds, tuple(wide)])), travel)
    # The direction of travel before the record only matters until the first slip.
    prob_neg = ValveProblem.of(ctx, w, kano, -1.0)
    d0 = -1.0 if prob_neg.costs(valve_rows(x[0], x[1]))[0] < c else 1.0
    prob = ValveProblem.of(ctx, w, kano, d0)
    v, ph = prob.series(valve_rows(x[0], x[1])[0])
    return ValveFit(v, ph, float(x[0]), float(x[1]), kano, d0)


def affine_map(v: np.ndarray, mv: np.ndarray, w: np.ndarray) -> tuple[float, float]:
    """Least-squares ``mv = b + k v`` on the weighted samples: (k, b)."""
    sw = w > 0
    vv, mm = v[sw], mv[sw]
    vm = vv.mean()
    den = float(np.dot(vv - vm, vv - vm))
    if den <= 0.0:
        return 1.0, float(mm.mean() - vm)
    k = float(np.dot(vv - vm, mm - mm.mean()) / den)
    return k, float(mm.mean() - k * vm)


def base_problem(ctx: ReplayContext, w: np.ndarray, valve: ValveFit) -> ValveProblem:
    """The stuck-phase logic and start of the base fit's valve ``valve``."""
    return ValveProblem.of(ctx, w, valve.kano, valve.initial_direction)


def pick_problem(ctx, w, base, init, evaluate) -> ValveProblem:
    """The stuck-phase logic for an augmented valve: the one of the whole-record fit
    ``init``, else whichever makes ``evaluate(problem)`` (the error at the starting
    points) lower.  The base fit's logic is not enough: an effect can make the other
    logic the better reading of the same data."""
    d0 = base.valve.initial_direction
    if init is not None:
        return ValveProblem.of(ctx, w, init.params.logic is ValveLogic.KANO, d0)
    probs = [ValveProblem.of(ctx, w, k, d0) for k in (False, True)]
    return min(probs, key=evaluate)


def logic_name(prob: ValveProblem) -> ValveLogic:
    """The stuck-phase logic of ``prob``."""
    return ValveLogic.KANO if prob.kano else ValveLogic.CHOUDHURY


def threshold_scale(*values: float) -> float:
    return max(max(values), 0.05)
