"""Steps of the withheld-effect benchmark generator (:mod:`stictiondiag.models.synthetic`).

:func:`stictiondiag.models.synthetic.generate_case` runs these in order on one working
record (:class:`CaseDraft`): sampling and friction, process and PI tuning, disturbances,
then the hidden effect (before the run, or sized on a pilot run of the same loop), then
the closed-loop run. Every random draw comes from the one generator the caller passes
in, in the order of the steps, so a seed gives the same case whatever the layout of the
code. The effects are described in the module docstring of
:mod:`stictiondiag.models.synthetic`; the friction elements (Choudhury, Thornhill &
Shah 2005, Section 5.1 stick-slip element and Section 4.1 Karnopp valve) live in
:mod:`stictiondiag.models.synthetic_loop`. Like them, this module imports nothing from
the diagnosis side of :mod:`stictiondiag`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.models.synthetic_loop import closed_loop, flow_characteristic

_DEFAULT_N_RANGE = (5000, 10000)
_TS_CHOICES = (0.5, 1.0, 2.0, 5.0)
_TS_CHOICES_PHYSICAL = (0.5, 1.0, 2.0)
WARMUP_SAMPLES = 1500

# Characteristic codes understood by the kernel.
_CHAR_LINEAR, _CHAR_EQUAL_PERCENTAGE, _CHAR_QUICK_OPENING = 0, 1, 2


# --------------------------------------------------------------------------------------
# Signal and loop helpers
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
    physical: bool,
    S_open: float,
    J_open: float,
    S_close: float,
    J_close: float,
    spring_constant: float,
) -> dict[str, float]:
    """Per-direction S and J [% of span] that the data show.

    For the stick-slip element they are its parameters. For the Karnopp valve the
    parameters set the forces, ``Fs = k (S + J)/2`` and ``Fc = k (S - J)/2`` per
    direction; a valve that stopped closing holds ``Fc_close`` and must build up
    ``Fs_open`` to open, so the opening band is ``(Fs_open + Fc_close)/k`` while the
    slip jump stays ``(Fs - Fc)/k`` of the moving direction. ``spring_constant`` is
    ``k`` [N/m]; 1 % of span is 1 cm of stem travel.
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
        "Fs_open_N": spring_constant * 0.01 * Fs_o,
        "Fc_open_N": spring_constant * 0.01 * Fc_o,
        "Fs_close_N": spring_constant * 0.01 * Fs_c,
        "Fc_close_N": spring_constant * 0.01 * Fc_c,
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


# --------------------------------------------------------------------------------------
# Working record
# --------------------------------------------------------------------------------------


@dataclass
class CaseDraft:
    """One case while it is drawn; each step fills or changes its own fields.

    Mutable on purpose and private: the frozen result is
    :class:`stictiondiag.models.synthetic.SyntheticCase`. Arrays run over the warm-up
    and the record, ``n + WARMUP_SAMPLES`` samples.
    """

    # Sampling and base valve.
    karnopp: dict[str, float]  # Karnopp valve constants (Table 1) and integration settings
    use_physical: bool  # Karnopp valve (True) or stick-slip element (False)
    ts: float  # sample time [s]
    n: int  # recorded samples
    S: float  # deadband plus stickband [% of span]
    J: float  # slip jump [% of span]
    # Process and PI controller.
    integrating: bool = False
    gain: float = 0.0  # process gain [pv units / %] (integrating: [pv units / (% s)])
    time_constant: float = 1.0  # [s]
    dead: int = 0  # dead time [samples]
    Kc: float = 0.0  # controller gain [% / pv unit]
    Ti: float = 0.0  # integral time [s]
    pv_per_pct: float = 0.0  # pv movement for 1 % of valve [pv units / %]
    filter_time: float = 0.0  # measurement filter [s]
    filter_weight: float = 1.0  # its discrete weight [-]
    op_bias: float = 0.0  # [% of span]
    pv0: float = 0.0  # operating point [pv units]
    # Disturbances, set point and noise.
    load_in: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [% of span]
    load_step_list: list = field(default_factory=list)  # (sample, size [% of span])
    walk_range: float = 0.0  # random-walk load spread [% of span]
    load_time: float = 0.0  # load lag [s]
    sp: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [pv units]
    sp_list: list = field(default_factory=list)  # (sample, size [pv units])
    noise: np.ndarray = field(default_factory=lambda: np.zeros(0))  # pv noise [pv units]
    noise_std: float = 0.0  # [pv units]
    noise_phi: float = 0.0  # AR(1) pole [-]
    mv_noise: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [% of span]
    mv_noise_std: float = 0.0  # [% of span]
    # Effect (neutral values until an effect step changes them).
    S_open: np.ndarray = field(init=False)  # per-sample friction [% of span]
    J_open: np.ndarray = field(init=False)
    S_close: np.ndarray = field(init=False)
    J_close: np.ndarray = field(init=False)
    cal_gain: float = 1.0  # positioner span gain [-]
    cal_pivot: float = 0.0  # [% of span]
    lag_time: float = 0.0  # actuator lag [s]
    char_kind: int = _CHAR_LINEAR
    rangeability: float = 1.0  # or quick-opening exponent [-]
    authority: float = 1.0  # [-]
    flow0: float = 0.0  # installed flow at the operating point [% of span]
    dflow0: float = 1.0  # its slope there [-]
    pv_quantum_instrument: float = 0.0  # [pv units]
    pv_quantum_historian: float = 0.0  # [pv units]
    mv_quantum: float = 0.0  # [% of span]
    load_out: np.ndarray = field(init=False)  # output disturbance [pv units]
    effect_params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n_total = self.n_total
        self.S_open = np.full(n_total, self.S)
        self.J_open = np.full(n_total, self.J)
        self.S_close = np.full(n_total, self.S)
        self.J_close = np.full(n_total, self.J)
        self.load_out = np.zeros(n_total)

    @property
    def n_total(self) -> int:
        """Samples simulated: warm-up plus record."""
        return self.n + WARMUP_SAMPLES


# --------------------------------------------------------------------------------------
# Loop: sampling, process and tuning, disturbances, the run
# --------------------------------------------------------------------------------------


def draw_sampling(
    rng: np.random.Generator,
    use_physical: bool,
    n_samples: int | None,
    ts: float | None,
    karnopp: dict[str, float],
) -> CaseDraft:
    """Sample time, record length, S and J; ``n_samples``/``ts`` override the draws."""
    ts_choice = float(rng.choice(_TS_CHOICES_PHYSICAL if use_physical else _TS_CHOICES))
    n_draw = int(rng.integers(_DEFAULT_N_RANGE[0], _DEFAULT_N_RANGE[1] + 1))
    ts = ts_choice if ts is None else float(ts)
    n = n_draw if n_samples is None else int(n_samples)

    S = float(rng.uniform(0.8, 6.0))
    J = float(S * rng.uniform(0.25, 1.0) if use_physical else S * rng.uniform(0.25, 1.4))
    return CaseDraft(karnopp=karnopp, use_physical=use_physical, ts=ts, n=n, S=S, J=J)


def draw_process_and_tuning(rng: np.random.Generator, w: CaseDraft) -> None:
    """Process and PI tuning (SIMC rules, randomly detuned), filter and operating point."""
    ts = w.ts
    w.integrating = bool(rng.random() < 0.35)
    if w.integrating:
        w.gain = float(rng.uniform(0.002, 0.02) / ts)  # pv units / (% s)
        w.time_constant = 1.0
        w.dead = int(rng.integers(0, 11))
        closed_loop_time = float(rng.uniform(10.0, 60.0) * ts)
        w.Kc = 1.0 / (w.gain * (closed_loop_time + w.dead * ts))
        w.Ti = 4.0 * (closed_loop_time + w.dead * ts) * float(rng.uniform(0.7, 1.5))
        w.pv_per_pct = w.gain * (closed_loop_time + w.dead * ts)
    else:
        w.gain = float(rng.uniform(0.3, 3.0))
        w.time_constant = float(rng.uniform(8.0, 60.0) * ts)
        dead = int(round(rng.uniform(0.0, 0.5) * w.time_constant / ts))
        w.dead = min(dead, 60)
        closed_loop_time = max(w.dead * ts, 0.2 * w.time_constant) * float(rng.uniform(1.0, 3.0))
        w.Kc = w.time_constant / (w.gain * (closed_loop_time + w.dead * ts))
        w.Ti = min(w.time_constant, 4.0 * (closed_loop_time + w.dead * ts)) * float(
            rng.uniform(0.6, 1.5)
        )
        w.pv_per_pct = w.gain
    w.filter_time = float(rng.uniform(0.0, 3.0) * ts)
    w.filter_weight = ts / (w.filter_time + ts)

    w.op_bias = float(rng.uniform(35.0, 65.0))
    w.pv0 = float(np.round(rng.uniform(20.0, 80.0), 1))


def draw_disturbances(rng: np.random.Generator, w: CaseDraft) -> None:
    """Load steps and random walk at the process input, set-point steps, noise."""
    ts, n_total = w.ts, w.n_total
    # Load steps move the operating point across at least 15 % of the valve span,
    # so that any operating-point dependent effect has room to show.
    for _ in range(50):
        n_load_steps = int(rng.integers(2, 5))
        load_steps, w.load_step_list = _step_schedule(
            rng, n_total, n_load_steps, rng.uniform(6.0, 18.0, n_load_steps), 25.0
        )
        if np.ptp(load_steps) >= 15.0:
            break
    w.walk_range = float(rng.uniform(1.0, 6.0))
    walk = np.cumsum(rng.standard_normal(n_total)) * w.walk_range / math.sqrt(n_total)
    w.load_time = float(rng.uniform(5.0, 30.0) * ts)
    w.load_in = _first_order(load_steps + walk, ts / (w.load_time + ts))

    n_sp = int(rng.integers(0, 4))
    if w.integrating:
        sp_sizes = rng.uniform(3.0, 10.0, n_sp) / w.Kc
    else:
        sp_sizes = rng.uniform(4.0, 12.0, n_sp) * w.gain
    sp_dev, w.sp_list = _step_schedule(rng, n_total, n_sp, sp_sizes, 20.0 * w.pv_per_pct)
    w.sp = w.pv0 + sp_dev

    w.noise_std = float(rng.uniform(0.03, 0.15) * w.pv_per_pct * max(w.J, 0.5 * w.S))
    w.noise_phi = float(rng.uniform(0.0, 0.6))
    w.noise = _ar1_noise(rng, n_total, w.noise_std, w.noise_phi)
    w.mv_noise_std = float(rng.uniform(0.03, 0.15))
    w.mv_noise = rng.standard_normal(n_total) * w.mv_noise_std


def run_case(w: CaseDraft, pv_quantum: float, output_disturbance: np.ndarray) -> tuple:
    """The closed loop as drawn so far: ``(pv, op, valve_out, position, flow, pv_clean)``."""
    kp = w.karnopp
    return closed_loop(
        w.ts,
        w.integrating,
        w.gain,
        w.time_constant,
        w.dead,
        w.Kc,
        w.Ti,
        w.filter_weight,
        w.op_bias,
        w.pv0,
        pv_quantum,
        w.sp,
        w.load_in,
        output_disturbance,
        w.noise,
        w.use_physical,
        w.S_open,
        w.J_open,
        w.S_close,
        w.J_close,
        w.cal_gain,
        w.cal_pivot,
        1.0 - math.exp(-w.ts / w.lag_time) if w.lag_time > 0.0 else 1.0,
        w.char_kind,
        w.rangeability,
        w.authority,
        w.flow0,
        w.dflow0,
        kp["mass_kg"],
        kp["spring_constant_N_per_m"],
        kp["viscous_friction_N_s_per_m"],
        kp["stem_m_per_percent"],
        kp["substep_s"],
        kp["stick_velocity_m_per_s"],
    )


# --------------------------------------------------------------------------------------
# Effects drawn before the run
# --------------------------------------------------------------------------------------


def _actuator_lag(rng: np.random.Generator, w: CaseDraft) -> None:
    """First-order positioner lag of 2-6 samples after the friction element."""
    w.lag_time = float(rng.uniform(2.0, 6.0) * w.ts)
    # A lag shows on slips: keep them clear of the position-transmitter noise.
    quieter = min(w.mv_noise_std, w.J / 10.0)
    w.mv_noise = w.mv_noise * (quieter / w.mv_noise_std)
    w.mv_noise_std = quieter
    w.effect_params = {"lag_time_constant_s": w.lag_time, "lag_samples": w.lag_time / w.ts}


def _miscalibration(rng: np.random.Generator, w: CaseDraft) -> None:
    """Positioner span error ``pivot + gain (op - pivot)`` (Section 4.2.1, Fig. 8)."""
    # The slope shows in the moving phase, which a valve with J >= S in an
    # integrating loop hardly has: keep some deadband.
    w.J = min(w.J, 0.8 * w.S)
    w.J_open[:] = w.J
    w.J_close[:] = w.J
    if rng.random() < 0.5:
        w.cal_gain = float(rng.uniform(0.65, 0.8))
    else:
        w.cal_gain = float(rng.uniform(1.2, 1.4))
    w.cal_pivot = float(rng.uniform(0.0, w.op_bias))
    # op moves 1/gain times as far as the valve must: scale the load so the
    # demand stays inside the travel.
    w.load_in = w.load_in * min(w.cal_gain, 1.0)
    w.effect_params = {
        "calibration_gain": w.cal_gain,
        "calibration_pivot_pct": w.cal_pivot,
        "S_on_op_axis": w.S / w.cal_gain,
        "note": "valve demand = pivot + gain (op - pivot); S, J act on the demand",
    }


def _asymmetry(rng: np.random.Generator, w: CaseDraft) -> None:
    """Different S and J opening and closing (Loop 1, Section 3)."""
    S, J = w.S, w.J
    s_o, s_c = _equal_split(rng, float(rng.uniform(1.8, 3.0)))
    if w.use_physical:
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
    w.S_open[:], w.S_close[:] = base_S * s_o, base_S * s_c
    w.J_open[:], w.J_close[:] = base_J * j_o, base_J * j_c
    if w.use_physical:
        # Coulomb friction must stay >= 0: J <= S in each direction.
        w.J_open[:] = np.minimum(w.J_open, 0.95 * w.S_open)
        w.J_close[:] = np.minimum(w.J_close, 0.95 * w.S_close)
    directional = _directional_equivalents(
        w.use_physical,
        w.S_open[0],
        w.J_open[0],
        w.S_close[0],
        w.J_close[0],
        w.karnopp["spring_constant_N_per_m"],
    )
    w.S = math.sqrt(directional["S_open"] * directional["S_close"])
    w.J = math.sqrt(directional["J_open"] * directional["J_close"])
    w.effect_params = dict(directional)
    w.effect_params["note"] = (
        "S_open: op travel after a reversal before an opening slip; J_open: opening "
        "slip jump; S and J are the geometric means of the two directions"
    )


def _time_varying_stiction(rng: np.random.Generator, w: CaseDraft) -> None:
    """S and J scaled by 2-3 (or 1/3-1/2) during the record, as a step or a ramp."""
    n, n_total = w.n, w.n_total
    factor = float(rng.uniform(2.0, 3.0))
    if rng.random() < 0.5:
        factor = 1.0 / factor
    start = int(WARMUP_SAMPLES + rng.uniform(0.3, 0.5) * n)
    if rng.random() < 0.5:
        kind = "step"
        profile = np.where(np.arange(n_total) >= start, factor, 1.0)
        end = start
    else:
        kind = "ramp"
        end = int(start + rng.uniform(0.1, 0.2) * n)
        profile = np.interp(np.arange(n_total), [start, end], [1.0, factor])
    for arr in (w.S_open, w.J_open, w.S_close, w.J_close):
        arr *= profile
    w.effect_params = {
        "change": kind,
        "factor": factor,
        "start_s": (start - WARMUP_SAMPLES) * w.ts,
        "end_s": (end - WARMUP_SAMPLES) * w.ts,
        "S_start": w.S,
        "J_start": w.J,
        "S_end": w.S * factor,
        "J_end": w.J * factor,
    }


# --------------------------------------------------------------------------------------
# Effects sized on a pilot run of the same loop
# --------------------------------------------------------------------------------------


def _valve_characteristic(rng: np.random.Generator, w: CaseDraft, pilot: tuple) -> None:
    """Equal-percentage or quick-opening installed characteristic, drawn until the
    installed gain differs by half between the ends of the travel the loop visits
    (5th-95th percentile of the pilot's valve position)."""
    lo, hi = np.percentile(pilot[3][WARMUP_SAMPLES:], [5.0, 95.0])
    position0 = w.cal_pivot + w.cal_gain * (w.op_bias - w.cal_pivot)
    need_lo, need_hi = np.percentile(pilot[3][WARMUP_SAMPLES:] - position0, [1.0, 99.0])
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
        reach_lo = (flow_characteristic(2.0, char_kind, rangeability, authority) - flow0) / dflow0
        reach_hi = (flow_characteristic(98.0, char_kind, rangeability, authority) - flow0) / dflow0
        if (
            max(slopes) >= 1.5 * min(slopes)
            and reach_lo <= need_lo - 3.0
            and reach_hi >= need_hi + 3.0
        ):
            break
    w.char_kind, w.rangeability, w.authority = char_kind, rangeability, authority
    w.flow0 = float(flow_characteristic(position0, char_kind, rangeability, authority))
    w.dflow0 = _flow_slope(char_kind, rangeability, authority, position0)
    equal_percentage = char_kind == _CHAR_EQUAL_PERCENTAGE
    w.effect_params = {
        "characteristic": "equal_percentage" if equal_percentage else "quick_opening",
        "rangeability": rangeability if equal_percentage else None,
        "quick_opening_exponent": rangeability if char_kind == _CHAR_QUICK_OPENING else None,
        "authority": authority,
        "gain_ratio_over_travel": max(slopes) / min(slopes),
        "note": "mv is the stem position; the process sees the installed flow, "
        "scaled to the linear valve's slope at the operating point",
    }


def _quantization(rng: np.random.Generator, w: CaseDraft, pilot: tuple) -> None:
    """``mv`` to 0.5-2 % of span, ``pv`` to 12-40 levels of its pilot range, or both
    (Loop 4, Section 3); ``pv`` at the instrument or in the historian."""
    pilot_pv = pilot[0][WARMUP_SAMPLES:]
    where = str(rng.choice(["mv", "pv", "both"]))
    levels = float(rng.uniform(12.0, 40.0))
    spread = float(np.percentile(pilot_pv, 99) - np.percentile(pilot_pv, 1))
    pv_quantum = max(spread / levels, 3.0 * w.noise_std)
    mode = "instrument" if rng.random() < 0.5 else "historian"
    if where in ("pv", "both"):
        if mode == "instrument":
            w.pv_quantum_instrument = pv_quantum
        else:
            w.pv_quantum_historian = pv_quantum
    if where in ("mv", "both"):
        mv_quantum = float(rng.uniform(0.5, 2.0))
        w.mv_quantum = max(mv_quantum, 3.0 * w.mv_noise_std)
    w.effect_params = {
        "quantised": where,
        "pv_quantum": pv_quantum if where in ("pv", "both") else None,
        "pv_resolution": mode if where in ("pv", "both") else None,
        "mv_quantum_pct": w.mv_quantum if where in ("mv", "both") else None,
    }


def _external_disturbance(rng: np.random.Generator, w: CaseDraft, pilot: tuple) -> None:
    """Periodic load at the process output, its period at least 40 % away from the
    pilot's own cycle, sized by what gets through the controller to pv."""
    pilot_err = pilot[0][WARMUP_SAMPLES:] - w.sp[WARMUP_SAMPLES:]
    ts = w.ts
    own_period = _dominant_period(pilot_err, ts)
    for _ in range(100):
        period = float(rng.uniform(15.0, 200.0) * ts)
        if own_period <= 0.0 or not (0.6 < period / own_period < 1.6):
            break
    omega = 2.0 * math.pi / period
    # Size the line by what reaches pv: the loop takes out a slow
    # disturbance, by the linear sensitivity 1/(1 + G C F) at its frequency.
    in_pv = max(float(rng.uniform(0.7, 1.5) * np.std(pilot_err)), 5.0 * w.noise_std)
    sensitivity = _linear_sensitivity(
        omega, w.integrating, w.gain, w.time_constant, w.dead * ts, w.Kc, w.Ti, w.filter_time
    )
    amplitude = in_pv / max(sensitivity, 0.1)
    phase = float(rng.uniform(0.0, 2.0 * math.pi))
    harmonic = float(rng.uniform(0.0, 0.3))
    t_all = np.arange(w.n_total) * ts
    w.load_out = amplitude * (
        np.sin(omega * t_all + phase) + harmonic * np.sin(2.0 * omega * t_all + 2.0 * phase)
    )
    w.effect_params = {
        "period_s": period,
        "amplitude": amplitude,
        "amplitude_in_pv_linear": amplitude * max(sensitivity, 0.1),
        "second_harmonic_ratio": harmonic,
        "loop_period_without_disturbance_s": own_period if own_period > 0 else None,
        "enters": "process output",
    }


#: Effects drawn before the loop runs.
PRE_RUN_EFFECTS: dict[str, Callable[[np.random.Generator, CaseDraft], None]] = {
    "actuator_lag": _actuator_lag,
    "miscalibration": _miscalibration,
    "asymmetry": _asymmetry,
    "time_varying_stiction": _time_varying_stiction,
}

#: Effects sized against a pilot run of the loop without them.
PILOT_EFFECTS: dict[str, Callable[[np.random.Generator, CaseDraft, tuple], None]] = {
    "valve_characteristic": _valve_characteristic,
    "quantization": _quantization,
    "external_disturbance": _external_disturbance,
}
