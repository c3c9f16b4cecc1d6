"""One BLAS thread per process.

The matrices here are small (a few dozen columns), and a multi-threaded BLAS on a
busy machine waits for its slowest thread: on two shared cores one Gram product of
the process fit took 0.3 s instead of 3 ms (``stiction gap`` 11 s -> 4 s).  The
setting must be in the environment before numpy is first imported in a process, so
this module imports no numpy.  A value the user set is kept.
"""

from __future__ import annotations

import contextlib
import os

#: Thread-count settings of the BLAS libraries numpy may be built with.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def default_to_one_thread() -> None:
    """One BLAS thread for this process and the ones it starts, unless set already."""
    for var in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(var, "1")


@contextlib.contextmanager
def one_blas_thread():
    """Processes started inside this block run one BLAS thread each (unless the
    user set a value); this process's environment is restored at the end."""
    added = [v for v in BLAS_THREAD_VARIABLES if v not in os.environ]
    for v in added:
        os.environ[v] = "1"
    try:
        yield
    finally:
        for v in added:
            os.environ.pop(v, None)
