"""The index page and the Markdown summary of a stiction report (see
:mod:`stictiondiag.apps.report`); each loop's page is :mod:`stictiondiag.apps.loop_page`.

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped in HTML and in Markdown, so a column called ``<script>`` shows as text.  The
pages also carry a Content-Security-Policy (:func:`stictiondiag.apps.pages.html_page`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from html import escape

from stictiondiag.apps.pages import (
    P_VALVE_WORDS,
    RANKING_RULE,
    duration_text,
    html_num,
    html_page,
    html_text,
    rank_key,
)
from stictiondiag.row import LoopRow, as_row
from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL, VALVE_LEVEL

__all__ = ["md_escape", "render_index_html", "render_markdown", "sort_key"]

_VERDICT_RANK = {"stiction": 0, "inconclusive": 1, "error": 2, "no_stiction": 3}

_num = html_num
_text = html_text


def md_escape(text) -> str:
    """Escape text for Markdown table cells and prose (no HTML, no formatting).

    ``<`` and ``>`` become entities (a tag shows as text), Markdown punctuation is
    backslash-escaped and ``|`` is escaped last so that it cannot end a table cell.
    """
    text = escape(str(text), quote=False)  # <script> -> &lt;script&gt;
    text = re.sub(r"\s*[\r\n]+\s*", " ", text)
    text = re.sub(r"([\\`*_{}\[\]()#+!~>])", r"\\\1", text)
    return text.replace("|", "\\|")


def sort_key(r: LoopRow | Mapping) -> tuple:
    """The ranking rule of every page (:data:`stictiondiag.apps.pages.RANKING_RULE`)."""
    return rank_key(r)


def _counts(rows: Sequence[LoopRow]) -> str:
    n = {k: sum(1 for r in rows if r.verdict == k) for k in _VERDICT_RANK}
    text = f"{len(rows)} loop{'s' if len(rows) != 1 else ''}: {n['stiction']} stiction"
    text += f", {n['inconclusive']} inconclusive, {n['no_stiction']} no stiction"
    if n["error"]:
        text += f", {n['error']} failed"
    return text


def _value_interval(v, lo, hi) -> str:
    if v is None:
        return "n/a"
    if lo is None or hi is None:
        return _num(v)
    return f"{_num(v)} ({_num(lo)}&ndash;{_num(hi)})"


def _row_param(r: LoopRow, sym: str, *, html: bool = True) -> str:
    """Value (interval) of an index row, marked when poorly determined."""
    text = _value_interval(*r.estimate(sym))
    if not r.poorly_determined(sym):
        return text
    if html:
        return f'{text} <span class="poor" title="poorly determined">poorly determined</span>'
    return f"{text} poorly determined"


def _loop_type(r: LoopRow) -> str:
    """``level (tag)``: an index row's loop type and what decided it."""
    kind = r.loop_type
    if not kind:
        return ""
    if kind == "other":  # no named type: say what the replay assumes
        kind = "integrating" if r.integrating else "self-regulating"
    source = r.loop_type_source
    text = f"{kind} ({source})" if source else str(kind)
    return _text(text)


def _ranked(rows: Sequence[LoopRow | Mapping]) -> list[LoopRow]:
    """The rows, typed, in the order of the ranking rule."""
    return sorted((as_row(r) for r in rows), key=rank_key)


def render_index_html(rows: Sequence[LoopRow | Mapping]) -> str:
    """Index page over all loops of a report (stiction first, most confident first)."""
    head = (
        "<tr><th>loop</th><th>loop type</th><th>verdict</th><th>P(valve)</th>"
        "<th>S [%] (interval)</th><th>J [%] (interval)</th><th>period</th>"
        "<th>gap effect</th><th>warnings</th></tr>"
    )
    body = []
    ranked = _ranked(rows)
    for r in ranked:
        loop = _text(r.loop)
        v = str(r.verdict)
        v_class = v if v in _VERDICT_RANK else "unknown"
        cell = f'<a href="{escape(str(r.page))}">{loop}</a>' if r.page else loop
        if v == "error":
            body.append(
                f"<tr><td>{cell}</td><td></td><td><span class='verdict error'>failed</span></td>"
                f"<td colspan='6'>{_text(r.error)}</td></tr>"
            )
            continue
        body.append(
            f"<tr><td>{cell}</td><td>{_loop_type(r)}</td>"
            f"<td><span class='verdict {v_class}'>{_text(v.replace('_', ' '))}</span></td>"
            f"<td class='num'>{_num(r.shown_probability, '.2f')}</td>"
            f"<td class='num'>{_row_param(r, 'S')}</td>"
            f"<td class='num'>{_row_param(r, 'J')}</td>"
            f"<td class='num'>{_text(duration_text(r.period_s))}</td>"
            f"<td>{_text(r.gap_effect or '')}</td>"
            f'<td title="{_text(r.flags or "")}">{r.n_warnings or 0}</td></tr>'
        )
    body_html = (
        f"<h1>Stiction report</h1><p>{_counts(ranked)}, {escape(RANKING_RULE)}.</p>"
        f"<table>{head}{''.join(body)}</table>"
        '<p class="muted">S: deadband + stickband, J: slip jump, both in % of the valve '
        "span (Choudhury, Thornhill &amp; Shah 2005); in parentheses the interval of values "
        f"the data cannot tell apart from the estimate. {escape(P_VALVE_WORDS)}; the "
        f"verdict is stiction at P(valve) {VALVE_LEVEL:g} or above, no stiction at "
        f"{1 - VALVE_LEVEL:g} or below (with mv: P(stiction) above {STICTION_LEVEL:g}, "
        f"below {NO_STICTION_LEVEL:g}), inconclusive between.</p>"
    )
    return html_page("stiction report", body_html)


def render_markdown(rows: Sequence[LoopRow | Mapping]) -> str:
    """Markdown summary over all loops (for a CI job summary)."""
    ranked = _ranked(rows)
    lines = [
        "## Stiction report",
        "",
        _counts(ranked) + ".",
        "",
        "| loop | verdict | P(valve) | S [%] | J [%] | gap effect | warnings |",
        "|---|---|---|---|---|---|---|",
    ]
    failed = []
    for r in ranked:
        v = str(r.verdict)
        if v == "error":
            failed.append(r)
            lines.append(f"| {md_escape(r.loop)} | failed | | | | | |")
            continue
        s_iv = _row_param(r, "S", html=False).replace("&ndash;", "-")
        j_iv = _row_param(r, "J", html=False).replace("&ndash;", "-")
        lines.append(
            f"| {md_escape(r.loop)} | {md_escape(v.replace('_', ' '))} | "
            f"{_num(r.shown_probability, '.2f')} | {md_escape(s_iv)} | {md_escape(j_iv)} | "
            f"{md_escape(r.gap_effect or '')} | {int(r.n_warnings or 0)} |"
        )
    if failed:
        lines += ["", "Failed:", ""]
        lines += [f"- {md_escape(r.loop)}: {md_escape(r.error)}" for r in failed]
    return "\n".join(lines) + "\n"
