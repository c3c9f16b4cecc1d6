"""One loop's row of the plant-wide tables: :class:`LoopRow`, the one definition of
their columns.

``stiction report`` keeps these rows in ``rows.json`` and shows them in its index and
Markdown summary; ``stiction scan`` ranks them in ``scan.parquet``/``scan.csv`` and
its fleet page, and keeps each in its loop record.  :meth:`Analysis.row <stictiondiag.result.Analysis.row>`
fills a row from an analysis; :meth:`LoopRow.to_dict` gives the
flat mapping those files hold; :meth:`LoopRow.from_dict` reads a row back (from
JSON, or a record of a table), so the pages read typed fields, not string keys.

This module imports no numerics: the scan's own process reads rows without loading
the analysis.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

#: Prefix of the KPI columns (``kpi_<name>``, :mod:`stictiondiag.signals.kpis`).
KPI_PREFIX = "kpi_"


@dataclass(frozen=True)
class LoopRow:
    """One loop in a plant-wide table.

    Attributes
    ----------
    loop : str
        Loop name.
    source : str or None
        The file (``file#loop`` for a loop of a plant export) or dataset.
    loop_type, loop_type_source : str or None
        The loop type and what decided it.
    integrating : bool or None
        The process integrates.
    n_samples : int or None
        Samples analysed [-].
    has_mv : bool or None
        The valve position was recorded.
    op_scale : str or None
        ``percent`` (op in % of span) or ``unknown`` (S and J in op's own units).
    start_time_s : float or None
        Clock time of the first sample [s since 1970-01-01 UTC].
    duration_s : float or None
        Record length [s].
    oscillating : bool or None
        pv oscillates.
    period_s : float or None
        Period of pv's oscillation [s].
    verdict : str or None
        ``stiction``, ``no_stiction``, ``inconclusive``; ``error`` for a loop that
        could not be analysed (then ``error`` says why); ``propagated`` when the
        plant-wide step traces the cycle to another loop.
    detected : bool or None
        True for stiction, False for none, None when undecided.
    confidence, probability : float or None
        Support for the verdict [0-1] and the calibrated P(stiction) [-].
    cause, runner_up : str or None
        The cause of the cycle the verdict names, and the next most likely.
    cause_model : str or None
        The cause model's most likely cause.
    p_valve_cause : float or None
        The cause model's P(the valve causes the cycle) [-].
    cause_atypicality : float or None
        How far the evidence lies from the simulated loops of the cause model's most
        likely cause, over the 99th percentile of theirs [-]; above 1 its call is an
        extrapolation (:attr:`~stictiondiag.stiction.cause.CauseReading.atypicality`).
    S, J : float or None
        Deadband plus stickband and slip jump [% of op span, or op units when
        ``op_scale`` is ``unknown``].
    S_lo, S_hi, J_lo, J_hi : float or None
        Their intervals [same units].
    S_determinacy, J_determinacy : str or None
        How well the data determine them (the words of
        :class:`~stictiondiag.stiction.fit_result.Determinacy`).
    method : str or None
        How S and J were estimated.
    replay_fit_pv : float or None
        ``100 (1 - NRMSE)`` of the replayed pv [%].
    replay_period_error_pct : float or None
        Period error of the replay [%].
    gap_effect : str or None
        The effect the sim-to-real gap diagnosis names.
    gap_shrink_pct : float or None
        How far it shrinks the gap [% of the gap before].
    n_warnings : int or None
        Warnings of the analysis [-].
    flags : str or None
        The warnings, ``; ``-separated.
    kpis : dict
        KPI name -> value [its unit, :mod:`stictiondiag.signals.kpis`]; the columns
        ``kpi_<name>``.
    page, error, rank, severity, unit, spark_pv, spark_op, trend : optional
        What the report and the scan add to a row: the loop page's link, why a loop
        failed, the rank and severity [P x % of span], the plant unit, the
        sparklines (text, see :mod:`stictiondiag.apps.scan_output`) and the trend
        over scans in words.  None when not added.
    """

    loop: str
    source: str | None = None
    loop_type: str | None = None
    loop_type_source: str | None = None
    integrating: bool | None = None
    n_samples: int | None = None
    has_mv: bool | None = None
    op_scale: str | None = None
    start_time_s: float | None = None
    duration_s: float | None = None
    oscillating: bool | None = None
    period_s: float | None = None
    verdict: str | None = None
    detected: bool | None = None
    confidence: float | None = None
    probability: float | None = None
    cause: str | None = None
    runner_up: str | None = None
    cause_model: str | None = None
    p_valve_cause: float | None = None
    cause_atypicality: float | None = None
    S: float | None = None
    J: float | None = None
    S_lo: float | None = None
    S_hi: float | None = None
    J_lo: float | None = None
    J_hi: float | None = None
    S_determinacy: str | None = None
    J_determinacy: str | None = None
    method: str | None = None
    replay_fit_pv: float | None = None
    replay_period_error_pct: float | None = None
    gap_effect: str | None = None
    gap_shrink_pct: float | None = None
    n_warnings: int | None = None
    flags: str | None = None
    kpis: dict[str, float | None] = field(default_factory=dict)
    page: str | None = None
    error: str | None = None
    rank: int | None = None
    severity: float | None = None
    unit: str | None = None
    spark_pv: str | None = None
    spark_op: str | None = None
    trend: str | None = None

    @classmethod
    def failed(cls, loop: str, source: str | None, error: str) -> LoopRow:
        """The row of a loop that could not be analysed: verdict ``error`` and why."""
        return cls(loop=loop, source=source, verdict="error", error=error)

    def to_dict(self) -> dict[str, Any]:
        """The row as the tables hold it: the analysis's columns in the order of the
        fields, ``kpi_<name>`` after them, then the context fields that are set; a
        failed loop's row holds ``loop``, ``source``, ``verdict`` and ``error`` only."""
        if self.verdict == "error":
            return {
                "loop": self.loop,
                "source": self.source,
                "verdict": self.verdict,
                "error": self.error,
            }
        out: dict[str, Any] = {}
        for spec in fields(self):
            if spec.name == "kpis":
                out.update({f"{KPI_PREFIX}{k}": v for k, v in self.kpis.items()})
            elif spec.name in CONTEXT_FIELDS:
                value = getattr(self, spec.name)
                if value is not None:
                    out[spec.name] = value
            else:
                out[spec.name] = getattr(self, spec.name)
        return out

    @classmethod
    def from_dict(cls, row: Mapping[str, Any]) -> LoopRow:
        """A row read back: its fields by name (missing ones None, a NaN cell of a
        table None), ``kpi_<name>`` into :attr:`kpis`; other columns are left out."""
        values = {
            spec.name: _cell(row.get(spec.name))
            for spec in fields(cls)
            if spec.name not in ("loop", "kpis")
        }
        kpis = {
            str(k)[len(KPI_PREFIX) :]: _cell(v)
            for k, v in row.items()
            if str(k).startswith(KPI_PREFIX)
        }
        return cls(loop=str(row.get("loop")), kpis=kpis, **values)

    def with_context(self, **context: Any) -> LoopRow:
        """This row with context fields (``page``, ``unit``, ...) set."""
        return replace(self, **context)

    def estimate(self, sym: str) -> tuple[float | None, float | None, float | None]:
        """``(value, lo, hi)`` of ``"S"`` or ``"J"``."""
        if sym == "S":
            return self.S, self.S_lo, self.S_hi
        return self.J, self.J_lo, self.J_hi

    def poorly_determined(self, sym: str) -> bool:
        """The data determine ``sym`` poorly (the rule of
        :func:`stictiondiag.stiction.fit_result.poorly_determined`)."""
        # Imported here: the valve fit's module brings numpy, which reading a row does
        # not otherwise need.
        from stictiondiag.stiction.fit_result import Determinacy, poorly_determined

        value, lo, hi = self.estimate(sym)
        words = self.S_determinacy if sym == "S" else self.J_determinacy
        return poorly_determined(Determinacy.of(words), value, [lo, hi])

    @property
    def shown_probability(self) -> float | None:
        """P(stiction) as the pages show it; a row from before the probability was
        recorded carries only the confidence, which is P itself for a stiction verdict."""
        if self.probability is None and self.verdict == "stiction":
            return self.confidence
        return self.probability


def as_row(row: LoopRow | Mapping[str, Any]) -> LoopRow:
    """``row`` as a :class:`LoopRow` (a mapping is read with :meth:`LoopRow.from_dict`)."""
    return row if isinstance(row, LoopRow) else LoopRow.from_dict(row)


#: Fields a report or a scan adds to a row (not filled from the analysis).
CONTEXT_FIELDS = ("page", "error", "rank", "severity", "unit", "spark_pv", "spark_op", "trend")


def _cell(v: Any) -> Any:
    """A value read back from a row: a missing or NaN cell is None."""
    if isinstance(v, float) and math.isnan(v):
        return None
    return v
