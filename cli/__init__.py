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
