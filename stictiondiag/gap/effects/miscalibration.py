"""Effect ``miscalibration``: a positioner whose moving-phase slope of mv against op is not 1.

Acts on mv (Section 4.2.1, Fig. 8 bottom row of Choudhury, Thornhill & Shah 2005):
``mv = offset + slope * valve(op)``.  Parameters: slope and offset.  Signature: the
position after each measured slip against the demand at its breakaway lies on a line
of slope other than 1, in the fitted direction (:func:`slip_slope_test`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.base import (
    BaseFit,
    Effect,
    EffectFit,
    EffectParams,
)
from stictiondiag.gap.effects.kernels import valve_rows
from stictiondiag.gap.effects.search import needle_from_seeds
from stictiondiag.gap.effects.signatures import (
    SIGNATURE_P,
    one_sided,
    signature_test,
    testable_slips,
    untested_p,
)
from stictiondiag.gap.effects.valve import (
    ValveLogic,
    ValveProblem,
    affine_map,
    demand_travel,
    logic_name,
    pick_problem,
    recorded_mv,
    sj_bounds,
    sj_wide,
    travel_seeds,
)


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
    leaves the decision to the replay, as :func:`slips_differ` does).
    """
    measured = testable_slips(slips)
    if measured is None:
        return math.nan, 1.0
    x, y, d, n_blocks = measured
    others = np.column_stack([(d > 0).astype(float), (d < 0).astype(float)])
    beta, p = signature_test(x, y - x, np.ones(x.size), others=others, n_blocks=n_blocks)
    if p >= 1.0 and beta == 0.0:
        return math.nan, 1.0
    return 1.0 + beta, p


def _centre_first(X: np.ndarray) -> np.ndarray:
    """Rows of a search grid nearest its centre first (each column by its spread)."""
    if X.shape[0] < 3:
        return np.arange(X.shape[0])
    lo, hi = X.min(axis=0), X.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    return np.argsort(np.abs((X - 0.5 * (lo + hi)) / span).sum(axis=1), kind="stable")


def _needle_sj_affine(prob: ValveProblem, seeds, travel: float, *, rel=0.15, zooms=2):
    lower, upper = sj_bounds(travel)

    def cost(X, bound):
        # needle_search uses the order of the ``beam`` (3) best rows of a grid only;
        # its grids are centred on the best point so far.
        return prob.costs(valve_rows(X[:, 0], X[:, 1]), affine=True, keep=3, order=_centre_first(X))

    return needle_from_seeds(cost, seeds, (0, 1), lower, upper, rel=rel, zooms=zooms)


@dataclass(frozen=True)
class MiscalibrationParams(EffectParams):
    """A miscalibrated positioner: the valve position is ``offset + slope`` times the
    friction element's output (Eq. 4, Section 4.2.1).

    Attributes
    ----------
    S, J : float
        Stiction thresholds on the valve's axis [% of span].
    S_on_op_axis, J_on_op_axis : float
        The same on the demand's axis [% of span].
    slope : float
        Gain from the friction element's output to mv [-].
    offset_pct : float
        Offset of mv [% of span].
    logic : ValveLogic
        The stuck-phase logic replayed.
    slip_slope : float
        Slope of the position after each slip against the demand at the breakaway,
        measured in the data [-] (NaN: too few slips; whole-record fit only).
    slip_slope_p : float
        p-value of the test that it differs from 1 in the fitted direction [-].
    """

    SIGNATURE = "slip_slope_p"

    S: float
    J: float
    S_on_op_axis: float
    J_on_op_axis: float
    slope: float
    offset_pct: float
    logic: ValveLogic
    slip_slope: float
    slip_slope_p: float


def fit_miscalibration(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[MiscalibrationParams] | None = None,
) -> EffectFit[MiscalibrationParams]:
    """Miscalibrated positioner: ``mv = offset + slope * valve(op)`` (Section 4.2.1, Fig. 8).

    A calibration factor that is too large makes the moving-phase slope of mv
    against op greater than 1.  The data-driven model scales exactly with its input,
    so a span error before the friction element (``demand = pivot + slope (op -
    pivot)``) is this model with S and J divided by the slope; S and J on the op
    axis are searched, slope and offset solved in closed form for every trial.
    """
    travel = demand_travel(ctx.sig.op)
    mv = recorded_mv(ctx)
    valve = base.recorded_valve()
    S0, J0 = valve.S, valve.J
    slopes = np.geomspace(0.4, 2.5, 41)
    prob = pick_problem(
        ctx,
        w,
        base,
        init,
        lambda pr: float(np.min(pr.costs(valve_rows(S0 / slopes, J0 / slopes), affine=True))),
    )
    if init is not None:
        # Thresholds from the whole record; slope and offset are solved on the samples
        # of ``w`` below.
        prob = prob.with_output_map(init.params.slope, init.params.offset_pct)
        x = np.array(init.x)
    else:
        c = prob.costs(valve_rows(S0 / slopes, J0 / slopes), affine=True)
        i = int(np.argmin(c))
        # The element starts at the recorded rest level in its own units: map it back
        # with the slope and offset of the best scanned point before the search.
        v, _ = prob.series(valve_rows(S0 / slopes[i], J0 / slopes[i])[0])
        prob = prob.with_output_map(*affine_map(v, mv, w))
        c = prob.costs(valve_rows(S0 / slopes, J0 / slopes), affine=True)
        seeds = [(S0 / slopes[i], J0 / slopes[i]) for i in np.argsort(c)[:2]]
        # The demand travel of the slips is on the op axis already.
        seeds += travel_seeds(ctx.slips)
        # Only the best point of the wide grid is used: the others need not be exact.
        wide = sj_wide(
            lambda X, bound: prob.costs(valve_rows(X[:, 0], X[:, 1]), affine=True, keep=1), seeds
        )
        x, _ = _needle_sj_affine(prob, [*seeds, tuple(wide)], travel * 3)
    v, _ = prob.series(valve_rows(x[0], x[1])[0])
    slope, offset = affine_map(v, mv, w)
    for _ in range(2 if init is None else 0):
        prob = prob.with_output_map(slope, offset)
        x, _ = _needle_sj_affine(prob, [x], travel * 3, rel=0.03, zooms=1)
        v, _ = prob.series(valve_rows(x[0], x[1])[0])
        slope, offset = affine_map(v, mv, w)
    # The signature (whole-record fit only): the slope of the position after each
    # slip against the demand at its breakaway, measured in the data, differs from 1
    # in the fitted direction (:func:`slip_slope_test`, one-sided).
    slip_slope, p_slope = math.nan, 0.0
    if init is None:
        slip_slope, p_slope = slip_slope_test(ctx.slips)
        if math.isfinite(slip_slope):
            p_slope = one_sided(p_slope, (slip_slope - 1.0) * (slope - 1.0) > 0.0)
        else:
            # Too few measured slips to test (as for :func:`slips_differ`): the
            # replay decides alone, except on a quantised mv (:func:`untested_p`).
            p_slope = untested_p(ctx.sig.mv)
    return EffectFit(
        effect="miscalibration",
        variant="slope_offset",
        n_params=2,
        supported=p_slope < SIGNATURE_P,
        params=MiscalibrationParams(
            S=float(x[0] * slope),
            J=float(x[1] * slope),
            S_on_op_axis=float(x[0]),
            J_on_op_axis=float(x[1]),
            slope=slope,
            offset_pct=offset,
            logic=logic_name(prob),
            slip_slope=slip_slope,
            slip_slope_p=p_slope,
        ),
        predictions={"mv": offset + slope * v},
        x=(float(x[0]), float(x[1])),
    )


EFFECT = Effect(
    name="miscalibration",
    acts_on=("mv",),
    parameters=("slope", "offset_pct"),
    fit=fit_miscalibration,
    signature="slope of the position after each slip against the demand at breakaway not 1",
    signature_test=slip_slope_test,
    valve_side=True,
)
