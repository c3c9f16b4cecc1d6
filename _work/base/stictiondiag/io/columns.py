"""Which column of an export is pv, op, mv, sp and time (rules in :mod:`stictiondiag.io.tags`).

Also :func:`numeric_column`, a column as numbers with sparse bad entries as gaps.
A column is never chosen silently over an equal claimant: two columns with the same
name (``pv`` twice; the parser would rename one ``pv.1``) are an error naming both,
and a column named exactly like its role that wins over other candidates is noted.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.io.readers import duplicate_names

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "MAX_MAGNITUDE",
    "ROLES",
    "VENDORS",
    "check_magnitude",
    "column_list",
    "is_time_name",
    "match_columns",
    "numeric_column",
    "roles_of",
]

#: Signal roles in the paper's notation (Section 3).
ROLES = ("pv", "op", "mv", "sp")

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
_SEPARATORS = re.compile(r"[\s._\-:/\\]+")

#: Control-system tag conventions (``vendor``).  Honeywell ``.PV/.OP/.SP``, Emerson
#: DeltaV ``/PV.CV``, ``/OUT.CV``, ``/SP.CV`` (``.CV`` is the parameter's current value),
#: OSIsoft PI tag-per-column exports (``\\server\TAG.PV``) and the generic names are
#: read by the suffix rules alike; they differ only in ``.MV``: Yokogawa CENTUM's
#: ``.PV/.MV/.SV`` name the controller output MV, everywhere else (and in the paper)
#: MV is the valve position.
VENDORS = ("yokogawa", "honeywell", "deltav", "pi", "generic")

# Field names a tag's parameter may carry after its role (DeltaV's current value).
_FIELDS = {"cv"}


def _refuse_duplicates(frame: pd.DataFrame, overrides: Mapping[str, str | None], file: str) -> None:
    """Two columns with one name that could serve a role are an error naming both."""
    written = [str(n) for n in frame.attrs.get("written_names", frame.columns)]
    named = {str(n).strip().lower() for n in overrides.values() if n is not None}
    for name, where in duplicate_names(written).items():
        # A repeated mode-like name (a "Status" quality column after every tag) is
        # not refused: the mode is optional, and such a column is only noted.
        if name in ROLES or roles_of(name) or is_time_name(name) or name in named:
            shown = written[where[0] - 1]
            numbers = " and ".join(str(i) for i in where)
            raise DataError(
                f"columns {numbers} of {file} are both named {shown!r}: which one is meant "
                "is not clear; rename one of them in the export"
            )


def _tokens(name: str) -> list[str]:
    cleaned = _BRACKETS.sub(" ", name.lower())
    tokens = [token for token in _SEPARATORS.split(cleaned) if token]
    if len(tokens) >= 3 and tokens[-1] in _FIELDS:
        tokens = tokens[:-1]  # FIC101/PV.CV -> fic101, pv
    return tokens


def is_mv_suffix(name: str) -> bool:
    """Whether a tag ends in ``MV`` (the Yokogawa output, elsewhere the valve position)."""
    tokens = _tokens(name)
    return len(tokens) >= 2 and tokens[-1] == "mv"


def check_vendor(vendor: str | None) -> None:
    if vendor is not None and vendor not in VENDORS:
        raise UsageError(f"vendor must be one of {', '.join(VENDORS)}, not {vendor!r}")


def yokogawa_note(column: str, given: bool) -> str:
    """The note that says which reading of an ``.MV`` tag was taken."""
    why = "vendor yokogawa" if given else "no op tag beside it: the Yokogawa CENTUM convention"
    return (
        f"op: {column!r} read as the controller output ({why}); if MV is the valve "
        "position, give vendor=generic (CLI --vendor generic) and name op"
    )


#: Last words of a mode tag, first preferred (:func:`mode_rank`); DeltaV's actual mode
#: ``MODE.ACTUAL``, ISA ``.MODE``, ``.MD``, ``MAN/AUTO``, ``STATUS``.
_MODE_ENDINGS = (("mode", "actual"), ("mode", "act"), ("mode",), ("md",), ("man", "auto"),
                 ("auto", "man"), ("status",))  # fmt: skip
_MODE_NAMES = {"controllermode", "loopmode", "pidmode"}


def mode_rank(name: str) -> int | None:
    """Rank of a column name as the controller's mode tag (0 best), None when it is not
    one (rules in :mod:`stictiondiag.io.mode`)."""
    tokens = _tokens(name)
    if not tokens or is_time_name(name):
        return None
    if "".join(tokens) in _MODE_NAMES:
        return 2
    for rank, ending in enumerate(_MODE_ENDINGS):
        if tuple(tokens[-len(ending) :]) == ending:
            return rank
    return None


def mode_prefix(name: str) -> str:
    """The loop prefix of a mode tag (``FIC101/MODE.ACTUAL`` -> ``FIC101``), or ``""``."""
    tokens = _tokens(name)
    rank = mode_rank(name)
    if rank is None or not tokens or "".join(tokens) in _MODE_NAMES:
        return ""
    cut = len(_MODE_ENDINGS[rank])
    words = re.split(r"([\s._\-:/\\]+)", str(name).strip())
    kept = [w for w in words if w]
    # Drop the ending's words and the separators before them.
    while cut and kept:
        word = kept.pop()
        if not _SEPARATORS.fullmatch(word):
            cut -= 1
    while kept and _SEPARATORS.fullmatch(kept[-1]):
        kept.pop()
    return "".join(kept)


def is_time_name(name: str) -> bool:
    tokens = _tokens(name)
    return bool(tokens) and (tokens[0] in _TIME_FIRST_TOKENS or tokens == ["t"])


def roles_of(name: str, vendor: str | None = None) -> set[str]:
    """Roles a column name is a candidate for (module docstring rules); with vendor
    ``yokogawa`` an ``.MV`` tag is op."""
    tokens = _tokens(name)
    if not tokens:
        return set()
    if vendor == "yokogawa" and len(tokens) >= 2 and tokens[-1] == "mv":
        return {"op"}
    joined = "".join(tokens)
    roles = {
        role for role in ROLES if tokens[-1] in _ROLE_SUFFIXES[role] or joined in _ROLE_NAMES[role]
    }
    if _POSITION_INSTRUMENT.match(tokens[0]):
        # ZT/ZI instruments measure valve position whatever their suffix says.
        return {"mv"}
    return roles


def column_list(frame: pd.DataFrame, limit: int = 12) -> str:
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
        f"{role} column {name!r} not found in {file} (columns: {column_list(frame)}): "
        f"check the spelling of {role}=<column>"
    )


def match_columns(
    frame: pd.DataFrame,
    overrides: Mapping[str, str | None],
    file: str,
    notes: list[str] | None = None,
    vendor: str | None = None,
) -> dict[str, str]:
    """Role -> column name, from explicit names first, then the matching rules.

    ``vendor`` as :data:`VENDORS`: with ``yokogawa`` ``.MV`` is op; without a vendor,
    an ``.MV`` tag and no op is read as op (noted); other vendors keep MV as mv.
    """
    import pandas as pd

    check_vendor(vendor)
    _refuse_duplicates(frame, overrides, file)
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
        candidates = exact or [column for column in free if role in roles_of(column, vendor)]
        if role == "op" and not candidates and vendor is None:
            candidates = [column for column in free if is_mv_suffix(column)][:2]
            if len(candidates) == 1 and notes is not None:
                notes.append(yokogawa_note(candidates[0], given=False))
        elif role == "op" and vendor == "yokogawa" and len(candidates) == 1 and notes is not None:
            if is_mv_suffix(candidates[0]):
                notes.append(yokogawa_note(candidates[0], given=True))
        if len(exact) == 1 and notes is not None:
            others = [c for c in free if c != exact[0] and role in roles_of(c)]
            if others:
                listed = ", ".join(repr(c) for c in others)
                notes.append(
                    f"{role}: used column {exact[0]!r}; {listed} also read as {role} "
                    f"(name the one to use with {role}=<column>, CLI --{role} <column>)"
                )
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
                (column for column in free if "mv" in roles_of(column)), None
            )
            if role == "op" and mv_like is not None:
                hint = f"; if {mv_like!r} is the controller output, pass op={mv_like!r}"
            raise DataError(
                f"no {role} column found in {file} (columns: {column_list(frame)}): "
                f"name it with {role}=<column> (CLI --{role} <column>){hint}"
            )
    if "mode" not in chosen:
        _match_mode(free, chosen, file, notes)
    if "time" not in chosen:
        by_name = [column for column in free if is_time_name(column)]
        # The types from one pass over the header: frame[column] for every column
        # would copy the frame's attrs (its header names) each time, quadratic in
        # the number of columns.
        datetime = {
            str(column)
            for column, dtype in zip(frame.columns, frame.dtypes, strict=True)
            if pd.api.types.is_datetime64_any_dtype(dtype)
        }
        named = set(by_name)
        by_type = [column for column in free if column not in named and column in datetime]
        candidates = by_name or by_type
        if len(candidates) > 1:
            typed = [column for column in candidates if column in datetime]
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


def _match_mode(
    free: list[str], chosen: dict[str, str], file: str, notes: list[str] | None
) -> None:
    """The controller's mode column among ``free``, by :func:`mode_rank`; two of one rank
    are noted and neither is used (the mode is optional, the loop is still read)."""
    ranked = sorted((rank, column) for column in free if (rank := mode_rank(column)) is not None)
    if not ranked:
        return
    best = [column for rank, column in ranked if rank == ranked[0][0]]
    if len(best) == 1:
        chosen["mode"] = best[0]
        free.remove(best[0])
    elif notes is not None:
        listed = ", ".join(repr(column) for column in best)
        notes.append(
            f"{len(best)} columns in {file} look like the controller mode ({listed}): none "
            "used, no service factor; name one with mode=<column> (CLI --mode <column>)"
        )


def numeric_column(
    series: pd.Series, role: str, column: str, file: str, notes: list[str]
) -> np.ndarray:
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


#: Largest magnitude of a signal value [signal units]: fourth powers (kurtosis) of
#: 1e7 samples stay below the float maximum (1.8e308): (1e75)^4 x 1e7 = 1e307.
MAX_MAGNITUDE = 1e75


def check_magnitude(values: np.ndarray, role: str, label: str, where: str) -> None:
    """Refuse values so large that the statistics of later steps would overflow.

    Raises
    ------
    DataError
        A finite value beyond :data:`MAX_MAGNITUDE`.
    """
    with np.errstate(invalid="ignore"):
        largest = float(np.nanmax(np.abs(values))) if np.isfinite(values).any() else 0.0
    if largest > MAX_MAGNITUDE:
        raise DataError(
            f"{role} {label!r}{where} reaches {largest:.3g}, beyond +-{MAX_MAGNITUDE:.0e}: "
            "no plant signal is that large; check the export's units or scaling"
        )
