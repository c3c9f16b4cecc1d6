"""Compressed historian archives ("recorded values") and their reconstruction on one grid.

A process historian does not store every scan.  Two compressions are common:

* **exception (deadband) reporting**: a value is archived only when it has moved
  more than a deadband from the last archived one; between archived values the
  historian holds the last one (a *step* reconstruction).  A flat set point is two
  rows; a stuck valve's position is archived only when it slips.
* **swinging-door compression** (Bristol 1990, the OSIsoft PI archive): a value is
  archived where a straight line from the last archived value no longer passes
  within a deviation of every scan in between; the historian interpolates linearly
  between archived values.

An export of the archived rows ("recorded values", as against "interpolated
values") therefore has irregular time stamps per tag, on the scan grid.  Reading
it on the grid of the coarsest or even the median step throws away the detail the
historian kept (:func:`reconstruct`), and the gap rule of uniformly sampled files
(a hole longer than ``MAX_GAP_SAMPLES`` steps is missing data) would cut a flat
record into pieces.

:func:`reconstruct` puts the tags of one loop on one grid:

* the grid step is the finest step of the loop's fastest tag (the scan rate the
  archive was written at): the median step of a regularly sampled tag, the scan
  step whose multiples the archived stamps are for a compressed one (:func:`tag_step`);
* a tag is *compressed* when its steps are irregular and many span more than two
  grid steps (:func:`is_compressed`); it is rebuilt the way its historian reads it,
  held (exception) or linear (swinging door); which one is told from the archived
  values themselves (:func:`archive_kind`): a deadband leaves no archived change
  smaller than a floor near the deadband, while a swinging door archives the
  corners of a piecewise-linear path, with changes of every size;
* the controller's output (op) of an exception archive is rebuilt *banded*
  (:func:`banded`): the straight line between archived values, kept within the
  deadband of the last one.  Under integral action op moves continuously, and the
  archive guarantees only that it stayed within the deadband until the next archived
  value.  Held, op is a staircase that stops at every step, and a valve model fed
  with it sticks at every step: the bundled level loop (S 5 %, J 2.5 %) archived at
  0.1 % of span gave S 4.10 % held and 4.96 % banded (``python
  scripts/compressed_op.py``).  The valve's position (mv), the set point and pv
  stay held: a valve that sticks is still between archived values, and a set point
  steps.  ``compression`` (``"hold"``, ``"linear"`` or ``"band"``) overrides the
  reading for every tag;
* a regularly sampled tag is interpolated linearly with the gap rule of
  :func:`stictiondiag.io.timebase.onto_grid` on its own step.

:func:`exception_compress` and :func:`swinging_door` write such archives from
uniformly sampled data (tests and the plant-export script use them).
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.io.timebase import check_grid, onto_grid

__all__ = [
    "COMPRESSIONS",
    "archive_deadbands",
    "archive_kind",
    "banded",
    "held_deadband",
    "from_archive",
    "sparse_roles",
    "exception_compress",
    "is_compressed",
    "reconstruct",
    "swinging_door",
    "tag_step",
]

#: Reconstructions of a compressed tag: held between archived values, linear, or
#: banded (linear, kept within the exception deadband: :func:`banded`).
COMPRESSIONS = ("hold", "linear", "band")

#: Roles whose exception archive is rebuilt banded rather than held (module docstring).
BANDED_ROLES = frozenset({"op"})

# Relative spread of steps still read as one uniform sampling (clock jitter).
_UNIFORM = 0.01

# A tag is compressed when at least this share of its steps spans more than two
# grid steps (a regular tag at a slower rate has all its steps alike).
_LONG_STEP_SHARE = 0.01

# Fewer archived changes than this are a step signal (a set point): held.
_FEW_CHANGES = 8

# Exception reporting: the smallest archived change is at least this share of the
# lower quartile of changes (every change passed the deadband); a swinging door
# archives corners with changes of all sizes down to zero.  Set on the bundled
# simulated samples (archive_kind's docstring), not on plant labels.
_DEADBAND_FLOOR = 0.2


def tag_step(t: np.ndarray) -> float:
    """The scan step of one tag [s]: its median step when regular; for an archive, the
    largest of the smallest step divided by 1 to 10 of which nine in ten steps are
    whole multiples (archived stamps sit on the scan grid), else the 5 % quantile of
    its steps.

    ``t`` are the tag's increasing time stamps [s] (two or more).
    """
    steps = np.diff(t)
    steps = steps[steps > 0]
    if steps.size == 0:
        return math.inf
    median = float(np.median(steps))
    if np.all(np.abs(steps - median) <= _UNIFORM * median):
        return median
    smallest = float(steps.min())
    for k in range(1, 11):
        ratio = steps / (smallest / k)
        if np.mean(np.abs(ratio - np.round(ratio)) <= 0.01 * ratio) >= 0.9:
            return smallest / k
    return float(np.quantile(steps, 0.05))


def is_compressed(t: np.ndarray, grid_step: float) -> bool:
    """Whether a tag's stamps are an archive's (irregular, often longer than 2 grid steps)."""
    if t.size <= 2:
        return True
    steps = np.diff(t)
    median = float(np.median(steps))
    if np.all(np.abs(steps - median) <= _UNIFORM * median):
        return False
    # A jittery clock with an outage has a long step or two; an archive skips scans often.
    return float(np.mean(steps > 2.0 * grid_step)) >= _LONG_STEP_SHARE


def archive_kind(v: np.ndarray) -> str:
    """``"hold"`` (exception/deadband archive) or ``"linear"`` (swinging door), from the values.

    A deadband archive stores a value only after a change larger than the deadband:
    it holds no zero change, and its smallest change is near the bulk of the small
    ones (at least :data:`_DEADBAND_FLOOR` of the lower quartile).  A swinging door
    stores the corners of a piecewise-linear path, with changes of every size, zero
    included (the two ends of a flat stretch).  The first and last changes are left
    out (an export's window cuts there).  Few archived changes (a set point) are held.
    On the bundled samples compressed at 1 to 30 % of each signal's standard deviation
    the rule reads 68 of 68 deadband archives and 59 of 68 swinging-door archives
    right; ``compression`` overrides it.
    """
    changes = np.abs(np.diff(np.asarray(v, dtype=float)))[1:-1]
    changes = changes[np.isfinite(changes)]
    if changes.size < _FEW_CHANGES:
        return "hold"
    smallest, quartile = float(changes.min()), float(np.quantile(changes, 0.25))
    return "hold" if smallest > 0 and smallest >= _DEADBAND_FLOOR * quartile else "linear"


def held_deadband(v: np.ndarray) -> float:
    """The deadband an exception archive was written with, from its archived values
    [units of v]; 0 when there are too few changes to tell (a set point).

    Every archived change passed the deadband, so the smallest change (the first and
    last left out, as in :func:`archive_kind`) is just above it: with a few hundred
    archived changes of a moving signal, within a scan's movement of it.
    """
    changes = np.abs(np.diff(np.asarray(v, dtype=float)))[1:-1]
    changes = changes[np.isfinite(changes) & (changes > 0)]
    return float(changes.min()) if changes.size >= _FEW_CHANGES else 0.0


def _held(t: np.ndarray, v: np.ndarray, grid: np.ndarray, tol: float) -> np.ndarray:
    index = np.searchsorted(t, grid + tol, side="right") - 1
    return v[np.clip(index, 0, t.size - 1)]


def banded(t: np.ndarray, v: np.ndarray, grid: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """An exception archive on ``grid``: the straight line between archived values,
    kept within the deadband (:func:`held_deadband`) of the last archived one.

    Between two archived values the signal stayed within the deadband of the first
    (else it would have been archived sooner) and reached the second at its stamp.
    A slow drift, archived each time it has moved one deadband, is rebuilt as the
    ramp it was; a jump after a long still stretch (a slip, a set-point step) stays
    within one deadband of held until the jump.  Without a measurable deadband (few
    archived changes) this is :func:`_held`.  Cost linear in the grid's length.
    """
    deadband = held_deadband(v)
    k = np.clip(np.searchsorted(t, grid + tol, side="right") - 1, 0, t.size - 1)
    if deadband <= 0:
        return v[k]
    nxt = np.minimum(k + 1, t.size - 1)
    span = t[nxt] - t[k]
    frac = np.divide(grid - t[k], span, out=np.zeros(grid.size), where=span > 0)
    line = v[k] + (v[nxt] - v[k]) * np.clip(frac, 0.0, 1.0)
    return np.clip(line, v[k] - deadband, v[k] + deadband)


def _kinds(
    series: dict[str, tuple[np.ndarray, np.ndarray]], label: str, compression: str | None
) -> tuple[dict, dict[str, float], float, dict[str, str | None]]:
    """The signal tags, their scan steps, the grid step and each tag's reconstruction
    (``"hold"``, ``"linear"``, or None for a regularly sampled tag)."""
    # The controller's mode is a step signal that changes rarely and off the scan
    # grid: it is held and takes no part in the grid or the record's span.
    signals = {r: tv for r, tv in series.items() if r != "mode"}
    steps = {r: tag_step(t) for r, (t, _) in signals.items() if t.size >= 2}
    step = min(steps.values()) if steps else math.inf
    if not (math.isfinite(step) and step > 0):
        raise DataError(f"{label}: the tags have no usable time step")
    kinds: dict[str, str | None] = {}
    for role, (t, v) in signals.items():
        if is_compressed(t, step):
            kind = compression or archive_kind(v)
            if compression is None and kind == "hold" and role in BANDED_ROLES:
                kind = "band"
            kinds[role] = kind
        else:
            kinds[role] = None
    return signals, steps, step, kinds


def archive_deadbands(
    series: dict[str, tuple[np.ndarray, np.ndarray]],
    label: str,
    compression: str | None = None,
) -> dict[str, float]:
    """Role -> the deadband of each tag :func:`reconstruct` holds (exception archive)
    [units of the tag] (:func:`held_deadband`; tags without one are left out).

    A held archive is a staircase: a value that moves by less than its deadband is
    not recorded, so a valve's stick and slip smaller than it cannot be told from the
    archive's own steps (:func:`stictiondiag.stiction.resolution.resolution`).
    """
    _, _, _, kinds = _kinds(series, label, compression)
    found = {r: held_deadband(series[r][1]) for r, k in kinds.items() if k in ("hold", "band")}
    return {r: d for r, d in found.items() if d > 0}


def reconstruct(
    series: dict[str, tuple[np.ndarray, np.ndarray]],
    label: str,
    compression: str | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray, float, str | None]:
    """The tags of one loop on one uniform grid (module docstring).

    Parameters
    ----------
    series : dict
        Role -> (time stamps [s], values), each sorted by time, NaN values dropped.
    label : str
        The loop, for messages.
    compression : {"hold", "linear", "band"}, optional
        How every compressed tag is rebuilt; default: told per tag from its values
        (an exception archive of op banded).

    Returns
    -------
    (arrays, grid, step, note)
        Role -> values on the grid; the grid [s]; its step [s]; a note saying which
        tags were compressed and how they were rebuilt (None when none was).

    Raises
    ------
    DataError
        A pv or op with fewer than two archived values, tags that do not overlap, or a
        grid beyond :data:`~stictiondiag.io.timebase.MAX_GRID_SAMPLES`.
    UsageError
        An unknown ``compression``.
    """
    if compression is not None and compression not in COMPRESSIONS:
        raise UsageError(
            f"compression must be one of {', '.join(COMPRESSIONS)}, not {compression!r}"
        )
    for role, (t, _) in series.items():
        if t.size < 2 and role in ("pv", "op"):
            raise DataError(f"{label}: {role} has {t.size} archived values: export more of it")
    signals, steps, step, kinds = _kinds(series, label, compression)
    # A step signal archived by exception (a set point: too few changes to read a
    # deadband from, held_deadband 0) may have no row for hours, and the window of a
    # recorded-values export can open long after its last change: it does not bound
    # the record's start, and before its first archived value it is taken at that
    # value (said in the note).
    steppy = {r for r, (_, v) in signals.items() if kinds[r] == "hold" and held_deadband(v) == 0}
    firsts = [t[0] for r, (t, _) in signals.items() if r not in steppy]
    start = max(firsts) if firsts else max(t[0] for t, _ in signals.values())
    # A held tag keeps its last archived value until the record ends: the export's
    # end is where its other tags stop.
    ends = [t[-1] for r, (t, _) in signals.items() if kinds[r] != "hold"]
    stop = min(ends) if ends else max(t[-1] for t, _ in signals.values())
    if not stop > start:
        raise DataError(f"{label}: the tags of the loop do not overlap in time")
    n_grid = int(math.floor((stop - start) / step + 1e-9)) + 1
    check_grid(n_grid, step, label)
    grid = start + step * np.arange(n_grid)
    tol = 1e-6 * (1.0 + step)
    out: dict[str, np.ndarray] = {}
    if "mode" in series:
        t, v = series["mode"]
        # Before its first archived value the mode is not known.
        out["mode"] = np.where(grid + tol >= t[0], _held(t, v, grid, tol), np.nan)
    for role, (t, v) in signals.items():
        kind = kinds[role]
        if kind == "hold":
            out[role] = _held(t, v, grid, tol)
        elif kind == "band":
            out[role] = banded(t, v, grid, tol)
        elif kind == "linear":
            out[role] = np.interp(grid, t, v) if t.size > 1 else np.full(grid.size, v[0])
        else:
            own = steps.get(role, step)
            out[role] = onto_grid({role: v}, t, grid, own)[role]
    compressed = {r: k for r, k in kinds.items() if k is not None}
    if not compressed:
        return out, grid, step, None
    told = "as given" if compression else "told from the archived values"

    def how(role: str, kind: str) -> str:
        if kind == "linear":
            return "linear"
        deadband = held_deadband(series[role][1])
        if kind == "band" and deadband > 0:
            return f"linear within its deadband {deadband:.3g}"
        return f"held (deadband {deadband:.3g})" if deadband > 0 else "held"

    rebuilt = ", ".join(
        f"{r} {series[r][0].size} values {how(r, k)}" for r, k in compressed.items()
    )
    late = [
        f"{r} taken at its first archived value for the {signals[r][0][0] - start:g} s before it"
        for r in sorted(steppy)
        if signals[r][0][0] > start + tol
    ]
    if late:
        rebuilt += "; " + ", ".join(late)
    note = (
        f"compressed archive (recorded values): rebuilt on a {step:g} s grid of {grid.size} "
        f"points (the fastest tag's scan step): {rebuilt} ({told}; override with "
        "compression=hold|linear|band, CLI --compression)"
    )
    return out, grid, step, note


# --------------------------------------------------------------------------- writers


def exception_compress(v: np.ndarray, deadband: float, previous: bool = False) -> np.ndarray:
    """Indices an exception (deadband) historian archives: the first and last sample and
    every sample that moved more than ``deadband`` from the last archived value; with
    ``previous`` also the sample before each of them (as the OSIsoft PI interface sends
    the previous value with an exception, so that linear interpolation holds flats)."""
    values = np.asarray(v, dtype=float)
    kept = [0]
    last = values[0]
    for i in range(1, values.size - 1):
        if abs(values[i] - last) > deadband:
            if previous and kept[-1] != i - 1:
                kept.append(i - 1)
            kept.append(i)
            last = values[i]
    if values.size > 1:
        kept.append(values.size - 1)
    return np.asarray(kept, dtype=int)


def swinging_door(t: np.ndarray, v: np.ndarray, deviation: float) -> np.ndarray:
    """Indices a swinging-door archive keeps (Bristol 1990): corners of a piecewise-linear
    path within ``deviation`` of every sample, plus the first and last sample."""
    times = np.asarray(t, dtype=float)
    values = np.asarray(v, dtype=float)
    n = values.size
    if n <= 2:
        return np.arange(n)
    kept = [0]
    anchor = 0
    upper, lower = math.inf, -math.inf
    for i in range(1, n):
        dt = times[i] - times[anchor]
        upper = min(upper, (values[i] + deviation - values[anchor]) / dt)
        lower = max(lower, (values[i] - deviation - values[anchor]) / dt)
        if lower > upper:
            anchor = i - 1
            kept.append(anchor)
            dt = times[i] - times[anchor]
            upper = (values[i] + deviation - values[anchor]) / dt
            lower = (values[i] - deviation - values[anchor]) / dt
    if kept[-1] != n - 1:
        kept.append(n - 1)
    return np.asarray(kept, dtype=int)


# --------------------------------------------------------------------------- wide files

#: A column of a timestamped file is an archive's when at least this share of its rows
#: with a time stamp is empty ...
_SPARSE_SHARE = 0.3
#: ... and its values stand mostly alone (present runs per present value): a record
#: with an outage has one long hole, a wide "recorded values" export a hole between
#: almost every pair of archived values.
_SCATTER = 0.2


def sparse_roles(arrays: dict[str, np.ndarray], seconds: np.ndarray) -> list[str]:
    """Roles whose column is a compressed archive in a wide file (empty between archived rows)."""
    stamped = np.isfinite(seconds)
    found = []
    for role, values in arrays.items():
        present = np.isfinite(values) & stamped
        n_present = int(present.sum())
        if n_present < 1 or n_present > (1.0 - _SPARSE_SHARE) * int(stamped.sum()):
            continue
        runs = int(np.count_nonzero(np.diff(present.astype(np.int8)) == 1) + present[0])
        if runs >= 2 and runs >= _SCATTER * n_present:
            found.append(role)
    return found


def from_archive(
    arrays: dict[str, np.ndarray],
    seconds: np.ndarray,
    label: str,
    compression: str | None,
    notes: list[str],
) -> tuple[dict[str, np.ndarray], float, float, dict[str, float]]:
    """A wide file's columns, each read as its own archive, on one grid (:func:`reconstruct`).

    Returns (role -> values on the grid, grid step [s], the grid's first time [s],
    role -> deadband of a held tag [units of the tag], :func:`archive_deadbands`); the
    reconstruction is noted.
    """
    series = {}
    for role, values in arrays.items():
        keep = np.isfinite(values) & np.isfinite(seconds)
        t, v = seconds[keep], values[keep]
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
        unique = np.concatenate(([True], np.diff(t) > 0)) if t.size else np.ones(0, bool)
        t, v = t[unique], v[unique]
        if t.size == 0:
            if role in ("pv", "op"):
                raise DataError(f"{label}: {role} has no values")
            continue
        series[role] = (t, v)
    out, grid, step, note = reconstruct(series, label, compression)
    if note is not None:
        notes.append(note)
    return out, step, float(grid[0]), archive_deadbands(series, label, compression)
