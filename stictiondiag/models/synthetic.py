"""Withheld-effect benchmark: closed loops with one hidden effect each.

Every case is a PI-controlled loop (self-regulating FOPTD or integrating process)
with a sticky valve, measurement noise, load disturbances and set-point changes,
plus exactly one *effect* that the diagnosis is not told about. The diagnosis sees
only the data (``time, sp, pv, op, mv``); the truth (effect, S, J, process,
controller, effect parameters) is kept apart, in :class:`SyntheticCase.truth` and in
the ``truth.json`` written by :func:`write_benchmark`.

The simulator here is deliberately independent of the diagnosis code: it has its own
compiled closed-loop kernel, its own stick-slip valve written from the description in
Section 5.1 of Choudhury, Thornhill & Shah (2005), "Modelling valve stiction",
Control Engineering Practice 13, 641-658, and its own Karnopp valve (Section 4.1,
Eqs. 1-2, Table 1). It imports nothing from the valve, loop or physical-model
modules of :mod:`stictiondiag`, so a benchmark result cannot come from both sides
sharing one mistake.

Effects (:data:`EFFECTS`)
-------------------------
``none``
    The base valve alone: the two-parameter data-driven model explains ``mv``
    from ``op`` within noise.
``actuator_lag``
    Positioner/actuator dynamics after the friction element: a first-order lag of
    2-6 samples between the stick-slip output and the recorded (and acting) valve
    position, so ``mv`` follows a slip with a visible delay.
``miscalibration``
    Positioner span error: the friction element is driven by
    ``pivot + gain (op - pivot)`` with a gain of 0.65-0.8 or 1.2-1.4, so the
    moving-phase slope of ``mv`` against ``op`` is not 1 (Section 4.2.1, Fig. 8
    bottom row). J is kept at or below 0.8 S so that there is a moving phase.
``asymmetry``
    Different S and J opening and closing, as the large downward slip of Loop 1,
    Section 3: ratio 1.8-3 for S and 1-3 for J with the stick-slip element; for the
    Karnopp valve per-direction friction forces giving slip jumps in a ratio
    1.8-3 (its reversal bands then differ by the difference of the jumps).
``valve_characteristic``
    Equal-percentage (rangeability 25-50, valve authority 0.6-1) or quick-opening
    (``1 - (1 - x)^m``, m 2-3, authority 0.3-1) installed characteristic between
    valve position and flow, drawn until the installed gain differs by at least
    half between the ends of the travel the loop visits. The recorded ``mv`` is the
    stem position; the process sees the flow.
``quantization``
    Historian or instrument resolution: ``mv`` quantised to 0.5-2 % of span
    (Loop 4, Section 3), or ``pv`` to 12-40 levels over its range, or both. With
    instrument resolution the controller acts on the quantised ``pv``.
``external_disturbance``
    A periodic load (fundamental plus a weaker second harmonic) entering at the
    process output, with a period at least 40 % away from the loop's own cycle,
    sized so that 0.7-1.5 times the loop's own error spread (and at least 5 noise
    standard deviations) gets through the controller to pv.
``time_varying_stiction``
    S and J scaled by 2-3 (or 1/3-1/2) during the record, as a step or a ramp.

Reading of the stick-slip model
-------------------------------
Section 5.1 says the input at which the valve stuck, ``x_ss``, "is kept in memory
and does not change until the valve gets stuck again". The element here keeps it
for as long as the valve is stuck, whatever the input does; only a valve that has
moved can stick again. This is also how Kano et al. (2004) state the model and how
the Karnopp valve behaves (the force builds up from where the stem stopped). A
reading that re-arms ``x_ss`` at every reversal of the input slope while stuck
(Fig. 10 taken literally) holds the valve for good once the controller output
carries measurement noise; replaying this benchmark with that reading needs the
EWMA pre-filter of Section 5.1.

Base valves
-----------
About 70 % of the cases use the data-driven stick-slip element
(:func:`stick_slip_step`), the rest the Karnopp physical valve
(:func:`karnopp_interval`) with Table 1 mass, spring, diaphragm area and viscous
friction and friction forces chosen from S and J through the quasi-static
correspondence ``Fs = k (S + J) / 2``, ``Fc = k (S - J) / 2`` (1 % of span = 1 cm
of stem travel), so the truth's S and J hold for both.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv

from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.errors import UsageError
from stictiondiag.models.synthetic_loop import closed_loop, flow_characteristic

#: Names of the hidden effects, in the order used for balancing a benchmark.
EFFECTS: tuple[str, ...] = (
    "none",
    "actuator_lag",
    "miscalibration",
    "asymmetry",
    "valve_characteristic",
    "quantization",
    "external_disturbance",
    "time_varying_stiction",
)

#: Share of cases whose base valve is the Karnopp physical model.
PHYSICAL_SHARE = 0.3

#: Karnopp valve constants (Table 1, nominal case) and integration settings.
KARNOPP_PARAMETERS: dict[str, float] = {
    "mass_kg": 1.36,
    "spring_constant_N_per_m": 52_500.0,
    "diaphragm_area_m2": 0.0645,
    "viscous_friction_N_s_per_m": 612.0,
    "substep_s": 1e-4,
    # Speed below which a valve whose applied force is inside the static band is
    # taken as stuck (Karnopp's zero-velocity window) [m/s].
    "stick_velocity_m_per_s": 1e-7,
    # Stem travel per % of span: 1 % = 1 cm (Section 4.2.1, Fig. 8 caption).
    "stem_m_per_percent": 0.01,
}

_DEFAULT_N_RANGE = (5000, 10000)
_TS_CHOICES = (0.5, 1.0, 2.0, 5.0)
_TS_CHOICES_PHYSICAL = (0.5, 1.0, 2.0)
_WARMUP_SAMPLES = 1500

# Characteristic codes understood by the kernel.
_CHAR_LINEAR, _CHAR_EQUAL_PERCENTAGE, _CHAR_QUICK_OPENING = 0, 1, 2



@dataclass(frozen=True)
class SyntheticCase:
    """One generated loop and what was hidden in it.

    Attributes
    ----------
    data : pandas.DataFrame
        Columns ``time`` [s], ``sp``, ``pv`` [pv units], ``op``, ``mv`` [% of span].
    truth : dict
        JSON-able description: ``effect``, ``seed``, ``S``, ``J`` [% of span, as
        the friction element sees them], ``valve`` (base valve and its parameters),
        ``process``, ``controller``, ``noise``, ``load``, ``setpoint_changes`` and
        ``effect_parameters``.
    hidden : dict
        Noise-free internal signals (ndarrays, one per sample): ``valve_output``
        (friction-element output [% of span]), ``position`` (valve position after
        any actuator lag [% of span]), ``flow`` (installed flow through the
        valve, scaled to % of span at the operating point), ``load_input`` (load
        added to the process input [% of span]),
        ``output_disturbance`` [pv units] and ``pv_clean`` (pv without noise).
        For tests and plots; not part of the benchmark files.
    """

    data: pd.DataFrame
    truth: dict
    hidden: dict = field(default_factory=dict, repr=False, compare=False)


# --------------------------------------------------------------------------------------
# Random case description
# --------------------------------------------------------------------------------------


def _first_order(x: np.ndarray, weight: float) -> np.ndarray:
    """Discrete first-order lag ``y[k] = y[k-1] + w (x[k] - y[k-1])``."""
    out = np.empty_like(x)
    acc = x[0]
    for k in range(x.shape[0]):
        acc += weight * (x[k] - acc)
        out[k] = acc
    return out


def _ar1_noise(rng: np.random.Generator, n: int, std: float, phi: float) -> np.ndarray:
    """Coloured measurement noise with standard deviation ``std`` and AR(1) pole ``phi``."""
    white = rng.standard_normal(n) * std * math.sqrt(1.0 - phi * phi)
    out = np.empty(n)
    acc = 0.0
    for k in range(n):
        acc = phi * acc + white[k]
        out[k] = acc
    return out


def _step_schedule(
    rng: np.random.Generator, n: int, n_steps: int, sizes: np.ndarray, limit: float
) -> tuple[np.ndarray, list[tuple[int, float]]]:
    """Piecewise-constant signal with ``n_steps`` steps kept within ``+-limit``."""
    times = np.sort(rng.choice(np.arange(n // 20, n - n // 20), size=n_steps, replace=False))
    level = 0.0
    out = np.zeros(n)
    steps = []
    for t, size in zip(times, sizes, strict=True):
        sign = 1.0 if rng.random() < 0.5 else -1.0
        if abs(level + sign * size) > limit:
            sign = -sign
        level += sign * size
        out[t:] = level
        steps.append((int(t), float(sign * size)))
    return out, steps


def _equal_split(rng: np.random.Generator, ratio: float) -> tuple[float, float]:
    """(open, close) multipliers with ``max/min = ratio``, the larger side random."""
    return (ratio, 1.0) if rng.random() < 0.5 else (1.0, ratio)


def _directional_equivalents(
    physical: bool, S_open: float, J_open: float, S_close: float, J_close: float
) -> dict[str, float]:
    """Per-direction S and J [% of span] that the data show.

    For the stick-slip element they are its parameters. For the Karnopp valve the
    parameters set the forces, ``Fs = k (S + J)/2`` and ``Fc = k (S - J)/2`` per
    direction; a valve that stopped closing holds ``Fc_close`` and must build up
    ``Fs_open`` to open, so the opening band is ``(Fs_open + Fc_close)/k`` while the
    slip jump stays ``(Fs - Fc)/k`` of the moving direction.
    """
    if not physical:
        return {"S_open": S_open, "J_open": J_open, "S_close": S_close, "J_close": J_close}
    Fs_o, Fc_o = (S_open + J_open) / 2.0, (S_open - J_open) / 2.0
    Fs_c, Fc_c = (S_close + J_close) / 2.0, (S_close - J_close) / 2.0
    return {
        "S_open": Fs_o + Fc_c,
        "J_open": Fs_o - Fc_o,
        "S_close": Fs_c + Fc_o,
        "J_close": Fs_c - Fc_c,
        "Fs_open_N": KARNOPP_PARAMETERS["spring_constant_N_per_m"] * 0.01 * Fs_o,
        "Fc_open_N": KARNOPP_PARAMETERS["spring_constant_N_per_m"] * 0.01 * Fc_o,
        "Fs_close_N": KARNOPP_PARAMETERS["spring_constant_N_per_m"] * 0.01 * Fs_c,
        "Fc_close_N": KARNOPP_PARAMETERS["spring_constant_N_per_m"] * 0.01 * Fc_c,
    }


def _flow_slope(kind: int, rangeability: float, authority: float, position: float) -> float:
    dp = 0.5
    hi = flow_characteristic(position + dp, kind, rangeability, authority)
    lo = flow_characteristic(position - dp, kind, rangeability, authority)
    return (hi - lo) / (2.0 * dp)


def _linear_sensitivity(
    w: float,
    integrating: bool,
    gain: float,
    time_constant: float,
    dead_time: float,
    Kc: float,
    Ti: float,
    filter_time: float,
) -> float:
    """``|1 / (1 + G C F)|`` at ``w`` [rad/s] for the loop with a linear valve."""
    s = 1j * w
    process = gain * np.exp(-dead_time * s) / (s if integrating else time_constant * s + 1.0)
    controller = Kc * (1.0 + 1.0 / (Ti * s)) / (filter_time * s + 1.0)
    return float(abs(1.0 / (1.0 + process * controller)))


def _dominant_period(x: np.ndarray, ts: float) -> float:
    """Period [s] of the largest spectral peak of a detrended signal (0 if none)."""
    x = x - np.mean(x)
    n = x.shape[0]
    spec = np.abs(np.fft.rfft(x * np.hanning(n))) ** 2
    freqs = np.fft.rfftfreq(n, ts)
    lo = 4  # ignore periods longer than a quarter of the record
    if spec.shape[0] <= lo + 1:
        return 0.0
    k = lo + int(np.argmax(spec[lo:]))
    return float(1.0 / freqs[k]) if freqs[k] > 0 else 0.0


def _plain(value):
    """JSON-able copy: numpy scalars to Python, NaN to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating | float):
        f = float(value)
        return None if not math.isfinite(f) else f
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def generate_case(
    effect: str,
    seed: int,
    *,
    n_samples: int | None = None,
    ts: float | None = None,
    physical: bool | None = None,
) -> SyntheticCase:
    """Simulate one closed loop with one hidden effect.

    Parameters
    ----------
    effect : str
        One of :data:`EFFECTS`.
    seed : int
        Seed of all random choices; the same seed and arguments give the same case.
    n_samples : int, optional
        Record length; default random in 5 000-10 000.
    ts : float, optional
        Sample time [s]; default random from 0.5, 1, 2, 5 s (0.5-2 s for the
        physical valve).
    physical : bool, optional
        Force the base valve (Karnopp physical model or data-driven); default random
        with probability :data:`PHYSICAL_SHARE` for the physical model.

    Returns
    -------
    SyntheticCase
        The recorded signals and the truth.
    """
    if effect not in EFFECTS:
        raise UsageError(f"unknown effect {effect!r}: use one of {', '.join(EFFECTS)}")
    if n_samples is not None and int(n_samples) < 200:
        raise UsageError(f"n_samples must be at least 200, got {n_samples}")
    if ts is not None and not (math.isfinite(float(ts)) and float(ts) > 0.0):
        raise UsageError(f"ts must be a positive number of seconds, got {ts}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), EFFECTS.index(effect)]))

    # Base valve and sampling -----------------------------------------------------
    use_physical = bool(rng.random() < PHYSICAL_SHARE) if physical is None else bool(physical)
    ts_choice = float(rng.choice(_TS_CHOICES_PHYSICAL if use_physical else _TS_CHOICES))
    n_draw = int(rng.integers(_DEFAULT_N_RANGE[0], _DEFAULT_N_RANGE[1] + 1))
    ts = ts_choice if ts is None else float(ts)
    n = n_draw if n_samples is None else int(n_samples)
    n_total = n + _WARMUP_SAMPLES

    S = float(rng.uniform(0.8, 6.0))
    J = float(S * rng.uniform(0.25, 1.0) if use_physical else S * rng.uniform(0.25, 1.4))

    # Process and PI tuning (SIMC rules, randomly detuned) --------------------------
    integrating = bool(rng.random() < 0.35)
    if integrating:
        gain = float(rng.uniform(0.002, 0.02) / ts)  # pv units / (% s)
        time_constant = 1.0
        dead = int(rng.integers(0, 11))
        closed_loop_time = float(rng.uniform(10.0, 60.0) * ts)
        Kc = 1.0 / (gain * (closed_loop_time + dead * ts))
        Ti = 4.0 * (closed_loop_time + dead * ts) * float(rng.uniform(0.7, 1.5))
        pv_per_pct = gain * (closed_loop_time + dead * ts)
    else:
        gain = float(rng.uniform(0.3, 3.0))
        time_constant = float(rng.uniform(8.0, 60.0) * ts)
        dead = int(round(rng.uniform(0.0, 0.5) * time_constant / ts))
        dead = min(dead, 60)
        closed_loop_time = max(dead * ts, 0.2 * time_constant) * float(rng.uniform(1.0, 3.0))
        Kc = time_constant / (gain * (closed_loop_time + dead * ts))
        Ti = min(time_constant, 4.0 * (closed_loop_time + dead * ts)) * float(rng.uniform(0.6, 1.5))
        pv_per_pct = gain
    filter_time = float(rng.uniform(0.0, 3.0) * ts)
    filter_weight = ts / (filter_time + ts)

    op_bias = float(rng.uniform(35.0, 65.0))
    pv0 = float(np.round(rng.uniform(20.0, 80.0), 1))

    # Disturbances, set point, noise ---------------------------------------------
    # Load steps move the operating point across at least 15 % of the valve span,
    # so that any operating-point dependent effect has room to show.
    for _ in range(50):
        n_load_steps = int(rng.integers(2, 5))
        load_steps, load_step_list = _step_schedule(
            rng, n_total, n_load_steps, rng.uniform(6.0, 18.0, n_load_steps), 25.0
        )
        if np.ptp(load_steps) >= 15.0:
            break
    walk_range = float(rng.uniform(1.0, 6.0))
    walk = np.cumsum(rng.standard_normal(n_total)) * walk_range / math.sqrt(n_total)
    load_time = float(rng.uniform(5.0, 30.0) * ts)
    load_in = _first_order(load_steps + walk, ts / (load_time + ts))

    n_sp = int(rng.integers(0, 4))
    if integrating:
        sp_sizes = rng.uniform(3.0, 10.0, n_sp) / Kc
    else:
        sp_sizes = rng.uniform(4.0, 12.0, n_sp) * gain
    sp_dev, sp_list = _step_schedule(rng, n_total, n_sp, sp_sizes, 20.0 * pv_per_pct)
    sp = pv0 + sp_dev

    noise_std = float(rng.uniform(0.03, 0.15) * pv_per_pct * max(J, 0.5 * S))
    noise_phi = float(rng.uniform(0.0, 0.6))
    noise = _ar1_noise(rng, n_total, noise_std, noise_phi)
    mv_noise_std = float(rng.uniform(0.03, 0.15))
    mv_noise = rng.standard_normal(n_total) * mv_noise_std

    # Effect parameters ------------------------------------------------------------
    S_open = np.full(n_total, S)
    J_open = np.full(n_total, J)
    S_close = np.full(n_total, S)
    J_close = np.full(n_total, J)
    cal_gain, cal_pivot = 1.0, 0.0
    lag_time = 0.0
    char_kind, rangeability, authority = _CHAR_LINEAR, 1.0, 1.0
    pv_quantum_instrument = 0.0
    pv_quantum_historian = 0.0
    mv_quantum = 0.0
    load_out = np.zeros(n_total)
    effect_params: dict = {}

    if effect == "actuator_lag":
        lag_time = float(rng.uniform(2.0, 6.0) * ts)
        # A lag shows on slips: keep them clear of the position-transmitter noise.
        quieter = min(mv_noise_std, J / 10.0)
        mv_noise = mv_noise * (quieter / mv_noise_std)
        mv_noise_std = quieter
        effect_params = {"lag_time_constant_s": lag_time, "lag_samples": lag_time / ts}
    elif effect == "miscalibration":
        # The slope shows in the moving phase, which a valve with J >= S in an
        # integrating loop hardly has: keep some deadband.
        J = min(J, 0.8 * S)
        J_open[:] = J
        J_close[:] = J
        if rng.random() < 0.5:
            cal_gain = float(rng.uniform(0.65, 0.8))
        else:
            cal_gain = float(rng.uniform(1.2, 1.4))
        cal_pivot = float(rng.uniform(0.0, op_bias))
        # op moves 1/gain times as far as the valve must: scale the load so the
        # demand stays inside the travel.
        load_in = load_in * min(cal_gain, 1.0)
        effect_params = {
            "calibration_gain": cal_gain,
            "calibration_pivot_pct": cal_pivot,
            "S_on_op_axis": S / cal_gain,
            "note": "valve demand = pivot + gain (op - pivot); S, J act on the demand",
        }
    elif effect == "asymmetry":
        s_o, s_c = _equal_split(rng, float(rng.uniform(1.8, 3.0)))
        if use_physical:
            # The Karnopp valve shows asymmetry through its slip jumps (Fs - Fc per
            # direction); its reversal bands mix both directions' forces.
            ratio_J = float(rng.uniform(1.8, 3.0))
            j_o, j_c = (ratio_J, 1.0) if s_o > s_c else (1.0, ratio_J)
        else:
            # A reversal slip must move the valve the way the demand went: the jump
            # (S_d + J_d)/2 - (S_-d - J_-d)/2 stays above a third of J_d.
            for _ in range(100):
                j_o, j_c = _equal_split(rng, float(rng.uniform(1.0, 3.0)))
                Jo, Jc = J * j_o / math.sqrt(j_o * j_c), J * j_c / math.sqrt(j_o * j_c)
                So, Sc = S * s_o / math.sqrt(s_o * s_c), S * s_c / math.sqrt(s_o * s_c)
                jump_open = (So + Jo) / 2.0 - (Sc - Jc) / 2.0
                jump_close = (Sc + Jc) / 2.0 - (So - Jo) / 2.0
                if jump_open > max(Jo / 3.0, 0.2) and jump_close > max(Jc / 3.0, 0.2):
                    break
                J = J * 1.1  # a larger slip jump keeps the reversal jumps forward
        base_S = S / math.sqrt(s_o * s_c)
        base_J = J / math.sqrt(j_o * j_c)
        S_open[:], S_close[:] = base_S * s_o, base_S * s_c
        J_open[:], J_close[:] = base_J * j_o, base_J * j_c
        if use_physical:
            # Coulomb friction must stay >= 0: J <= S in each direction.
            J_open[:] = np.minimum(J_open, 0.95 * S_open)
            J_close[:] = np.minimum(J_close, 0.95 * S_close)
        directional = _directional_equivalents(
            use_physical, S_open[0], J_open[0], S_close[0], J_close[0]
        )
        S = math.sqrt(directional["S_open"] * directional["S_close"])
        J = math.sqrt(directional["J_open"] * directional["J_close"])
        effect_params = dict(directional)
        effect_params["note"] = (
            "S_open: op travel after a reversal before an opening slip; J_open: opening "
            "slip jump; S and J are the geometric means of the two directions"
        )
    elif effect == "time_varying_stiction":
        factor = float(rng.uniform(2.0, 3.0))
        if rng.random() < 0.5:
            factor = 1.0 / factor
        start = int(_WARMUP_SAMPLES + rng.uniform(0.3, 0.5) * n)
        if rng.random() < 0.5:
            kind = "step"
            profile = np.where(np.arange(n_total) >= start, factor, 1.0)
            end = start
        else:
            kind = "ramp"
            end = int(start + rng.uniform(0.1, 0.2) * n)
            profile = np.interp(np.arange(n_total), [start, end], [1.0, factor])
        for arr in (S_open, J_open, S_close, J_close):
            arr *= profile
        effect_params = {
            "change": kind,
            "factor": factor,
            "start_s": (start - _WARMUP_SAMPLES) * ts,
            "end_s": (end - _WARMUP_SAMPLES) * ts,
            "S_start": S,
            "J_start": J,
            "S_end": S * factor,
            "J_end": J * factor,
        }

    kp = KARNOPP_PARAMETERS
    flow0, dflow0 = 0.0, 1.0

    def run(pv_quantum: float, output_disturbance: np.ndarray):
        return closed_loop(
            ts,
            integrating,
            gain,
            time_constant,
            dead,
            Kc,
            Ti,
            filter_weight,
            op_bias,
            pv0,
            pv_quantum,
            sp,
            load_in,
            output_disturbance,
            noise,
            use_physical,
            S_open,
            J_open,
            S_close,
            J_close,
            cal_gain,
            cal_pivot,
            1.0 - math.exp(-ts / lag_time) if lag_time > 0.0 else 1.0,
            char_kind,
            rangeability,
            authority,
            flow0,
            dflow0,
            kp["mass_kg"],
            kp["spring_constant_N_per_m"],
            kp["viscous_friction_N_s_per_m"],
            kp["stem_m_per_percent"],
            kp["substep_s"],
            kp["stick_velocity_m_per_s"],
        )

    if effect in ("quantization", "external_disturbance", "valve_characteristic"):
        # A pilot run of the same loop sizes the effect against what the loop does.
        pilot = run(0.0, load_out)
        pilot_pv = pilot[0][_WARMUP_SAMPLES:]
        pilot_err = pilot_pv - sp[_WARMUP_SAMPLES:]
        if effect == "valve_characteristic":
            # Draw characteristics until the installed gain differs by half between
            # the ends of the range of travel the loop visits (5th-95th percentile).
            lo, hi = np.percentile(pilot[3][_WARMUP_SAMPLES:], [5.0, 95.0])
            position0 = cal_pivot + cal_gain * (op_bias - cal_pivot)
            need_lo, need_hi = np.percentile(pilot[3][_WARMUP_SAMPLES:] - position0, [1.0, 99.0])
            for _ in range(200):
                if rng.random() < 0.6:
                    char_kind = _CHAR_EQUAL_PERCENTAGE
                    rangeability = float(rng.uniform(25.0, 50.0))
                    authority = float(rng.uniform(0.6, 1.0))
                else:
                    char_kind = _CHAR_QUICK_OPENING
                    rangeability = float(rng.uniform(2.0, 3.0))  # exponent m
                    authority = float(rng.uniform(0.3, 1.0))
                slopes = [_flow_slope(char_kind, rangeability, authority, p) for p in (lo, hi)]
                flow0 = float(flow_characteristic(position0, char_kind, rangeability, authority))
                dflow0 = _flow_slope(char_kind, rangeability, authority, position0)
                # The valve must still pass the flows the loop needs, with margin.
                reach_lo = (
                    flow_characteristic(2.0, char_kind, rangeability, authority) - flow0
                ) / dflow0
                reach_hi = (
                    flow_characteristic(98.0, char_kind, rangeability, authority) - flow0
                ) / dflow0
                if (
                    max(slopes) >= 1.5 * min(slopes)
                    and reach_lo <= need_lo - 3.0
                    and reach_hi >= need_hi + 3.0
                ):
                    break
            flow0 = float(flow_characteristic(position0, char_kind, rangeability, authority))
            dflow0 = _flow_slope(char_kind, rangeability, authority, position0)
            effect_params = {
                "characteristic": "equal_percentage"
                if char_kind == _CHAR_EQUAL_PERCENTAGE
                else "quick_opening",
                "rangeability": rangeability if char_kind == _CHAR_EQUAL_PERCENTAGE else None,
                "quick_opening_exponent": rangeability
                if char_kind == _CHAR_QUICK_OPENING
                else None,
                "authority": authority,
                "gain_ratio_over_travel": max(slopes) / min(slopes),
                "note": "mv is the stem position; the process sees the installed flow, "
                "scaled to the linear valve's slope at the operating point",
            }
        elif effect == "quantization":
            where = str(rng.choice(["mv", "pv", "both"]))
            levels = float(rng.uniform(12.0, 40.0))
            spread = float(np.percentile(pilot_pv, 99) - np.percentile(pilot_pv, 1))
            pv_quantum = max(spread / levels, 3.0 * noise_std)
            mode = "instrument" if rng.random() < 0.5 else "historian"
            if where in ("pv", "both"):
                if mode == "instrument":
                    pv_quantum_instrument = pv_quantum
                else:
                    pv_quantum_historian = pv_quantum
            if where in ("mv", "both"):
                mv_quantum = float(rng.uniform(0.5, 2.0))
                mv_quantum = max(mv_quantum, 3.0 * mv_noise_std)
            effect_params = {
                "quantised": where,
                "pv_quantum": pv_quantum if where in ("pv", "both") else None,
                "pv_resolution": mode if where in ("pv", "both") else None,
                "mv_quantum_pct": mv_quantum if where in ("mv", "both") else None,
            }
        else:
            own_period = _dominant_period(pilot_err, ts)
            for _ in range(100):
                period = float(rng.uniform(15.0, 200.0) * ts)
                if own_period <= 0.0 or not (0.6 < period / own_period < 1.6):
                    break
            w = 2.0 * math.pi / period
            # Size the line by what reaches pv: the loop takes out a slow
            # disturbance, by the linear sensitivity 1/(1 + G C F) at its frequency.
            in_pv = max(float(rng.uniform(0.7, 1.5) * np.std(pilot_err)), 5.0 * noise_std)
            sensitivity = _linear_sensitivity(
                w, integrating, gain, time_constant, dead * ts, Kc, Ti, filter_time
            )
            amplitude = in_pv / max(sensitivity, 0.1)
            phase = float(rng.uniform(0.0, 2.0 * math.pi))
            harmonic = float(rng.uniform(0.0, 0.3))
            t_all = np.arange(n_total) * ts
            load_out = amplitude * (
                np.sin(w * t_all + phase) + harmonic * np.sin(2.0 * w * t_all + 2.0 * phase)
            )
            effect_params = {
                "period_s": period,
                "amplitude": amplitude,
                "amplitude_in_pv_linear": amplitude * max(sensitivity, 0.1),
                "second_harmonic_ratio": harmonic,
                "loop_period_without_disturbance_s": own_period if own_period > 0 else None,
                "enters": "process output",
            }

    pv, op, valve_out, position, flow, pv_clean = run(pv_quantum_instrument, load_out)

    keep = slice(_WARMUP_SAMPLES, n_total)
    pv = pv[keep].copy()
    mv = position[keep] + mv_noise[keep]
    mv = np.clip(mv, 0.0, 100.0)
    if mv_quantum > 0.0:
        mv = mv_quantum * np.floor(mv / mv_quantum + 0.5)
    if pv_quantum_historian > 0.0:
        pv = pv_quantum_historian * np.floor(pv / pv_quantum_historian + 0.5)
    time = np.arange(n) * ts
    data = pd.DataFrame(
        {"time": time, "sp": sp[keep], "pv": pv, "op": op[keep], "mv": mv},
        columns=["time", "sp", "pv", "op", "mv"],
    )
    kp_truth = None
    if use_physical:
        k_spring = kp["spring_constant_N_per_m"]
        m_per_pct = kp["stem_m_per_percent"]
        kp_truth = {
            "mass_kg": kp["mass_kg"],
            "spring_constant_N_per_m": k_spring,
            "diaphragm_area_m2": kp["diaphragm_area_m2"],
            "viscous_friction_N_s_per_m": kp["viscous_friction_N_s_per_m"],
            # Forces at the start of the record; per direction under effect_parameters
            # for the asymmetric valve.
            "Fs_N": None if effect == "asymmetry" else k_spring * m_per_pct * (S + J) / 2.0,
            "Fc_N": None if effect == "asymmetry" else k_spring * m_per_pct * (S - J) / 2.0,
            "substep_s": kp["substep_s"],
            "stem_m_per_percent": m_per_pct,
        }
    truth = {
        "effect": effect,
        "seed": int(seed),
        "S": S,
        "J": J,
        "units": "% of span",
        "ts": ts,
        "n_samples": n,
        "valve": {
            "base": "karnopp" if use_physical else "data_driven",
            "S": S,
            "J": J,
            "note": "for the Karnopp valve S = (Fs + Fc)/k and J = (Fs - Fc)/k "
            "(quasi-static equivalent, 1 % of span = 1 cm)"
            if use_physical
            else "stick-slip element, Section 5.1",
            "karnopp": kp_truth,
        },
        "process": (
            {"type": "integrating", "gain": gain, "dead_time_s": dead * ts}
            if integrating
            else {
                "type": "foptd",
                "gain": gain,
                "time_constant_s": time_constant,
                "dead_time_s": dead * ts,
            }
        ),
        "controller": {
            "type": "pi",
            "gain": Kc,
            "integral_time_s": Ti,
            "measurement_filter_s": filter_time,
            "op_bias": op_bias,
        },
        "pv_bias": pv0,
        "noise": {"pv_std": noise_std, "pv_ar1": noise_phi, "mv_std": mv_noise_std},
        "load": {
            "enters": "process input [% of span]",
            # Steps at negative times came before the record starts.
            "steps": [{"time_s": (t - _WARMUP_SAMPLES) * ts, "size": s} for t, s in load_step_list],
            "random_walk_range": walk_range,
            "lag_s": load_time,
        },
        "setpoint_changes": [
            {"time_s": (t - _WARMUP_SAMPLES) * ts, "size": s}
            for t, s in sp_list
            if t >= _WARMUP_SAMPLES
        ],
        "effect_parameters": effect_params,
    }
    hidden = {
        "valve_output": valve_out[keep].copy(),
        "position": position[keep].copy(),
        "flow": flow[keep].copy(),
        "load_input": load_in[keep].copy(),
        "output_disturbance": load_out[keep].copy(),
        "pv_clean": pv_clean[keep].copy(),
        "S_open": S_open[keep].copy(),
        "J_open": J_open[keep].copy(),
        "S_close": S_close[keep].copy(),
        "J_close": J_close[keep].copy(),
    }
    return SyntheticCase(data=data, truth=_plain(truth), hidden=hidden)


def _csv_bytes(data: pd.DataFrame, decimals: int = 6) -> bytes:
    """CSV text of ``data`` (header unquoted, values rounded to ``decimals``).

    pyarrow's writer is an order of magnitude faster than pandas' for the ~10 MB of
    a 40-case benchmark.
    """
    table = pa.Table.from_pandas(data.round(decimals), preserve_index=False)
    sink = pa.BufferOutputStream()
    options = pa_csv.WriteOptions(include_header=False, quoting_style="none")
    pa_csv.write_csv(table, sink, write_options=options)
    header = (",".join(data.columns) + "\n").encode()
    return header + sink.getvalue().to_pybytes()


def benchmark_effects(n_cases: int, seed: int) -> list[str]:
    """Effects of a benchmark of ``n_cases``: balanced, in a seed-dependent order.

    Each effect appears ``n_cases // len(EFFECTS)`` times at least; the remainder
    goes round-robin in :data:`EFFECTS` order. The order of the cases is shuffled so
    the position of a file does not give its effect away.
    """
    effects = [EFFECTS[i % len(EFFECTS)] for i in range(n_cases)]
    order = np.random.default_rng(np.random.SeedSequence([int(seed), 7919])).permutation(n_cases)
    return [effects[i] for i in order]


def write_benchmark(out_dir: str | Path, n_cases: int, seed: int) -> list[tuple[Path, dict]]:
    """Write a withheld-effect benchmark: one CSV per case plus ``truth.json``.

    Parameters
    ----------
    out_dir : str or Path
        Directory (created if missing). Files ``case_000.csv`` ... hold the columns
        ``time, sp, pv, op, mv``; ``truth.json`` maps each file to its truth.
    n_cases : int
        Number of cases (>= 1), balanced across :data:`EFFECTS`.
    seed : int
        Benchmark seed; the same seed writes the same files.

    Returns
    -------
    list of (Path, dict)
        CSV path and truth of every case, in file order.
    """
    if int(n_cases) < 1:
        raise UsageError(f"n_cases must be at least 1, got {n_cases}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    effects = benchmark_effects(int(n_cases), int(seed))
    seeds = np.random.SeedSequence(int(seed)).generate_state(len(effects), dtype=np.uint32)
    width = max(3, len(str(len(effects) - 1)))
    written: list[tuple[Path, dict]] = []
    for i, (effect, case_seed) in enumerate(zip(effects, seeds, strict=True)):
        case = generate_case(effect, int(case_seed))
        path = out / f"case_{i:0{width}d}.csv"
        path.write_bytes(_csv_bytes(case.data))
        truth = dict(case.truth, file=path.name)
        written.append((path, truth))
    manifest = {
        "seed": int(seed),
        "n_cases": len(written),
        "effects": list(EFFECTS),
        "cases": [t for _, t in written],
    }
    write_atomic(out / "truth.json", json.dumps(manifest, indent=1))
    return written
