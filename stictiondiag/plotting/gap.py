"""Plots of the sim-to-real gap (:mod:`stictiondiag.gap.diagnose`).

:func:`plot_gap_breakdown` shows where the gap lies (signal, valve phase, frequency,
time) and how each candidate effect scored; :func:`plot_gap_replay` shows the replay
against the data before and after the winning effect, as time trends and as the
mv-op plot that Section 5.3.1 of Choudhury et al. (2005) recommends for valve faults.
Both read the diagnosis's typed parts by attribute (``breakdown``:
:class:`stictiondiag.gap.breakdown.Breakdown`; ``series``:
:class:`stictiondiag.gap.result.GapSeries`) without importing the gap layer.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stictiondiag.plotting.canvas import (
    decimate,
    new_figure,
    pin_decorations,
    place_axes,
    text_width,
    ytick_room,
)

_BEFORE = "tab:orange"
_AFTER = "tab:green"
_DATA = "0.25"
_UNITS = {"pv": "pv units", "op": "% of span", "mv": "% of span"}


def _bars(ax, labels, before, after, title, ylabel):
    x = np.arange(len(labels))
    ax.bar(
        x - 0.2, [np.nan if v is None else v for v in before], 0.4, color=_BEFORE, label="before"
    )
    ax.bar(x + 0.2, [np.nan if v is None else v for v in after], 0.4, color=_AFTER, label="after")
    ax.set_xticks(x, labels)
    ax.set_title(title, fontsize=10)
    ax.set_ylabel(ylabel)


def plot_gap_breakdown(diagnosis, *, title: str | None = None) -> Figure:
    """Where the gap lies, before and after the winning effect, and the candidates.

    Parameters
    ----------
    diagnosis : GapDiagnosis
        Result of :func:`stictiondiag.gap.diagnose.diagnose_gap`.
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
    """
    b = diagnosis.breakdown
    # Only the panels with something to show, in reading order; the summary text
    # takes the last cell and a cell left over is removed (no empty panels).
    panels = []
    if b is not None:
        panels.append(lambda ax: _signal_panel(ax, b.signal))
        phase, phase_signal = b.phase, _phase_signal(b.phase)
        if phase is not None and phase_signal is not None:
            panels.append(lambda ax: _phase_panel(ax, phase, phase_signal))
        if _frequency_signals(b.frequency)[0]:
            panels.append(lambda ax: _frequency_panel(ax, b.frequency))
        if b.time.items():
            panels.append(lambda ax: _time_panel(ax, b.time))
    if diagnosis.candidates:
        panels.append(lambda ax: _candidates_panel(ax, diagnosis))
    fig, axes = new_figure(2, 3, (14, 7.5))
    cells = list(axes.flat)
    for draw, ax in zip(panels, cells, strict=False):
        draw(ax)
    ax = cells[len(panels)]
    ax.set_axis_off()
    summary = _summary(diagnosis)
    ax.text(0.0, 1.0, summary, va="top", family="monospace", fontsize=8, transform=ax.transAxes)
    for spare in cells[len(panels) + 1 :]:
        spare.set_axis_off()
    fig.suptitle(title or "Sim-to-real gap: where the replay departs from the data")
    _breakdown_layout(fig, axes, text_width(summary, 8, "monospace"))
    for spare in cells[len(panels) + 1 :]:
        fig.delaxes(spare)
    return fig


def _signal_panel(ax, sig) -> None:
    """Gap per signal before and after, with each signal's noise floor."""
    names = sig.names()
    gaps = [g for _, g in sig.items()]
    _bars(
        ax,
        names,
        [g.before for g in gaps],
        [g.after for g in gaps],
        "By signal",
        "gap [%]",
    )
    ax.plot(
        np.arange(len(names)),
        [g.noise_floor for g in gaps],
        "k_",
        markersize=18,
        label="noise floor",
    )
    ax.legend(fontsize=8)


def _phase_signal(ph) -> str | None:
    """The signal whose error the valve-phase panel shows: mv where its replay
    departs at all, else pv; None when neither does (the panel is left out and the
    summary says so)."""
    if ph is None:
        return None
    for signal in ("mv", "pv"):
        shares = [p.share_before(signal) for _, p in ph.items()]
        if any(v is not None and np.isfinite(v) and v > 0 for v in shares):
            return signal
    return None


def _phase_panel(ax, ph, signal: str) -> None:
    """Share of the ``signal`` replay error per valve phase (stuck, slip, moving,
    reversal)."""
    labels = [name for name, _ in ph.items()]
    errors = [getattr(p, signal) for _, p in ph.items()]
    _bars(
        ax,
        labels,
        [None if e is None else e.share_pct_before for e in errors],
        [None if e is None else e.share_pct_after for e in errors],
        f"By valve phase (share of {signal} error)",
        "% of squared error",
    )
    for i, (_, p) in enumerate(ph.items()):
        ax.text(
            i,
            0,
            f"{p.samples_pct:.0f}% of\nsamples",
            ha="center",
            va="bottom",
            fontsize=7,
        )


def _frequency_signals(fr) -> tuple[list[str], list[str]]:
    """The signals with a replay error to split by frequency, and those whose replay
    is exact (no error: their shares are None, :mod:`stictiondiag.gap.breakdown`)."""
    if fr is None:
        return [], []
    present = [s for s in ("mv", "pv", "op") if getattr(fr.signals, s) is not None]
    exact = [s for s in present if getattr(fr.signals, s).fundamental_pct_before is None]
    return [s for s in present if s not in exact], exact


def _frequency_panel(ax, fr) -> None:
    """Error energy at the fundamental, its harmonics and elsewhere, per signal; a
    signal whose replay is exact gets no bar and is named in words instead."""
    sigs, exact = _frequency_signals(fr)
    if sigs:
        parts = ("fundamental", "harmonics", "other")
        x = np.arange(len(sigs))
        bottom = np.zeros(len(sigs))
        for part, color in zip(parts, ("tab:blue", "tab:purple", "0.7"), strict=True):
            vals = np.array(
                [getattr(getattr(fr.signals, s), f"{part}_pct_before") or 0.0 for s in sigs]
            )
            ax.bar(x, vals, 0.5, bottom=bottom, color=color, label=part)
            bottom += vals
        ax.set_xticks(x, sigs)
        period = fr.fundamental_period_s
        ax.set_title(
            "By frequency, before"
            + ("" if period is None else f" (fundamental period {period:.0f} s)"),
            fontsize=10,
        )
        ax.set_ylabel("% of error energy")
        ax.legend(fontsize=8)
        if exact:
            ax.set_xlabel(f"{', '.join(exact)}: replay exact, no error to split", fontsize=8)
    else:
        ax.set_axis_off()


def _time_panel(ax, tm) -> None:
    """Gap in the first and second half of the record, per signal; a signal with no
    gap in either half before or after gets no bars and is named in words."""
    labels, before, after, nil = [], [], [], []
    for s, v in tm.items():
        cells = [v.early_before, v.early_after, v.late_before, v.late_after]
        if all(c is not None and c == 0.0 for c in cells):
            nil.append(s)
            continue
        for half in ("early", "late"):
            labels.append(f"{s}\n{half}")
            before.append(getattr(v, f"{half}_before"))
            after.append(getattr(v, f"{half}_after"))
    if labels:
        _bars(ax, labels, before, after, "Over time (first and second half)", "gap [%]")
        if nil:
            ax.set_xlabel(f"{', '.join(nil)}: no gap in either half", fontsize=8)
    else:
        ax.set_axis_off()


def _candidates_panel(ax, diagnosis) -> None:
    """Held-out gap and penalised score of every candidate effect."""
    cands = list(diagnosis.candidates)
    if cands:
        y = np.arange(len(cands))
        ax.barh(y, [c.heldout for c in cands], color="0.6", label="held-out gap")
        ax.scatter(
            [c.penalised_score for c in cands],
            y,
            color=["tab:green" if c.accepted else "tab:red" for c in cands],
            zorder=3,
            label="penalised score",
        )
        ax.set_yticks(y, [c.effect for c in cands], fontsize=8)
        ax.invert_yaxis()
        ax.axvline(diagnosis.heldout_before, color="k", lw=0.8, ls="--", label="none (base)")
        ax.set_xlabel("gap [%]")
        ax.set_title("Candidates (green: beats the base on held-out data)", fontsize=10)
        ax.legend(fontsize=7, loc="lower right")
    else:
        ax.set_axis_off()


def _summary(diagnosis) -> str:
    """The text of the last panel: gap, effect, runner-up and the valve features."""
    b = diagnosis.breakdown
    lines = [
        f"gap before: {diagnosis.before:.1f} %",
        f"effect: {diagnosis.effect}",
        f"gap after: {diagnosis.after:.1f} % (shrink {diagnosis.shrink_pct:.0f} %)",
        f"runner-up: {diagnosis.runner_up} (margin {diagnosis.margin:.1f} %)",
    ]
    valve = None if b is None else b.feature.valve
    if valve is not None:
        for key, label in (
            ("jump_up", "jump up"),
            ("jump_down", "jump down"),
            ("moving_slope", "moving slope"),
            ("corner_rise_samples", "slip rise [samples]"),
        ):
            cells = [getattr(getattr(valve, w), key) for w in ("data", "before", "after")]
            txt = " / ".join("-" if v is None else f"{v:.2f}" for v in cells)
            lines.append(f"{label} (data/before/after): {txt}")
    phase = None if b is None else b.phase
    if phase is not None and _phase_signal(phase) is None:
        lines.append("by valve phase: no replay error in mv or pv")
    elif phase is None:
        lines.append("by valve phase: no valve phases (no stick and slip found)")
    fr = None if b is None else b.frequency
    with_error, exact = _frequency_signals(fr)
    if exact and not with_error:
        lines.append("by frequency: every replay exact, no error to split")
    elif not with_error and (fr is None or fr.fundamental_period_s is None):
        lines.append("by frequency: no oscillation to split the error by")
    if diagnosis.not_assessed:
        lines.append("not assessed: " + ", ".join(diagnosis.not_assessed))
    return "\n".join(lines)


def _breakdown_layout(fig: Figure, axes, summary_width: float) -> None:
    """Margins as ``tight_layout`` would set them, from estimates of the labels'
    widths; the right margin grows when the summary text is wider than its column."""
    pad = 0.1  # [in]

    def room(ax):
        return ytick_room(ax) if ax.axison else 0.0

    left = max(0.6, max(room(ax) for ax in axes[:, 0]) + pad)
    wspace = max(0.6, max(room(ax) for ax in axes[:, 1:].flat) + 2 * pad)
    # Summary text at the left edge of the last column (three equal columns); a
    # summary too wide for the figure widens it, so that no panel shrinks below
    # ``min_cell``.
    min_cell = 1.2  # [in]
    width = max(fig.get_figwidth(), left + 2 * wspace + 2 * min_cell + pad + summary_width)
    fig.set_figwidth(width)
    cell = (width - left - 2 * wspace - pad - summary_width) / 2
    right = max(0.25, width - left - 2 * wspace - 3 * cell)
    place_axes(fig, left=left, right=right, top=0.66, bottom=0.6, wspace=wspace, hspace=0.72)
    pin_decorations(fig)


def plot_gap_replay(diagnosis, *, window: int | None = None, title: str | None = None) -> Figure:
    """Replay against data before and after the winning effect.

    Parameters
    ----------
    diagnosis : GapDiagnosis
        Result of :func:`stictiondiag.gap.diagnose.diagnose_gap`.
    window : int, optional
        Samples shown (the last ones of the record); default the last quarter, at
        most 2000.
    title : str, optional
        Figure title.

    Returns
    -------
    Figure
    """
    series = diagnosis.series
    if series is None:
        raise ValueError("the gap diagnosis holds no series to plot")
    s = series.columns()
    t = np.asarray(s["time"])
    n = t.size
    m = min(max(n // 4, 200), 2000) if window is None else int(window)
    sl = slice(max(n - m, 0), n)
    rows = [name for name in ("mv", "pv", "op") if s.get(name) is not None]
    fig, axes = new_figure(len(rows), 2, (13, 2.7 * len(rows)), width_ratios=(2.4, 1))
    for i, name in enumerate(rows):
        ax = axes[i, 0]
        ax.plot(*decimate(t[sl], s[name][sl]), color=_DATA, lw=0.8, label="data")
        ax.plot(
            *decimate(t[sl], s[f"{name}_before"][sl]),
            color=_BEFORE,
            lw=0.8,
            label="replay before",
        )
        if diagnosis.effect != "none":
            ax.plot(
                *decimate(t[sl], s[f"{name}_after"][sl]),
                color=_AFTER,
                lw=0.8,
                label=f"with {diagnosis.effect}",
            )
        ax.set_ylabel(f"{name} [{_UNITS[name]}]")
        ax.legend(fontsize=7, loc="upper right")
        ax2 = axes[i, 1]
        if name == "mv":
            ax2.plot(s["op"][sl], s["mv"][sl], color=_DATA, lw=0.6, label="data")
            ax2.plot(s["op"][sl], s["mv_before"][sl], color=_BEFORE, lw=0.6, label="before")
            if diagnosis.effect != "none":
                ax2.plot(s["op"][sl], s["mv_after"][sl], color=_AFTER, lw=0.6, label="after")
            ax2.set_xlabel("op [% of span]")
            ax2.set_ylabel("mv [% of span]")
            ax2.set_title("mv-op plot", fontsize=9)
        else:
            r0 = s[name][sl] - s[f"{name}_before"][sl]
            r1 = s[name][sl] - s[f"{name}_after"][sl]
            ax2.plot(*decimate(t[sl], r0), color=_BEFORE, lw=0.6, label="before")
            if diagnosis.effect != "none":
                ax2.plot(*decimate(t[sl], r1), color=_AFTER, lw=0.6, label="after")
            ax2.set_title(f"{name} replay error", fontsize=9)
            ax2.set_xlabel("time [s]")
            ax2.set_ylabel(f"data - replay [{_UNITS[name]}]")
        ax2.legend(fontsize=7)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(
        title
        or f"Replay against data: before and after {diagnosis.effect} "
        f"(gap {diagnosis.before:.1f} % -> {diagnosis.after:.1f} %)"
    )
    # Margins as tight_layout would set them; a gap for the x label of the mv-op plot.
    pad = 0.1  # [in]
    xlabels = any(ax.get_xlabel() for ax in axes[:-1].flat)
    place_axes(
        fig,
        left=max(0.6, max(ytick_room(ax) for ax in axes[:, 0]) + pad),
        right=0.25,
        top=0.66,
        bottom=0.59,
        wspace=max(0.55, max(ytick_room(ax) for ax in axes[:, 1]) + 2 * pad),
        hspace=0.78 if xlabels else 0.58,
    )
    pin_decorations(fig)
    return fig
