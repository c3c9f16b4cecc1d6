"""The ranked table of a plant scan as one self-contained HTML page (``index.html``)."""

from __future__ import annotations

import math

import pandas as pd

from stictiondiag.apps.pages import safe_name as _safe_name

__all__ = ["scan_html"]


#: Column headings that differ from the column names.
_HEADINGS = {"probability": "P(stiction)", "S": "S [%]", "J": "J [%]", "severity": "severity [%]"}


def scan_html(table: pd.DataFrame, file_names: dict | None = None) -> str:
    """Self-contained HTML page with the ranked table and per-loop links."""
    from html import escape

    cols = [
        c
        for c in (
            "rank",
            "loop",
            "verdict",
            "probability",
            "S",
            "J",
            "severity",
            "period_s",
            "gap_effect",
            "loop_type",
            "flags",
            "error",
        )
        if c in table.columns
    ]
    head = "".join(f"<th>{escape(_HEADINGS.get(c, c))}</th>" for c in cols)
    body = []
    for _, r in table.iterrows():
        cells = []
        for c in cols:
            v = r[c]
            if v is None or (isinstance(v, float) and not math.isfinite(v)):
                txt = ""
            elif isinstance(v, float):
                txt = f"{v:.3g}"
            else:
                txt = str(v)
            if c == "loop":
                name = (file_names or {}).get(str(v)) or _safe_name(str(v))
                link = f"loops/{escape(name)}.html"
                txt = f'<a href="{link}">{escape(txt)}</a> <a class="j" href="loops/{escape(name)}.json">json</a>'
            else:
                txt = escape(txt)
            cells.append(f"<td>{txt}</td>")
        cls = escape(str(r.get("verdict", "")))
        body.append(f'<tr class="{cls}">{"".join(cells)}</tr>')
    n = len(table)
    n_st = int((table.get("verdict") == "stiction").sum()) if n else 0
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>stiction scan</title>
<style>
body{{font-family:system-ui,sans-serif;margin:1.5em;color:#222}}
table{{border-collapse:collapse;font-size:13px}}
th,td{{border:1px solid #ccc;padding:3px 7px;text-align:left}}
th{{background:#eee}} tr.stiction{{background:#fde2e1}} tr.inconclusive{{background:#fff5d6}}
tr.error{{background:#eee;color:#777}} a.j{{font-size:11px;color:#777}}
</style></head><body>
<h1>Stiction scan</h1>
<p>{n} loops, {n_st} with stiction, ranked by verdict then severity
(P(stiction) &times; (S + J), % of span).</p>
<table><thead><tr>{head}</tr></thead><tbody>
{"".join(body)}
</tbody></table></body></html>
"""
