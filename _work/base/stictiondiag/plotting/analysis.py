"""Phase plots and time trends of one loop, as Figs. 3-6 of Choudhury et al. (2005).

Time trends are mean-centred with unit variance, as the paper presents plant data
(Section 3), and show a window of a few cycles (the paper's "portion of the time
domain data"): a whole record of a hundred cycles is a solid band. The phase plots
draw the whole record in light grey, for context, and the same window in colour.

The mv-op plot is the one to read for valve faults; it is drawn in % of span on
equal axes, so the deadband plus stickband S (along op) and the slip jump J (along
mv) can be read off it as in Fig. 11. The pv-op plot mixes in the process dynamics
(Section 5.3.1), and pv-sp helps for a cascaded slave loop under mostly
proportional control (Loop 3, Fig. 5).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stictiondiag.plotting.canvas import (
    new_figure,
    pin_decorations,
)
from stictiondiag.plotting.valve import sj_label

#: Cycles shown in the trend window when the loop oscillates.
WINDOW_CYCLES = 8
#: Trend window [samples] when there is no cycle, and the bounds of any window.
WINDOW_DEFAULT, WINDOW_MIN, WINDOW_MAX = 1000, 200, 3000

_CONTEXT = {"color": "0.82", "lw": 0.5, "zorder": 1}
_OP = {"color": "0.3", "lw": 0.9}
# Legends of the trends sit above the axes, right of the title: never on the data.
_LEGEND = {
    "loc": "lower right",
    "bbox_to_anchor": (1.0, 1.0),
    "ncol": 3,
    "fontsize": 8,
    "frameon": False,
    "borderaxespad": 0.1,
}
_MARKER_LIMIT = 400  # show sample markers ("line with circles") below this many points


def _scaled(x: np.ndarray, like: np.ndarray | None = None) -> np.ndarray:
    """``x`` mean-centred and divided by the std of ``like`` (default ``x``)."""
    ref = x if like is None else like
    sd = float(np.std(ref))
    return (x - np.mean(ref)) / (sd if sd > 0 else 1.0)


def trend_window(n: int, ts: float, period_s: float | None) -> slice:
    """The last few cycles of the record (or its last samples when it does not cycle).

    Parameters
    ----------
    n : int
        Samples in the record.
    ts : float
        Sample time [s].
    period_s : float or None
        Oscillation period [s], None when the loop does not oscillate.

    Returns
    -------
    slice
        Sample range of the window, at the end of the record (past any start-up).
    """
    if period_s and period_s > 0:
        width = int(round(WINDOW_CYCLES * period_s / ts))
    else:
        width = WINDOW_DEFAULT
    width = min(n, max(WINDOW_MIN, min(WINDOW_MAX, width)))
    return slice(n - width, n)


def _line(ax, x, y, **style):
    markers = {"marker": "o", "ms": 2.2} if x.size <= _MARKER_LIMIT else {}
    ax.plot(x, y, **style, **markers)


#: The pv-sp panel needs a set point that moves with the cycle: sp changing on at
#: least this share of the window's samples, over at least this share of pv's range.
SP_MOVING_SHARE = 0.05
SP_RANGE_SHARE = 0.05


def sp_moves(sp: np.ndarray, pv: np.ndarray) -> bool:
    """Whether sp moves enough for a pv-sp phase plot (a constant sp, or one that steps
    once, draws a vertical line; a cascade slave's sp moves with the cycle, Fig. 5)."""
    sp = np.asarray(sp, dtype=float)
    if sp.size < 2:
        return False
    changes = np.abs(np.diff(sp)) > 1e-9 * max(1.0, float(np.abs(sp).max()))
    spread = float(np.ptp(sp))
    return float(np.mean(changes)) >= SP_MOVING_SHARE and spread >= SP_RANGE_SHARE * max(
        float(np.ptp(pv)), 1e-300
    )


def plot_phase(
    tags,
    *,
    fit=None,
    title: str | None = None,
    period_s: float | None = None,
    poorly: tuple[str, ...] | list[str] = (),
) -> Figure:
    """Time trends (left) and phase plots (right) of a loop.

    Parameters
    ----------
    tags : Tags
        Loop data (:class:`stictiondiag.io.tags.Tags`).
    fit : StictionFit, optional
        When given, the fitted valve output (``fit.mv_model``) is drawn against op,
        so the mv-op plot shows the model beside the data (or instead of it, when
        the loop has no mv).
    title : str, optional
        Figure title; default is the source name.
    period_s : float, optional
        Oscillation period [s]; sets the trend window to :data:`WINDOW_CYCLES`
        cycles (default: :data:`WINDOW_DEFAULT` samples).
    poorly : sequence of str
        The parameters (``"S"``, ``"J"``) the fit determines poorly
        (:meth:`stictiondiag.stiction.valvefit.StictionFit.poorly_determined`),
        marked in the mv-op title.

    Returns
    -------
    Figure
    """
    has_mv = tags.mv is not None
    mv_model = None if fit is None else getattr(fit, "mv_model", None)
    has_model = mv_model is not None and np.size(mv_model) == tags.n
    win = trend_window(tags.n, float(tags.ts), period_s)
    # pv-sp is for a set point that moves with the cycle (cascade slave, Fig. 5);
    # a set point that is constant over the window (or steps once) adds nothing.
    has_sp = tags.sp is not None and sp_moves(tags.sp[win], tags.pv[win])
    rows = 1 + int(has_mv or has_model) + int(has_sp)
    fig, axes = new_figure(rows, 2, (11.5, 3.1 * rows), width_ratios=(2.3, 1))
    t = np.asarray(tags.time)[win]
    start = getattr(tags, "start_time", None)
    if start is not None:
        # Clock time where the export has dates (UTC), to the millisecond.
        t = np.datetime64(0, "ms") + np.round((start + t) * 1000.0).astype("timedelta64[ms]")
    pv, op = _scaled(tags.pv), _scaled(tags.op)
    cycles = f", last {WINDOW_CYCLES} cycles" if period_s else ""

    # Row 1: pv and op (Figs. 3-6, top).
    ax_t, ax_p = axes[0]
    _line(ax_t, t, op[win], label="op", **_OP)
    _line(ax_t, t, pv[win], lw=1.2, color="tab:blue", label="pv")
    ax_t.set_ylabel("pv, op [scaled]")
    ax_t.legend(**_LEGEND)
    ax_t.set_title(f"time trends (mean-centred, unit variance{cycles})", fontsize=9, loc="left")
    ax_p.plot(op, pv, **_CONTEXT)
    _line(ax_p, op[win], pv[win], lw=0.8, color="tab:blue")
    ax_p.set_xlabel("op [scaled]")
    ax_p.set_ylabel("pv [scaled]")
    ax_p.set_title("pv-op", fontsize=9)

    r = 1
    if has_mv or has_model:
        # Row 2: mv and op, mv-op in % of span (Figs. 3, 6 bottom; Fig. 11).
        ax_t, ax_p = axes[r]
        _line(ax_t, t, op[win], label="op", **_OP)
        ax_p.plot(tags.op, tags.mv if has_mv else mv_model, **_CONTEXT)
        if has_mv:
            _line(ax_t, t, _scaled(tags.mv, tags.op)[win], lw=1.2, color="tab:red", label="mv")
            _line(ax_p, tags.op[win], tags.mv[win], lw=0.9, color="tab:red", label="mv data")
        if has_model:
            mvm = np.asarray(mv_model, dtype=float)
            ax_t.plot(t, _scaled(mvm, tags.op)[win], lw=1.0, ls="--", color="k", label="model")
            ax_p.plot(tags.op[win], mvm[win], lw=1.0, ls="--", color="k", label="model")
        ax_t.legend(**_LEGEND)
        ax_t.set_ylabel("mv, op [scaled as op]")
        ax_p.set_xlabel("op [% of span]")
        ax_p.set_ylabel("mv [% of span]")
        ax_p.set_aspect("equal", adjustable="datalim")
        label = "mv-op" if has_mv else "mv-op of the model (no mv recorded)"
        if fit is not None and np.isfinite(getattr(fit, "S", np.nan)):
            label += f"\n{sj_label(fit.S, fit.J, poorly)} of span"
        ax_p.set_title(label, fontsize=9)
        if has_mv and has_model:
            ax_p.legend(loc="best", fontsize=7, framealpha=0.85)
        r += 1
    if has_sp:
        # Row 3: pv and sp, scaled with pv's factors so the control error keeps
        # its meaning (Fig. 5, bottom).
        ax_t, ax_p = axes[r]
        sp = _scaled(tags.sp, tags.pv)
        _line(ax_t, t, sp[win], label="sp", **_OP)
        _line(ax_t, t, pv[win], lw=1.2, color="tab:blue", label="pv")
        ax_t.legend(**_LEGEND)
        ax_t.set_ylabel("pv, sp [scaled as pv]")
        ax_p.plot(sp, pv, **_CONTEXT)
        _line(ax_p, sp[win], pv[win], lw=0.8, color="tab:blue")
        ax_p.set_xlabel("sp [scaled as pv]")
        ax_p.set_ylabel("pv [scaled]")
        ax_p.set_title("pv-sp (cascade slave loops)", fontsize=9)
    for ax in axes[:, 0]:
        ax.set_xlim(t[0], t[-1])
        ax.grid(alpha=0.3)
    axes[-1][0].set_xlabel("time [s]" if start is None else "time (UTC)")
    fig.suptitle(title or str(getattr(tags, "source", "")), fontsize=10)
    _fixed_layout(fig, rows)
    pin_decorations(fig)
    return fig


def _fixed_layout(fig: Figure, rows: int) -> None:
    """Margins in inches for this fixed grid (``tight_layout`` measures every tick
    label and costs more than drawing the figure)."""
    height = fig.get_figheight()
    top, bottom, gap = 0.6, 0.5, 0.85  # [in]: suptitle, time label, titles + labels
    axes_height = (height - top - bottom - (rows - 1) * gap) / rows
    fig.subplots_adjust(
        left=0.065,
        right=0.985,
        top=1 - top / height,
        bottom=bottom / height,
        hspace=gap / axes_height,
        wspace=0.22,
    )
