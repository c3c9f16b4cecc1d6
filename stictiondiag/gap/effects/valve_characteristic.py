"""Effect ``valve_characteristic``: a non-linear installed characteristic.

Acts on pv (process side) or mv (valve side): the curve between valve position and
flow, the last step of Fig. 10 (Section 5.1 of Choudhury, Thornhill & Shah 2005):
an exponential (equal-percentage-like) or power (quick-opening-like) curve.
Parameter: its curvature (and, valve side, a gain and offset).  Signature: the loop's
gain changes with the operating point, which no linear process does
(:func:`gain_change_test`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from enum import StrEnum

import numpy as np

from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.base import (
    BaseFit,
    Effect,
    EffectFit,
    EffectParams,
    fit_process,
    process_input,
    pv_noise_floor,
)
from stictiondiag.gap.effects.kernels import valve_rows
from stictiondiag.gap.effects.signatures import (
    SIGNATURE_P,
    block_scale,
    one_sided,
    signature_test,
    testable_slips,
    untested_p,
)
from stictiondiag.gap.effects.valve import (
    affine_map,
    base_problem,
    recorded_mv,
)
from stictiondiag.identification.numerics import golden_section
from stictiondiag.identification.predictor_kernels import kalman_gains, process_regressors
from stictiondiag.identification.process_result import ProcessFit


class CurveFamily(StrEnum):
    """The family of an installed characteristic (:func:`characteristic_curve`)."""

    EXPONENTIAL = "exponential"
    POWER = "power"


class CharacteristicSide(StrEnum):
    """Where the characteristic acts: between mv and the process (``process``), or
    inside a flow-like recorded mv (``valve``)."""

    PROCESS = "process"
    VALVE = "valve"


@dataclass(frozen=True)
class CharacteristicParams(EffectParams):
    """A non-linear installed characteristic.

    Attributes
    ----------
    curvature : float
        Its curvature [-] (:func:`characteristic_curve`; 0 is linear).
    family : CurveFamily
        Exponential or power.
    side : CharacteristicSide
        Process side or valve side.
    gain_change : float or None
        Change of the loop's gain with the operating point, measured in the data [-]
        (NaN: too few slips to measure; None on part of the record).
    gain_change_p : float or None
        p-value of its test, one-sided in the direction of the curvature [-].
    """

    SIGNATURE = "gain_change_p"

    curvature: float
    family: CurveFamily
    side: CharacteristicSide
    gain_change: float | None = None
    gain_change_p: float | None = None


def characteristic_curve(x: np.ndarray, curvature: float, family: str) -> np.ndarray:
    """Normalised installed characteristic, flow [% of max] at position x [% of travel].

    ``exponential``: ``100 (e^{c x/100} - 1)/(e^c - 1)`` (equal-percentage-like for
    c > 0, c = ln R for rangeability R; quick-opening-like for c < 0);
    ``power``: ``100 (x/100)^p`` with ``p = e^{curvature}`` (quick-opening for p < 1,
    ``p = 1/2`` the square root of Section 5.1).  Both are the identity at curvature
    0 (the look-up table in the last step of Fig. 10).
    """
    z = np.clip(np.asarray(x, dtype=float), 0.0, 100.0) / 100.0
    if family == "power":
        return 100.0 * z ** math.exp(curvature)
    if family == "linear" or abs(curvature) < 1e-9:
        return 100.0 * z
    return 100.0 * np.expm1(curvature * z) / math.expm1(curvature)


_CURVATURE_GRIDS = {
    "exponential": (np.linspace(-6.0, 6.0, 13), (-10.0, 10.0)),
    "power": (np.linspace(-1.5, 1.5, 13), (-2.5, 2.5)),
}


def _search_curvature(cost: Callable[[float], float], family: str) -> tuple[float, float]:
    grid, bounds = _CURVATURE_GRIDS[family]
    costs = [cost(float(c)) for c in grid]
    i = int(np.argmin(costs))
    c = golden_section(cost, float(grid[max(i - 1, 0)]), float(grid[min(i + 1, grid.size - 1)]), 14)
    c = float(np.clip(c, *bounds))
    cc = cost(c)
    return (c, cc) if cc < costs[i] else (float(grid[i]), costs[i])


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    v = np.asarray(x, dtype=float)[w > 0]
    return float(np.median(v)) if v.size else float(np.median(x))


def gain_change_test(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, side: str
) -> tuple[float, float]:
    """The signature of an installed characteristic: a gain that changes with the
    operating point, which no linear process gives (Section 5.1, last step of Fig. 10).

    The base replay's input ``u`` is joined by a hinge ``max(u - u_50, 0)`` at its
    median: its coefficient is the relative change of the gain above the middle of
    the range travelled against below it, whatever the shape of the curve.
    Process side (``u`` the process input): the hinge passes through the base
    process's dynamics, load tracking and prediction horizon, and its coefficient is
    fitted to the base pv replay's errors, each block of the record weighted by the
    inverse of their variance there (:func:`block_scale`: the errors of a block with
    an unforeseen load step are mostly that load, and unweighted they decide the
    coefficient and its scatter).  Valve side (mv itself flow-like): the
    position after each slip against the demand at its breakaway and the hinge of it,
    with an offset per direction (as :func:`slip_slope_test`).  Returns the
    relative gain change and the two-sided p-value of :func:`signature_test` (the
    block-to-block scatter of the record decides, so a change that only part of the
    record shows does not pass).  An operating point that never moves (a cycle
    between two fixed positions) leaves the hinge a copy of ``u``: p = 1.  On the
    valve side with fewer than twelve measured slips: ``(nan, 1)``, too few to test.
    """
    sig = ctx.sig
    if side == "process":
        u = process_input(ctx, base)
        model = base.process.prediction.model
        k1, k2 = kalman_gains(model.pole, model.load_ratio)
        h = np.maximum(u - _weighted_median(u, w), 0.0)
        X_u = process_regressors(u, model, k1, k2)
        x_h = process_regressors(h, model, k1, k2) @ base.process.prediction.coef[:2]
        r = sig.pv - base.process.prediction.pv
        others = np.column_stack([np.ones(sig.n), X_u])
        # Weighted by each block's error variance: the blocks of unforeseen load
        # steps must not decide the test (:func:`block_scale`).
        g = block_scale(r, w)
        return signature_test(x_h * g, -r * g, w, others=others * g[:, None])
    measured = testable_slips(ctx.slips)
    if measured is None:
        return math.nan, 1.0
    x, y, d, n_blocks = measured
    others = np.column_stack([(d > 0).astype(float), (d < 0).astype(float), x])
    h = np.maximum(x - float(np.median(x)), 0.0)
    beta, p = signature_test(h, y, np.ones(x.size), others=others, n_blocks=n_blocks)
    b = float(np.linalg.lstsq(others, y, rcond=None)[0][2])
    return (beta / b if b != 0.0 else 0.0), p


#: One form's fit: (cost, form, n_params, params, predictions, process fit, process
#: input); the last two are None on the valve side.
_FormFit = tuple[
    float,
    str,
    int,
    CharacteristicParams,
    dict[str, np.ndarray],
    ProcessFit | None,
    np.ndarray | None,
]


def fit_valve_characteristic(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[CharacteristicParams] | None = None,
) -> EffectFit[CharacteristicParams]:
    """A non-linear installed characteristic between valve position and flow.

    Process side: ``pv = G(f(mv))``, the curvature of ``f`` searched with the process
    dynamics of the base fit and its gain, initial state and slow load refitted.
    Valve side (mv itself flow-like): ``mv = a + b f(valve(op))``.  Two families,
    exponential and power; the form with the lower error on mv and pv together is
    kept.
    """
    sig = ctx.sig
    u = process_input(ctx, base)
    model = base.process.prediction.model
    pv, var_pv = sig.pv, ctx.norm["pv"]
    base_pv_cost = float(np.dot(w, (base.process.prediction.pv - pv) ** 2)) / var_pv
    forms = ["process_exponential", "process_power"]
    if sig.mv is not None:
        forms += ["valve_exponential", "valve_power"]
        valve, mv = base.recorded_valve(), recorded_mv(ctx)
        prob = base_problem(ctx, w, valve)
        row = valve_rows(valve.S, valve.J)
        base_mv_cost = float(prob.costs(row)[0])
    if init is not None:
        forms = [init.variant]
    results: list[_FormFit] = []
    for form in forms:
        side, family = form.split("_")
        if side == "process":

            def cost_pv(c, family=family):
                f = fit_process(characteristic_curve(u, c, family), ctx, w, model=model)
                return float(np.dot(w, (f.prediction.pv - pv) ** 2)) / var_pv

            if init is not None:
                c = float(init.params.curvature)
                cc = cost_pv(c)
            else:
                c, cc = _search_curvature(cost_pv, family)
            ue = characteristic_curve(u, c, family)
            if init is None:
                f = fit_process(ue, ctx, w, model=model, retune=True)
            else:
                f = fit_process(
                    ue, ctx, w, model=init.process.prediction.model if init.process else model
                )
            cc = float(np.dot(w, (f.prediction.pv - pv) ** 2)) / var_pv
            results.append(
                (
                    cc,
                    form,
                    1,
                    CharacteristicParams(c, CurveFamily(family), CharacteristicSide(side)),
                    {"pv": f.prediction.pv},
                    f,
                    ue,
                )
            )
        else:

            def cost_mv(c, family=family):
                return float(prob.costs(row, affine=True, curvature=c, family=family)[0])

            if init is not None:
                c = float(init.params.curvature)
                cc = cost_mv(c)
            else:
                c, cc = _search_curvature(cost_mv, family)
            g = characteristic_curve(valve.mv, c, family)
            k, b = affine_map(g, mv, w)
            # On the same footing as the process side: error on mv and pv together.
            results.append(
                (
                    cc + base_pv_cost - base_mv_cost,
                    form,
                    3,
                    CharacteristicParams(c, CurveFamily(family), CharacteristicSide(side)),
                    {"mv": b + k * g},
                    None,
                    None,
                )
            )
    _, variant, n_params, params, preds, proc, proc_u = min(results, key=lambda r: r[0])
    supported = True
    if init is None:
        gain_change, p_gain = gain_change_test(ctx, w, base, params.side)
        if math.isfinite(gain_change):
            # Convex (curvature > 0, both families) means more gain above the middle.
            p_gain = one_sided(p_gain, gain_change * params.curvature > 0.0)
        else:
            # Too few measured slips to test: the replay decides alone, except on a
            # quantised mv (:func:`untested_p`).
            p_gain = untested_p(ctx.sig.mv)
        params = replace(params, gain_change=gain_change, gain_change_p=p_gain)
        supported = p_gain < SIGNATURE_P
    return EffectFit(
        effect="valve_characteristic",
        variant=variant,
        n_params=n_params,
        supported=supported,
        params=params,
        predictions=preds,
        x=(params.curvature,),
        process=proc,
        # proc_u is None exactly when proc is (the valve side).
        pv_floor=None
        if proc is None or proc_u is None or init is not None
        else pv_noise_floor(proc_u, ctx, proc),
    )


EFFECT = Effect(
    name="valve_characteristic",
    acts_on=("pv", "mv"),
    parameters=("curvature",),
    fit=fit_valve_characteristic,
    signature="the loop's gain changes with the operating point",
    signature_test=gain_change_test,
)
