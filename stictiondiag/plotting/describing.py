"""Graphical solution of the limit-cycle condition, as Fig. 17 of Choudhury et al. (2005).

The open-loop frequency response ``G0(i w)`` (solid) and the ``-1/N(X_m)`` curves of
the stiction describing function (dotted, one per (S, J) case) on the complex
plane; their intersections (Eq. 5) are the predicted limit cycles (Section 6.4).
"""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from stictiondiag.plotting import pyplot


def plot_nyquist_df(
    diagram,
    *,
    ax: Axes | None = None,
    xlim: tuple[float, float] = (-3.0, 0.5),
    ylim: tuple[float, float] = (-4.0, 0.5),
    title: str | None = None,
) -> Figure:
    """Nyquist plot of ``G0(i w)`` with the ``-1/N(X_m)`` curves (Fig. 17).

    Parameters
    ----------
    diagram : LimitCycleDiagram
        From :func:`stictiondiag.models.describing.limit_cycle_diagram` (read by
        attribute: this module imports nothing from the models).
    ax : Axes, optional
        Draw into these axes; default a new figure.
    xlim, ylim : (float, float)
        Axis limits (real and imaginary parts).
    title : str, optional
        Axes title.

    Returns
    -------
    Figure
        Each predicted limit cycle is marked with its period [s] and controller-output
        amplitude ``X_m`` [% of span].
    """
    plt = pyplot()
    if ax is None:
        fig, ax = plt.subplots(figsize=(6, 6))
    else:
        fig = ax.figure
    g0 = diagram.g0
    # Only the part near the plotted region: the integrator sends G0 to infinity.
    inside = (np.abs(g0) < 10 * max(abs(xlim[0]), abs(ylim[0]), 1.0)).nonzero()[0]
    ax.plot(g0.real[inside], g0.imag[inside], color="k", lw=1.5, label="G0(iw)")

    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, curve in enumerate(diagram.curves):
        color = colors[k % len(colors)]
        c = curve.locus
        ax.plot(c.real, c.imag, ls=":", lw=1.8, color=color, label=f"-1/N, {curve.label}")
        for sol, g in zip(curve.prediction.solutions, curve.at_g0, strict=True):
            ax.plot(
                g.real,
                g.imag,
                marker="o" if sol.stable else "x",
                ms=7,
                mfc=color if sol.stable else "none",
                color=color,
                ls="none",
            )
            ax.annotate(
                f"T = {sol.period_s:.3g} s, Xm = {sol.amplitude_op:.3g} %",
                (g.real, g.imag),
                textcoords="offset points",
                xytext=(6, 4),
                fontsize=7,
                color=color,
            )
    ax.axhline(0, color="0.7", lw=0.6)
    ax.axvline(0, color="0.7", lw=0.6)
    ax.plot([-1], [0], marker="+", color="0.3", ms=9, ls="none")
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_xlabel("Real [-]")
    ax.set_ylabel("Imaginary [-]")
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="lower left", fontsize=7)
    ax.set_title(title or "Limit cycles: G0(iw) = -1/N(Xm) (o stable, x unstable)", fontsize=9)
    return fig
