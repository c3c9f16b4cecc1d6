"""Reading historian exports (CSV, Excel .xlsx, Parquet) into a table, read-only and bounded in memory.

:func:`read_table` opens a file (never writing to it) and returns a DataFrame.  It
first reads the header (a CSV's first line, a Parquet file's schema) and lets the
caller choose the columns it needs (``select``), so a 20 000-column export costs the
few columns of one loop.  A large CSV is read in chunks of :data:`CHUNK_ROWS` rows,
so the parser's working memory does not grow with the file.

A CSV's separator is the most frequent of ``,``, ``;``, tab and ``|`` in its header; a
``;``-separated file whose numbers carry a decimal comma (a European locale) is read
with ``decimal=","``.  An ``.xlsx`` workbook's first sheet is read with openpyxl.

Header names are stripped of surrounding spaces.  Two columns whose names are equal
(ignoring case) would be silently renamed by the parser (``pv`` and ``pv.1``); the
header returned to ``select`` keeps them as they are, so the caller can refuse them
by name (:func:`duplicate_names`).
"""

from __future__ import annotations

import bz2
import csv
import gzip
import io
import lzma
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stictiondiag.core.errors import DataError, StictionError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["CHUNK_ROWS", "MAX_ROWS", "duplicate_names", "max_rows", "read_table"]

#: Rows per chunk when a CSV is read in chunks.
CHUNK_ROWS = 1_000_000

#: Most rows a file may have [rows]; ``STICTION_MAX_ROWS`` overrides it.  The
#: analysis needs up to about 1 KB per sample (docs/performance.md: 0.3 KB without
#: the gap diagnosis, about 2 KB with it; 10^7 samples ran in 3.4 GB), so 10^7 rows
#: keep one loop within a few GB.  Rows are counted while the file is read, a chunk
#: at a time (compressed files included, whose size on disk says nothing of their
#: rows), so a file past the ceiling stops the read in bounded memory.
MAX_ROWS = 10_000_000


def max_rows() -> int:
    """The row ceiling in force: ``STICTION_MAX_ROWS`` if set to a positive whole
    number, else :data:`MAX_ROWS`."""
    import os

    try:
        value = int(os.environ.get("STICTION_MAX_ROWS", MAX_ROWS))
    except ValueError:
        return MAX_ROWS
    return value if value > 0 else MAX_ROWS


def _too_many_rows(file: Path, ceiling: int) -> DataError:
    return DataError(
        f"{file} has more than {ceiling:,} rows, the ceiling of one record (the analysis "
        "needs up to 1 KB of memory per sample): cut the export to the period to "
        "analyse, or raise STICTION_MAX_ROWS"
    )


#: Files above this size [bytes] are read in chunks (below, one read is faster).
_CHUNKED_ABOVE = 64 * 1024 * 1024

_CSV_SUFFIXES = {".csv", ".tsv", ".txt"}
_PARQUET_SUFFIXES = {".parquet", ".pq"}
_COMPRESSION = {".gz": "gzip", ".bz2": "bz2", ".xz": "xz"}
_EXCEL_SUFFIXES = {".xlsx", ".xlsm"}
_SPREADSHEET_SUFFIXES = {".xls", ".ods"}
_DELIMITERS = (",", ";", "\t", "|")

#: ``select(header)`` gets the header as an empty DataFrame (Parquet: with the
#: column types) and returns the names to read, or None for all.
Select = Callable[["pd.DataFrame"], Sequence[str] | None]


def duplicate_names(names: Sequence[str]) -> dict[str, list[int]]:
    """Names (lower-cased) that occur more than once -> their 1-based column numbers."""
    seen: dict[str, list[int]] = {}
    for i, name in enumerate(names, start=1):
        seen.setdefault(str(name).strip().lower(), []).append(i)
    return {name: where for name, where in seen.items() if len(where) > 1}


def read_table(file: Path, select: Select | None = None) -> pd.DataFrame:
    """The table in ``file`` (CSV, compressed CSV or Parquet), opened read-only.

    Raises
    ------
    DataError
        Missing file, a directory, an empty, binary, corrupt or unknown file.
    """
    if not file.exists():
        raise DataError(f"file not found: {file}: check the path")
    if file.is_dir():
        raise DataError(f"{file} is a directory: give one CSV or Parquet file")
    suffixes = [suffix.lower() for suffix in file.suffixes]
    compression = _COMPRESSION.get(suffixes[-1]) if suffixes else None
    kind = suffixes[-2] if compression and len(suffixes) > 1 else (suffixes[-1] if suffixes else "")
    if kind in _PARQUET_SUFFIXES and compression is None:
        return _read_parquet(file, select)
    if kind in _CSV_SUFFIXES:
        return _read_csv(file, compression, select)
    if kind in _EXCEL_SUFFIXES and compression is None:
        return _read_excel(file, select)
    if kind in _SPREADSHEET_SUFFIXES:
        raise DataError(
            f"{file} is a {kind} spreadsheet: save the sheet as .xlsx or CSV, or export Parquet"
        )
    shown = "".join(file.suffixes) or "no extension"
    raise DataError(
        f"unknown file type ({shown}) for {file}: give a .csv, .tsv, .txt, .xlsx or .parquet file"
    )


def _reason(exc: BaseException) -> str:
    text = str(exc).strip()
    return " ".join(text.splitlines()[0].split())[:200] if text else type(exc).__name__


def _read_parquet(file: Path, select: Select | None) -> pd.DataFrame:
    import pyarrow
    import pyarrow.parquet as pq

    if file.stat().st_size == 0:
        raise DataError(f"{file} is empty: export the loop data again")
    try:
        with open(file, "rb") as handle:
            parquet = pq.ParquetFile(handle)
            ceiling = max_rows()
            if parquet.metadata.num_rows > ceiling:
                raise _too_many_rows(file, ceiling)
            if select is not None:
                header = parquet.schema_arrow.empty_table().to_pandas()
                header.columns = [str(c).strip() for c in header.columns]
                select(header)  # raises on a missing or ambiguous column
            frame = parquet.read().to_pandas()
    except StictionError:
        raise
    except (pyarrow.ArrowException, OSError, ValueError, TypeError) as exc:
        raise DataError(
            f"{file} is not a readable Parquet file ({_reason(exc)}): export it again"
        ) from None
    # A datetime index written by pandas becomes a column in read_frame and can
    # then serve as the time column.
    return frame


def _read_excel(file: Path, select: Select | None) -> pd.DataFrame:
    """The first sheet of an ``.xlsx`` workbook (openpyxl), header in its first row.

    The sheet is streamed row by row (openpyxl's read-only mode) and its rows are
    counted as they come: past :func:`max_rows` the read stops with a one-line
    :class:`DataError`, in memory bounded by the ceiling.
    """
    import zipfile

    import pandas as pd

    if file.stat().st_size == 0:
        raise DataError(f"{file} is empty: export the loop data again")
    try:
        from openpyxl import load_workbook
    except ImportError:
        raise DataError(f"{file}: reading .xlsx needs openpyxl (pip install openpyxl)") from None
    ceiling = max_rows()
    try:
        book = load_workbook(file, read_only=True, data_only=True)
        try:
            rows = book.worksheets[0].iter_rows(values_only=True)
            header = next(rows, None)
            data: list[tuple] = []
            for row in rows:
                if all(v is None for v in row):
                    continue  # an empty row, as pandas leaves it out
                if len(data) >= ceiling:
                    raise _too_many_rows(file, ceiling)
                data.append(row)
        finally:
            book.close()
    except (ValueError, KeyError, OSError, zipfile.BadZipFile, TypeError, IndexError) as exc:
        raise DataError(f"{file} is not a readable .xlsx workbook ({_reason(exc)})") from None
    if header is None:
        raise DataError(f"{file} has no header row: export the loop data with a header row")
    names = [
        f"Unnamed: {i}" if name is None else str(name).strip() for i, name in enumerate(header)
    ]
    width = len(names)
    frame = pd.DataFrame(
        [tuple(r[:width]) + (None,) * (width - len(r)) for r in data], columns=names
    )
    frame = frame.infer_objects()
    if select is not None:
        chosen = select(frame.iloc[:0])
        if chosen is not None:
            frame = frame[[c for c in frame.columns if c in set(chosen)]]
    return frame


def _decimal_comma(text: str, separator: str) -> bool:
    """Whether a ``;``-separated CSV writes numbers with a decimal comma (European locale)."""
    if separator == ",":
        return False
    body = "\n".join(text.splitlines()[1:50])
    return len(re.findall(r"\d,\d", body)) > len(re.findall(r"\d\.\d", body))


def _head(file: Path, compression: str | None) -> bytes:
    openers: dict[str | None, Callable[..., Any]] = {
        None: open,
        "gzip": gzip.open,
        "bz2": bz2.open,
        "xz": lzma.open,
    }
    opener = openers[compression]
    try:
        with opener(file, "rb") as handle:
            return handle.read(65536)
    except (OSError, EOFError, lzma.LZMAError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        what = f"{compression} " if compression else ""
        raise DataError(
            f"cannot read {what}file {file} ({reason}): check the file and its permissions"
        ) from None


def _read_csv(file: Path, compression: str | None, select: Select | None) -> pd.DataFrame:
    import pandas as pd

    if file.stat().st_size == 0:
        raise DataError(f"{file} is empty: export the loop data again")
    head = _head(file, compression)
    if not head.strip():
        raise DataError(f"{file} is empty: export the loop data again")
    if b"\x00" in head:
        raise DataError(f"{file} is not a text CSV file (binary content): export it as CSV")
    encoding = _encoding(head)
    first_line = head.decode(encoding, errors="replace").lstrip().splitlines()[0]
    separator = max(_DELIMITERS, key=first_line.count)
    options: dict[str, Any] = {
        "sep": separator,
        "encoding": encoding,
        "compression": compression,
        "skipinitialspace": True,
    }
    if _decimal_comma(head.decode(encoding, errors="replace"), separator):
        options["decimal"] = ","
    # A compressed file's size says nothing of its rows: read it in chunks, counted.
    chunked = compression is not None or file.stat().st_size > _CHUNKED_ABOVE
    ceiling = max_rows()
    try:
        if select is not None:
            with open(file, "rb") as handle:
                names = [str(c).strip() for c in pd.read_csv(handle, nrows=0, **options).columns]
            header = pd.DataFrame(columns=pd.Index(names, dtype=object))
            # The parser renames repeated names (pv, pv.1); the caller sees them as written.
            raw = [
                n.strip() for n in next(csv.reader(io.StringIO(first_line), delimiter=separator))
            ]
            header.attrs["written_names"] = raw if len(raw) == len(names) else names
            chosen = select(header)
            if chosen is not None:
                positions = {name: i for i, name in enumerate(names)}
                options["usecols"] = sorted({positions[n] for n in chosen if n in positions})
        with open(file, "rb") as handle:
            if chunked:
                frame = _read_chunks(handle, options, ceiling, file)
            else:
                frame = pd.read_csv(handle, low_memory=False, **options)
        if len(frame) > ceiling:
            raise _too_many_rows(file, ceiling)
    except StictionError:
        raise
    except pd.errors.EmptyDataError:
        raise DataError(f"{file} is empty: export the loop data again") from None
    except (
        pd.errors.ParserError,
        UnicodeDecodeError,
        ValueError,
        OSError,
        EOFError,
        lzma.LZMAError,
    ) as exc:
        raise DataError(
            f"{file} is not a readable CSV file ({_reason(exc)}): export it again"
        ) from None
    frame.columns = [str(column).strip() for column in frame.columns]
    return frame


def _read_chunks(handle, options: dict, ceiling: int, file: Path) -> pd.DataFrame:
    """A CSV read :data:`CHUNK_ROWS` rows at a time, each column kept as one array.

    Each chunk's columns are appended to per-column lists and the chunk is let go, so
    the peak is the columns read plus one chunk, not the parser's buffers for the
    whole file.  Past ``ceiling`` rows the read stops (DataError).
    """
    import numpy as np
    import pandas as pd

    parts: dict[str, list] = {}
    rows = 0
    size = max(1, min(CHUNK_ROWS, ceiling + 1))
    with pd.read_csv(handle, chunksize=size, **options) as reader:
        for chunk in reader:
            rows += len(chunk)
            if rows > ceiling:
                raise _too_many_rows(file, ceiling)
            for column in chunk.columns:
                parts.setdefault(column, []).append(chunk[column].to_numpy())
    columns = {}
    for column in list(parts):
        arrays = parts.pop(column)
        if len({a.dtype.kind for a in arrays}) > 1:  # numbers in one chunk, text in another
            arrays = [a.astype(object) for a in arrays]
        columns[column] = np.concatenate(arrays)
        del arrays
    return pd.DataFrame(columns, copy=False)


def _encoding(head: bytes) -> str:
    # Historian exports are UTF-8 or a Windows code page (degree signs in unit
    # annotations); latin-1 decodes any byte, so it is the fallback.
    try:
        head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        # A multi-byte character cut at the end of the sample is still UTF-8.
        if exc.start < len(head) - 4:
            return "latin-1"
    return "utf-8-sig"
