"""Plots. The only part of the library that imports ``matplotlib.pyplot``.

One submodule per domain; every plot function returns the figure and never calls
``plt.show()``.  The Agg backend is selected so plots render without a screen.
"""

import matplotlib

matplotlib.use("Agg")
