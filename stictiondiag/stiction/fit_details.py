"""The method-specific diagnostics of a stiction fit (``StictionFit.details``), typed.

:class:`MvFitDetails` is what :func:`stictiondiag.stiction.segments.estimate_from_mv`
found besides S and J (its least-squares estimate, :class:`LeastSquaresEstimate`, and
its event statistics, :class:`SegmentStatistics`); :class:`HammersteinDetails` is
what :func:`stictiondiag.stiction.hammerstein.fit_hammerstein` found.  ``to_dict``
writes each where the JSON has always had it (``details`` of the fit's JSON).
"""

from __future__ import annotations

from dataclasses import dataclass

from stictiondiag.core.serialize import to_plain as _plain


def _pair(value: tuple | None) -> list | None:
    return None if value is None else list(value)


@dataclass(frozen=True)
class ParameterCounts:
    """Free parameters of the two models a fit compares.

    Attributes
    ----------
    stiction, linear : int
        Parameters of the stiction model and of the linear valve [-].
    """

    stiction: int
    linear: int

    def to_dict(self) -> dict:
        """JSON-able dict (``details["n_parameters"]`` of the JSON)."""
        return {"stiction": int(self.stiction), "linear": int(self.linear)}


@dataclass(frozen=True)
class LeastSquaresEstimate:
    """The valve model fitted to mv by least squares (the reported S and J).

    Attributes
    ----------
    S, J : float
        Least-squares S and J [% of span].
    S_interval, J_interval : tuple of float
        95 % profile-cost intervals (F test) [% of span].
    cost : float
        Sum of squared residuals of the best valve model [% of span]^2.
    cost_by_valve_model : dict of str to float
        The same cost for each valve variant searched, by its name [% of span]^2.
    effective_samples : float
        Effective number of independent samples of the residual [-].
    S_bounded, J_bounded : bool
        The interval ends inside the search range (the data bound it from above).
    """

    S: float
    J: float
    S_interval: tuple[float, float]
    J_interval: tuple[float, float]
    cost: float
    cost_by_valve_model: dict[str, float]
    effective_samples: float
    S_bounded: bool
    J_bounded: bool

    def to_dict(self) -> dict:
        """JSON-able dict (``details["least_squares"]`` of the JSON)."""
        return {
            "S": self.S,
            "J": self.J,
            "S_interval": _pair(self.S_interval),
            "J_interval": _pair(self.J_interval),
            "cost": self.cost,
            "cost_by_valve_model": dict(self.cost_by_valve_model),
            "effective_samples": self.effective_samples,
            "S_bounded": bool(self.S_bounded),
            "J_bounded": bool(self.J_bounded),
        }


@dataclass(frozen=True)
class SegmentStatistics:
    """The event estimate of S and J: statistics over the recorded slips of mv.

    Attributes
    ----------
    S, J : float or None
        Median over the slips used of the per-slip S and J [% of span]; None
        without slips.
    S_interval, J_interval : tuple of float, or None
        95 % bootstrap intervals of the medians [% of span]; None when too few slips.
    S_iqr, J_iqr : tuple of float, or None
        Interquartile ranges of the per-slip S and J [% of span]; None with fewer
        than two slips.
    S_travel_at_reversals : float or None
        Median op travel between a reversal and the next slip [% of span]; None
        without reversals.
    n_slips, n_used, n_reversals : int
        Slips recorded, slips used for the statistics, slips after a reversal [-].
    cost : float or None
        Sum of squared residuals of the valve model at the event S and J
        [% of span]^2; None without an event estimate.
    noise_mv, noise_op : float
        Noise level of mv and of op [% of span].
    quantum_mv : float
        Step of mv's recorded values [% of span].
    """

    S: float | None
    J: float | None
    S_interval: tuple[float, float] | None
    J_interval: tuple[float, float] | None
    S_iqr: tuple[float, float] | None
    J_iqr: tuple[float, float] | None
    S_travel_at_reversals: float | None
    n_slips: int
    n_used: int
    n_reversals: int
    cost: float | None
    noise_mv: float
    noise_op: float
    quantum_mv: float

    def to_dict(self) -> dict:
        """JSON-able dict (``details["segments"]`` of the JSON)."""
        return {
            "S": self.S,
            "J": self.J,
            "S_interval": _pair(self.S_interval),
            "J_interval": _pair(self.J_interval),
            "S_iqr": _pair(self.S_iqr),
            "J_iqr": _pair(self.J_iqr),
            "S_travel_at_reversals": self.S_travel_at_reversals,
            "n_slips": self.n_slips,
            "n_used": self.n_used,
            "n_reversals": self.n_reversals,
            "cost": self.cost,
            "noise_mv": self.noise_mv,
            "noise_op": self.noise_op,
            "quantum_mv": self.quantum_mv,
        }


@dataclass(frozen=True)
class MvFitDetails:
    """What the fit with mv found besides S and J
    (:func:`stictiondiag.stiction.segments.estimate_from_mv`).

    Attributes
    ----------
    play_width : float
        Width of the play operator against op's noise of the fitted valve variant
        (0: none) [% of span].
    bias : float
        Offset between mv and the fitted valve's output [% of span].
    least_squares : LeastSquaresEstimate
        The valve model fitted to mv (the reported S and J).
    segments : SegmentStatistics
        The event estimate over the recorded slips.
    burn_in_samples : int
        Samples before the model valve is in step with the valve, left out of the
        cost [samples].
    noise_cost : float
        The cost mv's measurement noise alone would give [% of span]^2.
    n_parameters : ParameterCounts
        Free parameters of the stiction model and of the linear valve.
    effective_samples : float
        Effective number of independent samples of the residual [-].
    n_samples : int
        Samples in the cost [samples].
    """

    play_width: float
    bias: float
    least_squares: LeastSquaresEstimate
    segments: SegmentStatistics
    burn_in_samples: int
    noise_cost: float
    n_parameters: ParameterCounts
    effective_samples: float
    n_samples: int

    def to_dict(self) -> dict:
        """JSON-able dict (``details`` of the fit's JSON, before the typed fields of
        :class:`~stictiondiag.stiction.fit_result.StictionFit`)."""
        return _plain(
            {
                "play_width": self.play_width,
                "bias": self.bias,
                "least_squares": self.least_squares.to_dict(),
                "segments": self.segments.to_dict(),
                "burn_in_samples": self.burn_in_samples,
                "noise_cost": self.noise_cost,
                "n_parameters": self.n_parameters.to_dict(),
                "effective_samples": self.effective_samples,
                "n_samples": self.n_samples,
            }
        )


@dataclass(frozen=True)
class HammersteinDetails:
    """What the fit without mv found besides S and J
    (:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`).  The fit's cost is
    in units of pv scaled to unit variance ([scaled pv]).

    Attributes
    ----------
    play_width : float
        Width of the play operator against op's noise of the fitted valve variant
        (0: none) [% of op span].
    row_stride : int
        Stride of the rows of the regression [samples].
    rows_left_out : int
        Rows left out of the fit [-].
    dead_time_interval_s : tuple of float
        Interval of the dead times the data cannot tell apart from the estimate [s].
    linear_valve_dead_time_s : float
        Dead time of the linear valve's fit [s].
    highpass_corner_s : float
        Period of the high-pass filter's corner [s].
    search_limit : float
        Largest S searched [% of op span].
    fitted_samples : tuple of int
        First and one past the last sample fitted [samples].
    cost_by_valve_model_coarse : dict of str to float
        Least cost of the coarse search of each valve variant, by its name
        [scaled pv]^2.
    effective_samples, effective_samples_residual : float
        Effective numbers of independent samples used for the intervals and of the
        residual [-].
    noise_cost : float
        The cost pv's white measurement noise alone would give [scaled pv]^2.
    explained : float
        Fraction of the filtered pv's sum of squares the model explains [-].
    moving_fraction : float
        Share of samples the fitted valve moves smoothly with op [-].
    J_confounded_with_gain : bool
        J and the process gain trade off against each other in the fit.
    n_samples : int
        Residual samples [samples].
    n_parameters : ParameterCounts
        Free parameters of the stiction model and of the linear valve.
    n_evaluations : int
        Model evaluations of the search [-].
    note : str or None
        How the loop type changed the structure fitted, in words (a flow loop);
        None when it did not.
    """

    play_width: float
    row_stride: int
    rows_left_out: int
    dead_time_interval_s: tuple[float, float]
    linear_valve_dead_time_s: float
    highpass_corner_s: float
    search_limit: float
    fitted_samples: tuple[int, int]
    cost_by_valve_model_coarse: dict[str, float]
    effective_samples: float
    effective_samples_residual: float
    noise_cost: float
    explained: float
    moving_fraction: float
    J_confounded_with_gain: bool
    n_samples: int
    n_parameters: ParameterCounts
    n_evaluations: int
    note: str | None = None

    def to_dict(self) -> dict:
        """JSON-able dict (``details`` of the fit's JSON, before the typed fields of
        :class:`~stictiondiag.stiction.fit_result.StictionFit`; ``note`` only when
        set)."""
        out: dict = {
            "play_width": self.play_width,
            "row_stride": self.row_stride,
            "rows_left_out": self.rows_left_out,
            "dead_time_interval_s": _pair(self.dead_time_interval_s),
            "linear_valve_dead_time_s": self.linear_valve_dead_time_s,
            "highpass_corner_s": self.highpass_corner_s,
            "search_limit": self.search_limit,
            "fitted_samples": _pair(self.fitted_samples),
            "cost_by_valve_model_coarse": dict(self.cost_by_valve_model_coarse),
            "effective_samples": self.effective_samples,
            "effective_samples_residual": self.effective_samples_residual,
            "noise_cost": self.noise_cost,
            "explained": self.explained,
            "moving_fraction": self.moving_fraction,
            "J_confounded_with_gain": bool(self.J_confounded_with_gain),
            "n_samples": self.n_samples,
            "n_parameters": self.n_parameters.to_dict(),
            "n_evaluations": self.n_evaluations,
        }
        if self.note is not None:
            out["note"] = self.note
        return _plain(out)
