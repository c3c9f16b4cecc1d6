"""Reconstruction plot: the closed-loop replay over the recorded data.

Left: time trends of pv (with sp), op and mv, data and replay overlaid.  Right: the
mv-op map of the data (recorded mv, or the stiction fit's ``mv_model`` when mv is not
recorded) and of the replay, the valve signature of Section 5.3 of Choudhury,
Thornhill & Shah (2005), and the pv-op map of both.

The replay and its :class:`~stictiondiag.replay.metrics.ReplayMetrics` are read by
attribute, not imported: ``Replay.plot`` imports this module, which therefore
imports nothing from the replay layer.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from stictiondiag.core.serialize import plain_float
from stictiondiag.plotting.canvas import (
    decimate,
    new_figure,
    pin_decorations,
    place_axes,
    text_width,
    ytick_room,
)

DATA_STYLE = {"color": "0.15", "lw": 0.8, "zorder": 3}
REPLAY_STYLE = {"color": "tab:orange", "lw": 1.8, "alpha": 0.85, "zorder": 2}
WIDTH_RATIOS = (2.4, 1)


def _fmt(v, spec: str = ".3g") -> str:
    return "-" if v is None else format(v, spec)


def _num(v, spec: str = ".3g") -> str:
    """A number of the replay's models; "-" for None, NaN or inf (a P-only
    controller's integral time)."""
    return _fmt(plain_float(v), spec)


def _default_window(replay) -> float:
    """About eight data periods, or the whole record."""
    duration = replay.n * replay.dt
    period = replay.period_data_s or replay.period_replay_s
    if period is None:
        return duration
    return min(duration, 8.0 * period)


def _signal_title(name: str, replay, metrics) -> str:
    """Panel title: amplitude error and waveform agreement from ``metrics``
    (:mod:`stictiondiag.replay.metrics`), else the replay's fit and waveform."""
    if metrics is not None:
        s = metrics.agreement(name)
        err = None if s is None else plain_float(s.amplitude_error_pct)
        wave = None if s is None else plain_float(s.waveform)
        amp = "n/a" if err is None else f"{err:+.0f} %"
        return f"{name}: amplitude {amp}, waveform agreement {_fmt(wave, '.2f')}"
    m = replay.measures.by_signal().get(name)
    return (
        f"{name}: fit {_fmt(None if m is None else m.fit_pct, '.0f')} %, "
        f"waveform {_fmt(None if m is None else m.waveform, '.3f')}"
    )


def plot_replay(
    replay,
    *,
    window: float | None = None,
    title: str | None = None,
    metrics=None,
) -> Figure:
    """Overlay of a :class:`~stictiondiag.replay.closed_loop.Replay` and the recorded data.

    Parameters
    ----------
    replay : Replay
        Result of :func:`stictiondiag.replay.closed_loop.replay`.
    window : float, optional
        Length of record shown in the trends, from the start [s]; default about
        eight oscillation periods (the replay drifts in phase later on).  The maps
        use the whole record.
    title : str, optional
        Figure title; default names S, J, the periods and the pv fit.
    metrics : ReplayMetrics, optional
        :func:`stictiondiag.replay.metrics.replay_metrics` of the replay: the panels
        then show period error, amplitude error and waveform agreement.

    Returns
    -------
    Figure
    """
    if window is None:
        window = _default_window(replay)
    stop = max(2, min(replay.n, int(round(window / replay.dt))))
    t = replay.time[:stop]
    data = replay.data
    mv_data = data.mv
    mv_label = "mv data"
    if mv_data is None:
        mv_data = data.mv_model
        mv_label = "mv model (fit)"

    fig, axes = new_figure(3, 2, (12, 7.5), width_ratios=WIDTH_RATIOS)

    def trend(ax, y, **style):
        # A record without a cycle is shown whole: a long trend is drawn decimated.
        ax.plot(*decimate(t, y[:stop]), **style)

    ax = axes[0, 0]
    trend(ax, replay.sp, lw=0.7, color="0.55", ls="--", label="sp")
    trend(ax, data.pv, label="pv data", **DATA_STYLE)
    trend(ax, replay.pv, label="pv replay", **REPLAY_STYLE)
    ax.set_ylabel("pv [pv units]")
    ax.set_title(_signal_title("pv", replay, metrics), fontsize=9)
    ax.legend(loc="upper right", fontsize=7, ncol=3)

    ax = axes[1, 0]
    trend(ax, data.op, label="op data", **DATA_STYLE)
    trend(ax, replay.op, label="op replay", **REPLAY_STYLE)
    ax.set_ylabel("op [% of span]")
    ax.set_title(_signal_title("op", replay, metrics), fontsize=9)
    ax.legend(loc="upper right", fontsize=7, ncol=2)

    ax = axes[2, 0]
    if mv_data is not None:
        trend(ax, mv_data, label=mv_label, **DATA_STYLE)
    trend(ax, replay.mv, label="mv replay", **REPLAY_STYLE)
    ax.set_ylabel("mv [% of span]")
    ax.set_xlabel("time [s]")
    if replay.measures.mv is not None:
        ax.set_title(_signal_title("mv", replay, metrics), fontsize=9)
    ax.legend(loc="upper right", fontsize=7, ncol=2)

    ax = axes[0, 1]
    if mv_data is not None:
        ax.plot(data.op, mv_data, label=mv_label, **DATA_STYLE)
    ax.plot(replay.op, replay.mv, label="replay", **REPLAY_STYLE)
    ops = np.concatenate([data.op, replay.op])
    lo, hi = float(np.min(ops)), float(np.max(ops))
    ax.plot([lo, hi], [lo, hi], lw=0.5, color="0.6", ls=":")
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel("mv [% of span]")
    ax.set_title("mv-op", fontsize=9)
    ax.legend(loc="upper left", fontsize=7)

    ax = axes[1, 1]
    ax.plot(data.op, data.pv, label="data", **DATA_STYLE)
    ax.plot(replay.op, replay.pv, label="replay", **REPLAY_STYLE)
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel("pv [pv units]")
    ax.set_title("pv-op", fontsize=9)

    ax = axes[2, 1]
    ax.axis("off")
    summary = _summary(replay, metrics)
    ax.text(0.0, 1.0, summary, va="top", ha="left", fontsize=8, family="monospace")

    if title is None:
        title = "Closed-loop replay with the fitted valve"
    fig.suptitle(title, fontsize=10)
    _layout(fig, axes, text_width(summary, 8, "monospace"))
    return fig


#: The replayed valve's flowchart in words (``Replay.settings.valve``).
_FLOWCHARTS = {"choudhury": "Choudhury, Fig. 10", "kano": "Kano et al."}


def _summary(replay, metrics=None) -> str:
    """The text of the last panel: valve, controller, process, periods, amplitudes
    (by the one measure of ``metrics`` for data and replay, when given)."""
    pf, cf = replay.process_fit, replay.controller_fit
    proc, ctrl = pf.process, cf.controller
    lines = [
        f"valve: S = {replay.S:.3g} %, J = {replay.J:.3g} %"
        f" ({_FLOWCHARTS.get(str(replay.settings.valve), 'data-driven')})",
        f"controller: Kc = {_num(ctrl.gain)}, Ti = {_num(ctrl.integral_time)} s"
        f" (R2 {_num(cf.fit_r2, '.3f')})",
    ]
    if proc.kind == "foptd":
        lines.append(
            f"process: K = {_num(proc.gain)}, tau = {_num(proc.time_constant)}"
            f" s, theta = {_num(proc.dead_time)} s"
        )
    else:
        lines.append(
            f"process: K = {_num(proc.gain)} /s (integrating), theta = {_num(proc.dead_time)} s"
        )
    lines.append(f"process R2 {_num(pf.output_error.fit_r2, '.3f')}")
    lines.append(
        f"period [s]: data {_fmt(replay.period_data_s)}, "
        f"replay {_fmt(replay.period_replay_s)} ({replay.period_signal})"
    )
    amplitudes: list[tuple[str, float | None, float | None]] = []
    if metrics is not None:
        per = plain_float(metrics.period_error_pct)
        lines.append(f"period error: {'n/a' if per is None else format(per, '+.0f') + ' %'}")
        amplitudes = [
            (s.signal, plain_float(s.amplitude_data), plain_float(s.amplitude_replay))
            for s in metrics.signals
        ]
    if not amplitudes:
        amplitudes = [
            (name, m.amplitude_data, m.amplitude_replay)
            for name, m in replay.measures.by_signal().items()
        ]
    for name, data, rep in amplitudes:
        lines.append(f"amplitude {name}: data {_fmt(data)}, replay {_fmt(rep)}")
    return "\n".join(lines)


def _layout(fig: Figure, axes, summary_width: float) -> None:
    """Margins as ``tight_layout`` would set them, from estimates of the labels'
    widths; the right margin grows when the summary text is wider than its column."""
    pad = 0.1  # [in]
    left = max(0.6, max(ytick_room(ax) for ax in axes[:, 0]) + pad)
    wspace = max(0.6, max(ytick_room(ax) for ax in axes[:2, 1]) + 2 * pad)
    width = fig.get_figwidth()
    # Summary text at the left edge of the right column: the column ends at
    # left + wspace + total * cell, with cell = (right column width) / 1.
    total = sum(WIDTH_RATIOS)
    cell = (width - left - wspace - pad - summary_width) / (total - WIDTH_RATIOS[1])
    right = max(0.15, width - left - wspace - total * cell)
    place_axes(fig, left=left, right=right, top=0.64, bottom=0.59, wspace=wspace, hspace=0.76)
    pin_decorations(fig)
