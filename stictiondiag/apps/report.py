"""Reports for people and for CI: self-contained HTML, a Markdown summary, JSON.

A report folder holds, per loop, ``<loop>.html`` (plots embedded as base64 PNG, no
external assets: it opens offline) and ``<loop>.json`` (the full
:meth:`Analysis.to_dict`); over all loops an ``index.html``, ``summary.md`` (for a CI
job summary) and ``rows.json`` (the index rows, read back by the next run).  Every file
is written whole or not at all (:mod:`stictiondiag.core.atomic`).  An existing folder is
updated: loops of earlier runs stay listed in the index unless ``clean`` is asked for.

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped in HTML and in Markdown, so a column called ``<script>`` shows as text.  The
pages also carry a Content-Security-Policy that allows only their own inline style and
script and ``data:`` images, so nothing is fetched from the network and nothing
injected could run.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
import os
import re
import shutil
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path

from stictiondiag.core.errors import (
    DataError,
    StictionError,
    UsageError,
)

__all__ = [
    "ReportResult",
    "build_report",
    "md_escape",
    "render_index_html",
    "render_loop_html",
    "render_markdown",
    "safe_name",
]

#: Name of the file that marks a folder as a stiction report and keeps its index rows.
ROWS_FILE = "rows.json"

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:1.2em auto;max-width:1120px;
color:#222;padding:0 1em;line-height:1.4}
h1{font-size:1.5em;margin:.2em 0} h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
a{color:#0b57a4} .muted{color:#666;font-size:.9em}
table{border-collapse:collapse;font-size:13px;margin:.5em 0}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:left;vertical-align:middle}
th{background:#f2f2f2} td.num{text-align:right;font-variant-numeric:tabular-nums}
.verdict{display:inline-block;padding:.15em .6em;border-radius:4px;font-weight:600}
.stiction{background:#fde2e1} .inconclusive{background:#fff5d6} .no_stiction{background:#e3f5e1}
.error{background:#e6e6e6} .unknown{background:#eee}
.cards{display:flex;flex-wrap:wrap;gap:.6em;margin:.8em 0}
.card{border:1px solid #ddd;border-radius:6px;padding:.45em .8em;min-width:9em;background:#fafafa}
.card .label{font-size:.75em;color:#666;text-transform:uppercase;letter-spacing:.03em}
.card .value{font-size:1.15em;font-weight:600}
.card .sub{font-size:.8em;color:#555}
figure{margin:1em 0} figcaption{font-size:.85em;color:#444;margin-top:.3em;max-width:900px}
img{max-width:100%;height:auto;border:1px solid #eee}
.warn{color:#8a5300} code{background:#f5f5f5;padding:0 .2em;word-break:break-all}
svg.iv{vertical-align:middle}
details{margin:.4em 0} pre{background:#f7f7f7;padding:.5em;overflow:auto;font-size:12px}
"""

# Marks the page as fully loaded with all images decoded (read by the browser test and
# useful to any page checker): data-images-loaded="<decoded>/<total>".
_LOAD_JS = """
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute('data-images-loaded', ok + '/' + imgs.length);
});
"""


def _csp_hash(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'"


# Only this page's own style and script run; images only from data: URLs. Anything
# injected through the data (were escaping ever to fail) or any external asset is
# blocked by the browser.
_CSP = (
    f"default-src 'none'; img-src data:; style-src {_csp_hash(_CSS)}; "
    f"script-src {_csp_hash(_LOAD_JS)}; base-uri 'none'; form-action 'none'"
)

_VERDICT_RANK = {"stiction": 0, "inconclusive": 1, "error": 2, "no_stiction": 3}

_CAPTIONS = {
    "phase": (
        "Time trends (left) and phase plots (right), signals mean-centred with unit "
        "variance as in Figs. 3-6 of Choudhury, Thornhill & Shah (2005). A stuck valve "
        "shows as flat mv during op ramps and a parallelogram in the mv-op plot; dashed: "
        "the fitted valve model."
    ),
    "reconstruction": (
        "Closed-loop reconstruction: the fitted valve replayed with the identified "
        "controller and process (Sections 4.2.2 and 5.3), against the recorded data."
    ),
    "gap_breakdown": (
        "Sim-to-real gap: where the replay departs from the data, by signal, valve "
        "phase, frequency and time, and how each candidate effect changes the gap on "
        "held-out data."
    ),
    "gap_replay": (
        "Sim-to-real gap: the replay against the data before and after adding the most "
        "likely effect."
    ),
}


def _page(title: str, body: str) -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        '<link rel="icon" href="data:,">'
        f"<title>{escape(title)}</title><style>{_CSS}</style></head>"
        f"<body>\n{body}\n<script>{_LOAD_JS}</script>\n</body></html>\n"
    )


def _num(v, spec=".3g") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int | float):
        if not math.isfinite(float(v)):
            return "n/a"
        return format(round(v) if spec.endswith("d") else v, spec)
    return escape(str(v))


def _text(v) -> str:
    """Any value from the data as escaped HTML text."""
    return escape("" if v is None else str(v))


def md_escape(text) -> str:
    """Escape text for Markdown table cells and prose (no HTML, no formatting).

    ``<`` and ``>`` become entities (a tag shows as text), Markdown punctuation is
    backslash-escaped and ``|`` is escaped last so that it cannot end a table cell.
    """
    text = escape(str(text), quote=False)  # <script> -> &lt;script&gt;
    text = re.sub(r"\s*[\r\n]+\s*", " ", text)
    text = re.sub(r"([\\`*_{}\[\]()#+!~>])", r"\\\1", text)
    return text.replace("|", "\\|")


def _img(png: bytes, alt: str) -> str:
    b64 = base64.b64encode(png).decode("ascii")
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{b64}">'


def _figure(name: str, png: bytes) -> str:
    caption = _CAPTIONS.get(name) or (
        "Sim-to-real gap: " + name.removeprefix("gap").strip("_ ").replace("_", " ")
        if name.startswith("gap")
        else name.replace("_", " ")
    )
    return f"<figure>{_img(png, name)}<figcaption>{escape(caption)}</figcaption></figure>"


def _kv_table(rows: Sequence[tuple[str, str]]) -> str:
    """Two-column table; keys are escaped here, values must be escaped HTML already."""
    return (
        "<table>"
        + "".join(f"<tr><th>{escape(k)}</th><td>{v}</td></tr>" for k, v in rows)
        + "</table>"
    )


def _interval_text(iv) -> str:
    if not iv or len(iv) != 2 or None in iv:
        return "not determined"
    return f"{_num(iv[0])} to {_num(iv[1])}"


def _interval_svg(value, iv, x_max: float, label: str) -> str:
    """Inline bar: the interval as a band and the estimate as a dot on 0..x_max."""
    width, height, pad = 220, 18, 6
    if value is None or not x_max > 0:
        return ""

    def x(v: float) -> float:
        return pad + (width - 2 * pad) * min(max(v, 0.0), x_max) / x_max

    band = ""
    if iv and len(iv) == 2 and None not in iv:
        band = (
            f'<rect x="{x(iv[0]):.1f}" y="4" width="{max(x(iv[1]) - x(iv[0]), 1.5):.1f}" '
            'height="10" rx="2" fill="#9cc3e6"/>'
        )
    return (
        f'<svg class="iv" width="{width}" height="{height}" role="img" '
        f'aria-label="{escape(label)}"><title>{escape(label)}</title>'
        f'<line x1="{pad}" y1="9" x2="{width - pad}" y2="9" stroke="#bbb"/>{band}'
        f'<circle cx="{x(value):.1f}" cy="9" r="4" fill="#0b3d6b"/></svg>'
    )


def _card(label: str, value: str, sub: str = "") -> str:
    sub_html = f'<div class="sub">{sub}</div>' if sub else ""
    return (
        f'<div class="card"><div class="label">{escape(label)}</div>'
        f'<div class="value">{value}</div>{sub_html}</div>'
    )


def _params(d: dict | None, names: Sequence[tuple[str, str, str]]) -> str:
    """``symbol = value unit`` for the keys present in ``d``."""
    if not d:
        return "n/a"
    parts = [
        f"{sym} = {_num(d.get(key))}{unit}" for key, sym, unit in names if d.get(key) is not None
    ]
    return escape(", ".join(parts)) if parts else "n/a"


def _process_text(p: dict | None) -> str:
    if not p:
        return "n/a"
    kind = str(p.get("type") or "process")
    text = f"{escape(kind.upper() if kind == 'foptd' else kind)}: " + _params(
        p,
        [
            ("gain", "K", ""),
            ("time_constant_s", "\u03c4", " s"),
            ("dead_time_s", "\u03b8", " s"),
        ],
    )
    if p.get("fit_r2") is not None:
        text += f" (R\u00b2 {_num(p.get('fit_r2'), '.2f')})"
    return text


def _controller_text(c: dict | None) -> str:
    if not c:
        return "n/a"
    kind = str(c.get("type") or "controller").upper()
    text = f"{escape(kind)}: " + _params(
        c,
        [
            ("gain", "Kc", ""),
            ("integral_time_s", "Ti", " s"),
            ("op_bias", "op bias", " %"),
        ],
    )
    if c.get("fit_r2") is not None:
        text += f" (R\u00b2 {_num(c.get('fit_r2'), '.2f')})"
    return text


def _param_text(params) -> str:
    """Readable ``name = value`` list of effect parameters (numbers to 3 digits)."""
    if not isinstance(params, dict):
        return _text(json.dumps(params, default=str)) if params is not None else ""
    parts = []
    for k, v in params.items():
        if isinstance(v, bool) or v is None:
            parts.append(f"{k} = {v}")
        elif isinstance(v, int | float):
            parts.append(f"{k} = {_num(v)}")
        elif isinstance(v, str):
            parts.append(f"{k} = {v}")
        elif isinstance(v, list | tuple | dict):
            parts.append(f"{k}: {len(v)} entries")
        else:
            parts.append(f"{k} = {v}")
    return _text(", ".join(parts))


def _period(v) -> str:
    return "no cycle" if v is None else f"{_num(v)} s"


def _json_details(summary: str, obj) -> str:
    if not obj:
        return ""
    return (
        f"<details><summary>{escape(summary)}</summary>"
        f"<pre>{escape(json.dumps(obj, indent=1, default=str))}</pre></details>"
    )


def render_loop_html(d: dict, images: dict[str, bytes], *, json_name: str | None = None) -> str:
    """HTML page for one loop.

    Parameters
    ----------
    d : dict
        :meth:`stictiondiag.analysis.Analysis.to_dict` of the loop.
    images : dict
        Figure name -> PNG bytes (``phase``, ``reconstruction``, gap plots).
    json_name : str, optional
        File name of the loop's JSON next to the page, linked from the header.

    Returns
    -------
    str
        A complete, self-contained HTML document.
    """
    st = d.get("stiction") or {}
    tg = d.get("tags") or {}
    osc = (d.get("oscillation") or {}).get("pv") or {}
    rep = d.get("replay") or None
    gap = d.get("gap") or None
    warnings = list(d.get("warnings") or [])
    status = str(st.get("status") or st.get("verdict") or "unknown")
    status_class = status if status in _VERDICT_RANK else "unknown"
    S, J = st.get("S"), st.get("J")
    si, ji = st.get("S_interval"), st.get("J_interval")
    ends = [
        v
        for v in (S, J, *(si or []), *(ji or []))
        if isinstance(v, int | float) and math.isfinite(v)
    ]
    x_max = 1.15 * max(ends) if ends and max(ends) > 0 else 1.0
    details = st.get("details") or {}
    determinacy = details.get("determinacy") or {}

    links = ['<a href="index.html">&larr; all loops</a>']
    if json_name:
        links.append(f'<a href="{escape(json_name)}">analysis JSON</a>')
    names = tg.get("names") or {}
    parts = [
        f'<p class="muted">{" &middot; ".join(links)}</p>',
        f"<h1>Loop {_text(d.get('loop'))}</h1>",
        f'<p class="muted">source <code>{_text(d.get("source"))}</code> &middot; '
        f"{_num(tg.get('n_samples'), 'd')} samples at {_num(tg.get('ts_s'))} s &middot; "
        f"{_text(tg.get('loop_type'))} loop"
        f"{' (integrating)' if tg.get('integrating') else ''} &middot; tags "
        + ", ".join(f"{_text(k)} = <code>{_text(v)}</code>" for k, v in names.items())
        + "</p>",
    ]

    # Compact summary: everything a reader needs before scrolling.
    cards = [
        _card(
            "verdict",
            f'<span class="verdict {status_class}">{_text(status.replace("_", " "))}</span>',
            f"confidence {_num(st.get('confidence'), '.2f')}",
        ),
        _card(
            "S (deadband + stickband)",
            f"{_num(S)} %",
            f"interval {_interval_text(si)}",
        ),
        _card("J (slip jump)", f"{_num(J)} %", f"interval {_interval_text(ji)}"),
        _card(
            "oscillation",
            f"{_num(osc.get('period_s'), '.4g')} s" if osc.get("present") else "none",
            f"regularity {_num(osc.get('regularity'), '.3g')}" if osc.get("present") else "",
        ),
    ]
    if rep:
        per = rep.get("period_s") or {}
        fit_pv = (rep.get("fit") or {}).get("pv")
        cards.append(
            _card(
                "reconstruction",
                f"pv fit {_num(fit_pv, '.0f')} %" if fit_pv is not None else "n/a",
                f"period {_period(per.get('data'))} data / {_period(per.get('replay'))} replay",
            )
        )
    if gap:
        cards.append(
            _card(
                "gap effect",
                _text(gap.get("effect")),
                f"gap shrinks {_num(gap.get('shrink_pct'), '.0f')} %",
            )
        )
    cards.append(
        _card(
            "warnings",
            f'<a href="#warnings">{len(warnings)}</a>' if warnings else "0",
        )
    )
    parts.append('<div class="cards">' + "".join(cards) + "</div>")

    reasons = st.get("reasons") or []
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{_text(r)}</li>" for r in reasons) + "</ul>")
    parts.append(_json_details("verdict evidence", st.get("evidence")))

    parts.append("<h2>Stiction parameters</h2>")
    interval_note = details.get("interval_method")
    rows = []
    for sym, name, value, iv, scaled in (
        ("S", "deadband + stickband", S, si, st.get("S_scaled")),
        ("J", "slip jump", J, ji, st.get("J_scaled")),
    ):
        rows.append(
            f"<tr><th>{sym}</th><td>{name}</td><td class='num'>{_num(value)}</td>"
            f"<td>{_interval_text(iv)}</td>"
            f"<td>{_interval_svg(value, iv, x_max, f'{sym} {_num(value)} %, interval {_interval_text(iv)}')}</td>"
            f"<td class='num'>{_num(scaled)}</td><td>{_text(determinacy.get(sym, ''))}</td></tr>"
        )
    parts.append(
        "<table><tr><th></th><th>parameter</th><th>estimate [% of op span]</th>"
        "<th>interval [% of op span]</th><th>0 &ndash; "
        f"{_num(x_max, '.3g')} %</th><th>scaled [op std]</th><th>determined</th></tr>"
        + "".join(rows)
        + "</table>"
    )
    parts.append(
        f'<p class="muted">method <code>{_text(st.get("method"))}</code>'
        f" &middot; {_num(st.get('n_slips'), 'd')} slips"
        + (
            f" &middot; the stiction model removes {_num(100 * st['improvement'], '.0f')} % "
            "of the linear valve's residual"
            if isinstance(st.get("improvement"), int | float)
            else ""
        )
        + (f"<br>interval: {_text(interval_note)}" if interval_note else "")
        + "</p>"
    )

    parts.append('<h2 id="warnings">Data-quality warnings</h2>')
    parts.append(
        "<ul>" + "".join(f'<li class="warn">{_text(w)}</li>' for w in warnings) + "</ul>"
        if warnings
        else "<p>None.</p>"
    )

    if "phase" in images:
        parts += ["<h2>Phase plots and trends</h2>", _figure("phase", images["phase"])]

    parts.append("<h2>Closed-loop reconstruction</h2>")
    if rep:
        fit = rep.get("fit") or {}
        per = rep.get("period_s") or {}
        amp = rep.get("amplitude") or {}
        parts.append(
            _kv_table(
                [
                    ("process", _process_text(rep.get("process"))),
                    ("controller", _controller_text(rep.get("controller"))),
                    (
                        f"period of {rep.get('period_signal') or 'pv'}, data / replay [s]",
                        f"{_num(per.get('data'))} / {_num(per.get('replay'))}",
                    ),
                    (
                        "fit, 100 (1 - NRMSE) [%]",
                        escape(
                            ", ".join(
                                f"{k} {_num(v, '.0f')}"
                                for k, v in fit.items()
                                if not isinstance(v, dict)
                            )
                        )
                        or "n/a",
                    ),
                    (
                        "amplitude, data / replay",
                        escape(
                            ", ".join(
                                f"{k} {_num((v or {}).get('data'))} / {_num((v or {}).get('replay'))}"
                                for k, v in amp.items()
                                if isinstance(v, dict)
                            )
                        )
                        or "n/a",
                    ),
                ]
            )
        )
        if "reconstruction" in images:
            parts.append(_figure("reconstruction", images["reconstruction"]))
    else:
        parts.append("<p>No replay (see the warnings).</p>")

    parts.append("<h2>Sim-to-real gap</h2>")
    if gap:
        parts.append(
            _kv_table(
                [
                    ("metric", _text(gap.get("metric_name") or gap.get("metric"))),
                    (
                        "gap before / after",
                        f"{_num(gap.get('before'))} / {_num(gap.get('after'))}",
                    ),
                    ("shrink", f"{_num(gap.get('shrink_pct'), '.0f')} %"),
                    ("most likely effect", f"<strong>{_text(gap.get('effect'))}</strong>"),
                    ("runner-up", _text(gap.get("runner_up"))),
                    ("margin", _num(gap.get("margin"))),
                ]
            )
        )
        cands = gap.get("candidates") or []
        if cands:
            parts.append(
                "<table><tr><th>candidate effect</th><th>gap after</th><th>shrink %</th>"
                "<th>parameters</th></tr>"
                + "".join(
                    f"<tr><td>{_text(c.get('effect'))}</td><td class='num'>{_num(c.get('after'))}</td>"
                    f"<td class='num'>{_num(c.get('shrink_pct'), '.0f')}</td>"
                    f"<td>{_param_text(c.get('params'))}</td></tr>"
                    for c in cands
                )
                + "</table>"
            )
        parts.append(_json_details("gap breakdown", gap.get("breakdown")))
    elif gap is None and rep:
        parts.append("<p>Not run.</p>")
    else:
        parts.append("<p>Not run (needs the reconstruction).</p>")
    for name, png in images.items():
        if name not in ("phase", "reconstruction"):
            parts.append(_figure(name, png))
    return _page(f"stiction: {d.get('loop')}", "\n".join(p for p in parts if p))


def _sort_key(r: dict):
    v = str(r.get("verdict"))
    conf = r.get("confidence")
    conf = float(conf) if isinstance(conf, int | float) and math.isfinite(conf) else 0.0
    # Stiction first, most confident first: the maintenance order.
    return (_VERDICT_RANK.get(v, 2), -conf if v == "stiction" else 0.0, str(r.get("loop")))


def _counts(rows: Sequence[dict]) -> str:
    n = {k: sum(1 for r in rows if r.get("verdict") == k) for k in _VERDICT_RANK}
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


def render_index_html(rows: Sequence[dict]) -> str:
    """Index page over all loops of a report (stiction first, most confident first)."""
    head = (
        "<tr><th>loop</th><th>verdict</th><th>confidence</th><th>S [%] (interval)</th>"
        "<th>J [%] (interval)</th><th>period [s]</th><th>gap effect</th><th>warnings</th></tr>"
    )
    body = []
    for r in sorted(rows, key=_sort_key):
        loop = _text(r.get("loop"))
        v = str(r.get("verdict"))
        v_class = v if v in _VERDICT_RANK else "unknown"
        page = r.get("page")
        cell = f'<a href="{escape(str(page))}">{loop}</a>' if page else loop
        if v == "error":
            body.append(
                f"<tr><td>{cell}</td><td><span class='verdict error'>failed</span></td>"
                f"<td colspan='6'>{_text(r.get('error'))}</td></tr>"
            )
            continue
        n_warn = r.get("n_warnings") or 0
        body.append(
            f"<tr><td>{cell}</td>"
            f"<td><span class='verdict {v_class}'>{_text(v.replace('_', ' '))}</span></td>"
            f"<td class='num'>{_num(r.get('confidence'), '.2f')}</td>"
            f"<td class='num'>{_value_interval(r.get('S'), r.get('S_lo'), r.get('S_hi'))}</td>"
            f"<td class='num'>{_value_interval(r.get('J'), r.get('J_lo'), r.get('J_hi'))}</td>"
            f"<td class='num'>{_num(r.get('period_s'), '.4g')}</td>"
            f"<td>{_text(r.get('gap_effect') or '')}</td>"
            f'<td title="{_text(r.get("flags") or "")}">{n_warn}</td></tr>'
        )
    body_html = (
        f"<h1>Stiction report</h1><p>{_counts(rows)}.</p>"
        f"<table>{head}{''.join(body)}</table>"
        '<p class="muted">S: deadband + stickband, J: slip jump, both in % of the valve '
        "span (Choudhury, Thornhill &amp; Shah 2005); in parentheses the interval of values "
        "the data cannot tell apart from the estimate.</p>"
    )
    return _page("stiction report", body_html)


def render_markdown(rows: Sequence[dict]) -> str:
    """Markdown summary over all loops (for a CI job summary)."""
    lines = [
        "## Stiction report",
        "",
        _counts(rows) + ".",
        "",
        "| loop | verdict | confidence | S [%] | J [%] | gap effect | warnings |",
        "|---|---|---|---|---|---|---|",
    ]
    failed = []
    for r in sorted(rows, key=_sort_key):
        v = str(r.get("verdict"))
        if v == "error":
            failed.append(r)
            lines.append(f"| {md_escape(r.get('loop'))} | failed | | | | | |")
            continue
        s_iv = _value_interval(r.get("S"), r.get("S_lo"), r.get("S_hi")).replace("&ndash;", "-")
        j_iv = _value_interval(r.get("J"), r.get("J_lo"), r.get("J_hi")).replace("&ndash;", "-")
        lines.append(
            f"| {md_escape(r.get('loop'))} | {md_escape(v.replace('_', ' '))} | "
            f"{_num(r.get('confidence'), '.2f')} | {md_escape(s_iv)} | {md_escape(j_iv)} | "
            f"{md_escape(r.get('gap_effect') or '')} | {int(r.get('n_warnings') or 0)} |"
        )
    if failed:
        lines += ["", "Failed:", ""]
        lines += [f"- {md_escape(r.get('loop'))}: {md_escape(r.get('error'))}" for r in failed]
    return "\n".join(lines) + "\n"


def safe_name(loop: str) -> str:
    """File-system-safe name of a loop (letters, digits, ``-``, ``_`` and ``.``)."""
    keep = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in str(loop))
    return keep.strip(".") or "loop"


@dataclass(frozen=True)
class ReportResult:
    """Outcome of :func:`build_report`.

    Attributes
    ----------
    rows : list of dict
        One summary row per loop in the index (this run's and earlier runs'), in the
        index's order; failed loops have ``verdict == "error"`` and an ``error``.
    failed : list of (str, str)
        Inputs of this run that could not be analysed: (file, one-line message).
    outputs : dict
        Paths of ``index`` and ``markdown``.
    """

    rows: list
    failed: list = field(default_factory=list)
    outputs: dict = field(default_factory=dict)

    def max_stiction_confidence(self) -> float | None:
        """Highest confidence among loops called stiction; None when there is none."""
        vals = [
            float(r.get("confidence") or 0.0) for r in self.rows if r.get("verdict") == "stiction"
        ]
        return max(vals) if vals else None


def _prepare_folder(out: Path, clean: bool) -> None:
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a folder for the report")
    if clean and out.exists():
        # Only a folder this function wrote (or an empty one) is ever emptied.
        if any(out.iterdir()) and not (out / ROWS_FILE).exists():
            raise UsageError(
                f"refusing to clean {out}: it is not a stiction report folder (no {ROWS_FILE}); "
                "choose another --out or empty it yourself"
            )
        shutil.rmtree(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"cannot create the report folder {out}: {(exc.strerror or str(exc)).lower()}; "
            "choose a writable --out"
        ) from None


def _read_rows(out: Path) -> dict[str, dict]:
    try:
        return {str(r["loop"]): r for r in json.loads((out / ROWS_FILE).read_text())}
    except (OSError, ValueError, KeyError, TypeError):
        # No earlier report, or an unreadable index: start the index afresh (the loop
        # pages on disk are left alone).
        return {}


def _check_names(files: Sequence[str | os.PathLike]) -> None:
    seen: dict[str, str] = {}
    for f in files:
        key = safe_name(Path(f).stem)
        if key in seen and seen[key] != str(f):
            raise UsageError(
                f"{seen[key]} and {f} would share the report page {key}.html; "
                "rename one of them or report them into separate folders"
            )
        seen[key] = str(f)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def analyse_for_report(path: str, read_options: dict, gap: bool) -> dict:
    """Analyse one loop file and render its page; never raises for a bad loop.

    Module-level so that it runs in worker processes. Returns ``{"file", "loop",
    "base", "page", "json", "row"}`` on success, ``{"file", "loop", "error"}`` when the
    loop could not be analysed (one line: the data error, or the internal error and
    where it arose).
    """
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze_file,
    )

    name = Path(path).stem
    try:
        result = analyze_file(path, config=AnalysisConfig(gap=gap), **read_options)
        d = result.to_dict()
        from stictiondiag.plotting import figure_png

        images = {k: figure_png(fig) for k, fig in result.figures().items()}
        base = safe_name(result.loop)
        row = result.summary_row()
        row["page"] = f"{base}.html"
        return {
            "file": str(path),
            "loop": str(result.loop),
            "base": base,
            "page": render_loop_html(d, images, json_name=f"{base}.json"),
            "json": json.dumps(d, indent=2) + "\n",
            "row": row,
        }
    except StictionError as exc:
        message = _first_line(exc)
    except Exception as exc:  # one broken loop must not stop the report of the others
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {last[0].name}" if last else ""
        message = f"internal error{where}: {type(exc).__name__}: {_first_line(exc)}"
    return {"file": str(path), "loop": name, "error": message}


def _worker_died(path, exc: BaseException) -> dict:
    return {
        "file": str(path),
        "loop": Path(path).stem,
        "error": f"internal error: the analysis process failed ({type(exc).__name__})",
    }


def default_workers(n_files: int) -> int:
    """Worker processes for ``n_files`` loops: one per core (less one) on 4 cores or more.

    Each worker process pays the imports (about 3 s of CPU) before its first loop;
    with one or two cores that costs more than analysing side by side gains, so the
    loops are then analysed one after the other in this process.
    """
    try:
        cores = len(os.sched_getaffinity(0))  # the cores this process may use
    except AttributeError:  # not on every platform
        cores = os.cpu_count() or 1
    if cores < 4 or n_files < 2:
        return 1
    return min(n_files, cores - 1)


def build_report(
    files: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    read_options: dict | None = None,
    gap: bool = True,
    clean: bool = False,
    workers: int | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> ReportResult:
    """Analyse ``files`` and write (or update) the report folder ``out``.

    Parameters
    ----------
    files : sequence of path
        One loop per file (CSV or Parquet, see :func:`stictiondiag.io.tags.read_tags`).
        The loop's name is the file's stem.
    out : path
        Report folder; created if missing. Loops of earlier runs stay in the index.
    read_options : dict, optional
        Keyword arguments for :func:`read_tags` (column names, ``ts``, ...).
    gap : bool
        Run the sim-to-real gap diagnosis (the slowest step).
    clean : bool
        Empty ``out`` first (only a report folder or an empty folder).
    workers : int, optional
        Processes analysing loops side by side (default :func:`default_workers`);
        1 analyses them one after the other in this process.
    progress : callable, optional
        ``progress(done, n, loop)`` after each loop is finished (in completion order
        when ``workers`` > 1).

    Returns
    -------
    ReportResult

    Raises
    ------
    UsageError
        ``out`` is a file, cannot be created, is not a report folder to clean, two
        inputs would share one page, or ``workers`` < 1.
    DataError
        No input could be analysed (the index is written all the same).
    """
    from stictiondiag.apps.scan import run_local
    from stictiondiag.core.atomic import write_atomic

    out = Path(out)
    files = [str(f) for f in files]
    workers = default_workers(len(files)) if workers is None else int(workers)
    if workers < 1:
        raise UsageError(f"workers must be at least 1, got {workers}")
    _check_names(files)
    _prepare_folder(out, clean)
    rows = _read_rows(out)
    failed: list[tuple[str, str]] = []
    outcomes = run_local(
        files,
        analyse_for_report,
        (dict(read_options or {}), bool(gap)),
        min(workers, max(1, len(files))),
        on_error=_worker_died,
    )
    for done, res in enumerate(outcomes, start=1):
        if "error" in res:
            failed.append((res["file"], res["error"]))
            rows[res["loop"]] = {
                "loop": res["loop"],
                "source": res["file"],
                "verdict": "error",
                "error": res["error"],
            }
        else:
            # Written here, not in the worker: an output that cannot be written stops
            # the report (a usage error) instead of being blamed on the loop.
            write_atomic(out / f"{res['base']}.json", res["json"])
            write_atomic(out / f"{res['base']}.html", res["page"])
            rows[res["loop"]] = res["row"]
        if progress:
            progress(done, len(files), res["loop"])
    # Failures in file order, so the message of an all-failed run names the first file.
    failed.sort(key=lambda fm: files.index(fm[0]))
    ordered = sorted(rows.values(), key=_sort_key)
    write_atomic(out / ROWS_FILE, json.dumps(ordered, indent=1, default=str) + "\n")
    write_atomic(out / "index.html", render_index_html(ordered))
    write_atomic(out / "summary.md", render_markdown(ordered))
    if failed and len(failed) == len(files):
        # Nothing could be read: the caller reports a data error.
        raise DataError(f"no input could be analysed; {failed[0][0]}: {failed[0][1]}")
    return ReportResult(
        ordered,
        failed,
        {"index": str(out / "index.html"), "markdown": str(out / "summary.md")},
    )
