"""The process fit's result: one type for both objectives (Section 4.2.2, Eq. 3, Table 3).

The process ``G(s)`` from the valve position ``mv`` to ``pv`` is a first-order lag with
dead time ``K e^{-theta s} / (tau s + 1)`` or an integrator ``K e^{-theta s} / s``
(Choudhury, Thornhill & Shah 2005, Eq. 3 and Table 3).  It is fitted to one of two
objectives (:class:`Objective`):

* **output error** (:func:`stictiondiag.identification.process.identify_process`): the
  model is simulated from the input alone and the simulation error minimised.  This
  is the process the closed-loop replay runs (:mod:`stictiondiag.replay`); its extras
  are the operating point and the fit measures (:class:`OutputErrorFit`);
* **prediction error** (:func:`stictiondiag.identification.predictor.fit_predictor`):
  the unmeasured load is tracked by a steady-state Kalman filter and pv predicted
  ahead (one step for the structure search, ``horizon`` samples for the judged
  structure).  This is the process the gap diagnosis replays (:mod:`stictiondiag.gap`);
  its extras are the filter's structure, the linear coefficients and the predicted
  pv (:class:`PredictionFit`).

Either way the result is one :class:`ProcessFit`: the objective, the typed process
(:class:`~stictiondiag.models.processes.FOPTD` or
:class:`~stictiondiag.models.processes.Integrating`), the dead time in whole samples
and the objective's own extras.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.filters import integrating_regressors, lag_response, powers
from stictiondiag.core.serialize import to_plain
from stictiondiag.models.processes import FOPTD, Integrating


class Objective(str, Enum):
    """What the process fit minimises."""

    #: The squared error of the response simulated from the input alone.
    OUTPUT_ERROR = "output_error"
    #: The squared error of pv predicted ahead with the load tracked (Kalman filter).
    PREDICTION_ERROR = "prediction_error"


@dataclass(frozen=True)
class ProcessModel:
    """Structure of a prediction-error fit: the process and its load tracking.

    Attributes
    ----------
    pole : float
        Discrete pole of the lag [-] (1: integrating).
    delay : int
        Dead time [samples].
    load_ratio : float
        Load-to-noise variance ratio of the load tracking [-].
    horizon : int
        Prediction horizon [samples]: pv is predicted this far ahead.
    """

    pole: float
    delay: int
    load_ratio: float
    horizon: int = 1


@dataclass(frozen=True)
class OutputErrorFit:
    """The extras of an output-error fit: operating point, initial state, fit measures.

    Attributes
    ----------
    u_bias : float
        Input reference [% of span].  FOPTD: mean of ``u``; integrating: the balance
        input at which pv does not move.
    pv_bias : float
        FOPTD: steady-state pv at ``u = u_bias`` [pv units].  Integrating: pv at the
        first sample of the simulated response [pv units].
    initial_deviation : float
        FOPTD: pv[0] minus the steady state of ``u[0]`` (a decaying free response with
        the time constant) [pv units]; 0 for the integrating model.
    fit_r2 : float
        R^2 of the simulated response against pv, both high-passed against drift
        (``drift_time_constant``), over the samples after the first dead time (before
        it pv answers to inputs from before the record) [-].
    arx_r2 : float
        R^2 of the one-step ARX model at the chosen dead time, on pv differences [-].
    foptd_r2, integrating_r2 : float or None
        ``fit_r2`` of the FOPTD and of the integrating structure, where fitted [-].
    closed_loop_refit_r2 : float or None
        ``fit_r2`` of the dynamics refitted in closed loop
        (:func:`stictiondiag.replay.refit.refine_loop`), where they were [-].
    unfiltered_r2 : float
        R^2 of the simulated response against the raw pv (drift included) [-].
    drift_time_constant : float or None
        Time constant of the drift high-pass [s]; None when the fit was unfiltered.
    """

    u_bias: float
    pv_bias: float
    initial_deviation: float
    fit_r2: float = math.nan
    arx_r2: float = math.nan
    foptd_r2: float | None = None
    integrating_r2: float | None = None
    closed_loop_refit_r2: float | None = None
    unfiltered_r2: float = math.nan
    drift_time_constant: float | None = None

    def candidates(self) -> dict[str, float]:
        """``fit_r2`` of each structure fitted, by name [-]."""
        named = (
            ("foptd", self.foptd_r2),
            ("integrating", self.integrating_r2),
            ("closed_loop_refit", self.closed_loop_refit_r2),
        )
        return {k: v for k, v in named if v is not None}


@dataclass(frozen=True)
class PredictionFit:
    """The extras of a prediction-error fit.

    Attributes
    ----------
    pv : ndarray
        Prediction of pv, ``model.horizon`` samples ahead [pv units].
    model : ProcessModel
        Pole [-], dead time [samples], load-to-noise variance ratio [-] and horizon
        [samples] of the fitted structure.
    coef : ndarray
        Linear coefficients: the input's gains at the dead times ``delay`` and
        ``delay + 1`` [pv units / % of span per sample], then those of any extra
        columns [-].
    """

    pv: np.ndarray
    model: ProcessModel
    coef: np.ndarray


@dataclass(frozen=True)
class ProcessFit:
    """A process from valve position (or any input ``u``) to pv, fitted to an objective.

    Attributes
    ----------
    objective : Objective
        Output error or prediction error.
    process : FOPTD or Integrating
        Gain [pv units / % of span] (integrating: [pv units / (% of span s)]), time
        constant [s], dead time [s].  Output error: the dead time is a whole number
        of samples; prediction error: it carries the fraction between the two
        adjacent dead times whose gains were fitted.
    dead_time_samples : int
        Dead time [samples] (prediction error: the shorter of the two adjacent ones).
    detail : OutputErrorFit or PredictionFit
        The objective's own results (:attr:`output_error`, :attr:`prediction`).
    """

    objective: Objective
    process: FOPTD | Integrating
    dead_time_samples: int
    detail: OutputErrorFit | PredictionFit

    def __post_init__(self) -> None:
        kind = OutputErrorFit if self.objective is Objective.OUTPUT_ERROR else PredictionFit
        if not isinstance(self.detail, kind):
            raise UsageError(
                f"a {self.objective.value} process fit takes a {kind.__name__}, "
                f"got {type(self.detail).__name__}"
            )

    @property
    def integrating(self) -> bool:
        """The process is the integrating model."""
        return isinstance(self.process, Integrating)

    @property
    def output_error(self) -> OutputErrorFit:
        """The output-error extras (an output-error fit only)."""
        if not isinstance(self.detail, OutputErrorFit):
            raise UsageError("a prediction-error process fit has no output-error extras")
        return self.detail

    @property
    def prediction(self) -> PredictionFit:
        """The prediction-error extras (a prediction-error fit only)."""
        if not isinstance(self.detail, PredictionFit):
            raise UsageError("an output-error process fit has no prediction extras")
        return self.detail

    def simulate(self, u: np.ndarray, dt: float) -> np.ndarray:
        """Open-loop response of an output-error fit to ``u`` [pv units] (same length)."""
        oe = self.output_error
        u = np.asarray(u, dtype=float)
        d = self.dead_time_samples
        if isinstance(self.process, Integrating):
            return integrating_regressors(u, d, dt) @ np.array(
                [oe.pv_bias, self.process.gain, -self.process.gain * oe.u_bias]
            )
        a = math.exp(-dt / self.process.time_constant)
        z = lag_response(u, d, a)
        free = oe.initial_deviation * powers(a, 0, u.size)
        return oe.pv_bias + self.process.gain * (z - oe.u_bias) + free

    def to_dict(self) -> dict:
        """JSON-able dict.  Output error: the process parameters plus biases and fit
        measures.  Prediction error: the readable parameters of the process and of
        its load tracking."""
        if isinstance(self.detail, PredictionFit):
            m = self.detail.model
            p = self.process
            return {
                "integrating": self.integrating,
                "gain": p.gain,
                "time_constant_s": p.time_constant if isinstance(p, FOPTD) else None,
                "dead_time_s": p.dead_time,
                "load_to_noise_ratio": m.load_ratio,
                "horizon_samples": m.horizon,
            }
        oe = self.detail
        out = {
            k: to_plain(v) if isinstance(v, float) else v for k, v in self.process.to_dict().items()
        }
        out.update(
            {
                "u_bias": to_plain(oe.u_bias),
                "pv_bias": to_plain(oe.pv_bias),
                "fit_r2": to_plain(oe.fit_r2),
                "arx_r2": to_plain(oe.arx_r2),
                "dead_time_samples": int(self.dead_time_samples),
                "candidates": {k: to_plain(v) for k, v in oe.candidates().items()},
                "unfiltered_r2": to_plain(oe.unfiltered_r2),
                "drift_time_constant_s": to_plain(oe.drift_time_constant),
            }
        )
        return out
