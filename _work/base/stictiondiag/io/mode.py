"""The controller's mode (manual, automatic, cascade) in a plant export, and what it does
to the record analysed.

A loop's mode tag says when the controller closed the loop.  Desborough & Miller
(2002) put the *service factor*, the share of time in the normal (automatic or
cascade) mode, first among a loop audit's figures.  It also says which samples a
stiction diagnosis may use.  In manual the operator sets op and no controller acts
on pv.  So the closed-loop limit cycle by which stiction shows (Choudhury, Thornhill
& Shah 2005, Sections 4.2.2 and 5.3) cannot arise there, and the identified
controller would be wrong.

Names (:func:`is_mode_name`)
----------------------------
A column (or a long export's tag) is the mode when its name, split as the other tags
(:mod:`stictiondiag.io.columns`), ends in ``mode``, ``md`` or ``status``
(``FIC101.MODE``, Honeywell, Yokogawa CENTUM and OSIsoft PI alike; ``FIC101.MD``;
``FIC101_STATUS``), in DeltaV's ``mode.actual`` (``FIC101/MODE.ACTUAL``; the target mode
is what the operator asked for, not the mode the block was in) or in ``man/auto``
(``auto/man``); or when it is named ``mode``, ``controller mode`` or ``loop mode``.
``mode=<column>`` (CLI ``--mode``, manifest ``mode``) names it explicitly.

Values (:func:`mode_codes`)
---------------------------
Text, case-insensitive, in the forms of ISA-88 and the vendors:

* automatic (the loop closed): ``AUTO``, ``AUT`` (Yokogawa), ``AUTOMATIC``, ``CAS``,
  ``CASCADE``, ``BCAS`` (Honeywell back-up cascade), ``RCAS`` (remote cascade),
  ``RSP`` (remote set point);
* open loop: ``MAN``, ``MANUAL``, ``ROUT`` (remote output), ``IMAN`` (initialisation
  manual), ``LO`` (local override), ``OOS``/``O/S``/``OUT OF SERVICE``, ``TRK``/
  ``TRACK`` (output tracking), ``PRD`` (Yokogawa primary direct: the block does not
  act), ``INIT``; a compound display such as ``IMAN (CAS)`` is open loop whenever
  one of its words is;
* missing: an empty cell, and the system states an OSIsoft PI archive writes in
  place of a value (``Bad Input``, ``I/O Timeout``, ``Shutdown``, ``No Data`` ...).

A ``Status`` column of data-quality flags (``Good``, ``Uncertain`` ...) is noted as
such and not used.

Numbers have no meaning common to the control systems, so they are read only where
the code is a standard: DeltaV's ``MODE.ACTUAL`` (or ``vendor=deltav``) holds the
Foundation Fieldbus mode bit (1 ROUT, 2 RCAS, 4 CAS, 8 AUTO, 16 MAN, 32 LO, 64 IMAN,
128 OOS).  Any other number, or a word not listed, leaves the mode unused, with a
one-line warning that names it: no service factor, and the record read whole.

The record analysed (:func:`automatic_stretch`)
-----------------------------------------------
The mode is a step signal: a missing value holds the last one known (a compressed
archive's mode tag is held the same way, :mod:`stictiondiag.io.compression`).  The
service factor is the share of the record read (where the mode is known) in automatic
or cascade.  A record that leaves automatic is cut to its longest stretch in
automatic or cascade, the way a record with long gaps is cut to its longest complete
stretch (:mod:`stictiondiag.io.gaps`); a warning says so and where.  Fewer than
:data:`~stictiondiag.io.gaps.MIN_SAMPLES` samples in a row in automatic is a one-line
:class:`~stictiondiag.core.errors.DataError`: a stiction diagnosis needs the closed
loop.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.io.gaps import MIN_SAMPLES, longest_true_run

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "AUTOMATIC",
    "FIELDBUS_MODES",
    "OPEN_LOOP",
    "automatic_stretch",
    "mode_array",
    "mode_codes",
    "mode_labels",
]

#: Mode words that close the loop.
AUTOMATIC = frozenset({"AUTO", "AUT", "AUTOMATIC", "CAS", "CASC", "CASCADE", "BCAS", "RCAS", "RSP"})

#: Mode words of an open loop (the controller does not act on pv).
OPEN_LOOP = frozenset(
    {"MAN", "MANUAL", "ROUT", "IMAN", "LO", "OOS", "TRK", "TRACK", "TRACKING", "PRD", "INIT"}
)

# Phrases read whole (letters and digits only, upper case).
_PHRASES = {
    "OS": 0.0,  # O/S
    "OUTOFSERVICE": 0.0,
    "REMOTEOUTPUT": 0.0,
    "LOCALOVERRIDE": 0.0,
    "REMOTECASCADE": 1.0,
}

# System states a PI archive writes in place of a value: a missing mode.
_SYSTEM_STATES = frozenset(
    {
        "BAD",
        "BADINPUT",
        "BADDATA",
        "BADQUALITY",
        "IOTIMEOUT",
        "NODATA",
        "NORESULT",
        "NOSAMPLE",
        "SHUTDOWN",
        "COMMFAIL",
        "PTCREATED",
        "CALCFAILED",
        "SCANOFF",
        "SCANTIMEOUT",
        "CONFIGURE",
        "NOTCONNECTED",
        "INTFSHUT",
        "ARCOFFLINE",
        "OVERRANGE",
        "UNDERRANGE",
    }
)

# Data-quality words of a "Status" column written beside each value: not modes.
_QUALITY = frozenset({"GOOD", "UNCERTAIN", "QUESTIONABLE", "SUBSTITUTED", "ANNOTATED"})

#: Foundation Fieldbus actual-mode bits (DeltaV ``MODE.ACTUAL``) -> 1.0 closed, 0.0 open.
FIELDBUS_MODES = {1: 0.0, 2: 1.0, 4: 1.0, 8: 1.0, 16: 0.0, 32: 0.0, 64: 0.0, 128: 0.0}

_WORDS = re.compile(r"[^A-Z0-9]+")


def _word_code(text: str) -> float | None:
    """1.0 (automatic), 0.0 (open loop), NaN (missing) or None (not a mode) for one value."""
    upper = text.strip().upper()
    compact = _WORDS.sub("", upper)
    if not compact or compact in _SYSTEM_STATES:
        return float("nan")
    if compact in _PHRASES:
        return _PHRASES[compact]
    words = [w for w in _WORDS.split(upper) if w]
    if any(w in OPEN_LOOP for w in words):
        return 0.0
    if words and all(w in AUTOMATIC for w in words):
        return 1.0
    return None


def _fieldbus_name(column: str) -> bool:
    words = [w for w in re.split(r"[\s._\-:/\\]+", column.lower()) if w]
    return len(words) >= 2 and words[-2] == "mode" and words[-1] in ("actual", "act")


def mode_codes(
    series: pd.Series, column: str, source: str, notes: list[str], vendor: str | None = None
) -> np.ndarray | None:
    """A mode column as codes: 1.0 automatic or cascade, 0.0 open loop, NaN missing.

    None when the column cannot be read as modes (numbers without a standard meaning,
    or words that are not modes); the reason is one line in ``notes``.
    """
    import pandas as pd

    where = f" in {source}" if source not in ("", "<memory>") else ""
    if pd.api.types.is_bool_dtype(series) or pd.api.types.is_numeric_dtype(series):
        numbers = pd.to_numeric(series, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        if not np.isfinite(numbers).any():
            return np.full(numbers.size, np.nan)  # an empty column: no mode known
        if vendor == "deltav" or _fieldbus_name(column):
            codes = np.full(numbers.size, np.nan)
            bad = []
            for value in np.unique(numbers[np.isfinite(numbers)]):
                code = FIELDBUS_MODES.get(int(value)) if float(value).is_integer() else None
                if code is None:
                    bad.append(f"{value:g}")
                codes[numbers == value] = np.nan if code is None else code
            if not bad:
                return codes
            shown = ", ".join(bad[:3])
            notes.append(
                f"mode column {column!r}{where} holds {shown}, not a Fieldbus mode bit "
                "(1 ROUT, 2 RCAS, 4 CAS, 8 AUTO, 16 MAN, 32 LO, 64 IMAN, 128 OOS): mode not "
                "used, no service factor"
            )
            return None
        present = numbers[np.isfinite(numbers)]
        shown = ", ".join(f"{v:g}" for v in np.unique(present)[:3]) or "nothing"
        notes.append(
            f"mode column {column!r}{where} holds numbers ({shown}), whose meaning differs "
            "between control systems: mode not used, no service factor; export the mode as "
            "text (MAN, AUTO, CAS), or DeltaV's MODE.ACTUAL (Fieldbus bits, --vendor deltav)"
        )
        return None
    codes_of, text = pd.factorize(series.astype("string").fillna(""))
    values = np.full(len(text) + 1, np.nan)  # the last slot: factorize's -1 (missing)
    unknown: list[str] = []
    quality = True
    for i, word in enumerate(text):
        code = _word_code(str(word))
        if code is None:
            quality &= _WORDS.sub("", str(word).upper()) in _QUALITY
            count = int(np.sum(codes_of == i))
            unknown.append(f"{str(word)[:20]!r} ({count} row{'' if count == 1 else 's'})")
        else:
            values[i] = code
    if unknown and quality:
        notes.append(
            f"column {column!r}{where} holds data quality flags ({', '.join(unknown[:2])}), "
            "not the controller mode: not used as the mode, no service factor"
        )
        return None
    if unknown:
        notes.append(
            f"mode column {column!r}{where} holds {', '.join(unknown[:3])}, not a controller "
            "mode (MAN, AUTO, CAS, IMAN, ROUT, OOS ...): mode not used, no service factor; "
            "name the mode column with mode=<column> (CLI --mode)"
        )
        return None
    return values[codes_of]


def mode_labels(codes: np.ndarray) -> np.ndarray:
    """Codes back to words (``AUTO``, ``MAN``, missing None), read again by :func:`mode_codes`."""
    out = np.full(codes.size, None, dtype=object)
    out[codes == 1.0] = "AUTO"
    out[codes == 0.0] = "MAN"
    return out


def automatic_stretch(
    codes: np.ndarray, label: str, where: str, notes: list[str]
) -> tuple[int, int, float | None]:
    """(start, stop, service factor [% of time]) of a record with mode ``codes``.

    ``[start, stop)`` is the longest stretch in automatic or cascade (the whole record
    when it never leaves automatic); the service factor is over the samples whose
    mode is known, None when none is.  A cut is noted.

    Raises
    ------
    DataError
        Fewer than :data:`~stictiondiag.io.gaps.MIN_SAMPLES` samples in a row in
        automatic or cascade.
    """
    import pandas as pd

    n = codes.size
    held = pd.Series(codes).ffill().to_numpy(dtype=float)  # a step signal: held
    known = np.isfinite(held)
    if not known.any():
        notes.append(f"mode {label!r}{where} has no readable value: mode not used")
        return 0, n, None
    closed = held == 1.0
    factor = 100.0 * float(np.mean(closed[known]))
    if closed.all():
        return 0, n, factor
    start, stop = longest_true_run(closed)
    if stop - start < MIN_SAMPLES:
        longest = f", at most {stop - start} samples in a row" if stop > start else ""
        raise DataError(
            f"the controller was in automatic or cascade for {factor:.3g} % of the record"
            f"{where} (mode {label!r}{longest}; need {MIN_SAMPLES}): a stiction diagnosis "
            "needs the closed loop; export a period with the loop in automatic"
        )
    unknown = int(n - known.sum())
    first = f"; mode unknown for the first {unknown} samples" if unknown else ""
    notes.append(
        f"mode {label!r}: in automatic or cascade {factor:.3g} % of the record (service "
        f"factor){first}; samples in manual or another open-loop mode say nothing of the "
        f"closed loop: analysed the longest automatic stretch, samples {start} to "
        f"{stop - 1} ({stop - start} of {n})"
    )
    return start, stop, factor


def mode_array(mode: Sequence | np.ndarray, n: int) -> np.ndarray:
    """A mode per sample as codes (1.0 automatic, 0.0 open loop, NaN unknown): booleans
    or numbers (nonzero = automatic or cascade), or words (:func:`mode_codes`)."""
    import pandas as pd

    values = np.asarray(mode)
    if values.ndim != 1 or values.size != n:
        raise DataError(f"mode has {values.size} values for {n} samples: pass one per sample")
    if values.dtype.kind in "biuf":
        return np.where(np.isnan(values.astype(float)), np.nan, values.astype(float) != 0.0)
    notes: list[str] = []
    codes = mode_codes(pd.Series(values, dtype=object), "mode", "<memory>", notes)
    if codes is None:
        raise DataError(notes[0])
    return codes
