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
import os
from collections.abc import Sequence
from html import escape
from pathlib import Path

__all__ = ["CSS", "html_page", "safe_name", "unique_names"]

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
    f"default-src 'none'; img-src data:; style-src {_csp_hash(CSS)}; "
    f"script-src {_csp_hash(_LOAD_JS)}; base-uri 'none'; form-action 'none'"
)


def html_page(title: str, body: str) -> str:
    """A complete, self-contained HTML document.

    Parameters
    ----------
    title : str
        Page title (plain text; escaped here).
    body : str
        HTML of the body (escaped by the caller where it holds data).
    """
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="Content-Security-Policy" content="{_CSP}">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        '<link rel="icon" href="data:,">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head>"
        f"<body>\n{body}\n<script>{_LOAD_JS}</script>\n</body></html>\n"
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
