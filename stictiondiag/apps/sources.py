"""A plant's loops: finding them in a file or folder, and reading one of them.

A loop is a :class:`LoopSource`: one file, one loop of a whole-plant export (wide
``FIC101.PV, LIC200.PV, ...`` or long ``timestamp, tag, value``), or one loop id
inside a Parquet dataset (a file, or a folder with hive partitions such as
``loop_id=L1/``), read with a row filter so a worker holds one loop at a time.
:func:`discover` lists them; :func:`load_source` reads one as
:class:`~stictiondiag.io.tags.Tags`.  ``stiction scan``
(:mod:`stictiondiag.apps.scan`), its plant-wide step
(:mod:`stictiondiag.apps.plantwide`) and ``validate`` read loops through here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from stictiondiag.apps.pages import safe_name, unique_names
from stictiondiag.apps.scan_output import is_scan_output
from stictiondiag.core.errors import DataError, StictionError, UsageError
from stictiondiag.io.plant import PlantLoop, is_long_file, plant_loops, read_plant_loop
from stictiondiag.io.tags import read_frame, read_tags

__all__ = ["LOOP_FILE_SUFFIXES", "LOOP_ID_COLUMNS", "LoopSource", "discover", "load_source"]

#: Column names accepted as the loop id of a Parquet dataset (first match wins).
LOOP_ID_COLUMNS = ("loop_id", "loop", "loop_name", "tag", "loopid")

#: File types read as one loop each.
LOOP_FILE_SUFFIXES = (".csv", ".parquet", ".pq")


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
    if source.plant is not None:
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
