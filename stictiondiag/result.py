"""The result of one loop's analysis: :class:`Analysis`, with its JSON form, its
flat row for plant-wide tables, its time series and its figures.

The procedure that fills it is :mod:`stictiondiag.analysis`; this module holds the
result alone, so that renderers and applications read it without the procedure.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.core.schema import SCHEMA_VERSION, dumps, loads
from stictiondiag.core.serialize import plain_float, to_plain
from stictiondiag.gap.result import GapDiagnosis
from stictiondiag.io.tags import Tags
from stictiondiag.replay import Replay
from stictiondiag.replay.compensation import Compensation
from stictiondiag.replay.metrics import replay_metrics
from stictiondiag.row import LoopRow
from stictiondiag.signals.kpis import LoopKpis
from stictiondiag.signals.oscillation import Oscillation
from stictiondiag.stiction.fit_result import StictionFit
from stictiondiag.stiction.verdict_result import Verdict

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

#: Resolution of the PNG files of :meth:`Analysis.save_figures` [dots per inch].
FIGURE_DPI = 110

#: Name of the schema of :meth:`Analysis.to_json` (the whole result, arrays included).
ANALYSIS_SCHEMA = "stictiondiag.analysis"


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
    kpis : LoopKpis or None
        Loop performance indicators (:mod:`stictiondiag.signals.kpis`), each with
        its unit, definition and citation.
    gap_skipped : str or None
        Why there is no gap diagnosis, in words (not asked for, no replay to compare
        with, or why the diagnosis could not use the data); None when there is one.
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
    kpis: LoopKpis | None = None
    gap_skipped: str | None = None

    @property
    def loop(self) -> str:
        """Loop name: the tag of a loop of a plant export (``plant.csv#FIC101`` ->
        ``FIC101``), else the source file's stem."""
        source = str(self.tags.source)
        if "#" in source:
            return source.rsplit("#", 1)[1] or "loop"
        return Path(source).stem or "loop"

    def to_json(self) -> str:
        """The whole result, time series included, as one JSON document
        (:mod:`stictiondiag.core.schema`, with its version); :meth:`from_json` reads
        it back as the same typed object."""
        return dumps(self, schema=ANALYSIS_SCHEMA)

    @classmethod
    def from_json(cls, text: str) -> Analysis:
        """The :class:`Analysis` of a :meth:`to_json` document.

        Raises
        ------
        DataError
            Not such a document, or one of a newer schema version.
        """
        result = loads(text, schema=ANALYSIS_SCHEMA)
        if not isinstance(result, cls):
            raise DataError("the result file does not hold an analysis")
        return result

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary (the ``--json`` output of ``stiction analyze``), with
        the schema version of :mod:`stictiondiag.core.schema`."""
        tags = self.tags
        stiction = to_plain(self.fit.to_dict())
        op_scale = getattr(tags, "op_scale", "percent")
        stiction["units"] = "% of op span" if op_scale == "percent" else "op units (scale unknown)"
        stiction.update(to_plain(self.verdict.to_dict()))
        rep = None
        if self.replay is not None:
            rep = to_plain(self.replay.to_dict())
            rep["metrics"] = to_plain(replay_metrics(self.replay).to_dict())
        return {
            "schema_version": SCHEMA_VERSION,
            "source": str(tags.source),
            "loop": self.loop,
            "analysed_at": self.analysed_at or None,
            "tags": {
                "names": dict(tags.names),
                "n_samples": int(tags.n),
                "ts_s": float(tags.ts),
                "duration_s": float(tags.n * tags.ts),
                "start": clock_text(getattr(tags, "start_time", None)),
                "loop_type": tags.loop_type,
                "loop_type_source": _plain_text(getattr(tags, "loop_type_source", None)),
                "integrating": bool(tags.integrating),
                "has_mv": tags.mv is not None,
                "has_sp": tags.sp is not None,
                "op_scale": op_scale,
                "action": getattr(tags, "action", None),
                "start_time_s": getattr(tags, "start_time", None),
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
            "gap_skipped": self.gap_skipped,
            "kpis": None if self.kpis is None else to_plain(self.kpis.to_dict()),
            "warnings": list(self.warnings),
        }

    def summary_row(self) -> dict[str, Any]:
        """One flat row for plant-wide tables (``stiction scan``, ``stiction report``):
        :meth:`LoopRow.to_dict <stictiondiag.row.LoopRow.to_dict>` of :meth:`row`."""
        return self.row().to_dict()

    def row(self) -> LoopRow:
        """This analysis's row of the plant-wide tables (:class:`~stictiondiag.row.LoopRow`;
        the report's and the scan's own fields left None)."""
        tags, fit, verdict, rep = self.tags, self.fit, self.verdict, self.replay
        s_int = list(to_plain(fit.S_interval) or [None, None])
        j_int = list(to_plain(fit.J_interval) or [None, None])
        probs = verdict.cause_probabilities
        return LoopRow(
            loop=self.loop,
            source=str(tags.source),
            loop_type=tags.loop_type,
            loop_type_source=_plain_text(tags.loop_type_source),
            integrating=bool(tags.integrating),
            n_samples=int(tags.n),
            has_mv=tags.mv is not None,
            op_scale=tags.op_scale,
            start_time_s=tags.start_time,
            duration_s=float(tags.n * tags.ts),
            oscillating=bool(self.oscillation.present),
            period_s=plain_float(self.oscillation.period_s),
            verdict=verdict.status.value,
            detected=to_plain(verdict.detected),
            confidence=to_plain(verdict.confidence),
            probability=to_plain(verdict.probability),
            cause=None if verdict.cause is None else verdict.cause.value,
            runner_up=None if verdict.runner_up is None else verdict.runner_up.value,
            cause_model=probs.ranked()[0].value if probs is not None else None,
            p_valve_cause=probs.valve if probs is not None else None,
            cause_atypicality=probs.atypicality if probs is not None else None,
            S=to_plain(fit.S),
            J=to_plain(fit.J),
            S_lo=s_int[0],
            S_hi=s_int[1],
            J_lo=j_int[0],
            J_hi=j_int[1],
            S_determinacy=to_plain(fit.S_determinacy),
            J_determinacy=to_plain(fit.J_determinacy),
            method=fit.method,
            replay_fit_pv=None if rep is None else plain_float(rep.measures.pv.fit_pct),
            replay_period_error_pct=(
                None if rep is None else plain_float(replay_metrics(rep).period_error_pct)
            ),
            gap_effect=None if self.gap is None else self.gap.effect,
            gap_shrink_pct=None if self.gap is None else to_plain(self.gap.shrink_pct),
            n_warnings=len(self.warnings),
            flags="; ".join(self.warnings),
            kpis={} if self.kpis is None else to_plain(self.kpis.values()),
        )

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
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.analysis import plot_phase

        options: dict[str, Any] = {
            "fit": self.fit,
            "title": self.loop,
            "period_s": self.oscillation.period_s or self.oscillation_op.period_s,
            "poorly": [sym for sym in ("S", "J") if self.fit.poorly_determined(sym)],
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
            # Imported when a figure is asked for: callers that want numbers skip matplotlib.
            from stictiondiag.plotting.replay import plot_replay

            rep = self.replay
            metrics = replay_metrics(rep)
            builders["reconstruction"] = lambda: plot_replay(rep, metrics=metrics)
        if self.gap is not None:
            # Imported when a figure is asked for: callers that want numbers skip matplotlib.
            from stictiondiag.plotting.gap import plot_gap_breakdown, plot_gap_replay

            gap = self.gap
            builders["gap_breakdown"] = lambda: plot_gap_breakdown(gap)
            builders["gap_replay"] = lambda: plot_gap_replay(gap)
        return builders

    def _valve_zoom_builder(self) -> Callable[[], Figure] | None:
        """The ``valve_zoom`` figure's builder, None without a valve signal or a
        finite S and J."""
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.valve import plot_valve_zoom

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
            poorly=[sym for sym in ("S", "J") if fit.poorly_determined(sym)],
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
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting import save_png

        return [
            save_png(build(), Path(folder) / self.figure_file(name), dpi=dpi)
            for name, build in self.figure_builders().items()
        ]


def clock_text(seconds: float | None) -> str | None:
    """Clock time of the first sample as ISO 8601 UTC text (None without dates)."""
    if seconds is None or not math.isfinite(float(seconds)):
        return None
    from datetime import UTC, datetime

    return datetime.fromtimestamp(float(seconds), UTC).isoformat(timespec="seconds")


def _plain_text(v: object) -> str | None:
    """A tag attribute as text for the JSON (None stays None)."""
    return None if v is None else str(v)
