"""Plots. The only part of the library that imports ``matplotlib.pyplot``.

One submodule per domain; every plot function returns the figure and never calls
``plt.show()``.  Figures are made on the Agg canvas of :mod:`.canvas`, outside
pyplot's registry, so they render without a screen.  Importing this package imports
no matplotlib.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from stictiondiag.core.atomic import atomic_path

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def pyplot() -> Any:
    """``matplotlib.pyplot``, on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_png(fig: Figure, dpi: int = 90) -> bytes:
    """PNG bytes of a matplotlib figure; closes the figure."""
    import io

    plt = pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


def save_png(fig: Figure, path: str | os.PathLike[str], *, dpi: int = 110) -> Path:
    """Write ``fig`` as a PNG file, whole or not at all (temporary file, then
    rename); return the path.

    Raises
    ------
    UsageError
        The file cannot be written (:func:`stictiondiag.core.atomic.atomic_path`).
    """
    target = Path(path)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return target
