"""Effect ``actuator_lag``: positioner or actuator dynamics after the friction element.

Acts on mv: the stiction element of Fig. 10 (Choudhury, Thornhill & Shah 2005) is
followed by a first-order lag.  Parameter: its time constant [s] (S and J are
searched again with it).  Signature: a lag of at least half a sample (a shorter one
cannot be told from the timing jitter of the replayed slips).
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
from stictiondiag.gap.effects.search import WIDE_STAGES, grid_search_nd
from stictiondiag.gap.effects.valve import (
    ValveLogic,
    demand_travel,
    logic_name,
    needle_sj,
    pick_problem,
    sj_wide,
    slip_medians,
    travel_seeds,
)
from stictiondiag.identification.numerics import golden_section


@dataclass(frozen=True)
class ActuatorLagParams(EffectParams):
    """A valve followed by a first-order actuator lag.

    Attributes
    ----------
    S, J : float
        Stiction thresholds of the friction element [% of span].
    time_constant_s : float
        The lag's time constant [s].
    logic : ValveLogic
        The stuck-phase logic replayed.
    """

    S: float
    J: float
    time_constant_s: float
    logic: ValveLogic


def _lag_weight(tau_samples: float) -> float:
    return math.exp(-1.0 / tau_samples) if tau_samples > 1e-6 else 0.0


def fit_actuator_lag(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[ActuatorLagParams] | None = None,
) -> EffectFit[ActuatorLagParams]:
    """Positioner/actuator dynamics after the friction element: ``mv = lag(valve(op))``.

    The stiction element of Fig. 10 is followed by a first-order lag with time
    constant tau [s].  The breakaways of the element do not depend on the lag, so S
    and J are searched with a provisional lag, then tau by golden-section search,
    then S and J again.
    """
    valve = base.recorded_valve()
    seeds = [(valve.S, valve.J)]
    med = slip_medians(ctx.slips)
    if med is not None:
        seeds.append(med)
    seeds += travel_seeds(ctx.slips)
    # Every seed is an (S, J) pair: two columns.
    S_seeds, J_seeds = np.array(seeds).T
    prob = pick_problem(
        ctx,
        w,
        base,
        init,
        lambda pr: float(np.min(pr.costs(valve_rows(S_seeds, J_seeds, lag=_lag_weight(2.0))))),
    )
    travel = demand_travel(ctx.sig.op)
    dt = ctx.sig.dt
    tau_max = max(ctx.sig.n / 20.0, 2.0)

    def cost_tau(S, J):
        return lambda t: float(prob.costs(valve_rows(S, J, lag=_lag_weight(t)))[0])

    if init is not None:
        # Thresholds from the whole record; the lag is refitted here.
        S, J, tau = init.x
    else:
        # The breakaways do not depend on the lag: S and J with a few provisional lags
        # (a lag hides the size of the slips, so J can be far from the base fit's).
        best: tuple[float, np.ndarray, float] | None = None
        for tau in (1.0, 3.0, 6.0):

            def cost2(X, bound, tau=tau):
                return prob.costs(valve_rows(X[:, 0], X[:, 1], lag=_lag_weight(tau)), bound=bound)

            x = sj_wide(cost2, seeds)
            x, c = grid_search_nd(cost2, x, (0, 1), stages=WIDE_STAGES[1:])
            if best is None or c < best[0]:
                best = (c, x, tau)
        assert best is not None  # the loop above tried three lags
        _, (S, J), tau = best
        (S, J), _ = needle_sj(prob, [(S, J)], travel, rel=0.05, lag=_lag_weight(tau))
        lt = golden_section(
            lambda v: cost_tau(S, J)(math.exp(v)), math.log(0.1), math.log(tau_max), 24
        )
        tau = math.exp(lt)
        (S, J), _ = needle_sj(prob, [(S, J)], travel, rel=0.05, lag=_lag_weight(tau))
    lt = golden_section(
        lambda v: cost_tau(S, J)(math.exp(v)),
        math.log(max(tau / 3, 0.05)),
        math.log(min(3 * tau + 0.1, tau_max)),
        16,
    )
    tau = math.exp(lt)
    mv_hat, _ = prob.series(valve_rows(S, J, lag=_lag_weight(tau))[0])
    return EffectFit(
        # A lag shorter than half a sample cannot be told from the timing jitter of
        # the replayed slips: it smooths every mistimed jump a little.
        supported=tau >= 0.5,
        effect="actuator_lag",
        variant="first_order",
        n_params=1,
        params=ActuatorLagParams(
            S=float(S), J=float(J), time_constant_s=float(tau * dt), logic=logic_name(prob)
        ),
        predictions={"mv": mv_hat},
        x=(float(S), float(J), float(tau)),
    )


EFFECT = Effect(
    name="actuator_lag",
    acts_on=("mv",),
    parameters=("time_constant_s",),
    fit=fit_actuator_lag,
    signature="a lag of at least half a sample",
    valve_side=True,
)
