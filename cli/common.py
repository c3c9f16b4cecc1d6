"""Shared CLI plumbing: turn library errors into one-line messages and exit codes."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

import typer

from stictiondiag.core.errors import StictionError


def fail(message: str, code: int) -> None:
    """Print ``stiction: error: <message>`` on stderr and exit with ``code``."""
    typer.echo(f"stiction: error: {message}", err=True)
    raise typer.Exit(code)


@contextlib.contextmanager
def friendly_errors() -> Iterator[None]:
    """Map :class:`StictionError` (and stray OS errors) to one line and an exit code."""
    try:
        yield
    except StictionError as exc:
        fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__, exc.exit_code)
    except MemoryError:
        fail("not enough memory for this request: shorten the duration or the data", 2)
    except OSError as exc:
        fail(f"{exc.strerror or exc}: {getattr(exc, 'filename', '') or ''}".strip(), 3)


def info(message: str) -> None:
    """Progress and messages go to stderr; stdout carries data only."""
    print(message, file=sys.stderr)


def emit(d: dict, summary: str, json_path: str | None) -> None:
    """Print a result's summary and write its JSON.

    ``--json -`` puts the JSON on stdout (data only) and the summary on stderr;
    otherwise the summary goes to stdout and the JSON, if asked for, to the file,
    written whole or not at all.
    """
    import json

    text = json.dumps(d, indent=2) + "\n"
    if json_path == "-":
        info(summary)
        sys.stdout.write(text)
        return
    typer.echo(summary)
    if json_path:
        from stictiondiag.core.atomic import write_atomic

        write_atomic(json_path, text)
        info(f"wrote {json_path}")
