"""Plots of a closed-loop simulation, as Figs. 9 and 12-15 of Choudhury et al. (2005).

Time trends on the left (pv with sp; op with mv, op thin as in the paper) and the
mappings on the right: mv against op, the valve signature, and pv against op, which
mixes in the process dynamics (Section 5.3.1).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stictiondiag.plotting import pyplot


def _title(settings: dict) -> str:
    valve = settings.get("valve", "?")
    if valve in ("choudhury", "kano"):
        detail = f"S = {settings.get('S'):g} %, J = {settings.get('J'):g} %"
    elif valve == "physical" and settings.get("physical"):
        ph = settings["physical"]
        detail = f"Fs = {ph['Fs']:g} N, Fc = {ph['Fc']:g} N, Fv = {ph['Fv']:g} N s/m"
        if ph.get("calibration", 1.0) != 1.0:
            detail += f", calibration x{ph['calibration']:g}"
    else:
        detail = "no stiction"
    band = settings.get("integral_band")
    extra = f", integral band {band:g}" if band is not None else ""
    return f"{valve} valve: {detail}{extra}"


def plot_simulation(sim, *, last: float | None = None, title: str | None = None) -> Figure:
    """Trends and mappings of a :class:`~stictiondiag.models.loops.Simulation`.

    Parameters
    ----------
    sim : Simulation
        Result of :func:`stictiondiag.models.loops.simulate_loop`.
    last : float, optional
        Show only the last ``last`` seconds of the trends and mappings (the settled
        cycle); default the last third of the run.
    title : str, optional
        Figure title; default describes the valve.

    Returns
    -------
    Figure
    """
    duration = sim.n * sim.dt
    if last is None:
        last = duration / 3.0
    start = max(0, sim.n - max(2, int(round(last / sim.dt))))
    t = sim.time[start:]
    sp, pv, op, mv = sim.sp[start:], sim.pv[start:], sim.op[start:], sim.mv[start:]

    fig, axes = pyplot().subplots(2, 2, figsize=(11, 6), gridspec_kw={"width_ratios": [2.2, 1]})
    ax = axes[0, 0]
    ax.plot(t, sp, lw=0.8, color="0.5", ls="--", label="sp")
    ax.plot(t, pv, lw=1.2, color="tab:blue", label="pv")
    ax.set_ylabel("pv [pv units]")
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[1, 0]
    ax.plot(t, op, lw=0.8, color="0.3", label="op")
    ax.plot(t, mv, lw=1.6, color="tab:red", label="mv")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("op, mv [% of span]")
    ax.legend(loc="upper right", fontsize=8)

    ax = axes[0, 1]
    ax.plot(op, mv, lw=0.8, color="tab:red")
    lo = float(min(np.min(op), np.min(mv)))
    hi = float(max(np.max(op), np.max(mv)))
    ax.plot([lo, hi], [lo, hi], lw=0.5, color="0.6", ls=":")
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel("mv [% of span]")
    ax.set_title("mv-op", fontsize=9)
    ax = axes[1, 1]
    ax.plot(op, pv, lw=0.8, color="tab:blue")
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel("pv [pv units]")
    ax.set_title("pv-op", fontsize=9)

    fig.suptitle(title if title is not None else _title(sim.settings), fontsize=10)
    fig.tight_layout()
    return fig
