"""What a scan writes in its output folder: the ranked table, its page, each loop's files.

Split from :mod:`stictiondiag.apps.scan` (which analyses); the folder's rules are
those of :mod:`stictiondiag.apps.outdir`: the scan writes only where nothing stands
or where its manifest (:data:`SCAN_MANIFEST`) lists what it wrote, so no file of the
user is replaced; the folder is locked for the run.  The CSV table is
spreadsheet-safe (:mod:`stictiondiag.core.csvsafe`); Parquet and JSON stay raw.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

from stictiondiag.apps.history import (
    HISTORY_FOLDER,
    entry_of,
    history_html,
    merge_entry,
    read_entries,
    trend_sentence,
)
from stictiondiag.apps.outdir import OutputFolder
from stictiondiag.apps.pages import html_page, safe_name
from stictiondiag.apps.plantwide_page import plant_html
from stictiondiag.apps.scan_page import scan_html
from stictiondiag.core.atomic import atomic_path
from stictiondiag.core.csvsafe import safe_frame
from stictiondiag.core.errors import UsageError

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "OUTPUT_TABLES",
    "SCAN_MANIFEST",
    "SCAN_TOOL",
    "is_scan_output",
    "loop_extras",
    "loop_html",
    "scan_folder",
    "write_table",
]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: Files of a scan's output folder (beside ``loops/`` and ``index.html``).
OUTPUT_TABLES = ("scan.parquet", "scan.csv")


#: The scan's manifest: every file it wrote in its folder, with its digest
#: (:mod:`stictiondiag.apps.outdir`).
SCAN_MANIFEST = "scan-manifest.json"

#: Who writes a scan folder (recorded in its manifest).
SCAN_TOOL = "stiction scan"


def is_scan_output(f: Path) -> bool:
    """Whether ``f`` is a file a scan wrote: its table beside its ``loops/`` and index.

    Outputs are never read back as loops, so ``scan DIR --out DIR`` can run again.
    """
    return (
        f.name in OUTPUT_TABLES
        and (f.parent / "loops").is_dir()
        and ((f.parent / "index.html").is_file() or (f.parent / SCAN_MANIFEST).is_file())
    )


def _legacy_outputs(out: Path) -> list[str]:
    """Files of a scan folder written before scans kept a manifest, taken as the scan's.

    Only a folder an earlier scan evidently wrote (its table beside ``loops/`` and
    ``index.html``): its table, index and the loop records and pages of ``loops/``.
    """
    if not any(is_scan_output(out / name) for name in OUTPUT_TABLES):
        return []
    names = [n for n in ("index.html", "plantwide.json", *OUTPUT_TABLES) if (out / n).is_file()]
    loops = out / "loops"
    if loops.is_dir() and not loops.is_symlink():
        names += sorted(
            f"loops/{f.name}"
            for f in loops.iterdir()
            if f.suffix in (".json", ".html") and f.is_file() and not f.is_symlink()
        )
    return names


def scan_folder(out: str | os.PathLike) -> OutputFolder:
    """The scan's output folder ``out`` and its manifest."""
    return OutputFolder(out, SCAN_MANIFEST, SCAN_TOOL, adopt=_legacy_outputs)


def _save_loop(
    folder: OutputFolder, res: dict, file_names: dict, keys: dict, settings: dict
) -> dict:
    """Write one finished loop's history, page and record; a write that fails fails its row.

    The history (:mod:`stictiondiag.apps.history`) keeps the results of earlier scans
    of the loop, one entry per record period; the row carries its trend in words.
    """
    row = res["row"]
    name = file_names.get(row["loop"], safe_name(row["loop"]))
    entries: list[dict] = []
    try:
        # Named together in the manifest before either is written (one manifest write).
        folder.claim(f"loops/{name}.html", f"loops/{name}.json")
        if res["analysis"] is not None:
            entries = _update_history(folder, name, row, res["analysis"], keys.get(row["loop"]))
            trend = trend_sentence(entries)
            if trend:
                row = {**row, "trend": trend}
        record = {
            "row": row,
            "settings": settings,
            "source_key": keys.get(row["loop"]),
            "analysis": res["analysis"],
        }
        page = loop_html(row, res["analysis"], name, res.get("images") or {}, entries)
        # The JSON record marks the loop as done, so it is written last.
        folder.write({f"loops/{name}.html": page})
        folder.write({f"loops/{name}.json": json.dumps(record, indent=1, default=_json_default)})
    except UsageError as exc:
        return {**row, "verdict": "error", "error": _first_line(exc)}
    return row


def _update_history(
    folder: OutputFolder, name: str, row: dict, analysis: dict, key: dict | None
) -> list[dict]:
    """The loop's history with this result merged in, written back (only a history file
    the scan wrote is read; anything else there is refused by the write)."""
    path = f"{HISTORY_FOLDER}/{name}.json"
    entries: list[dict] = []
    target = folder.out / path
    if target.is_file() and folder.owns(path):
        entries = read_entries(target.read_text(encoding="utf-8", errors="replace"))
    entry = entry_of(row, analysis, (key or {}).get("sha256"))
    entries = merge_entry(entries, entry)
    payload = {"loop": row["loop"], "entries": entries}
    folder.write({path: json.dumps(payload, indent=1, default=_json_default)})
    return entries


#: Points of a loop's sparkline on the fleet page.
SPARK_POINTS = 96


def _spark(values) -> str:
    """A signal as :data:`SPARK_POINTS` block means scaled to 0-99, as text (``12,40,...``)."""
    import numpy as np

    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return ""
    edges = np.linspace(0, x.size, min(SPARK_POINTS, x.size) + 1).astype(int)
    means = np.add.reduceat(x, edges[:-1]) / np.diff(edges)
    lo, hi = float(means.min()), float(means.max())
    scaled = np.zeros_like(means) if hi == lo else (means - lo) / (hi - lo) * 99.0
    return ",".join(str(int(round(v))) for v in scaled)


def loop_extras(result, plots: bool, plant: bool) -> tuple[dict[str, bytes], dict]:
    """The loop page's figures (PNG, when ``plots``) and the fleet page's extra row
    fields: pv and op sparklines and the unit (the export a loop of a plant file came
    from, else the folder of its file)."""
    images: dict[str, bytes] = {}
    if plots:
        # Upward (plotting sits above apps): imported only when figures are drawn.
        from stictiondiag.plotting import figure_png

        builders = result.figure_builders()
        for fig_name in ("phase", "valve_zoom"):
            if fig_name in builders:
                images[fig_name] = figure_png(builders[fig_name]())
    tags = result.tags
    source = str(tags.source).split("#", 1)[0]
    unit = Path(source).stem if plant else Path(source).parent.name
    extras = {"spark_pv": _spark(tags.pv), "spark_op": _spark(tags.op), "unit": unit}
    return images, extras


def _make_dir(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"cannot create the scan folder {out}: {(exc.strerror or str(exc)).lower()}; "
            "choose a writable --out"
        ) from None


def _make_loops_dir(out: Path) -> Path:
    loops_dir = out / "loops"
    if os.path.lexists(loops_dir) and (loops_dir.is_symlink() or not loops_dir.is_dir()):
        raise UsageError(
            f"{loops_dir} exists and was not made by {SCAN_TOOL}: the scan writes its loop "
            "records there; move it or choose another --out"
        )
    try:
        loops_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"cannot create the scan folder {loops_dir}: {(exc.strerror or str(exc)).lower()}; "
            "choose a writable --out"
        ) from None
    return loops_dir


def _check_out(out: Path) -> None:
    """Refuse an output folder that is a file, or whose files are not the scan's."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"cannot write to {out}: it is a file; give a folder for --out")
    if out.is_dir():
        scan_folder(out).refuse_foreign(("index.html", *OUTPUT_TABLES))


def loop_html(
    row: dict,
    analysis: dict | None,
    name: str | None = None,
    images: dict[str, bytes] | None = None,
    history: list[dict] | None = None,
) -> str:
    """Per-loop page linked from the scan's ``index.html``: the analysis with its
    figures (drawn by the worker) and the loop's history across scans."""
    from html import escape

    # Imported here: the page's findings bring the verdict and numba (about 0.5 s),
    # which a scan's own process does not otherwise load.
    from stictiondiag.apps.report_html import render_loop_html

    name = name or safe_name(row["loop"])
    if analysis is not None:
        page = render_loop_html(
            analysis, images or {}, json_name=f"{name}.json", index_href="../index.html"
        )
        section = history_html(history or [])
        return page.replace("\n<script>", section + "\n<script>", 1) if section else page
    body = (
        f"<h1>Loop {escape(str(row.get('loop')))}</h1>"
        f"<p>Source <code>{escape(str(row.get('source')))}</code></p>"
        f'<p><span class="verdict error">not analysed</span></p>'
        f"<p>{escape(str(row.get('error')))}</p>"
        '<p><a href="../index.html">all loops</a></p>'
    )
    return html_page(f"stiction: {row.get('loop')}", body)


def _json_default(o):
    try:
        v = float(o)
    except (TypeError, ValueError):
        return str(o)
    return v if math.isfinite(v) else None


def write_table(
    table: pd.DataFrame,
    out: Path,
    file_names: dict | None = None,
    folder: OutputFolder | None = None,
    plant: dict | None = None,
) -> dict:
    """Write the ranked table as an HTML page, Parquet and CSV (each atomically).

    The page comes first: beside ``loops/`` it marks the tables as the scan's own
    (:func:`is_scan_output`), also when the run stops between them.
    ``file_names`` maps a loop to its file name in ``loops/`` (default its safe name);
    ``plant``, the plant-wide step's result, adds its section to the page.
    The files are written through ``folder`` (default :func:`scan_folder` of
    ``out``), so none replaces a file the scan did not write.  Text cells of the CSV
    that a spreadsheet would run as a formula are escaped
    (:func:`stictiondiag.core.csvsafe.safe_frame`).
    """
    folder = scan_folder(out) if folder is None else folder
    paths = {"parquet": out / "scan.parquet", "csv": out / "scan.csv", "html": out / "index.html"}
    clean = table.copy()
    for c in clean.columns:
        if clean[c].dtype == object:
            clean[c] = clean[c].map(
                lambda v: (
                    None
                    if v is None
                    else (v if isinstance(v, str | bool) else str(v))
                    if not isinstance(v, int | float)
                    else v
                )
            )

    page = scan_html(clean, file_names)
    section = plant_html(plant)
    if section:
        page = page.replace("</body>", section + "</body>", 1)
    folder.write({"index.html": page})
    folder.claim("scan.parquet")
    with atomic_path(paths["parquet"]) as tmp:
        clean.to_parquet(tmp, index=False)
    folder.record("scan.parquet")
    folder.write({"scan.csv": safe_frame(clean).to_csv(index=False)})
    folder.flush()
    return {k: str(v) for k, v in paths.items()}
