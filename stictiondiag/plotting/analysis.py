"""Phase plots and time trends of one loop, as Figs. 3-6 of Choudhury et al. (2005).

Signals are shown mean-centred with unit variance, as the paper presents plant data
(Section 3). The mv-op plot is the one to read for valve faults; the pv-op plot mixes
in the process dynamics (Section 5.3.1), and pv-sp helps for a cascaded slave loop
under mostly proportional control (Loop 3, Fig. 5).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

_MAX_POINTS = 4000  # trend window shown: enough cycles to read, few enough to see the shape


def _scaled(x: np.ndarray) -> np.ndarray:
    sd = float(np.std(x))
    return (x - np.mean(x)) / (sd if sd > 0 else 1.0)


def plot_phase(tags, *, fit=None, title: str | None = None) -> Figure:
    """Time trends (left) and phase plots (right) of a loop.

    Parameters
    ----------
    tags : Tags
        Loop data (:class:`stictiondiag.tags.Tags`).
    fit : StictionFit, optional
        When given, the fitted valve output (``fit.mv_model``) is drawn against op,
        so the phase plot shows the model beside the data (or instead of it, when
        the loop has no mv).
    title : str, optional
        Figure title; default is the source name.

    Returns
    -------
    Figure
    """
    has_mv = tags.mv is not None
    has_sp = tags.sp is not None and float(np.std(tags.sp)) > 0
    rows = 1 + int(has_mv or fit is not None) + int(has_sp)
    fig, axes = plt.subplots(
        rows, 2, figsize=(11, 3.0 * rows), gridspec_kw={"width_ratios": [2.2, 1]}, squeeze=False
    )
    n = min(tags.n, _MAX_POINTS)
    t = tags.time[:n] - tags.time[0]
    pv, op = _scaled(tags.pv), _scaled(tags.op)

    ax_t, ax_p = axes[0]
    ax_t.plot(t, op[:n], lw=0.8, color="0.35", label="op")
    ax_t.plot(t, pv[:n], lw=1.2, color="tab:blue", label="pv")
    ax_t.set_ylabel("scaled")
    ax_t.legend(loc="upper right", fontsize=8)
    ax_t.set_title("time trends (mean-centred, unit variance)", fontsize=9)
    ax_p.plot(op, pv, lw=0.5, color="tab:blue")
    ax_p.set_xlabel("op")
    ax_p.set_ylabel("pv")
    ax_p.set_title("pv-op", fontsize=9)

    r = 1
    if has_mv or fit is not None:
        ax_t, ax_p = axes[r]
        if has_mv:
            mv = tags.mv
            mv_s = (mv - np.mean(tags.op)) / (float(np.std(tags.op)) or 1.0)
            ax_t.plot(t, op[:n], lw=0.8, color="0.35", label="op")
            ax_t.plot(t, mv_s[:n], lw=1.2, color="tab:red", label="mv")
            ax_p.plot(op, mv_s, lw=0.6, color="tab:red", label="data")
        if fit is not None and getattr(fit, "mv_model", None) is not None:
            mvm = (np.asarray(fit.mv_model) - np.mean(tags.op)) / (float(np.std(tags.op)) or 1.0)
            ax_t.plot(t, mvm[:n], lw=1.0, ls="--", color="k", label="fitted valve")
            ax_p.plot(
                op, mvm, lw=0.8, ls="--", color="k", label=f"model S={fit.S:.2f} J={fit.J:.2f}"
            )
        ax_t.legend(loc="upper right", fontsize=8)
        ax_t.set_ylabel("scaled by op")
        ax_p.set_xlabel("op")
        ax_p.set_ylabel("mv")
        ax_p.set_title("mv-op" + ("" if has_mv else " (model only: no mv recorded)"), fontsize=9)
        ax_p.legend(loc="upper left", fontsize=7)
        r += 1
    if has_sp:
        ax_t, ax_p = axes[r]
        sp = (tags.sp - np.mean(tags.pv)) / (float(np.std(tags.pv)) or 1.0)
        ax_t.plot(t, sp[:n], lw=0.8, color="0.35", label="sp")
        ax_t.plot(t, pv[:n], lw=1.2, color="tab:blue", label="pv")
        ax_t.legend(loc="upper right", fontsize=8)
        ax_t.set_ylabel("scaled by pv")
        ax_p.plot(sp, pv, lw=0.5, color="tab:blue")
        ax_p.set_xlabel("sp")
        ax_p.set_ylabel("pv")
        ax_p.set_title("pv-sp (cascade slave loops)", fontsize=9)
    axes[-1][0].set_xlabel("time [s]")
    fig.suptitle(title or str(getattr(tags, "source", "")), fontsize=10)
    fig.tight_layout()
    return fig
