"""Replay figures an engineer reads right: period, amplitude and waveform agreement.

A stiction limit cycle runs free: its phase drifts, so a point-by-point error (the
NRMSE behind the replay's ``fit``) calls a replay wrong that has the right period,
size and shape but is half a cycle away after a while.  The questions an engineer
asks of a reconstruction of a limit cycle (Sections 4.2.2 and 5.3 of Choudhury,
Thornhill & Shah 2005, where the model's cycles of Figs. 12-15 are compared with
the plant's of Figs. 3-6 by their shape, not sample by sample) are answered here one
at a time, from a :class:`~stictiondiag.replay.closed_loop.Replay`:

``period_error_pct``
    ``100 (T_replay / T_data - 1)`` of the signal the replay reports the period of [%].
``amplitude`` and ``amplitude_error_pct``
    Half peak-to-peak amplitude of data and replay by *one* measure for both
    (:func:`cycle_amplitude`), and ``100 (A_replay / A_data - 1)`` [%].  The replay's
    own ``amplitude`` field uses the oscillation detector's amplitude where a signal
    oscillates and a percentile range where it does not, so a drifting data signal
    and a clean replay can be measured differently; this module does not.
``waveform``
    Correlation of the average cycle of data and replay after aligning their phase
    over one cycle (:func:`stictiondiag.replay.cycles.waveform_similarity`),
    1 = same shape [-].
``nrmse``
    Kept as the replay computed it, for those who want the phase-sensitive figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from stictiondiag.core.serialize import plain_float
from stictiondiag.signals.oscillation import (
    REGULARITY_THRESHOLD,
    detect_oscillation,
    dominant_period,
)

if TYPE_CHECKING:
    import pandas as pd

#: Percentiles of the amplitude measure when no period is known [%].
PERCENTILES = (2.0, 98.0)


def cycle_amplitude(x: np.ndarray, window: int | None) -> float | None:
    """Half peak-to-peak amplitude of a cycling signal, in its own units.

    With a period of ``window`` samples: the median, over consecutive windows of one
    period, of half the window's range (a slow drift adds only its change over one
    period, a single spike changes one window only).  Without a period, or with
    fewer than two whole windows: half the range between the 2nd and 98th
    percentiles of the whole signal.  None for an empty or non-finite signal.
    """
    y = np.asarray(x, dtype=float)
    if y.size == 0 or not np.all(np.isfinite(y)):
        return None
    if window is not None and window >= 2 and y.size >= 2 * window:
        m = y.size // window
        blocks = y[: m * window].reshape(m, window)
        return float(np.median(blocks.max(axis=1) - blocks.min(axis=1))) / 2.0
    lo, hi = np.percentile(y, PERCENTILES)
    return float(hi - lo) / 2.0


def _pct_error(model: float | None, data: float | None) -> float | None:
    if model is None or data is None or not data > 0:
        return None
    return 100.0 * (model / data - 1.0)


@dataclass(frozen=True)
class ReplayMetrics:
    """Period, amplitude and waveform agreement of a replay with its data.

    Attributes
    ----------
    period_signal : str
        Signal whose period is compared (``pv``, or ``op`` when pv does not cycle).
    period_data_s, period_replay_s : float or None
        Oscillation periods [s]; None where the signal does not oscillate.
    period_error_pct : float or None
        ``100 (T_replay / T_data - 1)`` [%].
    amplitude : dict
        Signal -> ``{"data", "replay"}`` half peak-to-peak [units of the signal: pv
        units, or % of span for op and mv], both by :func:`cycle_amplitude` with the
        data's period.
    amplitude_error_pct : dict
        Signal -> ``100 (A_replay / A_data - 1)`` [%].
    waveform : dict
        Signal -> correlation of the phase-aligned average cycles [-].
    nrmse : dict
        Signal -> NRMSE of the replay [-] (phase-sensitive).
    """

    period_signal: str
    period_data_s: float | None
    period_replay_s: float | None
    period_error_pct: float | None
    amplitude: dict = field(default_factory=dict)
    amplitude_error_pct: dict = field(default_factory=dict)
    waveform: dict = field(default_factory=dict)
    nrmse: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return {
            "period_signal": self.period_signal,
            "period_data_s": plain_float(self.period_data_s),
            "period_replay_s": plain_float(self.period_replay_s),
            "period_error_pct": plain_float(self.period_error_pct),
            "amplitude": {
                k: {side: plain_float(v.get(side)) for side in ("data", "replay")}
                for k, v in self.amplitude.items()
            },
            "amplitude_error_pct": {k: plain_float(v) for k, v in self.amplitude_error_pct.items()},
            "waveform": {k: plain_float(v) for k, v in self.waveform.items()},
            "nrmse": {k: plain_float(v) for k, v in self.nrmse.items()},
            "amplitude_measure": "median over one-period windows of half the range",
        }

    def to_pandas(self) -> pd.DataFrame:
        """One row per signal: amplitudes, amplitude error [%], waveform, NRMSE."""
        import pandas as pd

        rows = [
            {
                "signal": name,
                "amplitude_data": amp.get("data"),
                "amplitude_replay": amp.get("replay"),
                "amplitude_error_pct": self.amplitude_error_pct.get(name),
                "waveform": self.waveform.get(name),
                "nrmse": self.nrmse.get(name),
            }
            for name, amp in self.amplitude.items()
        ]
        return pd.DataFrame(rows)

    def text(self) -> str:
        """One line: period error, amplitude errors and waveform agreement."""
        return render_metrics(self.to_dict())


def _signed(v, unit: str = " %") -> str:
    return "n/a" if v is None else f"{v:+.0f}{unit}"


def render_metrics(m: dict) -> str:
    """One line from :meth:`ReplayMetrics.to_dict`."""
    per = m.get("period_error_pct")
    d, r = m.get("period_data_s"), m.get("period_replay_s")
    if per is not None:
        period = f"period {_signed(per)} ({r:.4g} s against {d:.4g} s)"
    elif d is not None:
        period = "period: the replay does not cycle"
    else:
        period = "period: the data do not cycle"
    amp = ", ".join(f"{k} {_signed(v)}" for k, v in (m.get("amplitude_error_pct") or {}).items())
    wave = ", ".join(
        f"{k} {'n/a' if v is None else format(v, '.2f')}"
        for k, v in (m.get("waveform") or {}).items()
    )
    return f"{period}; amplitude {amp or 'n/a'}; waveform agreement [1 = same] {wave or 'n/a'}"


def replay_metrics(rep) -> ReplayMetrics:
    """:class:`ReplayMetrics` of a :class:`~stictiondiag.replay.closed_loop.Replay`."""
    d = rep.period_s.get("data")
    r = rep.period_s.get("replay")
    window = None if not d else int(round(float(d) / float(rep.dt)))
    pairs = {"pv": (rep.data["pv"], rep.pv), "op": (rep.data["op"], rep.op)}
    if rep.data.get("mv") is not None:
        pairs["mv"] = (rep.data["mv"], rep.mv)
    amplitude: dict[str, dict] = {}
    errors: dict[str, float | None] = {}
    for name, (y, yr) in pairs.items():
        a_d, a_r = cycle_amplitude(y, window), cycle_amplitude(yr, window)
        amplitude[name] = {"data": a_d, "replay": a_r}
        errors[name] = _pct_error(a_r, a_d)
    return ReplayMetrics(
        period_signal=rep.period_signal,
        period_data_s=d,
        period_replay_s=r,
        period_error_pct=_pct_error(r, d),
        amplitude=amplitude,
        amplitude_error_pct=errors,
        waveform={k: rep.waveform.get(k) for k in pairs},
        nrmse={k: rep.nrmse.get(k) for k in pairs},
    )


# --------------------------------------------------------------------------- reproduction

#: A replay reproduces a recorded cycle when its period is within this fraction of
#: the data's [-] ...
PERIOD_TOLERANCE = 0.20
#: ... and its amplitude (:func:`spread_amplitude`) within this fraction [-].
AMPLITUDE_TOLERANCE = 0.35
#: Percentiles of :func:`spread_amplitude` [%].
SPREAD_PERCENTILES = (5.0, 95.0)


def spread_amplitude(x: np.ndarray) -> float | None:
    """Half the spread between the 5th and 95th percentiles of ``x`` [units of x]
    (a sine of amplitude a gives 0.95 a, a square wave a); None when empty or not
    finite."""
    y = np.asarray(x, dtype=float)
    if y.size == 0 or not np.all(np.isfinite(y)):
        return None
    lo, hi = np.percentile(y, SPREAD_PERCENTILES)
    return float(hi - lo) / 2.0


@dataclass(frozen=True)
class CycleReproduction:
    """Does a replay reproduce the recorded limit cycle of one signal?

    Both sides are measured on the same samples: the period by the autocorrelation
    zero crossings (Thornhill et al. 2003, :func:`detect_oscillation`) and the
    amplitude by :func:`spread_amplitude`.

    Attributes
    ----------
    period_data_s, period_replay_s : float or None
        Oscillation periods [s]; None where the signal does not cycle
        (:func:`_cycle_period`: regular and sustained).
    amplitude_data, amplitude_replay : float or None
        Half the 5-95 % spread [units of the signal].
    period_error_pct, amplitude_error_pct : float or None
        ``100 (replay / data - 1)`` [%].
    reproduced : bool
        Both signals cycle, the period within :data:`PERIOD_TOLERANCE` and the
        amplitude within :data:`AMPLITUDE_TOLERANCE`.
    reason : str
        Why not reproduced, in words ("" when reproduced).
    """

    period_data_s: float | None
    period_replay_s: float | None
    amplitude_data: float | None
    amplitude_replay: float | None
    period_error_pct: float | None
    amplitude_error_pct: float | None
    reproduced: bool
    reason: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return {
            "period_data_s": plain_float(self.period_data_s),
            "period_replay_s": plain_float(self.period_replay_s),
            "amplitude_data": plain_float(self.amplitude_data),
            "amplitude_replay": plain_float(self.amplitude_replay),
            "period_error_pct": plain_float(self.period_error_pct),
            "amplitude_error_pct": plain_float(self.amplitude_error_pct),
            "reproduced": bool(self.reproduced),
            "reason": self.reason,
        }


def _cycle_period(x: np.ndarray, dt: float) -> tuple[float | None, str]:
    """Period [s] of a cycling signal and, when None, why not.

    A signal cycles when :func:`detect_oscillation` finds a regular, sustained
    oscillation; a record too short for its three cycles still cycles when its
    autocorrelation is regular (five zero crossings at least, regularity >= 1,
    Thornhill et al. 2003): the period is then the autocorrelation's.
    """

    osc = detect_oscillation(x, dt)
    if osc.present:
        return osc.period_s, ""
    reason = str(osc.reason)
    if reason.startswith("only ") and (osc.regularity or 0.0) >= REGULARITY_THRESHOLD:
        return dominant_period(x, dt), ""
    return None, reason


def cycle_reproduction(data: np.ndarray, replayed: np.ndarray, dt: float) -> CycleReproduction:
    """Compare the cycle of ``replayed`` with that of ``data`` (same samples, sample
    time ``dt`` [s]).  O(n log n) (the autocorrelations)."""
    y = np.asarray(data, dtype=float)
    yr = np.asarray(replayed, dtype=float)
    (t_d, why_d), (t_r, why_r) = _cycle_period(y, dt), _cycle_period(yr, dt)
    a_d, a_r = spread_amplitude(y), spread_amplitude(yr)
    per = _pct_error(t_r, t_d)
    amp = _pct_error(a_r, a_d)
    if t_d is None:
        reason = f"the data do not cycle ({why_d})"
    elif t_r is None:
        reason = f"the replay does not cycle ({why_r})"
    elif per is None or abs(per) > 100.0 * PERIOD_TOLERANCE:
        reason = f"period {_signed(per)} (tolerance {100 * PERIOD_TOLERANCE:.0f} %)"
    elif amp is None or abs(amp) > 100.0 * AMPLITUDE_TOLERANCE:
        reason = f"amplitude {_signed(amp)} (tolerance {100 * AMPLITUDE_TOLERANCE:.0f} %)"
    else:
        reason = ""
    return CycleReproduction(
        period_data_s=t_d,
        period_replay_s=t_r,
        amplitude_data=a_d,
        amplitude_replay=a_r,
        period_error_pct=per,
        amplitude_error_pct=amp,
        reproduced=reason == "",
        reason=reason,
    )
