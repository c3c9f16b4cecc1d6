"""What the report and the scan share: the HTML page frame and the names of loop files.

* :func:`html_page` wraps a body in the self-contained page of every report and scan
  page: its own style and script only, images only from ``data:`` URLs, under a
  Content-Security-Policy that blocks anything else (nothing fetched from the
  network, nothing injected could run).
* :func:`safe_name` and :func:`unique_names` give each loop a file name of its own:
  two inputs with the same stem (``loop.csv`` and ``loop.parquet``, or ``a b.csv``
  and ``a_b.csv``) get distinct names, and the caller lists the mapping.
"""

from __future__ import annotations

import base64
import hashlib
import math
import os
from collections.abc import Mapping, Sequence
from html import escape
from pathlib import Path

from stictiondiag.row import LoopRow, as_row

__all__ = [
    "CSS",
    "RANKING_RULE",
    "VERDICT_ORDER",
    "duration_text",
    "html_num",
    "html_page",
    "html_text",
    "rank_key",
    "safe_name",
    "severity",
    "sparkline",
    "unique_names",
]

CSS = """
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
.poor{color:#a33;font-weight:600} span.poor{font-size:.7em}
table.findings{max-width:1000px} table.findings th{white-space:nowrap;vertical-align:top}
details{margin:.4em 0} pre{background:#f7f7f7;padding:.5em;overflow:auto;font-size:12px}
body:has(#fleet){max-width:none} #fleet td{font-size:12px} #fleet td.kpi{white-space:nowrap}
#fleet td.trend{max-width:16em}
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


def html_num(v, spec=".3g") -> str:
    """A number as text (``n/a`` for None or not finite), anything else escaped."""
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, int | float):
        if not math.isfinite(float(v)):
            return "n/a"
        return format(round(v) if spec.endswith("d") else v, spec)
    return escape(str(v))


def html_text(v) -> str:
    """Any value from the data as escaped HTML text."""
    return escape("" if v is None else str(v))


def _csp_hash(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'"


# Only this page's own style and script run; images only from data: URLs. Anything
# injected through the data (were escaping ever to fail) or any external asset is
# blocked by the browser.
_CSP = (
    f"default-src 'none'; img-src data:; style-src {_csp_hash(CSS)}; "
    f"script-src {_csp_hash(_LOAD_JS)}; base-uri 'none'; form-action 'none'"
)


def html_page(title: str, body: str, script: str = "") -> str:
    """A complete, self-contained HTML document.

    Parameters
    ----------
    title : str
        Page title (plain text; escaped here).
    body : str
        HTML of the body (escaped by the caller where it holds data).
    script : str
        The page's own script (a fixed text, never data), allowed by its hash.
    """
    csp = _CSP
    tail = f"<script>{_LOAD_JS}</script>"
    if script:
        csp = _CSP.replace(
            f"script-src {_csp_hash(_LOAD_JS)}",
            f"script-src {_csp_hash(_LOAD_JS)} {_csp_hash(script)}",
        )
        tail += f"<script>{script}</script>"
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="Content-Security-Policy" content="{csp}">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        '<link rel="icon" href="data:,">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head>"
        f"<body>\n{body}\n{tail}\n</body></html>\n"
    )


# --------------------------------------------------------------------------- ranking

#: Order of verdicts on every page and table: what maintenance looks at first.
VERDICT_ORDER = ("stiction", "inconclusive", "propagated", "no_stiction", "error")

#: The one ranking rule of the scan table, its page and the report's index.
RANKING_RULE = (
    "ranked by verdict (stiction, inconclusive, propagated from another loop, no stiction, "
    "failed), then P(valve) "
    "(highest first), then severity = P(valve) \u00d7 (S + J) [% of span], then loop name"
)

#: What the P(valve) of every table is.
P_VALVE_WORDS = (
    "P(valve): the probability that the valve causes the loop's cycle (stage 2's cause "
    "model, for a loop with a cycle and without mv; the calibrated P(stiction) of the "
    "friction model where mv is recorded; 0 for a loop without a cycle)"
)


def severity(row: LoopRow | Mapping) -> float:
    """Maintenance priority of a loop: P(valve) times stiction size (S + J) [% of span].

    A row without a probability (written by an older run) uses its confidence.
    """
    r = as_row(row)
    conf = r.probability if r.probability is not None else r.confidence
    if conf is None or r.S is None or r.J is None:
        return 0.0
    try:
        v = float(conf) * (float(r.S) + float(r.J))
    except (TypeError, ValueError):
        return 0.0
    return v if math.isfinite(v) else 0.0


def rank_key(row: LoopRow | Mapping) -> tuple:
    """Sort key of :data:`RANKING_RULE`."""
    r = as_row(row)
    verdict = str(r.verdict)
    order = VERDICT_ORDER.index(verdict) if verdict in VERDICT_ORDER else len(VERDICT_ORDER)
    try:
        p = float(r.probability)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        p = -1.0  # a row of an older run without P: severity decides
    p = p if math.isfinite(p) else -1.0
    return (order, -p, -severity(r), str(r.loop))


def duration_text(seconds) -> str:
    """A period or duration for people: ``85 s``, ``21.5 min``, ``3.2 h``, ``2.1 d``."""
    try:
        s = float(seconds)
    except (TypeError, ValueError):
        return ""
    if not math.isfinite(s):
        return ""
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 172800:
        return f"{s / 3600:.3g} h"
    return f"{s / 86400:.3g} d"


def sparkline(
    values: Sequence[float], *, width: int = 120, height: int = 22, color: str = "#1f77b4"
) -> str:
    """An inline SVG polyline of ``values`` (scaled to their own range), no script, no style."""
    vals = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if len(vals) < 2:
        return ""
    lo, hi = min(vals), max(vals)
    span = (hi - lo) or 1.0
    step = (width - 2) / (len(vals) - 1)
    points = " ".join(
        f"{1 + i * step:.1f},{height - 1 - (v - lo) / span * (height - 2):.1f}"
        for i, v in enumerate(vals)
    )
    return (
        f'<svg class="spark" width="{width}" height="{height}" viewBox="0 0 {width} {height}">'
        f'<polyline fill="none" stroke="{color}" stroke-width="1" points="{points}"/></svg>'
    )


#: Longest file name of a loop [bytes of UTF-8], before its extension: with
#: ``.html`` and the atomic writer's temporary names it stays far below the 255
#: bytes of common file systems.  A longer name is cut and ends in a short hash of
#: the whole name, so two long names that share their start stay distinct.
MAX_NAME_BYTES = 120


def safe_name(loop: object) -> str:
    """File-system-safe name of a loop (letters, digits, ``-``, ``_`` and ``.``).

    At most :data:`MAX_NAME_BYTES` bytes: a longer name keeps its start and ends in
    ``-`` and 10 hex digits of the SHA-256 of the whole name.
    """
    keep = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in str(loop))
    name = keep.strip(".") or "loop"
    if len(name.encode("utf-8")) <= MAX_NAME_BYTES:
        return name
    tag = hashlib.sha256(str(loop).encode("utf-8", "surrogatepass")).hexdigest()[:10]
    head = name.encode("utf-8")[: MAX_NAME_BYTES - len(tag) - 1].decode("utf-8", "ignore")
    return f"{head.rstrip('.')}-{tag}"


def unique_names(
    loops: Sequence[str], paths: Sequence[str | os.PathLike[str]] | None = None
) -> list[str]:
    """A distinct file name for each loop, in the order given.

    The name is :func:`safe_name` of the loop; names that would collide (two loops
    with the same safe name, compared without regard to case, as some file
    systems do) get the file's extension added (``loop_csv``, ``loop_parquet``)
    when ``paths`` tell them apart that way, then a counter (``loop-2``). The
    first loop to claim a name keeps it.

    Parameters
    ----------
    loops : sequence of str
        Loop names (file stems, or loop ids of a dataset).
    paths : sequence of path, optional
        The file of each loop, for the extension.
    """
    bases = [safe_name(loop) for loop in loops]
    count: dict[str, int] = {}
    for base in bases:
        count[base.lower()] = count.get(base.lower(), 0) + 1
    taken: set[str] = set()
    names: list[str] = []
    for i, base in enumerate(bases):
        name = base
        if count[base.lower()] > 1 and paths is not None:
            suffix = "".join(Path(paths[i]).suffixes).lstrip(".").replace(".", "_")
            if suffix and base.lower() in taken:
                name = f"{base}_{safe_name(suffix)}"
        k = 2
        candidate = name
        while candidate.lower() in taken:
            candidate = f"{name}-{k}"
            k += 1
        taken.add(candidate.lower())
        names.append(candidate)
    return names
