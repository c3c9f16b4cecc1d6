"""A few cycles of the mv-op plot with S and J drawn on it, as in Fig. 10 of
Choudhury, Thornhill & Shah (2005).

Fig. 10 (Section 5.1) defines the data-driven model on the input-output plot of a
sticky valve: after a reversal the valve stays stuck while op travels the deadband
plus stickband ``S`` (along the op axis), then slips by the jump ``J`` (along the mv
axis).  :func:`plot_valve_zoom` draws the last few cycles of the recorded mv against
op (or of the fitted model's mv, when mv is not recorded) in % of span on equal
axes, finds the largest slip in the window and draws ``S`` as a horizontal arrow
ending at it and ``J`` as a vertical arrow from the stuck position, so the fitted
values can be checked against the data by eye.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stictiondiag.plotting.canvas import new_figure, pin_decorations

#: Cycles shown.
ZOOM_CYCLES = 3
#: Samples shown when the loop does not oscillate, and the fewest shown.
ZOOM_DEFAULT, ZOOM_MIN = 400, 40
#: A jump counts as a slip when it is at least this share of J [-].
SLIP_SHARE = 0.5

_S_COLOR = "tab:blue"
_J_COLOR = "tab:red"


def _one_label(sym: str, value: float, poorly=()) -> str:
    mark = " (poorly determined)" if sym in poorly else ""
    return f"{sym} = {value:.3g} %{mark}"


def sj_label(S: float, J: float, poorly=()) -> str:
    """``S = 5 %, J = 5.78 % (poorly determined)`` for figure titles."""
    return f"{_one_label('S', S, poorly)}, {_one_label('J', J, poorly)}"


def zoom_window(n: int, ts: float, period_s: float | None) -> slice:
    """The last :data:`ZOOM_CYCLES` cycles of the record (or its last
    :data:`ZOOM_DEFAULT` samples when it does not cycle)."""
    width = int(round(ZOOM_CYCLES * period_s / ts)) if period_s and period_s > 0 else ZOOM_DEFAULT
    return slice(max(0, n - max(ZOOM_MIN, width)), n)


def find_slip(mv: np.ndarray, J: float) -> int | None:
    """Index ``k`` of the largest jump ``mv[k] - mv[k-1]`` in ``mv``, or None when
    no jump reaches :data:`SLIP_SHARE` of ``J`` (or ``J`` is not positive)."""
    if mv.size < 2 or not J > 0:
        return None
    jumps = np.abs(np.diff(mv))
    k = int(np.argmax(jumps))
    return k + 1 if jumps[k] >= SLIP_SHARE * J else None


def _arrow(ax, start, end, color: str, text: str, offset) -> None:
    ax.annotate(
        "",
        xy=end,
        xytext=start,
        arrowprops={"arrowstyle": "<->", "color": color, "lw": 1.6, "shrinkA": 0, "shrinkB": 0},
        zorder=5,
    )
    mid = ((start[0] + end[0]) / 2, (start[1] + end[1]) / 2)
    ax.annotate(
        text,
        xy=mid,
        xytext=offset,
        textcoords="offset points",
        color=color,
        fontsize=9,
        fontweight="bold",
        ha="center" if offset[0] == 0 else ("left" if offset[0] > 0 else "right"),
        va="center",
        zorder=6,
        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
    )


def plot_valve_zoom(
    op,
    mv,
    *,
    ts: float,
    S: float,
    J: float,
    period_s: float | None = None,
    model: bool = False,
    poorly=(),
    title: str | None = None,
) -> Figure:
    """mv against op over the last few cycles, with S and J drawn as in Fig. 10.

    Parameters
    ----------
    op, mv : array_like
        Controller output and valve position [% of span] (``mv`` the fitted model's
        output when ``model``).
    ts : float
        Sample time [s].
    S, J : float
        Fitted deadband plus stickband and slip jump [% of span].
    period_s : float, optional
        Oscillation period [s]; sets the window to :data:`ZOOM_CYCLES` cycles.
    model : bool
        ``mv`` is the model's (no mv recorded): said in the title and legend.
    poorly : sequence of str
        Parameters (``"S"``, ``"J"``) the data determine poorly: marked so on the
        figure.
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
    """
    op = np.asarray(op, dtype=float)
    mv = np.asarray(mv, dtype=float)
    win = zoom_window(op.size, float(ts), period_s)
    x, y = op[win], mv[win]
    fig, axes = new_figure(1, 1, (6.2, 5.0))
    ax = axes[0, 0]
    label = "mv of the fitted model" if model else "mv recorded"
    ax.plot(x, y, color="0.3", ls="--" if model else "-", lw=1.0, marker="o", ms=2, label=label)
    lo, hi = float(min(x.min(), y.min())), float(max(x.max(), y.max()))
    ax.plot([lo, hi], [lo, hi], color="0.6", lw=0.6, ls=":", label="mv = op")
    k = find_slip(y, J)
    if k is not None and S > 0:
        d = 1.0 if y[k] > y[k - 1] else -1.0
        stuck, slip_op = float(y[k - 1]), float(x[k])
        s_text, j_text = _one_label("S", S, poorly), _one_label("J", J, poorly)
        # Labels on the side of the jump: inside the loop, away from the title.
        _arrow(ax, (slip_op - d * S, stuck), (slip_op, stuck), _S_COLOR, s_text, (0, 11 * d))
        _arrow(ax, (slip_op, stuck), (slip_op, stuck + d * J), _J_COLOR, j_text, (-6 * d, 0))
        note = "arrows at the largest slip of the window"
    else:
        ax.text(
            0.02,
            0.98,
            f"{sj_label(S, J, poorly)} (no slip of J in this window)",
            transform=ax.transAxes,
            va="top",
            fontsize=8,
        )
        note = "no slip in the window"
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel(("mv model" if model else "mv") + " [% of span]")
    cycles = f"last {ZOOM_CYCLES} cycles" if period_s else f"last {win.stop - win.start} samples"
    ax.set_title(f"mv-op, {cycles} ({note})", fontsize=9)
    ax.legend(loc="lower right", fontsize=7, framealpha=0.85)
    ax.grid(alpha=0.3)
    fig.suptitle(title or "Valve signature (Fig. 10)", fontsize=10)
    fig.subplots_adjust(left=0.14, right=0.97, top=0.88, bottom=0.11)
    pin_decorations(fig)
    return fig
