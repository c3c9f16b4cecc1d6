"""Reading control-loop tags (pv, op, mv, sp) from historian exports.

This is the first step of the procedure: turn a CSV or Parquet export into the
four signals of one loop on a uniform time grid, in the notation of Choudhury,
Thornhill & Shah (2005), Section 3: ``pv`` the process (controlled) variable,
``op`` the controller output, ``mv`` the valve output (valve position) and ``sp``
the set point. ``op`` and ``mv`` are expressed in % of valve span, the unit of the
stiction parameters S and J (Section 5). :meth:`Tags.scaled` gives the
mean-centred, unit-variance view in which Section 3 presents plant data.

Column matching rules (:func:`read_tags`)
-----------------------------------------
Every column name is normalised before matching: lower-cased, bracketed unit
annotations removed (``"PV [degC]"`` -> ``"pv"``), then split into tokens at
``.``, ``_``, ``-``, ``:``, ``/`` and spaces (``"FIC101.PV"`` -> ``fic101``,
``pv``). A column is a candidate for a role when

=====  ================================================================================
role   rule
=====  ================================================================================
pv     last token is ``pv``, ``meas`` or ``measurement``; or the whole name is
       ``process value``/``process variable``/``controlled variable``/``y``
op     last token is ``op``, ``out``, ``output`` or ``co``; or the whole name is
       ``controller output``/``control output``/``u``
mv     last token is ``mv``, ``pos``, ``position`` or ``zt``; or the tag is a
       valve-position instrument, first token ``zt...``/``zi...`` (ISA 5.1 letters
       for a position transmitter/indicator, e.g. ``ZT101`` or ``ZT-101.PV``, which is
       therefore *not* a pv candidate); or the whole name is ``valve``/``valve
       position``
sp     last token is ``sp``, ``sv``, ``spt`` or ``setpoint``; or the whole name is
       ``set point``/``reference``/``r``
time   first token is ``time``, ``timestamp``, ``datetime`` or ``date``, or the name
       is ``t``; or the column holds datetimes (also a datetime Parquet index)
=====  ================================================================================

Matching is case-insensitive. A column named exactly like the role (``pv``) wins
over other candidates. Two or more remaining candidates for a role are ambiguous
and raise :class:`~stictiondiag.core.errors.DataError` asking to name the column
(``pv="FIC101.PV"``, on the command line ``--pv FIC101.PV``). Columns given
explicitly are taken first and are never candidates for another role. Note that
``.MV`` is read as valve position, as in the paper; on systems where ``MV`` is the
controller output (Yokogawa ``.SV``/``.MV``), pass ``op=...MV`` explicitly.

Sampling
--------
* ``ts`` given: samples are taken as uniformly spaced by ``ts`` and a time column
  is not used as a clock (historian exports often carry sample counters or shifted
  clocks in the time column); a disagreeing time column is noted in the warnings.
* else a time column (numeric seconds, or timestamps / ISO 8601 strings): its
  median step is the sample time. Steps all within 1 % of the median count as
  uniform; otherwise the signals are linearly resampled onto a uniform grid with the
  median step (noted in the warnings), and grid points inside a time gap longer
  than :data:`MAX_GAP_SAMPLES` steps become missing values.
* neither: ``ts = 1 s``, noted in the warnings.

Missing values
--------------
Gaps (NaN, empty cells, non-numeric entries such as ``"Bad"`` in an otherwise
numeric column) of at most :data:`MAX_GAP_SAMPLES` samples inside the record are
linearly interpolated. Longer gaps, and gaps at the start or end of the record,
cannot be filled honestly: the longest contiguous stretch without them is kept.
Both are reported in :attr:`Tags.warnings`. Fewer than :data:`MIN_SAMPLES`
remaining samples raise :class:`~stictiondiag.core.errors.DataError`.

Warnings are collected in :attr:`Tags.warnings` (one line each) rather than issued
through :mod:`warnings`, so the caller decides how to show them (the CLI prints
them on stderr, the JSON output carries them).
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from stictiondiag.core.errors import (
    DataError,
    UsageError,
)

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "LOOP_TYPES",
    "MAX_GAP_SAMPLES",
    "MIN_SAMPLES",
    "OP_UNITS",
    "ROLES",
    "Tags",
    "read_frame",
    "read_tags",
    "scale",
]

#: Fewest samples a loop record must keep after gap handling. Stiction shows as
#: stick-slip cycles; 100 samples hold only a few cycles at typical sampling, which
#: is the least any of the later steps (oscillation detection, fitting) can use.
MIN_SAMPLES = 100

#: Longest run of missing samples [samples] that is linearly interpolated; longer
#: runs would invent whole stick or slip phases, so the record is cut instead.
MAX_GAP_SAMPLES = 10

#: Loop types accepted by ``loop_type``; "level" implies an integrating process.
LOOP_TYPES = ("flow", "pressure", "level", "temperature", "composition", "other")

#: Units of the op (and mv) columns in the file.
OP_UNITS = ("percent", "mA")

#: Signal roles in the paper's notation (Section 3).
ROLES = ("pv", "op", "mv", "sp")

LoopType = Literal["flow", "pressure", "level", "temperature", "composition", "other"]

# Relative spread of time steps still treated as uniform sampling (historian
# clocks jitter by a fraction of a percent).
_UNIFORM_STEP_TOLERANCE = 0.01

# Relative mismatch between an explicit ts and a time column's median step that
# is worth a note.
_TS_MISMATCH_TOLERANCE = 0.01

_CSV_SUFFIXES = {".csv", ".tsv", ".txt"}
_PARQUET_SUFFIXES = {".parquet", ".pq"}
_COMPRESSION = {".gz": "gzip", ".bz2": "bz2", ".xz": "xz"}
_SPREADSHEET_SUFFIXES = {".xls", ".xlsx", ".xlsm", ".ods"}
_DELIMITERS = (",", ";", "\t", "|")

_ROLE_SUFFIXES = {
    "pv": {"pv", "meas", "measurement"},
    "op": {"op", "out", "output", "co"},
    "mv": {"mv", "pos", "position", "zt"},
    "sp": {"sp", "sv", "spt", "setpoint"},
}
_ROLE_NAMES = {
    "pv": {"processvalue", "processvariable", "controlledvariable", "y"},
    "op": {"controlleroutput", "controloutput", "u"},
    "mv": {"valve", "valveposition"},
    "sp": {"setpoint", "reference", "r"},
}
_TIME_FIRST_TOKENS = {"time", "timestamp", "datetime", "date"}
_POSITION_INSTRUMENT = re.compile(r"^z[ti][a-z]?\d*[a-z]?$")
_BRACKETS = re.compile(r"[\(\[\{][^\)\]\}]*[\)\]\}]")
_SEPARATORS = re.compile(r"[\s._\-:/]+")


def scale(x: np.ndarray) -> np.ndarray:
    """Mean-centred, unit-variance copy of ``x`` (Section 3 presentation of plant data).

    Parameters
    ----------
    x : array_like
        Signal [any units].

    Returns
    -------
    ndarray
        ``(x - mean(x)) / std(x)`` [dimensionless], population standard deviation
        (ddof = 0). A constant signal has no scale: it is returned mean-centred
        (all zeros) instead of dividing by zero.
    """
    values = np.asarray(x, dtype=float)
    centred = values - values.mean()
    spread = values.std()
    if spread == 0.0 or not np.isfinite(spread):
        return centred
    return centred / spread


@dataclass(frozen=True, eq=False)
class Tags:
    """The signals of one control loop on a uniform time grid.

    Arrays are read-only, equally long and free of NaN.

    Attributes
    ----------
    time : ndarray
        Time since the first sample [s], ``k * ts``.
    pv : ndarray
        Process variable [engineering units of the file].
    op : ndarray
        Controller output [% of valve span].
    mv : ndarray or None
        Valve output / position [% of valve span], None when not recorded.
    sp : ndarray or None
        Set point [pv units], None when not recorded.
    ts : float
        Sample time [s].
    names : dict
        Role (``"pv"``, ``"op"``, ``"mv"``, ``"sp"``, ``"time"``) -> source column name.
    source : str
        Where the data came from (file path, or ``"<memory>"``).
    loop_type : str
        One of :data:`LOOP_TYPES`.
    integrating : bool
        True when the process integrates (level loops, Section 4.2.2, Table 3).
    warnings : tuple of str
        One-line notes about what reading changed (resampling, gaps, defaults).
    """

    time: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray | None
    sp: np.ndarray | None
    ts: float
    names: dict[str, str] = field(default_factory=dict)
    source: str = "<memory>"
    loop_type: str = "other"
    integrating: bool = False
    warnings: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.pv.size)

    @property
    def duration(self) -> float:
        """Record length ``n * ts`` [s]."""
        return self.n * self.ts

    def signals(self) -> dict[str, np.ndarray]:
        """Present signals by role, in the order pv, op, mv, sp."""
        found = {"pv": self.pv, "op": self.op, "mv": self.mv, "sp": self.sp}
        return {role: values for role, values in found.items() if values is not None}

    def scale_factors(self) -> dict[str, tuple[float, float]]:
        """(mean, std) used by :meth:`scaled` for each present signal.

        ``sp`` shares pv's factors and ``mv`` shares op's, so the control error
        ``sp - pv`` and the valve error ``op - mv`` keep their meaning after
        scaling (S and J in scaled op units convert back with op's std).
        """
        pv_factors = (float(self.pv.mean()), float(self.pv.std()))
        op_factors = (float(self.op.mean()), float(self.op.std()))
        factors = {"pv": pv_factors, "op": op_factors}
        if self.mv is not None:
            factors["mv"] = op_factors
        if self.sp is not None:
            factors["sp"] = pv_factors
        return factors

    def scaled(self) -> dict[str, np.ndarray]:
        """Mean-centred, unit-variance signals, as plant data are shown in Section 3.

        Returns
        -------
        dict
            Role -> scaled array [dimensionless]. ``pv`` and ``op`` have mean 0
            and standard deviation 1 (ddof = 0); ``sp`` is scaled with pv's mean
            and std and ``mv`` with op's (see :meth:`scale_factors`).
        """
        factors = self.scale_factors()
        return {
            role: (values - factors[role][0]) / factors[role][1]
            for role, values in self.signals().items()
        }

    def to_pandas(self) -> pd.DataFrame:
        """DataFrame with columns ``time`` [s], ``sp``, ``pv``, ``op``, ``mv`` (present ones)."""
        import pandas as pd

        columns: dict[str, np.ndarray] = {"time": self.time}
        for role in ("sp", "pv", "op", "mv"):
            values = getattr(self, role)
            if values is not None:
                columns[role] = values
        return pd.DataFrame(columns)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description of the record (no sample arrays; see :meth:`to_pandas`)."""
        return {
            "source": self.source,
            "names": dict(self.names),
            "n_samples": self.n,
            "ts_s": float(self.ts),
            "duration_s": float(self.duration),
            "loop_type": self.loop_type,
            "integrating": bool(self.integrating),
            "has_mv": self.mv is not None,
            "has_sp": self.sp is not None,
            "op_range_pct": [float(self.op.min()), float(self.op.max())],
            "warnings": list(self.warnings),
        }

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Tags):
            return NotImplemented
        scalars = ("ts", "names", "source", "loop_type", "integrating", "warnings")
        if any(getattr(self, name) != getattr(other, name) for name in scalars):
            return False
        for name in ("time", "pv", "op", "mv", "sp"):
            mine, theirs = getattr(self, name), getattr(other, name)
            if (mine is None) != (theirs is None):
                return False
            if mine is not None and not np.array_equal(mine, theirs):
                return False
        return True

    __hash__ = None  # type: ignore[assignment]  # holds arrays: equal but unhashable

    @classmethod
    def from_arrays(
        cls,
        pv: Sequence[float] | np.ndarray,
        op: Sequence[float] | np.ndarray,
        *,
        mv: Sequence[float] | np.ndarray | None = None,
        sp: Sequence[float] | np.ndarray | None = None,
        ts: float = 1.0,
        op_units: str = "percent",
        op_range: tuple[float, float] | None = None,
        loop_type: str = "other",
        integrating: bool | None = None,
        source: str = "<memory>",
        names: Mapping[str, str] | None = None,
    ) -> Tags:
        """Tags from in-memory arrays (simulations, benchmarks, notebooks).

        The same validation, unit conversion and gap handling as :func:`read_tags`
        apply; samples are uniformly spaced by ``ts``.

        Parameters
        ----------
        pv, op : array_like
            Process variable [pv units] and controller output [``op_units``].
        mv, sp : array_like, optional
            Valve position [``op_units``] and set point [pv units].
        ts : float
            Sample time [s], > 0.
        op_units, op_range, loop_type, integrating
            As for :func:`read_tags`.
        source : str
            Label stored in :attr:`Tags.source`.
        names : mapping, optional
            Role -> name to record in :attr:`Tags.names` (default: the role names).

        Raises
        ------
        DataError
            Unequal lengths, non-numeric, all-NaN or constant pv/op, too few samples.
        UsageError
            Bad ``ts``, ``op_units``, ``op_range`` or ``loop_type``.
        """
        ts = _check_ts(ts)
        raw = {"pv": pv, "op": op, "mv": mv, "sp": sp}
        arrays: dict[str, np.ndarray] = {}
        for role, values in raw.items():
            if values is None:
                continue
            try:
                array = np.asarray(values, dtype=float)
            except (TypeError, ValueError):
                raise DataError(
                    f"{role} is not numeric: pass an array of numbers for {role}"
                ) from None
            if array.ndim != 1:
                raise DataError(
                    f"{role} has shape {array.shape}: pass a one-dimensional array for {role}"
                )
            arrays[role] = array
        lengths = {role: array.size for role, array in arrays.items()}
        if len(set(lengths.values())) > 1:
            listed = ", ".join(f"{role} {size}" for role, size in lengths.items())
            raise DataError(f"signals differ in length ({listed}): pass equally long arrays")
        labels = {role: role for role in arrays}
        if names:
            labels.update({role: str(name) for role, name in names.items()})
        return _assemble(
            arrays,
            ts=ts,
            labels=labels,
            source=source,
            op_units=op_units,
            op_range=op_range,
            loop_type=loop_type,
            integrating=integrating,
            notes=[],
        )


def read_tags(
    path: str | os.PathLike[str],
    *,
    pv: str | None = None,
    op: str | None = None,
    mv: str | None = None,
    sp: str | None = None,
    time: str | None = None,
    ts: float | None = None,
    op_units: str = "percent",
    op_range: tuple[float, float] | None = None,
    loop_type: str = "other",
    integrating: bool | None = None,
) -> Tags:
    """Read one control loop from a CSV or Parquet file.

    The file is opened read-only and never modified.

    Parameters
    ----------
    path : str or path-like
        ``.csv``, ``.tsv``, ``.txt`` (delimiter ``,`` ``;`` tab or ``|`` detected from
        the header; optionally compressed ``.gz``/``.bz2``/``.xz``),
        or ``.parquet``/``.pq``.
    pv, op, mv, sp : str, optional
        Column names overriding the automatic matching (module docstring). ``pv``
        and ``op`` are required in the file; ``mv`` and ``sp`` are optional.
    time : str, optional
        Time column: numeric seconds, or timestamps / ISO 8601 strings.
    ts : float, optional
        Sample time [s]; when given, samples are taken as uniformly spaced by ``ts``
        and a time column is not used as a clock.
    op_units : {"percent", "mA"}
        Units of op and mv in the file. ``mA`` is a 4-20 mA signal, converted to
        % of span (Section 5.1).
    op_range : (float, float), optional
        Raw op (and mv) values at 0 % and 100 % of span, in ``op_units``
        (default (0, 100) for percent, (4, 20) for mA). E.g. ``(0, 1)`` for a
        fraction, ``(0, 4095)`` for raw DAC counts.
    loop_type : {"flow", "pressure", "level", "temperature", "composition", "other"}
        Kind of loop; ``"level"`` implies an integrating process.
    integrating : bool, optional
        Whether the process integrates; default: True for level loops only.

    Returns
    -------
    Tags
        Uniformly sampled signals, op and mv in % of span.

    Raises
    ------
    DataError
        Missing file, directory, unreadable/corrupt/empty file, unknown extension,
        missing pv/op column, ambiguous column, non-numeric column, all-NaN or
        constant pv/op, fewer than :data:`MIN_SAMPLES` usable samples.
    UsageError
        Bad ``ts``, ``op_units``, ``op_range``, ``loop_type``, or one column named
        for two roles.
    """
    _check_options(op_units, op_range, loop_type)
    if ts is not None:
        _check_ts(ts)
    file = Path(path)
    return read_frame(
        _read_frame(file),
        source=str(file),
        pv=pv,
        op=op,
        mv=mv,
        sp=sp,
        time=time,
        ts=ts,
        op_units=op_units,
        op_range=op_range,
        loop_type=loop_type,
        integrating=integrating,
    )


def read_frame(
    frame: pd.DataFrame,
    *,
    source: str = "<frame>",
    pv: str | None = None,
    op: str | None = None,
    mv: str | None = None,
    sp: str | None = None,
    time: str | None = None,
    ts: float | None = None,
    op_units: str = "percent",
    op_range: tuple[float, float] | None = None,
    loop_type: str = "other",
    integrating: bool | None = None,
) -> Tags:
    """Tags from a DataFrame already in memory, with the rules of :func:`read_tags`.

    Parameters
    ----------
    frame : pandas.DataFrame
        One loop's table (not modified). A non-default index (e.g. a
        DatetimeIndex) is used as a column, so it can serve as the time column.
    source : str
        Label for messages and :attr:`Tags.source`.
    pv, op, mv, sp, time, ts, op_units, op_range, loop_type, integrating
        As for :func:`read_tags`.
    """
    import pandas as pd

    _check_options(op_units, op_range, loop_type)
    if ts is not None:
        ts = _check_ts(ts)
    if not isinstance(frame.index, pd.RangeIndex):
        frame = frame.reset_index()
    frame = frame.rename(columns=lambda column: str(column).strip())
    if frame.shape[1] == 0 or frame.shape[0] == 0:
        raise DataError(f"{source} has no data rows: export the loop data with a header row")
    overrides = {"pv": pv, "op": op, "mv": mv, "sp": sp, "time": time}
    columns = _match_columns(frame, overrides, source)
    notes: list[str] = []
    arrays = {
        role: _numeric(frame[column], role, column, source, notes)
        for role, column in columns.items()
        if role != "time"
    }
    if ts is None and "time" in columns:
        seconds = _time_seconds(frame[columns["time"]], columns["time"], source)
        arrays, ts = _uniform(arrays, seconds, columns["time"], notes)
    else:
        if ts is None:
            ts = 1.0
            notes.append(
                "no time column and no ts given: assumed ts = 1 s; pass ts=<seconds> "
                "(CLI --ts) if the sample time differs"
            )
        elif "time" in columns:
            _note_ts_mismatch(frame[columns["time"]], columns["time"], ts, notes)
    return _assemble(
        arrays,
        ts=ts,
        labels=columns,
        source=source,
        op_units=op_units,
        op_range=op_range,
        loop_type=loop_type,
        integrating=integrating,
        notes=notes,
    )


# --------------------------------------------------------------------------- options


def _check_ts(ts: float) -> float:
    try:
        value = float(ts)
    except (TypeError, ValueError):
        raise UsageError(f"ts must be a number of seconds, not {ts!r}") from None
    if not math.isfinite(value) or value <= 0.0:
        raise UsageError(f"ts must be a positive sample time in seconds, not {ts!r}")
    return value


def _check_options(
    op_units: str, op_range: tuple[float, float] | None, loop_type: str
) -> tuple[float, float]:
    if op_units not in OP_UNITS:
        raise UsageError(f"op_units must be 'percent' or 'mA', not {op_units!r}")
    if loop_type not in LOOP_TYPES:
        raise UsageError(f"loop_type must be one of {', '.join(LOOP_TYPES)}, not {loop_type!r}")
    if op_range is None:
        return (4.0, 20.0) if op_units == "mA" else (0.0, 100.0)
    try:
        low, high = (float(value) for value in op_range)
    except (TypeError, ValueError):
        raise UsageError(
            f"op_range must be two numbers (LO, HI), the op values at 0 % and 100 % of span, "
            f"not {op_range!r}"
        ) from None
    if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
        raise UsageError(
            f"op_range must be (LO, HI) with finite LO < HI (op at 0 % and 100 % of span), "
            f"not {op_range!r}"
        )
    return low, high


# --------------------------------------------------------------------------- reading


def _read_frame(file: Path) -> pd.DataFrame:
    if not file.exists():
        raise DataError(f"file not found: {file}: check the path")
    if file.is_dir():
        raise DataError(f"{file} is a directory: give one CSV or Parquet file")
    suffixes = [suffix.lower() for suffix in file.suffixes]
    compression = _COMPRESSION.get(suffixes[-1]) if suffixes else None
    kind = suffixes[-2] if compression and len(suffixes) > 1 else (suffixes[-1] if suffixes else "")
    if kind in _PARQUET_SUFFIXES and compression is None:
        return _read_parquet(file)
    if kind in _CSV_SUFFIXES:
        return _read_csv(file, compression)
    if kind in _SPREADSHEET_SUFFIXES:
        raise DataError(f"{file} is a spreadsheet: save the sheet as CSV, or export Parquet")
    shown = "".join(file.suffixes) or "no extension"
    raise DataError(
        f"unknown file type ({shown}) for {file}: give a .csv, .tsv, .txt or .parquet file"
    )


def _read_parquet(file: Path) -> pd.DataFrame:
    import pyarrow
    import pyarrow.parquet as pq

    if file.stat().st_size == 0:
        raise DataError(f"{file} is empty: export the loop data again")
    try:
        with open(file, "rb") as handle:
            frame = pq.read_table(handle).to_pandas()
    except (pyarrow.ArrowException, OSError, ValueError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(
            f"{file} is not a readable Parquet file ({reason}): export it again"
        ) from None
    # A datetime index written by pandas becomes a column in read_frame and can
    # then serve as the time column.
    return frame


def _read_csv(file: Path, compression: str | None) -> pd.DataFrame:
    import pandas as pd

    if file.stat().st_size == 0:
        raise DataError(f"{file} is empty: export the loop data again")
    opener = {None: open, "gzip": gzip.open, "bz2": bz2.open, "xz": lzma.open}[compression]
    try:
        with opener(file, "rb") as handle:
            head = handle.read(65536)
    except (OSError, EOFError, lzma.LZMAError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        what = f"{compression} " if compression else ""
        raise DataError(
            f"cannot read {what}file {file} ({reason}): check the file and its permissions"
        ) from None
    if not head.strip():
        raise DataError(f"{file} is empty: export the loop data again")
    if b"\x00" in head:
        raise DataError(f"{file} is not a text CSV file (binary content): export it as CSV")
    encoding = _encoding(head)
    first_line = head.decode(encoding, errors="replace").lstrip().splitlines()[0]
    separator = max(_DELIMITERS, key=first_line.count)
    try:
        with open(file, "rb") as handle:
            frame = pd.read_csv(
                handle,
                sep=separator,
                encoding=encoding,
                compression=compression,
                skipinitialspace=True,
                low_memory=False,
            )
    except pd.errors.EmptyDataError:
        raise DataError(f"{file} is empty: export the loop data again") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError, OSError, EOFError) as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"{file} is not a readable CSV file ({reason}): export it again") from None
    frame.columns = [str(column).strip() for column in frame.columns]
    return frame


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


# --------------------------------------------------------------------------- columns


def _tokens(name: str) -> list[str]:
    cleaned = _BRACKETS.sub(" ", name.lower())
    return [token for token in _SEPARATORS.split(cleaned) if token]


def _is_time_name(name: str) -> bool:
    tokens = _tokens(name)
    return bool(tokens) and (tokens[0] in _TIME_FIRST_TOKENS or tokens == ["t"])


def _roles_of(name: str) -> set[str]:
    """Roles a column name is a candidate for (module docstring rules)."""
    tokens = _tokens(name)
    if not tokens:
        return set()
    joined = "".join(tokens)
    roles = {
        role for role in ROLES if tokens[-1] in _ROLE_SUFFIXES[role] or joined in _ROLE_NAMES[role]
    }
    if _POSITION_INSTRUMENT.match(tokens[0]):
        # ZT/ZI instruments measure valve position whatever their suffix says.
        return {"mv"}
    return roles


def _column_list(frame: pd.DataFrame, limit: int = 12) -> str:
    names = [str(column) for column in frame.columns]
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names)} columns)" if len(names) > limit else "")


def _resolve_override(frame: pd.DataFrame, role: str, name: str, file: str) -> str:
    columns = [str(column) for column in frame.columns]
    if name in columns:
        return name
    folded = [column for column in columns if column.lower() == str(name).lower()]
    if len(folded) == 1:
        return folded[0]
    raise DataError(
        f"{role} column {name!r} not found in {file} (columns: {_column_list(frame)}): "
        f"check the spelling of {role}=<column>"
    )


def _match_columns(
    frame: pd.DataFrame, overrides: Mapping[str, str | None], file: str
) -> dict[str, str]:
    """Role -> column name, from explicit names first, then the matching rules."""
    import pandas as pd

    chosen: dict[str, str] = {}
    for role, name in overrides.items():
        if name is None:
            continue
        column = _resolve_override(frame, role, name, file)
        for other, taken in chosen.items():
            if taken == column:
                raise UsageError(
                    f"column {column!r} is named for both {other} and {role}: "
                    f"give each role its own column"
                )
        chosen[role] = column
    free = [str(column) for column in frame.columns if str(column) not in chosen.values()]
    for role in ("pv", "op", "mv", "sp"):
        if role in chosen:
            continue
        exact = [column for column in free if column.strip().lower() == role]
        candidates = exact or [column for column in free if role in _roles_of(column)]
        if len(candidates) > 1:
            listed = ", ".join(repr(column) for column in candidates)
            raise DataError(
                f"{len(candidates)} columns in {file} look like {role} ({listed}): "
                f"name the one to use with {role}=<column> (CLI --{role} <column>)"
            )
        if candidates:
            chosen[role] = candidates[0]
            free.remove(candidates[0])
        elif role in ("pv", "op"):
            hint = ""
            mv_like = chosen.get("mv") or next(
                (column for column in free if "mv" in _roles_of(column)), None
            )
            if role == "op" and mv_like is not None:
                hint = f"; if {mv_like!r} is the controller output, pass op={mv_like!r}"
            raise DataError(
                f"no {role} column found in {file} (columns: {_column_list(frame)}): "
                f"name it with {role}=<column> (CLI --{role} <column>){hint}"
            )
    if "time" not in chosen:
        by_name = [column for column in free if _is_time_name(column)]
        by_type = [
            column
            for column in free
            if column not in by_name and pd.api.types.is_datetime64_any_dtype(frame[column])
        ]
        candidates = by_name or by_type
        if len(candidates) > 1:
            typed = [
                column
                for column in candidates
                if pd.api.types.is_datetime64_any_dtype(frame[column])
            ]
            if len(typed) != 1:
                listed = ", ".join(repr(column) for column in candidates)
                raise DataError(
                    f"{len(candidates)} columns in {file} look like time ({listed}): "
                    f"name the one to use with time=<column>, or give ts=<seconds>"
                )
            candidates = typed
        if candidates:
            chosen["time"] = candidates[0]
    return chosen


def _numeric(series: pd.Series, role: str, column: str, file: str, notes: list[str]) -> np.ndarray:
    """Column as float array; sparse non-numeric entries become gaps, mostly text is an error."""
    import pandas as pd

    if pd.api.types.is_bool_dtype(series) or pd.api.types.is_numeric_dtype(series):
        return series.to_numpy(dtype=float, na_value=np.nan)
    if pd.api.types.is_datetime64_any_dtype(series):
        raise DataError(
            f"{role} column {column!r} in {file} holds timestamps, not numbers: "
            f"name the {role} column with {role}=<column>"
        )
    text = series.astype("string").str.strip()
    present = text.notna() & (text != "")
    values = pd.to_numeric(text.where(present), errors="coerce")
    bad = present & values.isna()
    n_present, n_bad = int(present.sum()), int(bad.sum())
    if n_present == 0:
        return values.to_numpy(dtype=float, na_value=np.nan)
    if n_bad * 2 > n_present:
        example = str(text[bad].iloc[0])
        raise DataError(
            f"{role} column {column!r} in {file} is not numeric (e.g. {example[:30]!r}): "
            f"export numbers with a '.' decimal point, or name another column with {role}=<column>"
        )
    if n_bad:
        example = str(text[bad].iloc[0])
        notes.append(
            f"{role}: {n_bad} non-numeric entries (e.g. {example[:30]!r}) treated as missing"
        )
    return values.to_numpy(dtype=float, na_value=np.nan)


# --------------------------------------------------------------------------- time


def _time_seconds(series: pd.Series, column: str, file: str) -> np.ndarray:
    """Time column as seconds (float, NaN where unreadable)."""
    import pandas as pd

    if pd.api.types.is_datetime64_any_dtype(series):
        stamps = series
    elif pd.api.types.is_timedelta64_dtype(series):
        return series.dt.total_seconds().to_numpy(dtype=float, na_value=np.nan)
    elif pd.api.types.is_numeric_dtype(series) and not pd.api.types.is_bool_dtype(series):
        return series.to_numpy(dtype=float, na_value=np.nan)
    else:
        text = series.astype("string").str.strip()
        numbers = pd.to_numeric(text, errors="coerce")
        if numbers.notna().sum() >= 0.5 * text.notna().sum() > 0:
            return numbers.to_numpy(dtype=float, na_value=np.nan)
        try:
            stamps = pd.to_datetime(text, format="ISO8601", utc=True, errors="coerce")
        except (ValueError, TypeError):
            stamps = pd.Series(pd.NaT, index=series.index)
        if stamps.notna().sum() < 0.5 * max(int(text.notna().sum()), 1):
            try:
                stamps = pd.to_datetime(text, format="mixed", utc=True, errors="coerce")
            except (ValueError, TypeError):
                stamps = pd.Series(pd.NaT, index=series.index)
        if stamps.notna().sum() < 0.5 * max(int(text.notna().sum()), 1):
            example = str(text.dropna().iloc[0]) if text.notna().any() else ""
            raise DataError(
                f"time column {column!r} in {file} is neither seconds nor timestamps "
                f"(e.g. {example[:30]!r}): name the time column with time=<column> or give ts=<seconds>"
            )
    stamps = pd.Series(stamps)
    if stamps.dt.tz is not None:
        stamps = stamps.dt.tz_convert("UTC").dt.tz_localize(None)
    nanoseconds = stamps.to_numpy(dtype="datetime64[ns]").astype("int64").astype(float)
    nanoseconds[stamps.isna().to_numpy()] = np.nan
    return nanoseconds * 1e-9


def _note_ts_mismatch(series: pd.Series, column: str, ts: float, notes: list[str]) -> None:
    try:
        seconds = _time_seconds(series, column, "")
    except DataError:
        return
    steps = np.diff(seconds[np.isfinite(seconds)])
    steps = steps[steps > 0]
    if steps.size and abs(np.median(steps) - ts) > _TS_MISMATCH_TOLERANCE * ts:
        notes.append(
            f"time column {column!r} steps by {np.median(steps):.6g} s (median) but ts = "
            f"{ts:g} s was given: used ts, the time column is ignored"
        )


def _uniform(
    arrays: dict[str, np.ndarray], seconds: np.ndarray, column: str, notes: list[str]
) -> tuple[dict[str, np.ndarray], float]:
    """Signals on a uniform grid with the median time step; returns (arrays, ts)."""
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
    order = np.argsort(seconds, kind="stable")
    if np.any(np.diff(seconds) < 0):
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
    if np.all(np.abs(steps - ts) <= _UNIFORM_STEP_TOLERANCE * ts):
        return arrays, ts
    n_grid = int(math.floor((seconds[-1] - seconds[0]) / ts + 1e-9)) + 1
    grid = seconds[0] + ts * np.arange(n_grid)
    # Grid points inside a time gap too long to interpolate become missing values,
    # so the gap rules below treat a hole in the clock like a hole in the data.
    right = np.clip(np.searchsorted(seconds, grid, side="left"), 1, seconds.size - 1)
    bracket = seconds[right] - seconds[right - 1]
    exact = np.isclose(grid, seconds[right]) | np.isclose(grid, seconds[right - 1])
    in_gap = (bracket > (MAX_GAP_SAMPLES + 1) * ts) & ~exact
    resampled = {}
    for role, values in arrays.items():
        on_grid = np.interp(grid, seconds, values)
        on_grid[in_gap] = np.nan
        resampled[role] = on_grid
    notes.append(
        f"time steps of {column!r} are irregular ({steps.min():.6g} to {steps.max():.6g} s, "
        f"median {ts:.6g} s): resampled linearly onto a uniform {ts:.6g} s grid"
    )
    return resampled, ts


# --------------------------------------------------------------------------- assembly


def _nan_runs(missing: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of runs of True."""
    padded = np.concatenate(([False], missing, [False])).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist(), strict=True))


def _longest_true_run(good: np.ndarray) -> tuple[int, int]:
    runs = _nan_runs(good)
    if not runs:
        return 0, 0
    return max(runs, key=lambda run: (run[1] - run[0], -run[0]))


def _fill_gaps(
    arrays: dict[str, np.ndarray], labels: Mapping[str, str], notes: list[str]
) -> dict[str, np.ndarray]:
    """Interpolate short interior gaps, cut to the longest stretch without long gaps."""
    n = next(iter(arrays.values())).size
    if not any(np.isnan(values).any() for values in arrays.values()):
        return arrays
    unusable = np.zeros(n, dtype=bool)
    long_gaps: dict[str, int] = {}
    for role, values in arrays.items():
        for start, stop in _nan_runs(np.isnan(values)):
            if stop - start > MAX_GAP_SAMPLES or start == 0 or stop == n:
                unusable[start:stop] = True
                if stop - start > MAX_GAP_SAMPLES:
                    long_gaps[role] = max(long_gaps.get(role, 0), stop - start)
    start, stop = _longest_true_run(~unusable)
    # Cutting can leave a short gap of one signal at the new edge; edges cannot be
    # interpolated, so trim until every signal is present at both ends.
    while start < stop and any(np.isnan(values[start]) for values in arrays.values()):
        start += 1
    while stop > start and any(np.isnan(values[stop - 1]) for values in arrays.values()):
        stop -= 1
    if stop - start < MIN_SAMPLES:
        raise DataError(
            f"only {stop - start} contiguous samples without gaps longer than "
            f"{MAX_GAP_SAMPLES} remain (need at least {MIN_SAMPLES}): fill the gaps or "
            f"export a longer complete record"
        )
    if long_gaps:
        worst = ", ".join(f"{role} up to {size}" for role, size in long_gaps.items())
        notes.append(
            f"gaps longer than {MAX_GAP_SAMPLES} samples ({worst}): kept the longest complete "
            f"stretch, samples {start} to {stop - 1} ({stop - start} of {n})"
        )
    elif start > 0 or stop < n:
        notes.append(
            f"missing values at the start or end: kept samples {start} to {stop - 1} "
            f"({stop - start} of {n})"
        )
    index = np.arange(stop - start, dtype=float)
    filled: dict[str, np.ndarray] = {}
    interpolated: list[str] = []
    for role, values in arrays.items():
        part = values[start:stop].copy()
        missing = np.isnan(part)
        if missing.any():
            part[missing] = np.interp(index[missing], index[~missing], part[~missing])
            runs = _nan_runs(missing)
            interpolated.append(
                f"{labels.get(role, role)} ({len(runs)} gaps, {int(missing.sum())} samples)"
            )
        filled[role] = part
    if interpolated:
        notes.append(
            f"interpolated short gaps (<= {MAX_GAP_SAMPLES} samples) in " + ", ".join(interpolated)
        )
    return filled


def _assemble(
    arrays: dict[str, np.ndarray],
    *,
    ts: float,
    labels: Mapping[str, str],
    source: str,
    op_units: str,
    op_range: tuple[float, float] | None,
    loop_type: str,
    integrating: bool | None,
    notes: list[str],
) -> Tags:
    """Validate, convert op/mv to % of span, handle gaps and build :class:`Tags`."""
    low, high = _check_options(op_units, op_range, loop_type)
    where = "" if source == "<memory>" else f" in {source}"
    # Private copies: the caller's arrays are neither modified nor frozen.
    arrays = {role: np.array(values, dtype=float) for role, values in arrays.items()}
    for role in ("pv", "op"):
        if not np.isfinite(arrays[role]).any():
            raise DataError(
                f"{role} {labels.get(role, role)!r}{where} has no numeric values: "
                f"check the data or name another column with {role}=<column>"
            )
    for role in ("mv", "sp"):
        if role in arrays and not np.isfinite(arrays[role]).any():
            notes.append(f"{role} column {labels.get(role, role)!r} is empty: ignored")
            arrays = {key: values for key, values in arrays.items() if key != role}
    for role, values in arrays.items():
        if np.isinf(values).any():
            notes.append(f"{role}: infinite values treated as missing")
            values[np.isinf(values)] = np.nan
    arrays = _fill_gaps(arrays, labels, notes)
    n = arrays["pv"].size
    if n < MIN_SAMPLES:
        raise DataError(
            f"only {n} samples{where} (need at least {MIN_SAMPLES}): export a longer record"
        )
    for role in ("pv", "op"):
        values = arrays[role]
        if np.ptp(values) <= 1e-12 * max(1.0, float(np.abs(values).max())):
            raise DataError(
                f"{role} {labels.get(role, role)!r}{where} is constant ({values[0]:g}): stiction "
                f"needs a moving loop; pick a period when the loop was in automatic and cycling"
            )
    for role in ("op", "mv"):
        if role in arrays and (low, high) != (0.0, 100.0):
            arrays[role] = (arrays[role] - low) / (high - low) * 100.0
    outside = (arrays["op"] < -5.0) | (arrays["op"] > 105.0)
    if outside.mean() > 0.01:
        notes.append(
            f"op spans {arrays['op'].min():.4g} to {arrays['op'].max():.4g} % of span, beyond "
            f"0-100 %: check op_units/op_range (S and J are reported in these units)"
        )
    if integrating is None:
        integrating = loop_type == "level"
    for values in arrays.values():
        values.setflags(write=False)
    time = ts * np.arange(n, dtype=float)
    time.setflags(write=False)
    names = {role: str(labels[role]) for role in (*ROLES, "time") if role in labels}
    names = {role: name for role, name in names.items() if role in arrays or role == "time"}
    return Tags(
        time=time,
        pv=arrays["pv"],
        op=arrays["op"],
        mv=arrays.get("mv"),
        sp=arrays.get("sp"),
        ts=float(ts),
        names=names,
        source=source,
        loop_type=loop_type,
        integrating=bool(integrating),
        warnings=tuple(notes),
    )
