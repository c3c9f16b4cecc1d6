"""The plant-wide step of a scan: group the aligned loops, rank sources, relabel the rows.

After every loop of a scan has its own analysis, :func:`plantwide_step` reads the
pv of the loops again with their time stamps, puts them on one grid, and runs
:func:`stictiondiag.stiction.plantwide.diagnose_plant`.  Each row of the scan's
table gets:

* ``plant_group``: the groups it belongs to (``"1"``, ``"1,3"``; empty for none);
* ``plant_role``: ``source_candidate``, ``propagated`` or ``independent``;
* ``plant_cause``: ``"propagated: the cycle comes from <loop>"`` for a propagated loop;
* for a propagated loop, ``verdict`` becomes ``propagated`` and ``cause`` the
  ``plant_cause``; its own call and cause are kept in ``own_verdict`` and
  ``own_cause`` (the cycle it shows is not its valve's).

Loops are time-aligned when each has a time column, all share one sample time
(within :data:`TS_TOLERANCE`) and their records overlap for at least
:data:`MIN_OVERLAP` of the shortest one: separate files recorded together, or the
loops of one wide plant export.  Otherwise grouping is off and the result says why
(a scan of loops recorded at different times has no common cycle to find).  The
loops of a long (``timestamp, tag, value``) export are read from the file's own
stamps and put on the coarsest of their pv tags' steps; loops of a Parquet dataset
with a loop-id column are not grouped.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from stictiondiag.apps.sources import load_source
from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.errors import StictionError
from stictiondiag.io.plant import long_tag_series
from stictiondiag.io.readers import read_table
from stictiondiag.io.timebase import time_seconds

__all__ = ["MIN_OVERLAP", "TS_TOLERANCE", "plantwide_step", "write_plantwide"]

#: Largest relative difference between the loops' sample times [-].
TS_TOLERANCE = 0.01
#: Shortest common span, as a fraction of the shortest record [-].
MIN_OVERLAP = 0.5
#: Fewest loops for grouping.
MIN_LOOPS = 2


def _stamped_pv(source, read_options: dict) -> tuple[np.ndarray, np.ndarray, float] | str:
    """(time [s], pv, ts [s]) of one loop file with its own stamps, or why not."""
    if source.loop_column is not None:
        return "a loop of a Parquet dataset"
    tags = load_source(source, **{**read_options, **(source.read_options or {})})
    tcol, pcol = tags.names.get("time"), tags.names.get("pv")
    if not tcol or not pcol:
        return "no time column"
    got = _read_stamped(source.path, tcol, [pcol])
    return got if isinstance(got, str) else (*got[pcol], float(tags.ts))


def _read_stamped(path: str, tcol: str, pcols: list[str]) -> dict | str:
    """Column -> (time [s], values) of ``pcols`` in one read of ``path``, or why not."""
    frame = read_table(Path(path), lambda header: [tcol, *dict.fromkeys(pcols)])
    missing = [c for c in (tcol, *pcols) if c not in frame.columns]
    if missing:
        return f"column {missing[0]!r} not found"
    t = time_seconds(frame[tcol], tcol, path)
    out = {}
    for c in pcols:
        values = frame[c].to_numpy(dtype=float, na_value=np.nan)
        ok = np.isfinite(t) & np.isfinite(values)
        if ok.sum() < 2:
            return f"{c}: no readable time stamps"
        out[c] = (t[ok], values[ok])
    return out


def _stamped_wide(sources: list, read_options: dict) -> dict | str:
    """Loop -> (time [s], pv, ts [s]) of the loops of one wide export, in one read.

    The columns are the grouping's (a loops manifest's names win); the sample time
    is the median step of the file's time stamps.
    """
    first = sources[0]
    names = {
        s.loop: {**s.plant.columns, **_named(read_options), **_named(s.read_options)}
        for s in sources
    }
    tcols = {n.get("time") for n in names.values()}
    tcol = tcols.pop() if len(tcols) == 1 else None
    if not tcol:
        return "no common time column"
    pcols = {loop: n["pv"] for loop, n in names.items()}
    got = _read_stamped(first.path, tcol, list(pcols.values()))
    if isinstance(got, str):
        return got
    out = {}
    for loop, c in pcols.items():
        t, values = got[c]
        steps = np.diff(t)
        steps = steps[steps > 0]
        if steps.size == 0:
            return f"{loop}: no increasing time stamps"
        out[loop] = (t, values, float(np.median(steps)))
    return out


def _stamped_long(sources: list, read_options: dict) -> dict | str:
    """Loop -> (time [s], pv, ts [s]) of the loops of one long export, in one read.

    Each pv tag keeps its own stamps; every loop is given the coarsest of the pv
    tags' median steps as its sample time, as the long reader puts a loop's tags
    on the coarsest of their steps (:mod:`stictiondiag.io.plant`), so the grid
    gives no tag detail it does not have.
    """
    tags = {
        s.loop: {**s.plant.columns, **_named(read_options), **_named(s.read_options)}["pv"]
        for s in sources
    }
    series = long_tag_series(sources[0].path, list(dict.fromkeys(tags.values())))
    steps = {}
    for loop, tag in tags.items():
        t = series[tag][0]
        d = np.diff(t)
        d = d[d > 0]
        if d.size == 0:
            return f"{loop}: no increasing time stamps"
        steps[loop] = float(np.median(d))
    ts = max(steps.values())
    return {loop: (*series[tag], ts) for loop, tag in tags.items()}


def _named(options: dict | None) -> dict:
    return {r: v for r, v in (options or {}).items() if r in ("pv", "time") and v}


def _gather(chosen: list, read_options: dict) -> dict | str:
    """Every chosen loop's stamped pv (one read per file), or why grouping is off."""
    stamped: dict = {}
    wide: dict[str, list] = {}
    for s in chosen:
        if s.plant is not None and s.plant.layout in ("wide", "long"):
            wide.setdefault(s.path, []).append(s)
    for path, group in wide.items():
        reader = _stamped_long if group[0].plant.layout == "long" else _stamped_wide
        got = _guarded(reader, group, read_options)
        if isinstance(got, str):
            return f"{path}: {got}"
        stamped.update(got)
    for s in chosen:
        if s.loop not in stamped:
            got = _guarded(_stamped_pv, s, read_options)
            if isinstance(got, str):
                return f"{s.loop}: {got}"
            stamped[s.loop] = got
    return stamped


def _guarded(fn, *args):
    try:
        return fn(*args)
    except StictionError as exc:
        return _first_line(exc)
    except Exception as exc:  # the loops' own results must survive a failed step
        return f"internal error: {type(exc).__name__}: {_first_line(exc)}"


def _aligned(stamped: dict) -> tuple[dict, float] | str:
    """The loops' pv on one grid [s], or why they are not aligned."""
    ts = np.array([v[2] for v in stamped.values()])
    dt = float(np.median(ts))
    if np.max(np.abs(ts / dt - 1.0)) > TS_TOLERANCE:
        return f"the loops' sample times differ ({ts.min():g} to {ts.max():g} s)"
    start = max(float(v[0][0]) for v in stamped.values())
    stop = min(float(v[0][-1]) for v in stamped.values())
    shortest = min(float(v[0][-1] - v[0][0]) for v in stamped.values())
    if stop - start < MIN_OVERLAP * shortest or stop <= start:
        return "the loops' records do not overlap in time (recorded at different times)"
    grid = start + dt * np.arange(int(math.floor((stop - start) / dt + 1e-9)) + 1)
    return {k: np.interp(grid, v[0], v[1]) for k, v in stamped.items()}, dt


def plantwide_step(sources, rows: list[dict], read_options: dict) -> dict:
    """Group the scan's aligned loops and mark their rows (see the module docstring).

    Parameters
    ----------
    sources : list of LoopSource
        The scan's loops.
    rows : list of dict
        Their table rows (updated in place: ``plant_group``, ``plant_role``,
        ``plant_cause``, and ``verdict``/``own_verdict`` of propagated loops).
    read_options : dict
        The scan's reading options.

    Returns
    -------
    dict
        ``{"status": "on", ...}`` with the :class:`PlantDiagnosis` as a dict and the
        object under ``"diagnosis"``, or ``{"status": "off", "reason": ...}``.
    """
    # Imported here: it brings numba (about 0.4 s), needed only once loops are analysed.
    from stictiondiag.stiction.plantwide import diagnose_plant

    analysed = {r["loop"] for r in rows if r.get("verdict") not in (None, "error")}
    chosen = [s for s in sources if s.loop in analysed]
    if len(chosen) < MIN_LOOPS:
        return _off(rows, f"fewer than {MIN_LOOPS} analysed loops")
    stamped = _gather(chosen, read_options)
    if isinstance(stamped, str):
        return _off(rows, f"{stamped}; grouping needs time-aligned loops")
    aligned = _aligned(stamped)
    if isinstance(aligned, str):
        return _off(rows, aligned)
    signals, dt = aligned
    probabilities = {r["loop"]: r.get("probability") for r in rows}
    try:
        diagnosis = diagnose_plant(signals, dt, probabilities)
    except StictionError as exc:
        return _off(rows, _first_line(exc))
    except Exception as exc:  # the loops' own results must survive a failed step
        return _off(rows, f"internal error: {type(exc).__name__}: {_first_line(exc)}")
    for r in rows:
        role = diagnosis.roles.get(r["loop"])
        if role is None:
            r.update(plant_group=None, plant_role=None, plant_cause=None)
            continue
        r.update(
            plant_group=",".join(str(g) for g in role.groups) or None,
            plant_role=role.role,
            plant_cause=role.cause,
        )
        if role.role == "propagated":
            r["own_verdict"] = r.get("verdict")
            r["verdict"] = "propagated"
            # The cause of its cycle is the source's, not what its own analysis said.
            r["own_cause"] = r.get("cause")
            r["cause"] = role.cause
    return {"status": "on", **diagnosis.to_dict(), "diagnosis": diagnosis}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _off(rows: list[dict], reason: str) -> dict:
    for r in rows:
        r.update(plant_group=None, plant_role=None, plant_cause=None)
    return {"status": "off", "reason": f"plant-wide grouping off: {reason}"}


def write_plantwide(plant: dict, out: Path) -> str:
    """Write the plant-wide result to ``out/plantwide.json`` (atomically); its path."""
    import json

    path = Path(out) / "plantwide.json"
    record = {k: v for k, v in plant.items() if k != "diagnosis"}
    write_atomic(path, json.dumps(record, indent=1))
    return str(path)
