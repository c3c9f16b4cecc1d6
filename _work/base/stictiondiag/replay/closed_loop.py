"""Closed-loop replay: the fitted valve in the identified loop, compared with the data.

The paper's argument for the data-driven model (Choudhury, Thornhill & Shah 2005,
Sections 5.3 and 4.2.2) is that, placed in the loop of Eq. 3 / Table 3, it
reproduces the limit cycles seen in plant data (Figs. 3-6 against Figs. 12-15).
:func:`replay` makes that check for one recorded loop:

1. identify the PI controller from ``sp``, ``pv``, ``op``
   (:func:`stictiondiag.identification.controller.identify_controller`);
2. identify the process from the valve position to ``pv``: the recorded ``mv`` when
   there is one, otherwise the fitted valve output ``mv_model`` of the stiction fit
   (:func:`stictiondiag.identification.process.identify_process`);
3. simulate the closed loop with the data-driven valve (S, J of the fit) from the
   recorded setpoint and the recorded initial state
   (:func:`stictiondiag.models.loops.simulate_loop`);
4. compare replay and data, signal by signal.

Start-up
--------
The replay starts from the data's own state:

- the valve: at the first clear extreme of op, where a sticky valve's state is
  known (it slipped on the way there and is stuck when op turns, Figs. 12 and 14).
  Without a recorded mv that is where the stiction fit's valve model starts
  (``fit.details["start_sample"]``), and the replayed valve takes the fit's state
  there: its position, the op at which it stuck (``start_offset`` back from the
  extreme) and the direction of its last movement (``start_direction``), so it
  breaks away where the fitted valve does, J on in the same direction or S back
  (:func:`stictiondiag.models.loops.simulate_loop`, ``initial_stop``).  With mv the
  valve is stuck at the extreme, its last movement the travel into it.  Started
  stuck with no history instead, a valve needs S to move either way and the
  replay's first slip comes late, setting the whole cycle out of phase;
- the controller: op of the first sample, the integral set so it is reproduced;
- the process: its free response from the identified initial state (carried by the
  simulator's ``load`` input, as is any operating point the simulator cannot take
  directly).  Within the first dead time pv answers to inputs from before the
  record, so the replay takes the recorded pv there; where the modelled pv then
  starts away from the record by more than the noise, the difference is carried on
  as an initial state of the process (:func:`_anchor`).

With the true controller and process the replay reproduces noise-free data from the
model to rounding.  Records whose op leaves 0-100 % (scaled data) are replayed with
op and mv shifted into the simulator's range.

The replay is deterministic by default.  Choudhury's model re-arms its stuck band at
every reversal of its input, so in-loop measurement noise keeps it stuck (the paper
asks for an EWMA filter on noisy op, Section 5.1); ``noise_std`` is meant for the
Kano valve.

Comparison measures
-------------------
A stiction limit cycle is self-sustained: its phase drifts freely, so after a few
cycles a perfect model can be half a cycle away from the data.  Point-by-point error
alone would then call a right model wrong, so two kinds of measure are reported:

``fit`` [%] (phase-sensitive)
    ``100 (1 - NRMSE)``, ``NRMSE = ||y - y_replay|| / ||y - mean(y)||``, as in
    system identification's "fit" (100 = exact, 0 = no better than the mean, can be
    negative).  ``nrmse`` holds the NRMSE itself.
``waveform`` [-] (phase-insensitive)
    Correlation of the *average cycle shapes*: each signal is cut into cycles at its
    upward mean crossings (with hysteresis against noise), every cycle is resampled
    to :data:`~stictiondiag.replay.cycles.CYCLE_BINS` points of phase, the cycles are averaged, and the
    correlation of the data's and the replay's average cycle is taken at the best
    circular shift.  1 = same shape; it ignores period, amplitude, offset and phase,
    which are reported separately.
``period_s``, ``amplitude``
    Oscillation period [s] and half peak-to-peak amplitude of each signal from
    :func:`stictiondiag.signals.oscillation.detect_oscillation` (ACF zero crossings,
    Thornhill et al. 2003).  When a signal does not oscillate the amplitude is half
    the range between its 2nd and 98th percentiles, and its period is None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from stictiondiag.core.checks import span_offset
from stictiondiag.core.errors import (
    DataError,
    UsageError,
)
from stictiondiag.core.filters import lfilter1
from stictiondiag.core.robust import second_difference_noise_std
from stictiondiag.core.serialize import to_plain
from stictiondiag.identification.controller import (
    ControllerFit,
    controller_fit,
    identify_controller,
)
from stictiondiag.identification.looptype import StructureEvidence
from stictiondiag.identification.process import (
    ProcessFit,
    drift_pole,
    identify_process,
    process_fit,
)
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import (
    FOPTD,
    PI,
    Integrating,
)
from stictiondiag.replay.cycles import waveform_similarity
from stictiondiag.replay.refit import refine_loop
from stictiondiag.signals.oscillation import detect_oscillation
from stictiondiag.stiction.hammerstein import first_extreme

#: Integral time standing in for "no integral action" in the simulator [x record].
P_ONLY_INTEGRAL_FACTOR = 1.0e6
#: Fewest samples a replay covers.
MIN_REPLAY_SAMPLES = 100
#: The process fit's drift high-pass is at most this many integral times of the
#: identified controller, and at least this many samples [-].
DRIFT_INTEGRAL_TIMES = 10.0
MIN_DRIFT_SAMPLES = 20
#: Identification R^2 below which the replay carries a warning [-].
LOW_FIT_R2 = 0.5

SIGNALS = ("pv", "op", "mv")


@dataclass(frozen=True, eq=False)
class Replay:
    """Closed-loop replay of a recorded loop with the fitted valve (Sections 4.2.2, 5.3).

    Attributes
    ----------
    time : ndarray
        Time [s] from the first sample of the record (the replay starts at
        ``settings["start_sample"]`` when the fitted valve model starts there).
    sp : ndarray
        Setpoint used [pv units] (recorded, or constant at mean(pv) when missing).
    pv, op, mv : ndarray
        Replayed process variable [pv units], controller output and valve position
        [% of span].
    data : dict
        Recorded arrays: ``pv``, ``op``, ``sp`` (as used), ``mv`` (None when not
        recorded), ``mv_model`` (the stiction fit's valve output, or None).
    process : dict
        Identified process (``ProcessFit.to_dict``: type, gain, time constant [s],
        dead time [s], biases, R^2).
    controller : dict
        Identified controller (``ControllerFit.to_dict``: gain, integral time [s],
        op bias [% of span], R^2).
    fit : dict
        Signal -> ``100 (1 - NRMSE)`` [%] of the replay against the data (pv, op, and
        mv where recorded).
    nrmse : dict
        Signal -> NRMSE [-].
    waveform : dict
        Signal -> correlation of the average cycle shapes [-], None when either
        signal has fewer than two cycles.
    period_s : dict
        ``data`` and ``replay`` oscillation period of pv [s] (of op when the recorded
        pv does not oscillate, see ``period_signal``); None where not oscillating.
    period_signal : str
        Signal whose period is reported in ``period_s``.
    amplitude : dict
        Signal -> ``{"data": ..., "replay": ...}`` half peak-to-peak amplitude [units
        of the signal].
    S, J : float
        Stiction parameters of the replayed valve [% of span].
    dt : float
        Sample time [s].
    settings : dict
        Simulator settings derived from the identification, in the units of the
        data: op bias (the process operating point) and pv bias, initial op and mv,
        valve, ``op_offset`` (shift of op and mv into the simulator's 0-100 % when
        the recorded op leaves that range), ``start_sample``.
    process_fit : ProcessFit
    controller_fit : ControllerFit
    warnings : tuple of str
        One-line notes (inconsistent signs, poor identification, no cycle).
    """

    time: np.ndarray
    sp: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray
    data: dict
    process: dict
    controller: dict
    fit: dict
    nrmse: dict
    waveform: dict
    period_s: dict
    period_signal: str
    amplitude: dict
    S: float
    J: float
    dt: float
    settings: dict = field(default_factory=dict)
    process_fit: ProcessFit | None = None
    controller_fit: ControllerFit | None = None
    warnings: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    @property
    def period_error_pct(self) -> float | None:
        """Relative period error of the replay, ``100 (replay / data - 1)`` [%]."""
        d, r = self.period_s.get("data"), self.period_s.get("replay")
        if d is None or r is None:
            return None
        return 100.0 * (r / d - 1.0)

    def to_dict(self, include_series: bool = False) -> dict:
        """JSON-able dict: models, measures and, optionally, the time series."""
        out = {
            "process": to_plain(self.process),
            "controller": to_plain(self.controller),
            "S": to_plain(self.S),
            "J": to_plain(self.J),
            "fit": to_plain(self.fit),
            "nrmse": to_plain(self.nrmse),
            "waveform": to_plain(self.waveform),
            "period_s": to_plain(self.period_s),
            "period_signal": self.period_signal,
            "period_error_pct": to_plain(self.period_error_pct),
            "amplitude": to_plain(self.amplitude),
            "settings": to_plain(self.settings),
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
            "pv_data": self.data["pv"],
            "op_data": self.data["op"],
        }
        if self.data.get("mv") is not None:
            cols["mv_data"] = self.data["mv"]
        if self.data.get("mv_model") is not None:
            cols["mv_model"] = self.data["mv_model"]
        return pd.DataFrame(cols)

    def plot(self, **kwargs):
        """Replay over data: pv, op, mv trends and the mv-op maps of both.

        Keyword arguments go to :func:`stictiondiag.plotting.replay.plot_replay`.
        """
        from stictiondiag.plotting.replay import plot_replay

        return plot_replay(self, **kwargs)


# --------------------------------------------------------------------------- measures


def nrmse(data: np.ndarray, model: np.ndarray) -> float | None:
    """Normalised root-mean-square error ``||y - y_model|| / ||y - mean(y)||`` [-].

    None for a constant ``data`` (the normalisation is zero).
    """
    y = np.asarray(data, dtype=float)
    ym = np.asarray(model, dtype=float)
    den = float(np.linalg.norm(y - y.mean()))
    if den == 0.0 or not math.isfinite(den):
        return None
    return float(np.linalg.norm(y - ym)) / den


def _amplitude(x: np.ndarray, osc) -> float:
    if osc.present and osc.amplitude is not None:
        return float(osc.amplitude)
    lo, hi = np.percentile(x, [2.0, 98.0])
    return float(hi - lo) / 2.0


# --------------------------------------------------------------------------- replay


def _open_loop_like_simulator(
    pf: ProcessFit, u: np.ndarray, dt: float, op_bias: float, pv_bias: float
) -> np.ndarray:
    """Response of the process to ``u`` under the simulator's start-up convention:
    process at rest at ``pv_bias``, dead-time line filled with ``op_bias``."""
    d = pf.dead_time_samples
    x = np.empty(u.size)
    x[: d + 1] = op_bias
    x[d + 1 :] = u[: u.size - d - 1]
    dev = x - op_bias
    if pf.integrating:
        return pv_bias + pf.process.gain * dt * np.cumsum(dev)
    # Not integrating: the process is a FOPTD (see identify_process, process_fit).
    a = math.exp(-dt / cast(FOPTD, pf.process).time_constant)
    y = lfilter1((pf.process.gain * (1.0 - a),), -a, dev)
    return pv_bias + y


#: Samples on each side of the first modelled sample whose mean recorded pv the
#: replay starts from (noise on one sample would otherwise set the start) [-].
ANCHOR_HALF_WIDTH = 2

#: Standard deviations of the noise of that mean within which the identified initial
#: state is kept (a two-sided test at about 0.3 %) [-].
ANCHOR_NOISE_SIGMAS = 3.0


def _anchor(pf: ProcessFit, pv: np.ndarray, model: np.ndarray, warm: int, dt: float) -> np.ndarray:
    """Correction of the load that starts the modelled pv where the record is.

    From the first sample the replay models (``warm``, after the first dead time) the
    process's free response is its identified initial state, fitted over the whole
    record; the record's own pv there can differ by the fit's error at that moment.
    The difference is carried on as the process would carry an initial state: held
    by an integrating process, decaying with the time constant of a FOPTD.  O(n).
    """
    n = pv.size
    if warm >= n:
        return np.zeros(n)
    lo, hi = max(warm - ANCHOR_HALF_WIDTH, 0), min(warm + ANCHOR_HALF_WIDTH + 1, n)
    gap = float(np.mean(pv[lo:hi]) - np.mean(model[lo:hi]))
    out = np.zeros(n)
    # Within the noise of the mean the identified state stands: noise on the record
    # is no evidence that the fit starts in the wrong place.
    if abs(gap) <= ANCHOR_NOISE_SIGMAS * second_difference_noise_std(pv) / math.sqrt(hi - lo):
        return out
    if pf.integrating:
        out[warm:] = gap
    else:
        a = math.exp(-dt / cast(FOPTD, pf.process).time_constant)
        out[warm:] = gap * a ** np.arange(n - warm)
    return out


@dataclass(frozen=True, eq=False)
class _Record:
    """The part of the record the replay covers, from ``start`` on.

    ``pv`` [pv units]; ``op``, ``u`` (the valve position the process is identified
    from: ``mv``, else ``mv_model``), ``mv``, ``mv_model`` [% of span]; ``sp`` [pv
    units] or None; ``dt`` [s]; ``start`` [samples]; ``warnings``; ``stop``: the
    valve's state at the start as the record shows it, the op at which it stuck [%
    of span] and the direction of its last movement (None: unknown).
    """

    pv: np.ndarray
    op: np.ndarray
    u: np.ndarray
    sp: np.ndarray | None
    mv: np.ndarray | None
    mv_model: np.ndarray | None
    dt: float
    start: int
    warnings: tuple[str, ...]
    stop: tuple[float, float] | None = None

    @property
    def n(self) -> int:
        return int(self.pv.size)


@dataclass(frozen=True, eq=False)
class _Simulated:
    """The replayed loop: pv [pv units], op and mv [% of span] in the units of the
    data, the setpoint used, and the simulator settings of :attr:`Replay.settings`."""

    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray
    sp: np.ndarray
    settings: dict


def _replay_record(tags, fit) -> _Record:
    """Step 0: the recorded arrays, and where the replay starts.

    A fitted valve output may be defined only from some sample on (the fit starts
    its valve at a known state, e.g. the first extreme of op, and holds it before):
    without a recorded mv, the replay covers that part of the record only.  With a
    recorded mv the simulated valve starts stuck where op turns (the state a sticky
    valve is known to be in there): started anywhere else, it would forget how far
    op had already travelled towards the next slip.  O(n log n) (the oscillation of
    op, with mv).
    """

    dt = float(tags.ts)
    pv = np.asarray(tags.pv, dtype=float)
    op = np.asarray(tags.op, dtype=float)
    n = pv.size
    mv_rec = None if getattr(tags, "mv", None) is None else np.asarray(tags.mv, dtype=float)
    sp_rec = None if getattr(tags, "sp", None) is None else np.asarray(tags.sp, dtype=float)
    mv_model = getattr(fit, "mv_model", None)
    mv_model = None if mv_model is None else np.asarray(mv_model, dtype=float)
    S, J = float(fit.S), float(fit.J)
    if not (math.isfinite(S) and math.isfinite(J)):
        raise DataError("the stiction fit has no finite S and J: nothing to replay")
    u = mv_rec if mv_rec is not None else mv_model
    if u is None or u.size != n:
        raise DataError("replay needs the valve position: record mv or pass a fit with mv_model")
    warnings: list[str] = []
    start, direction, back = 0, 0.0, 0.0
    why = "where the fitted valve model starts"
    if mv_rec is None:
        details = getattr(fit, "details", None)
        if isinstance(details, dict):
            start = int(details.get("start_sample") or 0)
            direction = float(details.get("start_direction") or 0.0)
            back = max(float(details.get("start_offset") or 0.0), 0.0)
    elif S > 0.0:
        osc_op = detect_oscillation(op, dt)
        if osc_op.present and osc_op.period_s:
            start, direction = first_extreme(op, max(4, int(round(osc_op.period_s / dt))))
            why = "the first extreme of op, where the sticky valve's state is known"
    if not 0 <= start <= n - MIN_REPLAY_SAMPLES:
        start, direction = 0, 0.0
    # The valve's own state there: stuck since op was ``back`` before the extreme,
    # its last movement in the direction of travel into it (the fit's start state,
    # stictiondiag.stiction.valvefit.valve_run).
    stop = (float(op[start]) - direction * back, direction) if direction else None
    if start > 0:
        pv, op, u = pv[start:], op[start:], u[start:]
        sp_rec = None if sp_rec is None else sp_rec[start:]
        mv_rec = None if mv_rec is None else mv_rec[start:]
        mv_model = None if mv_model is None else mv_model[start:]
        if mv_rec is None:  # with mv, settings["start_sample"] records it
            warnings.append(f"replay starts at sample {start}, {why}")
    return _Record(pv, op, u, sp_rec, mv_rec, mv_model, dt, start, tuple(warnings), stop)


def _replay_models(
    rec: _Record,
    controller,
    process,
    integrating: bool | None,
    action: str | None = None,
    known: StructureEvidence | None = None,
) -> tuple[ControllerFit, ProcessFit, list[str]]:
    """Steps 1 and 2: the PI controller from sp, pv, op and the process from the
    valve position to pv (given, completed from the data, or identified), with
    notes on a poor identification or inconsistent signs.  ``known``: the fits of
    the loop-type step, used where they are the very identification this step
    would make (the same samples and settings: the replay starts at sample 0, and
    for the process mv is recorded and no drift high-pass is imposed).  O(n log n): the
    controller is O(n), the process fit O(n log n) with a number of O(n) cost
    evaluations that does not grow with the record (its search ranges follow the
    loop's period, :func:`stictiondiag.identification.process.search_span`)."""
    warnings: list[str] = []
    pv, op, dt = rec.pv, rec.op, rec.dt
    same_samples = known is not None and rec.start == 0
    if controller is None:
        if same_samples and known is not None and known.controller is not None:
            cf = known.controller
        else:
            cf = identify_controller(rec.sp, pv, op, dt)
    elif isinstance(controller, ControllerFit):
        cf = controller
    else:
        cf = controller_fit(controller, rec.sp, pv, op, dt)
    if action is not None and controller is None:
        # The declared action fixes the controller's sign (e = sp - pv: reverse Kc > 0,
        # direct Kc < 0); an identification of the other sign keeps its size only.
        sign = -1.0 if action == "direct" else 1.0
        if cf.controller.gain * sign < 0:
            flipped = PI(gain=-cf.controller.gain, integral_time=cf.controller.integral_time)
            cf = controller_fit(flipped, rec.sp, pv, op, dt)
            warnings.append(
                f"identified controller gain has the sign of the other action; the declared "
                f"{action} action is used (Kc = {cf.controller.gain:.3g})"
            )
    if cf.sp_assumed:
        warnings.append("no setpoint recorded: taken as constant at the mean of pv")
    if process is None:
        # The loop rejects disturbances slower than some integral times; pv drifts
        # on that scale are the load's, not the process's (identification/process.py, drift
        # high-pass), so the high-pass is no slower than that.
        drift = None
        ti_c = cf.controller.integral_time
        if math.isfinite(ti_c):
            _, default_T = drift_pole(pv, dt, None)
            if default_T is not None and DRIFT_INTEGRAL_TIMES * ti_c < default_T:
                drift = max(DRIFT_INTEGRAL_TIMES * ti_c, MIN_DRIFT_SAMPLES * dt)
        reuse = None
        if same_samples and known is not None and known.u_signal == "mv" and rec.mv is not None:
            if drift is None and integrating is not None:
                reuse = known.processes.get(bool(integrating))
        pf = reuse or identify_process(
            rec.u, pv, dt, integrating=integrating, drift_time_constant=drift
        )
    elif isinstance(process, ProcessFit):
        pf = process
    else:
        pf = process_fit(process, rec.u, pv, dt)
    for what, r2 in (("controller", cf.fit_r2), ("process", pf.fit_r2)):
        if r2 is not None and math.isfinite(r2) and r2 < LOW_FIT_R2:
            warnings.append(f"{what} identification explains little of the data (R^2 = {r2:.2f})")
    if cf.controller.gain * pf.process.gain < 0:
        warnings.append(
            "controller and process gains have opposite signs (positive feedback): "
            "the replay is unstable; check the sign convention of op and pv"
        )
    return cf, pf, warnings


def _replay_simulate(
    rec: _Record,
    cf: ControllerFit,
    pf: ProcessFit,
    S: float,
    J: float,
    valve: str,
    noise_std: float,
    seed: int | None,
) -> _Simulated:
    """Step 3: the closed loop with the data-driven valve from the recorded state
    (see "Start-up" in the module docstring).  O(n)."""

    pv, op, u, dt, n = rec.pv, rec.op, rec.u, rec.dt, rec.n
    kc, gain = cf.controller.gain, pf.process.gain
    # The simulator's op lives in [0, 100] % of span.  Data whose op leaves that
    # range (scaled or mean-centred records) are replayed with op and mv shifted
    # into it: the valve model and the linear blocks do not care about an offset,
    # the clamp at 0 and 100 % is then out of the way.
    offset = span_offset(op, u)
    # The process operating point is the identification's input reference; one
    # outside the span is clipped and the difference carried by the load, which also
    # carries the free response of the recorded initial state (the simulator starts
    # the process at rest, its dead-time line filled with the operating point).
    op_bias_sim = float(np.clip(pf.u_bias + offset, 0.0, 100.0))
    ref = op_bias_sim - offset  # the operating point in the units of the data
    if pf.integrating:
        pv_bias_sim = pf.pv_bias
    else:
        pv_bias_sim = pf.pv_bias + gain * (ref - pf.u_bias)
    free = _open_loop_like_simulator(pf, u, dt, ref, pv_bias_sim)
    modelled = pf.simulate(u, dt)
    load = modelled - free
    # Within the first dead time pv answers to inputs from before the record, which
    # the replay cannot know: it takes the recorded pv there.
    warm = min(pf.dead_time_samples + 1, n)
    load[:warm] = pv[:warm] - free[:warm]
    load += _anchor(pf, pv, modelled, warm, dt)
    sp_used = rec.sp if rec.sp is not None else np.full(n, float(pv.mean()))
    ti = cf.controller.integral_time
    op0 = float(np.clip(op[0] + offset, 0.0, 100.0)) - offset
    e0 = float(sp_used[0] - (pv_bias_sim + load[0]))
    if math.isinf(ti):
        # P-only: the simulator needs a finite Ti; a very long one with the integral
        # set to give the identified manual reset acts as a pure gain.
        ti = P_ONLY_INTEGRAL_FACTOR * max(n * dt, dt)
        initial_integral = ti * (cf.op_bias - ref) / kc
    else:
        # The recorded op[0] already holds the first sample's integration step, which
        # the simulator adds before computing its first output.
        initial_integral = ti * ((op0 - ref) / kc - e0) - e0 * dt
    sim = simulate_loop(
        pf.process,
        PI(gain=kc, integral_time=ti),
        duration=n * dt,
        dt=dt,
        valve=valve,
        S=S,
        J=J,
        sp=sp_used,
        load=load,
        op_bias=op_bias_sim,
        pv_bias=pv_bias_sim,
        initial_op=op0 + offset,
        initial_mv=float(np.clip(u[0] + offset, 0.0, 100.0)),
        initial_integral=initial_integral,
        initial_stop=None if rec.stop is None else (rec.stop[0] + offset, rec.stop[1]),
        noise_std=noise_std,
        seed=seed,
        pv_filter_time=cf.pv_filter_time,
    )
    settings = {
        "valve": valve,
        "process_input": "mv" if rec.mv is not None else "mv_model",
        "op_bias": ref,
        "pv_bias": pv_bias_sim,
        "initial_op": float(sim.settings["initial_op"]) - offset,
        "initial_mv": float(sim.settings["initial_mv"]) - offset,
        "op_offset": offset,
        "integral_time_simulated_s": ti,
        "sp_recorded": rec.sp is not None,
        "start_sample": rec.start,
        "noise_std": float(noise_std),
    }
    return _Simulated(sim.pv[:n], sim.op[:n] - offset, sim.mv[:n] - offset, sp_used, settings)


def _replay_compare(rec: _Record, sim: _Simulated) -> dict[str, Any]:
    """Step 4: fit, NRMSE, waveform, amplitude per signal and the period of pv (of
    op when the recorded pv does not oscillate).  O(n log n) (the autocorrelations)."""

    pairs = {"pv": (rec.pv, sim.pv), "op": (rec.op, sim.op)}
    if rec.mv is not None:
        pairs["mv"] = (rec.mv, sim.mv)
    fit_pct: dict[str, float | None] = {}
    err: dict[str, float | None] = {}
    shape: dict[str, float | None] = {}
    amplitude: dict[str, dict] = {}
    osc: dict[str, tuple] = {}
    for name, (y, yr) in pairs.items():
        e = nrmse(y, yr)
        err[name] = e
        fit_pct[name] = None if e is None else 100.0 * (1.0 - e)
        shape[name] = waveform_similarity(y, yr)
        od, orp = detect_oscillation(y, rec.dt), detect_oscillation(yr, rec.dt)
        osc[name] = (od, orp)
        amplitude[name] = {"data": _amplitude(y, od), "replay": _amplitude(yr, orp)}
    period_signal = "pv"
    if not osc["pv"][0].present and osc["op"][0].present:
        period_signal = "op"
    od, orp = osc[period_signal]
    warnings = []
    if od.present and not orp.present:
        warnings.append(f"the data oscillate but the replay does not ({orp.reason})")
    return {
        "fit": fit_pct,
        "nrmse": err,
        "waveform": shape,
        "period_s": {"data": od.period_s, "replay": orp.period_s},
        "period_signal": period_signal,
        "amplitude": amplitude,
        "warnings": warnings,
    }


def replay(
    tags,
    fit,
    *,
    controller: PI | ControllerFit | None = None,
    process: FOPTD | Integrating | ProcessFit | None = None,
    integrating: bool | None = None,
    valve: str = "choudhury",
    noise_std: float = 0.0,
    seed: int | None = 0,
    refit: bool = True,
    action: str | None = None,
    known: StructureEvidence | None = None,
) -> Replay:
    """Replay a recorded loop with the fitted valve and compare with the data.

    The steps of the module docstring, one function each: the record and where
    the replay starts (:func:`_replay_record`), the controller and the process
    (:func:`_replay_models`), the closed-loop simulation (:func:`_replay_simulate`)
    and the comparison (:func:`_replay_compare`).  Cost O(n log n) in the record
    length n besides the identification (the autocorrelations of the comparison;
    every other step of this module is O(n)).

    Parameters
    ----------
    tags : Tags
        Recorded loop (anything with ``pv``, ``op``, ``mv``, ``sp``, ``ts``).
    fit : StictionFit
        Stiction fit (anything with ``S``, ``J`` [% of span] and ``mv_model``).
    controller : PI or ControllerFit, optional
        Controller to use; identified from the data when None.  A bare PI gets its
        op bias estimated from the data.
    process : FOPTD, Integrating or ProcessFit, optional
        Process to use; identified (from mv, or from ``fit.mv_model``) when None.
    integrating : bool or None
        Process structure for the identification; None chooses by fit.
    valve : {"choudhury", "kano"}
        Data-driven valve model of the replay (Section 5.1; Kano et al. 2004).
    noise_std : float
        White measurement noise added to the replayed pv [pv units]; 0 replays the
        deterministic loop.  Choudhury's model needs a smooth input (Section 5.1
        asks for an EWMA filter on noisy op), so use ``valve="kano"`` with noise.
    seed : int, optional
        Seed of the replay noise.
    refit : bool
        Refine S, J and the process by closed-loop simulation when the open-loop
        fit's replay does not reproduce the recorded cycle
        (:mod:`stictiondiag.replay.refit`; at most 60 more O(n) simulations).  The
        replay then uses the refitted loop; ``settings["refit"]`` holds both.
    action : {"direct", "reverse"}, optional
        Declared controller action: fixes the sign of the identified controller gain.
    known : StructureEvidence, optional
        The controller and process fits of the loop-type step
        (:func:`stictiondiag.identification.looptype.identify_structure`), reused
        where they are the identification this replay would make.

    Returns
    -------
    Replay
        Replayed series, identified models and the comparison measures (see the
        module docstring).

    Raises
    ------
    DataError
        The data do not allow the identification.
    UsageError
        Bad arguments.
    """
    if valve not in ("choudhury", "kano"):
        raise UsageError(f"replay valve must be choudhury or kano, got {valve!r}")
    rec = _replay_record(tags, fit)
    S, J = float(fit.S), float(fit.J)
    cf, pf, model_warnings = _replay_models(rec, controller, process, integrating, action, known)
    refit_result = None
    if refit and noise_std == 0.0 and process is None:
        refit_result, pf = refine_loop(
            rec,
            pf,
            S,
            J,
            lambda p, s, j: _replay_simulate(rec, cf, p, s, j, valve, 0.0, seed),
            controller=cf.controller,
        )
        S, J = refit_result.S, refit_result.J
    sim = _replay_simulate(rec, cf, pf, S, J, valve, noise_std, seed)
    if refit_result is not None:
        sim.settings["refit"] = refit_result.to_dict()
    measures = _replay_compare(rec, sim)
    data = {"pv": rec.pv, "op": rec.op, "sp": sim.sp, "mv": rec.mv, "mv_model": rec.mv_model}
    return Replay(
        time=(rec.start + np.arange(rec.n)) * rec.dt,
        sp=sim.sp,
        pv=sim.pv,
        op=sim.op,
        mv=sim.mv,
        data=data,
        process=pf.to_dict(),
        controller=cf.to_dict(),
        fit=measures["fit"],
        nrmse=measures["nrmse"],
        waveform=measures["waveform"],
        period_s=measures["period_s"],
        period_signal=measures["period_signal"],
        amplitude=measures["amplitude"],
        S=S,
        J=J,
        dt=rec.dt,
        settings=sim.settings,
        process_fit=pf,
        controller_fit=cf,
        warnings=(*rec.warnings, *model_warnings, *measures["warnings"]),
    )
