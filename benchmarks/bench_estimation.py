"""Accuracy and speed of the stiction estimators on simulated closed loops.

Closed PI loops (:func:`stictiondiag.models.loops.simulate_loop`) with a sticky valve, S drawn
from 1-8 % and J from 0-1.4 S, self-regulating (FOPTD) and integrating processes,
three levels of measurement noise on pv.  Noise-free loops use the published
flowchart (Fig. 10); noisy loops use Kano's variant, because the published flowchart
re-arms at every noise reversal of op and its valve never slips (Section 5.1 asks for
a filter in front of it).  The FOPTD loops get a slow set-point square wave, so that
loops with a pure deadband (J = 0, no limit cycle in a FOPTD loop, Section 5.3.1)
still move their valve.

For every loop the script runs :func:`stictiondiag.stiction.segments.estimate_from_mv`
(valve position recorded) and :func:`stictiondiag.stiction.hammerstein.fit_hammerstein`
(op and pv only) and prints one row per loop, then the median absolute errors of S
and J [% of span] by estimator, process and noise level, the share of loops whose
reported interval holds the truth, the share called stiction / no stiction by
:func:`stictiondiag.stiction.valvefit.stiction_verdict` (every loop has a sticky valve), and the
wall time per fit (the first fit of a fresh install includes numba compilation).

Usage::

    python benchmarks/bench_estimation.py [--cases N] [--seed SEED] [--samples N]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import (
    FOPTD,
    PI,
    Integrating,
)
from stictiondiag.signals.oscillation import detect_oscillation
from stictiondiag.stiction.cause import find_cycle
from stictiondiag.stiction.hammerstein import fit_hammerstein
from stictiondiag.stiction.segments import estimate_from_mv
from stictiondiag.stiction.verdict import stiction_verdict

#: Measurement noise levels: standard deviation of the noise on pv as a fraction of
#: the standard deviation of the noise-free pv.
NOISE_LEVELS = (0.0, 0.03, 0.1)


def make_case(rng: np.random.Generator, integrating: bool, noise: float, n: int) -> dict:
    """One simulated loop: settings, the truth and the recorded signals."""
    S = float(rng.uniform(1.0, 8.0))
    J = float(rng.uniform(0.0, 1.4 * S))
    if integrating:
        K = float(rng.uniform(0.05, 0.5))
        theta = float(rng.uniform(0.0, 3.0))
        process = Integrating(gain=K, dead_time=theta)
        controller = PI(gain=0.4 / K / (1.0 + theta), integral_time=2.0 + 4.0 * theta)
        dt = 0.1
        sp_amp, sp_period = 0.0, None
    else:
        K = float(rng.uniform(0.5, 3.0))
        tau = float(rng.uniform(5.0, 20.0))
        theta = float(rng.uniform(2.0, 10.0))
        process = FOPTD(gain=K, time_constant=tau, dead_time=theta)
        controller = PI(gain=0.4 * tau / (K * theta), integral_time=tau)
        dt = theta / 10.0
        sp_amp, sp_period = 0.5 * K * S, 60.0 * (tau + theta)
    warm = n // 5
    total = n + warm
    t = np.arange(total) * dt
    sp = 0.0 if sp_period is None else sp_amp * np.sign(np.sin(2 * np.pi * t / sp_period))
    valve = "kano" if noise > 0 else "choudhury"
    seed = int(rng.integers(2**31))
    clean = simulate_loop(
        process, controller, duration=total * dt, dt=dt, valve=valve, S=S, J=J, sp=sp, kick=2.0
    )
    noise_std = noise * float(np.std(clean.pv[warm:]))
    sim = clean
    if noise_std > 0:
        sim = simulate_loop(
            process,
            controller,
            duration=total * dt,
            dt=dt,
            valve=valve,
            S=S,
            J=J,
            sp=sp,
            kick=2.0,
            noise_std=noise_std,
            seed=seed,
        )
    return {
        "S": S,
        "J": J,
        "integrating": integrating,
        "noise": noise,
        "dt": dt,
        "op": sim.op[warm:],
        "mv": sim.mv[warm:],
        "pv": sim.pv[warm:],
    }


def run(n_cases: int, seed: int, n_samples: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_cases):
        integrating = bool(i % 2)
        noise = NOISE_LEVELS[(i // 2) % len(NOISE_LEVELS)]
        case = make_case(rng, integrating, noise, n_samples)
        t0 = time.perf_counter()
        fm = estimate_from_mv(case["op"], case["mv"], case["dt"])
        t1 = time.perf_counter()
        fh = fit_hammerstein(
            case["op"], case["pv"], case["dt"], integrating=integrating, flow_loop=False
        )
        t2 = time.perf_counter()
        osc_pv = detect_oscillation(case["pv"], case["dt"])
        osc_op = detect_oscillation(case["op"], case["dt"])
        for name, fit, secs in (("mv", fm, t1 - t0), ("hammerstein", fh, t2 - t1)):
            S_iv, J_iv = fit.S_interval, fit.J_interval
            cycle = find_cycle(osc_pv, osc_op, short_record=False)
            verdict = stiction_verdict(fit, osc_pv, oscillation_op=osc_op, cycle=cycle)
            rows.append(
                {
                    "case": i,
                    "estimator": name,
                    "process": "integrating" if integrating else "foptd",
                    "noise": noise,
                    "S": case["S"],
                    "J": case["J"],
                    "S_hat": fit.S,
                    "J_hat": fit.J,
                    "S_err": fit.S - case["S"],
                    "J_err": fit.J - case["J"],
                    "S_in": S_iv is not None and S_iv[0] <= case["S"] <= S_iv[1],
                    "J_in": J_iv is not None and J_iv[0] <= case["J"] <= J_iv[1],
                    "seconds": secs,
                    "n": case["op"].size,
                    "model": fit.valve_model,
                    "verdict": verdict.status,
                }
            )
        r = rows[-2:]
        print(
            f"{i:3d} {r[0]['process']:11s} noise {noise:4.2f}  S {case['S']:5.2f} J {case['J']:5.2f}"
            f" | mv {r[0]['S_hat']:5.2f} {r[0]['J_hat']:5.2f} ({r[0]['seconds']:.2f} s)"
            f" | ham {r[1]['S_hat']:5.2f} {r[1]['J_hat']:5.2f} ({r[1]['seconds']:.2f} s)"
            f" {r[1]['model']} | {r[0]['verdict']} / {r[1]['verdict']}",
            flush=True,
        )
    return rows


def summarise(rows: list[dict]) -> None:
    import pandas as pd

    df = pd.DataFrame(rows)
    df["abs_S"] = df.S_err.abs()
    df["abs_J"] = df.J_err.abs()
    df["stiction"] = df.verdict == "stiction"
    df["no_stiction"] = df.verdict == "no_stiction"
    print()
    print("Median absolute error [% of span], interval coverage, wall time per fit")
    g = df.groupby(["estimator", "process", "noise"])
    table = g.agg(
        loops=("case", "size"),
        S_med_abs_err=("abs_S", "median"),
        J_med_abs_err=("abs_J", "median"),
        S_covered=("S_in", "mean"),
        J_covered=("J_in", "mean"),
        called_stiction=("stiction", "mean"),
        called_no_stiction=("no_stiction", "mean"),
        seconds_median=("seconds", "median"),
        seconds_max=("seconds", "max"),
    )
    print(table.round(3).to_string())
    print()
    overall = df.groupby("estimator").agg(
        loops=("case", "size"),
        S_med_abs_err=("abs_S", "median"),
        J_med_abs_err=("abs_J", "median"),
        S_covered=("S_in", "mean"),
        J_covered=("J_in", "mean"),
        called_stiction=("stiction", "mean"),
        called_no_stiction=("no_stiction", "mean"),
        seconds_median=("seconds", "median"),
        seconds_max=("seconds", "max"),
    )
    print(overall.round(3).to_string())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=36)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--samples", type=int, default=10_000)
    a = ap.parse_args()
    summarise(run(a.cases, a.seed, a.samples))


if __name__ == "__main__":
    main()
