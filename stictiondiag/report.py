"""Reports for people and for CI: self-contained HTML, a Markdown summary, JSON.

A report folder holds, per loop, ``<loop>.html`` (plots embedded as base64 PNG, no
external assets: it opens offline) and ``<loop>.json``; over all loops an
``index.html`` and ``summary.md`` (for a CI job summary).  Every file is written
whole or not at all (:mod:`stictiondiag.atomic`).  An existing folder is updated:
loops of earlier runs stay listed in the index unless ``clean`` is asked for.

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped in HTML and in Markdown, so a column called ``<script>`` shows as text.
"""

from __future__ import annotations

import base64
import json
import math
import os
import re
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path

from .errors import DataError, StictionError

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;margin:1.5em auto;max-width:1100px;
color:#222;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em} h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ddd}
table{border-collapse:collapse;font-size:13px;margin:.5em 0}
th,td{border:1px solid #ccc;padding:3px 8px;text-align:left;vertical-align:top}
th{background:#f2f2f2} .verdict{display:inline-block;padding:.2em .6em;border-radius:4px;font-weight:600}
.stiction{background:#fde2e1} .inconclusive{background:#fff5d6} .no_stiction{background:#e3f5e1}
.error{background:#eee} img{max-width:100%;height:auto;border:1px solid #eee}
.warn{color:#8a5300} code{background:#f5f5f5;padding:0 .2em}
"""

# Marks the page as fully loaded with all images decoded (read by the browser test).
_LOAD_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.body.setAttribute('data-images-loaded', ok + '/' + imgs.length);
});
</script>"""


def _page(title: str, body: str) -> str:
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{escape(title)}</title><style>{_CSS}</style></head>"
        f"<body>\n{body}\n{_LOAD_SCRIPT}\n</body></html>\n"
    )


def _num(v, spec=".3g") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int | float):
        return format(v, spec) if math.isfinite(float(v)) else "n/a"
    return escape(str(v))


def md_escape(text: str) -> str:
    """Escape text for Markdown table cells and prose (no HTML, no formatting)."""
    text = escape(str(text), quote=False)  # <script> -> &lt;script&gt;
    text = text.replace("\n", " ").replace("|", "\\|")
    return re.sub(r"([\\`*_{}\[\]()#+!~>])", r"\\\1", text)


def _img(png: bytes, alt: str) -> str:
    b64 = base64.b64encode(png).decode("ascii")
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{b64}">'


def _kv_table(rows: Sequence[tuple[str, str]]) -> str:
    return (
        "<table>"
        + "".join(f"<tr><th>{escape(k)}</th><td>{v}</td></tr>" for k, v in rows)
        + "</table>"
    )


def render_loop_html(d: dict, images: dict[str, bytes]) -> str:
    """HTML page for one loop from :meth:`Analysis.to_dict` and its figures' PNGs."""
    st = d.get("stiction") or {}
    tg = d.get("tags") or {}
    status = str(st.get("status") or st.get("verdict") or "unknown")
    si, ji = st.get("S_interval"), st.get("J_interval")

    def interval(iv):
        if not iv or None in iv:
            return "not determined"
        return f"[{_num(iv[0])}, {_num(iv[1])}]"

    parts = [
        f"<h1>Loop {escape(str(d.get('loop')))}</h1>",
        f"<p>Source <code>{escape(str(d.get('source')))}</code></p>",
        f'<p><span class="verdict {escape(status)}">{escape(status.replace("_", " "))}</span> '
        f"confidence {_num(st.get('confidence'), '.2f')}</p>",
        "<h2>Stiction parameters</h2>",
        _kv_table(
            [
                (
                    "S (deadband + stickband)",
                    f"{_num(st.get('S'))} % of op span, interval {interval(si)}",
                ),
                ("J (slip jump)", f"{_num(st.get('J'))} % of op span, interval {interval(ji)}"),
                ("method", escape(str(st.get("method")))),
                ("evidence", "<br>".join(escape(str(r)) for r in st.get("reasons") or [])),
            ]
        ),
        "<h2>Data</h2>",
        _kv_table(
            [
                ("tags", escape(", ".join(f"{k}={v}" for k, v in (tg.get("names") or {}).items()))),
                ("samples", f"{_num(tg.get('n_samples'), 'd')} at {_num(tg.get('ts_s'))} s"),
                (
                    "loop type",
                    escape(f"{tg.get('loop_type')} (integrating: {tg.get('integrating')})"),
                ),
            ]
        ),
    ]
    warnings = d.get("warnings") or []
    parts.append("<h2>Data-quality warnings</h2>")
    parts.append(
        "<ul>" + "".join(f'<li class="warn">{escape(str(w))}</li>' for w in warnings) + "</ul>"
        if warnings
        else "<p>None.</p>"
    )
    if "phase" in images:
        parts += ["<h2>Phase plots and trends</h2>", _img(images["phase"], "phase plots")]
    rep = d.get("replay")
    parts.append("<h2>Closed-loop reconstruction</h2>")
    if rep:
        fit = rep.get("fit") or {}
        per = rep.get("period_s") or {}
        parts.append(
            _kv_table(
                [
                    ("process", escape(json.dumps(rep.get("process"), default=str))),
                    ("controller", escape(json.dumps(rep.get("controller"), default=str))),
                    (
                        "period data / replay [s]",
                        f"{_num(per.get('data'))} / {_num(per.get('replay'))}",
                    ),
                    ("fit", escape(json.dumps(fit, default=str))),
                ]
            )
        )
        if "reconstruction" in images:
            parts.append(_img(images["reconstruction"], "reconstruction"))
    else:
        parts.append("<p>No replay (see warnings).</p>")
    gap = d.get("gap")
    parts.append("<h2>Sim-to-real gap</h2>")
    if gap:
        parts.append(
            _kv_table(
                [
                    ("metric", escape(str(gap.get("metric")))),
                    ("before / after", f"{_num(gap.get('before'))} / {_num(gap.get('after'))}"),
                    ("shrink", f"{_num(gap.get('shrink_pct'), '.0f')} %"),
                    ("effect", escape(str(gap.get("effect")))),
                    ("runner-up", escape(str(gap.get("runner_up")))),
                ]
            )
        )
        cands = gap.get("candidates") or []
        if cands:
            parts.append(
                "<table><tr><th>effect</th><th>gap after</th><th>shrink %</th><th>params</th></tr>"
                + "".join(
                    f"<tr><td>{escape(str(c.get('effect')))}</td><td>{_num(c.get('after'))}</td>"
                    f"<td>{_num(c.get('shrink_pct'), '.0f')}</td>"
                    f"<td>{escape(json.dumps(c.get('params'), default=str))}</td></tr>"
                    for c in cands
                )
                + "</table>"
            )
        for name, png in images.items():
            if name.startswith("gap"):
                parts.append(_img(png, name))
    else:
        parts.append("<p>Not run.</p>")
    parts.append('<p><a href="index.html">all loops</a></p>')
    return _page(f"stiction: {d.get('loop')}", "\n".join(parts))


def render_index_html(rows: Sequence[dict]) -> str:
    """Index page over all loops of a report."""
    head = "<tr><th>loop</th><th>verdict</th><th>confidence</th><th>S</th><th>J</th><th>gap effect</th><th>warnings</th></tr>"
    body = []
    for r in rows:
        loop = str(r.get("loop"))
        v = str(r.get("verdict"))
        link = f"{escape(safe_name(loop))}.html"
        body.append(
            f'<tr class="{escape(v)}"><td><a href="{link}">{escape(loop)}</a></td>'
            f"<td>{escape(v.replace('_', ' '))}</td><td>{_num(r.get('confidence'), '.2f')}</td>"
            f"<td>{_num(r.get('S'))}</td><td>{_num(r.get('J'))}</td>"
            f"<td>{escape(str(r.get('gap_effect') or ''))}</td>"
            f"<td>{escape(str(r.get('error') or r.get('flags') or ''))}</td></tr>"
        )
    n_st = sum(1 for r in rows if r.get("verdict") == "stiction")
    body_html = (
        f"<h1>Stiction report</h1><p>{len(rows)} loops, {n_st} with stiction.</p>"
        f"<table>{head}{''.join(body)}</table>"
    )
    return _page("stiction report", body_html)


def render_markdown(rows: Sequence[dict]) -> str:
    """Markdown summary (for a CI job summary)."""
    n_st = sum(1 for r in rows if r.get("verdict") == "stiction")
    lines = [
        "## Stiction report",
        "",
        f"{len(rows)} loops, {n_st} with stiction.",
        "",
        "| loop | verdict | confidence | S [%] | J [%] | gap effect |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {md_escape(r.get('loop'))} | {md_escape(str(r.get('verdict')).replace('_', ' '))} | "
            f"{_num(r.get('confidence'), '.2f')} | {_num(r.get('S'))} | {_num(r.get('J'))} | "
            f"{md_escape(r.get('gap_effect') or r.get('error') or '')} |"
        )
    return "\n".join(lines) + "\n"


def safe_name(loop: str) -> str:
    """File-system-safe name of a loop."""
    keep = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in str(loop))
    return keep.strip(".") or "loop"


@dataclass(frozen=True)
class ReportResult:
    """Outcome of :func:`build_report`.

    Attributes
    ----------
    rows : list of dict
        One summary row per loop in the index (this run's and earlier runs').
    failed : list of (file, message)
        Inputs of this run that could not be analysed.
    outputs : dict
        Paths of ``index`` and ``markdown``.
    """

    rows: list
    failed: list = field(default_factory=list)
    outputs: dict = field(default_factory=dict)

    def max_stiction_confidence(self) -> float | None:
        vals = [
            float(r.get("confidence") or 0.0) for r in self.rows if r.get("verdict") == "stiction"
        ]
        return max(vals) if vals else None


def build_report(
    files: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    read_options: dict | None = None,
    gap: bool = True,
    clean: bool = False,
    progress: Callable[[int, int, str], None] | None = None,
) -> ReportResult:
    """Analyse ``files`` and write (or update) the report folder ``out``."""
    from .analysis import AnalysisConfig, analyze_file
    from .atomic import write_atomic

    out = Path(out)
    if clean and out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.json"
    rows: dict[str, dict] = {}
    if rows_path.exists():
        try:
            rows = {r["loop"]: r for r in json.loads(rows_path.read_text())}
        except (ValueError, KeyError, TypeError):
            rows = {}
    failed = []
    for i, f in enumerate(files):
        name = Path(f).stem
        if progress:
            progress(i, len(files), name)
        try:
            result = analyze_file(f, config=AnalysisConfig(gap=gap), **(read_options or {}))
        except StictionError as exc:
            failed.append((str(f), str(exc)))
            rows[name] = {"loop": name, "verdict": "error", "error": str(exc)}
            continue
        d = result.to_dict()
        from .plotting import figure_png

        images = {k: figure_png(fig) for k, fig in result.figures().items()}
        base = safe_name(result.loop)
        write_atomic(out / f"{base}.html", render_loop_html(d, images))
        write_atomic(out / f"{base}.json", json.dumps(d, indent=2) + "\n")
        rows[result.loop] = result.summary_row()
    if progress:
        progress(len(files), len(files), "")
    ordered = sorted(rows.values(), key=lambda r: str(r.get("loop")))
    write_atomic(rows_path, json.dumps(ordered, indent=1, default=str))
    write_atomic(out / "index.html", render_index_html(ordered))
    write_atomic(out / "summary.md", render_markdown(ordered))
    if failed and len(failed) == len(files):
        # Nothing could be read: the caller reports a data error.
        raise DataError(f"no input could be analysed; first error: {failed[0][0]}: {failed[0][1]}")
    return ReportResult(
        ordered,
        failed,
        {"index": str(out / "index.html"), "markdown": str(out / "summary.md")},
    )
