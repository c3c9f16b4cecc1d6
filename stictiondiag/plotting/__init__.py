"""Plots. The only part of the library that imports ``matplotlib.pyplot``.

One submodule per domain; every plot function returns the figure and never calls
``plt.show()``.  The Agg backend is selected so plots render without a screen.
"""

import matplotlib

matplotlib.use("Agg")


def figure_png(fig, dpi: int = 90) -> bytes:
    """PNG bytes of a matplotlib figure; closes the figure."""
    import io

    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
