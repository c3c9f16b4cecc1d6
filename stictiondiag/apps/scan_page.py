"""The fleet page of a plant scan (``index.html``): which valves to send maintenance to,
in what order, and why, at a glance.

One row per loop, in the order of :data:`~stictiondiag.apps.pages.RANKING_RULE` (stated
on the page): the verdict with P(valve), the cause, S and J with their intervals
(in % of span, or marked when op's scale is unknown), sparklines of pv and op over
the record, the loop KPIs (:mod:`stictiondiag.signals.kpis`), the oscillation period,
the unit and loop type, and the trend of S over earlier scans
(:mod:`stictiondiag.apps.history`).  Filters by verdict and by unit run in the page's
own script (allowed by its hash, nothing fetched).  Internal notes stay on the loop
pages; a failed loop shows its one-line reason.
"""

from __future__ import annotations

import math
from html import escape

import pandas as pd

from stictiondiag.apps.pages import (
    P_VALVE_WORDS,
    RANKING_RULE,
    VERDICT_ORDER,
    duration_text,
    html_page,
    sparkline,
)
from stictiondiag.apps.pages import safe_name as _safe_name
from stictiondiag.row import LoopRow

__all__ = ["FILTER_JS", "scan_html"]

#: The page's filter script (a fixed text: its hash is in the page's CSP).
FILTER_JS = """
(function () {
  var verdict = document.getElementById('f-verdict');
  var unit = document.getElementById('f-unit');
  function apply() {
    var rows = document.querySelectorAll('#fleet tbody tr');
    var shown = 0;
    for (var i = 0; i < rows.length; i++) {
      var r = rows[i];
      var ok = (!verdict.value || r.getAttribute('data-verdict') === verdict.value) &&
               (!unit.value || r.getAttribute('data-unit') === unit.value);
      r.hidden = !ok;
      if (ok) { shown++; }
    }
    document.getElementById('f-count').textContent = shown + ' shown';
  }
  verdict.addEventListener('change', apply);
  unit.addEventListener('change', apply);
  apply();
})();
"""

_STYLE_VERDICT = {"stiction", "inconclusive", "no_stiction", "error", "propagated"}


def _finite(v) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _num(v, spec: str = ".3g") -> str:
    x = _finite(v)
    return "" if x is None else format(x, spec)


def _param(r: LoopRow, sym: str) -> str:
    value_f, lo_f, hi_f = r.estimate(sym)
    value = _num(value_f)
    if not value:
        return ""
    lo, hi = _num(lo_f), _num(hi_f)
    interval = f" <span class='muted'>[{lo}, {hi}]</span>" if lo and hi else ""
    return f"{value}{interval}"


def _spark(text) -> list[float]:
    if not isinstance(text, str) or not text:
        return []
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return []


#: The KPIs of the fleet page: name, wording (``{}`` the value), format.
FLEET_KPIS = (
    ("op_travel_per_day", "travel {}{unit}/d", ".0f"),
    ("op_reversals_per_day", "reversals {}/d", ".0f"),
    ("time_at_op_limits", "at op limits {} %", ".2g"),
    ("harris_index", "Harris index {}", ".2g"),
    ("service_factor", "in auto {} %", ".3g"),
)


def _kpis(r: LoopRow) -> str:
    parts = []
    unit = "" if r.op_scale == "unknown" else " %"
    for name, form, spec in FLEET_KPIS:
        value = _num(r.kpis.get(name), spec)
        if value:
            parts.append(form.replace("{unit}", unit).format(value))
    return "<br>".join(escape(p) for p in parts)


def _text(v) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else str(v)


#: How a cause of the cycle reads in the fleet table (the verdict's own word otherwise).
_CAUSE_WORDS = {"none": "no cycle"}


def _cause_text(r: LoopRow, verdict: str) -> str:
    """The cause cell: the verdict's cause of the cycle; ``undecided`` for an
    inconclusive verdict, which names none (the gap's effect is another question: why
    the replay departs from the data, so it does not stand in for it); a row of an
    older scan without a cause keeps its gap effect."""
    cause = _text(r.cause)
    if cause:
        return _CAUSE_WORDS.get(cause, cause)
    if verdict == "inconclusive":
        return "undecided"
    return _text(r.gap_effect)


def _row(r: LoopRow, file_names: dict | None) -> str:
    loop = _text(r.loop)
    name = (file_names or {}).get(loop) or _safe_name(loop)
    verdict = _text(r.verdict)
    v_class = verdict if verdict in _STYLE_VERDICT else "unknown"
    link = (
        f'<a href="loops/{escape(name)}.html">{escape(loop)}</a> '
        f'<a class="muted" href="loops/{escape(name)}.json">json</a>'
    )
    unit = _text(r.unit)
    cells = [
        f"<td class='num'>{_num(r.rank, '.0f')}</td>",
        f"<td>{link}</td>",
        f"<td><span class='verdict {v_class}'>{escape(verdict.replace('_', ' '))}</span></td>",
    ]
    if verdict == "error":
        cells.append(f"<td colspan='9'>{escape(_text(r.error))}</td>")
    else:
        scale = " <span class='warn'>(op units)</span>" if r.op_scale == "unknown" else ""
        cause = _cause_text(r, verdict)
        cells += [
            f"<td class='num'>{_num(r.probability, '.2f')}</td>",
            f"<td>{escape(cause)}</td>",
            f"<td class='num'>{_param(r, 'S')}{scale}</td>",
            f"<td class='num'>{_param(r, 'J')}{scale}</td>",
            f"<td>{sparkline(_spark(r.spark_pv))}<br>"
            f"{sparkline(_spark(r.spark_op), color='#555')}</td>",
            f"<td class='kpi'>{_kpis(r)}</td>",
            f"<td class='num'>{escape(duration_text(r.period_s))}</td>",
            f"<td>{escape(_text(r.loop_type))}</td>",
            f"<td class='trend'>{escape(_text(r.trend))}</td>",
        ]
    cells.append(f"<td>{escape(unit)}</td>")
    return (
        f'<tr class="{v_class}" data-verdict="{escape(verdict)}" data-unit="{escape(unit)}">'
        f"{''.join(cells)}</tr>"
    )


def scan_html(table: pd.DataFrame, file_names: dict | None = None) -> str:
    """The fleet page (module docstring) of a ranked scan table."""
    rows = [LoopRow.from_dict(r) for r in table.to_dict("records")] if len(table) else []
    counts = {v: sum(1 for r in rows if r.verdict == v) for v in VERDICT_ORDER}
    summary = ", ".join(f"{n} {v.replace('_', ' ')}" for v, n in counts.items() if n)
    units = sorted({_text(r.unit) for r in rows if _text(r.unit)})
    verdicts = [v for v in VERDICT_ORDER if counts[v]]
    v_options = "".join(
        f'<option value="{escape(v)}">{escape(v.replace("_", " "))}</option>' for v in verdicts
    )
    u_options = "".join(f'<option value="{escape(u)}">{escape(u)}</option>' for u in units)
    head = (
        "<tr><th>rank</th><th>loop</th><th>verdict</th><th>P(valve)</th><th>cause</th>"
        "<th>S [% of span] (interval)</th><th>J [% of span] (interval)</th>"
        "<th>pv / op (whole record)</th><th>KPIs</th><th>period</th><th>loop type</th>"
        "<th>trend over scans</th><th>unit</th></tr>"
    )
    body = (
        f"<h1>Stiction scan: the fleet</h1><p>{len(rows)} loops: {escape(summary)}.</p>"
        f'<p id="ranking-rule">Loops are {escape(RANKING_RULE)}. {escape(P_VALVE_WORDS)}.</p>'
        '<p><label>verdict <select id="f-verdict"><option value="">all</option>'
        f"{v_options}</select></label> "
        '<label>unit <select id="f-unit"><option value="">all</option>'
        f'{u_options}</select></label> <span id="f-count" class="muted"></span></p>'
        f'<table id="fleet"><thead>{head}</thead><tbody>'
        f"{''.join(_row(r, file_names) for r in rows)}</tbody></table>"
        '<p class="muted">S: deadband + stickband, J: slip jump (Choudhury, Thornhill &amp; '
        "Shah 2005), with the interval of values the data cannot tell apart; "
        "&ldquo;(op units)&rdquo;: op was not in % of span, so S and J are in op's own units. "
        "Cause: what the analysis names as the cause of the cycle (undecided where the "
        "verdict is inconclusive; no cycle where the loop does not oscillate). KPIs (Desborough &amp; "
        "Miller 2002): op travel and reversals per day, time at the op limits, the Harris "
        "index where the dead time was identified, the service factor where the mode is "
        "recorded; definitions in each loop's JSON. Notes and warnings are on the loop "
        "pages.</p>"
    )
    return html_page("stiction scan", body, script=FILTER_JS)
