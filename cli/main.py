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
    import gc
    import sys

    from .report import normalise_argv

    try:
        app(args=normalise_argv(sys.argv[1:]), prog_name="stiction")
    finally:
        # Python's shutdown runs the garbage collector over every object left, more
        # than once: about 1 s after an analysis (numba, scipy, matplotlib and
        # pandas loaded) against 0.15 s with the objects frozen.  Nothing is left
        # for it to do: the outputs are written and closed, and the exit frees the
        # memory.
        gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    # ``python -m cli.main``: the sub-commands registered themselves on the ``app`` of
    # ``cli.main`` (imported under its package name), not on this ``__main__`` copy.
    from cli.main import main as _main

    _main()
