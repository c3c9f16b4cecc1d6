"""Plots. The only part of the library that imports ``matplotlib.pyplot``.

One submodule per domain; every plot function returns the figure and never calls
``plt.show()``.  pyplot runs on the Agg backend (:func:`pyplot`), so plots render
without a screen.  Importing this package imports no matplotlib: a process that
only hands figures to :mod:`~stictiondiag.plotting.writer`'s workers never pays
for it.
"""


def pyplot():
    """``matplotlib.pyplot``, on the Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_png(fig, dpi: int = 90) -> bytes:
    """PNG bytes of a matplotlib figure; closes the figure."""
    import io

    plt = pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()
