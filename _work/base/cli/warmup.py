"""``stiction warm-up``: compile the numba kernels ahead of the first analysis.

A fresh installation compiles its kernels at first use (12-30 s of CPU); this
command does it once, with progress on stderr, and every later process (an
``analyze``, each worker of a ``scan``) loads them from numba's on-disk cache.
Without it the first ``analyze`` compiles them itself, after a one-line note on
stderr.  See docs/performance.md, "First run".
"""

from __future__ import annotations

import sys

import typer

from .app import app
from .common import friendly_errors, info


@app.command("warm-up")
def warm_up() -> None:
    """Compile the numba kernels now (first run after install), with progress on stderr.

    Safe to repeat: kernels already in the cache are loaded, not compiled again.
    Prints one summary line on stdout.
    """
    from stictiondiag.apps.warmup import warm_up as run

    with friendly_errors():
        info("stiction warm-up: compiling the numba kernels (first run only)")
        result = run(progress=lambda line: print(line, file=sys.stderr, flush=True))
        typer.echo(
            f"{len(result.compiled)} kernels compiled in {result.seconds:.1f} s; "
            f"{result.kernels - len(result.not_cached)} of {result.kernels} in the cache"
        )
        if result.not_cached:
            info(f"not reached (compiled at first use): {', '.join(result.not_cached)}")
