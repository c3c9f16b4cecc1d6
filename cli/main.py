"""Assembles the ``stiction`` command from one module per sub-command."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="stiction",
    help="Diagnose control-valve stiction from plant data (Choudhury, Thornhill & Shah 2005).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version(value: bool) -> None:
    if value:
        from stictiondiag import __version__

        typer.echo(__version__)
        raise typer.Exit(0)


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", help="Print the version and exit.", callback=_version, is_eager=True
    ),
) -> None:
    """Diagnose control-valve stiction from plant data."""


# Sub-commands register themselves on import: one file per command.
from . import _commands  # noqa: E402,F401


def main() -> None:
    """Console-script entry point (``stiction``)."""
    import sys

    from .report import normalise_argv

    app(args=normalise_argv(sys.argv[1:]), prog_name="stiction")


if __name__ == "__main__":  # pragma: no cover
    # ``python -m cli.main``: the sub-commands registered themselves on the ``app`` of
    # ``cli.main`` (imported under its package name), not on this ``__main__`` copy.
    from cli.main import main as _main

    _main()
