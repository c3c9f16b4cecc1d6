"""The result of a gap diagnosis (:func:`stictiondiag.gap.diagnose.diagnose_gap`).

A :class:`GapDiagnosis` holds the gap before and after the winning effect, every
candidate effect (:class:`Candidate`, with its effect's own typed parameters,
:class:`stictiondiag.gap.effects.base.EffectParams`), where the gap lies
(:class:`stictiondiag.gap.breakdown.Breakdown`), the base replay's parameters
(:class:`GapBase`) and the series for plots (:class:`GapSeries`), each a frozen
dataclass with its units.  ``GapDiagnosis.to_dict`` writes the ``gap`` entry of
``stiction analyze --json`` and the output of ``stiction gap --json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.gap.breakdown import Breakdown, PerSignal
from stictiondiag.gap.context import LoopSignals, ReplayContext
from stictiondiag.gap.effects.base import BaseFit, EffectParams
from stictiondiag.gap.effects.valve import ValveLogic
from stictiondiag.identification.controller import ControllerReplay
from stictiondiag.identification.process_result import ProcessFit


@dataclass(frozen=True)
class Candidate:
    """One effect added to the replay.

    Attributes
    ----------
    effect : str
        Effect name (see :data:`stictiondiag.gap.effects.EFFECTS`).
    variant : str
        Form that fitted best (e.g. ``step`` for a time-varying stiction).
    after : float
        Gap with the effect added, fitted on the whole record [%].
    shrink_pct : float
        Reduction of the gap [% of the gap before].
    params : EffectParams
        Fitted parameters (the effect's own type, units per field).
    n_params : int
        Parameters beyond the base model's.
    heldout : float
        Gap on held-out data (fitted on the other half) [%].
    penalised_score : float
        Held-out gap with the penalty for extra parameters added [%].
    accepted : bool
        The held-out improvement over the base model exceeds the penalty.
    """

    effect: str
    variant: str
    after: float
    shrink_pct: float
    params: EffectParams
    n_params: int
    heldout: float
    penalised_score: float
    accepted: bool

    def to_dict(self) -> dict:
        return to_plain(
            {
                "effect": self.effect,
                "variant": self.variant,
                "after": self.after,
                "shrink_pct": self.shrink_pct,
                "params": self.params.to_dict(),
                "n_params": self.n_params,
                "heldout": self.heldout,
                "penalised_score": self.penalised_score,
                "accepted": self.accepted,
            }
        )


@dataclass(frozen=True)
class BaseValve:
    """The base replay's two-parameter valve (Section 5.1, Fig. 10).

    Attributes
    ----------
    S, J : float
        Deadband plus stickband and slip jump [% of span].
    logic : ValveLogic
        The stuck-phase logic replayed.
    initial_direction : float
        Direction of travel before the record (+1 opening, -1 closing).
    """

    S: float
    J: float
    logic: ValveLogic
    initial_direction: float

    def to_dict(self) -> dict:
        return to_plain(
            {
                "S": self.S,
                "J": self.J,
                "logic": self.logic,
                "initial_direction": self.initial_direction,
            }
        )


@dataclass(frozen=True)
class GapBase:
    """The base replay's parameters: valve, process, controller, noise floors.

    Attributes
    ----------
    valve : BaseValve or None
        None when mv is not recorded.
    process : ProcessFit
        The process replay (prediction error, load tracked): gain, time constant [s],
        dead time [s], load-to-noise ratio [-], horizon [samples].
    controller : ControllerReplay
        The PI law that replays op.
    noise_floor : PerSignal of float
        Each signal's noise floor over the variance of its cycle-scale part, ``N_s /
        V_s`` [-].
    judged_from_sample : int
        First sample the gap is judged on [-].
    """

    valve: BaseValve | None
    process: ProcessFit
    controller: ControllerReplay
    noise_floor: PerSignal[float]
    judged_from_sample: int

    @classmethod
    def of(cls, ctx: ReplayContext, base: BaseFit, floors: dict) -> GapBase:
        """The parameters of the base fit ``base`` on the context ``ctx``, with the
        noise floors ``floors`` [units^2] the gap was measured with."""
        valve = base.valve
        return cls(
            valve=None
            if valve is None
            else BaseValve(valve.S, valve.J, valve.logic, valve.initial_direction),
            process=base.process,
            controller=base.controller,
            noise_floor=PerSignal.of({s: floors[s] / ctx.norm[s] for s in floors}),
            judged_from_sample=int(np.argmax(ctx.w_eval > 0)),
        )

    def to_dict(self) -> dict:
        return {
            "valve": None if self.valve is None else self.valve.to_dict(),
            "process": to_plain(self.process.to_dict()),
            "controller": self.controller.to_dict(),
            "noise_floor": self.noise_floor.to_dict(),
            "judged_from_sample": int(self.judged_from_sample),
        }


@dataclass(frozen=True, eq=False)
class GapSeries:
    """Recorded signals and the driven replays before and after the winning effect,
    one value per sample, in the units of the record.

    Attributes
    ----------
    time : ndarray
        Time from the first sample [s].
    op, op_before, op_after : ndarray
        Controller output: recorded, replayed [% of span].
    mv, mv_before, mv_after : ndarray or None
        Valve position [% of span]; None without a recorded mv.
    pv, pv_before, pv_after : ndarray
        Process variable [pv units].
    """

    time: np.ndarray
    op: np.ndarray
    op_before: np.ndarray
    op_after: np.ndarray
    mv: np.ndarray | None
    mv_before: np.ndarray | None
    mv_after: np.ndarray | None
    pv: np.ndarray
    pv_before: np.ndarray
    pv_after: np.ndarray

    @classmethod
    def of(cls, sig: LoopSignals, before: dict, after: dict) -> GapSeries:
        """The recorded signals of ``sig`` and the replays ``before`` and ``after`` (by
        signal name), op and mv shifted back into the units of the record."""
        series: dict[str, np.ndarray | None] = {"time": np.arange(sig.n) * sig.dt}
        for s in ("op", "mv", "pv"):
            # op and mv back in the units of the record (signals_of shifted them).
            shift = sig.offset if s in ("op", "mv") else 0.0
            for key, x in (
                (s, getattr(sig, s)),
                (f"{s}_before", before.get(s)),
                (f"{s}_after", after.get(s)),
            ):
                series[key] = None if x is None else np.asarray(x) - shift
        return cls(**series)  # type: ignore[arg-type]

    def columns(self) -> dict[str, np.ndarray]:
        """The series present, by name, in field order."""
        return {
            f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None
        }

    def to_pandas(self):
        """One row per sample, one column per series present."""
        import pandas as pd

        return pd.DataFrame(self.columns())


@dataclass(frozen=True)
class GapDiagnosis:
    """Sim-to-real gap of a loop and the effect that explains it.

    Attributes
    ----------
    metric : str
        Name of the gap measure (:data:`stictiondiag.gap.diagnose.METRIC_NAME`).
    definition : str
        Its definition (:data:`stictiondiag.gap.diagnose.METRIC_DEFINITION`).
    before : float
        Gap of the two-parameter replay [%].
    after : float
        Gap with the winning effect added [%] (= before for ``none``).
    shrink_pct : float
        Reduction of the gap by the winning effect [% of before].
    effect : str
        The winning effect, ``none`` when the two-parameter model explains the data
        to within its noise or no effect beats it on held-out data.
    runner_up : str or None
        Second-best candidate (accepted effects by evidence, then ``none``, then the
        rest by penalised score).
    margin : float
        How clearly the winner won [%]: the share of the winner's penalised gain over
        the base model that the runner-up does not reach (100 when the runner-up gains
        nothing; between two accepted effects, the share of the winner's evidence the
        runner-up lacks); for ``none``, how far the best candidate's penalised score lies
        above the base model's error, in % of it.
    candidates : tuple of Candidate
        Every assessed effect, in the order of ``runner_up``.
    breakdown : Breakdown or None
        Where the gap lies, before and after: by signal, valve phase, frequency,
        time and feature (None only in results built by hand).
    not_assessed : tuple of str
        Effects that cannot be assessed with the data (e.g. valve-side effects
        without a recorded mv).
    within_noise : tuple of str
        Effects not fitted because they cannot lower the gap: they act on mv alone and
        the base replay of mv is already within its noise (its excess is 0), so no
        fit of theirs can be named
        (:func:`stictiondiag.gap.selection.mv_within_noise`).
    heldout_before : float
        Gap of the two-parameter replay on held-out data [%] (the score of ``none``).
    base : GapBase or None
        The base replay's parameters: S and J [% of span], valve logic, process,
        controller, noise floors (None only in results built by hand).
    series : GapSeries or None
        Time series for plots: time [s], the recorded op, mv, pv and the replays
        before and after (None only in results built by hand).
    """

    metric: str
    definition: str
    before: float
    after: float
    shrink_pct: float
    effect: str
    runner_up: str | None
    margin: float
    candidates: tuple[Candidate, ...]
    breakdown: Breakdown | None = None
    not_assessed: tuple[str, ...] = ()
    within_noise: tuple[str, ...] = ()
    heldout_before: float = 0.0
    base: GapBase | None = None
    series: GapSeries | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-able summary (no time series): the keys of ``gap`` in the analysis JSON."""
        return to_plain(
            {
                "metric": self.metric,
                "definition": self.definition,
                "units": "%",
                "before": self.before,
                "after": self.after,
                "shrink_pct": self.shrink_pct,
                "effect": self.effect,
                "runner_up": self.runner_up,
                "margin": self.margin,
                "candidates": [c.to_dict() for c in self.candidates],
                "breakdown": {} if self.breakdown is None else self.breakdown.to_dict(),
                "not_assessed": list(self.not_assessed),
                "within_noise": list(self.within_noise),
                "heldout_before": self.heldout_before,
                "base": {} if self.base is None else self.base.to_dict(),
            }
        )

    def to_pandas(self):
        """The recorded signals and the replays before and after, one row per sample."""
        import pandas as pd

        return pd.DataFrame() if self.series is None else self.series.to_pandas()

    def plot(self):
        """Where the gap lies (:func:`stictiondiag.plotting.gap.plot_gap_breakdown`)."""
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.gap import plot_gap_breakdown

        return plot_gap_breakdown(self)

    def figures(self) -> dict:
        """Figures by name: ``gap_breakdown`` and ``gap_replay``."""
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.gap import (
            plot_gap_breakdown,
            plot_gap_replay,
        )

        return {"gap_breakdown": plot_gap_breakdown(self), "gap_replay": plot_gap_replay(self)}
