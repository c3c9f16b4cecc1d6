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
* else a time column (numbers, timestamps or ISO 8601 strings; units detected as
  described in :mod:`stictiondiag.io.timebase`: epoch ms/us/ns, Excel serial dates,
  a unit in the header): its median step is the sample time. Steps all within 1 % of
  the median count as uniform; otherwise the signals are linearly resampled onto a
  uniform grid with the median step (noted in the warnings), and grid points inside
  a time gap longer than :data:`MAX_GAP_SAMPLES` steps become missing values. A
  clock that jumps (one mistyped stamp far away) splits the record instead of
  stretching the grid, so the grid's size is bounded by the number of rows.
* neither: ``ts = 1 s``, noted in the warnings.

Missing values
--------------
Gaps (NaN, empty cells, non-numeric entries such as ``"Bad"`` in an otherwise
numeric column) of at most :data:`MAX_GAP_SAMPLES` samples inside the record are
linearly interpolated. Longer gaps, and gaps at the start or end of the record,
cannot be filled honestly: the longest contiguous stretch without them is kept.
Both are reported in :attr:`Tags.warnings`. Fewer than :data:`MIN_SAMPLES`
remaining samples raise :class:`~stictiondiag.core.errors.DataError`.

Values beyond +-:data:`~stictiondiag.io.columns.MAX_MAGNITUDE` are a
:class:`~stictiondiag.core.errors.DataError` (the statistics of later steps would
overflow); infinite values are missing values.
Files are read by :mod:`stictiondiag.io.readers`: only the loop's columns, large CSVs in
chunks; column matching lives in :mod:`stictiondiag.io.columns`.

Warnings are collected in :attr:`Tags.warnings` (one line each) rather than issued
through :mod:`warnings`, so the caller decides how to show them (the CLI prints
them on stderr, the JSON output carries them).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from stictiondiag.core.checks import check_dt
from stictiondiag.core.errors import (
    DataError,
    UsageError,
    require_bool,
)
from stictiondiag.io.columns import (
    ROLES,
    check_magnitude,
    match_columns,
    numeric_column,
)
from stictiondiag.io.compression import from_archive, sparse_roles
from stictiondiag.io.gaps import MIN_SAMPLES, fill_gaps
from stictiondiag.io.looptype import resolve_loop_type
from stictiondiag.io.mode import automatic_stretch, mode_array, mode_codes
from stictiondiag.io.opunits import check_op_travel, check_op_units
from stictiondiag.io.readers import read_table
from stictiondiag.io.timebase import (
    # Longest run of missing samples [samples] that is linearly interpolated; longer
    # runs would invent whole stick or slip phases, so the record is cut instead.
    MAX_GAP_SAMPLES,
    note_ts_mismatch,
    time_seconds,
    uniform,
)

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "LOOP_TYPES",
    "MAX_GAP_SAMPLES",
    "MIN_SAMPLES",
    "OP_UNITS",
    "ACTIONS",
    "ROLES",
    "Tags",
    "read_frame",
    "read_tags",
    "scale",
]


#: Loop types accepted by ``loop_type``; "level" implies an integrating process.
LOOP_TYPES = ("flow", "pressure", "level", "temperature", "composition", "other")

#: Units of the op (and mv) columns in the file.
OP_UNITS = ("percent", "mA")

#: Controller actions (ISA): ``direct`` raises op when pv rises, ``reverse`` lowers it.
ACTIONS = ("direct", "reverse")


LoopType = Literal["flow", "pressure", "level", "temperature", "composition", "other"]


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
    loop_type_source : str
        What decided ``loop_type`` and ``integrating``: ``"user"`` (given),
        ``"tag"`` (ISA tag prefix, :mod:`stictiondiag.io.looptype`), ``"data"``
        (:mod:`stictiondiag.identification.looptype`), ``"default"`` (nothing did:
        self-regulating assumed), or ``"pending"`` (read without a loop type; the
        data are still to decide).
    action : str or None
        Controller action given by the user (:data:`ACTIONS`), None when not given.
    op_scale : str
        ``"percent"`` (op read as % of span, units given or consistent with it) or
        ``"unknown"`` (op's range says it is in other units:
        :func:`stictiondiag.io.opunits.check_op_units`); S and J are then in op's units.
    start_time : float or None
        Clock time of the first sample [s since 1970-01-01 UTC] where the export has
        dates, else None.
    service_factor : float or None
        Share of the record read with the controller in automatic or cascade [% of
        time], where a mode tag was read (:mod:`stictiondiag.io.mode`; the samples kept
        are then the longest automatic stretch), else None.
    archive_deadband : dict
        Role -> the deadband its held (exception) archive was written with [% of span
        for op and mv, pv units for pv and sp] (:func:`~stictiondiag.io.compression.
        archive_deadbands`); empty for a record of every sample.
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
    loop_type_source: str = "user"
    action: str | None = None
    op_scale: str = "percent"
    start_time: float | None = None
    service_factor: float | None = None
    archive_deadband: Mapping[str, float] = field(default_factory=dict)

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
            "loop_type_source": self.loop_type_source,
            "has_mv": self.mv is not None,
            "has_sp": self.sp is not None,
            "op_range_pct": [float(self.op.min()), float(self.op.max())],
            "op_scale": self.op_scale,
            "action": self.action,
            "start_time_s": self.start_time,
            "service_factor_pct": self.service_factor,
            "warnings": list(self.warnings),
            # Only for a held archive: a record of every sample reads as before.
            **({"archive_deadband": dict(self.archive_deadband)} if self.archive_deadband else {}),
        }

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Tags):
            return NotImplemented
        scalars = ("ts", "names", "source", "loop_type", "integrating", "warnings",
                   "loop_type_source", "action", "op_scale", "start_time", "service_factor",
                   "archive_deadband")  # fmt: skip
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
        mode: Sequence | np.ndarray | None = None,
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
        mode : array_like, optional
            Controller mode per sample: True (automatic or cascade) or False, or the
            words of :mod:`stictiondiag.io.mode` (``"MAN"``, ``"AUTO"``, ``"CAS"`` ...);
            the record is cut to its longest automatic stretch (:attr:`Tags.service_factor`).

        Raises
        ------
        DataError
            Unequal lengths, non-numeric, all-NaN or constant pv/op, too few samples.
        UsageError
            Bad ``ts``, ``op_units``, ``op_range`` or ``loop_type``.
        """
        ts = check_dt(ts, "ts")
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
        if mode is not None:
            arrays["mode"] = mode_array(mode, arrays["pv"].size)
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
    loop_type: str | None = None,
    integrating: bool | None = None,
    compression: str | None = None,
    vendor: str | None = None,
    action: str | None = None,
    mode: str | None = None,
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
    loop_type : {"flow", "pressure", "level", "temperature", "composition", "other"}, optional
        Kind of loop; ``"level"`` implies an integrating process.  None: from the
        ISA tag prefix of the pv, op and sp columns (``LIC101.PV`` -> level,
        :mod:`stictiondiag.io.looptype`); when the names do not tell,
        :attr:`Tags.loop_type_source` is ``"pending"`` and
        :func:`stictiondiag.identification.looptype.settle_loop_type` (run by
        :func:`stictiondiag.analysis.analyze`) lets the data decide.
    integrating : bool, optional
        Whether the process integrates; default: True for level loops only.
    compression : {"hold", "linear", "band"}, optional
        How a compressed archive's tags are rebuilt (:mod:`stictiondiag.io.compression`);
        default: told per tag from its archived values.
    vendor : {"yokogawa", "honeywell", "deltav", "pi", "generic"}, optional
        The control system's tag convention (:mod:`stictiondiag.io.vendors`); decides
        whether ``.MV`` is the controller output (Yokogawa) or the valve position.
    action : {"direct", "reverse"}, optional
        Controller action (:attr:`Tags.action`), used by the replay and compensation.
    mode : str, optional
        The controller's mode column (default: found by name, :mod:`stictiondiag.io.mode`);
        the record is cut to its longest stretch in automatic or cascade.

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
    _check_options(op_units, op_range, loop_type, integrating)
    if ts is not None:
        check_dt(ts, "ts")
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a file path (str or Path), not {type(path).__name__}")
    file = Path(path)
    overrides = {"pv": pv, "op": op, "mv": mv, "sp": sp, "time": time, "mode": mode}

    def select(header: pd.DataFrame) -> list[str]:
        # The columns of this loop, matched on the header alone (same rules, same
        # errors as on the whole table), so only they are read.
        chosen = match_columns(header, overrides, str(file), header_notes, vendor)
        return list(chosen.values())

    header_notes: list[str] = []
    tags = read_frame(
        read_table(file, select),
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
        compression=compression,
        vendor=vendor,
        action=action,
        mode=mode,
    )
    if header_notes:
        # Notes about columns that were not read (another candidate for a role).
        tags = replace(tags, warnings=(*header_notes, *tags.warnings))
    return tags


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
    loop_type: str | None = None,
    integrating: bool | None = None,
    compression: str | None = None,
    vendor: str | None = None,
    action: str | None = None,
    mode: str | None = None,
    archive_deadband: Mapping[str, float] | None = None,
) -> Tags:
    """Tags from a DataFrame already in memory, with the rules of :func:`read_tags`.

    Parameters
    ----------
    frame : pandas.DataFrame
        One loop's table (not modified). A non-default index (e.g. a
        DatetimeIndex) is used as a column, so it can serve as the time column.
    source : str
        Label for messages and :attr:`Tags.source`.
    pv, op, mv, sp, time, ts, op_units, op_range, loop_type, integrating, compression,
    vendor, action, mode
        As for :func:`read_tags`.
    archive_deadband : mapping, optional
        Role -> deadband [units of the frame] of a held archive the frame was rebuilt
        from (:attr:`Tags.archive_deadband`); a sparse frame's own is read.
    """
    import pandas as pd

    if not isinstance(frame, pd.DataFrame):
        raise TypeError(
            f"read_frame takes a pandas DataFrame, not {type(frame).__name__}; "
            "use read_tags(path) for a file"
        )
    _check_options(op_units, op_range, loop_type, integrating)
    if ts is not None:
        ts = check_dt(ts, "ts")
    if not isinstance(frame.index, pd.RangeIndex):
        frame = frame.reset_index()
    frame = frame.rename(columns=lambda column: str(column).strip())
    if frame.shape[1] == 0 or frame.shape[0] == 0:
        raise DataError(f"{source} has no data rows: export the loop data with a header row")
    overrides = {"pv": pv, "op": op, "mv": mv, "sp": sp, "time": time, "mode": mode}
    notes: list[str] = []
    columns = match_columns(frame, overrides, source, notes, vendor)
    arrays = {
        role: numeric_column(frame[column], role, column, source, notes)
        for role, column in columns.items()
        if role not in ("time", "mode")
    }
    if "mode" in columns:
        codes = mode_codes(frame[columns["mode"]], columns["mode"], source, notes, vendor)
        if codes is None:
            del columns["mode"]
        else:
            arrays["mode"] = codes
    start_time: float | None = None
    deadband = dict(archive_deadband or {})
    if ts is None and "time" in columns:
        seconds = time_seconds(frame[columns["time"]], columns["time"], source, notes)
        first: float | None
        if sparse_roles(arrays, seconds):
            arrays, ts, first, deadband = from_archive(arrays, seconds, source, compression, notes)
        else:
            arrays, ts = uniform(arrays, seconds, columns["time"], notes)
            first = float(np.nanmin(seconds)) if np.isfinite(seconds).any() else None
        # Clock time only where the stamps are dates (epoch seconds 1990 to 2100).
        start_time = first if first is not None and 6.3e8 <= first <= 4.1e9 else None
    else:
        if ts is None:
            ts = 1.0
            notes.append(
                "no time column and no ts given: assumed ts = 1 s; pass ts=<seconds> "
                "(CLI --ts) if the sample time differs"
            )
        elif "time" in columns:
            note_ts_mismatch(frame[columns["time"]], columns["time"], ts, notes)
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
        action=action,
        start_time=start_time,
        archive_deadband=deadband,
    )


# --------------------------------------------------------------------------- options


def _check_options(
    op_units: str,
    op_range: tuple[float, float] | None,
    loop_type: str | None,
    integrating: object = None,
) -> tuple[float, float]:
    # integrating="no" must not be read as True: booleans (or None) only.
    require_bool("integrating", integrating, optional=True)
    for name, value in (("op_units", op_units), ("loop_type", loop_type)):
        if value is not None and not isinstance(value, str):
            raise TypeError(f"{name} must be a string, not {type(value).__name__}")
    if op_units not in OP_UNITS:
        raise UsageError(f"op_units must be 'percent' or 'mA', not {op_units!r}")
    if loop_type is not None and loop_type not in LOOP_TYPES:
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
    if not (math.isfinite(low) and math.isfinite(high) and math.isfinite(high - low)) or (
        high <= low
    ):
        raise UsageError(
            f"op_range must be (LO, HI) with finite LO < HI (op at 0 % and 100 % of span), "
            f"not {op_range!r}"
        )
    return low, high


# --------------------------------------------------------------------------- assembly


def _assemble(
    arrays: dict[str, np.ndarray],
    *,
    ts: float,
    labels: Mapping[str, str],
    source: str,
    op_units: str,
    op_range: tuple[float, float] | None,
    loop_type: str | None,
    integrating: bool | None,
    notes: list[str],
    action: str | None = None,
    start_time: float | None = None,
    archive_deadband: Mapping[str, float] | None = None,
) -> Tags:
    """Validate, convert op/mv to % of span, handle gaps and build :class:`Tags`."""
    if action is not None and action not in ACTIONS:
        raise UsageError(f"action must be one of {', '.join(ACTIONS)}, not {action!r}")
    low, high = _check_options(op_units, op_range, loop_type, integrating)
    where = "" if source == "<memory>" else f" in {source}"
    # Private copies: the caller's arrays are neither modified nor frozen.
    arrays = {role: np.array(values, dtype=float) for role, values in arrays.items()}
    mode = arrays.pop("mode", None)  # a step signal: no gap rule of its own
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
        check_magnitude(values, role, labels.get(role, role), where)
    arrays, first = fill_gaps(arrays, labels, notes)
    service_factor = None
    if mode is not None:
        cut, stop, service_factor = automatic_stretch(
            mode[first : first + arrays["pv"].size], labels.get("mode", "mode"), where, notes
        )
        arrays = {role: values[cut:stop] for role, values in arrays.items()}
        first += cut
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
    op_scale = check_op_units(
        arrays["op"], op_units, op_range, labels.get("op", "op"), where, notes
    )
    for role in ("op", "mv"):
        if role in arrays and (low, high) != (0.0, 100.0):
            arrays[role] = (arrays[role] - low) / (high - low) * 100.0
    deadband = {r: d * (100.0 / (high - low) if r in ("op", "mv") else 1.0)
                for r, d in (archive_deadband or {}).items() if r in arrays}  # fmt: skip
    if op_range is not None:
        check_op_travel(arrays["op"], (low, high), labels.get("op", "op"), notes)
    loop_type, integrating, decided_by = resolve_loop_type(
        loop_type, integrating, [labels[r] for r in ("pv", "op", "sp") if r in labels], notes
    )
    for values in arrays.values():
        values.setflags(write=False)
    time = ts * np.arange(n, dtype=float)
    time.setflags(write=False)
    names = {role: str(labels[role]) for role in (*ROLES, "time", "mode") if role in labels}
    names = {r: name for r, name in names.items() if r in arrays or r == "time" or r == "mode"}
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
        loop_type_source=decided_by,
        action=action,
        op_scale=op_scale,
        start_time=None if start_time is None else start_time + first * ts,
        service_factor=service_factor,
        archive_deadband=deadband,
    )
