"""The ``stiction`` command (Typer app). No numerics here: parse, call, render."""

import os as _os

# One BLAS thread per process, set before numpy is first imported.  The matrices
# here are small (a few dozen columns), and a multi-threaded BLAS on a busy machine
# waits for its slowest thread: on two shared cores one Gram product of the process
# fit took 0.3 s instead of 3 ms (``stiction gap`` 11 s -> 4 s).  A value the user
# set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
del _var
# pyarrow (which pandas imports) starts a background thread of its jemalloc
# allocator; without it the process keeps a single thread, so ``stiction analyze``
# can draw its figures in forked worker processes while the analysis runs
# (stictiondiag.plotting.writer forks only a single-threaded process).
_os.environ.setdefault("JE_ARROW_MALLOC_CONF", "background_thread:false")
