"""The result of a closed-loop replay: the replayed series, the models and the comparison.

:func:`stictiondiag.replay.closed_loop.replay` fills a :class:`Replay`: the replayed
pv, op and mv, the recorded signals they are compared with (:class:`RecordedSignals`),
the identified process and controller, the agreement per signal
(:class:`ReplayMeasures`) and the simulator's settings (:class:`ReplaySettings`),
each a typed field with its units.  ``Replay.to_dict`` writes them as the ``replay``
entry of ``stiction analyze --json``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.identification.controller import ControllerFit
from stictiondiag.identification.process_result import ProcessFit
from stictiondiag.replay.refit import ClosedLoopRefit


@dataclass(frozen=True, eq=False)
class RecordedSignals:
    """The recorded arrays a replay is compared with, from the replay's first sample.

    Attributes
    ----------
    pv : ndarray
        Process variable [pv units].
    op : ndarray
        Controller output [% of span].
    sp : ndarray
        Setpoint as used by the replay [pv units] (recorded, or constant at mean(pv)).
    mv : ndarray or None
        Valve position [% of span]; None when not recorded.
    mv_model : ndarray or None
        The stiction fit's valve output [% of span]; None when it has none.
    """

    pv: np.ndarray
    op: np.ndarray
    sp: np.ndarray
    mv: np.ndarray | None = None
    mv_model: np.ndarray | None = None

    def pairs(self, replayed) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Signal -> (recorded, replayed) for pv, op and, where recorded, mv; ``replayed``
        has ``pv``, ``op`` and ``mv`` arrays (a replay or its simulation)."""
        out = {"pv": (self.pv, replayed.pv), "op": (self.op, replayed.op)}
        if self.mv is not None:
            out["mv"] = (self.mv, replayed.mv)
        return out


@dataclass(frozen=True)
class SignalMeasures:
    """How one replayed signal agrees with its record.

    Attributes
    ----------
    fit_pct : float or None
        ``100 (1 - NRMSE)`` [%]; None for a constant record.
    nrmse : float or None
        Normalised RMS error of the replay, point by point [-]; None for a constant
        record.
    waveform : float or None
        Correlation of the average cycle shapes [-]; None when either signal has
        fewer than two cycles.
    amplitude_data, amplitude_replay : float
        Half peak-to-peak amplitude of record and replay [units of the signal]: the
        oscillation detector's where the signal oscillates, else half the range
        between the 2nd and 98th percentiles.
    """

    fit_pct: float | None
    nrmse: float | None
    waveform: float | None
    amplitude_data: float
    amplitude_replay: float


@dataclass(frozen=True)
class ReplayMeasures:
    """The replay's agreement with its record, per signal (pv, op and, where recorded, mv).

    Attributes
    ----------
    pv, op : SignalMeasures
    mv : SignalMeasures or None
        None when mv is not recorded.
    """

    pv: SignalMeasures
    op: SignalMeasures
    mv: SignalMeasures | None = None

    def by_signal(self) -> dict[str, SignalMeasures]:
        """Signal -> its measures, in the order pv, op, mv (mv where recorded)."""
        out = {"pv": self.pv, "op": self.op}
        if self.mv is not None:
            out["mv"] = self.mv
        return out

    def to_dict(self) -> dict[str, dict]:
        """``fit`` [%], ``nrmse`` [-], ``waveform`` [-] and ``amplitude`` (``data`` and
        ``replay`` [units of the signal]), each a dict by signal."""
        by = self.by_signal()
        return {
            "fit": {k: m.fit_pct for k, m in by.items()},
            "nrmse": {k: m.nrmse for k, m in by.items()},
            "waveform": {k: m.waveform for k, m in by.items()},
            "amplitude": {
                k: {"data": m.amplitude_data, "replay": m.amplitude_replay} for k, m in by.items()
            },
        }


@dataclass(frozen=True)
class ReplaySettings:
    """The simulator's settings of a replay, derived from the identification, in the
    units of the data.

    Attributes
    ----------
    valve : str
        Data-driven valve model replayed (``choudhury`` or ``kano``).
    process_input : str
        Signal the process was identified from: ``mv``, else ``mv_model``.
    op_bias : float
        The process operating point [% of span].
    pv_bias : float
        pv at the operating point [pv units].
    initial_op, initial_mv : float
        op and mv at the first replayed sample [% of span].
    op_offset : float
        Shift of op and mv into the simulator's 0-100 % [% of span] (0 unless the
        recorded op leaves that range).
    integral_time_simulated_s : float
        Integral time simulated [s] (a very long one for a P-only controller).
    sp_recorded : bool
        The setpoint was recorded (else held at mean(pv)).
    start_sample : int
        First sample of the record replayed [-].
    noise_std : float
        White measurement noise added to the replayed pv [pv units].
    refit : ClosedLoopRefit or None
        The closed-loop refit (:mod:`stictiondiag.replay.refit`), where it was run.
    """

    valve: str
    process_input: str
    op_bias: float
    pv_bias: float
    initial_op: float
    initial_mv: float
    op_offset: float
    integral_time_simulated_s: float
    sp_recorded: bool
    start_sample: int
    noise_std: float
    refit: ClosedLoopRefit | None = None

    def to_dict(self) -> dict:
        """JSON-able dict (``refit`` only where the refit was run)."""
        out = {
            "valve": self.valve,
            "process_input": self.process_input,
            "op_bias": self.op_bias,
            "pv_bias": self.pv_bias,
            "initial_op": self.initial_op,
            "initial_mv": self.initial_mv,
            "op_offset": self.op_offset,
            "integral_time_simulated_s": self.integral_time_simulated_s,
            "sp_recorded": self.sp_recorded,
            "start_sample": self.start_sample,
            "noise_std": self.noise_std,
        }
        if self.refit is not None:
            out["refit"] = self.refit.to_dict()
        return to_plain(out)


@dataclass(frozen=True, eq=False)
class Replay:
    """Closed-loop replay of a recorded loop with the fitted valve (Sections 4.2.2, 5.3).

    Attributes
    ----------
    time : ndarray
        Time [s] from the first sample of the record (the replay starts at
        ``settings.start_sample`` when the fitted valve model starts there).
    sp : ndarray
        Setpoint used [pv units] (recorded, or constant at mean(pv) when missing).
    pv, op, mv : ndarray
        Replayed process variable [pv units], controller output and valve position
        [% of span].
    data : RecordedSignals
        Recorded arrays: pv, op, sp (as used), mv and the stiction fit's valve output
        ``mv_model`` (each None when absent).
    process_fit : ProcessFit
        Identified process (type, gain, time constant [s], dead time [s], biases,
        R^2; ``to_dict`` gives the ``process`` entry of :meth:`to_dict`).
    controller_fit : ControllerFit
        Identified controller (gain, integral time [s], op bias [% of span], R^2;
        ``to_dict`` gives the ``controller`` entry of :meth:`to_dict`).
    measures : ReplayMeasures
        Per signal (pv, op, and mv where recorded): ``100 (1 - NRMSE)`` [%], NRMSE
        [-], correlation of the average cycle shapes [-] and the half peak-to-peak
        amplitudes of record and replay [units of the signal].
    period_data_s, period_replay_s : float or None
        Oscillation period of pv in the record and in the replay [s] (of op when the
        recorded pv does not oscillate, see ``period_signal``); None where not
        oscillating.
    period_signal : str
        Signal whose period is reported.
    S, J : float
        Stiction parameters of the replayed valve [% of span].
    dt : float
        Sample time [s].
    settings : ReplaySettings
        Simulator settings derived from the identification, in the units of the
        data: op bias (the process operating point) and pv bias, initial op and mv,
        valve, ``op_offset`` (shift of op and mv into the simulator's 0-100 % when
        the recorded op leaves that range), ``start_sample``, the closed-loop refit.
    warnings : tuple of str
        One-line notes (inconsistent signs, poor identification, no cycle).
    """

    time: np.ndarray
    sp: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray
    data: RecordedSignals
    process_fit: ProcessFit
    controller_fit: ControllerFit
    measures: ReplayMeasures
    period_data_s: float | None
    period_replay_s: float | None
    period_signal: str
    S: float
    J: float
    dt: float
    settings: ReplaySettings
    warnings: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def period_error_pct(self) -> float | None:
        """Relative period error of the replay, ``100 (replay / data - 1)`` [%]."""
        d, r = self.period_data_s, self.period_replay_s
        if d is None or r is None:
            return None
        return 100.0 * (r / d - 1.0)

    def to_dict(self, include_series: bool = False) -> dict:
        """JSON-able dict: models, measures and, optionally, the time series."""
        measures = self.measures.to_dict()
        out = {
            "process": to_plain(self.process_fit.to_dict()),
            "controller": to_plain(self.controller_fit.to_dict()),
            "S": to_plain(self.S),
            "J": to_plain(self.J),
            "fit": to_plain(measures["fit"]),
            "nrmse": to_plain(measures["nrmse"]),
            "waveform": to_plain(measures["waveform"]),
            "period_s": to_plain({"data": self.period_data_s, "replay": self.period_replay_s}),
            "period_signal": self.period_signal,
            "period_error_pct": to_plain(self.period_error_pct),
            "amplitude": to_plain(measures["amplitude"]),
            "settings": self.settings.to_dict(),
            "warnings": list(self.warnings),
        }
        if include_series:
            out["series"] = {
                name: [to_plain(v) for v in np.asarray(col).tolist()]
                for name, col in self.to_pandas().items()
            }
        return out

    def to_pandas(self):
        """DataFrame: time, sp, replayed pv/op/mv and recorded ``*_data`` columns."""
        import pandas as pd

        cols = {
            "time": self.time,
            "sp": self.sp,
            "pv": self.pv,
            "op": self.op,
            "mv": self.mv,
            "pv_data": self.data.pv,
            "op_data": self.data.op,
        }
        if self.data.mv is not None:
            cols["mv_data"] = self.data.mv
        if self.data.mv_model is not None:
            cols["mv_model"] = self.data.mv_model
        return pd.DataFrame(cols)

    def plot(self, **kwargs):
        """Replay over data: pv, op, mv trends and the mv-op maps of both.

        Keyword arguments go to :func:`stictiondiag.plotting.replay.plot_replay`.
        """
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.replay import plot_replay

        return plot_replay(self, **kwargs)
