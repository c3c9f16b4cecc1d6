"""Plant-scale scan: analyse hundreds of loops and rank them for maintenance.

A plant has hundreds or thousands of loops (Section 1 of Choudhury et al. 2005); the
question is which valves to send maintenance to first.  :func:`scan` runs
:func:`stictiondiag.analysis.analyze` on every loop, on a local process pool or a Dask
cluster (``dask.distributed``), and ranks the loops by stiction severity and
confidence.

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

import json
import math
import os
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from stictiondiag.core.blas import one_blas_thread
from stictiondiag.core.errors import (
    DataError,
    StictionError,
    UsageError,
)

#: Column names accepted as the loop id of a Parquet dataset (first match wins).
LOOP_ID_COLUMNS = ("loop_id", "loop", "loop_name", "tag", "loopid")

#: File types read as one loop each.
LOOP_FILE_SUFFIXES = (".csv", ".parquet", ".pq")

#: Order of verdicts in the ranked table: what maintenance should look at first.
VERDICT_RANK = {"stiction": 0, "inconclusive": 1, "no_stiction": 2, "error": 3}


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
    """

    loop: str
    path: str
    loop_column: str | None = None
    read_options: dict | None = None


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
    """

    table: pd.DataFrame
    n_loops: int
    n_failed: int
    n_skipped: int
    outputs: dict = field(default_factory=dict)


def _safe_name(loop: str) -> str:
    keep = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in str(loop))
    return keep.strip(".") or "loop"


def _is_hidden(name: str) -> bool:
    # Dataset writers leave _SUCCESS, _common_metadata and .crc files beside the data.
    return name.startswith((".", "_"))


def _parquet_files(folder: Path) -> list[Path]:
    """Parquet files of a dataset folder, including hive partitions (``loop_id=L1/``)."""
    return sorted(
        f
        for f in folder.rglob("*")
        if f.is_file()
        and f.suffix.lower() in (".parquet", ".pq")
        and not any(_is_hidden(part) for part in f.relative_to(folder).parts)
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


def discover(path: str | os.PathLike, *, loop_column: str | None = None) -> list[LoopSource]:
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
        top = sorted(
            f
            for f in p.iterdir()
            if f.is_file() and f.suffix.lower() in LOOP_FILE_SUFFIXES and not _is_hidden(f.name)
        )
        nested = [f for f in _parquet_files(p) if f.parent != p]
    else:
        top, nested = [p], []
    if not top and not nested:
        raise DataError(f"{p}: no .csv or .parquet files found")
    all_parquet = all(f.suffix.lower() in (".parquet", ".pq") for f in top)
    if all_parquet:
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
    return [LoopSource(f.stem, str(f)) for f in top]


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
    value = source.loop
    if pa.types.is_integer(field_type):
        value = int(value)
    elif pa.types.is_floating(field_type):
        value = float(value)
    frame = dataset.to_table(filter=ds.field(col) == value).to_pandas().drop(columns=[col])
    return read_frame(frame, source=label, **read_options)


def analyse_source(source: LoopSource, read_options: dict, gap: bool) -> dict:
    """Analyse one loop and return its table row plus the full JSON (never raises)."""
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze,
    )

    row: dict = {"loop": source.loop, "source": source.path, "error": None}
    try:
        tags = load_source(source, **{**read_options, **(source.read_options or {})})
        result = analyze(tags, config=AnalysisConfig(gap=gap))
        full = result.to_dict()
        full["loop"] = source.loop
        row.update(result.summary_row())
        row["loop"] = source.loop
        row["source"] = source.path
        return {"row": row, "analysis": full}
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


def severity(row: dict) -> float:
    """Maintenance priority of a loop: confidence times stiction size (S + J) [% of span].

    Loops called ``stiction`` rank above ``inconclusive``, above ``no_stiction``,
    above failed loops; within a verdict, higher severity first.
    """
    conf = row.get("confidence")
    s, j = row.get("S"), row.get("J")
    if conf is None or s is None or j is None:
        return 0.0
    try:
        v = float(conf) * (float(s) + float(j))
    except (TypeError, ValueError):
        return 0.0
    return v if math.isfinite(v) else 0.0


#: Leading columns of the ranked table; the others follow in alphabetical order, so
#: the table's layout does not depend on which loop finished first.
LEADING_COLUMNS = (
    "rank",
    "loop",
    "verdict",
    "probability",
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
    """Rows ordered by verdict, then P(stiction) and severity (descending), then loop name.

    Verdicts in the order of :data:`VERDICT_RANK` (the verdict follows from
    P(stiction), so this ranks the analysed loops by their probability); severity
    from :func:`severity`.
    Columns: :data:`LEADING_COLUMNS`, then the rest alphabetically.
    """
    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    if "error" not in frame:
        frame["error"] = None
    frame["severity"] = [severity(r) for r in rows]
    frame["_vr"] = frame["verdict"].map(VERDICT_RANK).fillna(len(VERDICT_RANK))
    p = frame["probability"] if "probability" in frame else pd.Series(float("nan"), frame.index)
    frame["_p"] = pd.to_numeric(p, errors="coerce").fillna(-1.0)
    frame["_loop"] = frame["loop"].astype(str)
    frame = frame.sort_values(
        ["_vr", "_p", "severity", "_loop"], ascending=[True, False, False, True], kind="mergesort"
    )
    frame = frame.drop(columns=["_vr", "_p", "_loop"]).reset_index(drop=True)
    frame.insert(0, "rank", range(1, len(frame) + 1))
    lead = [c for c in LEADING_COLUMNS if c in frame.columns]
    return frame[lead + sorted(c for c in frame.columns if c not in lead)]


def run_local(
    todo,
    fn,
    args: tuple,
    workers: int,
    on_error: Callable[[object, BaseException], object] | None = None,
) -> Iterator:
    """Yield ``fn(src, *args)`` for each source, on a process pool of ``workers``.

    At most ``2 x workers`` loops are in flight, so memory is bounded by the loops
    being analysed, not by their number.  Results come in completion order.

    Parameters
    ----------
    todo : iterable
        Sources (picklable), consumed lazily.
    fn : callable
        Module-level function run in the workers (``spawn`` start method).
    args : tuple
        Further arguments of ``fn``.
    workers : int
        Worker processes; 1 runs ``fn`` in this process.
    on_error : callable, optional
        ``on_error(src, exc)`` gives the result for a source whose call raised or
        whose worker died; without it the exception propagates.  After a worker
        dies the pool is replaced and the remaining sources continue.
    """
    if workers <= 1:
        for src in todo:
            try:
                res = fn(src, *args)
            except Exception as exc:
                if on_error is None:
                    raise
                res = on_error(src, exc)
            yield res
        return
    import concurrent.futures as cf
    import multiprocessing as mp
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")  # no forked numba/BLAS state in workers
    it = iter(todo)
    pool = None
    pending: dict = {}
    # Workers (this pool's, and a fresh pool's after a worker died) get one BLAS
    # thread each.  The scan already runs one worker per core; a multi-threaded BLAS
    # in each put two threads on every core: on two cores 100 loops took 206 s with
    # two workers against 79-90 s with one BLAS thread each (benchmarks/bench_scan.py).
    with one_blas_thread():
        try:
            while True:
                if pool is None:
                    pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx)
                for src in it:
                    pending[pool.submit(fn, src, *args)] = src
                    if len(pending) >= 2 * workers:
                        break
                if not pending:
                    return
                done, _ = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
                broken = False
                for fut in done:
                    src = pending.pop(fut)
                    try:
                        res = fut.result()
                    except Exception as exc:
                        if on_error is None:
                            raise
                        broken = broken or isinstance(exc, BrokenProcessPool)
                        res = on_error(src, exc)
                    yield res
                if broken:
                    # A dead worker breaks the whole pool: the loops still in flight fail
                    # with it, and a fresh pool takes the rest.
                    for fut in cf.as_completed(list(pending)):
                        src = pending.pop(fut)
                        exc = fut.exception()
                        yield fut.result() if exc is None else on_error(src, exc)
                    pool.shutdown(wait=True, cancel_futures=True)
                    pool = None
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)


def run_dask(
    todo,
    fn,
    args: tuple,
    workers: int,
    scheduler: str | None,
    on_error: Callable[[object, BaseException], object] | None = None,
) -> Iterator:
    """Like :func:`run_local` on ``dask.distributed`` (a LocalCluster or ``scheduler``).

    The LocalCluster has ``workers`` single-threaded worker processes; with a
    ``scheduler`` address its workers must have ``stiction`` installed and see the
    data at the same paths.  At most ``2 x`` (number of workers) loops are
    submitted at a time.
    """
    try:
        from distributed import Client, LocalCluster, as_completed
    except ImportError:  # pragma: no cover - dask is a declared dependency
        raise UsageError(
            "the dask engine needs dask.distributed: pip install 'dask[distributed]'"
        ) from None
    cluster = None
    try:
        if scheduler:
            client = Client(scheduler, timeout="10s")
        else:
            # The scheduler's HTTP server (health, dashboard) takes a free port: another
            # cluster on the default 8787 must not make the scan fail or warn.
            with one_blas_thread():
                cluster = LocalCluster(
                    n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
                )
            client = Client(cluster)
    except OSError as exc:
        if cluster is not None:
            cluster.close()
        raise UsageError(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)
        it = iter(todo)
        pending: dict = {}
        for _, src in zip(range(2 * n_workers), it, strict=False):
            pending[client.submit(fn, src, *args, pure=False)] = src
        ac = as_completed(list(pending))
        for fut in ac:
            src = pending.pop(fut)
            try:
                res = fut.result()
            except Exception as exc:  # KilledWorker, or a failure outside fn
                if on_error is None:
                    raise
                res = on_error(src, exc)
            fut.release()
            yield res
            nxt = next(it, None)
            if nxt is not None:
                new = client.submit(fn, nxt, *args, pure=False)
                pending[new] = nxt
                ac.add(new)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def scan(
    path: str | os.PathLike,
    *,
    out: str | os.PathLike,
    engine: str = "local",
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    gap: bool = True,
    loop_column: str | None = None,
    read_options: dict | None = None,
    progress: Callable[[int, int, str], None] | None = None,
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
    loop_column : str, optional
        Loop-id column of a Parquet dataset (see :func:`discover`).
    read_options : dict, optional
        Options of :func:`stictiondiag.io.tags.read_tags` for every loop (e.g. ``ts``).
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
    from stictiondiag.core.atomic import write_atomic

    if engine not in ("local", "dask"):
        raise UsageError(f"unknown engine {engine!r}: use local or dask")
    if workers is not None and int(workers) < 1:
        raise UsageError(f"workers must be at least 1, got {workers}")
    workers = int(workers or os.cpu_count() or 1)
    read_options = dict(read_options or {})
    sources = discover(path, loop_column=loop_column)
    names = [_safe_name(s.loop) for s in sources]
    if len(set(names)) != len(names):
        raise DataError(f"{path}: two loops share a name after sanitising; rename the files")
    out = Path(out)
    loops_dir = out / "loops"
    loops_dir.mkdir(parents=True, exist_ok=True)
    settings = {"gap": bool(gap), "read_options": read_options}

    rows: list[dict] = []
    todo: list[LoopSource] = []
    for src, name in zip(sources, names, strict=True):
        done = None if force else _finished_row(loops_dir / f"{name}.json", src, settings)
        if done is None:
            todo.append(src)
        else:
            rows.append(done)
    n_skipped = len(rows)
    total = len(sources)

    args = (read_options, gap)
    runner = (
        run_local(todo, analyse_source, args, workers, on_error=worker_failure)
        if engine == "local"
        else run_dask(todo, analyse_source, args, workers, scheduler, on_error=worker_failure)
    )
    n_done = n_skipped
    if progress:
        progress(n_done, total, "")
    for res in runner:
        row = res["row"]
        rows.append(row)
        name = _safe_name(row["loop"])
        record = {"row": row, "settings": settings, "analysis": res["analysis"]}
        write_atomic(loops_dir / f"{name}.html", loop_html(row, res["analysis"]))
        # The JSON record marks the loop as done, so it is written last.
        write_atomic(
            loops_dir / f"{name}.json", json.dumps(record, indent=1, default=_json_default)
        )
        n_done += 1
        if progress:
            progress(n_done, total, row["loop"])

    table = rank(rows)
    outputs = write_table(table, out)
    n_failed = int((table["verdict"] == "error").sum()) if not table.empty else 0
    return ScanResult(table, total, n_failed, n_skipped, outputs)


def _finished_row(record_file: Path, source: LoopSource, settings: dict) -> dict | None:
    """The table row of a loop analysed by an earlier run, or None to analyse it (again).

    A loop is analysed again when its record is missing or unreadable, comes from
    another source file or other settings, or records a failure (the cause may
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
        or row.get("source") != source.path
        or record.get("settings") != json.loads(json.dumps(settings, default=_json_default))
    ):
        return None
    return row


def loop_html(row: dict, analysis: dict | None) -> str:
    """Per-loop page linked from the scan's ``index.html`` (no plots: fast at scale).

    ``stiction report`` on the loop's file gives the page with the phase and
    reconstruction plots.
    """
    from html import escape

    from stictiondiag.apps.report import (
        _page,
        render_loop_html,
    )

    if analysis is not None:
        page = render_loop_html(analysis, {}, json_name=f"{_safe_name(row['loop'])}.json")
        return page.replace('<a href="index.html">', '<a href="../index.html">')
    body = (
        f"<h1>Loop {escape(str(row.get('loop')))}</h1>"
        f"<p>Source <code>{escape(str(row.get('source')))}</code></p>"
        f'<p><span class="verdict error">not analysed</span></p>'
        f"<p>{escape(str(row.get('error')))}</p>"
        '<p><a href="../index.html">all loops</a></p>'
    )
    return _page(f"stiction: {row.get('loop')}", body)


def _json_default(o):
    try:
        v = float(o)
    except (TypeError, ValueError):
        return str(o)
    return v if math.isfinite(v) else None


def write_table(table: pd.DataFrame, out: Path) -> dict:
    """Write the ranked table as Parquet, CSV and an HTML page (each atomically)."""
    from stictiondiag.core.atomic import (
        atomic_path,
        write_atomic,
    )

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
    with atomic_path(paths["parquet"]) as tmp:
        clean.to_parquet(tmp, index=False)
    write_atomic(paths["csv"], clean.to_csv(index=False))
    write_atomic(paths["html"], scan_html(clean))
    return {k: str(v) for k, v in paths.items()}


def scan_html(table: pd.DataFrame) -> str:
    """Self-contained HTML page with the ranked table and per-loop links."""
    from html import escape

    cols = [
        c
        for c in (
            "rank",
            "loop",
            "verdict",
            "confidence",
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
    head = "".join(f"<th>{escape(c)}</th>" for c in cols)
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
                name = _safe_name(str(v))
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
(confidence &times; (S + J), % of span).</p>
<table><thead><tr>{head}</tr></thead><tbody>
{"".join(body)}
</tbody></table></body></html>
"""
