"""HTML pages and the Markdown summary of a stiction report (see :mod:`stictiondiag.apps.report`).

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped in HTML and in Markdown, so a column called ``<script>`` shows as text.  The
pages also carry a Content-Security-Policy (:func:`stictiondiag.apps.pages.html_page`).
"""

from __future__ import annotations

import base64
import json
import math
import re
from collections.abc import Sequence
from html import escape

from stictiondiag.apps.findings import (
    determinacy,
    findings_from_dict,
    is_poorly_determined,
    param_note,
    probability_text,
)
from stictiondiag.apps.pages import RANKING_RULE, duration_text, html_page, rank_key
from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

__all__ = ["md_escape", "render_index_html", "render_loop_html", "render_markdown", "sort_key"]

_VERDICT_RANK = {"stiction": 0, "inconclusive": 1, "error": 2, "no_stiction": 3}

_CAPTIONS = {
    "phase": (
        "Time trends (left) and phase plots (right), signals mean-centred with unit "
        "variance as in Figs. 3-6 of Choudhury, Thornhill & Shah (2005). A stuck valve "
        "shows as flat mv during op ramps and a parallelogram in the mv-op plot; dashed: "
        "the fitted valve model."
    ),
    "valve_zoom": (
        "The last few cycles of mv against op (of the fitted model when mv is not "
        "recorded), both in % of span, with the fitted S (deadband + stickband, along "
        "op) and J (slip jump, along mv) drawn at the largest slip, as in Fig. 10 of "
        "Choudhury, Thornhill & Shah (2005)."
    ),
    "reconstruction": (
        "Closed-loop reconstruction: the fitted valve replayed with the identified "
        "controller and process (Sections 4.2.2 and 5.3), against the recorded data. "
        "The panel titles give the amplitude error and the waveform agreement of the "
        "phase-aligned average cycle (1 = same shape)."
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
    return "no cycle" if v is None else _text(duration_text(v))


def _json_details(summary: str, obj) -> str:
    if not obj:
        return ""
    return (
        f"<details><summary>{escape(summary)}</summary>"
        f"<pre>{escape(json.dumps(obj, indent=1, default=str))}</pre></details>"
    )


def _duration_text(seconds) -> str:
    """A duration in the unit that reads best (s, min, h or days)."""
    if not isinstance(seconds, int | float) or not math.isfinite(seconds):
        return "n/a"
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def _header(d: dict, json_name: str | None, index_href: str) -> list[str]:
    """Links, title, source, data span and analysis date, loop type and its source."""
    tg = d.get("tags") or {}
    links = [f'<a href="{escape(index_href)}">&larr; all loops</a>']
    if json_name:
        links.append(f'<a href="{escape(json_name)}">analysis JSON</a>')
    names = tg.get("names") or {}
    start = tg.get("start")
    span = (
        f"{_num(tg.get('n_samples'), 'd')} samples at {_num(tg.get('ts_s'))} s = "
        f"{_duration_text(tg.get('duration_s'))}" + (f" from {_text(start)}" if start else "")
    )
    loop_type_source = tg.get("loop_type_source") or "user/default"
    return [
        f'<p class="muted">{" &middot; ".join(links)}</p>',
        f"<h1>Loop {_text(d.get('loop'))}</h1>",
        f'<p class="muted">source <code>{_text(d.get("source"))}</code> &middot; tags '
        + ", ".join(f"{_text(k)} = <code>{_text(v)}</code>" for k, v in names.items())
        + "</p>",
        _kv_table(
            [
                ("data span", f'<span id="data-span">{span}</span>'),
                (
                    "analysed",
                    f'<span id="analysed-at">{_text(d.get("analysed_at") or "n/a")}</span>',
                ),
                (
                    "loop type",
                    f'<span id="loop-type">{_text(tg.get("loop_type"))}'
                    f"{' (integrating)' if tg.get('integrating') else ''}</span>"
                    f' <span class="muted">from {_text(loop_type_source)}</span>',
                ),
            ]
        ),
    ]


def _param_card(st: dict, sym: str, label: str) -> str:
    """Card of S or J: value, and the interval or the poorly-determined note."""
    poor = is_poorly_determined(st, sym)
    unit = " %" if str(st.get("units") or "%").startswith("%") else " op units (scale unknown)"
    value = f"{_num(st.get(sym))}{unit}" + (
        ' <span class="poor">poorly determined</span>' if poor else ""
    )
    return _card(label, value, escape(param_note(st, sym)))


def _cards(d: dict, st: dict, warnings: list) -> str:
    """The compact summary: verdict with P(stiction), S, J, cycle, replay, gap."""
    osc = (d.get("oscillation") or {}).get("pv") or {}
    rep, gap = d.get("replay") or None, d.get("gap") or None
    status = str(st.get("status") or st.get("verdict") or "unknown")
    status_class = status if status in _VERDICT_RANK else "unknown"
    cards = [
        _card(
            "verdict",
            f'<span class="verdict {status_class}">{_text(status.replace("_", " "))}</span>',
            escape(probability_text(st)),
        ),
        _param_card(st, "S", "S (deadband + stickband)"),
        _param_card(st, "J", "J (slip jump)"),
        _card(
            "oscillation",
            _text(duration_text(osc.get("period_s"))) if osc.get("present") else "none",
            f"regularity {_num(osc.get('regularity'), '.3g')}" if osc.get("present") else "",
        ),
    ]
    if rep:
        m = rep.get("metrics") or {}
        per = m.get("period_error_pct")
        cards.append(
            _card(
                "reconstruction",
                f"period {per:+.0f} %" if isinstance(per, int | float) else "no period",
                escape(
                    "waveform agreement "
                    + ", ".join(
                        f"{k} {_num(v, '.2f')}" for k, v in (m.get("waveform") or {}).items()
                    )
                ),
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
    cards.append(_card("warnings", f'<a href="#warnings">{len(warnings)}</a>' if warnings else "0"))
    return '<div class="cards">' + "".join(cards) + "</div>"


def _findings_section(d: dict) -> str:
    """The findings in words (:mod:`stictiondiag.apps.findings`)."""
    f = findings_from_dict(d)
    rows = "".join(
        f"<tr><th>{escape(topic)}</th><td>{_text(text)}</td></tr>" for topic, text in f.items()
    )
    return f'<h2 id="findings">Findings</h2><table class="findings">{rows}</table>'


def _parameters_section(st: dict) -> list[str]:
    """Table of S and J with intervals, bars and determinacy; method and improvement."""
    S, J = st.get("S"), st.get("J")
    si, ji = st.get("S_interval"), st.get("J_interval")
    ends = [
        v
        for v in (S, J, *(si or []), *(ji or []))
        if isinstance(v, int | float) and math.isfinite(v)
    ]
    x_max = 1.15 * max(ends) if ends and max(ends) > 0 else 1.0
    details = st.get("details") or {}
    rows = []
    for sym, name, value, iv, scaled in (
        ("S", "deadband + stickband", S, si, st.get("S_scaled")),
        ("J", "slip jump", J, ji, st.get("J_scaled")),
    ):
        cls = ' class="poor"' if is_poorly_determined(st, sym) else ""
        label = f"{sym} {_num(value)} %, interval {_interval_text(iv)}"
        rows.append(
            f"<tr><th>{sym}</th><td>{name}</td><td class='num'>{_num(value)}</td>"
            f"<td>{_interval_text(iv)}</td>"
            f"<td>{_interval_svg(value, iv, x_max, label)}</td>"
            f"<td class='num'>{_num(scaled)}</td>"
            f"<td{cls}>{_text(determinacy(st, sym))}</td></tr>"
        )
    interval_note = details.get("interval_method")
    units = _text(st.get("units") or "% of op span")
    return [
        "<h2>Stiction parameters</h2>",
        f"<table><tr><th></th><th>parameter</th><th>estimate [{units}]</th>"
        f"<th>interval [{units}]</th><th>0 &ndash; "
        f"{_num(x_max, '.3g')}</th><th>scaled [op std]</th><th>determined</th></tr>"
        + "".join(rows)
        + "</table>",
        f'<p class="muted">method <code>{_text(st.get("method"))}</code>'
        f" &middot; {_num(st.get('n_slips'), 'd')} slips"
        + (
            f" &middot; the stiction model removes {_num(100 * st['improvement'], '.0f')} % "
            "of the linear valve's residual"
            if isinstance(st.get("improvement"), int | float)
            else ""
        )
        + (f"<br>interval: {_text(interval_note)}" if interval_note else "")
        + "</p>",
    ]


def _amplitude_text(amp: dict, errors: dict) -> str:
    parts = []
    for k, v in amp.items():
        if not isinstance(v, dict):
            continue
        err = errors.get(k)
        err_text = f" ({err:+.0f} %)" if isinstance(err, int | float) else ""
        parts.append(f"{k} {_num(v.get('data'))} / {_num(v.get('replay'))}{err_text}")
    return escape(", ".join(parts)) or "n/a"


def _replay_section(rep: dict | None, images: dict[str, bytes]) -> list[str]:
    """Identified models, period/amplitude/waveform agreement, NRMSE, the figure."""
    parts = ["<h2>Closed-loop reconstruction</h2>"]
    if not rep:
        return [*parts, "<p>No replay (see the warnings).</p>"]
    m = rep.get("metrics") or {}
    per = m.get("period_error_pct")
    parts.append(
        _kv_table(
            [
                ("process", _process_text(rep.get("process"))),
                ("controller", _controller_text(rep.get("controller"))),
                (
                    f"period of {m.get('period_signal') or rep.get('period_signal') or 'pv'}, "
                    "data / replay [s]",
                    f"{_num(m.get('period_data_s'))} / {_num(m.get('period_replay_s'))}"
                    + (f" (period error {per:+.0f} %)" if isinstance(per, int | float) else ""),
                ),
                (
                    "amplitude, data / replay (amplitude error) [signal units]",
                    _amplitude_text(m.get("amplitude") or {}, m.get("amplitude_error_pct") or {}),
                ),
                (
                    "waveform agreement, phase-aligned cycle [1 = same]",
                    escape(
                        ", ".join(
                            f"{k} {_num(v, '.2f')}" for k, v in (m.get("waveform") or {}).items()
                        )
                    )
                    or "n/a",
                ),
                (
                    "NRMSE, point by point [-] (punishes phase drift)",
                    escape(
                        ", ".join(
                            f"{k} {_num(v, '.2f')}" for k, v in (rep.get("nrmse") or {}).items()
                        )
                    )
                    or "n/a",
                ),
            ]
        )
    )
    if "reconstruction" in images:
        parts.append(_figure("reconstruction", images["reconstruction"]))
    return parts


def _gap_section(gap: dict | None, has_replay: bool, images: dict[str, bytes]) -> list[str]:
    """Gap table, candidate effects and the gap figures."""
    parts = ["<h2>Sim-to-real gap</h2>"]
    if gap:
        parts.append(
            _kv_table(
                [
                    ("metric", _text(gap.get("metric_name") or gap.get("metric"))),
                    (
                        "gap before / after [%]",
                        f"{_num(gap.get('before'))} / {_num(gap.get('after'))}",
                    ),
                    ("shrink", f"{_num(gap.get('shrink_pct'), '.0f')} %"),
                    ("most likely effect", f"<strong>{_text(gap.get('effect'))}</strong>"),
                    ("runner-up", _text(gap.get("runner_up"))),
                    ("margin [%]", _num(gap.get("margin"))),
                ]
            )
        )
        cands = gap.get("candidates") or []
        if cands:
            parts.append(
                "<table><tr><th>candidate effect</th><th>gap after [%]</th><th>shrink %</th>"
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
    elif has_replay:
        parts.append("<p>Not run.</p>")
    else:
        parts.append("<p>Not run (needs the reconstruction).</p>")
    for name, png in images.items():
        if name not in ("phase", "reconstruction", "valve_zoom"):
            parts.append(_figure(name, png))
    return parts


def render_loop_html(
    d: dict,
    images: dict[str, bytes],
    *,
    json_name: str | None = None,
    index_href: str = "../index.html",
) -> str:
    """HTML page for one loop.

    Parameters
    ----------
    d : dict
        :meth:`stictiondiag.analysis.Analysis.to_dict` of the loop.
    images : dict
        Figure name -> PNG bytes (``phase``, ``valve_zoom``, ``reconstruction``,
        gap plots).
    json_name : str, optional
        File name of the loop's JSON next to the page, linked from the header.
    index_href : str
        Link to the index page (the pages live in ``loops/``, beside nothing else).

    Returns
    -------
    str
        A complete, self-contained HTML document.
    """
    st = d.get("stiction") or {}
    warnings = list(d.get("warnings") or [])
    parts = _header(d, json_name, index_href)
    parts.append(_cards(d, st, warnings))
    parts.append(_findings_section(d))
    reasons = st.get("reasons") or []
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{_text(r)}</li>" for r in reasons) + "</ul>")
    parts.append(_json_details("verdict evidence", st.get("evidence")))
    parts += _parameters_section(st)
    parts.append('<h2 id="warnings">Data-quality warnings</h2>')
    parts.append(
        "<ul>" + "".join(f'<li class="warn">{_text(w)}</li>' for w in warnings) + "</ul>"
        if warnings
        else "<p>None.</p>"
    )
    if "phase" in images:
        parts += ["<h2>Phase plots and trends</h2>", _figure("phase", images["phase"])]
    if "valve_zoom" in images:
        parts += [
            '<h2 id="valve-signature">Valve signature: S and J on the mv&ndash;op plot</h2>',
            _figure("valve_zoom", images["valve_zoom"]),
        ]
    parts += _replay_section(d.get("replay") or None, images)
    parts += _gap_section(d.get("gap") or None, bool(d.get("replay")), images)
    return html_page(f"stiction: {d.get('loop')}", "\n".join(p for p in parts if p))


def sort_key(r: dict):
    """The ranking rule of every page (:data:`stictiondiag.apps.pages.RANKING_RULE`)."""
    return rank_key(r)


def _probability(r: dict):
    """P(stiction) of an index row; rows from before the probability was recorded
    carry only the confidence, which is P itself for a stiction verdict."""
    p = r.get("probability")
    if p is None and r.get("verdict") == "stiction":
        return r.get("confidence")
    return p


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


def _row_poorly(r: dict, sym: str) -> bool:
    """An index row's ``sym`` is poorly determined (``<sym>_determinacy``)."""
    st = {
        sym: r.get(sym),
        f"{sym}_interval": [r.get(f"{sym}_lo"), r.get(f"{sym}_hi")],
        "details": {"determinacy": {sym: r.get(f"{sym}_determinacy")}},
    }
    return is_poorly_determined(st, sym)


def _row_param(r: dict, sym: str, *, html: bool = True) -> str:
    """Value (interval) of an index row, marked when poorly determined."""
    text = _value_interval(r.get(sym), r.get(f"{sym}_lo"), r.get(f"{sym}_hi"))
    if not _row_poorly(r, sym):
        return text
    if html:
        return f'{text} <span class="poor" title="poorly determined">poorly determined</span>'
    return f"{text} poorly determined"


def _loop_type(r: dict) -> str:
    """``level (tag)``: an index row's loop type and what decided it."""
    kind = r.get("loop_type")
    if not kind:
        return ""
    if kind == "other":  # no named type: say what the replay assumes
        kind = "integrating" if r.get("integrating") else "self-regulating"
    source = r.get("loop_type_source")
    text = f"{kind} ({source})" if source else str(kind)
    return _text(text)


def render_index_html(rows: Sequence[dict]) -> str:
    """Index page over all loops of a report (stiction first, most confident first)."""
    head = (
        "<tr><th>loop</th><th>loop type</th><th>verdict</th><th>P(stiction)</th>"
        "<th>S [%] (interval)</th><th>J [%] (interval)</th><th>period</th>"
        "<th>gap effect</th><th>warnings</th></tr>"
    )
    body = []
    for r in sorted(rows, key=sort_key):
        loop = _text(r.get("loop"))
        v = str(r.get("verdict"))
        v_class = v if v in _VERDICT_RANK else "unknown"
        page = r.get("page")
        cell = f'<a href="{escape(str(page))}">{loop}</a>' if page else loop
        if v == "error":
            body.append(
                f"<tr><td>{cell}</td><td></td><td><span class='verdict error'>failed</span></td>"
                f"<td colspan='6'>{_text(r.get('error'))}</td></tr>"
            )
            continue
        n_warn = r.get("n_warnings") or 0
        body.append(
            f"<tr><td>{cell}</td><td>{_loop_type(r)}</td>"
            f"<td><span class='verdict {v_class}'>{_text(v.replace('_', ' '))}</span></td>"
            f"<td class='num'>{_num(_probability(r), '.2f')}</td>"
            f"<td class='num'>{_row_param(r, 'S')}</td>"
            f"<td class='num'>{_row_param(r, 'J')}</td>"
            f"<td class='num'>{_text(duration_text(r.get('period_s')))}</td>"
            f"<td>{_text(r.get('gap_effect') or '')}</td>"
            f'<td title="{_text(r.get("flags") or "")}">{n_warn}</td></tr>'
        )
    body_html = (
        f"<h1>Stiction report</h1><p>{_counts(rows)}, {escape(RANKING_RULE)}.</p>"
        f"<table>{head}{''.join(body)}</table>"
        '<p class="muted">S: deadband + stickband, J: slip jump, both in % of the valve '
        "span (Choudhury, Thornhill &amp; Shah 2005); in parentheses the interval of values "
        "the data cannot tell apart from the estimate. P(stiction): the calibrated "
        f"probability of stiction; the verdict is stiction above {STICTION_LEVEL:g}, "
        f"no stiction below {NO_STICTION_LEVEL:g}, inconclusive between.</p>"
    )
    return html_page("stiction report", body_html)


def render_markdown(rows: Sequence[dict]) -> str:
    """Markdown summary over all loops (for a CI job summary)."""
    lines = [
        "## Stiction report",
        "",
        _counts(rows) + ".",
        "",
        "| loop | verdict | P(stiction) | S [%] | J [%] | gap effect | warnings |",
        "|---|---|---|---|---|---|---|",
    ]
    failed = []
    for r in sorted(rows, key=sort_key):
        v = str(r.get("verdict"))
        if v == "error":
            failed.append(r)
            lines.append(f"| {md_escape(r.get('loop'))} | failed | | | | | |")
            continue
        s_iv = _row_param(r, "S", html=False).replace("&ndash;", "-")
        j_iv = _row_param(r, "J", html=False).replace("&ndash;", "-")
        lines.append(
            f"| {md_escape(r.get('loop'))} | {md_escape(v.replace('_', ' '))} | "
            f"{_num(_probability(r), '.2f')} | {md_escape(s_iv)} | {md_escape(j_iv)} | "
            f"{md_escape(r.get('gap_effect') or '')} | {int(r.get('n_warnings') or 0)} |"
        )
    if failed:
        lines += ["", "Failed:", ""]
        lines += [f"- {md_escape(r.get('loop'))}: {md_escape(r.get('error'))}" for r in failed]
    return "\n".join(lines) + "\n"
