"""A valve's history across scans: S, J and the cause, export after export.

A scan into a folder that already holds results keeps them: each loop's history is
``OUT/history/<loop>.json``, one entry per record period (the export's clock span,
or, without a clock, the content of the source file).  A new export of the same
loop adds an entry; the same export analysed again replaces its own.  The trend of
S over the entries is what schedules maintenance: :func:`trend_sentence` says it in
words ("S rose from 1.2 % to 3.4 % over 6 exports"), :func:`history_html` shows it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from html import escape
from typing import TYPE_CHECKING, Any

from stictiondiag.row import LoopRow, as_row

if TYPE_CHECKING:
    from stictiondiag.result import Analysis

__all__ = [
    "HISTORY_FOLDER",
    "HistoryEntry",
    "absent_html",
    "entry_of",
    "history_html",
    "merge_entry",
    "read_entries",
    "trend_sentence",
]

#: Folder of the histories inside a scan's output folder.
HISTORY_FOLDER = "history"


def _finite(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class HistoryEntry:
    """One scan's result for a loop, in its history file.

    Attributes
    ----------
    key : str or None
        What makes two entries one record: the record period (``start-end`` [s]),
        or without a clock the SHA-256 of the source file.
    record_start_s, record_end_s : float or None
        Clock time of the record's first sample and its end [s since 1970-01-01 UTC].
    analysed_at : str or None
        When the analysis ran (ISO 8601, UTC).
    source : str or None
        The file the record came from.
    cause : str or None
        The cause the analysis names (:func:`cause_of`).
    verdict : str or None
        The verdict.
    probability : float or None
        P(valve) [-] (:data:`stictiondiag.apps.pages.P_VALVE_WORDS`).
    S, S_lo, S_hi, J, J_lo, J_hi : float or None
        S and J with their intervals [% of span, or op units when ``op_scale`` is
        ``unknown``].
    op_scale : str or None
        ``percent`` or ``unknown`` (:attr:`stictiondiag.row.LoopRow.op_scale`).
    """

    key: str | None = None
    record_start_s: float | None = None
    record_end_s: float | None = None
    analysed_at: str | None = None
    source: str | None = None
    cause: str | None = None
    verdict: str | None = None
    probability: float | None = None
    S: float | None = None
    S_lo: float | None = None
    S_hi: float | None = None
    J: float | None = None
    J_lo: float | None = None
    J_hi: float | None = None
    op_scale: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The entry as the history file holds it."""
        return {spec.name: getattr(self, spec.name) for spec in fields(self)}

    @classmethod
    def from_dict(cls, entry: Mapping[str, Any]) -> HistoryEntry:
        """An entry read back (missing fields None, other keys left out)."""
        return cls(**{spec.name: entry.get(spec.name) for spec in fields(cls)})

    def estimate(self, sym: str) -> tuple[float | None, float | None, float | None]:
        """``(value, lo, hi)`` of ``"S"`` or ``"J"``, finite numbers or None."""
        values = (self.S, self.S_lo, self.S_hi) if sym == "S" else (self.J, self.J_lo, self.J_hi)
        return _finite(values[0]), _finite(values[1]), _finite(values[2])


def cause_of(row: LoopRow, analysis: Analysis | None) -> str | None:
    """The cause of the loop's trouble as the analysis names it: the verdict's cause of
    the cycle when it gives one, else the sim-to-real gap's effect."""
    verdict_cause = None if analysis is None else analysis.verdict.cause
    for value in (row.cause, verdict_cause, row.gap_effect):
        if isinstance(value, str) and value:
            return str(value)
    return None


def entry_of(
    row: LoopRow | Mapping, analysis: Analysis | None, source_sha: str | None
) -> HistoryEntry:
    """One history entry of a finished loop: its record period, key and results."""
    r = as_row(row)
    start = _finite(r.start_time_s)
    duration = _finite(r.duration_s)
    end = None if start is None or duration is None else start + duration
    key = f"{start:.3f}-{end:.3f}" if start is not None and end is not None else source_sha
    return HistoryEntry(
        key=key,
        record_start_s=start,
        record_end_s=end,
        analysed_at=None if analysis is None else (analysis.analysed_at or None),
        source=r.source,
        cause=cause_of(r, analysis),
        verdict=r.verdict,
        probability=r.probability,
        S=r.S,
        S_lo=r.S_lo,
        S_hi=r.S_hi,
        J=r.J,
        J_lo=r.J_lo,
        J_hi=r.J_hi,
        op_scale=r.op_scale,
    )


def _order(entry: HistoryEntry) -> tuple:
    start = entry.record_start_s
    return (start is None, start or 0.0, str(entry.analysed_at or ""))


def merge_entry(entries: list[HistoryEntry], entry: HistoryEntry) -> list[HistoryEntry]:
    """``entries`` with ``entry`` added (replacing one of the same key), in record order."""
    kept = [e for e in entries if e.key != entry.key or entry.key is None]
    return sorted([*kept, entry], key=_order)


def read_entries(text: str) -> list[HistoryEntry]:
    """The entries of a history file (an unreadable one is an empty history)."""
    try:
        data = json.loads(text)
    except ValueError:
        return []
    entries = data.get("entries") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        return []
    return [HistoryEntry.from_dict(e) for e in entries if isinstance(e, dict)]


def trend_sentence(entries: list[HistoryEntry], sym: str = "S") -> str | None:
    """``S rose from 1.2 % to 3.4 % over 6 exports``; None with fewer than two values.

    When the first and last intervals overlap the change is not told apart from
    the estimate's uncertainty: "S stayed at about ...".
    """
    values = [e.estimate(sym) for e in entries if e.estimate(sym)[0] is not None]
    if len(values) < 2:
        return None
    (a, lo_a, hi_a), (b, lo_b, hi_b) = values[0], values[-1]
    assert a is not None and b is not None  # kept above: finite estimates only
    shown = [e for e in entries if e.estimate(sym)[0] is not None]
    unit = " %" if all((e.op_scale or "percent") == "percent" for e in shown) else ""
    n = len(values)
    overlap = False
    if lo_a is not None and hi_a is not None and lo_b is not None and hi_b is not None:
        overlap = max(lo_a, lo_b) <= min(hi_a, hi_b)
    if overlap or a == b:
        return f"{sym} stayed at about {b:.3g}{unit} over {n} exports (intervals overlap)"
    verb = "rose" if b > a else "fell"
    return f"{sym} {verb} from {a:.3g}{unit} to {b:.3g}{unit} over {n} exports"


def _when(entry: HistoryEntry) -> str:
    start = _finite(entry.record_start_s)
    if start is None:
        return str(entry.analysed_at or "")[:16]
    import datetime as _dt

    return _dt.datetime.fromtimestamp(start, _dt.UTC).strftime("%Y-%m-%d %H:%M")


def _chart(entries: list[HistoryEntry], width: int = 420, height: int = 140) -> str:
    """S and J with their intervals over the entries, as inline SVG (no script, no style)."""
    points = [(k, e) for k, e in enumerate(entries) if e.estimate("S")[0] is not None]
    if not points:
        return ""
    highs = [e.estimate(s)[2] or e.estimate(s)[0] or 0.0 for _, e in points for s in ("S", "J")]
    top = max([*highs, 1e-9]) * 1.1
    n = max(len(entries) - 1, 1)
    x0, x1, y0, y1 = 40, width - 10, height - 20, 10

    def xy(k: int, v: float) -> tuple[float, float]:
        return x0 + (x1 - x0) * k / n, y0 - (y0 - y1) * v / top

    parts = [
        f'<svg class="history" width="{width}" height="{height}" viewBox="0 0 {width} {height}">',
        f'<line x1="{x0}" y1="{y0}" x2="{x1}" y2="{y0}" stroke="#999"/>',
        f'<line x1="{x0}" y1="{y0}" x2="{x0}" y2="{y1}" stroke="#999"/>',
        f'<text x="2" y="{y1 + 8}" font-size="10">{top:.3g}</text>',
        f'<text x="2" y="{y0}" font-size="10">0</text>',
    ]
    for sym, color in (("S", "#c0392b"), ("J", "#2c7fb8")):
        line = []
        for k, e in points:
            v, lo, hi = e.estimate(sym)
            if v is None:
                continue
            x, y = xy(k, v)
            line.append(f"{x:.1f},{y:.1f}")
            if lo is not None and hi is not None:
                _, ylo = xy(k, lo)
                _, yhi = xy(k, hi)
                parts.append(
                    f'<line x1="{x:.1f}" y1="{ylo:.1f}" x2="{x:.1f}" y2="{yhi:.1f}" '
                    f'stroke="{color}" stroke-width="3" stroke-opacity="0.4"/>'
                )
            parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3" fill="{color}"/>')
        if len(line) > 1:
            parts.append(
                f'<polyline fill="none" stroke="{color}" stroke-width="1.2" points="{" ".join(line)}"/>'
            )
    parts.append(
        f'<text x="{x0 + 4}" y="{y1 + 8}" font-size="10" fill="#c0392b">S</text>'
        f'<text x="{x0 + 16}" y="{y1 + 8}" font-size="10" fill="#2c7fb8">J</text></svg>'
    )
    return "".join(parts)


def history_html(entries: list[HistoryEntry]) -> str:
    """The history section of a loop page: trend sentences, chart and table."""
    if not entries:
        return ""
    sentences = [t for t in (trend_sentence(entries, "S"), trend_sentence(entries, "J")) if t]

    def num(v: Any) -> str:
        x = _finite(v)
        return "" if x is None else f"{x:.3g}"

    def param(e: HistoryEntry, sym: str) -> str:
        v, lo, hi = e.estimate(sym)
        return f"{num(v)} [{num(lo)}, {num(hi)}]"

    rows = "".join(
        f"<tr><td>{escape(_when(e))}</td><td>{escape(str(e.verdict or ''))}</td>"
        f"<td class='num'>{num(e.probability)}</td>"
        f"<td class='num'>{param(e, 'S')}</td>"
        f"<td class='num'>{param(e, 'J')}</td>"
        f"<td>{escape(str(e.cause or ''))}</td></tr>"
        for e in entries
    )
    said = "".join(f"<p class='trend'>{escape(t)}.</p>" for t in sentences)
    return (
        f'<h2 id="history">History ({len(entries)} export{"s" if len(entries) != 1 else ""})</h2>'
        f"{said}{_chart(entries)}"
        "<table><tr><th>record from</th><th>verdict</th><th>P(valve)</th>"
        "<th>S (interval)</th><th>J (interval)</th><th>cause</th></tr>"
        f"{rows}</table>"
    )


def absent_html(histories: Mapping[str, list[HistoryEntry]], pages: Mapping[str, str]) -> str:
    """The fleet page's section of loops with a history that are not in this export.

    A loop that an export leaves out (a renamed tag, a unit out of service) keeps its
    history; its last result and trend stay in view, marked as not re-analysed.
    ``histories``: loop -> its entries; ``pages``: loop -> the file of its page from
    an earlier scan in ``loops/`` (left out when there is none).
    """
    if not histories:
        return ""

    def num(v: Any) -> str:
        x = _finite(v)
        return "" if x is None else f"{x:.3g}"

    rows = []
    for loop in sorted(histories):
        entries = histories[loop]
        if not entries:
            continue
        last = entries[-1]
        link = escape(loop)
        if loop in pages:
            link = f'<a href="loops/{escape(pages[loop])}">{link}</a>'
        S, S_lo, S_hi = last.estimate("S")
        trend = trend_sentence(entries) or ""
        rows.append(
            f"<tr><td>{link}</td><td>{escape(_when(last))}</td>"
            f"<td>{escape(str(last.verdict or '').replace('_', ' '))}</td>"
            f"<td class='num'>{num(S)} [{num(S_lo)}, {num(S_hi)}]</td>"
            f"<td>{escape(str(last.cause or ''))}</td><td>{escape(trend)}</td></tr>"
        )
    if not rows:
        return ""
    return (
        f'<h2 id="absent">Not in this export ({len(rows)} loop{"s" if len(rows) != 1 else ""})'
        "</h2><p>These loops have results from earlier scans into this folder but no "
        "record in this one: their last result, not re-analysed.</p>"
        "<table><tr><th>loop</th><th>last record from</th><th>last verdict</th>"
        "<th>S (interval)</th><th>cause</th><th>trend over scans</th></tr>"
        f"{''.join(rows)}</table>"
    )
