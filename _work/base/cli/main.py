"""Assembles the ``stiction`` command from one module per sub-command.

The application object lives in :mod:`cli.app`; the command modules register on it
there, and this module imports them (one direction only, no import cycle).
"""

from __future__ import annotations

import contextlib

from . import app as _app_module
from .app import EXIT_INTERRUPTED, EXIT_TERMINATED, StictionGroup, app

__all__ = ["EXIT_INTERRUPTED", "EXIT_TERMINATED", "StictionGroup", "app", "main"]

# Sub-commands register themselves on import: one file per command.
from . import _commands  # noqa: E402,F401


def _terminate(signum, frame) -> None:
    """SIGTERM takes Ctrl-C's path: the command stops its workers on the way out,
    one line is printed (``stiction: terminated``) and the exit code is 143."""
    import signal

    _app_module.terminated = True
    # Once is enough: a second SIGTERM must not interrupt the stopping of the workers.
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt


def _flush_stdout() -> int | None:
    """Flush stdout; an exit code 2 and one line when it cannot take the output."""
    import os
    import sys

    try:
        sys.stdout.flush()
    except OSError as exc:
        reason = (exc.strerror or type(exc).__name__).lower()
        sys.stderr.write(
            f"stiction: error: cannot write to standard output: {reason}; "
            "redirect it to a writable file\n"
        )
        # Python would try the flush again at exit and print a traceback-like note.
        with contextlib.suppress(OSError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        return 2
    return None


def main() -> None:
    """Console-script entry point (``stiction``)."""
    import signal
    import sys

    from .report import normalise_argv

    # From here on Ctrl-C raises KeyboardInterrupt: the command stops its workers on
    # the way out and StictionGroup prints the one line.  SIGTERM does the same.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminate)
    code: int | str | None = 0
    try:
        app(args=normalise_argv(sys.argv[1:]), prog_name="stiction")
    except KeyboardInterrupt:
        line, code = _app_module.stop_message()
        sys.stderr.write(line + "\n")
    except SystemExit as exc:
        code = exc.code
    finally:
        # The work is done (or has stopped): a Ctrl-C from here on would only
        # interrupt Python's shutdown (its exit handlers) with a traceback.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    failed = _flush_stdout()
    sys.exit(failed if failed is not None and not code else code)


if __name__ == "__main__":  # pragma: no cover
    # ``python -m cli.main``: the sub-commands registered themselves on the ``app`` of
    # ``cli.main`` (imported under its package name), not on this ``__main__`` copy.
    from cli.main import main as _main

    _main()
