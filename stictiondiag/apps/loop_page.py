"""The HTML page of one loop, rendered from its typed result.

:func:`render_loop_html` takes the :class:`~stictiondiag.result.Analysis` itself (as
run, or as read back with :meth:`~stictiondiag.result.Analysis.from_json`) and reads
its typed parts: the tags, the :class:`~stictiondiag.stiction.fit_result.StictionFit`,
the :class:`~stictiondiag.stiction.verdict.Verdict`, the
:class:`~stictiondiag.replay.closed_loop.Replay` with its
:class:`~stictiondiag.replay.metrics.ReplayMetrics`, the
:class:`~stictiondiag.gap.diagnose.GapDiagnosis`; what stays a mapping inside them
(the verdict's evidence, the identified models, the gap's breakdown and an effect's
parameters) is shown as it is.  Used by ``stiction report`` and ``stiction scan``.

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped; the page carries a Content-Security-Policy
(:func:`stictiondiag.apps.pages.html_page`).
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Sequence
from html import escape
from typing import TYPE_CHECKING

from stictiondiag.apps.findings import (
    determinacy,
    estimate,
    findings_of,
    interval,
    param_note,
    probability_text,
)
from stictiondiag.apps.pages import duration_text, html_num, html_page, html_text
from stictiondiag.core.serialize import plain_float
from stictiondiag.models.processes import FOPTD
from stictiondiag.replay.metrics import ReplayMetrics, replay_metrics
from stictiondiag.result import clock_text

if TYPE_CHECKING:
    from stictiondiag.gap.result import GapDiagnosis
    from stictiondiag.identification.controller import ControllerFit
    from stictiondiag.identification.process_result import ProcessFit
    from stictiondiag.replay.closed_loop import Replay
    from stictiondiag.result import Analysis
    from stictiondiag.stiction.fit_result import StictionFit

__all__ = ["VERDICT_CLASSES", "render_loop_html"]

#: Verdicts with a style of their own on the pages.
VERDICT_CLASSES = ("stiction", "inconclusive", "error", "no_stiction")

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


def _params(values: Sequence[tuple[float | None, str, str]]) -> str:
    """``symbol = value unit`` for the finite values among ``(value, symbol, unit)``."""
    parts = [
        f"{sym} = {_num(v)}{unit}"
        for v, sym, unit in ((plain_float(v), sym, unit) for v, sym, unit in values)
        if v is not None
    ]
    return escape(", ".join(parts)) if parts else "n/a"


def _r2_text(r2: float | None) -> str:
    r2 = plain_float(r2)
    return "" if r2 is None else f" (R\u00b2 {_num(r2, '.2f')})"


def _process_text(pf: ProcessFit) -> str:
    """The identified process: structure, K, \u03c4, \u03b8 and the fit's R\u00b2."""
    p = pf.process
    tau = p.time_constant if isinstance(p, FOPTD) else None
    kind = "FOPTD" if isinstance(p, FOPTD) else "integrating"
    values = [(p.gain, "K", ""), (tau, "\u03c4", " s"), (p.dead_time, "\u03b8", " s")]
    return f"{kind}: " + _params(values) + _r2_text(pf.output_error.fit_r2)


def _controller_text(cf: ControllerFit) -> str:
    """The identified controller: P or PI, Kc, Ti, op bias and the fit's R\u00b2."""
    kind = "P" if cf.p_only else "PI"
    c = cf.controller
    values = [(c.gain, "Kc", ""), (c.integral_time, "Ti", " s"), (cf.op_bias, "op bias", " %")]
    return f"{kind}: " + _params(values) + _r2_text(cf.fit_r2)


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


_num = html_num
_text = html_text


def _header(a: Analysis, loop: str, json_name: str | None, index_href: str) -> list[str]:
    """Links, title, source, data span and analysis date, loop type and its source."""
    tags = a.tags
    links = [f'<a href="{escape(index_href)}">&larr; all loops</a>']
    if json_name:
        links.append(f'<a href="{escape(json_name)}">analysis JSON</a>')
    start = clock_text(tags.start_time)
    span = (
        f"{_num(int(tags.n), 'd')} samples at {_num(float(tags.ts))} s = "
        f"{_duration_text(float(tags.n * tags.ts))}" + (f" from {_text(start)}" if start else "")
    )
    loop_type_source = tags.loop_type_source or "user/default"
    return [
        f'<p class="muted">{" &middot; ".join(links)}</p>',
        f"<h1>Loop {_text(loop)}</h1>",
        f'<p class="muted">source <code>{_text(tags.source)}</code> &middot; tags '
        + ", ".join(f"{_text(k)} = <code>{_text(v)}</code>" for k, v in tags.names.items())
        + "</p>",
        _kv_table(
            [
                ("data span", f'<span id="data-span">{span}</span>'),
                (
                    "analysed",
                    f'<span id="analysed-at">{_text(a.analysed_at or "n/a")}</span>',
                ),
                (
                    "loop type",
                    f'<span id="loop-type">{_text(tags.loop_type)}'
                    f"{' (integrating)' if tags.integrating else ''}</span>"
                    f' <span class="muted">from {_text(loop_type_source)}</span>',
                ),
            ]
        ),
    ]


def _units(a: Analysis) -> str:
    """The unit of S and J: % of op span, or op's own when its scale is unknown."""
    return "% of op span" if a.tags.op_scale == "percent" else "op units (scale unknown)"


def _param_card(a: Analysis, sym: str, label: str) -> str:
    """Card of S or J: value, and the interval or the poorly-determined note."""
    poor = a.fit.poorly_determined(sym)
    unit = " %" if a.tags.op_scale == "percent" else " op units (scale unknown)"
    value = f"{_num(estimate(a.fit, sym))}{unit}" + (
        ' <span class="poor">poorly determined</span>' if poor else ""
    )
    return _card(label, value, escape(param_note(a.fit, sym)))


def _waveform_text(m: ReplayMetrics) -> str:
    return ", ".join(f"{s.signal} {_num(plain_float(s.waveform), '.2f')}" for s in m.signals)


def _cards(a: Analysis, metrics: ReplayMetrics | None) -> str:
    """The compact summary: verdict with P(stiction), S, J, cycle, replay, gap."""
    osc = a.oscillation
    status = str(a.verdict.status or "unknown")
    status_class = status if status in VERDICT_CLASSES else "unknown"
    cards = [
        _card(
            "verdict",
            f'<span class="verdict {status_class}">{_text(status.replace("_", " "))}</span>',
            escape(probability_text(a.verdict)),
        ),
        _param_card(a, "S", "S (deadband + stickband)"),
        _param_card(a, "J", "J (slip jump)"),
        _card(
            "oscillation",
            _text(duration_text(plain_float(osc.period_s))) if osc.present else "none",
            f"regularity {_num(plain_float(osc.regularity), '.3g')}" if osc.present else "",
        ),
    ]
    if metrics is not None:
        per = plain_float(metrics.period_error_pct)
        cards.append(
            _card(
                "reconstruction",
                # + 0.0: a period error that rounds to zero reads "+0 %", never "-0 %".
                f"period {round(per) + 0.0:+.0f} %" if per is not None else "no period",
                escape("waveform agreement " + _waveform_text(metrics)),
            )
        )
    if a.gap is not None:
        cards.append(
            _card(
                "gap effect",
                _text(a.gap.effect),
                f"gap shrinks {_num(plain_float(a.gap.shrink_pct), '.0f')} %",
            )
        )
    n_warn = len(a.warnings)
    cards.append(_card("warnings", f'<a href="#warnings">{n_warn}</a>' if n_warn else "0"))
    return '<div class="cards">' + "".join(cards) + "</div>"


def _findings_section(a: Analysis, loop: str) -> str:
    """The findings in words (:mod:`stictiondiag.apps.findings`)."""
    f = findings_of(a, loop=loop)
    rows = "".join(
        f"<tr><th>{escape(topic)}</th><td>{_text(text)}</td></tr>" for topic, text in f.items()
    )
    return f'<h2 id="findings">Findings</h2><table class="findings">{rows}</table>'


def _ends(fit: StictionFit, sym: str) -> list[float]:
    """The finite ends of the interval of ``sym`` [% of op span]."""
    iv = fit.S_interval if sym == "S" else fit.J_interval
    return [x for x in (plain_float(v) for v in (iv or ())) if x is not None]


def _parameters_section(a: Analysis) -> list[str]:
    """Table of S and J with intervals, bars and determinacy; method and improvement."""
    fit = a.fit
    S, J = estimate(fit, "S"), estimate(fit, "J")
    ends = [v for v in (S, J, *_ends(fit, "S"), *_ends(fit, "J")) if v is not None]
    x_max = 1.15 * max(ends) if ends and max(ends) > 0 else 1.0
    rows = []
    for sym, name, value, scaled in (
        ("S", "deadband + stickband", S, fit.S_scaled),
        ("J", "slip jump", J, fit.J_scaled),
    ):
        iv = interval(fit, sym)
        cls = ' class="poor"' if fit.poorly_determined(sym) else ""
        label = f"{sym} {_num(value)} %, interval {_interval_text(iv)}"
        rows.append(
            f"<tr><th>{sym}</th><td>{name}</td><td class='num'>{_num(value)}</td>"
            f"<td>{_interval_text(iv)}</td>"
            f"<td>{_interval_svg(value, iv, x_max, label)}</td>"
            f"<td class='num'>{_num(plain_float(scaled))}</td>"
            f"<td{cls}>{_text(determinacy(fit, sym))}</td></tr>"
        )
    interval_note = fit.interval_method
    units = _text(_units(a))
    improvement = plain_float(fit.improvement)
    return [
        "<h2>Stiction parameters</h2>",
        f"<table><tr><th></th><th>parameter</th><th>estimate [{units}]</th>"
        f"<th>interval [{units}]</th><th>0 &ndash; "
        f"{_num(x_max, '.3g')}</th><th>scaled [op std]</th><th>determined</th></tr>"
        + "".join(rows)
        + "</table>",
        f'<p class="muted">method <code>{_text(fit.method)}</code>'
        f" &middot; {_num(int(fit.n_slips), 'd')} slips"
        + (
            f" &middot; the stiction model removes {_num(100 * improvement, '.0f')} % "
            "of the linear valve's residual"
            if improvement is not None
            else ""
        )
        + (f"<br>interval: {_text(interval_note)}" if interval_note else "")
        + "</p>",
    ]


def _amplitude_text(m: ReplayMetrics) -> str:
    parts = []
    for s in m.signals:
        err = plain_float(s.amplitude_error_pct)
        err_text = f" ({err:+.0f} %)" if err is not None else ""
        data, rep = plain_float(s.amplitude_data), plain_float(s.amplitude_replay)
        parts.append(f"{s.signal} {_num(data)} / {_num(rep)}{err_text}")
    return escape(", ".join(parts)) or "n/a"


def _replay_section(
    rep: Replay | None, m: ReplayMetrics | None, images: dict[str, bytes]
) -> list[str]:
    """Identified models, period/amplitude/waveform agreement, NRMSE, the figure."""
    parts = ["<h2>Closed-loop reconstruction</h2>"]
    if rep is None or m is None:
        return [*parts, "<p>No replay (see the warnings).</p>"]
    per = plain_float(m.period_error_pct)
    parts.append(
        _kv_table(
            [
                ("process", _process_text(rep.process_fit)),
                ("controller", _controller_text(rep.controller_fit)),
                (
                    f"period of {m.period_signal or rep.period_signal or 'pv'}, data / replay [s]",
                    f"{_num(plain_float(m.period_data_s))} / "
                    f"{_num(plain_float(m.period_replay_s))}"
                    + (f" (period error {per:+.0f} %)" if per is not None else ""),
                ),
                (
                    "amplitude, data / replay (amplitude error) [signal units]",
                    _amplitude_text(m),
                ),
                (
                    "waveform agreement, phase-aligned cycle [1 = same]",
                    escape(_waveform_text(m)) or "n/a",
                ),
                (
                    "NRMSE, point by point [-] (punishes phase drift)",
                    escape(
                        ", ".join(
                            f"{k} {_num(plain_float(m.nrmse), '.2f')}"
                            for k, m in rep.measures.by_signal().items()
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


def _gap_section(gap: GapDiagnosis | None, has_replay: bool, images: dict[str, bytes]) -> list[str]:
    """Gap table, candidate effects and the gap figures."""
    parts = ["<h2>Sim-to-real gap</h2>"]
    if gap is not None:
        parts.append(
            _kv_table(
                [
                    ("metric", _text(gap.metric)),
                    (
                        "gap before / after [%]",
                        f"{_num(plain_float(gap.before))} / {_num(plain_float(gap.after))}",
                    ),
                    ("shrink", f"{_num(plain_float(gap.shrink_pct), '.0f')} %"),
                    ("most likely effect", f"<strong>{_text(gap.effect)}</strong>"),
                    ("runner-up", _text(gap.runner_up)),
                    ("margin [%]", _num(plain_float(gap.margin))),
                ]
            )
        )
        if gap.candidates:
            parts.append(
                "<table><tr><th>candidate effect</th><th>gap after [%]</th><th>shrink %</th>"
                "<th>parameters</th></tr>"
                + "".join(
                    f"<tr><td>{_text(c.effect)}</td>"
                    f"<td class='num'>{_num(plain_float(c.after))}</td>"
                    f"<td class='num'>{_num(plain_float(c.shrink_pct), '.0f')}</td>"
                    f"<td>{_param_text(c.params.to_dict())}</td></tr>"
                    for c in gap.candidates
                )
                + "</table>"
            )
        if gap.breakdown is not None:
            parts.append(_json_details("gap breakdown", gap.breakdown.to_dict()))
    elif has_replay:
        parts.append("<p>Not run.</p>")
    else:
        parts.append("<p>Not run (needs the reconstruction).</p>")
    for name, png in images.items():
        if name not in ("phase", "reconstruction", "valve_zoom"):
            parts.append(_figure(name, png))
    return parts


def render_loop_html(
    a: Analysis,
    images: dict[str, bytes],
    *,
    loop: str | None = None,
    json_name: str | None = None,
    index_href: str = "../index.html",
) -> str:
    """HTML page for one loop.

    Parameters
    ----------
    a : Analysis
        The loop's result.
    images : dict
        Figure name -> PNG bytes (``phase``, ``valve_zoom``, ``reconstruction``,
        gap plots).
    loop : str, optional
        The loop's name on the page (default :attr:`Analysis.loop`).
    json_name : str, optional
        File name of the loop's JSON next to the page, linked from the header.
    index_href : str
        Link to the index page (the pages live in ``loops/``, beside nothing else).

    Returns
    -------
    str
        A complete, self-contained HTML document.
    """
    loop = a.loop if loop is None else loop
    metrics = None if a.replay is None else replay_metrics(a.replay)
    warnings = list(a.warnings)
    parts = _header(a, loop, json_name, index_href)
    parts.append(_cards(a, metrics))
    parts.append(_findings_section(a, loop))
    reasons = a.verdict.reasons
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{_text(r)}</li>" for r in reasons) + "</ul>")
    parts.append(_json_details("verdict evidence", a.verdict.evidence.to_dict()))
    parts += _parameters_section(a)
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
    parts += _replay_section(a.replay, metrics, images)
    parts += _gap_section(a.gap, a.replay is not None, images)
    return html_page(f"stiction: {loop}", "\n".join(p for p in parts if p))
