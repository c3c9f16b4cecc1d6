"""Effect ``asymmetry``: S and J differ opening and closing (Loop 1, Section 3).

Acts on mv: Fig. 10 and Eq. 4 of Choudhury, Thornhill & Shah (2005) with S and J
taken from the direction of travel.  Parameters: S and J of the second direction.
Signature: the slips measured in the data differ by direction (rank test,
:func:`stictiondiag.gap.effects.signatures.slips_differ`).
"""

from __future__ import annotations

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
from stictiondiag.gap.effects.search import WIDE_STAGES, grid_search_nd, needle_search
from stictiondiag.gap.effects.signatures import (
    SLIP_TEST_P,
    slips_differ,
    untested_p,
)
from stictiondiag.gap.effects.valve import (
    ValveLogic,
    demand_travel,
    logic_name,
    pick_problem,
    travel_seeds,
)


@dataclass(frozen=True)
class AsymmetryParams(EffectParams):
    """A valve whose S and J differ opening and closing.

    Attributes
    ----------
    S_open, J_open, S_close, J_close : float
        Stiction thresholds opening and closing [% of span].
    logic : ValveLogic
        The stuck-phase logic replayed.
    slips_differ_p : float
        p-value of the rank test that the slips differ by direction [-].
    """

    SIGNATURE = "slips_differ_p"

    S_open: float
    J_open: float
    S_close: float
    J_close: float
    logic: ValveLogic
    slips_differ_p: float


def fit_asymmetry(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, init: EffectFit[AsymmetryParams] | None = None
) -> EffectFit[AsymmetryParams]:
    """Different S and J opening and closing (Loop 1 of Section 3, Fig. 3).

    Fig. 10 and Eq. 4 with S and J taken from the direction of travel: four
    parameters instead of two, searched a direction at a time (the other held) from
    the base fit and from the slips measured in each direction.
    """
    travel = demand_travel(ctx.sig.op)
    lower, upper = np.zeros(4), np.array([travel, 1.5 * travel] * 2)
    valve = base.recorded_valve()
    S0, J0 = valve.S, valve.J
    seeds = [np.array([S0, J0, S0, J0])]
    ups = travel_seeds(ctx.slips, 1.0) or [(S0, J0)]
    dns = travel_seeds(ctx.slips, -1.0) or [(S0, J0)]
    for up in ups:
        for dn in dns:
            seeds.append(np.array([up[0], up[1], dn[0], dn[1]]))
    S4 = np.array(seeds)
    prob = pick_problem(ctx, w, base, init, lambda pr: float(np.min(pr.costs(valve_rows(*S4.T)))))

    def cost(X, bound):
        return prob.costs(valve_rows(X[:, 0], X[:, 1], X[:, 2], X[:, 3]), bound=bound)

    if init is not None:
        # Thresholds only: kept from the whole record (judged there with a penalty per
        # parameter and the block consistency of :mod:`stictiondiag.gap.diagnose`).
        x = np.array(init.x)
    else:
        c = cost(S4, np.inf)
        x = seeds[int(np.argmin(c))]
        # All four together: the two directions' slips are coupled through where the
        # valve stops.
        x, _ = grid_search_nd(cost, x, (0, 1, 2, 3), stages=WIDE_STAGES)
        for pair in ((0, 1), (2, 3)):
            x, _ = needle_search(cost, x, pair, lower, upper, rel=0.03, zooms=1, n_grid=11)
    mv_hat, _ = prob.series(valve_rows(x[0], x[1], x[2], x[3])[0])
    untested = untested_p(ctx.sig.mv)
    p_slips = (
        slips_differ(ctx.slips, ctx.slips["direction"] > 0, ctx.slips["direction"] < 0, untested)
        if ctx.slips is not None
        else untested
    )
    return EffectFit(
        supported=p_slips < SLIP_TEST_P,
        effect="asymmetry",
        variant="open_close",
        n_params=2,
        params=AsymmetryParams(
            S_open=float(x[0]),
            J_open=float(x[1]),
            S_close=float(x[2]),
            J_close=float(x[3]),
            logic=logic_name(prob),
            slips_differ_p=p_slips,
        ),
        predictions={"mv": mv_hat},
        x=tuple(float(v) for v in x),
    )


EFFECT = Effect(
    name="asymmetry",
    acts_on=("mv",),
    parameters=("S_close", "J_close"),
    fit=fit_asymmetry,
    signature="measured slips differ opening and closing",
    signature_test=slips_differ,
    valve_side=True,
)
