"""The ``stiction`` command (Typer app). No numerics here: parse, call, render.

Each command imports the library's layers inside its function, so that ``stiction
--help`` and one command's start pay only for what that command runs (the analysis
brings numpy and numba, about a second); only ``stictiondiag.core``'s errors and
atomic writes, which load no numpy, are imported at module level.
"""

import os as _os
import signal as _signal
import sys as _sys

# One BLAS thread per process, set before numpy is first imported
# (stictiondiag.core.blas imports no numpy).
from stictiondiag.core.blas import default_to_one_thread as _one_thread

_one_thread()
del _one_thread


def _interrupted_while_starting(signum, frame) -> None:  # pragma: no cover - timing
    # Ctrl-C while the command's modules are still being imported: one line, exit
    # 130, no traceback.  cli.main.main() puts Python's own handler back once the
    # command can stop cleanly.
    _sys.stderr.write("stiction: interrupted\n")
    _sys.stderr.flush()
    _os._exit(130)


def _terminated_while_starting(signum, frame) -> None:  # pragma: no cover - timing
    # SIGTERM before the command can stop cleanly: the same one line and exit 143
    # (cli.main.main() puts its own handler in place once the command runs).
    _sys.stderr.write("stiction: terminated\n")
    _sys.stderr.flush()
    _os._exit(143)


if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
if _signal.getsignal(_signal.SIGTERM) == _signal.SIG_DFL:
    _signal.signal(_signal.SIGTERM, _terminated_while_starting)
