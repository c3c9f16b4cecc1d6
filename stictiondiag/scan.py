"""Plant-scale scan: analyse hundreds of loops and rank them for maintenance.

A plant has hundreds or thousands of loops (Section 1 of Choudhury et al. 2005); the
question is which valves to send maintenance to first.  :func:`scan` runs
:func:`stictiondiag.analysis.analyze` on every loop, on a local process pool or a Dask
cluster (``dask.distributed``), and ranks the loops by stiction severity and
confidence.

Design:

* A loop is a :class:`LoopSource`: one file, or one loop id inside a Parquet dataset
  (read with a row filter, so a worker holds one loop at a time).
* At most ``2 x workers`` loops are in flight, so memory is bounded by the loops being
  analysed, not by the size of the plant.
* A broken loop never stops the scan: its error is a row of the table.
* Each finished loop is written to ``OUT/loops/<loop>.json`` at once (atomically); a
  rerun skips the loops already there unless ``force`` is set, so a scan resumes.
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

from .errors import DataError, StictionError, UsageError

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


def discover(path: str | os.PathLike, *, loop_column: str | None = None) -> list[LoopSource]:
    """List the loops under ``path``.

    ``path`` is a folder of per-loop CSV or Parquet files, or a Parquet file or dataset
    folder with a loop-id column (``loop_column``, or one of :data:`LOOP_ID_COLUMNS`).
    """
    import pyarrow.dataset as ds

    p = Path(path)
    if not p.exists():
        raise DataError(
            f"{p}: no such file or folder; give a folder of loop files or a Parquet dataset"
        )
    files = (
        sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in LOOP_FILE_SUFFIXES)
        if p.is_dir()
        else [p]
    )
    if not files:
        raise DataError(f"{p}: no .csv or .parquet files found")
    parquet = [f for f in files if f.suffix.lower() in (".parquet", ".pq")]
    # A Parquet dataset with a loop-id column: one dataset, many loops.
    if parquet and len(parquet) == len(files):
        try:
            dataset = ds.dataset([str(f) for f in parquet], format="parquet")
            names = dataset.schema.names
        except Exception as exc:  # pyarrow raises many types for corrupt files
            raise DataError(f"{p}: cannot read as Parquet ({exc})") from None
        lower = {n.lower(): n for n in names}
        col = loop_column
        if col is None:
            col = next((lower[c] for c in LOOP_ID_COLUMNS if c in lower), None)
        elif col not in names:
            raise UsageError(f"loop column {col!r} not in {p} (columns: {', '.join(names)})")
        if col is not None:
            ids = dataset.to_table(columns=[col]).column(col).to_pandas().dropna().unique()
            target = str(p)
            return [LoopSource(str(i), target, col) for i in sorted(ids, key=str)]
    return [LoopSource(f.stem, str(f)) for f in files]


def load_source(source: LoopSource, **read_options):
    """Read one loop as :class:`~stictiondiag.tags.Tags` (one loop in memory)."""
    from .tags import read_tags

    if source.loop_column is None:
        return read_tags(source.path, **read_options)
    import pyarrow.dataset as ds

    p = Path(source.path)
    files = (
        sorted(str(f) for f in p.iterdir() if f.suffix.lower() in (".parquet", ".pq"))
        if p.is_dir()
        else [str(p)]
    )
    dataset = ds.dataset(files, format="parquet")
    col = source.loop_column
    field_type = dataset.schema.field(col).type
    import pyarrow as pa

    value = source.loop
    if pa.types.is_integer(field_type):
        value = int(value)
    elif pa.types.is_floating(field_type):
        value = float(value)
    frame = dataset.to_table(filter=ds.field(col) == value).to_pandas().drop(columns=[col])
    from .tags import read_frame

    return read_frame(frame, source=f"{source.path}#{source.loop}", **read_options)


def analyse_source(source: LoopSource, read_options: dict, gap: bool) -> dict:
    """Analyse one loop and return its table row plus the full JSON (never raises)."""
    from .analysis import AnalysisConfig, analyze

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
        row.update(
            verdict="error", error=str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        )
    except Exception as exc:  # one broken loop must never stop a plant scan
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" at {last[0].name}" if last else ""
        row.update(verdict="error", error=f"internal error{where}: {type(exc).__name__}: {exc}")
    return {"row": row, "analysis": None}


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


def rank(rows: list[dict]) -> pd.DataFrame:
    """Rows ordered by verdict, then severity (descending), then loop name."""
    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    if "error" not in frame:
        frame["error"] = None
    frame["severity"] = [severity(r) for r in rows]
    frame["_vr"] = frame["verdict"].map(VERDICT_RANK).fillna(len(VERDICT_RANK))
    frame = frame.sort_values(
        ["_vr", "severity", "loop"], ascending=[True, False, True], kind="mergesort"
    )
    frame = frame.drop(columns="_vr").reset_index(drop=True)
    frame.insert(0, "rank", range(1, len(frame) + 1))
    return frame


def run_local(todo, fn, args: tuple, workers: int) -> Iterator:
    """Yield ``fn(src, *args)`` for each source, on a process pool of ``workers``.

    At most ``2 x workers`` loops are in flight, so memory is bounded by the loops
    being analysed, not by their number.  Results come in completion order.
    """
    if workers <= 1:
        for src in todo:
            yield fn(src, *args)
        return
    import concurrent.futures as cf
    import multiprocessing as mp

    ctx = mp.get_context("spawn")  # no forked numba/BLAS state in workers
    with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        it = iter(todo)
        pending = {
            pool.submit(fn, src, *args) for _, src in zip(range(2 * workers), it, strict=False)
        }
        while pending:
            done, pending = cf.wait(pending, return_when=cf.FIRST_COMPLETED)
            for fut in done:
                yield fut.result()
                nxt = next(it, None)
                if nxt is not None:
                    pending.add(pool.submit(fn, nxt, *args))


def run_dask(todo, fn, args: tuple, workers: int, scheduler: str | None) -> Iterator:
    """Like :func:`run_local` on ``dask.distributed`` (a LocalCluster or ``scheduler``)."""
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
            cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
            )
            client = Client(cluster)
    except OSError as exc:
        raise UsageError(f"cannot reach Dask scheduler {scheduler!r}: {exc}") from None
    try:
        n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)
        it = iter(todo)
        first = [
            client.submit(fn, s, *args, pure=False)
            for _, s in zip(range(2 * n_workers), it, strict=False)
        ]
        ac = as_completed(first)
        for fut in ac:
            yield fut.result()
            fut.release()
            nxt = next(it, None)
            if nxt is not None:
                ac.add(client.submit(fn, nxt, *args, pure=False))
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
        Output folder: ``scan.parquet``, ``scan.csv``, ``index.html`` and
        ``loops/<loop>.json``.
    engine : {"local", "dask"}
        Process pool on this machine, or ``dask.distributed`` (a LocalCluster, or the
        scheduler at ``scheduler``).
    workers : int, optional
        Worker processes (default: all cores).
    force : bool
        Re-analyse loops already in ``out`` (default: resume, skipping them).
    gap : bool
        Include the sim-to-real gap diagnosis (slower).
    progress : callable, optional
        Called as ``progress(done, total, loop)`` after each loop.
    """
    from .atomic import write_atomic

    if engine not in ("local", "dask"):
        raise UsageError(f"unknown engine {engine!r}: use local or dask")
    workers = int(workers or os.cpu_count() or 1)
    if workers < 1:
        raise UsageError("workers must be >= 1")
    read_options = dict(read_options or {})
    sources = discover(path, loop_column=loop_column)
    names = [_safe_name(s.loop) for s in sources]
    if len(set(names)) != len(names):
        raise DataError(f"{path}: two loops share a name after sanitising; rename the files")
    out = Path(out)
    loops_dir = out / "loops"
    loops_dir.mkdir(parents=True, exist_ok=True)

    rows: list[dict] = []
    todo: list[LoopSource] = []
    for src, name in zip(sources, names, strict=True):
        done_file = loops_dir / f"{name}.json"
        if done_file.exists() and not force:
            try:
                rows.append(json.loads(done_file.read_text())["row"])
                continue
            except (ValueError, KeyError, OSError):
                pass  # unreadable record: analyse again
        todo.append(src)
    n_skipped = len(rows)
    total = len(sources)

    args = (read_options, gap)
    runner = (
        run_local(todo, analyse_source, args, workers)
        if engine == "local"
        else run_dask(todo, analyse_source, args, workers, scheduler)
    )
    n_done = n_skipped
    if progress:
        progress(n_done, total, "")
    for res in runner:
        row = res["row"]
        rows.append(row)
        write_atomic(
            loops_dir / f"{_safe_name(row['loop'])}.json",
            json.dumps({"row": row, "analysis": res["analysis"]}, indent=1, default=_json_default),
        )
        n_done += 1
        if progress:
            progress(n_done, total, row["loop"])

    table = rank(rows)
    outputs = write_table(table, out)
    n_failed = int((table["verdict"] == "error").sum()) if not table.empty else 0
    return ScanResult(table, total, n_failed, n_skipped, outputs)


def _json_default(o):
    try:
        v = float(o)
    except (TypeError, ValueError):
        return str(o)
    return v if math.isfinite(v) else None


def write_table(table: pd.DataFrame, out: Path) -> dict:
    """Write the ranked table as Parquet, CSV and an HTML page (each atomically)."""
    from .atomic import atomic_path, write_atomic

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
