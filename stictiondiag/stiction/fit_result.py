"""The result of a stiction fit: S and J with their intervals and what the fit found.

:class:`StictionFit` is what both estimators return
(:func:`stictiondiag.stiction.segments.estimate_from_mv` with mv,
:func:`stictiondiag.stiction.hammerstein.fit_hammerstein` from op and pv; the shared
toolbox is :mod:`stictiondiag.stiction.valvefit`).  Its parts are typed: how well
the data determine S and J (:class:`Determinacy`, an enum), and for a fit without mv
the sign its process gain was held to (:class:`GainSign`), the valve's state where
its model starts (:class:`ValveStart`), the refit with drift states
(:class:`DriftComparison`) and the disturbance model used (:class:`DisturbanceChoice`).
``details`` holds the remaining method-specific diagnostics, typed per method
(:class:`~stictiondiag.stiction.fit_details.MvFitDetails`,
:class:`~stictiondiag.stiction.fit_details.HammersteinDetails`); ``to_dict`` writes
all of them where the JSON has always had them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from stictiondiag.core.serialize import to_plain as _plain
from stictiondiag.stiction.fit_details import HammersteinDetails, MvFitDetails


class Determinacy(StrEnum):
    """How well the data determine S or J (:func:`determinacy`).

    The value is the phrase the JSON and the reports carry; code reads the member
    (``Determinacy(text)``, :attr:`poor`, :attr:`open`), never the words.
    """

    WELL = "well determined"
    MODERATE = "moderately determined"
    POOR = "poorly determined"
    OPEN = "poorly determined (interval reaches the search limit)"

    @property
    def poor(self) -> bool:
        """Values across the interval fit the data alike: poorly determined."""
        return self in (Determinacy.POOR, Determinacy.OPEN)

    @property
    def open(self) -> bool:
        """The interval reaches the search limit: the data give no upper bound."""
        return self is Determinacy.OPEN

    @classmethod
    def of(cls, value: object) -> Determinacy | None:
        """The member for a JSON value (None for a missing or unknown one)."""
        try:
            return cls(str(value)) if value is not None else None
        except ValueError:
            return None


def poorly_determined(determinacy: Determinacy | None, value, interval) -> bool:
    """The data determine a parameter poorly: its :class:`Determinacy` says so,
    unless estimate and interval are all zero (a zero estimate cannot pass the
    width-to-value test of :func:`determinacy`; the data pin it at zero).  The one
    rule of the figures and the findings (:meth:`StictionFit.poorly_determined`) and of
    the report's index (:meth:`stictiondiag.row.LoopRow.poorly_determined`)."""
    if determinacy is None or not determinacy.poor:
        return False
    values = [value, *(interval or (None, None))]
    return not all(isinstance(v, int | float) and v == 0 for v in values)


@dataclass(frozen=True)
class GainSign:
    """What the sign of the process gain did to a fit without mv
    (:func:`stictiondiag.stiction.hammerstein.search.gain_sign_evidence`).

    Attributes
    ----------
    required : int
        +1 or -1, the sign the process gain (pv per op) was held to, the controller's
        (a loop under control has ``Kc Kp > 0``); 0: free.
    binding_at_estimate : bool
        At the estimate, the linear part fitted with the sign free has a process gain
        of the other sign.
    consistent_fit : bool
        The fitted process gain is not zero (with the sign held, a record no valve
        output drives with that sign is fitted with gains of zero).
    controller_fit_r2 : float or None
        R^2 of the controller's law the sign comes from [-]; None when the fit was not
        given the controller's sign by :func:`stictiondiag.analysis.estimate_stiction`.
    """

    required: int
    binding_at_estimate: bool
    consistent_fit: bool
    controller_fit_r2: float | None = None

    def to_dict(self) -> dict:
        """JSON-able dict (``controller_fit_r2`` where the controller's law was read)."""
        out: dict = {
            "required": int(self.required),
            "binding_at_estimate": bool(self.binding_at_estimate),
            "consistent_fit": bool(self.consistent_fit),
        }
        if self.controller_fit_r2 is not None:
            out["controller_fit_r2"] = _plain(self.controller_fit_r2)
        return out


@dataclass(frozen=True)
class ValveStart:
    """The fitted valve's state where its model starts (a fit without mv begins at
    the first clear extreme of op, where a sticky valve's state is known).

    Attributes
    ----------
    sample : int
        First sample the valve model covers [-].
    offset : float
        How far op had come back from the point where the valve stuck [% of span].
    direction : float
        Direction of the valve's last movement (+1, -1; 0 when not known) [-].
    """

    sample: int
    offset: float
    direction: float


@dataclass(frozen=True)
class DriftComparison:
    """Both valves of a fit without mv refitted with drift states estimated alongside
    (:mod:`stictiondiag.stiction.hammerstein`, "The disturbance model").

    Attributes
    ----------
    n_states : int
        Drift states [-].
    cutoff_cycles : float
        Highest drift frequency, in cycles of the loop's oscillation [-].
    cost, linear_cost : float
        Sum of squared residuals of the stiction and of the linear valve with the
        drift states [scaled pv]^2.
    effective_samples : float
        Effective number of independent samples of the stiction model's residual [-].
    block_sse_stiction, block_sse_linear : ndarray
        The two residuals' sums of squares per block of the record [scaled pv]^2.
    """

    n_states: int
    cutoff_cycles: float
    cost: float
    linear_cost: float
    effective_samples: float
    block_sse_stiction: np.ndarray
    block_sse_linear: np.ndarray

    @property
    def improvement(self) -> float | None:
        """Fraction of the linear valve's residual the stiction model removes [-]."""
        return 1.0 - self.cost / self.linear_cost if self.linear_cost > 0 else None

    def to_dict(self) -> dict:
        """JSON-able dict (``details["drift_model"]`` of the JSON)."""
        return {
            "n_states": int(self.n_states),
            "cutoff_cycles": self.cutoff_cycles,
            "cost": self.cost,
            "linear_cost": self.linear_cost,
            "improvement": self.improvement,
            "effective_samples": self.effective_samples,
            "block_sse": {
                "stiction": np.asarray(self.block_sse_stiction).tolist(),
                "linear": np.asarray(self.block_sse_linear).tolist(),
            },
        }


@dataclass(frozen=True)
class BlockCosts:
    """Both valves' residual sums of squares per block of about one cycle: what the
    verdict's block bootstrap resamples
    (:func:`stictiondiag.stiction.verdict.improvement_support`).

    Attributes
    ----------
    samples : int
        Block length [samples].
    stiction, linear : ndarray
        Sum of squared residuals of the stiction and of the linear valve per block
        [units of ``StictionFit.cost``].
    """

    samples: int
    stiction: np.ndarray
    linear: np.ndarray


@dataclass(frozen=True)
class ArchiveResolution:
    """What the record's resolution hides of a valve fitted on mv
    (:func:`stictiondiag.stiction.resolution.archive_resolution`): a quantised mv or
    the deadband of a compressed archive make a healthy valve look like stick-slip.

    Attributes
    ----------
    mv_quantum : float
        Step of mv's values [% of span].
    mv_deadband, op_deadband : float
        Archive deadbands of mv and op [% of span].
    S_hidden, J_hidden : float
        Largest S and J a healthy valve so recorded shows [% of span].
    within : bool
        The fitted S and J lie within them.
    """

    mv_quantum: float
    mv_deadband: float
    op_deadband: float
    S_hidden: float
    J_hidden: float
    within: bool

    def to_dict(self) -> dict:
        """JSON-able dict (``details["resolution"]`` of the JSON)."""
        return {
            "mv_quantum": self.mv_quantum,
            "mv_deadband": self.mv_deadband,
            "op_deadband": self.op_deadband,
            "S_hidden": self.S_hidden,
            "J_hidden": self.J_hidden,
            "within": bool(self.within),
        }


@dataclass(frozen=True)
class DisturbanceChoice:
    """The disturbance model a fit without mv used (``highpass`` or ``drift``) and why."""

    model: str
    reason: str


@dataclass(frozen=True)
class LinearPart:
    """The linear process of a fit without mv (the Hammerstein model's linear block).

    Attributes
    ----------
    structure : str
        ``integrating`` or ``self-regulating``.
    dead_time_s : float
        Dead time [s].
    time_constant_s : float
        Time constant of the lag [s].
    direct_gain, lag_gain : float
        Gains of the direct and the lagged valve column, in the fit's units (pv scaled
        to unit variance per cycle travel of op) [-].
    gain_units : float
        pv units per % of op [per sample, integrating] for one unit of the gains.
    """

    structure: str
    dead_time_s: float
    time_constant_s: float
    direct_gain: float
    lag_gain: float
    gain_units: float


@dataclass(frozen=True)
class StictionFit:
    """Estimated stiction parameters of the data-driven model (Section 5.1).

    Attributes
    ----------
    S : float
        Deadband plus stickband [% of op span].
    J : float
        Slip jump [% of op span] (the model's output axis is in the units of op).
    S_scaled, J_scaled : float
        S and J divided by the standard deviation of op [units of scaled op, as in the
        mean-centred unit-variance plots of Section 3].
    S_interval, J_interval : tuple of float, or None
        Interval [% of op span] of the values the data cannot tell apart from the
        estimate (see ``interval_method``); None when not determined.
    method : str
        ``"mv_segments"`` (valve position recorded) or ``"hammerstein"`` (op and pv).
    mv_model : ndarray
        Fitted valve position for the recorded op [% of span].
    n_slips : int
        Number of slips (breakaways) of the fitted valve over the record [-].
    cost : float
        Sum of squared residuals of the stiction model (mv fit: [% of span]^2;
        Hammerstein fit: [scaled pv]^2, pv scaled to unit variance).
    linear_cost : float
        The same cost with a linear valve (S = J = 0), fitted the same way.
    details : MvFitDetails, HammersteinDetails or None
        Method-specific diagnostics: the least-squares and the event estimates of the
        mv method (:class:`MvFitDetails`), the search and the residual of a fit without
        mv (:class:`HammersteinDetails`); None when the estimator gave none.
    S_determinacy, J_determinacy : Determinacy or None
        How well the data determine S and J; None when the estimator did not say.
    gain_sign : GainSign or None
        What the sign of the process gain did to a fit without mv; None for the mv
        method.
    valve_model : str or None
        The valve model variant fitted (:func:`valve_variants`: Choudhury's or Kano's
        flowchart, with or without the play operator); None when the fit does not say.
    valve_start : ValveStart or None
        The fitted valve's state where its model starts (fit without mv); None for
        the mv method.
    drift : DriftComparison or None
        Both valves refitted with drift states (fit without mv); None for the mv
        method.
    disturbance : DisturbanceChoice or None
        The disturbance model the fit without mv used, and why; None for the mv
        method.
    linear_part : LinearPart or None
        The linear process of a fit without mv; None for the mv method.
    period_samples : float or None
        The cycle period that set the time scales of a fit without mv [samples];
        None for the mv method.
    interval_method : str or None
        How ``S_interval`` and ``J_interval`` were found, in words.
    block_costs : BlockCosts or None
        Both valves' residuals per cycle block; None when the estimator gave none.
    resolution : ArchiveResolution or None
        What the record's resolution hides (mv method, an archive or S and J within
        it); None otherwise.
    """

    S: float
    J: float
    S_scaled: float
    J_scaled: float
    S_interval: tuple[float, float] | None
    J_interval: tuple[float, float] | None
    method: str
    mv_model: np.ndarray = field(repr=False)
    n_slips: int
    cost: float
    linear_cost: float
    details: MvFitDetails | HammersteinDetails | None = field(default=None, repr=False)
    S_determinacy: Determinacy | None = None
    J_determinacy: Determinacy | None = None
    gain_sign: GainSign | None = None
    valve_model: str | None = None
    valve_start: ValveStart | None = None
    drift: DriftComparison | None = None
    disturbance: DisturbanceChoice | None = None
    linear_part: LinearPart | None = None
    period_samples: float | None = None
    interval_method: str | None = None
    block_costs: BlockCosts | None = None
    resolution: ArchiveResolution | None = None

    def determinacy_of(self, sym: str) -> Determinacy | None:
        """How well the data determine ``sym`` (``"S"`` or ``"J"``); None when the
        estimator did not say."""
        return self.S_determinacy if sym == "S" else self.J_determinacy

    def poorly_determined(self, sym: str) -> bool:
        """``sym`` is poorly determined (:func:`poorly_determined`)."""
        return poorly_determined(
            self.determinacy_of(sym), getattr(self, sym), getattr(self, f"{sym}_interval")
        )

    @property
    def valve_family(self) -> str:
        """The flowchart of the fitted valve, ``"choudhury"`` (Fig. 10) or ``"kano"``
        (Kano et al. 2004), with or without the play operator against op's noise
        (:attr:`valve_model`); ``"choudhury"`` when the fit does not say.  The
        replay runs the valve that was fitted."""
        name = self.valve_model or "choudhury"
        return "kano" if name.startswith("kano") else "choudhury"

    @property
    def improvement(self) -> float | None:
        """Fraction of the linear valve's residual removed by the stiction model [-]."""
        if not (self.linear_cost > 0 and math.isfinite(self.linear_cost)):
            return None
        return 1.0 - self.cost / self.linear_cost

    @property
    def improvement_drift(self) -> float | None:
        """The improvement with drift states estimated alongside both valves [-].

        Hammerstein fit only (:attr:`drift`, see "The disturbance model" in
        :mod:`stictiondiag.stiction.hammerstein`): the share of the linear valve's
        residual the stiction model removes once slow load, set-point and
        operating-point drifts are fitted too.  None without it.
        """
        value = None if self.drift is None else self.drift.improvement
        return None if value is None else float(value)

    def to_dict(self) -> dict:
        """JSON-able summary (no time series; ``mv_model`` is left out)."""
        return _plain(
            {
                "S": self.S,
                "J": self.J,
                "S_scaled": self.S_scaled,
                "J_scaled": self.J_scaled,
                "S_interval": None if self.S_interval is None else list(self.S_interval),
                "J_interval": None if self.J_interval is None else list(self.J_interval),
                "method": self.method,
                "n_slips": self.n_slips,
                "cost": self.cost,
                "linear_cost": self.linear_cost,
                "improvement": self.improvement,
                "details": self._details_dict(),
            }
        )

    def _details_dict(self) -> dict:
        """``details`` with the valve model, its start, the determinacy and the gain
        sign, as the JSON carries them."""
        out = {} if self.details is None else self.details.to_dict()
        if self.valve_model is not None:
            out["valve_model"] = self.valve_model
        if self.valve_start is not None:
            out["start_sample"] = int(self.valve_start.sample)
            out["start_offset"] = self.valve_start.offset
            out["start_direction"] = self.valve_start.direction
        words = {"S": self.S_determinacy, "J": self.J_determinacy}
        if any(w is not None for w in words.values()):
            out["determinacy"] = {k: w.value for k, w in words.items() if w is not None}
        if self.linear_part is not None:
            lp = self.linear_part
            out["structure"] = lp.structure
            out["dead_time_s"] = lp.dead_time_s
            out["time_constant_s"] = lp.time_constant_s
            out["process_gains"] = {"direct": lp.direct_gain, "lag": lp.lag_gain}
            out["gain_units"] = lp.gain_units
        if self.gain_sign is not None:
            out["gain_sign"] = self.gain_sign.to_dict()
        if self.drift is not None:
            out["drift_model"] = self.drift.to_dict()
        if self.disturbance is not None:
            out["disturbance_model"] = {
                "model": self.disturbance.model,
                "reason": self.disturbance.reason,
            }
        if self.period_samples is not None:
            out["period_samples"] = self.period_samples
        if self.interval_method is not None:
            out["interval_method"] = self.interval_method
        if self.block_costs is not None:
            out["block_samples"] = self.block_costs.samples
            out["block_sse"] = {
                "stiction": np.asarray(self.block_costs.stiction).tolist(),
                "linear": np.asarray(self.block_costs.linear).tolist(),
            }
        if self.resolution is not None:
            out["resolution"] = self.resolution.to_dict()
        return out
