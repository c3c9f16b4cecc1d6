"""The ``stiction`` command (Typer app). No numerics here: parse, call, render."""

import gc as _gc
import os as _os
import signal as _signal
import sys as _sys

# One BLAS thread per process, set before numpy is first imported
# (stictiondiag.core.blas imports no numpy).
from stictiondiag.core.blas import default_to_one_thread as _one_thread

_one_thread()
del _one_thread

# pyarrow (which pandas imports) starts a background thread of its jemalloc
# allocator; without it the process keeps a single thread, so ``stiction analyze``
# can draw its figures in forked worker processes while the analysis runs
# (stictiondiag.plotting.writer forks only a single-threaded process).
_os.environ.setdefault("JE_ARROW_MALLOC_CONF", "background_thread:false")

# The cyclic garbage collector runs after every 700 net new container objects by
# default: about 400 times in one ``stiction analyze`` (0.2 s), mostly while
# modules are imported and numba sets up its compiler, which make objects and no
# garbage (the analysis frees its own by reference counting: the peak memory is
# the same without the collector).  Every 20 000 it runs 14 times (0.07 s).
# cli.main.main() also freezes the objects at exit (see there).
_gc.set_threshold(20_000, *_gc.get_threshold()[1:])


def _interrupted_while_starting(signum, frame) -> None:  # pragma: no cover - timing
    # Ctrl-C while the command's modules are still being imported: one line, exit
    # 130, no traceback.  cli.main.main() puts Python's own handler back once the
    # command can stop cleanly.
    _sys.stderr.write("stiction: interrupted\n")
    _sys.stderr.flush()
    _os._exit(130)


if _signal.getsignal(_signal.SIGINT) is _signal.default_int_handler:
    _signal.signal(_signal.SIGINT, _interrupted_while_starting)
