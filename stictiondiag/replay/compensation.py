"""Stiction compensation by a variable-integral PI, tried on the fitted loop.

Section 6.4 of Choudhury, Thornhill & Shah (2005) draws from the describing function
that a PI controller "where the integral action has a variable strength (Gerry and
Ruel, 2001)" can remove the stiction cycle: while ``|sp - pv|`` is below a band the
integral action is taken out, so the controller output stops integrating while the
valve sits in its stiction band.  The price is an offset: the loop may come to rest
anywhere inside the band.

:func:`compensate` runs that scheme on a loop (process, PI controller and data-driven
valve, Eq. 3 / Table 3 form, simulated by
:func:`stictiondiag.models.loops.simulate_loop`) and searches the smallest band that
stops the cycle; :func:`compensation_from_replay` takes the loop from a closed-loop
replay of recorded data (:mod:`stictiondiag.replay.closed_loop`).

The run
-------
Each trial is deterministic: the setpoint is constant, the valve starts stuck
``kick`` % of span away from the operating point, and the loop runs with its normal
PI for :data:`WARM_CYCLES` periods of its limit cycle; then the band is switched on
and the loop runs :data:`TEST_CYCLES` more periods.  The switch-on falls at
:data:`N_PHASES` different phases of the cycle; a band *stops the cycle* when, for
every phase, the valve position does not move at all over the last
:data:`STILL_CYCLES` periods (a stiction limit cycle cannot go on without slips).

For an integrating process (a level loop) the scheme leaves the process's own
integrator in the loop: with P action only, the open-loop phase still tends to
``-pi/2`` minus the dead time's lag at low frequency, which can meet the ``-1/N``
curve of a valve with a slip jump (Fig. 17, right).  The search then reports that
no band stops the cycle, which is a finding, not a failure.

The offset bound
----------------
Suppose the valve has stopped for good and pv has settled, with control error
``e = sp - pv``.  If ``|e|`` were at least the band, the integral would go on
integrating a constant ``e`` and op would ramp without bound until the valve
slipped, a contradiction.  So a loop stopped by the scheme rests with
``|sp - pv| < band``: the band is a bound on the offset, whatever the process.  The
offset reported is the largest ``|sp - pv|`` over the last :data:`OFFSET_CYCLES`
periods of the run, over all switch-on phases [pv units].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.serialize import plain_float
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI, Integrating

if TYPE_CHECKING:
    import pandas as pd


#: Periods of the limit cycle run with the normal PI before the band is switched on.
WARM_CYCLES = 8
#: Periods run with the band switched on.
TEST_CYCLES = 24
#: Last periods over which a stopped valve must not move at all.
STILL_CYCLES = 8
#: Last periods over which the offset is measured.
OFFSET_CYCLES = 2
#: Switch-on phases tried (evenly spread over one period).
N_PHASES = 4
#: Bands tried on the coarse grid, as multiples of the uncompensated pv amplitude.
BAND_GRID = tuple(float(x) for x in np.geomspace(0.02, 4.0, 16))
#: Bisection steps between the last band that failed and the first that stopped.
BISECTION_STEPS = 6
#: Fewest samples per period of the cycle: a coarser record is not simulated.
MIN_SAMPLES_PER_PERIOD = 8
#: Most samples a trial run may take (long runs are refused, not simulated).
MAX_TRIAL_SAMPLES = 400_000
#: Valve movement [% of span] below which the valve counts as still (rounding only).
STILL_TOLERANCE = 1e-9


@dataclass(frozen=True)
class Compensation:
    """Outcome of the variable-integral compensation search (Section 6.4).

    Attributes
    ----------
    applicable : bool
        The loop has integral action and sustains a stiction cycle; False otherwise
        (``reason`` says why).
    reason : str
        One line: what was found, or why nothing was tried.
    band : float or None
        Smallest band found that stops the cycle [pv units]; None when none of the
        bands tried (up to ``BAND_GRID[-1]`` amplitudes) stopped it.
    band_pct_of_amplitude : float or None
        ``band`` in % of the uncompensated pv amplitude [%].
    offset : float or None
        Largest ``|sp - pv|`` at rest with that band, over the switch-on phases
        [pv units]; at most ``band`` (module docstring).
    amplitude : float or None
        Half peak-to-peak amplitude of the uncompensated pv cycle [pv units].
    period_s : float or None
        Period of the uncompensated cycle [s].
    settle_s : float or None
        Longest time from switch-on to the last valve movement, over the phases [s].
    trials : tuple of (float, bool)
        Every band tried [pv units] and whether it stopped the cycle.
    """

    applicable: bool
    reason: str
    band: float | None = None
    band_pct_of_amplitude: float | None = None
    offset: float | None = None
    amplitude: float | None = None
    period_s: float | None = None
    settle_s: float | None = None
    trials: tuple[tuple[float, bool], ...] = field(default_factory=tuple)

    @property
    def stops_cycle(self) -> bool:
        """A band was found that stops the cycle."""
        return self.band is not None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict (units in the key names)."""
        return {
            "applicable": bool(self.applicable),
            "reason": self.reason,
            "band_pv": plain_float(self.band),
            "band_pct_of_amplitude": plain_float(self.band_pct_of_amplitude),
            "offset_pv": plain_float(self.offset),
            "offset_bound_pv": plain_float(self.band),
            "amplitude_pv": plain_float(self.amplitude),
            "period_s": plain_float(self.period_s),
            "settle_s": plain_float(self.settle_s),
            "n_trials": len(self.trials),
            "model": "variable-integral PI (Gerry & Ruel 2001), Section 6.4",
        }

    def to_pandas(self) -> pd.DataFrame:
        """The bands tried: columns ``band`` [pv units] and ``stopped`` [bool]."""
        import pandas as pd

        return pd.DataFrame(
            {
                "band": [b for b, _ in self.trials],
                "stopped": [s for _, s in self.trials],
            }
        )


def _trial(
    run, band: float | None, n: int, warm: int, per: int, phases: tuple[int, ...]
) -> tuple[bool, float, float]:
    """Run the loop with ``band`` switched on after ``warm + phase`` samples, for
    each phase; return (stopped for every phase, largest offset, longest settle [samples])."""
    offset = 0.0
    settle = 0.0
    for phase in phases:
        bands = np.full(n, np.nan)
        if band is not None:
            bands[warm + phase :] = band
        sim = run(bands)
        still = n - STILL_CYCLES * per
        moves = np.flatnonzero(np.abs(np.diff(sim.mv)) > STILL_TOLERANCE)
        if moves.size and moves[-1] + 1 >= still:
            return False, math.nan, math.nan
        last = int(moves[-1]) + 1 if moves.size else 0
        settle = max(settle, last - (warm + phase))
        tail = slice(n - OFFSET_CYCLES * per, n)
        offset = max(offset, float(np.max(np.abs(sim.sp[tail] - sim.pv[tail]))))
    return True, offset, settle


def _search(try_band, amplitude: float):
    """Coarse grid of :data:`BAND_GRID` amplitudes up to the first band that stops
    the cycle, then :data:`BISECTION_STEPS` halvings below it.  Returns the trials
    ``[(band, stopped)]`` and ``(band, offset, settle)`` of the smallest band that
    stopped it, or None."""
    trials: list[tuple[float, bool]] = []
    found: tuple[float, float, float] | None = None
    below = 0.0
    for factor in BAND_GRID:
        band = factor * amplitude
        stopped, offset, settle = try_band(band)
        trials.append((band, stopped))
        if stopped:
            found = (band, offset, settle)
            break
        below = band
    if found is not None:
        lo, hi = below, found[0]
        for _ in range(BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            stopped, offset, settle = try_band(mid)
            trials.append((mid, stopped))
            if stopped:
                hi, found = mid, (mid, offset, settle)
            else:
                lo = mid
    return trials, found


def _no_band(process, amplitude: float, period: float, trials) -> Compensation:
    """The result when no band of :data:`BAND_GRID` stops the cycle, and why an
    integrating process cannot be helped (Section 6.4, Fig. 17)."""
    why = (
        "; the process integrates, so without the controller's integral the loop "
        "still holds an integrator, which sustains the cycle of a slip jump "
        "(Section 6.4, Fig. 17)"
        if getattr(process, "kind", "") == "integrating"
        else ""
    )
    return Compensation(
        True,
        f"no band up to {BAND_GRID[-1]:g} times the cycle's pv amplitude stops the cycle{why}",
        amplitude=amplitude,
        period_s=period,
        trials=tuple(trials),
    )


def compensate(
    process: FOPTD | Integrating,
    controller: PI,
    S: float,
    J: float,
    *,
    dt: float,
    period_s: float,
    valve: str = "choudhury",
    op_bias: float = 50.0,
    pv_bias: float = 0.0,
    kick: float | None = None,
    pv_filter_time: float = 0.0,
) -> Compensation:
    """Search the smallest variable-integral band that stops the stiction cycle.

    Parameters
    ----------
    process, controller
        The loop (Eq. 3 form): process gain [pv units / % of span], PI gain
        [% of span / pv units] and integral time [s].
    S, J : float
        Data-driven valve [% of span] (Section 5.1).
    dt : float
        Sample time of the simulation [s].
    period_s : float
        Expected period of the cycle [s] (sets the run lengths); the period of the
        simulated cycle is measured and used when it differs.
    valve : {"choudhury", "kano"}
        Data-driven valve model.
    op_bias, pv_bias : float
        Operating point [% of span] and pv there [pv units]; the setpoint is
        ``pv_bias``.
    kick : float, optional
        Initial displacement of the stuck valve [% of span]; default ``S``.
    pv_filter_time : float
        The controller's filter on pv [s].

    Returns
    -------
    Compensation

    Raises
    ------
    UsageError
        Bad arguments, or a run longer than :data:`MAX_TRIAL_SAMPLES` samples.
    """

    if not (math.isfinite(period_s) and period_s > 0 and dt > 0):
        raise UsageError(f"compensation needs a positive period and dt, got {period_s}, {dt}")
    if not math.isfinite(controller.integral_time):
        return Compensation(False, "the controller has no integral action: nothing to switch")
    if controller.gain * process.gain <= 0:
        return Compensation(False, "controller and process gains have opposite signs")
    kick = float(S if kick is None else kick)

    def run_for(per: int):
        n = (WARM_CYCLES + TEST_CYCLES) * per
        if n > MAX_TRIAL_SAMPLES:
            raise UsageError(
                f"compensation run of {n} samples exceeds {MAX_TRIAL_SAMPLES}: "
                "resample the data more coarsely"
            )

        def run(bands: np.ndarray):
            return simulate_loop(
                process,
                controller,
                duration=n * dt,
                dt=dt,
                valve=valve,
                S=S,
                J=J,
                sp=pv_bias,
                op_bias=op_bias,
                pv_bias=pv_bias,
                kick=kick,
                integral_band=bands,
                pv_filter_time=pv_filter_time,
            )

        return n, run

    per = max(MIN_SAMPLES_PER_PERIOD, int(round(period_s / dt)))
    n, run = run_for(per)
    base = run(np.full(n, np.nan))
    cycle = base.limit_cycle(transient=WARM_CYCLES * per * dt)
    if not cycle.present or cycle.period_s is None:
        return Compensation(False, "the fitted loop does not sustain a limit cycle")
    measured = max(MIN_SAMPLES_PER_PERIOD, int(round(cycle.period_s / dt)))
    if abs(measured - per) > 0.25 * per:
        per = measured
        n, run = run_for(per)
    amplitude = float(cycle.amplitude["pv"] or 0.0)
    if not amplitude > 0:
        return Compensation(False, "the fitted loop's pv cycle has no amplitude")
    warm = WARM_CYCLES * per
    phases = tuple(int(k * per / N_PHASES) for k in range(N_PHASES))
    trials, found = _search(lambda band: _trial(run, band, n, warm, per, phases), amplitude)
    period = float(cycle.period_s)
    if found is None:
        return _no_band(process, amplitude, period, trials)
    band, offset, settle = found
    return Compensation(
        True,
        f"a band of {band:.3g} pv units stops the cycle; the loop rests "
        f"{offset:.3g} pv units from the setpoint (at most the band)",
        band=band,
        band_pct_of_amplitude=100.0 * band / amplitude,
        offset=offset,
        amplitude=amplitude,
        period_s=period,
        settle_s=settle * dt,
        trials=tuple(trials),
    )


def compensation_from_replay(rep) -> Compensation:
    """:func:`compensate` on the loop a replay identified (fitted valve, identified
    process and controller, the replay's operating point and sample time).

    Parameters
    ----------
    rep : Replay
        From :func:`stictiondiag.replay.closed_loop.replay`.
    """
    pf, cf = rep.process_fit, rep.controller_fit
    period = rep.period_replay_s or rep.period_data_s
    if not period:
        return Compensation(False, "neither the data nor the replay show a cycle")
    if not (rep.S > 0 or rep.J > 0):
        return Compensation(False, "the fitted valve has no stiction (S = J = 0)")
    settings = rep.settings
    op_bias = float(np.clip(float(settings.op_bias) + float(settings.op_offset), 0, 100))
    return compensate(
        pf.process,
        cf.controller,
        float(rep.S),
        float(rep.J),
        dt=float(rep.dt),
        period_s=float(period),
        valve=str(settings.valve),
        op_bias=op_bias,
        pv_bias=float(settings.pv_bias),
        pv_filter_time=float(cf.pv_filter_time or 0.0),
    )
