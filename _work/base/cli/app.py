"""The ``stiction`` Typer application and its one error format.

Every command module registers on :data:`app` (imported from here, so the command
modules and :mod:`cli.main` import each other in one direction only).

One error format: whatever goes wrong is reported as one line on stderr,
``stiction: error: <what is wrong and how to fix it>``, with a documented exit code
(:mod:`stictiondiag.core.errors`): 2 for a usage error, Click's and Typer's own
included (unknown option, bad option value, missing argument), 3 for data that
cannot be read or analysed, 130 after Ctrl-C (``stiction: interrupted``) and 143
after SIGTERM, which takes the same path (``stiction: terminated``).
"""

from __future__ import annotations

import os
import sys
import traceback
from typing import Any

import typer
from typer.core import TyperGroup

# Typer carries its own copy of Click (``typer._click``); its exceptions are the
# ones raised while parsing the command line.
click = typer.core._click

#: Exit code after Ctrl-C (128 + SIGINT, the shell's convention).
EXIT_INTERRUPTED = 130

#: Exit code after SIGTERM (128 + SIGTERM), which takes Ctrl-C's path.
EXIT_TERMINATED = 143

#: Set by the SIGTERM handler of :func:`cli.main.main` before it raises
#: KeyboardInterrupt: the interrupt was a termination.
terminated = False


def stop_message() -> tuple[str, int]:
    """The line and exit code of an interrupt: Ctrl-C (130) or SIGTERM (143)."""
    if terminated:
        return "stiction: terminated", EXIT_TERMINATED
    return "stiction: interrupted", EXIT_INTERRUPTED


#: Exit code of a usage error (same value as ``stictiondiag.core.errors.EXIT_USAGE``;
#: repeated here so that parsing the command line imports no numerics).
_EXIT_USAGE = 2
_EXIT_DATA = 3


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines included) made one space."""
    return " ".join(str(text).split())


def usage_message(exc) -> str:
    """Click's message for a usage error, on one line, with the command it concerns."""
    message = one_line(exc.format_message()).rstrip(".")
    command = exc.ctx.command_path if exc.ctx is not None else "stiction"
    hint = f"; see '{command} --help'" if command else ""
    return f"{message}{hint}"


def internal_message(exc: BaseException) -> str:
    """One line for an unforeseen exception: its type, message and where it arose."""
    last = traceback.extract_tb(exc.__traceback__)[-1:]
    where = f" in {last[0].name}" if last else ""
    text = one_line(exc) or type(exc).__name__
    return (
        f"cannot analyse these data ({type(exc).__name__}{where}: {text[:200]}); "
        "set STICTION_DEBUG=1 for the traceback"
    )


class StictionGroup(TyperGroup):
    """Typer's group with the one-line error format instead of its boxed messages."""

    def main(  # type: ignore[override]
        self,
        args: Any = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        **extra: Any,
    ) -> Any:
        try:
            code = super().main(
                args=args,
                prog_name=prog_name,
                complete_var=complete_var,
                standalone_mode=False,
                **extra,
            )
        except click.exceptions.NoArgsIsHelpError as exc:
            click.echo(exc.ctx.get_help(), err=True)
            code = _EXIT_USAGE
        except click.exceptions.UsageError as exc:
            click.echo(f"stiction: error: {usage_message(exc)}", err=True)
            code = _EXIT_USAGE
        except click.exceptions.ClickException as exc:
            click.echo(f"stiction: error: {one_line(exc.format_message())}", err=True)
            code = exc.exit_code
        except typer.Abort:
            # EOF on a prompt, or Ctrl-C (or SIGTERM) outside a command.
            line, code = stop_message()
            click.echo(line, err=True)
        except MemoryError:
            click.echo(
                "stiction: error: not enough memory for this request: shorten the data "
                "or the duration",
                err=True,
            )
            code = _EXIT_USAGE
        except Exception as exc:
            # A failure the library did not foresee still ends in one line; the data
            # caused it (the commands map every foreseen error themselves).
            if os.environ.get("STICTION_DEBUG"):
                raise
            click.echo(f"stiction: error: {internal_message(exc)}", err=True)
            code = _EXIT_DATA
        else:
            # Typer turns Ctrl-C (KeyboardInterrupt) into exit code 130 and prints
            # nothing; the command has already stopped its workers on the way out.
            if code == EXIT_INTERRUPTED:
                line, code = stop_message()
                click.echo(line, err=True)
            code = code if isinstance(code, int) else 0
        if standalone_mode:
            sys.exit(code)
        return code


app = typer.Typer(
    name="stiction",
    cls=StictionGroup,
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
