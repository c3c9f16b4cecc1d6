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

Starts: the open-loop fit, and the describing function's prediction
(:func:`df_start`, Section 6): the J/S whose predicted cycle has the recorded
period, scaled to the recorded op amplitude.  Both are simulated; the search
starts from the better.

Search: a compass search in the logarithms of S, J + j0 (``j0`` a small floor so a
zero J can grow), the process gain and time constant, and in the dead time [samples],
from the open-loop fit, each step tried up and down, halved when no step helps,
stopped after :data:`MAX_SIMULATIONS` simulations or when the steps are below
:data:`MIN_STEP`.  The refit is kept only when it lowers the cost by
:data:`MIN_IMPROVEMENT`; otherwise the open-loop fit stands.

Cost: at most :data:`MAX_SIMULATIONS` + 3 closed-loop simulations (the search, the
describing function's start, and the check that an accepted refit cycles wherever
the open-loop fit did), each O(n) in the record length n, and the cycle measures
of each: the autocorrelation's period, O(n log n) by FFT, everything else O(n).
Linear in n up to that logarithm; the describing function's start does not depend
on n.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.core.serialize import to_plain
from stictiondiag.identification.numerics import r_squared
from stictiondiag.models.describing import predict_limit_cycle
from stictiondiag.models.processes import FOPTD, PI, Integrating
from stictiondiag.replay.cycles import _up_crossings, waveform_similarity
from stictiondiag.replay.metrics import _cycle_period
from stictiondiag.signals.oscillation import _detrend_by_cycles

if TYPE_CHECKING:
    from stictiondiag.identification.process import ProcessFit

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
    process_open_loop, process : dict
        The process before and after (``to_dict`` of the model: gain, time constant
        [s], dead time [s]).
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
    process_open_loop: dict
    process: dict
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
            "process_open_loop": to_plain(self.process_open_loop),
            "process": to_plain(self.process),
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
    are further starting points (the describing function's, :func:`df_start`): each
    is simulated once, and the search starts from the best of all.  See the module
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
    for cand in candidates:
        c, t = evaluate(cand)
        sims += 1
        if math.isfinite(c) and c < best:
            x, best, best_terms = _to_vector(cand, j0, dt), c, t
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
                c, t = evaluate(_from_vector(trial, start, j0, dt))
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
    found = _from_vector(x, start, j0, dt)
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
        process_open_loop=start.process.to_dict(),
        process=found.process.to_dict(),
        cost_open_loop=cost0,
        cost=cost,
        accepted=accepted,
        simulations=sims,
        reason=reason,
        terms=terms,
    )


#: Ratios J/S the describing-function start tries [-] (Section 6: the period of the
#: predicted cycle depends on J/S alone, its amplitude scales with S).
DF_RATIOS = (0.0, 0.1, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0)


def df_start(
    start: LoopParameters, controller: PI, period_s: float, op_amplitude: float
) -> LoopParameters | None:
    """The describing function's starting point (Section 6, Eq. 5), no simulation.

    For the open-loop fit's process and the identified controller, the limit cycle
    predicted from ``G0(i w) = -1/N(X_m)`` has a period that depends on J/S alone
    and an op amplitude ``X_m`` proportional to S.  The ratio of :data:`DF_RATIOS`
    whose stable predicted cycle has the period nearest the recorded ``period_s``
    [s] is taken, and S and J scaled so that ``X_m`` is the recorded op amplitude
    [% of span].  None when no ratio predicts a stable cycle.  Cost independent of
    the record length (a few describing-function solutions on coarse grids).
    """

    if not (math.isfinite(controller.integral_time) and op_amplitude > 0 and period_s > 0):
        return None
    best: tuple[float, float, float] | None = None
    for r in DF_RATIOS:
        try:
            pred = predict_limit_cycle(
                start.process, controller, 1.0, r, n_amplitudes=120, n_frequencies=3000
            )
        except (StictionError, ArithmeticError, ValueError):
            continue
        if not (pred.limit_cycle and pred.stable and pred.period_s and pred.amplitude_op):
            continue
        miss = abs(math.log(pred.period_s / period_s))
        if best is None or miss < best[0]:
            best = (miss, r, float(pred.amplitude_op))
    if best is None:
        return None
    _, r, xm = best
    scale = op_amplitude / xm  # X_m is proportional to S at a fixed J/S
    return LoopParameters(S=scale, J=r * scale, process=start.process)


def with_process(pf, process: FOPTD | Integrating, dt: float):
    """``pf`` (a :class:`~stictiondiag.identification.process.ProcessFit`) with its
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
    if data[0].period_s is None or not S > 0.0:
        cost = math.nan
        terms: dict = {}
        why = "the recorded pv does not cycle" if S > 0.0 else "the fitted valve has no stiction"
        return (
            ClosedLoopRefit(
                S,
                J,
                S,
                J,
                pf.process.to_dict(),
                pf.process.to_dict(),
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
        df = df_start(
            start, controller, data[0].period_s, cycle_spread(rec.op, data[0].period_s, dt)
        )
        cands = () if df is None else (df,)
    result = refit_closed_loop(start, evaluate, dt, valve_fixed=fixed, candidates=cands)
    if not result.accepted:
        return result, pf
    new = with_process(pf, _refitted_process(result, pf.process), dt)
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
                process=start.process.to_dict(),
                cost=result.cost_open_loop,
                accepted=False,
                reason="the refit's replay would lose the cycle the open-loop fit's has",
            ),
            pf,
        )
    d = new.dead_time_samples
    r2 = r_squared(rec.pv[d + 1 :], new.simulate(rec.u, dt)[d + 1 :])
    return result, replace(
        new,
        fit_r2=r2,
        unfiltered_r2=r2,
        drift_time_constant=None,
        candidates={"closed_loop_refit": r2},
    )


def _refitted_process(result: ClosedLoopRefit, template: FOPTD | Integrating):
    p = result.process
    if isinstance(template, FOPTD):
        return FOPTD(gain=p["gain"], time_constant=p["time_constant_s"], dead_time=p["dead_time_s"])
    return Integrating(gain=p["gain"], dead_time=p["dead_time_s"])
