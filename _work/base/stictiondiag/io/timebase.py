"""Time columns: their unit, and the uniform grid the signals are put on.

Section 3 of Choudhury, Thornhill & Shah (2005) works on uniformly sampled plant
data; historian exports give time stamps, not always in seconds and not always
regular.  This module turns a time column into seconds (:func:`time_seconds`) and the
signals onto a uniform grid whose size is bounded by the number of rows, never by
the worst time stamp (:func:`uniform`).

Units (:func:`time_seconds`)
----------------------------
* Timestamps and ISO 8601 strings: seconds since the epoch.
* A unit named in the header wins: ``time [ms]``, ``time_us``, ``t (min)`` ...
  (:data:`NAME_UNITS`).
* Otherwise numbers are seconds, except where the size of the bulk of them (5 to
  95 % quantiles; a few mistyped stamps do not decide) says otherwise (dates from
  1990 to 2100): epoch milliseconds (6.3e11 to 4.1e12), microseconds (6.3e14 to
  4.1e15) and nanoseconds (6.3e17 to 4.1e18) are converted, and so are Excel serial
  dates (days since 1899-12-30, 32 874 to 73 051) whose step is below 0.01 day
  (14.4 min: a sampling no seconds counter in that range would have).  Each
  conversion is noted in the warnings; sizes that fit no reading are warned about.

Grid (:func:`uniform`)
----------------------
The sample time is the median step, so one stamp far in the future (a typo in one
ISO stamp) changes nothing of it.  Where the clock jumps by more than
``MAX_GAP_SAMPLES + 1`` steps the record is split: the grid covers the stretches
between such gaps only, with a marker of missing samples in place of each gap
(which the gap rules of :mod:`stictiondiag.io.tags` then cut at), so the grid holds
at most about ``(MAX_GAP_SAMPLES + 1) x`` rows samples.  A grid longer than
:data:`MAX_GRID_SAMPLES` is a one-line :class:`DataError`.
"""

from __future__ import annotations

import math
import re
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import DataError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["MAX_GRID_SAMPLES", "NAME_UNITS", "note_ts_mismatch", "time_seconds", "uniform"]

#: Longest run of missing samples [samples] interpolated later (see io.tags).
MAX_GAP_SAMPLES = 10

#: Most samples a uniform grid may hold: 2e7 samples are 160 MB per signal, 231 days
#: at 1 s; a longer record should be cut before the analysis.
MAX_GRID_SAMPLES = 20_000_000

#: A whole-span grid up to this many times the number of rows is built as is; a
#: longer one (a clock that jumps) is split at its gaps.
_GRID_PER_ROW = 4

# Relative mismatch between an explicit ts and a time column's median step that
# is worth a note.
_TS_MISMATCH_TOLERANCE = 0.01

# Relative spread of time steps still treated as uniform sampling (historian
# clocks jitter by a fraction of a percent).
_UNIFORM_STEP_TOLERANCE = 0.01

#: Units named in a time column's header [s per unit].
NAME_UNITS = {
    "s": 1.0,
    "sec": 1.0,
    "secs": 1.0,
    "second": 1.0,
    "seconds": 1.0,
    "ms": 1e-3,
    "msec": 1e-3,
    "millis": 1e-3,
    "milliseconds": 1e-3,
    "us": 1e-6,
    "\u00b5s": 1e-6,
    "\u03bcs": 1e-6,
    "usec": 1e-6,
    "microseconds": 1e-6,
    "ns": 1e-9,
    "nanoseconds": 1e-9,
    "min": 60.0,
    "mins": 60.0,
    "minutes": 60.0,
    "h": 3600.0,
    "hr": 3600.0,
    "hrs": 3600.0,
    "hours": 3600.0,
    "d": 86400.0,
    "day": 86400.0,
    "days": 86400.0,
}

# Epoch ranges for dates from 1990-01-01 to 2100-01-01 [s]: (low, high, s per unit, name).
_EPOCH_LOW, _EPOCH_HIGH = 631_152_000.0, 4_102_444_800.0
_EPOCH_UNITS = (
    (1e-3, "epoch milliseconds"),
    (1e-6, "epoch microseconds"),
    (1e-9, "epoch nanoseconds"),
)
# Excel serial days of the same dates, and the step below which they are days.
_EXCEL_LOW, _EXCEL_HIGH = 32_874.0, 73_051.0
_EXCEL_MAX_STEP_DAYS = 0.01
_EXCEL_EPOCH_S = -2_209_161_600.0  # 1899-12-30 in epoch seconds

_BRACKETED = re.compile(r"[\(\[\{]\s*([^\)\]\}]*?)\s*[\)\]\}]")
_SEPARATORS = re.compile(r"[\s._\-:/]+")


def _named_unit(column: str) -> float | None:
    """Seconds per unit named in a time header (``time [ms]``, ``time_ms``), else None."""
    name = str(column).lower()
    for inside in _BRACKETED.findall(name):
        if inside.strip() in NAME_UNITS:
            return NAME_UNITS[inside.strip()]
    tokens = [token for token in _SEPARATORS.split(_BRACKETED.sub(" ", name)) if token]
    if len(tokens) >= 2 and tokens[-1] in NAME_UNITS:
        return NAME_UNITS[tokens[-1]]
    return None


def _numeric_seconds(values: np.ndarray, column: str, notes: list[str]) -> np.ndarray:
    """Numbers of a time column as seconds: the named unit, or one their size implies."""
    per_unit = _named_unit(column)
    if per_unit is not None:
        return values * per_unit
    finite = values[np.isfinite(values)]
    if finite.size < 2:
        return values
    # The bulk of the stamps decides (a few mistyped ones are the grid's business).
    low, middle, high = (float(q) for q in np.quantile(finite, [0.05, 0.5, 0.95]))
    for per, label in _EPOCH_UNITS:
        if _EPOCH_LOW <= low * per and high * per <= _EPOCH_HIGH:
            notes.append(
                f"time column {column!r} holds {label} ({low:.6g} to {high:.6g}): converted "
                f"to seconds; name the unit in the header (e.g. 'time [s]') to read it otherwise"
            )
            return values * per
    if _EXCEL_LOW <= low and high <= _EXCEL_HIGH:
        steps = np.diff(np.sort(finite))
        steps = steps[steps > 0]
        step = float(np.median(steps)) if steps.size else 0.0
        if 0.0 < step < _EXCEL_MAX_STEP_DAYS:
            notes.append(
                f"time column {column!r} holds Excel serial dates ({low:.6g} to {high:.6g} "
                f"days): converted to seconds; name the unit in the header (e.g. 'time [s]') "
                "to read it otherwise"
            )
            return _EXCEL_EPOCH_S + values * 86400.0
        if _EXCEL_MAX_STEP_DAYS <= step < 1.0:
            notes.append(
                f"time column {column!r} ({low:.6g} to {high:.6g}, step {step:.6g}) could be "
                "Excel serial days or seconds: read as seconds; name the unit in the header "
                "(e.g. 'time [d]') or give ts=<seconds>"
            )
    elif middle > 10 * _EPOCH_HIGH:
        notes.append(
            f"time column {column!r} is near {middle:.6g}, too large for epoch seconds and "
            "unlike epoch ms/us/ns: read as seconds; name the unit in the header "
            "(e.g. 'time [ms]') or give ts=<seconds>"
        )
    return values


def time_seconds(
    series: pd.Series, column: str, file: str, notes: list[str] | None = None
) -> np.ndarray:
    """Time column as seconds (float, NaN where unreadable); unit rules in the module doc.

    Raises
    ------
    DataError
        The column holds neither numbers nor timestamps.
    """
    import pandas as pd

    notes = [] if notes is None else notes
    if pd.api.types.is_datetime64_any_dtype(series):
        stamps = series
    elif pd.api.types.is_timedelta64_dtype(series):
        return series.dt.total_seconds().to_numpy(dtype=float, na_value=np.nan)
    elif pd.api.types.is_numeric_dtype(series) and not pd.api.types.is_bool_dtype(series):
        values = series.to_numpy(dtype=float, na_value=np.nan)
        return _numeric_seconds(values, column, notes)
    else:
        text = series.astype("string").str.strip()
        numbers = pd.to_numeric(text, errors="coerce")
        if numbers.notna().sum() >= 0.5 * text.notna().sum() > 0:
            values = numbers.to_numpy(dtype=float, na_value=np.nan)
            return _numeric_seconds(values, column, notes)
        stamps = _parse_stamps(text, column, file)
    stamps = pd.Series(stamps)
    if stamps.dt.tz is not None:
        stamps = stamps.dt.tz_convert("UTC").dt.tz_localize(None)
    nanoseconds = stamps.to_numpy(dtype="datetime64[ns]").astype("int64").astype(float)
    nanoseconds[stamps.isna().to_numpy()] = np.nan
    return nanoseconds * 1e-9


def _parse_stamps(text: pd.Series, column: str, file: str) -> pd.Series:
    """ISO 8601 strings (then any format pandas recognises) as UTC timestamps."""
    import pandas as pd

    need = 0.5 * max(int(text.notna().sum()), 1)
    try:
        stamps = pd.to_datetime(text, format="ISO8601", utc=True, errors="coerce")
    except (ValueError, TypeError, OverflowError):
        stamps = pd.Series(pd.NaT, index=text.index)
    if stamps.notna().sum() < need:
        # 26.11.2026 14:00 (a European locale) is day first; 11/26/2026 is left to pandas.
        first = str(text.dropna().iloc[0]) if text.notna().any() else ""
        dayfirst = re.match(r"^\d{1,2}\.\d{1,2}\.\d{4}", first) is not None
        try:
            stamps = pd.to_datetime(
                text, format="mixed", utc=True, errors="coerce", dayfirst=dayfirst
            )
        except (ValueError, TypeError, OverflowError):
            stamps = pd.Series(pd.NaT, index=text.index)
    if stamps.notna().sum() < need:
        example = str(text.dropna().iloc[0]) if text.notna().any() else ""
        raise DataError(
            f"time column {column!r} in {file} is neither seconds nor timestamps "
            f"(e.g. {example[:30]!r}): name the time column with time=<column> or give ts=<seconds>"
        )
    return stamps


def check_grid(n_grid: int, ts: float, column: str) -> None:
    """Refuse a grid longer than :data:`MAX_GRID_SAMPLES` (memory bounded by the data)."""
    if n_grid > MAX_GRID_SAMPLES:
        raise DataError(
            f"time column {column!r} needs a grid of {n_grid:,} samples at {ts:.6g} s, more "
            f"than {MAX_GRID_SAMPLES:,}: cut the record, or give ts=<seconds> to read the rows "
            "as uniformly sampled"
        )


def _on_grid(
    arrays: dict[str, np.ndarray], seconds: np.ndarray, ts: float
) -> dict[str, np.ndarray]:
    """Linear interpolation onto ``seconds[0] + k ts``; points inside long gaps are NaN."""
    n_grid = int(math.floor((seconds[-1] - seconds[0]) / ts + 1e-9)) + 1
    return onto_grid(arrays, seconds, seconds[0] + ts * np.arange(n_grid), ts)


def onto_grid(
    arrays: dict[str, np.ndarray], seconds: np.ndarray, grid: np.ndarray, ts: float
) -> dict[str, np.ndarray]:
    """Signals sampled at increasing ``seconds``, linearly interpolated onto ``grid``
    (step ``ts`` [s]); grid points inside a clock gap longer than
    :data:`MAX_GAP_SAMPLES` steps are NaN.  O(n log n) in the grid's length."""
    # Grid points inside a time gap too long to interpolate become missing values,
    # so the gap rules treat a hole in the clock like a hole in the data.
    right = np.clip(np.searchsorted(seconds, grid, side="left"), 1, max(seconds.size - 1, 1))
    if seconds.size > 1:
        bracket = seconds[right] - seconds[right - 1]
        # On a sample: within rounding of the stamp (1 us, or a millionth of a step).
        # A relative tolerance would not do: on epoch seconds (about 1.7e9) numpy's
        # default one spans hours, and no clock gap was ever found in a timestamped file.
        near = 1e-6 * (1.0 + ts)
        exact = (np.abs(grid - seconds[right]) <= near) | (
            np.abs(grid - seconds[right - 1]) <= near
        )
        in_gap = (bracket > (MAX_GAP_SAMPLES + 1) * ts) & ~exact
    else:
        in_gap = np.zeros(grid.size, dtype=bool)
    resampled = {}
    for role, values in arrays.items():
        on_grid = np.interp(grid, seconds, values)
        on_grid[in_gap] = np.nan
        resampled[role] = on_grid
    return resampled


def _split_at_gaps(
    arrays: dict[str, np.ndarray], seconds: np.ndarray, ts: float, column: str, notes: list[str]
) -> dict[str, np.ndarray]:
    """Grid per stretch between long clock gaps, joined by markers of missing samples."""
    steps = np.diff(seconds)
    gaps = np.flatnonzero(steps > (MAX_GAP_SAMPLES + 1) * ts)
    bounds = np.concatenate(([0], gaps + 1, [seconds.size]))
    sizes = [
        int(math.floor((seconds[b - 1] - seconds[a]) / ts + 1e-9)) + 1
        for a, b in zip(bounds[:-1], bounds[1:], strict=True)
    ]
    marker = MAX_GAP_SAMPLES + 1
    check_grid(sum(sizes) + marker * (len(sizes) - 1), ts, column)
    pieces: dict[str, list[np.ndarray]] = {role: [] for role in arrays}
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        part = _on_grid({role: v[a:b] for role, v in arrays.items()}, seconds[a:b], ts)
        for role, values in part.items():
            if k:
                pieces[role].append(np.full(marker, np.nan))
            pieces[role].append(values)
    widest = float(steps[gaps].max())
    notes.append(
        f"time: {gaps.size} jump(s) of the clock in {column!r} longer than "
        f"{MAX_GAP_SAMPLES + 1} steps (up to {widest:.6g} s, e.g. a mistyped stamp): the record "
        f"is split there into {len(sizes)} stretches ({', '.join(map(str, sizes[:6]))}"
        f"{', ...' if len(sizes) > 6 else ''} samples)"
    )
    return {role: np.concatenate(parts) for role, parts in pieces.items()}


def uniform(
    arrays: dict[str, np.ndarray], seconds: np.ndarray, column: str, notes: list[str]
) -> tuple[dict[str, np.ndarray], float]:
    """Signals on a uniform grid with the median time step; returns (arrays, ts [s]).

    Rows without a readable stamp are dropped, rows are sorted by time and repeated
    stamps dropped (each noted).  See the module docstring for the grid.

    Raises
    ------
    DataError
        Fewer than two distinct stamps, or a grid beyond :data:`MAX_GRID_SAMPLES`.
    """
    keep = np.isfinite(seconds)
    if not keep.all():
        notes.append(f"time: dropped {int((~keep).sum())} rows without a readable time stamp")
        seconds = seconds[keep]
        arrays = {role: values[keep] for role, values in arrays.items()}
    if seconds.size < 2:
        raise DataError(
            f"time column {column!r} has fewer than 2 readable time stamps: "
            f"fix the time column or give ts=<seconds>"
        )
    if np.any(np.diff(seconds) < 0):
        order = np.argsort(seconds, kind="stable")
        notes.append(f"time: rows were not in time order; sorted by {column!r}")
        seconds = seconds[order]
        arrays = {role: values[order] for role, values in arrays.items()}
    unique = np.concatenate(([True], np.diff(seconds) > 0))
    if not unique.all():
        notes.append(f"time: dropped {int((~unique).sum())} rows with a repeated time stamp")
        seconds = seconds[unique]
        arrays = {role: values[unique] for role, values in arrays.items()}
    if seconds.size < 2:
        raise DataError(
            f"time column {column!r} does not increase: fix the time column or give ts=<seconds>"
        )
    steps = np.diff(seconds)
    ts = float(np.median(steps))
    if not (math.isfinite(ts) and ts > 0.0):
        raise DataError(
            f"time column {column!r} has no usable step: fix the time column or give ts=<seconds>"
        )
    if np.all(np.abs(steps - ts) <= _UNIFORM_STEP_TOLERANCE * ts):
        return arrays, ts
    span = (seconds[-1] - seconds[0]) / ts
    irregular = (
        f"time steps of {column!r} are irregular ({steps.min():.6g} to {steps.max():.6g} s, "
        f"median {ts:.6g} s): resampled linearly onto a uniform {ts:.6g} s grid"
    )
    if span <= _GRID_PER_ROW * seconds.size:
        check_grid(int(span) + 1, ts, column)
        resampled = _on_grid(arrays, seconds, ts)
        notes.append(irregular)
        return resampled, ts
    resampled = _split_at_gaps(arrays, seconds, ts, column, notes)
    notes.append(irregular)
    return resampled, ts


def note_ts_mismatch(series: pd.Series, column: str, ts: float, notes: list[str]) -> None:
    """Note when an explicit ``ts`` disagrees with the time column's median step."""
    try:
        seconds = time_seconds(series, column, "")
    except DataError:
        return
    steps = np.diff(seconds[np.isfinite(seconds)])
    steps = steps[steps > 0]
    if steps.size and abs(np.median(steps) - ts) > _TS_MISMATCH_TOLERANCE * ts:
        notes.append(
            f"time column {column!r} steps by {np.median(steps):.6g} s (median) but ts = "
            f"{ts:g} s was given: used ts, the time column is ignored"
        )
