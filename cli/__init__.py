"""The ``stiction`` command (Typer app). No numerics here: parse, call, render."""

# One BLAS thread per process, set before numpy is first imported
# (stictiondiag.core.blas imports no numpy).
from stictiondiag.core.blas import default_to_one_thread as _one_thread

_one_thread()
del _one_thread
