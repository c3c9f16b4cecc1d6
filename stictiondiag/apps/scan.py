"""Plant-scale scan: analyse hundreds of loops and rank them for maintenance.

A plant has hundreds or thousands of loops (Section 1 of Choudhury et al. 2005); the
question is which valves to send maintenance to first.  :func:`scan` runs
:func:`stictiondiag.analysis.analyze` on every loop, on a local process pool or a Dask
cluster (``dask.distributed``), and ranks the loops by verdict, P(stiction) and
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
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from stictiondiag.apps.pages import VERDICT_ORDER, rank_key, safe_name, unique_names
from stictiondiag.apps.pages import severity as _severity
from stictiondiag.apps.scan_output import (
    OUTPUT_TABLES,
    SCAN_MANIFEST,
    SCAN_TOOL,
    _check_out,
    _json_default,
    _make_dir,
    _make_loops_dir,
    _save_loop,
    is_scan_output,
    loop_html,
    scan_folder,
    write_table,
)
from stictiondiag.apps.workers import run_dask, run_local
from stictiondiag.core.errors import (
    DataError,
    StictionError,
    UsageError,
    require_bool,
)
from stictiondiag.io.plant import PlantLoop, is_long_file, plant_loops

#: Column names accepted as the loop id of a Parquet dataset (first match wins).
LOOP_ID_COLUMNS = ("loop_id", "loop", "loop_name", "tag", "loopid")

#: File types read as one loop each.
LOOP_FILE_SUFFIXES = (".csv", ".parquet", ".pq")

#: Order of verdicts in the ranked table: what maintenance should look at first.
VERDICT_RANK = {verdict: k for k, verdict in enumerate(VERDICT_ORDER)}


@dataclass(frozen=True)
class LoopSource:
    """Where one loop's data lives.

    Attributes
    ----------
    loop : str
        Loop name (file stem, or the loop id in a dataset).
    path : str
        File, or Parquet dataset, path.
    loop_column : str or None
        Loop-id column when ``path`` is a dataset holding many loops.
    read_options : dict or None
        Options of this loop (from a loops manifest), over the scan's own.
    plant : PlantLoop or None
        The loop's place in a whole-plant file (wide or long export,
        :mod:`stictiondiag.io.plant`).
    """

    loop: str
    path: str
    loop_column: str | None = None
    read_options: dict | None = None
    plant: PlantLoop | None = None


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


def _is_hidden(name: str) -> bool:
    # Dataset writers leave _SUCCESS, _common_metadata and .crc files beside the data.
    return name.startswith((".", "_"))


def _walk(folder: Path) -> list[Path]:
    """Files under ``folder``, hidden entries left out; symlinked folders followed once.

    Each folder is entered once (a visited set of device and inode), so a link back
    up the tree (a cycle) or two links to one folder cost nothing twice.  A file is
    listed under the path it was found at.
    """
    files: list[Path] = []
    visited: set[tuple[int, int]] = set()
    for root, dirs, names in os.walk(folder, followlinks=True):
        try:
            st = os.stat(root)
        except OSError:
            dirs[:] = []
            continue
        if (st.st_dev, st.st_ino) in visited:
            dirs[:] = []
            continue
        visited.add((st.st_dev, st.st_ino))
        dirs[:] = sorted(d for d in dirs if not _is_hidden(d))
        files.extend(Path(root) / n for n in names if not _is_hidden(n))
    return files


def _loop_files(folder: Path) -> list[Path]:
    """Loop files under ``folder``, subfolders included (symlinked ones once); hidden
    ones and scan outputs not."""
    return sorted(
        f
        for f in _walk(folder)
        if f.suffix.lower() in LOOP_FILE_SUFFIXES and f.is_file() and not is_scan_output(f)
    )


def _parquet_files(folder: Path) -> list[Path]:
    """Parquet files of a dataset folder, including hive partitions (``loop_id=L1/``)."""
    return sorted(
        f
        for f in _walk(folder)
        if f.suffix.lower() in (".parquet", ".pq") and f.is_file() and not is_scan_output(f)
    )


def _open_dataset(path: Path):
    """A pyarrow dataset over a Parquet file or folder (hive partitions become columns)."""
    import pyarrow.dataset as ds

    if path.is_dir():
        files = [str(f) for f in _parquet_files(path)]
        return ds.dataset(
            files, format="parquet", partitioning="hive", partition_base_dir=str(path)
        )
    return ds.dataset(str(path), format="parquet")


def _loop_ids(dataset, column: str) -> list:
    """Distinct loop ids, read batch by batch so memory does not grow with the plant."""
    import pyarrow.compute as pc

    ids: set = set()
    for batch in dataset.to_batches(columns=[column]):
        ids.update(v for v in pc.unique(batch.column(0)).to_pylist() if v is not None)
    return sorted(ids, key=str)


def discover(
    path: str | os.PathLike,
    *,
    loop_column: str | None = None,
    exclude: tuple[str | os.PathLike, ...] = (),
) -> list[LoopSource]:
    """List the loops under ``path``.

    Parameters
    ----------
    path : path
        A folder of per-loop CSV or Parquet files (one loop per file, named by the
        file stem); a CSV or Parquet file holding one loop; or a Parquet file or
        dataset folder (hive partitions such as ``loop_id=L1/`` included) with a
        loop-id column, one loop per distinct id.
    loop_column : str, optional
        Loop-id column of a Parquet dataset; default the first of
        :data:`LOOP_ID_COLUMNS` present (case-insensitive).
    exclude : tuple of path
        Files that are not loops (the loops manifest inside the folder).

    A file holding many loops (a wide export grouped by tag prefix, or a long
    ``timestamp, tag, value`` export; :mod:`stictiondiag.io.plant`) gives one source
    per loop, named by its tag prefix (by ``<file stem>:<prefix>`` when another loop
    has that name); an incomplete or ambiguous loop is a source whose analysis fails
    with the reason.

    Returns
    -------
    list of LoopSource
        Sorted by loop name.

    Raises
    ------
    DataError
        ``path`` does not exist, holds no loop files, or a dataset cannot be read.
    UsageError
        ``loop_column`` is not a column of the dataset, or ``path`` is not a dataset.
    """
    p = Path(path)
    if not p.exists():
        raise DataError(
            f"{p}: no such file or folder; give a folder of loop files or a Parquet dataset"
        )
    if p.is_dir():
        files = _loop_files(p)
        top = [f for f in files if f.parent == p]
        nested = [f for f in files if f.parent != p]
    else:
        files, top, nested = [p], [p], []
    if not files:
        raise DataError(f"{p}: no .csv or .parquet files found")
    all_parquet = all(f.suffix.lower() in (".parquet", ".pq") for f in files)
    if all_parquet and not any(is_long_file(f) for f in files):
        # Possibly one dataset holding many loops, told apart by a loop-id column.
        try:
            dataset = _open_dataset(p)
            names = dataset.schema.names
        except Exception as exc:  # pyarrow raises many types for corrupt files
            if nested or not top:
                raise DataError(f"{p}: cannot read as a Parquet dataset ({exc})") from None
            # A folder of per-loop files: a corrupt one fails in its own row below.
            dataset, names = None, []
        lower = {n.lower(): n for n in names}
        col = loop_column
        if col is None:
            col = next((lower[c] for c in LOOP_ID_COLUMNS if c in lower), None)
        elif dataset is not None and col not in names:
            raise UsageError(f"loop column {col!r} not in {p} (columns: {', '.join(names)})")
        if dataset is not None and col is not None:
            try:
                ids = _loop_ids(dataset, col)
            except Exception as exc:  # a corrupt file inside the dataset
                raise DataError(f"{p}: cannot read loop ids from {col!r} ({exc})") from None
            if not ids:
                raise DataError(f"{p}: the loop column {col!r} holds no loop ids")
            return [LoopSource(str(i), str(p), col) for i in ids]
        if nested:
            raise DataError(
                f"{p}: Parquet files in subfolders but no loop-id column "
                f"(one of {', '.join(LOOP_ID_COLUMNS)}); give --loop-column"
            )
    if loop_column is not None:
        raise UsageError(
            f"--loop-column {loop_column!r} applies to a Parquet dataset; {p} holds CSV files"
        )
    # One loop per file, or many in a whole-plant export (io.plant), in subfolders
    # too; loops with one name get distinct names.
    skip = {Path(f).resolve() for f in exclude}
    found = [
        (plant.loop, f, plant)
        for f in files
        if f.resolve() not in skip
        for plant in _plant_loops(f)
    ]
    if not found:
        raise DataError(f"{p}: no loop files found (only the loops manifest)")
    # A loop of a plant file whose name another loop also has is named by its file too.
    count: dict[str, int] = {}
    for loop, _, _ in found:
        count[loop.lower()] = count.get(loop.lower(), 0) + 1
    found = [
        (
            f"{f.stem}:{loop}" if plant.layout != "file" and count[loop.lower()] > 1 else loop,
            f,
            plant,
        )
        for loop, f, plant in found
    ]
    names = unique_names([n for n, _, _ in found], [str(f) for _, f, _ in found])
    loops = [
        loop if safe_name(loop) == n else n for (loop, _, _), n in zip(found, names, strict=True)
    ]
    return sorted(
        (
            LoopSource(loop, str(f), plant=None if plant.layout == "file" else plant)
            for loop, (_, f, plant) in zip(loops, found, strict=True)
        ),
        key=lambda s: s.loop,
    )


def _plant_loops(f: Path) -> list[PlantLoop]:
    """The loops of one file; a file that cannot be read is one loop that fails in its row."""
    try:
        return plant_loops(f)
    except StictionError:
        return [PlantLoop(f.stem, str(f))]


def load_source(source: LoopSource, **read_options):
    """Read one loop as :class:`~stictiondiag.io.tags.Tags` (one loop in memory).

    A loop of a dataset is read with a row filter on the loop-id column, so only
    its own rows are read (row groups whose statistics exclude the loop are
    skipped).  In a hive-partitioned dataset only the loop's own folder
    (``<column>=<loop>/``) is opened, so reading one loop does not list the whole
    plant.
    """
    from stictiondiag.io.tags import (
        read_frame,
        read_tags,
    )

    if source.plant is not None:
        from stictiondiag.io.plant import read_plant_loop

        return read_plant_loop(source.plant, **read_options)
    if source.loop_column is None:
        return read_tags(source.path, **read_options)
    import pyarrow as pa
    import pyarrow.dataset as ds

    col = source.loop_column
    label = f"{source.path}#{source.loop}"
    partition = Path(source.path) / f"{col}={source.loop}"
    if partition.is_dir():
        files = [str(f) for f in _parquet_files(partition)]
        frame = ds.dataset(files, format="parquet").to_table().to_pandas()
        return read_frame(frame.drop(columns=[col], errors="ignore"), source=label, **read_options)
    dataset = _open_dataset(Path(source.path))
    field_type = dataset.schema.field(col).type
    value: str | int | float = source.loop
    if pa.types.is_integer(field_type):
        value = int(value)
    elif pa.types.is_floating(field_type):
        value = float(value)
    frame = dataset.to_table(filter=ds.field(col) == value).to_pandas().drop(columns=[col])
    return read_frame(frame, source=label, **read_options)


def analyse_source(source: LoopSource, read_options: dict, gap: bool, plots: bool = True) -> dict:
    """Analyse one loop and return its table row, the full JSON and the loop page's
    figures (PNG bytes, drawn in the worker; none when ``plots`` is False) (never raises)."""
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze,
    )
    from stictiondiag.apps.scan_output import loop_extras

    row: dict = {"loop": source.loop, "source": source.path, "error": None}
    try:
        tags = load_source(source, **{**read_options, **(source.read_options or {})})
        result = analyze(tags, config=AnalysisConfig(gap=gap))
        full = result.to_dict()
        row.update(result.summary_row(full))
        full["loop"] = source.loop
        row["loop"] = source.loop
        row["source"] = source.path
        images, extras = loop_extras(result, plots, plant=source.plant is not None)
        row.update(extras)
        return {"row": row, "analysis": full, "images": images}
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


def error_result(source: LoopSource, message: str) -> dict:
    """The result of a loop that could not be analysed: verdict ``error`` and one line."""
    row = {"loop": source.loop, "source": source.path, "verdict": "error", "error": message}
    return {"row": row, "analysis": None}


def worker_failure(source: LoopSource, exc: BaseException) -> dict:
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
    P(stiction) and severity, descending, then loop name), the rule of every page.

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
    if engine not in ("local", "dask"):
        raise UsageError(f"unknown engine {engine!r}: use local or dask")
    if workers is not None and int(workers) < 1:
        raise UsageError(f"workers must be at least 1, got {workers}")
    workers = int(workers or os.cpu_count() or 1)
    read_options = dict(read_options or {})
    out = Path(out)
    _check_out(out)
    sources = discover(path, loop_column=loop_column, exclude=exclude)
    notes: list[str] = []
    if manifest:
        from dataclasses import replace

        from stictiondiag.io.plant import manifest_options, unmatched_manifest_rows

        sources = [
            replace(
                s,
                read_options=manifest_options(
                    manifest, s.plant.loop if s.plant is not None else s.loop, s.path
                ),
            )
            for s in sources
        ]
        notes += unmatched_manifest_rows(
            manifest, [(s.plant.loop if s.plant is not None else s.loop, s.path) for s in sources]
        )
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
        args = (read_options, gap, plots)
        runner = (
            run_local(todo, analyse_source, args, n_workers, on_error=worker_failure)
            if engine == "local"
            else run_dask(todo, analyse_source, args, n_workers, scheduler, on_error=worker_failure)
        )
        if progress:
            progress(n_skipped, len(sources), "")
        for res in runner:
            row = _save_loop(folder, res, file_names, keys, settings)
            rows.append(row)
            if progress:
                progress(len(rows), len(sources), row["loop"])
        from stictiondiag.apps.plantwide import plantwide_step, write_plantwide

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
