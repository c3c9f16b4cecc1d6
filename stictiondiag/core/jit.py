"""Compilation helper: every per-sample kernel is compiled once by numba and cached
on disk (``cache=True``), so a CLI run does not pay for compiling every time.

The cache lives next to the source in ``__pycache__``; where that is not writable
numba falls back to its user-wide cache directory (``NUMBA_CACHE_DIR`` overrides).
"""

from __future__ import annotations

import numba

#: Decorator for a compiled, cached, GIL-free kernel.
jit = numba.njit(cache=True, nogil=True)
