"""The loop type from ISA 5.1 tag names (``FIC101.PV`` -> flow, ``LIC200.OP`` -> level).

The first letters of an ISA 5.1 instrument tag name the measured variable (F flow,
L level, P pressure, T temperature, A analysis, Q quantity/quality), optional
modifiers follow (I indicating, R recording) and C marks a controller: ``FIC``,
``FC``, ``LIC``, ``PIC``, ``TRC``, ``AIC``, ``QIC``.  The loop number follows, with or
without a separator (``FIC101``, ``FIC-101``, ``FIC_101``).

Only the controller's tags decide (pv, op and sp of one loop); a valve-position tag
(``ZT101``) names no loop type.  When the tags of one loop name two types, none is
chosen.  A level loop integrates (Choudhury, Thornhill & Shah 2005, Section 4.2.2,
Table 3).  When the names say nothing, the data decide
(:mod:`stictiondiag.identification.looptype`).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

__all__ = ["ISA_LOOP_TYPES", "SOURCES", "isa_loop_type", "loop_tag", "resolve_loop_type"]

#: First letter of an ISA controller tag -> loop type.
ISA_LOOP_TYPES = {
    "f": "flow",
    "l": "level",
    "p": "pressure",
    "t": "temperature",
    "a": "composition",
    "q": "composition",
}

#: Where a loop's type came from: given by the user (option, manifest or argument),
#: the ISA tag prefix, the data, or nothing decided it (self-regulating assumed).
SOURCES = ("user", "tag", "data", "default")

# Controller tag: variable letter, optional I/R modifiers, C, optional separator, digits.
_ISA_CONTROLLER = re.compile(r"^([flptaq])[ir]{0,2}c[-_ ]?\d+[a-z]?$", re.IGNORECASE)
_ROLE_SEPARATOR = re.compile(r"[.:/]")


def loop_tag(name: str) -> str | None:
    """The ISA controller tag a column name starts with (``"FIC-101.PV"`` -> ``"FIC-101"``)."""
    head = _ROLE_SEPARATOR.split(str(name).strip(), maxsplit=1)[0].strip()
    if _ISA_CONTROLLER.match(head):
        return head
    # "FIC101_PV", "FIC101 PV": the tag is the part before the role suffix.
    parts = re.split(r"[_\s]+", head)
    if len(parts) > 1 and _ISA_CONTROLLER.match("".join(parts[:-1])):
        return "_".join(parts[:-1])
    return None


def isa_loop_type(names: Iterable[str]) -> tuple[str, str] | None:
    """(loop type, tag) named by the ISA tags among ``names``, or None.

    Parameters
    ----------
    names : iterable of str
        Column (tag) names of one loop's pv, op and sp.

    Returns
    -------
    (str, str) or None
        The loop type and the tag that named it; None when no name is an ISA
        controller tag, or the names disagree.
    """
    found: dict[str, str] = {}
    for name in names:
        tag = loop_tag(name)
        if tag is not None:
            found.setdefault(ISA_LOOP_TYPES[tag[0].lower()], tag)
    if len(found) != 1:
        return None
    loop_type, tag = next(iter(found.items()))
    return loop_type, tag


def resolve_loop_type(
    loop_type: str | None,
    integrating: bool | None,
    names: Iterable[str],
    notes: list[str],
) -> tuple[str, bool, str]:
    """(loop type, integrating, source) of a loop being read.

    A given ``loop_type`` is the user's; else the ISA tag prefix of ``names`` decides
    (a note says which tag); else the loop type is ``"other"`` and the source
    ``"pending"``: the data are to decide
    (:func:`stictiondiag.identification.looptype.settle_loop_type`).  ``integrating``,
    when given, is the user's and is kept whatever decides the type; by default a
    level loop integrates and no other does.
    """
    if loop_type is not None:
        source = "user"
    else:
        named = isa_loop_type(names)
        if named is not None:
            loop_type, tag = named
            source = "tag"
            notes.append(f"loop type {loop_type} from the ISA tag {tag!r} (override: --loop-type)")
        else:
            loop_type, source = "other", "pending"
    if integrating is None:
        integrating = loop_type == "level"
    elif source == "pending":
        source = "user"
    return loop_type, bool(integrating), source
