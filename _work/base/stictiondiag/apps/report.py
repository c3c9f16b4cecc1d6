"""Reports for people and for CI: self-contained HTML, a Markdown summary, JSON.

A report folder holds, per loop, ``loops/<loop>.html`` (plots embedded as base64 PNG,
no external assets: it opens offline) and ``loops/<loop>.json`` (the full
:meth:`Analysis.to_dict`); over all loops an ``index.html``, ``summary.md`` (for a CI
job summary), ``rows.json`` (the index rows, read back by the next run) and
``manifest.json`` (every file the report wrote, the only files ``clean`` removes).
The loop files live in their own folder, so no loop name (``index``, ``rows``) can
replace one of the report's files, and two inputs with one stem get distinct names.
Every file is written whole or not at all (:mod:`stictiondiag.core.atomic`).  An
existing folder is updated: loops of earlier runs stay listed in the index unless
``clean`` is asked for.  No input is ever removed or overwritten.

Everything that comes from the data (tag names, file names, comments, warnings) is
escaped in HTML and in Markdown, so a column called ``<script>`` shows as text.  The
pages also carry a Content-Security-Policy that allows only their own inline style and
script and ``data:`` images, so nothing is fetched from the network and nothing
injected could run.
"""

from __future__ import annotations

import json
import os
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from stictiondiag.apps.findings import with_findings
from stictiondiag.apps.outdir import OutputFolder
from stictiondiag.apps.pages import safe_name, unique_names
from stictiondiag.apps.report_html import (
    md_escape,
    render_index_html,
    render_loop_html,
    render_markdown,
    sort_key,
)
from stictiondiag.apps.workers import run_local
from stictiondiag.core.errors import (
    DataError,
    StictionError,
    UsageError,
    require_bool,
)
from stictiondiag.io.plant import (
    PlantLoop,
    manifest_options,
    plant_loops,
    read_plant_loop,
    unmatched_manifest_rows,
)

__all__ = [
    "ReportResult",
    "build_report",
    "clean_report",
    "md_escape",
    "render_index_html",
    "render_loop_html",
    "render_markdown",
    "safe_name",
]

#: Name of the file that marks a folder as a stiction report and keeps its index rows.
ROWS_FILE = "rows.json"

#: The files the report wrote (relative to its folder), read by ``clean``.
MANIFEST_FILE = "manifest.json"

#: Sub-folder of the per-loop pages and JSON: no loop name can collide with the
#: report's own files (``index.html``, ``rows.json``, ...).
LOOPS_DIR = "loops"


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
    renamed : dict
        Input file -> loop name, for inputs whose name is not their file's stem
        (two inputs with one stem get distinct names).
    notes : tuple of str
        Warnings of the run (manifest rows that match no loop), one line each.
    """

    rows: list
    failed: list = field(default_factory=list)
    outputs: dict = field(default_factory=dict)
    renamed: dict = field(default_factory=dict)
    notes: tuple = ()

    def max_stiction_confidence(self) -> float | None:
        """Highest confidence among loops called stiction; None when there is none."""
        vals = [
            float(r.get("confidence") or 0.0) for r in self.rows if r.get("verdict") == "stiction"
        ]
        return max(vals) if vals else None


#: Who writes a report folder (recorded in its manifest).
REPORT_TOOL = "stiction report"

#: The report's own files beside ``loops/`` (the manifest aside).
REPORT_FILES = (ROWS_FILE, "index.html", "summary.md")


def _folder(out: Path) -> OutputFolder:
    return OutputFolder(out, MANIFEST_FILE, REPORT_TOOL)


def clean_report(out: Path, inputs: Sequence[str | os.PathLike] = ()) -> list[Path]:
    """Remove the files an earlier report wrote in ``out``, as its manifest lists them.

    Nothing else is touched: not a file the manifest does not list, not a file the
    user has replaced or edited since, not a link's target (a listed name that is a
    link is removed as the link), never one of ``inputs``; folders only when left
    empty (:meth:`stictiondiag.apps.outdir.OutputFolder.clean`).

    Returns
    -------
    list of Path
        The entries removed.
    """
    return _folder(Path(out)).clean(inputs)


def _prepare_folder(out: Path) -> None:
    st = out.lstat() if os.path.lexists(out) else None
    if st is not None and not out.is_dir():
        raise UsageError(f"--out {out} is a file; give a folder for the report")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"cannot create the report folder {out}: {(exc.strerror or str(exc)).lower()}; "
            "choose a writable --out"
        ) from None


def _make_loops_dir(out: Path) -> None:
    loops = out / LOOPS_DIR
    if os.path.lexists(loops) and (loops.is_symlink() or not loops.is_dir()):
        raise UsageError(
            f"{loops} exists and was not made by {REPORT_TOOL}: the report writes its loop "
            "pages there; move it or choose another --out"
        )
    try:
        loops.mkdir(exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"cannot create {loops}: {(exc.strerror or str(exc)).lower()}; choose a writable --out"
        ) from None


def _inside(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
        return True
    except ValueError:
        return False


def _read_rows(out: Path) -> dict[str, dict]:
    try:
        return {str(r["loop"]): r for r in json.loads((out / ROWS_FILE).read_text())}
    except (OSError, ValueError, KeyError, TypeError):
        # No earlier report, or an unreadable index: start the index afresh (the loop
        # pages on disk are left alone).
        return {}


def _check_outputs(out: Path, files: Sequence[str]) -> None:
    """Refuse a report whose own files would replace an input."""
    # realpath, not resolve: a link loop in the folder must not stop the check.
    inputs = {Path(os.path.realpath(f)) for f in files}
    for name in (ROWS_FILE, "index.html", "summary.md", MANIFEST_FILE):
        if Path(os.path.realpath(out / name)) in inputs:
            raise UsageError(
                f"{out / name} is an input and the report would overwrite it; choose another --out"
            )
    loops = Path(os.path.realpath(out / LOOPS_DIR))
    for f in inputs:
        if _inside(f, loops):
            raise UsageError(
                f"{f} lies in the report's {LOOPS_DIR}/ folder, which the report writes; "
                "move it or choose another --out"
            )


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _display_name(path: str, name: str) -> str:
    """The loop's name in the index: its file's stem, unless it had to be renamed."""
    stem = Path(path).stem
    return stem if safe_name(stem) == name else name


def analyse_for_report(source: tuple[str, str], read_options: dict, gap: bool) -> dict:
    """Analyse one loop file and render its page; never raises for a bad loop.

    Module-level so that it runs in worker processes. ``source`` is (file, name):
    the name is the loop's file name in the report (distinct for every input).
    Returns ``{"file", "loop", "page", "json", "row"}`` on success, ``{"file",
    "loop", "error"}`` when the loop could not be analysed (one line: the data error,
    or the internal error and where it arose).
    """
    # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze_file,
    )

    path, name = source[0], source[1]
    plant = source[2] if len(source) > 2 else None
    options = {**read_options, **(source[3] if len(source) > 3 and source[3] else {})}
    loop = source[4] if len(source) > 4 else _display_name(path, name)
    label = f"{path}#{plant.loop}" if plant is not None else str(path)
    try:
        if plant is not None:
            # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
            from stictiondiag.analysis import analyze

            result = analyze(read_plant_loop(plant, **options), config=AnalysisConfig(gap=gap))
        else:
            result = analyze_file(path, config=AnalysisConfig(gap=gap), **options)
        plain = result.to_dict()
        row = result.summary_row(plain)
        d = with_findings({**plain, "loop": loop})
        # Upward (plotting sits above apps): imported only when figures are drawn.
        from stictiondiag.plotting import figure_png

        images = {k: figure_png(fig) for k, fig in result.figures().items()}
        row["loop"] = loop
        row["source"] = label
        row["page"] = f"{LOOPS_DIR}/{name}.html"
        return {
            "file": label,
            "loop": loop,
            "name": name,
            "page": render_loop_html(d, images, json_name=f"{name}.json"),
            "json": json.dumps(d, indent=2) + "\n",
            "row": row,
        }
    except StictionError as exc:
        message = _first_line(exc)
    except Exception as exc:  # one broken loop must not stop the report of the others
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {last[0].name}" if last else ""
        message = f"internal error{where}: {type(exc).__name__}: {_first_line(exc)}"
    return {"file": label, "loop": loop, "error": message}


def _worker_died(source: tuple, exc: BaseException) -> dict:
    plant = source[2] if len(source) > 2 else None
    return {
        "file": f"{source[0]}#{plant.loop}" if plant is not None else str(source[0]),
        "loop": source[4] if len(source) > 4 else _display_name(source[0], source[1]),
        "error": f"internal error: the analysis process failed ({type(exc).__name__})",
    }


def _expand(files: Sequence[str]) -> list[tuple[str, str, PlantLoop | None]]:
    """(file, loop name, plant loop or None) for every loop of ``files``.

    A one-loop file is named by its stem; a loop of a plant file by its tag prefix,
    by ``<stem>:<prefix>`` when another loop has that name.  A file that cannot be
    read is one loop that fails with the reason.
    """
    found: list[tuple[str, str, PlantLoop | None]] = []
    for f in files:
        try:
            loops = plant_loops(f)
        except StictionError:
            loops = []
        if len(loops) <= 1 or all(p.layout == "file" for p in loops):
            found.append((f, Path(f).stem, None))
        else:
            found.extend((f, p.loop, p) for p in loops)
    count: dict[str, int] = {}
    for _, loop, _ in found:
        count[loop.lower()] = count.get(loop.lower(), 0) + 1
    return [
        (f, f"{Path(f).stem}:{loop}" if p is not None and count[loop.lower()] > 1 else loop, p)
        for f, loop, p in found
    ]


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


def _loop_sources(
    paths: list[str], manifest: dict[str, dict]
) -> tuple[list[tuple], dict[str, str], list[str], list[str]]:
    """The loops of ``paths`` and their names.

    Returns one ``(file, name, plant loop or None, manifest options, display name)``
    per loop, the files whose loop got another name than its stem, the loops' keys in
    file order (``file#loop`` for a plant file's loop), and a note for each manifest
    row that names no loop.
    """
    entries = _expand(paths)
    names = unique_names([loop for _, loop, _ in entries], [f for f, _, _ in entries])
    renamed = {
        f: n
        for (f, loop, plant), n in zip(entries, names, strict=True)
        if plant is None and n != safe_name(loop)
    }
    sources = [
        (
            f,
            n,
            plant,
            manifest_options(manifest, plant.loop if plant else loop, f) or {},
            loop if plant is not None else _display_name(f, n),
        )
        for (f, loop, plant), n in zip(entries, names, strict=True)
    ]
    order = [f"{f}#{plant.loop}" if plant is not None else f for f, _, plant in entries]
    notes = unmatched_manifest_rows(
        manifest, [(plant.loop if plant else loop, f) for f, loop, plant in entries]
    )
    return sources, renamed, order, notes


def build_report(
    files: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    read_options: dict | None = None,
    gap: bool = True,
    clean: bool = False,
    workers: int | None = None,
    manifest: dict[str, dict] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    on_note: Callable[[str], None] | None = None,
) -> ReportResult:
    """Analyse ``files`` and write (or update) the report folder ``out``.

    Parameters
    ----------
    files : sequence of path
        One loop per file (CSV or Parquet, see :func:`stictiondiag.io.tags.read_tags`).
        The loop's name is the file's stem; inputs with one stem get distinct names
        (:func:`stictiondiag.apps.pages.unique_names`, listed in
        :attr:`ReportResult.renamed`).
    out : path
        Report folder; created if missing. Loops of earlier runs stay in the index.
    read_options : dict, optional
        Keyword arguments for :func:`read_tags` (column names, ``ts``, ...).
    gap : bool
        Run the sim-to-real gap diagnosis (the slowest step).
    clean : bool
        First remove the files earlier reports wrote in ``out``, as listed in its
        manifest (:func:`clean_report`): nothing else, never an input.
    workers : int, optional
        Processes analysing loops side by side (default :func:`default_workers`);
        1 analyses them one after the other in this process.
    manifest : dict, optional
        Per-loop read options (:func:`stictiondiag.io.plant.read_manifest`) by loop
        name or file; they win over ``read_options``.
    progress : callable, optional
        ``progress(done, n, loop)`` after each loop is finished (in completion order
        when ``workers`` > 1).

    Returns
    -------
    ReportResult

    Raises
    ------
    UsageError
        ``out`` is a file or cannot be created, a file of the report would replace
        an input, or ``workers`` < 1.
    DataError
        No input could be analysed (the index is written all the same).

    Notes
    -----
    A file holding many loops (wide or long plant export, :mod:`stictiondiag.io.plant`)
    gives one page per loop, named by its tag prefix; an incomplete or ambiguous loop
    is listed as failed with the reason.
    """
    gap = bool(require_bool("gap", gap))
    clean = bool(require_bool("clean", clean))
    if isinstance(files, str | os.PathLike):
        raise TypeError("files must be a list of paths, not one path: build_report([path], out)")
    out = Path(out)
    paths = [str(f) for f in files]
    workers = default_workers(len(paths)) if workers is None else int(workers)
    if workers < 1:
        raise UsageError(f"workers must be at least 1, got {workers}")
    sources, renamed, order, notes = _loop_sources(paths, manifest or {})
    for note in notes:
        if on_note:
            on_note(f"warning: {note}")
    _check_outputs(out, paths)
    _prepare_folder(out)
    folder = _folder(out)
    started = time.time()
    with folder.locked(on_note):
        if clean:
            folder.clean(paths)
        folder.sweep(started, ("", LOOPS_DIR))
        folder.refuse_foreign(REPORT_FILES)
        _make_loops_dir(out)
        folder.claim(*REPORT_FILES)
        rows = _read_rows(out)
        failed = _run_loops(
            folder, sources, rows, dict(read_options or {}), bool(gap), workers, progress
        )
        # Failures in file order, so the message of an all-failed run names the first file.
        failed.sort(key=lambda fm: order.index(fm[0]) if fm[0] in order else len(order))
        ordered = sorted(rows.values(), key=sort_key)
        folder.write(
            {
                ROWS_FILE: _rows_json(rows),
                "index.html": render_index_html(ordered),
                "summary.md": render_markdown(ordered),
            }
        )
        folder.flush()
    if failed and len(failed) == len(sources):
        # Nothing could be read: the caller reports a data error.
        raise DataError(f"no input could be analysed; {failed[0][0]}: {failed[0][1]}")
    return ReportResult(
        ordered,
        failed,
        {"index": str(out / "index.html"), "markdown": str(out / "summary.md")},
        renamed,
        tuple(notes),
    )


def _run_loops(
    folder: OutputFolder,
    sources: list,
    rows: dict[str, dict],
    read_options: dict,
    gap: bool,
    workers: int,
    progress: Callable[[int, int, str], None] | None,
) -> list[tuple[str, str]]:
    """Analyse ``sources`` and write each loop's files as it finishes; the failures.

    A loop's page and JSON are written here, not in the worker.  A page that cannot
    be written (a foreign file at its name, a name the file system refuses) fails
    its own row (when no page at all could be written, the run: UsageError); the index rows are written after every loop, so an interrupted
    report keeps what it did, and a full disk stops the report at the index.
    """
    failed: list[tuple[str, str]] = []
    unwritten: set[str] = set()
    outcomes = run_local(
        sources,
        analyse_for_report,
        (read_options, gap),
        min(workers, max(1, len(sources))),
        on_error=_worker_died,
    )
    for done, res in enumerate(outcomes, start=1):
        if "error" not in res:
            base = f"{LOOPS_DIR}/{res['name']}"
            try:
                folder.write({f"{base}.json": res["json"], f"{base}.html": res["page"]})
            except UsageError as exc:
                res = {"file": res["file"], "loop": res["loop"], "error": _first_line(exc)}
                unwritten.add(res["file"])
        if "error" in res:
            failed.append((res["file"], res["error"]))
            rows[res["loop"]] = {
                "loop": res["loop"],
                "source": res["file"],
                "verdict": "error",
                "error": res["error"],
            }
        else:
            rows[res["loop"]] = res["row"]
        folder.write({ROWS_FILE: _rows_json(rows)})
        if progress:
            progress(done, len(sources), res["loop"])
    if failed and len(unwritten) == len(sources):
        # Every loop was analysed and none could be written: an output error.
        raise UsageError(failed[0][1])
    return failed


def _rows_json(rows: dict[str, dict]) -> str:
    return json.dumps(sorted(rows.values(), key=sort_key), indent=1, default=str) + "\n"
