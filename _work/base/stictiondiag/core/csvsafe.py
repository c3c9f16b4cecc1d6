"""Spreadsheet-safe CSV cells (OWASP's rule against CSV injection).

A text cell that begins with ``=``, ``+``, ``-``, ``@``, a tab or a carriage return
is read by a spreadsheet as a formula, which may run commands or send data away.
Loop names come from file names and tag prefixes, so a CSV output of this tool must
not carry them as they are: such a cell is written with a leading apostrophe
(``'=cmd``), which spreadsheets show as text (OWASP, "CSV Injection").  Numbers
(``-1.5`` as a number) are not text and stay as they are; Parquet and JSON outputs
stay raw.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["FORMULA_STARTS", "safe_cell", "safe_frame"]

#: First characters that make a spreadsheet read a cell as a formula.
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def safe_cell(value: object) -> object:
    """``value`` with a leading apostrophe when it is text that starts a formula."""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        return "'" + value
    return value


def safe_frame(frame: pd.DataFrame) -> pd.DataFrame:
    """A copy of ``frame`` whose text cells (and column names) are :func:`safe_cell`."""
    import pandas as pd

    out = frame.copy()
    for column in out.columns:
        dtype = out[column].dtype
        if pd.api.types.is_object_dtype(dtype) or pd.api.types.is_string_dtype(dtype):
            out[column] = out[column].map(safe_cell)
    out.columns = [safe_cell(c) for c in out.columns]
    return out
