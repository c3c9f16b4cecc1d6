"""Whole-plant exports: many loops in one file, wide or long, and a loops manifest.

A historian export of a plant comes in two layouts:

* **wide**: one column per tag, loops told apart by the tag's prefix
  (``Timestamp, FIC101.PV, FIC101.OP, LIC200.PV, LIC200.OP, ...``).  Columns are
  grouped by everything before their role suffix (the rules of
  :mod:`stictiondiag.io.tags`: ``.PV``, ``.OP``, ``.MV``, ``.SP`` ...); a group with
  a pv and an op is a loop, read with :func:`~stictiondiag.io.tags.read_tags` and
  its columns named, so only its columns are read;
* **long**: three columns ``timestamp, tag, value`` (CSV or Parquet).  Tags are
  grouped by prefix as above; each loop's tags are put on one grid by
  :func:`stictiondiag.io.compression.reconstruct`: the step is the scan step of the
  loop's fastest tag, a compressed tag ("recorded values" of an exception or
  swinging-door archive) is held or interpolated the way its historian reads it, a
  regularly sampled one is interpolated linearly with the gap rule of a wide file.
  The grid is reported in the loop's warnings.

A file is a wide plant export when at least two prefixes have a pv and an op.  In
it, a group that is not a loop (a pv without op, two pv columns) is listed with the
reason (:attr:`PlantLoop.problem`); the other loops are analysed.  A file with one
loop keeps the file's own reading (:func:`~stictiondiag.io.tags.read_tags`).

The loops manifest (:func:`read_manifest`) gives per-loop settings: a CSV with a
column ``file`` or ``loop`` and any of ``loop_type``, ``ts``, ``op_units``,
``op_range`` (``LO HI``) or ``op_lo``/``op_hi``, ``integrating``, ``vendor``
(``yokogawa`` reads ``.MV`` as op), ``action`` (``direct``/``reverse``),
``compression`` (``hold``/``linear``/``band``) and the tag names ``pv``, ``op``, ``mv``,
``sp``, ``time`` and ``mode`` (the controller's mode, :mod:`stictiondiag.io.mode`).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.io.columns import (
    ROLES,
    is_mv_suffix,
    is_time_name,
    mode_prefix,
    mode_rank,
    roles_of,
    yokogawa_note,
)
from stictiondiag.io.compression import archive_deadbands, reconstruct
from stictiondiag.io.mode import mode_codes, mode_labels
from stictiondiag.io.readers import read_table
from stictiondiag.io.tags import LOOP_TYPES, OP_UNITS, Tags, read_frame, read_tags
from stictiondiag.io.timebase import time_seconds

if TYPE_CHECKING:
    import pandas as pd


__all__ = [
    "LONG_COLUMNS",
    "PlantLoop",
    "is_long_file",
    "long_tag_series",
    "manifest_options",
    "plant_loops",
    "read_manifest",
    "read_plant_loop",
    "unmatched_manifest_rows",
]

#: Column names of a long export (first match of each, case-insensitive).
LONG_COLUMNS = {
    "time": ("timestamp", "time", "datetime", "date", "t"),
    "tag": ("tag", "tagname", "tag_name", "name", "point"),
    "value": ("value", "val", "v"),
}

_SUFFIX = re.compile(r"[\s._\-:/]+[^\s._\-:/]+$")
_FIELD = re.compile(r"[.](cv)$", re.IGNORECASE)  # DeltaV's current value: FIC101/PV.CV
_SERVER = re.compile(r"^\\\\[^\\]+\\")  # a PI server path: \\SRV01\FIC101.PV


@dataclass(frozen=True)
class PlantLoop:
    """One loop of a plant file.

    Attributes
    ----------
    loop : str
        Loop name: the tag prefix (``FIC101``), or the file's stem for a one-loop file.
    path : str
        The file.
    layout : str
        ``"file"`` (one loop), ``"wide"`` or ``"long"``.
    columns : dict
        Role -> column (wide) or tag (long) name.
    problem : str or None
        Why the loop cannot be analysed (incomplete or ambiguous), else None.
    notes : tuple of str
        How the tags were read (a Yokogawa ``.MV`` taken as op), for the loop's warnings.
    """

    loop: str
    path: str
    layout: str = "file"
    columns: dict = field(default_factory=dict)
    problem: str | None = None
    notes: tuple[str, ...] = ()


def _prefix(name: str) -> str:
    """A tag's loop prefix: the name without its role suffix (``FIC101.PV`` -> ``FIC101``)."""
    name = _FIELD.sub("", _SERVER.sub("", str(name).strip()))
    stripped = _SUFFIX.sub("", name)
    return stripped if stripped != name else ""


def group_tags(names: list[str]) -> dict[str, dict[str, list[str]]]:
    """Prefix -> role -> tag names, for names with a role suffix and a prefix.

    A loop's mode tags (``FIC101.MODE``, ``FIC101/MODE.ACTUAL``, :mod:`stictiondiag.io.mode`)
    join its group under ``"mode"``, the best-named first; a prefix with nothing but
    a mode tag (an on/off valve's status) is no group.
    """
    groups: dict[str, dict[str, list[str]]] = {}
    modes: dict[str, list[tuple[int, str]]] = {}
    for name in names:
        if is_time_name(name):
            continue
        rank = mode_rank(name)
        if rank is not None:
            prefix = mode_prefix(_FIELD.sub("", _SERVER.sub("", str(name).strip())))
            if prefix:
                modes.setdefault(prefix, []).append((rank, name))
            continue
        prefix = _prefix(name)
        roles = roles_of(name)
        if not prefix or len(roles) != 1:
            continue
        groups.setdefault(prefix, {}).setdefault(next(iter(roles)), []).append(name)
    for prefix, ranked in modes.items():
        if prefix in groups:
            groups[prefix]["mode"] = [name for _, name in sorted(ranked)]
    return groups


def _promote_mv(groups: dict[str, dict[str, list[str]]]) -> dict[str, str]:
    """Groups with one ``.MV`` tag and no op: the MV read as op (Yokogawa), in place.

    Returns prefix -> the note saying so.
    """

    notes = {}
    for prefix, roles in groups.items():
        mv = roles.get("mv", [])
        if "op" not in roles and len(mv) == 1 and is_mv_suffix(mv[0]):
            roles["op"] = roles.pop("mv")
            notes[prefix] = yokogawa_note(mv[0], given=False)
    return notes


def _loops_of_groups(
    path: str, groups: dict[str, dict[str, list[str]]], layout: str, time: str | None
) -> list[PlantLoop]:
    loops = []
    promoted = _promote_mv(groups)
    for prefix, roles in sorted(groups.items()):
        problem = None
        twice = [
            f"{r} ({', '.join(repr(n) for n in roles[r])})"
            for r in roles
            if len(roles[r]) > 1 and r != "mode"
        ]
        missing = [r for r in ("pv", "op") if r not in roles]
        if twice:
            problem = f"ambiguous: more than one tag for {'; '.join(twice)}: name them in --loops"
        elif missing:
            have = ", ".join(n for r in ROLES for n in roles.get(r, []))
            problem = f"incomplete: no {' and no '.join(missing)} tag (has {have})"
        columns = {r: names[0] for r, names in roles.items()}
        if time is not None:
            columns["time"] = time
        note: tuple[str, ...] = (promoted[prefix],) if prefix in promoted else ()
        if len(roles.get("mode", [])) > 1:
            others = ", ".join(repr(n) for n in roles["mode"][1:])
            note += (f"mode: read {columns['mode']!r}; {others} also looked like the mode",)
        loops.append(PlantLoop(prefix, path, layout, columns, problem, note))
    return loops


def _header(path: Path) -> pd.DataFrame:

    if path.suffix.lower() in (".parquet", ".pq") and path.is_file():
        import pandas as pd
        import pyarrow.parquet as pq

        try:
            names = pq.read_schema(path).names
        except Exception:  # noqa: BLE001 - pyarrow raises many types; read_table says why
            names = None
        if names is not None:
            return pd.DataFrame(columns=pd.Index([str(n).strip() for n in names], dtype=object))

    seen: list = []

    def select(header):
        seen.append(header)
        raise _HeaderRead  # only the header is wanted: stop before the rows are parsed

    try:
        frame = read_table(path, select)
    except _HeaderRead:
        return seen[0]
    return frame.iloc[:0]


class _HeaderRead(Exception):
    """Raised by :func:`_header`'s column selection once the header is known."""


def _long_columns(names: list[str]) -> dict[str, str] | None:
    lower = {str(n).strip().lower(): str(n) for n in names}
    if len(names) != 3:
        return None
    found = {}
    for role, options in LONG_COLUMNS.items():
        hit = next((lower[o] for o in options if o in lower), None)
        if hit is None:
            return None
        found[role] = hit
    return found if len(set(found.values())) == 3 else None


def plant_loops(path: str | os.PathLike) -> list[PlantLoop]:
    """The loops of one file: a wide or long plant export, or a one-loop file.

    Raises
    ------
    DataError
        The file cannot be read (:func:`stictiondiag.io.readers.read_table`).
    """
    file = Path(path)
    header = _header(file)
    names = [str(c) for c in header.attrs.get("written_names", header.columns)]
    long = _long_columns(names)
    if long is not None:
        tags = _long_tags(file, long)
        groups = group_tags(tags)
        if not groups:
            raise DataError(
                f"{file}: a long export ({', '.join(long.values())}) but no tag has a role "
                "suffix such as .PV or .OP: name the tags <loop>.PV, <loop>.OP"
            )
        return _loops_of_groups(str(file), groups, "long", None)
    groups = group_tags(names)
    complete = [
        g for g in groups.values() if "pv" in g and ("op" in g or len(g.get("mv", [])) == 1)
    ]
    if len(complete) < 2:
        # One loop (perhaps beside a valve-position tag of another name): the file's
        # own reading, with its column rules and messages.
        return [PlantLoop(file.stem, str(file))]
    times = [n for n in names if is_time_name(n)]
    return _loops_of_groups(str(file), groups, "wide", times[0] if len(times) == 1 else None)


def _long_tags(file: Path, long: dict[str, str]) -> list[str]:
    """The distinct tags of a long export (of a Parquet file, only its tag column is read)."""
    if file.suffix.lower() in (".parquet", ".pq"):
        import pyarrow.compute as pc
        import pyarrow.parquet as pq

        column = pq.read_table(file, columns=[long["tag"]]).column(0)
        return sorted(str(t) for t in pc.unique(column).to_pylist() if t is not None)
    frame = _read_long(file, long, None)
    return sorted({str(t) for t in frame[long["tag"]].dropna().unique()})


def _read_long(file: Path, long: dict[str, str], tags: list[str] | None) -> pd.DataFrame:

    if file.suffix.lower() in (".parquet", ".pq") and tags is not None:
        import pyarrow.dataset as ds

        table = ds.dataset(str(file), format="parquet").to_table(
            filter=ds.field(long["tag"]).isin(tags)
        )
        return table.to_pandas()
    frame = read_table(file)
    if tags is not None:
        frame = frame[frame[long["tag"]].astype(str).isin(tags)]
    return frame


def _resample_long(
    frame: pd.DataFrame,
    long: dict[str, str],
    tags: dict[str, str],
    label: str,
    compression: str | None = None,
    notes: list[str] | None = None,
) -> tuple[pd.DataFrame, str, dict[str, float]]:
    """Role columns on one grid (time [s] from the first grid point), a note and the
    deadband of each held tag by role
    (:func:`stictiondiag.io.compression.archive_deadbands`).

    The grid and the reconstruction of compressed tags are those of
    :func:`stictiondiag.io.compression.reconstruct`.  A mode tag's words are read by
    :func:`stictiondiag.io.mode.mode_codes` (a tag that holds no modes is left out,
    said in ``notes``), held on the grid and written back as words.
    """
    import pandas as pd

    seconds = time_seconds(frame[long["time"]], long["time"], label)
    values = pd.to_numeric(frame[long["value"]], errors="coerce").to_numpy(dtype=float)
    series = {}
    repeated: dict[str, int] = {}
    for role, tag in tags.items():
        if role == "time":
            continue
        keep = (frame[long["tag"]].astype(str) == tag).to_numpy() & np.isfinite(seconds)
        if role == "mode":
            codes = mode_codes(
                frame[long["value"]][keep], tag, label, [] if notes is None else notes
            )
            if codes is None:
                continue
            mode_values = np.full(values.size, np.nan)
            mode_values[keep] = codes
            keep &= np.isfinite(mode_values)
            t, v = _in_time_order(seconds[keep], mode_values[keep])
            if t.size:
                series[role] = t, v
            continue
        keep &= np.isfinite(values)
        t, v = seconds[keep], values[keep]
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        unique = np.concatenate(([True], np.diff(t) > 0)) if t.size else np.ones(0, bool)
        if not unique.all():
            repeated[tag] = int((~unique).sum())
        t, v = t[unique], v[unique]
        if t.size < 1 or (t.size < 2 and role in ("pv", "op")):
            raise DataError(f"{label}: tag {tag!r} has {t.size} samples: export more of it")
        series[role] = (t, v)
    arrays, grid, step, compressed = reconstruct(series, label, compression)
    if "mode" in arrays:
        arrays["mode"] = mode_labels(arrays["mode"])
    # Absolute time kept (epoch seconds where the export has dates): the clock of the record.
    out = {"time": grid, **arrays}
    if compressed is not None:
        note = f"long export: {compressed}"
    else:
        tagged = ", ".join(f"{tags[r]} {series[r][0].size} rows" for r in series if r != "mode")
        note = (
            f"long export: tags resampled to a common grid of {grid.size} points every "
            f"{step:g} s (the fastest tag's step: {tagged})"
        )
    if repeated:
        # A clock set back (the daylight-saving fall-back hour written in local
        # time) repeats stamps: the first value of each stamp is kept, said here.
        listed = ", ".join(f"{tag} {n}" for tag, n in repeated.items())
        note += (
            f"; repeated time stamps ({listed} rows; a clock set back, e.g. the "
            "daylight-saving fall-back hour in local time?): kept the first value of each, "
            "export in UTC to keep them all"
        )
    return pd.DataFrame(out), note, archive_deadbands(series, label, compression)


def _in_time_order(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and values sorted by time, the first value of a repeated stamp kept."""
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    unique = np.concatenate(([True], np.diff(t) > 0)) if t.size else np.ones(0, bool)
    return t[unique], v[unique]


def read_plant_loop(loop: PlantLoop, **read_options) -> Tags:
    """Read one loop of a plant file as :class:`~stictiondiag.io.tags.Tags`.

    ``read_options`` are those of :func:`~stictiondiag.io.tags.read_tags`; column
    names given there win over the grouping's.

    Raises
    ------
    DataError
        The loop is incomplete or ambiguous (:attr:`PlantLoop.problem`), or cannot be read.
    """
    from dataclasses import replace

    if loop.problem:
        raise DataError(f"loop {loop.loop} of {loop.path}: {loop.problem}")
    if loop.layout == "file":
        return read_tags(loop.path, **read_options)
    vendor = read_options.get("vendor")
    if loop.notes and vendor not in (None, "yokogawa") and read_options.get("op") is None:
        raise DataError(
            f"loop {loop.loop} of {loop.path}: no op tag (vendor {vendor} reads "
            f"{loop.columns['op']!r} as the valve position): name op in --loops"
        )
    named = {r: c for r, c in loop.columns.items() if read_options.get(r) is None}
    options = {**read_options, **named}
    label = f"{loop.path}#{loop.loop}"
    if loop.layout == "wide":
        tags = _read_wide(Path(loop.path), options, label)
        return replace(tags, warnings=(*loop.notes, *tags.warnings)) if loop.notes else tags
    file = Path(loop.path)
    header = _header(file)
    long = _long_columns([str(c) for c in header.columns])
    if long is None:
        raise DataError(f"{file} is no longer a long export (timestamp, tag, value)")
    wanted = {r: options[r] for r in (*ROLES, "mode") if options.get(r)}
    frame = _read_long(file, long, list(wanted.values()))
    notes: list[str] = []
    grid, note, deadband = _resample_long(
        frame, long, wanted, label, options.get("compression"), notes
    )
    wanted = {r: tag for r, tag in wanted.items() if r in grid.columns}
    given = {k: v for k, v in options.items() if k not in (*ROLES, "time", "compression", "mode")}
    # Columns named by their tags, so the ISA tag decides the loop type as in a wide file.
    tags = read_frame(
        grid.rename(columns=wanted),
        source=label,
        time="time",
        archive_deadband=deadband,
        **given,
        **wanted,
    )
    return replace(tags, warnings=(*loop.notes, note, *notes, *tags.warnings))


def _read_wide(file: Path, options: dict, label: str) -> Tags:
    """One loop of a wide export: only its own columns, its own rows.

    Rows before the loop's first and after its last sample (loops of one export
    recorded over different spans) are not part of its record.
    """

    columns = [options[r] for r in (*ROLES, "time", "mode") if options.get(r)]
    frame = read_table(file, lambda header: columns)
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise DataError(f"{label}: column {missing[0]!r} not found in {file}")
    frame = frame[columns]
    roles = [options[r] for r in ROLES if options.get(r)]
    present = frame[roles].notna().any(axis=1).to_numpy()
    if present.any():
        first, last = int(np.argmax(present)), len(present) - int(np.argmax(present[::-1]))
        frame = frame.iloc[first:last].reset_index(drop=True)
    return read_frame(frame, source=label, **options)


# --------------------------------------------------------------------------- manifest

_MANIFEST_KEYS = (
    "loop_type",
    "ts",
    "op_units",
    "op_range",
    "integrating",
    "vendor",
    "action",
    "compression",
    *ROLES,
    "time",
    "mode",
)

#: Manifest columns with a fixed set of values -> the values (lower case).
_CHOICES = {
    "vendor": ("yokogawa", "honeywell", "deltav", "pi", "generic"),
    "action": ("direct", "reverse"),
    "compression": ("hold", "linear", "band"),
}


def _cell(value) -> str | None:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return None
    text = str(value).strip()
    return text or None


def read_manifest(path: str | os.PathLike) -> dict[str, dict]:
    """Per-loop read options from a loops manifest CSV (module docstring).

    Returns
    -------
    dict
        Key (the row's ``file`` as written, or ``loop``) -> options for
        :func:`~stictiondiag.io.tags.read_tags`.

    Raises
    ------
    UsageError
        The file cannot be read, has no ``file``/``loop`` column, an unknown
        column, a bad value (row named).
    """

    file = Path(path)
    try:
        frame = read_table(file)
    except DataError as exc:
        # The manifest is the user's settings, not plant data: a usage error.
        raise UsageError(f"loops manifest: {str(exc).splitlines()[0]}") from None
    frame.columns = [str(c).strip().lower() for c in frame.columns]
    keys = [c for c in ("file", "loop") if c in frame.columns]
    if not keys:
        raise UsageError(f"loops manifest {file} needs a 'file' or 'loop' column")
    allowed = {*keys, *_MANIFEST_KEYS, "op_lo", "op_hi", "comment"}
    unknown = [c for c in frame.columns if c not in allowed]
    if unknown:
        raise UsageError(
            f"loops manifest {file}: unknown column {unknown[0]!r} "
            f"(use {', '.join(('file', 'loop', *_MANIFEST_KEYS, 'op_lo', 'op_hi'))})"
        )
    out: dict[str, dict] = {}
    for i, row in enumerate(frame.to_dict("records"), start=2):
        key = next((_cell(row[k]) for k in keys if _cell(row.get(k))), None)
        where = f"loops manifest {file} line {i}"
        if key is None:
            raise UsageError(f"{where}: no file or loop named")
        options: dict = {}
        for role in (*ROLES, "time", "mode"):
            if _cell(row.get(role)):
                options[role] = _cell(row[role])
        lt = _cell(row.get("loop_type"))
        if lt is not None:
            if lt.lower() not in LOOP_TYPES:
                raise UsageError(f"{where}: loop_type {lt!r} is not one of {', '.join(LOOP_TYPES)}")
            options["loop_type"] = lt.lower()
        units = _cell(row.get("op_units"))
        if units is not None:
            unit = {"%": "percent", "percent": "percent", "ma": "mA"}.get(units.lower())
            if unit is None:
                raise UsageError(f"{where}: op_units {units!r} is not one of {', '.join(OP_UNITS)}")
            options["op_units"] = unit
        ts = _cell(row.get("ts"))
        if ts is not None:
            try:
                value = float(ts)
            except ValueError:
                value = float("nan")
            if not (math.isfinite(value) and value > 0):
                raise UsageError(f"{where}: ts {ts!r} is not a positive number of seconds")
            options["ts"] = value
        rng = _cell(row.get("op_range"))
        lo, hi = _cell(row.get("op_lo")), _cell(row.get("op_hi"))
        if rng is not None or lo is not None or hi is not None:
            parts = re.split(r"[\s;/]+|(?<=\d)-(?=\d)", rng) if rng else [lo, hi]
            try:
                low, high = (float(p) for p in parts if p not in (None, ""))
            except (TypeError, ValueError):
                raise UsageError(
                    f"{where}: op_range {rng or f'{lo} {hi}'!r} must be 'LO HI' with LO < HI"
                ) from None
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise UsageError(f"{where}: op_range must be 'LO HI' with finite LO < HI")
            options["op_range"] = (low, high)
        for setting, choices in _CHOICES.items():
            choice = _cell(row.get(setting))
            if choice is not None:
                if choice.lower() not in choices:
                    raise UsageError(
                        f"{where}: {setting} {choice!r} is not one of {', '.join(choices)}"
                    )
                options[setting] = choice.lower()
        integ = _cell(row.get("integrating"))
        if integ is not None:
            flag = {"true": True, "yes": True, "1": True, "false": False, "no": False, "0": False}
            if integ.lower() not in flag:
                raise UsageError(f"{where}: integrating {integ!r} must be true or false")
            options["integrating"] = flag[integ.lower()]
        if key in out:
            raise UsageError(f"{where}: {key!r} is listed twice")
        out[key] = options
    return out


def manifest_options(manifest: dict[str, dict], loop: str, path: str) -> dict | None:
    """The manifest's options for a loop (by loop name) or its file (by name or path)."""
    p = Path(path)
    for key in (loop, p.name, str(p), p.stem):
        if key in manifest:
            return manifest[key]
    return None


def unmatched_manifest_rows(manifest: dict[str, dict], loops: list[tuple[str, str]]) -> list[str]:
    """One warning naming the manifest rows that match none of ``loops`` (name, file).

    A row that matches no loop (a typo, a name in the wrong case) would otherwise be
    dropped without a word, its settings never applied.  Returns an empty list when
    every row matches.
    """
    used: set[str] = set()
    for loop, path in loops:
        p = Path(path)
        for key in (loop, p.name, str(p), p.stem):
            if key in manifest:
                used.add(key)
                break
    unmatched = [key for key in manifest if key not in used]
    if not unmatched:
        return []
    known = {name.lower(): name for loop, path in loops for name in (loop, Path(path).name)}
    shown = []
    for key in unmatched[:10]:
        near = known.get(key.lower())
        shown.append(f"{key!r} (did you mean {near!r}?)" if near else repr(key))
    more = f" and {len(unmatched) - 10} more" if len(unmatched) > 10 else ""
    return [
        f"loops manifest: {len(unmatched)} row(s) match no loop, their settings are not "
        f"used: {', '.join(shown)}{more}; names are matched exactly (case included)"
    ]


def is_long_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a long ``timestamp, tag, value`` export (False if unreadable)."""
    try:
        header = _header(Path(path))
    except (DataError, OSError):
        return False
    return _long_columns([str(c) for c in header.columns]) is not None


def long_tag_series(
    path: str | os.PathLike, tags: list[str]
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Time [s] and values of each of ``tags`` in a long export, in time order (one read).

    The stamps as recorded, not resampled (the plant-wide grouping puts every
    loop on one grid itself); rows whose time or value cannot be read are left out.

    Raises
    ------
    DataError
        The file is not a long export, or cannot be read.
    """
    import pandas as pd

    file = Path(path)
    long = _long_columns([str(c) for c in _header(file).columns])
    if long is None:
        raise DataError(f"{file} is not a long export (timestamp, tag, value)")
    frame = _read_long(file, long, list(tags))
    t = time_seconds(frame[long["time"]], long["time"], str(file))
    values = pd.to_numeric(frame[long["value"]], errors="coerce").to_numpy(dtype=float)
    names = frame[long["tag"]].astype(str).to_numpy()
    out = {}
    for tag in tags:
        sel = (names == tag) & np.isfinite(t) & np.isfinite(values)
        order = np.argsort(t[sel], kind="stable")
        out[tag] = (t[sel][order], values[sel][order])
    return out
