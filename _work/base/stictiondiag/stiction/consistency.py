"""Describing-function consistency (Choudhury, Thornhill & Shah 2005, Section 6):
do the identified loop and the fitted S and J predict the cycle the record shows?

A sticky valve in a loop with integral action makes a limit cycle whose period and
controller-output amplitude follow from ``G0(i w) = -1/N(X_m)`` (Eq. 5), ``N`` the
describing function of the data-driven valve (Eqs. 7-10,
:func:`stictiondiag.models.describing.predict_limit_cycle`).  The same loop with a
linear valve (``N = 1``) has no cycle of its own when it is stable (Nyquist): a cycle
there needs an external source, or a loop tuned so tight that it rings.  So for a
loop with a cycle (stage 1 of :mod:`stictiondiag.stiction.cause`):

* **the loop as identified**, with no second identifier: the process is the linear
  part of the Hammerstein fit that gave S and J (a direct part and a first-order lag
  behind a dead time, integrating for a level loop,
  :class:`stictiondiag.models.processes.SampledLag`, its gains brought back to pv
  units per % of op by ``details["gain_units"]``); the PI controller is
  :func:`stictiondiag.identification.controller.identify_controller` of sp, pv, op.
  A P-only law (no significant integral term) is taken as a PI whose integral time is
  :data:`P_ONLY_PERIODS` observed periods, which leaves the loop's response at the
  cycle's frequency unchanged to a tenth of a degree.
* **the observed cycle**: its period (stage 1's, or the fit's cycle time scale for a
  short record) and op's fundamental amplitude
  (:func:`stictiondiag.signals.oscillation.fundamental_amplitude`, the amplitude a
  describing function speaks of).

The features (:data:`FEATURES`):

``df_cycle``
    1 when the describing function predicts a stable limit cycle (Loeb), else 0.
``df_period_miss``
    ``|log(T_predicted / T_observed)|``, capped at :data:`LOG_CAP` (the cap also
    without a predicted cycle).
``df_amplitude_ratio``
    ``log(X_m predicted / op's fundamental amplitude)``, clipped to
    ``+-LOG_CAP``; ``-LOG_CAP`` without a predicted cycle (a predicted amplitude of 0).
``linear_gain_margin``
    ``log`` of the gain margin of the loop with a linear valve
    (:func:`stictiondiag.models.describing.stability_margins`), clipped to
    ``+-LOG_CAP`` (below 0: the linear loop is unstable and cycles on its own).
``linear_phase_margin``
    Its phase margin [deg] / 180, clipped to [-1, 1].
``df_available``
    1 when the loop could be identified (a Hammerstein fit, a controller whose gain
    has the sign of negative feedback with the fitted process); else 0 and the
    others take their values for "no prediction" (:data:`FILL`).

Cost: the controller fit is O(n) (least squares of the velocity-form law); the
describing-function solution and the margins run on fixed grids
(:data:`N_AMPLITUDES` by :data:`N_FREQUENCIES`, the grids of the replay's
describing-function start), whatever the record's length.  Loops without a cycle, or
with a recorded valve position (no Hammerstein fit), skip it.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.identification.controller import identify_controller
from stictiondiag.models.describing import predict_limit_cycle, stability_margins
from stictiondiag.models.processes import PI, SampledLag
from stictiondiag.signals.oscillation import fundamental_amplitude
from stictiondiag.stiction.valvefit import StictionFit

#: The features of this module, in order.
FEATURES: tuple[str, ...] = (
    "df_available",
    "df_cycle",
    "df_period_miss",
    "df_amplitude_ratio",
    "linear_gain_margin",
    "linear_phase_margin",
)

#: Largest |log ratio| kept [-]: a factor of 10 either way is "no match" already.
LOG_CAP = math.log(10.0)

#: The features' values when there is no prediction (no cycle, no Hammerstein fit, a
#: loop that cannot be identified): no predicted cycle, a linear loop that is not
#: known to be near its stability limit.
FILL: dict[str, float] = {
    "df_available": 0.0,
    "df_cycle": 0.0,
    "df_period_miss": LOG_CAP,
    "df_amplitude_ratio": -LOG_CAP,
    "linear_gain_margin": LOG_CAP,
    "linear_phase_margin": 1.0,
}

#: Integral time given to a P-only controller, in observed periods [-].
P_ONLY_PERIODS = 100.0

#: Grids of the describing-function solution (log-spaced amplitudes and frequencies).
N_AMPLITUDES = 120
N_FREQUENCIES = 3000


def fitted_process(fit: StictionFit, dt: float, integrating: bool) -> SampledLag | None:
    """The linear part of a Hammerstein fit in pv units per % of op
    (:class:`~stictiondiag.models.processes.SampledLag`); None for another fit."""
    d = fit.details or {}
    gains, units = d.get("process_gains"), d.get("gain_units")
    if fit.method != "hammerstein" or not gains or units is None or not math.isfinite(units):
        return None
    return SampledLag(
        direct_gain=float(gains["direct"]) * float(units),
        lag_gain=float(gains["lag"]) * float(units),
        time_constant=float(d.get("time_constant_s", 0.0)),
        dead_time=float(d.get("dead_time_s", dt)),
        sample_time=float(dt),
        integrating=d.get("structure") == "integrating" or bool(integrating),
    )


def _clip(v: float, lo: float, hi: float) -> float:
    return float(min(max(v, lo), hi))


def identified_loop(fit: StictionFit, data, period_s: float) -> tuple[SampledLag, PI] | None:
    """The process of the fit and the controller identified from the record; None
    when either is missing or their gains make positive feedback."""
    dt = float(data.ts)
    process = fitted_process(fit, dt, bool(getattr(data, "integrating", False)))
    if process is None or not process.gain != 0.0:
        return None
    try:
        cf = identify_controller(data.sp, data.pv, data.op, dt)
    except StictionError:
        return None
    c = cf.controller
    if not (math.isfinite(c.gain) and c.gain * process.gain > 0):
        return None
    ti = c.integral_time
    if not (math.isfinite(ti) and ti > 0):
        ti = P_ONLY_PERIODS * period_s
    return process, PI(gain=float(c.gain), integral_time=float(ti))


def describing_features(fit: StictionFit, data, period_s: float | None) -> dict[str, float]:
    """The features of :data:`FEATURES` for a loop whose cycle has period ``period_s``
    [s] (None: the fit's cycle time scale); :data:`FILL` where there is no prediction."""
    out = dict(FILL)
    if data is None or fit.method != "hammerstein":
        return out
    dt = float(data.ts)
    if not (period_s and period_s > 0 and math.isfinite(period_s)):
        p = (fit.details or {}).get("period_samples")
        period_s = float(p) * dt if p else None
    if not period_s:
        return out
    loop = identified_loop(fit, data, period_s)
    amp = fundamental_amplitude(np.asarray(data.op, dtype=float), period_s / dt)
    if loop is None or not (amp and amp > 0):
        return out
    process, controller = loop
    out["df_available"] = 1.0
    try:
        margins = stability_margins(process, controller, n_frequencies=N_FREQUENCIES)
        pred = predict_limit_cycle(
            process,
            controller,
            max(float(fit.S), 0.0),
            max(float(fit.J), 0.0),
            n_amplitudes=N_AMPLITUDES,
            n_frequencies=N_FREQUENCIES,
        )
    except (StictionError, ArithmeticError, ValueError):
        return {**FILL, "df_available": 1.0}
    gm = margins.gain_margin
    out["linear_gain_margin"] = _clip(math.log(gm), -LOG_CAP, LOG_CAP) if gm > 0 else -LOG_CAP
    out["linear_phase_margin"] = _clip(margins.phase_margin_deg / 180.0, -1.0, 1.0)
    stable = [s for s in pred.solutions if s.stable]
    if stable:
        best = stable[-1]
        out["df_cycle"] = 1.0
        out["df_period_miss"] = min(abs(math.log(best.period_s / period_s)), LOG_CAP)
        out["df_amplitude_ratio"] = _clip(math.log(best.amplitude_op / amp), -LOG_CAP, LOG_CAP)
    return out
