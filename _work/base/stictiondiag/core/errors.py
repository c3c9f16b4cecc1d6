"""Exceptions and the documented exit codes of the ``stiction`` command.

Every error a user can cause carries a one-line message that says what is wrong and
how to fix it. The CLI maps each exception class to one exit code; nothing else in
the library knows about exit codes.

Exit codes
----------
0  success
1  a finding the user asked to fail on (``--fail-on-stiction``)
2  usage error: bad option value, unknown loop or valve, impossible request, or an
   output that cannot be written (named)
3  unreadable or invalid data: missing file, unknown format, missing tag,
   non-numeric, all-NaN or constant signals, too few samples
4  partial failure: some loops of a scan or report could not be analysed
130, 143  stopped by Ctrl-C (SIGINT) or SIGTERM (cli.app)
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_FINDING = 1
EXIT_USAGE = 2
EXIT_DATA = 3
EXIT_PARTIAL = 4


class StictionError(Exception):
    """Base of all errors the library raises on purpose (message is one line)."""

    exit_code = EXIT_USAGE


class UsageError(StictionError, ValueError):
    """A parameter or option is out of range or inconsistent."""

    exit_code = EXIT_USAGE


class DataError(StictionError, ValueError):
    """Input data cannot be read or does not support the requested analysis."""

    exit_code = EXIT_DATA


def require_bool(name: str, value: object, *, optional: bool = False) -> bool | None:
    """``value`` if it is a boolean (numpy's included), else a TypeError naming ``name``.

    A truthy string (``"no"``, ``"false"``) is not taken for True: the library's
    boolean options take booleans only.  ``optional`` lets None through.

    Raises
    ------
    TypeError
        ``value`` is not a boolean (nor None when ``optional``).
    """
    if value is None and optional:
        return None
    kind = type(value)
    if isinstance(value, bool) or (
        kind.__module__ == "numpy" and kind.__name__ in ("bool", "bool_")
    ):
        return bool(value)  # type: ignore[arg-type]
    allowed = "True, False or None" if optional else "True or False"
    raise TypeError(f"{name} must be {allowed}, not {value!r} ({type(value).__name__})")
