"""Assembles the ``stiction`` command from one module per sub-command.

The application object lives in :mod:`cli.app`; the command modules register on it
there, and this module imports them (one direction only, no import cycle).
"""

from __future__ import annotations

from .app import EXIT_INTERRUPTED, StictionGroup, app

__all__ = ["EXIT_INTERRUPTED", "StictionGroup", "app", "main"]

# Sub-commands register themselves on import: one file per command.
from . import _commands  # noqa: E402,F401


def main() -> None:
    """Console-script entry point (``stiction``)."""
    import signal
    import sys

    from .report import normalise_argv

    # From here on Ctrl-C raises KeyboardInterrupt: the command stops its workers on
    # the way out and StictionGroup prints the one line.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        app(args=normalise_argv(sys.argv[1:]), prog_name="stiction")
    except KeyboardInterrupt:
        sys.stderr.write("stiction: interrupted\n")
        sys.exit(EXIT_INTERRUPTED)
    finally:
        # The work is done (or has stopped): a Ctrl-C from here on would only
        # interrupt Python's shutdown (its exit handlers) with a traceback.
        signal.signal(signal.SIGINT, signal.SIG_IGN)


if __name__ == "__main__":  # pragma: no cover
    # ``python -m cli.main``: the sub-commands registered themselves on the ``app`` of
    # ``cli.main`` (imported under its package name), not on this ``__main__`` copy.
    from cli.main import main as _main

    _main()
