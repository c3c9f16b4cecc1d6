"""Shared CLI plumbing: turn library errors into one-line messages and exit codes."""

from __future__ import annotations

import contextlib
import errno
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import typer

from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.errors import StictionError, UsageError


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
        if getattr(exc, "filename", None) is None and exc.errno in _OUTPUT_ERRNOS:
            # A write that failed without a file name: a print to a full or closed
            # stdout (typer.echo).  Reading never fails so: an output error.
            reason = (exc.strerror or type(exc).__name__).lower()
            fail(
                f"cannot write the output: {reason}; redirect standard output to a writable "
                "file, or free space",
                2,
            )
        fail(f"{exc.strerror or exc}: {getattr(exc, 'filename', '') or ''}".strip(), 3)


#: errno values only a write gives: a full device or quota, a closed pipe, a
#: read-only file system, a file too large.
_OUTPUT_ERRNOS = frozenset(
    getattr(errno, name)
    for name in ("ENOSPC", "EDQUOT", "EPIPE", "EROFS", "EFBIG")
    if hasattr(errno, name)
)


def info(message: str) -> None:
    """Progress and messages go to stderr; stdout carries data only."""
    print(message, file=sys.stderr)


#: Said at once when the kernels must be compiled before the command can run.
COMPILE_NOTE = (
    "stiction: compiling kernels, first run only, about a minute "
    "('stiction warm-up' does it ahead); progress below"
)


def compile_if_cold() -> None:
    """On a cold kernel cache (a fresh installation, or kernels edited since), say so at
    once and compile them with progress on stderr before the command's own work
    (:func:`stictiondiag.apps.warmup.warm_up`); on a warm cache, nothing (milliseconds)."""
    import stictiondiag.analysis  # noqa: F401  (imports the kernels the commands run)
    from stictiondiag.core import jit

    if not jit.cache_is_cold():
        return
    from stictiondiag.apps.warmup import warm_up

    info(COMPILE_NOTE)
    result = warm_up(progress=info)
    info(
        f"stiction: {len(result.compiled)} kernels compiled in {result.seconds:.0f} s; "
        "later runs load them from the cache"
    )


def write_stdout(text: str) -> None:
    """Write ``text`` to stdout and flush it; a stdout that cannot take it is an
    output error (exit 2) naming it, not a data error.

    Raises
    ------
    UsageError
        stdout is full (``/dev/full``), closed or otherwise unwritable.
    """
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except OSError as exc:
        reason = (exc.strerror or type(exc).__name__).lower()
        raise UsageError(
            f"cannot write to standard output: {reason}; redirect it to a writable file"
        ) from None


def probe_writable(target: Path, option: str, shown: Path | None = None) -> None:
    """Refuse, before any work, an output location this process cannot write.

    ``target`` is the folder the output goes into (it may not exist yet): a
    temporary file is made and removed at once in it, or when it does not exist
    yet in the nearest existing folder above it (where its folders would be made;
    ``os.access`` would not do: it grants root everything).  ``shown`` is the path
    the message names (default ``target``).

    Raises
    ------
    UsageError
        Naming ``target`` and the reason.
    """
    import os
    import tempfile

    existing = target
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:
        if not existing.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a directory")
        fd, name = tempfile.mkstemp(prefix=".stiction-probe-", dir=existing)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        reason = (exc.strerror or type(exc).__name__).lower()
        raise UsageError(
            f"cannot write {shown or target}: {reason}; choose a writable {option}"
        ) from None


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
        write_stdout(text)
        return
    write_stdout(summary + "\n")
    if json_path:
        write_atomic(json_path, text)
        info(f"wrote {json_path}")


#: Figure formats the plots can be written in (by the file's extension).
FIGURE_SUFFIXES = (
    ".png",
    ".svg",
    ".svgz",
    ".pdf",
    ".eps",
    ".ps",
    ".jpg",
    ".jpeg",
    ".tif",
    ".tiff",
    ".webp",
)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and a.samefile(b))
    except (OSError, RuntimeError):  # RuntimeError: a link loop
        return False


def check_output_file(
    option: str,
    path: str | Path | None,
    inputs: Sequence[str | Path] = (),
    *,
    figure: bool = False,
) -> None:
    """Refuse an output file that cannot be written, or that is one of the inputs.

    Run before any work, so a typo costs nothing and no input is ever overwritten.

    Raises
    ------
    UsageError
        ``path`` is a directory, lies below a file, is an input file, or (``figure``)
        has an extension no figure can be written in.
    """
    if path in (None, "-"):
        return
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"cannot write {target}: it is a directory; give a file name for {option}")
    for parent in target.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(
                    f"cannot write {target}: {parent} is a file, not a directory; "
                    f"choose another {option} path"
                )
            break
    for given in inputs:
        if _same_file(target, Path(given)):
            raise UsageError(
                f"{option} {target} is an input file: it would be overwritten; "
                f"give another {option} path"
            )
    if figure and target.suffix and target.suffix.lower() not in FIGURE_SUFFIXES:
        raise UsageError(
            f"cannot write a figure as {target.suffix!r} ({target}): use one of "
            f"{', '.join(FIGURE_SUFFIXES)}"
        )
    probe_writable(target.parent, option, shown=target)


def check_output_dir(
    option: str, path: str | Path | None, inputs: Sequence[str | Path] = ()
) -> None:
    """Refuse an output folder that is a file, lies below a file, or is an input file.

    Raises
    ------
    UsageError
        As described.
    """
    if path is None:
        return
    target = Path(path)
    if target.exists() and not target.is_dir():
        what = "an input file" if any(_same_file(target, Path(i)) for i in inputs) else "a file"
        raise UsageError(f"cannot write to {target}: it is {what}; give a folder for {option}")
    for parent in target.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(
                    f"cannot write to {target}: {parent} is a file, not a folder; "
                    f"choose another {option}"
                )
            break
    probe_writable(target, option)
