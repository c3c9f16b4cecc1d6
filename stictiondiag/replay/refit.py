"""Closed-loop refit: the fitted loop adjusted until its replay reproduces the data's cycle.

The open-loop fit (S and J of the valve, Section 5.1; the process from the valve
position to pv) is made one block at a time: each block is fitted with the recorded
input of the next.  Small errors of each block add up in the loop, and a stiction
limit cycle is sensitive to them: the phase of the loop at the cycle's frequency
sets the period, and the balance of the valve's describing function against the
loop's gain (Section 6, Eq. 5) decides whether the cycle is sustained at all.  A
loop whose blocks each fit well (R^2 0.99) can thus replay a decaying transient
instead of the recorded cycle.

:func:`refit_closed_loop` takes the open-loop fit as its first step and refines, by
simulating the closed loop (:func:`stictiondiag.models.loops.simulate_loop`, from
the data's own state, as the replay does), the valve's S and J and the process's
gain, time constant and dead time so that the replay's cycle matches the data's:

    cost = w_T log(T_replay / T_data)^2 + log(A_pv replay / A_pv data)^2
           + log(A_op replay / A_op data)^2 [+ log(A_mv replay / A_mv data)^2]
           + (1 - waveform_pv)

with ``T`` the period of pv by the autocorrelation (Thornhill et al. 2003, as the
replay reports it; :func:`recorded_cycle`), ``A``
half the 5-95 % spread of the signal less its running mean over three recorded
periods (:func:`cycle_spread`: a drift or a load slow against the cycle is left
out), data and replay compared over the whole record and over its second half,
the worse of the two counting (a start-up transient and a decaying
replay both cost what their amplitude costs, which leads the search towards the
recorded, sustained cycle), and ``waveform`` the correlation of the average cycle
shapes (:func:`stictiondiag.replay.cycles.waveform_similarity`); the mv term
only where mv is recorded.  A replay
that does not cycle costs :data:`NO_CYCLE_COST` on top of its amplitudes.

The controller is not refitted: it is measured directly from the recorded sp, pv
and op (no block's model output enters it), so the loop's error lies in the valve
and the process.  With a recorded mv, S and J are measured from the valve's own
stick and slip segments (Figs. 3 and 6) and are kept too: the process alone is
refined.

Starts: the open-loop fit, and the describing function's predictions
(:func:`df_starts`, Section 6): for each case of Section 5.1 (deadband, undershoot,
no offset, overshoot) the J/S whose predicted cycle has the period nearest the
recorded one, S scaled so that the predicted op amplitude is the recorded one.  S
is thus seeded from op's swing, not from the open-loop fit: a fit with S near 0, or
one whose replay settles, sits in a basin where no small step cycles, and the
search could not leave it from there.  The starts hold the process gain at the
controller's sign (a loop cycling about its set point has negative feedback), and
where no ratio predicts the recorded period within about 10 %, one more start moves
the process's dead time to where the phase condition of Eq. 5 meets it.  Each start
is simulated once; the search starts from the best of all.

Search: a compass search in the logarithms of S, J + j0 (``j0`` a small floor so a
zero J can grow), the process gain and time constant, and in the dead time [samples],
from the best start, each step tried up and down, halved when no step helps,
stopped after :data:`MAX_SIMULATIONS` simulations or when the steps are below
:data:`MIN_STEP`.  The refit is kept only when it lowers the cost by
:data:`MIN_IMPROVEMENT`; otherwise the open-loop fit stands.

Cost: at most :data:`MAX_SIMULATIONS` + 2 closed-loop simulations (the starts, at
most five, and the search share :data:`MAX_SIMULATIONS`; two more check that an
accepted refit cycles wherever the open-loop fit did), each O(n) in the record
length n, and the cycle measures of each: the autocorrelation's period, O(n log n)
by FFT, everything else O(n).  Linear in n up to that logarithm.  The starts add
at most 9 + 15 describing-function solutions on coarse grids, whose cost does not
depend on n.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.core.serialize import to_plain
from stictiondiag.identification.numerics import r_squared
from stictiondiag.identification.process_result import OutputErrorFit, ProcessFit
from stictiondiag.models.describing import predict_limit_cycle
from stictiondiag.models.processes import FOPTD, PI, Integrating, open_loop_response
from stictiondiag.replay.cycles import _up_crossings, waveform_similarity
from stictiondiag.replay.metrics import _cycle_period
from stictiondiag.signals.oscillation import _detrend_by_cycles

#: Weight ``w_T`` of the period's term against the amplitudes' [-].  The period of a
#: limit cycle is measured over all its cycles, to a few per cent; an amplitude
#: carries the noise, the quantisation and the unmodelled effects of the data, ten
#: per cent and more: weights as the inverse squared uncertainties, (10/3)^2.
PERIOD_WEIGHT = 10.0
#: Most closed-loop simulations of one refit [-].
MAX_SIMULATIONS = 60
#: Initial step of the compass search in log units (a factor of e^0.5 = 1.65) [-].
INITIAL_STEP = 0.5
#: Smallest step [log units]; the search stops below it [-].
MIN_STEP = 0.06
#: Relative cost reduction a refit must bring to replace the open-loop fit [-].
MIN_IMPROVEMENT = 0.1
#: Cost added when the replay does not cycle [-] (a period off by a factor of 2).
NO_CYCLE_COST = 2.0 * math.log(2.0) ** 2  # a period off by a factor of 2 at w_T = 2
#: A replay whose cost is below this already reproduces the cycle; no refit [-]
#: (period within about 3 %, amplitudes within about 4 %).
GOOD_ENOUGH_COST = 0.002
#: Floor added to J before taking its logarithm, as a fraction of S [-].
J_FLOOR_FRACTION = 0.05
#: Hysteresis of the crossing counter, as a fraction of the standard deviation [-].
HYSTERESIS = 0.25
#: Late cycles smaller than this fraction of the early ones: the cycle decays [-].
SUSTAIN_RATIO = 0.3


@dataclass(frozen=True)
class CycleStats:
    """Period [s] (None when the signal does not cycle) and amplitude (half the
    5-95 % spread, units of the signal) of one signal."""

    period_s: float | None
    amplitude: float


def cycle_stats(x: np.ndarray, dt: float) -> CycleStats:
    """Period and amplitude of a cycling signal, O(n) besides the percentiles.

    The period is the median spacing of the upward crossings of the linearly
    detrended signal (hysteresis :data:`HYSTERESIS` standard deviations); the
    signal cycles when it has three crossings at least and its last third's
    swing is at least :data:`SUSTAIN_RATIO` of its first third's.
    """

    y = np.asarray(x, dtype=float)
    lo, hi = np.percentile(y, (5.0, 95.0))
    amplitude = float(hi - lo) / 2.0
    k = np.arange(y.size)
    yd = y - np.polyval(np.polyfit(k, y, 1), k)
    sd = float(yd.std())
    if sd == 0.0:
        return CycleStats(None, amplitude)
    ups = _up_crossings(yd, HYSTERESIS * sd)
    if ups.size < 3:
        return CycleStats(None, amplitude)
    third = y.size // 3
    early, late = float(np.ptp(yd[:third])), float(np.ptp(yd[-third:]))
    if early > 0 and late < SUSTAIN_RATIO * early:
        return CycleStats(None, amplitude)
    return CycleStats(float(np.median(np.diff(ups))) * dt, amplitude)


def recorded_cycle(x: np.ndarray, dt: float) -> CycleStats:
    """:func:`cycle_stats` with the period by the autocorrelation (Thornhill et al.
    2003, as the replay reports it) where the signal has one: a plant's cycles vary
    in length, and the median spacing of their crossings can differ from the
    autocorrelation's period by several per cent; data and replay are measured
    alike.  O(n log n) (the FFT)."""

    st = cycle_stats(x, dt)
    period, _ = _cycle_period(x, dt)
    return CycleStats(period if period is not None else st.period_s, st.amplitude)


@dataclass(frozen=True)
class LoopParameters:
    """The refined part of the loop: S, J [% of span] and the process."""

    S: float
    J: float
    process: FOPTD | Integrating


@dataclass(frozen=True)
class ClosedLoopRefit:
    """Result of :func:`refit_closed_loop`.

    Attributes
    ----------
    S_open_loop, J_open_loop : float
        The open-loop fit's S and J [% of span].
    S, J : float
        The refitted S and J [% of span] (the open-loop ones when not ``accepted``).
    process_open_loop, process : FOPTD or Integrating
        The process before and after: gain [pv units / % of span] (integrating: per
        second), time constant [s], dead time [s].
    cost_open_loop, cost : float
        Cycle mismatch of the replay (module docstring) before and after [-].
    accepted : bool
        The refit lowered the cost enough to replace the open-loop fit.
    simulations : int
        Closed-loop simulations run [-].
    reason : str
        Why the refit was or was not run or kept, in words.
    """

    S_open_loop: float
    J_open_loop: float
    S: float
    J: float
    process_open_loop: FOPTD | Integrating
    process: FOPTD | Integrating
    cost_open_loop: float
    cost: float
    accepted: bool
    simulations: int
    reason: str = ""
    terms: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-able dict."""

        return {
            "S_open_loop": to_plain(self.S_open_loop),
            "J_open_loop": to_plain(self.J_open_loop),
            "S": to_plain(self.S),
            "J": to_plain(self.J),
            "process_open_loop": to_plain(self.process_open_loop.to_dict()),
            "process": to_plain(self.process.to_dict()),
            "cost_open_loop": to_plain(self.cost_open_loop),
            "cost": to_plain(self.cost),
            "accepted": bool(self.accepted),
            "simulations": int(self.simulations),
            "reason": self.reason,
            "terms": to_plain(self.terms),
        }


def cycle_spread(x: np.ndarray, period_s: float | None, dt: float) -> float:
    """Half the 5-95 % spread of ``x`` less its running mean over three periods
    (a drift or a load that is slow against the cycle is left out; measurement
    noise weighs as it does in the spread of the data) [units of x]; O(n) besides
    the percentiles.  Without a period, of ``x`` less its mean."""

    y = np.asarray(x, dtype=float)
    if y.size < 4:
        return 0.0
    if period_s is not None and period_s > 0:
        y = _detrend_by_cycles(y, period_s / dt)
    lo, hi = np.percentile(y, (5.0, 95.0))
    return float(hi - lo) / 2.0


def cycle_cost(
    pv: np.ndarray,
    op: np.ndarray,
    pv_r: np.ndarray,
    op_r: np.ndarray,
    dt: float,
    data: tuple[CycleStats, CycleStats] | None = None,
    mv: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[float, dict]:
    """Cycle mismatch of a replay (module docstring) and its terms; ``mv`` (recorded,
    replayed) adds the amplitude term of a recorded valve position.  O(n log n)."""

    d_pv = data[0] if data is not None else recorded_cycle(pv, dt)
    r_pv = recorded_cycle(pv_r, dt)
    terms = {}
    pairs = [("amplitude_pv", pv, pv_r), ("amplitude_op", op, op_r)]
    if mv is not None:
        pairs.append(("amplitude_mv", mv[0], mv[1]))
    for name, y, yr in pairs:
        y, yr = np.asarray(y, dtype=float), np.asarray(yr, dtype=float)
        h = y.size // 2
        worst = 0.0
        for a, b in ((y, yr), (y[h:], yr[h:])):  # the whole record, its second half
            d = cycle_spread(a, d_pv.period_s, dt)
            r = cycle_spread(b, d_pv.period_s, dt)
            if d > 0:
                worst = max(worst, math.log(max(r, 1e-9 * d) / d) ** 2)
        terms[name] = worst
    if d_pv.period_s is None or r_pv.period_s is None:
        terms["period"] = NO_CYCLE_COST
        terms["waveform"] = 1.0
    else:
        terms["period"] = PERIOD_WEIGHT * math.log(r_pv.period_s / d_pv.period_s) ** 2
        w = waveform_similarity(pv, pv_r)
        terms["waveform"] = 1.0 if w is None else 1.0 - w
    return float(sum(terms.values())), terms


def _to_vector(p: LoopParameters, j0: float, dt: float) -> np.ndarray:
    proc = p.process
    tau = proc.time_constant if isinstance(proc, FOPTD) else 1.0
    return np.array(
        [
            math.log(max(p.S, 1e-6)),
            math.log(p.J + j0),
            math.log(abs(proc.gain)),
            math.log(tau),
            proc.dead_time / dt,
        ]
    )


def _from_vector(v: np.ndarray, template: LoopParameters, j0: float, dt: float) -> LoopParameters:
    proc = template.process
    sign = 1.0 if proc.gain > 0 else -1.0
    dead = max(0.0, round(float(v[4]))) * dt
    if isinstance(proc, FOPTD):
        new: FOPTD | Integrating = FOPTD(
            gain=sign * math.exp(v[2]), time_constant=math.exp(v[3]), dead_time=dead
        )
    else:
        new = Integrating(gain=sign * math.exp(v[2]), dead_time=dead)
    return LoopParameters(S=math.exp(v[0]), J=max(0.0, math.exp(v[1]) - j0), process=new)


def _steps(p: LoopParameters, dt: float, valve_fixed: bool) -> np.ndarray:
    """Initial step per coordinate: log units, and samples for the dead time."""
    d = p.process.dead_time / dt
    tau_step = INITIAL_STEP if isinstance(p.process, FOPTD) else 0.0
    sj_step = 0.0 if valve_fixed else INITIAL_STEP
    return np.array([sj_step, sj_step, INITIAL_STEP, tau_step, max(1.0, 0.5 * d)])


def refit_closed_loop(
    start: LoopParameters,
    evaluate: Callable[[LoopParameters], tuple[float, dict]],
    dt: float,
    *,
    valve_fixed: bool = False,
    candidates: tuple[LoopParameters, ...] = (),
) -> ClosedLoopRefit:
    """Refine S, J and the process from ``start`` until the replay's cycle matches.

    ``evaluate`` simulates the loop with the given parameters from the data's own
    state and returns :func:`cycle_cost` of the replay; it is called at most
    :data:`MAX_SIMULATIONS` times (each O(n)).  ``valve_fixed`` keeps S and J
    (measured from a recorded mv) and refines the process alone.  ``candidates``
    are further starting points (the describing function's, :func:`df_starts`): each
    is put on the search's grid, simulated once, and the search starts from the best of all.  See the module
    docstring.
    """
    j0 = J_FLOOR_FRACTION * max(start.S, 0.1)
    cost0, terms0 = evaluate(start)
    sims = 1
    base = _done(start, start, cost0, cost0, terms0, sims, False, "")
    if not math.isfinite(cost0):
        return replace(base, reason="the open-loop fit's replay could not be measured")
    if cost0 <= GOOD_ENOUGH_COST:
        return replace(base, reason="the open-loop fit's replay reproduces the cycle already")
    x = _to_vector(start, j0, dt)
    step = _steps(start, dt, valve_fixed)
    best, best_terms = cost0, terms0
    template = start  # the process structure and gain sign the search keeps
    for cand in candidates:
        # On the search's grid (the dead time in whole samples), so that the start
        # simulated is the one the search and the result hold.
        cand = _from_vector(_to_vector(cand, j0, dt), cand, j0, dt)
        c, t = evaluate(cand)
        sims += 1
        if math.isfinite(c) and c < best:
            x, best, best_terms, template = _to_vector(cand, j0, dt), c, t, cand
    while sims < MAX_SIMULATIONS:
        improved = False
        for i in range(x.size):
            if step[i] == 0.0 or sims >= MAX_SIMULATIONS:
                continue
            for sgn in (1.0, -1.0):
                trial = x.copy()
                trial[i] += sgn * step[i]
                if i == 4 and trial[4] < -0.5:
                    continue
                c, t = evaluate(_from_vector(trial, template, j0, dt))
                sims += 1
                if math.isfinite(c) and c < best:
                    x, best, best_terms, improved = trial, c, t, True
                    break
                if sims >= MAX_SIMULATIONS:
                    break
        if not improved:
            step = step / 2.0
            step[4] = float(round(step[4])) if step[4] >= 1.0 else 0.0
            if np.all(step[:4] < MIN_STEP) and step[4] == 0.0:
                break
    found = _from_vector(x, template, j0, dt)
    if valve_fixed:  # exactly the measured S and J, not their round trip through logs
        found = replace(found, S=start.S, J=start.J)
    accepted = best < (1.0 - MIN_IMPROVEMENT) * cost0
    reason = (
        f"the closed-loop refit lowers the cycle mismatch from {cost0:.3g} to {best:.3g}"
        if accepted
        else f"no refit lowers the cycle mismatch ({cost0:.3g}) by {100 * MIN_IMPROVEMENT:.0f} %"
    )
    return _done(
        start,
        found if accepted else start,
        cost0,
        best if accepted else cost0,
        best_terms if accepted else terms0,
        sims,
        accepted,
        reason,
    )


def _done(start, found, cost0, cost, terms, sims, accepted, reason) -> ClosedLoopRefit:
    return ClosedLoopRefit(
        S_open_loop=start.S,
        J_open_loop=start.J,
        S=found.S,
        J=found.J,
        process_open_loop=start.process,
        process=found.process,
        cost_open_loop=cost0,
        cost=cost,
        accepted=accepted,
        simulations=sims,
        reason=reason,
        terms=terms,
    )


#: Ratios J/S the describing-function starts try [-] (Section 6: the period of the
#: predicted cycle depends on J/S alone, its amplitude scales with S), grouped by the
#: cases of Section 5.1: deadband (J = 0), undershoot (J < S), no offset (J = S) and
#: overshoot (J > S).
DF_CASES: dict[str, tuple[float, ...]] = {
    "deadband": (0.0,),
    "undershoot": (0.1, 0.25, 0.5, 0.75),
    "no offset": (1.0,),
    "overshoot": (1.5, 2.0),
}
#: All ratios, in order [-].
DF_RATIOS = tuple(r for case in DF_CASES.values() for r in case)
#: When the best describing-function start's predicted period misses the recorded
#: one by more than this (log units, about 10 %), one more start has the dead time
#: moved to where the phase condition meets the recorded period [-].
PHASE_MISS = 0.1


@dataclass(frozen=True)
class Cycle:
    """A stable cycle the describing function predicts: period [s], angular
    frequency [rad/s] and op amplitude X_m [% of span]."""

    period_s: float
    frequency_rad_s: float
    amplitude_op: float


def _predict(process, controller: PI, ratio: float) -> Cycle | None:
    """The describing function's stable cycle at S = 1, J = ``ratio`` (period [s],
    op amplitude X_m [% of span]), or None."""
    try:
        pred = predict_limit_cycle(
            process, controller, 1.0, ratio, n_amplitudes=120, n_frequencies=3000
        )
    except (StictionError, ArithmeticError, ValueError):
        return None
    if not (pred.limit_cycle and pred.stable and pred.period_s and pred.amplitude_op):
        return None
    return Cycle(float(pred.period_s), float(pred.frequency_rad_s or 0.0), float(pred.amplitude_op))


def _phase_shift(process, controller: PI, w_pred: float, w_rec: float) -> float | None:
    """Dead time to add [s] so that the loop's phase at the recorded frequency
    ``w_rec`` is the phase it has at the predicted one ``w_pred`` (Eq. 5's phase
    condition then meets the recorded period at about the same ``-1/N``): a dead
    time ``d`` adds ``-w d`` to the phase.  None when no dead time >= 0 does."""
    g = open_loop_response(process, controller, np.array([w_pred, w_rec]))
    lag = float(np.angle(g[0] / g[1]))  # arg G0(w_pred) - arg G0(w_rec), wrapped
    add = -lag / w_rec
    if not math.isfinite(add) or process.dead_time + add < 0.0:
        return None
    return add


#: Total dead times, as fractions of the recorded period, the phase start tries when
#: the open-loop process predicts no cycle near the recorded period [-]: a stiction
#: cycle's period is a few times the loop's dead time plus lag (Section 6).
DEAD_TIME_FRACTIONS = (0.05, 0.1, 0.2, 0.35)
#: J/S of the phase start when no ratio predicts a cycle with the open-loop process:
#: one per case of Section 5.1 that holds a slip jump [-].
PHASE_RATIOS = (0.5, 1.0, 1.5)


def _phase_start(
    process, controller: PI, period_s: float, found: list
) -> tuple[FOPTD | Integrating, float, Cycle] | None:
    """The process with its dead time moved to where the phase condition of Eq. 5
    meets the recorded period [s], with the J/S and the predicted cycle there; None
    when no dead time tried predicts a stable cycle.  Tried: the dead time of
    :func:`_phase_shift` from the best prediction (``found``, sorted), and the total
    dead times :data:`DEAD_TIME_FRACTIONS` of the period; J/S the best prediction's,
    else :data:`PHASE_RATIOS`.  At most 15 describing-function solutions."""
    w_rec = 2 * math.pi / period_s
    deads = [f * period_s for f in DEAD_TIME_FRACTIONS]
    ratios: tuple[float, ...] = PHASE_RATIOS
    if found:
        _, r, pred = found[0]
        ratios = (r,)
        add = _phase_shift(process, controller, pred.frequency_rad_s, w_rec)
        if add is not None:
            deads.insert(0, process.dead_time + add)
    best = None
    for r in ratios:
        for d in deads:
            proc = replace(process, dead_time=d)
            pred = _predict(proc, controller, r)
            if pred is None:
                continue
            miss = abs(math.log(pred.period_s / period_s))
            if best is None or miss < best[0]:
                best = (miss, (proc, r, pred))
    return None if best is None else best[1]


def df_starts(
    start: LoopParameters, controller: PI, period_s: float, op_amplitude: float
) -> tuple[LoopParameters, ...]:
    """The describing function's starting points (Section 6, Eq. 5), no simulation.

    For the open-loop fit's process and the identified controller, the limit cycle
    predicted from ``G0(i w) = -1/N(X_m)`` has a period that depends on J/S alone
    and an op amplitude ``X_m`` proportional to S.  For each case of Section 5.1
    (:data:`DF_CASES`) whose ratios predict a stable cycle, the ratio with the
    period nearest the recorded ``period_s`` [s] gives one start, S and J scaled so
    that ``X_m`` is the recorded op amplitude [% of span]: S is seeded from op's
    swing, not from the open-loop fit, so a fit with S near 0 (a replay without a
    cycle, whose neighbourhood holds none either) still has starts that cycle.  The
    starts are ordered by their period's miss; where the best one misses by more
    than :data:`PHASE_MISS`, a twin of it has the process's dead time moved so that
    the phase condition of Eq. 5 holds at the recorded period
    (:func:`_phase_shift`), its S and J scaled to the recorded amplitude again.
    At most ``len(DF_CASES) + 1`` starts; empty when no ratio predicts a stable
    cycle.  Cost independent of the record length (at most ``len(DF_RATIOS) + 1``
    describing-function solutions on coarse grids).
    """

    if not (math.isfinite(controller.integral_time) and op_amplitude > 0 and period_s > 0):
        return ()
    process = start.process
    if process.gain * controller.gain < 0.0:
        # A loop that cycles about its set point has negative feedback: its process
        # gain has the controller's sign.  A fit of the other sign (a poorly
        # determined process, pv and op cycling nearly in quadrature) replays a
        # loop that runs away or saturates, and no J/S makes it cycle.
        process = replace(process, gain=-process.gain)
    found: list[tuple[float, float, Cycle]] = []
    for ratios in DF_CASES.values():
        best: tuple[float, float, Cycle] | None = None
        for r in ratios:
            pred = _predict(process, controller, r)
            if pred is None:
                continue
            miss = abs(math.log(pred.period_s / period_s))
            if best is None or miss < best[0]:
                best = (miss, r, pred)
        if best is not None:
            found.append(best)
    found.sort(key=lambda b: b[0])
    out = []
    for _, r, pred in found:
        scale = op_amplitude / pred.amplitude_op  # X_m is proportional to S at fixed J/S
        out.append(LoopParameters(S=scale, J=r * scale, process=process))
    if not found or found[0][0] > PHASE_MISS:
        moved = _phase_start(process, controller, period_s, found)
        if moved is not None:
            proc, r, pred = moved
            scale = op_amplitude / pred.amplitude_op
            out.append(LoopParameters(S=scale, J=r * scale, process=proc))
    return tuple(out)


def with_process(pf, process: FOPTD | Integrating, dt: float):
    """``pf`` (a :class:`~stictiondiag.identification.process_result.ProcessFit`) with its
    dynamics replaced by ``process``, biases and initial state kept."""
    return replace(pf, process=process, dead_time_samples=int(round(process.dead_time / dt)))


def refine_loop(
    rec, pf: ProcessFit, S: float, J: float, simulate, controller: PI | None = None
) -> tuple[ClosedLoopRefit, ProcessFit]:
    """The closed-loop refit of a replay's loop (module docstring).

    ``rec`` is the replay's record (``pv``, ``op``, ``u``, ``dt``), ``pf`` the
    identified process, ``simulate(pf, S, J)`` the replay's closed-loop simulation
    (O(n)) returning pv and op.  Returns the refit and the process fit to replay
    with (the refitted one, its R^2 against the record recomputed, when accepted).
    """

    dt = float(rec.dt)
    data = (recorded_cycle(rec.pv, dt), recorded_cycle(rec.op, dt))
    start = LoopParameters(S=float(S), J=float(J), process=pf.process)
    sticky = S > 0.0 or J > 0.0  # a slip jump alone is stiction too (Section 5.1)
    if data[0].period_s is None or not sticky:
        cost = math.nan
        terms: dict = {}
        why = "the recorded pv does not cycle" if sticky else "the fitted valve has no stiction"
        return (
            ClosedLoopRefit(
                S,
                J,
                S,
                J,
                pf.process,
                pf.process,
                cost,
                cost,
                False,
                0,
                f"no refit: {why}",
                terms,
            ),
            pf,
        )

    def evaluate(p: LoopParameters) -> tuple[float, dict]:
        try:
            sim = simulate(with_process(pf, p.process, dt), p.S, p.J)
        except Exception:  # a candidate the simulator refuses is simply not taken
            return math.inf, {}
        if not (np.all(np.isfinite(sim.pv)) and np.all(np.isfinite(sim.op))):
            return math.inf, {}
        mv = None if rec.mv is None else (rec.mv, sim.mv)
        return cycle_cost(rec.pv, rec.op, sim.pv, sim.op, dt, data, mv)

    fixed = rec.mv is not None
    cands: tuple[LoopParameters, ...] = ()
    if not fixed and controller is not None and data[1].period_s is not None:
        cands = df_starts(
            start, controller, data[0].period_s, cycle_spread(rec.op, data[0].period_s, dt)
        )
    result = refit_closed_loop(start, evaluate, dt, valve_fixed=fixed, candidates=cands)
    if not result.accepted:
        return result, pf
    new = with_process(pf, result.process, dt)
    # The search measures cycles by their crossings; the refit must also cycle by
    # the autocorrelation (Thornhill et al. 2003) wherever the open-loop fit did.

    before = _cycle_period(simulate(pf, S, J).pv, dt)[0]
    after = _cycle_period(simulate(new, result.S, result.J).pv, dt)[0]
    if before is not None and after is None:
        return (
            replace(
                result,
                S=start.S,
                J=start.J,
                process=start.process,
                cost=result.cost_open_loop,
                accepted=False,
                reason="the refit's replay would lose the cycle the open-loop fit's has",
            ),
            pf,
        )
    d = new.dead_time_samples
    r2 = r_squared(rec.pv[d + 1 :], new.simulate(rec.u, dt)[d + 1 :])
    oe = OutputErrorFit(
        u_bias=new.output_error.u_bias,
        pv_bias=new.output_error.pv_bias,
        initial_deviation=new.output_error.initial_deviation,
        fit_r2=r2,
        arx_r2=new.output_error.arx_r2,
        closed_loop_refit_r2=r2,
        unfiltered_r2=r2,
        drift_time_constant=None,
    )
    return result, replace(new, detail=oe)
