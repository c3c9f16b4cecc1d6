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
from html import escape
from typing import Any

__all__ = ["HISTORY_FOLDER", "entry_of", "history_html", "merge_entry", "trend_sentence"]

#: Folder of the histories inside a scan's output folder.
HISTORY_FOLDER = "history"

_FIELDS = ("verdict", "probability", "S", "S_lo", "S_hi", "J", "J_lo", "J_hi", "op_scale")


def _finite(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def cause_of(row: dict, analysis: dict | None) -> str | None:
    """The cause of the loop's trouble as the analysis names it: the verdict's cause of
    the cycle when it gives one, else the sim-to-real gap's effect."""
    st = (analysis or {}).get("stiction") or {}
    for value in (row.get("cause"), st.get("cause"), row.get("gap_effect")):
        if isinstance(value, str) and value:
            return value
        if isinstance(value, dict) and value.get("name"):
            return str(value["name"])
    return None


def entry_of(row: dict, analysis: dict | None, source_sha: str | None) -> dict:
    """One history entry of a finished loop: its record period, key and results."""
    start = _finite(row.get("start_time_s"))
    duration = _finite(row.get("duration_s"))
    end = None if start is None or duration is None else start + duration
    key = f"{start:.3f}-{end:.3f}" if start is not None and end is not None else source_sha
    entry = {
        "key": key,
        "record_start_s": start,
        "record_end_s": end,
        "analysed_at": (analysis or {}).get("analysed_at"),
        "source": row.get("source"),
        "cause": cause_of(row, analysis),
    }
    entry.update({f: row.get(f) for f in _FIELDS})
    return entry


def _order(entry: dict) -> tuple:
    start = entry.get("record_start_s")
    return (start is None, start or 0.0, str(entry.get("analysed_at") or ""))


def merge_entry(entries: list[dict], entry: dict) -> list[dict]:
    """``entries`` with ``entry`` added (replacing one of the same key), in record order."""
    kept = [e for e in entries if e.get("key") != entry.get("key") or entry.get("key") is None]
    return sorted([*kept, entry], key=_order)


def read_entries(text: str) -> list[dict]:
    """The entries of a history file (an unreadable one is an empty history)."""
    try:
        data = json.loads(text)
    except ValueError:
        return []
    entries = data.get("entries") if isinstance(data, dict) else None
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def trend_sentence(entries: list[dict], sym: str = "S") -> str | None:
    """``S rose from 1.2 % to 3.4 % over 6 exports``; None with fewer than two values.

    When the first and last intervals overlap the change is not told apart from
    the estimate's uncertainty: "S stayed at about ...".
    """
    values = [e for e in entries if _finite(e.get(sym)) is not None]
    if len(values) < 2:
        return None
    first, last = values[0], values[-1]
    a, b = float(first[sym]), float(last[sym])
    unit = " %" if all(e.get("op_scale", "percent") == "percent" for e in values) else ""
    n = len(values)
    lo_a, hi_a = _finite(first.get(f"{sym}_lo")), _finite(first.get(f"{sym}_hi"))
    lo_b, hi_b = _finite(last.get(f"{sym}_lo")), _finite(last.get(f"{sym}_hi"))
    overlap = False
    if lo_a is not None and hi_a is not None and lo_b is not None and hi_b is not None:
        overlap = max(lo_a, lo_b) <= min(hi_a, hi_b)
    if overlap or a == b:
        return f"{sym} stayed at about {b:.3g}{unit} over {n} exports (intervals overlap)"
    verb = "rose" if b > a else "fell"
    return f"{sym} {verb} from {a:.3g}{unit} to {b:.3g}{unit} over {n} exports"


def _when(entry: dict) -> str:
    start = _finite(entry.get("record_start_s"))
    if start is None:
        return str(entry.get("analysed_at") or "")[:16]
    import datetime as _dt

    return _dt.datetime.fromtimestamp(start, _dt.UTC).strftime("%Y-%m-%d %H:%M")


def _chart(entries: list[dict], width: int = 420, height: int = 140) -> str:
    """S and J with their intervals over the entries, as inline SVG (no script, no style)."""
    points = [(k, e) for k, e in enumerate(entries) if _finite(e.get("S")) is not None]
    if not points:
        return ""
    highs = [
        _finite(e.get(f"{s}_hi")) or _finite(e.get(s)) or 0.0 for _, e in points for s in ("S", "J")
    ]
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
            v = _finite(e.get(sym))
            if v is None:
                continue
            x, y = xy(k, v)
            line.append(f"{x:.1f},{y:.1f}")
            lo, hi = _finite(e.get(f"{sym}_lo")), _finite(e.get(f"{sym}_hi"))
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


def history_html(entries: list[dict]) -> str:
    """The history section of a loop page: trend sentences, chart and table."""
    if not entries:
        return ""
    sentences = [t for t in (trend_sentence(entries, "S"), trend_sentence(entries, "J")) if t]

    def num(v: Any) -> str:
        x = _finite(v)
        return "" if x is None else f"{x:.3g}"

    rows = "".join(
        f"<tr><td>{escape(_when(e))}</td><td>{escape(str(e.get('verdict') or ''))}</td>"
        f"<td class='num'>{num(e.get('probability'))}</td>"
        f"<td class='num'>{num(e.get('S'))} [{num(e.get('S_lo'))}, {num(e.get('S_hi'))}]</td>"
        f"<td class='num'>{num(e.get('J'))} [{num(e.get('J_lo'))}, {num(e.get('J_hi'))}]</td>"
        f"<td>{escape(str(e.get('cause') or ''))}</td></tr>"
        for e in entries
    )
    said = "".join(f"<p class='trend'>{escape(t)}.</p>" for t in sentences)
    return (
        f'<h2 id="history">History ({len(entries)} export{"s" if len(entries) != 1 else ""})</h2>'
        f"{said}{_chart(entries)}"
        "<table><tr><th>record from</th><th>verdict</th><th>P(stiction)</th>"
        "<th>S (interval)</th><th>J (interval)</th><th>cause</th></tr>"
        f"{rows}</table>"
    )
