"""Plant-scale scan: analyse hundreds of loops and rank them for maintenance.

A plant has hundreds or thousands of loops (Section 1 of Choudhury et al. 2005); the
question is which valves to send maintenance to first.  :func:`scan` runs
:func:`stictiondiag.analysis.analyze` on every loop, on a local process pool or a Dask
cluster (``dask.distributed``), and ranks the loops by verdict, P(valve) and
severity.

Design:

* A loop is a :class:`LoopSource`: one file, or one loop id inside a Parquet dataset
  (a file, or a folder with hive partitions such as ``loop_id=L1/``), read with a
  row filter so a worker holds one loop at a time.
* At most ``2 x workers`` loops are in flight, so memory is bounded by the loops being
  analysed, not by the size of the plant.
* A broken loop never stops the scan: its error is a row of the table.  A worker
  process that dies (out of memory, a crash in compiled code) fails the loops in
  flight with it; the pool is replaced and the scan goes on.
* Each finished loop is written to ``OUT/loops/<loop>.json`` (and a page
  ``<loop>.html``) at once, atomically; a rerun skips the loops already there from
  the same source with the same settings unless ``force`` is set, so a scan resumes.
  Failed loops are tried again.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import pandas as pd

from stictiondiag.apps.pages import VERDICT_ORDER, rank_key, safe_name, unique_names
from stictiondiag.apps.pages import severity as _severity
from stictiondiag.apps.plantwide import plantwide_step, write_plantwide
from stictiondiag.apps.scan_output import (
    OUTPUT_TABLES,
    SCAN_MANIFEST,
    SCAN_TOOL,
    ScannedLoop,
    _check_out,
    _json_default,
    _make_dir,
    _make_loops_dir,
    _save_loop,
    is_scan_output,
    loop_extras,
    loop_html,
    scan_folder,
    write_table,
)
from stictiondiag.apps.sources import (
    LoopSource,
    _parquet_files,
    discover,
    load_source,
)
from stictiondiag.apps.workers import run_dask, run_local
from stictiondiag.core.errors import (
    StictionError,
    UsageError,
    require_bool,
)
from stictiondiag.io.plant import manifest_options, unmatched_manifest_rows
from stictiondiag.row import LoopRow

#: Order of verdicts in the ranked table: what maintenance should look at first.
VERDICT_RANK = {verdict: k for k, verdict in enumerate(VERDICT_ORDER)}


@dataclass(frozen=True)
class ScanResult:
    """Outcome of :func:`scan`.

    Attributes
    ----------
    table : DataFrame
        One row per loop, ranked (most urgent first).
    n_loops, n_failed, n_skipped : int
        Loops in the plant, loops whose analysis failed, loops resumed from ``out``.
    outputs : dict
        Paths written (``parquet``, ``csv``, ``html``).
    renamed : dict
        File -> loop name, for files named otherwise than their stem (two files
        with one stem, e.g. ``loop.csv`` and ``loop.parquet``, get distinct names).
    plantwide : dict
        The plant-wide step (:func:`stictiondiag.apps.plantwide.plantwide_step`):
        ``status`` ``"on"`` with the groups, or ``"off"`` with the ``reason``.
    """

    table: pd.DataFrame
    n_loops: int
    n_failed: int
    n_skipped: int
    outputs: dict = field(default_factory=dict)
    renamed: dict = field(default_factory=dict)
    plantwide: dict = field(default_factory=dict)
    notes: tuple = ()


_safe_name = safe_name

__all__ = [
    "OUTPUT_TABLES",
    "SCAN_MANIFEST",
    "SCAN_TOOL",
    "LoopSource",
    "ScanResult",
    "discover",
    "is_scan_output",
    "loop_html",
    "rank",
    "scan",
    "write_table",
]


def analyse_source(
    source: LoopSource, read_options: dict, gap: bool, plots: bool = True
) -> ScannedLoop:
    """Analyse one loop: its table row, its :class:`~stictiondiag.result.Analysis` and
    the loop page's figures (none when ``plots`` is False), as a :class:`ScannedLoop`
    (never raises)."""
    # Imported here: only the workers analyse; the scan's own process stays 0.3 s lighter.
    from stictiondiag.analysis import AnalysisConfig, analyze

    row: dict = {"loop": source.loop, "source": source.path, "error": None}
    try:
        tags = load_source(source, **{**read_options, **(source.read_options or {})})
        result = analyze(tags, config=AnalysisConfig(gap=gap))
        row.update(result.summary_row())
        row["loop"] = source.loop
        row["source"] = source.path
        images, extras = loop_extras(result, plots, plant=source.plant is not None)
        row.update(extras)
        return ScannedLoop(row, result, images)
    except StictionError as exc:
        return error_result(source, _first_line(exc))
    except Exception as exc:  # one broken loop must never stop a plant scan
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {last[0].name}" if last else ""
        return error_result(
            source, f"internal error{where}: {type(exc).__name__}: {_first_line(exc)}"
        )


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def error_result(source: LoopSource, message: str) -> ScannedLoop:
    """The result of a loop that could not be analysed: verdict ``error`` and one line."""
    return ScannedLoop(LoopRow.failed(source.loop, source.path, message).to_dict())


def worker_failure(source: LoopSource, exc: BaseException) -> ScannedLoop:
    """Result for a loop whose worker failed outside :func:`analyse_source`.

    A worker killed by the operating system (out of memory, a crash in compiled
    code) takes the loops in flight with it; they are recorded as failed, and a
    resumed scan analyses them again.
    """
    if type(exc).__name__ in ("BrokenProcessPool", "KilledWorker"):
        message = (
            "worker process died while analysing this or a concurrent loop "
            "(out of memory or a crash); rerun the scan to retry"
        )
    else:
        message = f"worker failed: {type(exc).__name__}: {_first_line(exc)}"
    return error_result(source, message)


#: Maintenance priority of a loop (:func:`stictiondiag.apps.pages.severity`).
severity = _severity


#: Leading columns of the ranked table; the others follow in alphabetical order, so
#: the table's layout does not depend on which loop finished first.
LEADING_COLUMNS = (
    "rank",
    "loop",
    "verdict",
    "probability",
    "cause",
    "severity",
    "confidence",
    "S",
    "J",
    "gap_effect",
    "flags",
    "error",
    "source",
)


def rank(rows: list[dict]) -> pd.DataFrame:
    """Rows in the order of :data:`~stictiondiag.apps.pages.RANKING_RULE` (verdict, then
    P(valve) and severity, descending, then loop name), the rule of every page.

    Columns: :data:`LEADING_COLUMNS`, then the rest alphabetically.
    """
    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    if "error" not in frame:
        frame["error"] = None
    frame["severity"] = [severity(r) for r in rows]
    order = sorted(range(len(rows)), key=lambda i: rank_key(rows[i]))
    frame = frame.iloc[order].reset_index(drop=True)
    frame.insert(0, "rank", range(1, len(frame) + 1))
    lead = [c for c in LEADING_COLUMNS if c in frame.columns]
    return frame[lead + sorted(c for c in frame.columns if c not in lead)]


def _check_engine(engine: str, workers: int | None) -> int:
    """Check the engine's name; the number of workers (default: all cores)."""
    if engine not in ("local", "dask"):
        raise UsageError(f"unknown engine {engine!r}: use local or dask")
    if workers is not None and int(workers) < 1:
        raise UsageError(f"workers must be at least 1, got {workers}")
    return int(workers or os.cpu_count() or 1)


def _with_manifest(
    sources: list[LoopSource], manifest: dict[str, dict]
) -> tuple[list[LoopSource], list[str]]:
    """Each source with its manifest row's reading options (by its plant loop's name,
    else its own), and a note for each manifest row that names no source."""
    sources = [
        replace(
            s,
            read_options=manifest_options(
                manifest, s.plant.loop if s.plant is not None else s.loop, s.path
            ),
        )
        for s in sources
    ]
    notes = unmatched_manifest_rows(
        manifest, [(s.plant.loop if s.plant is not None else s.loop, s.path) for s in sources]
    )
    return sources, list(notes)


def _runner(engine: str, scheduler: str | None, n_workers: int, todo: list, args: tuple):
    """The analysed loops, as the engine finishes them (a generator of results)."""
    if engine == "local":
        return run_local(todo, analyse_source, args, n_workers, on_error=worker_failure)
    return run_dask(todo, analyse_source, args, n_workers, scheduler, on_error=worker_failure)


def scan(
    path: str | os.PathLike,
    *,
    out: str | os.PathLike,
    engine: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    gap: bool = True,
    plots: bool = True,
    loop_column: str | None = None,
    read_options: dict | None = None,
    manifest: dict[str, dict] | None = None,
    exclude: tuple[str | os.PathLike, ...] = (),
    progress: Callable[[int, int, str], None] | None = None,
    on_note: Callable[[str], None] | None = None,
) -> ScanResult:
    """Analyse every loop under ``path`` and write the ranked table to ``out``.

    Parameters
    ----------
    path : path
        Folder of per-loop files, or Parquet file/dataset with a loop-id column.
    out : path
        Output folder: ``scan.parquet``, ``scan.csv``, ``index.html``, and per loop
        ``loops/<loop>.json`` (row, settings and full analysis) and
        ``loops/<loop>.html``.
    engine : {"local", "dask"}
        Process pool on this machine, or ``dask.distributed`` (a LocalCluster, or the
        scheduler at ``scheduler``).
    workers : int, optional
        Worker processes (default: all cores).
    force : bool
        Re-analyse loops already in ``out`` (default: resume, skipping loops analysed
        by an earlier run from the same source with the same settings; failed loops
        are always analysed again).
    gap : bool
        Include the sim-to-real gap diagnosis (slower).
    plots : bool
        Draw each loop page's figures (trends and phase plots, the valve signature).
    loop_column : str, optional
        Loop-id column of a Parquet dataset (see :func:`discover`).
    read_options : dict, optional
        Options of :func:`stictiondiag.io.tags.read_tags` for every loop (e.g. ``ts``).
    manifest : dict, optional
        Per-loop options (:func:`stictiondiag.io.plant.read_manifest`), by loop name
        (a plant file's loop by its tag prefix) or file; they win over
        ``read_options``.
    exclude : tuple of path
        Files under ``path`` that are not loops (the manifest).
    progress : callable, optional
        Called as ``progress(done, total, loop)`` at the start and after each loop.

    Returns
    -------
    ScanResult
        The ranked table (:func:`rank`), counts and output paths.

    Raises
    ------
    UsageError
        Unknown engine, fewer than one worker, unreachable Dask scheduler.
    DataError
        ``path`` holds no loops (see :func:`discover`).  A loop that cannot be read
        or analysed is not an exception: it is a row with verdict ``error``.
    """
    gap = bool(require_bool("gap", gap))
    force = bool(require_bool("force", force))
    workers = _check_engine(engine, workers)
    read_options = dict(read_options or {})
    out = Path(out)
    _check_out(out)
    sources = discover(path, loop_column=loop_column, exclude=exclude)
    notes: list[str] = []
    if manifest:
        sources, notes = _with_manifest(sources, manifest)
    names = unique_names([s.loop for s in sources])
    file_names = {s.loop: name for s, name in zip(sources, names, strict=True)}
    renamed = {
        s.path: s.loop
        for s in sources
        if s.loop_column is None and s.plant is None and s.loop != Path(s.path).stem
    }
    _make_dir(out)
    folder = scan_folder(out)
    settings = {"gap": bool(gap), "read_options": read_options}
    if manifest:
        settings["manifest"] = manifest
    started = time.time()
    for note in notes:
        if on_note:
            on_note(f"warning: {note}")
    with folder.locked(on_note):
        folder.sweep(started, ("", "loops", "history"))
        folder.refuse_foreign(("index.html", "plantwide.json", *OUTPUT_TABLES))
        loops_dir = _make_loops_dir(out)
        rows, todo = _resumed(sources, names, loops_dir, settings, force)
        n_skipped = len(rows)
        keys = {src.loop: source_key(src) for src in todo}
        n_workers = _pool_size(engine, scheduler, workers, len(todo), notes, on_note)
        runner = _runner(engine, scheduler, n_workers, todo, (read_options, gap, plots))
        if progress:
            progress(n_skipped, len(sources), "")
        for res in runner:
            row = _save_loop(folder, res, file_names, keys, settings)
            rows.append(row)
            if progress:
                progress(len(rows), len(sources), row["loop"])

        plant = plantwide_step(sources, rows, read_options)
        table = rank(rows)
        outputs = write_table(table, out, file_names, folder, plant)
        folder.claim("plantwide.json")
        outputs["plantwide"] = write_plantwide(plant, out)
        folder.record("plantwide.json")
        folder.flush()
    n_failed = int((table["verdict"] == "error").sum()) if not table.empty else 0
    return ScanResult(
        table, len(sources), n_failed, n_skipped, outputs, renamed, plant, notes=tuple(notes)
    )


#: Dask workers of a LocalCluster per core at most: each is a process of about
#: 300 MB, and more of them than this only compete for the cores.
DASK_WORKERS_PER_CORE = 2


def _pool_size(
    engine: str,
    scheduler: str | None,
    workers: int,
    n_loops: int,
    notes: list[str],
    on_note: Callable[[str], None] | None,
) -> int:
    """Worker processes to start: no more than loops to analyse, and for a Dask
    LocalCluster no more than :data:`DASK_WORKERS_PER_CORE` per core (with a note)."""
    n = max(1, min(workers, n_loops))
    if engine == "dask" and scheduler is None:
        cores = os.cpu_count() or 1
        n = min(n, DASK_WORKERS_PER_CORE * cores)
        if n < workers:
            note = (
                f"note: started {n} Dask workers, not {workers}: at most one per loop to "
                f"analyse ({n_loops}) and {DASK_WORKERS_PER_CORE} per core ({cores} cores)"
            )
            notes.append(note)
            if on_note:
                on_note(note)
    return n


def _resumed(
    sources: list[LoopSource], names: list[str], loops_dir: Path, settings: dict, force: bool
) -> tuple[list[dict], list[LoopSource]]:
    """(rows of loops an earlier run finished, sources still to analyse)."""
    rows: list[dict] = []
    todo: list[LoopSource] = []
    hashes: dict[str, str] = {}
    for src, name in zip(sources, names, strict=True):
        record_file = loops_dir / f"{name}.json"
        done = (
            None
            if force or not record_file.is_file()
            else _finished_row(record_file, source_key(src, hashes), settings)
        )
        if done is None:
            todo.append(src)
        else:
            rows.append(done)
    return rows, todo


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def source_key(source: LoopSource, cache: dict[str, str] | None = None) -> dict:
    """What a finished loop's record must match to be resumed: where and what the data are.

    The resolved path (however PATH was spelled), the loop id inside a dataset, and
    the SHA-256 of the file's content (of every file of a dataset folder), so an
    edited file is analysed again.  Unreadable files get no digest (they fail, and
    failures are always retried).
    """
    cache = {} if cache is None else cache
    path = Path(source.path).resolve()
    key = str(path)
    if key not in cache:
        try:
            if path.is_dir():
                digest = hashlib.sha256()
                for f in _parquet_files(path):
                    digest.update(str(f.relative_to(path)).encode())
                    digest.update(_file_digest(f).encode())
                cache[key] = digest.hexdigest()
            else:
                cache[key] = _file_digest(path)
        except OSError:
            cache[key] = ""
    return {"path": key, "loop": source.loop if source.loop_column else None, "sha256": cache[key]}


def _finished_row(record_file: Path, key: dict, settings: dict) -> dict | None:
    """The table row of a loop analysed by an earlier run, or None to analyse it (again).

    A loop is analysed again when its record is missing or unreadable, comes from
    another file or other content (:func:`source_key`) or other settings, or records
    a failure (the cause may
    have been fixed, or the worker may have died for another loop).
    """
    try:
        record = json.loads(record_file.read_text())
        row = record["row"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if (
        not isinstance(row, dict)
        or row.get("verdict") == "error"
        or record.get("source_key") != key
        or record.get("settings") != json.loads(json.dumps(settings, default=_json_default))
    ):
        return None
    return row
