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
from stictiondiag.core.serialize import to_plain
from stictiondiag.models.synthetic_effects import (
    PILOT_EFFECTS,
    PRE_RUN_EFFECTS,
    WARMUP_SAMPLES,
    CaseDraft,
    draw_disturbances,
    draw_process_and_tuning,
    draw_sampling,
    run_case,
)

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

    use_physical = bool(rng.random() < PHYSICAL_SHARE) if physical is None else bool(physical)
    w = draw_sampling(rng, use_physical, n_samples, ts, KARNOPP_PARAMETERS)
    draw_process_and_tuning(rng, w)
    draw_disturbances(rng, w)
    # "none": the base valve alone.
    if effect in PRE_RUN_EFFECTS:
        PRE_RUN_EFFECTS[effect](rng, w)
    elif effect in PILOT_EFFECTS:
        # A pilot run of the same loop sizes the effect against what the loop does.
        PILOT_EFFECTS[effect](rng, w, run_case(w, 0.0, w.load_out))
    pv, op, valve_out, position, flow, pv_clean = run_case(w, w.pv_quantum_instrument, w.load_out)

    keep = slice(WARMUP_SAMPLES, w.n_total)
    data = _recorded_data(w, pv[keep].copy(), op[keep], position[keep])
    hidden = _hidden(w, valve_out, position, flow, pv_clean)
    return SyntheticCase(data=data, truth=to_plain(_truth(w, effect, seed)), hidden=hidden)


def _recorded_data(
    w: CaseDraft, pv: np.ndarray, op: np.ndarray, position: np.ndarray
) -> pd.DataFrame:
    """What the diagnosis sees: ``mv`` with transmitter noise, clipped to the span and
    quantised, ``pv`` quantised in the historian (arguments and result over the record)."""
    keep = slice(WARMUP_SAMPLES, w.n_total)
    mv = position + w.mv_noise[keep]
    mv = np.clip(mv, 0.0, 100.0)
    if w.mv_quantum > 0.0:
        mv = w.mv_quantum * np.floor(mv / w.mv_quantum + 0.5)
    if w.pv_quantum_historian > 0.0:
        pv = w.pv_quantum_historian * np.floor(pv / w.pv_quantum_historian + 0.5)
    time = np.arange(w.n) * w.ts
    return pd.DataFrame(
        {"time": time, "sp": w.sp[keep], "pv": pv, "op": op, "mv": mv},
        columns=["time", "sp", "pv", "op", "mv"],
    )


def _hidden(
    w: CaseDraft,
    valve_out: np.ndarray,
    position: np.ndarray,
    flow: np.ndarray,
    pv_clean: np.ndarray,
) -> dict[str, np.ndarray]:
    """Noise-free internal signals over the record (see :class:`SyntheticCase`)."""
    keep = slice(WARMUP_SAMPLES, w.n_total)
    return {
        "valve_output": valve_out[keep].copy(),
        "position": position[keep].copy(),
        "flow": flow[keep].copy(),
        "load_input": w.load_in[keep].copy(),
        "output_disturbance": w.load_out[keep].copy(),
        "pv_clean": pv_clean[keep].copy(),
        "S_open": w.S_open[keep].copy(),
        "J_open": w.J_open[keep].copy(),
        "S_close": w.S_close[keep].copy(),
        "J_close": w.J_close[keep].copy(),
    }


def _karnopp_truth(w: CaseDraft, effect: str) -> dict | None:
    """Karnopp valve constants and the forces at the start of the record (None for the
    stick-slip element)."""
    if not w.use_physical:
        return None
    kp = KARNOPP_PARAMETERS
    k_spring = kp["spring_constant_N_per_m"]
    m_per_pct = kp["stem_m_per_percent"]
    S, J = w.S, w.J
    return {
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


def _truth(w: CaseDraft, effect: str, seed: int) -> dict:
    """The truth of a case (see :class:`SyntheticCase`); times relative to the record."""
    ts = w.ts
    return {
        "effect": effect,
        "seed": int(seed),
        "S": w.S,
        "J": w.J,
        "units": "% of span",
        "ts": ts,
        "n_samples": w.n,
        "valve": {
            "base": "karnopp" if w.use_physical else "data_driven",
            "S": w.S,
            "J": w.J,
            "note": "for the Karnopp valve S = (Fs + Fc)/k and J = (Fs - Fc)/k "
            "(quasi-static equivalent, 1 % of span = 1 cm)"
            if w.use_physical
            else "stick-slip element, Section 5.1",
            "karnopp": _karnopp_truth(w, effect),
        },
        "process": (
            {"type": "integrating", "gain": w.gain, "dead_time_s": w.dead * ts}
            if w.integrating
            else {
                "type": "foptd",
                "gain": w.gain,
                "time_constant_s": w.time_constant,
                "dead_time_s": w.dead * ts,
            }
        ),
        "controller": {
            "type": "pi",
            "gain": w.Kc,
            "integral_time_s": w.Ti,
            "measurement_filter_s": w.filter_time,
            "op_bias": w.op_bias,
        },
        "pv_bias": w.pv0,
        "noise": {"pv_std": w.noise_std, "pv_ar1": w.noise_phi, "mv_std": w.mv_noise_std},
        "load": {
            "enters": "process input [% of span]",
            # Steps at negative times came before the record starts.
            "steps": [
                {"time_s": (t - WARMUP_SAMPLES) * ts, "size": s} for t, s in w.load_step_list
            ],
            "random_walk_range": w.walk_range,
            "lag_s": w.load_time,
        },
        "setpoint_changes": [
            {"time_s": (t - WARMUP_SAMPLES) * ts, "size": s}
            for t, s in w.sp_list
            if t >= WARMUP_SAMPLES
        ],
        "effect_parameters": w.effect_params,
    }


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


#: Most cases one benchmark may have: each costs seconds of CPU to diagnose, so more
#: would run for days (the CLI's ``--cases`` has the same bound).
MAX_BENCHMARK_CASES = 100_000


def check_benchmark(n_cases: object, seed: object) -> tuple[int, int]:
    """``(n_cases, seed)`` as ints, or a UsageError saying what is wrong."""
    for name, value in (("n_cases", n_cases), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, int | np.integer):
            raise UsageError(f"{name} must be a whole number, not {value!r}")
    n, s = int(n_cases), int(seed)  # type: ignore[call-overload]
    if not 1 <= n <= MAX_BENCHMARK_CASES:
        raise UsageError(f"n_cases must be between 1 and {MAX_BENCHMARK_CASES:,}, got {n}")
    if not 0 <= s < 2**32:
        raise UsageError(f"seed must be between 0 and {2**32 - 1}, got {s}")
    return n, s


def iter_benchmark(out_dir: str | Path, n_cases: int, seed: int):
    """Write the cases of a withheld-effect benchmark one at a time, lazily.

    Yields ``(path, truth)`` after each case's CSV is written (whole or not at
    all); a case is simulated only when the caller asks for it, so memory does not
    grow with ``n_cases``.  Same files as :func:`write_benchmark` (without
    ``truth.json``).

    Raises
    ------
    UsageError
        ``n_cases`` outside 1 to :data:`MAX_BENCHMARK_CASES`, a seed outside
        0 to 2**32 - 1, or either not a whole number.
    """
    n, s = check_benchmark(n_cases, seed)
    out = Path(out_dir)
    # Each effect n // len(EFFECTS) times at least, the remainder round-robin, in a
    # seed-dependent order (as benchmark_effects): case i's effect is that of
    # position order[i] of the round-robin list.
    order = np.random.default_rng(np.random.SeedSequence([s, 7919])).permutation(n)
    seeds = np.random.SeedSequence(s).generate_state(n, dtype=np.uint32)
    width = max(3, len(str(n - 1)))
    for i in range(n):
        effect = EFFECTS[int(order[i]) % len(EFFECTS)]
        case = generate_case(effect, int(seeds[i]))
        path = out / f"case_{i:0{width}d}.csv"
        write_atomic(path, _csv_bytes(case.data))
        yield path, dict(case.truth, file=path.name)


def write_benchmark_truth(out_dir: str | Path, seed: int, truths: list[dict]) -> None:
    """Write ``truth.json`` of a benchmark: each case file's hidden truth."""
    manifest = {
        "seed": int(seed),
        "n_cases": len(truths),
        "effects": list(EFFECTS),
        "cases": truths,
    }
    write_atomic(Path(out_dir) / "truth.json", json.dumps(manifest, indent=1))


def write_benchmark(out_dir: str | Path, n_cases: int, seed: int) -> list[tuple[Path, dict]]:
    """Write a withheld-effect benchmark: one CSV per case plus ``truth.json``.

    Parameters
    ----------
    out_dir : str or Path
        Directory (created if missing). Files ``case_000.csv`` ... hold the columns
        ``time, sp, pv, op, mv``; ``truth.json`` maps each file to its truth.
    n_cases : int
        Number of cases (1 to :data:`MAX_BENCHMARK_CASES`), balanced across
        :data:`EFFECTS`.
    seed : int
        Benchmark seed (0 to 2**32 - 1); the same seed writes the same files.

    Returns
    -------
    list of (Path, dict)
        CSV path and truth of every case, in file order.
    """
    written = list(iter_benchmark(out_dir, n_cases, seed))
    write_benchmark_truth(out_dir, seed, [t for _, t in written])
    return written
