"""The orchestrator: one loop's data in, the stiction diagnosis out.

:func:`analyze` follows the paper's procedure for plant data (Choudhury, Thornhill &
Shah 2005):

1. the tags, in % of span for op and mv (Section 5.1), shown mean-centred with unit
   variance in plots and comparisons (Section 3);
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
order and gathers their results in :class:`Analysis`.  Nothing here starts a
process or a thread: the parallelism of many loops is ``stiction scan``'s.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from stictiondiag.core.errors import DataError, StictionError
from stictiondiag.core.memo import memo_scope
from stictiondiag.core.serialize import to_plain
from stictiondiag.gap.diagnose import GapDiagnosis, diagnose_gap
from stictiondiag.identification.looptype import settle_loop_type
from stictiondiag.io.tags import Tags, read_tags
from stictiondiag.replay import Replay, replay
from stictiondiag.replay.compensation import Compensation, compensation_from_replay
from stictiondiag.replay.metrics import replay_metrics
from stictiondiag.signals.oscillation import (
    MIN_CYCLES,
    REGULARITY_THRESHOLD,
    Oscillation,
    detect_oscillation,
    dominant_period,
)
from stictiondiag.stiction.hammerstein import fit_hammerstein
from stictiondiag.stiction.segments import Segments, estimate_from_mv, segment_valve
from stictiondiag.stiction.valvefit import StictionFit
from stictiondiag.stiction.verdict import Verdict, stiction_verdict

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

#: Loop types where pv is (nearly) proportional to the valve opening (Section 5.3.1:
#: "in liquid flow loops ... pv can be taken to be proportional to valve opening").
#: Without mv the fit records it and uses the self-regulating structure
#: (:mod:`stictiondiag.stiction.hammerstein`, "The linear part").
FLOW_LIKE = frozenset({"flow"})

#: Resolution of the PNG files of :meth:`Analysis.save_figures` [dots per inch].
FIGURE_DPI = 110

_T = TypeVar("_T")


@dataclass(frozen=True)
class AnalysisConfig:
    """Options of :func:`analyze`.

    Attributes
    ----------
    gap : bool
        Run the sim-to-real gap diagnosis (the slowest step).
    replay : bool
        Run the closed-loop replay (needed by the gap diagnosis).
    compensation : bool
        Try the variable-integral compensation on the replayed loop (Section 6.4,
        :mod:`stictiondiag.replay.compensation`; needs the replay).
    """

    gap: bool = True
    replay: bool = True
    compensation: bool = True


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
        Oscillation of op (period [s], amplitude [% of span]).
    fit : StictionFit
        S and J [% of op span] with intervals and method.
    verdict : Verdict
        stiction / no_stiction / inconclusive, with confidence [0-1] and reasons.
    replay : Replay or None
        Closed-loop reconstruction (pv in pv units, op and mv in % of span), None
        when not run or not possible (see ``warnings``).
    gap : GapDiagnosis or None
        Sim-to-real gap diagnosis (errors in % of the data's spread), None when not
        run or not possible.
    warnings : tuple of str
        Data-quality and analysis warnings, in the order they arose.
    compensation : Compensation or None
        The smallest variable-integral band [pv units] that stops the replayed
        loop's cycle and the offset it leaves (Section 6.4), None when not run.
    analysed_at : str
        When the analysis ran (ISO 8601, UTC).
    """

    tags: Tags
    oscillation: Oscillation
    oscillation_op: Oscillation
    fit: StictionFit
    verdict: Verdict
    replay: Replay | None = None
    gap: GapDiagnosis | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    compensation: Compensation | None = None
    analysed_at: str = ""

    @property
    def loop(self) -> str:
        """Loop name: the source file's stem."""
        return Path(str(self.tags.source)).stem or "loop"

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (the ``--json`` output of ``stiction analyze``)."""
        tags = self.tags
        stiction = to_plain(self.fit.to_dict())
        stiction["units"] = "% of op span"
        stiction.update(to_plain(self.verdict.to_dict()))
        rep = None
        if self.replay is not None:
            rep = to_plain(self.replay.to_dict())
            rep["metrics"] = to_plain(replay_metrics(self.replay).to_dict())
        return {
            "source": str(tags.source),
            "loop": self.loop,
            "analysed_at": self.analysed_at or None,
            "tags": {
                "names": dict(tags.names),
                "n_samples": int(tags.n),
                "ts_s": float(tags.ts),
                "duration_s": float(tags.n * tags.ts),
                "start": _plain_text(getattr(tags, "start", None)),
                "loop_type": tags.loop_type,
                "loop_type_source": _plain_text(getattr(tags, "loop_type_source", None)),
                "integrating": bool(tags.integrating),
                "has_mv": tags.mv is not None,
                "has_sp": tags.sp is not None,
            },
            "oscillation": {
                "pv": to_plain(self.oscillation.to_dict()),
                "op": to_plain(self.oscillation_op.to_dict()),
            },
            "stiction": stiction,
            "replay": rep,
            "compensation": (
                None if self.compensation is None else to_plain(self.compensation.to_dict())
            ),
            "gap": None if self.gap is None else to_plain(self.gap.to_dict()),
            "warnings": list(self.warnings),
        }

    def summary_row(self, d: dict[str, Any] | None = None) -> dict[str, Any]:
        """One flat row for plant-wide tables (``stiction scan``).

        ``d`` is this analysis's :meth:`to_dict` when the caller has it already (it
        is not computed again; a scan serialises every loop once).
        """
        if d is None:
            d = self.to_dict()
        st = d["stiction"]
        gap = d["gap"] or {}
        rep = d["replay"] or {}
        s_int = st.get("S_interval") or [None, None]
        j_int = st.get("J_interval") or [None, None]
        return {
            "loop": self.loop,
            "source": d["source"],
            "loop_type": d["tags"]["loop_type"],
            "loop_type_source": d["tags"]["loop_type_source"],
            "integrating": d["tags"]["integrating"],
            "n_samples": d["tags"]["n_samples"],
            "has_mv": d["tags"]["has_mv"],
            "oscillating": bool(self.oscillation.present),
            "period_s": d["oscillation"]["pv"].get("period_s"),
            "verdict": st.get("status"),
            "detected": st.get("detected"),
            "confidence": st.get("confidence"),
            "probability": st.get("probability"),
            "cause": st.get("cause"),
            "runner_up": st.get("runner_up"),
            "S": st.get("S"),
            "J": st.get("J"),
            "S_lo": s_int[0],
            "S_hi": s_int[1],
            "J_lo": j_int[0],
            "J_hi": j_int[1],
            "S_determinacy": ((st.get("details") or {}).get("determinacy") or {}).get("S"),
            "J_determinacy": ((st.get("details") or {}).get("determinacy") or {}).get("J"),
            "method": st.get("method"),
            "replay_fit_pv": (rep.get("fit") or {}).get("pv"),
            "replay_period_error_pct": (rep.get("metrics") or {}).get("period_error_pct"),
            "gap_effect": gap.get("effect"),
            "gap_shrink_pct": gap.get("shrink_pct"),
            "n_warnings": len(self.warnings),
            "flags": "; ".join(self.warnings),
        }

    def to_pandas(self) -> pd.DataFrame:
        """The loop's time series, one row per sample.

        Columns: ``time`` [s], the recorded ``sp``, ``pv`` [pv units], ``op``, ``mv``
        [% of span] (those present), ``mv_model`` (the fitted valve's output for the
        recorded op [% of span]) and, with a replay, ``pv_replay``, ``op_replay``,
        ``mv_replay`` (NaN on the samples before the replay starts).
        """
        frame = self.tags.to_pandas()
        if np.size(self.fit.mv_model) == self.tags.n:
            frame["mv_model"] = np.asarray(self.fit.mv_model, dtype=float)
        if self.replay is not None:
            start = int(round(float(self.replay.time[0]) / float(self.replay.dt)))
            for name in ("pv", "op", "mv"):
                column = np.full(self.tags.n, np.nan)
                values = np.asarray(getattr(self.replay, name), dtype=float)
                stop = min(self.tags.n, start + values.size)
                column[start:stop] = values[: stop - start]
                frame[f"{name}_replay"] = column
        return frame

    def plot(self, **kwargs: Any) -> Figure:
        """Time trends and phase plots of the loop with the fitted valve (Figs. 3-6).

        Keyword arguments go to :func:`stictiondiag.plotting.analysis.plot_phase`.
        """
        from stictiondiag.plotting.analysis import plot_phase

        options: dict[str, Any] = {
            "fit": self.fit,
            "title": self.loop,
            "period_s": self.oscillation.period_s or self.oscillation_op.period_s,
        }
        return plot_phase(self.tags, **{**options, **kwargs})

    def figure_builders(self) -> dict[str, Callable[[], Figure]]:
        """The functions that draw :meth:`figures`, by name, without drawing them:
        ``phase`` (Figs. 3-6 style), ``valve_zoom`` (a few cycles of mv-op, or of the
        model's mv-op, with S and J drawn as in Fig. 10), ``reconstruction`` (with a
        replay), ``gap_breakdown`` and ``gap_replay`` (with a gap diagnosis)."""
        builders: dict[str, Callable[[], Figure]] = {"phase": self.plot}
        zoom = self._valve_zoom_builder()
        if zoom is not None:
            builders["valve_zoom"] = zoom
        if self.replay is not None:
            from stictiondiag.plotting.replay import plot_replay

            rep = self.replay
            metrics = to_plain(replay_metrics(rep).to_dict())
            builders["reconstruction"] = lambda: plot_replay(rep, metrics=metrics)
        if self.gap is not None:
            from stictiondiag.plotting.gap import plot_gap_breakdown, plot_gap_replay

            gap = self.gap
            builders["gap_breakdown"] = lambda: plot_gap_breakdown(gap)
            builders["gap_replay"] = lambda: plot_gap_replay(gap)
        return builders

    def _valve_zoom_builder(self) -> Callable[[], Figure] | None:
        """The ``valve_zoom`` figure's builder, None without a valve signal or a
        finite S and J."""
        from stictiondiag.plotting.valve import plot_valve_zoom, poorly_determined

        tags, fit = self.tags, self.fit
        model = tags.mv is None
        mv = np.asarray(fit.mv_model if model else tags.mv, dtype=float)
        if mv.size != tags.n or not (math.isfinite(fit.S) and math.isfinite(fit.J)):
            return None
        period = self.oscillation_op.period_s or self.oscillation.period_s
        return lambda: plot_valve_zoom(
            tags.op,
            mv,
            ts=float(tags.ts),
            S=float(fit.S),
            J=float(fit.J),
            period_s=period,
            model=model,
            poorly=[sym for sym in ("S", "J") if poorly_determined(fit, sym)],
            title=f"{self.loop}: valve signature (Fig. 10)",
        )

    def figures(self) -> dict[str, Figure]:
        """Figures by name (see :meth:`figure_builders`)."""
        return {name: build() for name, build in self.figure_builders().items()}

    def figure_file(self, name: str) -> str:
        """File name of the figure ``name``: ``<loop>_<name>.png``."""
        return f"{self.loop}_{name}.png"

    def save_figures(self, folder: str | os.PathLike[str], *, dpi: int = FIGURE_DPI) -> list[Path]:
        """Write every figure as ``folder/<loop>_<name>.png``, one at a time, each
        file whole or not at all; return the files in the order of :meth:`figures`.

        Raises
        ------
        UsageError
            ``folder`` cannot be written.
        """
        from stictiondiag.plotting import save_png

        return [
            save_png(build(), Path(folder) / self.figure_file(name), dpi=dpi)
            for name, build in self.figure_builders().items()
        ]


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


def analyze(tags: Tags, *, config: AnalysisConfig | None = None) -> Analysis:
    """Diagnose stiction in one loop, in the paper's order (see the module docstring).

    Parameters
    ----------
    tags : Tags
        Loop data from :func:`stictiondiag.io.tags.read_tags` or ``Tags.from_arrays``
        (op and mv already in % of span: step 1).
    config : AnalysisConfig, optional
        Which optional steps to run.

    Returns
    -------
    Analysis

    Raises
    ------
    DataError
        The record holds fewer than two periods of a regular cycle
        (:func:`check_record_length`), or a step cannot use the data (its message
        says why).  The replay and the gap diagnosis do not raise: when they cannot
        use the data the reason goes into the warnings and their field is None.

    Notes
    -----
    The steps run inside one :func:`stictiondiag.core.memo.memo_scope`: the loop
    type from the data and the replay identify the controller and the process from
    the same signals, and the second identification is the first one's result.
    """
    with memo_scope():
        return _procedure(tags, config or AnalysisConfig())


def _procedure(tags: Tags, config: AnalysisConfig) -> Analysis:
    """The steps of :func:`analyze`, in the paper's order."""
    tags = settle_loop_type(tags)  # the data decide the structure when nothing else did
    warnings = list(tags.warnings)

    # 2. Is there an oscillation at all?
    osc_pv, osc_op = find_oscillations(tags, warnings)
    short = check_record_length(tags, osc_pv, osc_op)
    if short:
        warnings.append(short)

    # 3. S and J: from the valve's own signal when recorded, else the Hammerstein fit.
    # The stick and slip segments of the mv-op plot serve the gap diagnosis too.
    segments = segment_valve(tags.op, tags.mv, float(tags.ts)) if tags.mv is not None else None
    fit = estimate_stiction(tags, segments=segments)

    # 4. Verdict.
    verdict = stiction_verdict(
        fit,
        osc_pv,
        oscillation_op=osc_op,
        has_mv=tags.mv is not None,
        short_record=bool(short),
        data=tags,
    )

    # 5. Closed-loop replay; its own notes (a poor identification, a replay without
    # a cycle) say how far the reconstruction can be trusted.
    rep = None
    if config.replay:
        rep = _or_warn(
            "replay not possible",
            warnings,
            lambda: replay(tags, fit, integrating=tags.integrating),
        )
        if rep is not None:
            warnings.extend(f"replay: {w}" for w in rep.warnings)

    # 5b. Variable-integral compensation of the replayed loop (Section 6.4).
    comp = None
    if config.compensation and rep is not None and verdict.status != "no_stiction":
        replayed_loop = rep
        comp = _or_warn(
            "compensation not tried",
            warnings,
            lambda: compensation_from_replay(replayed_loop),
        )

    # 6. Sim-to-real gap (it needs the replay).
    gap = None
    if config.gap and rep is not None:
        replayed = rep
        gap = _or_warn(
            "gap diagnosis not possible",
            warnings,
            lambda: diagnose_gap(tags, fit, replayed, segments=segments),
        )

    return Analysis(
        tags=tags,
        oscillation=osc_pv,
        oscillation_op=osc_op,
        fit=fit,
        verdict=verdict,
        replay=rep,
        gap=gap,
        warnings=tuple(warnings),
        compensation=comp,
        analysed_at=datetime.now(UTC).isoformat(timespec="seconds"),
    )


def find_oscillations(tags: Tags, warnings: list[str]) -> tuple[Oscillation, Oscillation]:
    """Step 2: the oscillation of pv (or of the control error) and of op.

    A set-point change puts a step into pv that can hide the cycle from the
    autocorrelation; the control error ``sp - pv``, on which Thornhill et al. (2003)
    detect oscillations, has the cycle without the step.  When only the error shows
    it, its oscillation stands for pv's and a note goes into ``warnings``.
    """
    dt = float(tags.ts)
    osc_pv = detect_oscillation(tags.pv, dt)
    if not osc_pv.present and tags.sp is not None and float(np.ptp(tags.sp)) > 0:
        osc_error = detect_oscillation(tags.sp - tags.pv, dt)
        if osc_error.present:
            osc_pv = osc_error
            warnings.append(
                "the set point moves: the oscillation was found in the control error sp - pv"
            )
    return osc_pv, detect_oscillation(tags.op, dt)


def estimate_stiction(tags: Tags, segments: Segments | None = None) -> StictionFit:
    """Step 3: S and J [% of op span] of the data-driven model (Section 5.1).

    From the stick and slip segments of the mv-op plot when mv is recorded (Figs. 3
    and 6), otherwise from the valve model and a linear process fitted together to
    op and pv (Section 5.3.1).  ``segments``: :func:`segment_valve` of op, mv and
    ts when the caller has it already.
    """
    if tags.mv is not None:
        return estimate_from_mv(tags.op, tags.mv, float(tags.ts), segments=segments)
    return fit_hammerstein(
        tags.op,
        tags.pv,
        float(tags.ts),
        integrating=bool(tags.integrating),
        flow_loop=tags.loop_type in FLOW_LIKE,
    )


def _plain_text(v: object) -> str | None:
    """A tag attribute as text for the JSON (None stays None)."""
    return None if v is None else str(v)


def _or_warn(what: str, warnings: list[str], step: Callable[[], _T]) -> _T | None:
    """``step()``, or None with ``"<what>: <reason>"`` among the warnings when the
    step cannot use the data (a :class:`StictionError`; other errors propagate)."""
    try:
        return step()
    except StictionError as exc:
        warnings.append(f"{what}: {exc}")
        return None


def analyze_file(
    path: str | os.PathLike[str],
    *,
    config: AnalysisConfig | None = None,
    **read_options: Any,
) -> Analysis:
    """Read one loop's file with :func:`~stictiondiag.io.tags.read_tags` and
    :func:`analyze` it."""
    return analyze(read_tags(path, **read_options), config=config)
