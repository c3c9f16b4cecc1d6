"""The orchestrator: one loop's data in, the stiction diagnosis out.

:func:`analyze` follows the paper's procedure for plant data (Choudhury, Thornhill &
Shah 2005):

1. the tags, scaled to mean-centred unit variance for plots and comparisons
   (Section 3);
2. is there an oscillation at all (the limit cycles of Sections 4.2.2 and 5.3);
3. S and J of the data-driven model (Section 5.1): from the stick and slip segments
   of the mv-op plot when mv is recorded, otherwise by fitting the valve model and a
   linear process together to op and pv;
4. the verdict: does the stiction model explain the oscillation better than a linear
   valve;
5. the closed-loop replay of the fitted valve with the identified controller and
   process, compared with the data;
6. the sim-to-real gap: where the replay departs from the data and which unmodelled
   effect explains the departure.

Every step is a pure function of its own module; this module only calls them in
order and gathers their results in :class:`Analysis`.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from stictiondiag.core.errors import (
    DataError,
    StictionError,
)
from stictiondiag.io.tags import (
    Tags,
    read_tags,
)
from stictiondiag.signals.oscillation import (
    MIN_CYCLES,
    REGULARITY_THRESHOLD,
    Oscillation,
    detect_oscillation,
    dominant_period,
)

#: Loop types where pv is (nearly) proportional to the valve opening (Section 5.3.1:
#: "in liquid flow loops ... pv can be taken to be proportional to valve opening").
#: Without mv the fit records it and uses the self-regulating structure
#: (:mod:`stictiondiag.stiction.hammerstein`, "The linear part").
FLOW_LIKE = frozenset({"flow"})


@dataclass(frozen=True)
class AnalysisConfig:
    """Options of :func:`analyze`.

    Attributes
    ----------
    gap : bool
        Run the sim-to-real gap diagnosis (the slowest step).
    replay : bool
        Run the closed-loop replay (needed by the gap diagnosis).
    """

    gap: bool = True
    replay: bool = True


@dataclass(frozen=True)
class Analysis:
    """Everything :func:`analyze` found for one loop.

    Attributes
    ----------
    tags : Tags
        The data as analysed (uniformly sampled, op and mv in % of span).
    oscillation : Oscillation
        Oscillation of pv (period [s], amplitude [pv units], regularity); of the
        control error ``sp - pv`` when only that shows it (a set-point change hides
        the cycle of pv; noted in ``warnings``).
    oscillation_op : Oscillation
        Oscillation of op (amplitude in % of span).
    fit : StictionFit
        S and J [% of op span] with intervals and method.
    verdict : Verdict
        stiction / no_stiction / inconclusive, with confidence and reasons.
    replay : Replay or None
        Closed-loop reconstruction, None when it could not be built (see warnings).
    gap : GapDiagnosis or None
        Sim-to-real gap diagnosis, None when not run or not possible.
    warnings : tuple of str
        Data-quality and analysis warnings, in the order they arose.
    """

    tags: Tags
    oscillation: Oscillation
    oscillation_op: Oscillation
    fit: Any
    verdict: Any
    replay: Any = None
    gap: Any = None
    warnings: tuple[str, ...] = field(default_factory=tuple)

    @property
    def loop(self) -> str:
        """Loop name: the source file's stem."""
        return Path(str(self.tags.source)).stem or "loop"

    def to_dict(self) -> dict:
        """JSON-able summary (the ``--json`` output of ``stiction analyze``)."""
        tags = self.tags
        stiction = _clean(self.fit.to_dict())
        stiction["units"] = "% of op span"
        stiction.update(_clean(self.verdict.to_dict()))
        return {
            "source": str(tags.source),
            "loop": self.loop,
            "tags": {
                "names": dict(tags.names),
                "n_samples": int(tags.n),
                "ts_s": float(tags.ts),
                "duration_s": float(tags.n * tags.ts),
                "loop_type": tags.loop_type,
                "integrating": bool(tags.integrating),
                "has_mv": tags.mv is not None,
                "has_sp": tags.sp is not None,
            },
            "oscillation": {
                "pv": _clean(self.oscillation.to_dict()),
                "op": _clean(self.oscillation_op.to_dict()),
            },
            "stiction": stiction,
            "replay": None if self.replay is None else _clean(self.replay.to_dict()),
            "gap": None if self.gap is None else _clean(self.gap.to_dict()),
            "warnings": list(self.warnings),
        }

    def summary_row(self) -> dict:
        """One flat row for plant-wide tables (``stiction scan``)."""
        d = self.to_dict()
        st = d["stiction"]
        gap = d["gap"] or {}
        rep = d["replay"] or {}
        return {
            "loop": self.loop,
            "source": d["source"],
            "loop_type": d["tags"]["loop_type"],
            "n_samples": d["tags"]["n_samples"],
            "has_mv": d["tags"]["has_mv"],
            "oscillating": bool(self.oscillation.present),
            "period_s": d["oscillation"]["pv"].get("period_s"),
            "verdict": st.get("status"),
            "detected": st.get("detected"),
            "confidence": st.get("confidence"),
            "probability": st.get("probability"),
            "S": st.get("S"),
            "J": st.get("J"),
            "S_lo": (st.get("S_interval") or [None, None])[0],
            "S_hi": (st.get("S_interval") or [None, None])[1],
            "J_lo": (st.get("J_interval") or [None, None])[0],
            "J_hi": (st.get("J_interval") or [None, None])[1],
            "method": st.get("method"),
            "replay_fit_pv": (rep.get("fit") or {}).get("pv"),
            "gap_effect": gap.get("effect"),
            "gap_shrink_pct": gap.get("shrink_pct"),
            "n_warnings": len(self.warnings),
            "flags": "; ".join(self.warnings),
        }

    def figures(self) -> dict:
        """Figures by name: ``phase`` (Figs. 3-6 style), ``reconstruction``, gap plots."""
        return {name: build() for name, build in self.figure_builders().items()}

    def figure_builders(self) -> dict:
        """The functions that build :meth:`figures`, by name, without building them.

        Each is a module-level function bound to its data (picklable, so that a
        worker process started before the analysis can draw it); none imports
        matplotlib before it is called.
        """
        builders = {"phase": functools.partial(_phase_figure, self)}
        if self.replay is not None:
            # Looked up when drawn: the replay may still be on its way from a worker.
            builders["reconstruction"] = functools.partial(_reconstruction_figure, self)
        if self.gap is not None and hasattr(self.gap, "figures"):
            # The figures of GapDiagnosis.figures(), one at a time.
            builders["gap_breakdown"] = functools.partial(_gap_figure, "breakdown", self.gap)
            builders["gap_replay"] = functools.partial(_gap_figure, "replay", self.gap)
        return builders

    def figure_file(self, name: str) -> str:
        """File name of the figure ``name``: ``<loop>_<name>.png``."""
        return f"{self.loop}_{name}.png"


def _replay(tags: Tags, fit):
    """Step 5, the closed-loop replay (:func:`stictiondiag.replay.closed_loop.replay`, looked up
    when called)."""
    from stictiondiag.replay.closed_loop import replay

    return replay(tags, fit, integrating=tags.integrating)


def _phase_figure(analysis: Analysis):
    from stictiondiag.plotting.analysis import plot_phase

    period = analysis.oscillation.period_s or analysis.oscillation_op.period_s
    return plot_phase(analysis.tags, fit=analysis.fit, title=analysis.loop, period_s=period)


def _reconstruction_figure(analysis: Analysis):
    return analysis.replay.plot()


def _gap_figure(which: str, gap):
    from stictiondiag.plotting.gap import (
        plot_gap_breakdown,
        plot_gap_replay,
    )

    return (plot_gap_breakdown if which == "breakdown" else plot_gap_replay)(gap)


def prepare_analysis() -> None:
    """Import the modules of the analysis steps and set up numba's compiler state
    (the first call of any compiled kernel: about 0.3 s), before the data arrive."""
    import numpy as np

    from stictiondiag.core.filters import lfilter1
    from stictiondiag.gap import diagnose, effects  # noqa: F401
    from stictiondiag.stiction import hammerstein, segments, valvefit, verdict  # noqa: F401

    lfilter1((1.0,), 0.0, np.zeros(1))


def prepare_figure_worker() -> None:
    """Warm-up of a worker process that will draw this module's figures and replay
    the loop (:meth:`~stictiondiag.plotting.writer.FigureWriter.warm_up`): the
    plotting modules imported and numba's compiler state set up, before the work
    arrives."""
    import numpy as np  # noqa: F401

    from stictiondiag.core.filters import lfilter1
    from stictiondiag.plotting import analysis, gap  # noqa: F401
    from stictiondiag.plotting import replay as _replay_plots  # noqa: F401
    from stictiondiag.replay import closed_loop as replay  # noqa: F401

    # The first call of any compiled kernel sets up numba's target (about 0.3 s);
    # the replay's own kernels then load in a few ms each.
    lfilter1((1.0,), 0.0, np.zeros(1))


def _clean(obj):
    """Make a nested structure strictly JSON-able: numpy scalars to Python, NaN to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_clean(v) for v in obj.tolist()]
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.floating | float):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


#: Fewest periods of a regular cycle a record must hold to be analysed at all [-].
#: Seen twice, a pattern repeats (and a sticky valve slips at least four times);
#: seen once it is an event.  Between this and
#: :data:`~stictiondiag.signals.oscillation.MIN_CYCLES` the analysis runs but cannot
#: conclude "no oscillation" (see :func:`check_record_length`).
MIN_ANALYSIS_CYCLES = 2.0


def check_record_length(tags: Tags, osc_pv: Oscillation, osc_op: Oscillation) -> str | None:
    """Check that the record holds enough periods of a regular cycle.

    Stiction shows as a sustained limit cycle (Sections 4.2.2 and 5.3), and the
    oscillation test needs :data:`~stictiondiag.signals.oscillation.MIN_CYCLES` periods.
    When pv or op has a regular autocorrelation (regularity above
    :data:`~stictiondiag.signals.oscillation.REGULARITY_THRESHOLD`) whose period
    (:func:`~stictiondiag.signals.oscillation.dominant_period`) the record holds fewer than
    ``MIN_CYCLES`` times, "no oscillation" would only mean "not enough data":

    * fewer than :data:`MIN_ANALYSIS_CYCLES` periods: the analysis stops and says
      how long a record it needs;
    * from ``MIN_ANALYSIS_CYCLES`` to ``MIN_CYCLES`` periods: the analysis runs, the
      returned message goes into the warnings, and the verdict is told the record is
      short (:func:`~stictiondiag.stiction.valvefit.stiction_verdict`, ``short_record``): the
      valve model's own evidence can still show stiction, but the missing cycle is
      not taken as evidence against it.

    A slow irregular wander is not a cycle and passes. A recorded mv is exempt: its
    stick and slip phases show the stiction directly, cycle or not (Figs. 3 and 6).

    Returns
    -------
    str or None
        The short-record warning, or None when the record is long enough.

    Raises
    ------
    DataError
        The record holds fewer than ``MIN_ANALYSIS_CYCLES`` periods of a regular
        cycle.
    """
    if osc_pv.present or osc_op.present or tags.mv is not None:
        return None
    for role, osc in (("pv", osc_pv), ("op", osc_op)):
        if osc.regularity is None or not osc.regularity > REGULARITY_THRESHOLD:
            continue
        period = dominant_period(getattr(tags, role), float(tags.ts))
        if not period or tags.duration >= MIN_CYCLES * period:
            continue
        need = math.ceil(MIN_CYCLES * period / float(tags.ts))
        held = (
            f"{tags.n} samples hold only {tags.duration / period:.1f} cycles of the "
            f"{period:.0f} s oscillation in {role}"
        )
        if tags.duration < MIN_ANALYSIS_CYCLES * period:
            raise DataError(
                f"record too short: {held}, and telling a limit cycle needs "
                f"{MIN_CYCLES:g}; export at least {need} samples ({MIN_CYCLES * period:.0f} s)"
            )
        return (
            f"short record: {held}, and confirming a limit cycle needs {MIN_CYCLES:g}; "
            "the verdict rests on the valve model alone and does not take the missing "
            f"cycle as evidence against stiction (export at least {need} samples)"
        )
    return None


def analyze(tags: Tags, *, config: AnalysisConfig | None = None, figures: Any = None) -> Analysis:
    """Diagnose stiction in one loop.

    Parameters
    ----------
    tags : Tags
        Loop data from :func:`stictiondiag.io.tags.read_tags` or ``Tags.from_arrays``.
    config : AnalysisConfig, optional
        Which optional steps to run.
    figures : FigureWriter, optional
        Receives every figure of the result, named by :meth:`Analysis.figure_file`
        (:class:`stictiondiag.plotting.writer.FigureWriter`); the caller writes them
        with ``figures.finish()``.  A worker process starts at once and imports
        and sets up what drawing and replaying need (:func:`prepare_figure_worker`)
        while this process finds the oscillation and fits S and J; the figures
        that do not need the gap diagnosis, and the closed-loop replay, are then
        handed to it while this process diagnoses the gap, and the gap's figures
        at the end: the result is the same as without ``figures``, and this
        process never imports matplotlib.

    Returns
    -------
    Analysis

    Raises
    ------
    DataError
        The record holds fewer than two periods of a regular cycle
        (:func:`check_record_length`),
        or a step cannot use the data (its message says why).
    """
    from stictiondiag.stiction.hammerstein import fit_hammerstein
    from stictiondiag.stiction.segments import estimate_from_mv
    from stictiondiag.stiction.verdict import stiction_verdict

    config = config or AnalysisConfig()
    warnings = list(tags.warnings)
    dt = float(tags.ts)
    if figures is not None and hasattr(figures, "warm_up"):
        # A worker process gets ready to draw and replay (imports, compiler set-up)
        # on the other core while this one finds the oscillation and fits S and J.
        figures.warm_up(prepare_figure_worker)

    # 2. Is there an oscillation at all?
    osc_pv = detect_oscillation(tags.pv, dt)
    if not osc_pv.present and tags.sp is not None and float(np.ptp(tags.sp)) > 0:
        # A set-point change puts a step into pv that can hide the cycle from the
        # autocorrelation; the control error sp - pv, on which Thornhill et al.
        # (2003) detect oscillations, has the cycle without the step.
        osc_error = detect_oscillation(tags.sp - tags.pv, dt)
        if osc_error.present:
            osc_pv = osc_error
            warnings.append(
                "the set point moves: the oscillation was found in the control error sp - pv"
            )
    osc_op = detect_oscillation(tags.op, dt)
    short = check_record_length(tags, osc_pv, osc_op)
    if short:
        warnings.append(short)

    # 3. S and J: from the valve's own signal when recorded, else the Hammerstein fit.
    if tags.mv is not None:
        fit = estimate_from_mv(tags.op, tags.mv, dt)
    else:
        fit = fit_hammerstein(
            tags.op,
            tags.pv,
            dt,
            integrating=bool(tags.integrating),
            flow_loop=tags.loop_type in FLOW_LIKE,
        )

    # 4. Verdict.
    verdict = stiction_verdict(
        fit,
        osc_pv,
        oscillation_op=osc_op,
        has_mv=tags.mv is not None,
        short_record=bool(short),
        data=tags,
    )

    def so_far(replay_value, gap_value=None) -> Analysis:
        return Analysis(
            tags=tags,
            oscillation=osc_pv,
            oscillation_op=osc_op,
            fit=fit,
            verdict=verdict,
            replay=replay_value,
            gap=gap_value,
            warnings=tuple(warnings),
        )

    def take_replay(get):
        # The replay's outcome, or None with the reason among the warnings.
        try:
            value = get()
        except StictionError as exc:
            warnings.append(f"replay not possible: {exc}")
            return None
        # A poor identification or a replay without a cycle changes how far the
        # reconstruction can be trusted: the user sees it with the verdict.
        warnings.extend(f"replay: {w}" for w in getattr(value, "warnings", ()))
        return value

    sent: set[str] = set()

    def hand_over(partial: Analysis) -> None:
        # The figures of the steps so far are drawn while the gap is diagnosed.
        for name, build in partial.figure_builders().items():
            figures.add(partial.figure_file(name), build)
            sent.add(name)
        figures.start()

    rep = gap = None
    if (
        figures is not None
        and config.replay
        and config.gap
        and hasattr(figures, "compute")
        and figures.can_start()
    ):
        # 5 and 6 side by side: a worker process replays the loop (and draws the
        # figures of the steps so far), this one diagnoses the gap, which needs the
        # replay only at its end (for the feature breakdown) and then waits for it.
        # The outcome is that of the two steps one after the other.
        from stictiondiag.gap.diagnose import diagnose_gap

        # A picklable call: the worker may have been started before the fit.
        pending = figures.compute(functools.partial(_replay, tags, fit))
        hand_over(so_far(pending.stand_in()))
        gap_error = None
        try:
            gap = diagnose_gap(tags, fit, pending.stand_in())
        except Exception as exc:  # judged once the replay's outcome is known
            gap_error = exc
        rep = take_replay(pending.get)
        if rep is None:
            gap = gap_error = None  # without a replay there is no gap diagnosis
        if gap_error is not None:
            if not isinstance(gap_error, StictionError):
                raise gap_error
            warnings.append(f"gap diagnosis not possible: {gap_error}")
    else:
        # 5. Closed-loop replay; a worker, when there is one, draws the phase plot
        # meanwhile.
        if figures is not None and config.replay and not config.gap:
            hand_over(so_far(None))
        if config.replay:
            rep = take_replay(functools.partial(_replay, tags, fit))

        # 6. Sim-to-real gap.
        if config.gap and rep is not None:
            from stictiondiag.gap.diagnose import diagnose_gap

            if figures is not None:
                hand_over(so_far(rep))
            try:
                gap = diagnose_gap(tags, fit, rep)
            except StictionError as exc:
                warnings.append(f"gap diagnosis not possible: {exc}")

    result = so_far(rep, gap)
    if figures is not None:
        for name, build in result.figure_builders().items():
            if name not in sent:
                figures.add(result.figure_file(name), build)
    return result


def analyze_file(
    path: str | os.PathLike,
    *,
    config: AnalysisConfig | None = None,
    figures: Any = None,
    **read_options,
) -> Analysis:
    """Read one loop's file with :func:`read_tags` and :func:`analyze` it.

    With ``figures`` (a :class:`~stictiondiag.plotting.writer.FigureWriter`) the
    file is read by the figure worker as it starts, while this process sets up the
    steps that follow (:func:`prepare_analysis`): pandas and the compiled kernels'
    set-up, each about half a second, then load side by side.  A file that cannot
    be read is read again here, so its error is the one :func:`read_tags` raises.
    """
    tags = None
    if figures is not None and hasattr(figures, "warm_up") and figures.can_start():
        reading = figures.compute(functools.partial(read_tags, path, **read_options))
        if figures.warm_up(prepare_figure_worker):
            prepare_analysis()
        try:
            tags = reading.get()
        except Exception:
            pass  # read again here: the error as read_tags raises it
    if tags is None:
        tags = read_tags(path, **read_options)
    return analyze(tags, config=config, figures=figures)
