"""Calibration of the no-mv S intervals and of the verdict on simulated loops; prints a table.

Without the valve position, S and J come from the Hammerstein fit
(:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`) with a nominal 95 % profile-cost
interval (:func:`stictiondiag.stiction.valvefit.cost_threshold`).  On simulated loops the
true S is known, so the interval can be checked: a calibrated 95 % interval holds
the true S in about 95 % of the records.  Much more than that, with wide intervals
that reach 0, is an over-conservative interval (and an ``inconclusive`` verdict
that the data do not call for); much less is over-confident.

Cases, drawn with a fixed seed (every combination, ``--reps`` times):

* five PI loops of :func:`stictiondiag.models.loops.simulate_loop`: the four templates of
  ``benchmarks/accuracy_analyze.py`` (the concentration loop of Eq. 3 / Table 3,
  a faster FOPTD loop and two integrating, level-like, loops) and a flow loop
  (1 s dead time, 3 s lag, analysed as loop type ``flow``), sampled at 1 s,
  :data:`N_SAMPLES` samples after a :data:`WARMUP_S` start-up;
* the valve: the data-driven valve with true S in :data:`S_TRUE` % of span and J a
  random 0.2-1.0 S, in Kano's form (``valve="kano"``): the published flowchart
  re-arms at every noise reversal of op and, with noise fed back, sticks for good
  (Section 5.1 asks for a filter in front of it); or a healthy linear
  valve (S = 0), either with nothing but the disturbance below or with an external
  sinusoidal load (an oscillation that is not the valve's);
* the disturbance, in units of the standard deviation of the noise-free pv of the
  same loop with a :data:`REFERENCE_S` % valve (so that it does not scale with
  the S of the case, as plant noise does not): ``white`` (white measurement noise
  5 %), ``coloured`` (an AR(1) load on pv with a 20 s time constant, 25 %, plus
  white noise 3 %) and ``heavy`` (the same load at 50 %, white noise 5 %);
* records of :data:`N_SAMPLES` samples.

Each record is analysed without mv (``analyze`` on ``Tags.from_arrays`` with pv,
op and sp; no replay, no gap diagnosis).  Per group the table gives the coverage of
the nominal 95 % S interval (share of records whose interval holds the true S;
a record with an error counts as not covered), the median interval width, the
share whose interval reaches 0 (S not told apart from a linear valve), the median
|S error|, the same coverage and width for J (and the share of fits that leave J
unbounded), and the shares of the verdicts.  The healthy rows show the false-stiction
rate: the share of loops with a linear valve called ``stiction``.

Usage: ``python benchmarks/calibration_nomv.py [--reps 1] [--seed 7] [--workers 1]
[--csv rows.csv]``.  One rep is 180 records, about 90 s with two workers on an
idle two-core machine.  The threshold of the intervals
(:data:`stictiondiag.stiction.hammerstein.MODEL_ERROR_SHARE`) was set on ``--seed 7 --reps
2``; other seeds check it.
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

#: Sample time [s], start-up dropped [s].
TS, WARMUP_S = 1.0, 1000.0
#: Record lengths analysed [samples] (every case at each).
N_SAMPLES = (2000, 4000)
#: True S of the sticky valves [% of span].
S_TRUE = (1.0, 2.0, 3.0, 5.0)
#: S of the loop whose noise-free pv standard deviation is the unit of the disturbance.
REFERENCE_S = 2.0
#: Disturbances: name -> (white noise, AR(1) load) standard deviations, in units of
#: the reference pv standard deviation.
DISTURBANCES = {"white": (0.05, 0.0), "coloured": (0.03, 0.25), "heavy": (0.05, 0.5)}
#: Time constant of the AR(1) load [s].
LOAD_TIME_CONSTANT_S = 20.0
#: External oscillation of the healthy loops: amplitude in reference standard
#: deviations, period in oscillation periods of the reference loop.
EXTERNAL_AMPLITUDE, EXTERNAL_PERIOD_FACTOR = 1.0, 1.7
#: Valve cases: label -> (S, external oscillation).
VALVES = {
    **{f"S={s:g}": (s, False) for s in S_TRUE},
    "linear": (0.0, False),
    "linear+ext": (0.0, True),
}
LEVEL = 0.95


def templates():
    """Loop templates: name -> (integrating, process, controller)."""
    from stictiondiag.models.processes import (
        FOPTD,
        LOOP_PARAMETERS,
        PI,
        Integrating,
    )

    conc = LOOP_PARAMETERS["concentration"]
    return {
        "concentration": (False, conc["process"], conc["controller"]),
        "foptd_fast": (False, FOPTD(1.5, 20.0, 4.0), PI(0.6, 8.0)),
        "level_slow": (True, Integrating(0.1, 0.0), PI(0.4, 20.0)),
        "level_deadtime": (True, Integrating(0.05, 3.0), PI(1.5, 40.0)),
        # A flow loop (pv about proportional to the valve, a few seconds of lag),
        # analysed as loop type "flow".
        "flow": (False, FOPTD(1.0, 3.0, 1.0), PI(0.3, 5.0)),
    }


#: Loop type given to the analysis, by template (integrating ones are "level").
LOOP_TYPES = {"flow": "flow"}


def draw_cases(reps: int, seed: int) -> list[dict]:
    """Every template x valve x disturbance, ``reps`` times, each with its own seed and J."""
    rng = np.random.default_rng(seed)
    cases = []
    for rep in range(reps):
        for template in templates():
            for valve, (S, external) in VALVES.items():
                for dist, n in itertools.product(DISTURBANCES, N_SAMPLES):
                    cases.append(
                        {
                            "rep": rep,
                            "template": template,
                            "valve": valve,
                            "S": S,
                            "J": round(float(rng.uniform(0.2, 1.0)) * S, 3),
                            "external": external,
                            "disturbance": dist,
                            "n": n,
                            "seed": int(rng.integers(0, 2**31 - 1)),
                        }
                    )
    return cases


def _reference(template: str) -> tuple[float, float]:
    """Noise-free pv standard deviation and period [s] of the loop with a 2 % valve."""
    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.signals.oscillation import detect_oscillation

    _, process, controller = templates()[template]
    sim = simulate_loop(
        process,
        controller,
        duration=WARMUP_S + max(N_SAMPLES) * TS,
        dt=TS,
        S=REFERENCE_S,
        J=REFERENCE_S / 2,
        valve="kano",
    )
    pv = sim.pv[int(WARMUP_S / TS) :]
    osc = detect_oscillation(pv, TS)
    period = osc.period_s if osc.present else 100.0
    return float(np.std(pv)), float(period)


def _ar1(rng: np.random.Generator, n: int, std: float, tau: float) -> np.ndarray:
    from scipy.signal import lfilter

    phi = math.exp(-TS / tau)
    return lfilter([std * math.sqrt(1.0 - phi * phi)], [1.0, -phi], rng.standard_normal(n))


def run_case(case: dict) -> dict:
    """Simulate one case and analyse it without mv; one result row."""
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze,
    )
    from stictiondiag.core.errors import StictionError
    from stictiondiag.io.tags import Tags
    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.stiction.fit_details import HammersteinDetails

    integrating, process, controller = templates()[case["template"]]
    ref_std, ref_period = _reference(case["template"])
    white, coloured = DISTURBANCES[case["disturbance"]]
    n_total = int(WARMUP_S / TS) + case["n"]
    rng = np.random.default_rng(case["seed"])
    load = _ar1(rng, n_total, coloured * ref_std, LOAD_TIME_CONSTANT_S)
    if case["external"]:
        t = np.arange(n_total) * TS
        phase = rng.uniform(0, 2 * math.pi)
        period = EXTERNAL_PERIOD_FACTOR * ref_period
        load = load + EXTERNAL_AMPLITUDE * ref_std * math.sqrt(2) * np.sin(
            2 * math.pi * t / period + phase
        )
    sim = simulate_loop(
        process,
        controller,
        duration=n_total * TS,
        dt=TS,
        valve="kano" if case["S"] > 0 else "linear",
        S=case["S"],
        J=case["J"],
        load=load,
        noise_std=white * ref_std,
        seed=int(rng.integers(0, 2**31 - 1)),
    )
    keep = slice(int(WARMUP_S / TS), n_total)
    tags = Tags.from_arrays(
        sim.pv[keep],
        sim.op[keep],
        sp=sim.sp[keep],
        ts=TS,
        loop_type="level" if integrating else LOOP_TYPES.get(case["template"], "other"),
        integrating=integrating,
        source=f"{case['template']}/{case['valve']}/{case['disturbance']}",
    )
    row = dict(case)
    t0 = time.perf_counter()
    try:
        result = analyze(tags, config=AnalysisConfig(gap=False, replay=False))
    except StictionError as exc:
        row.update(error=str(exc), seconds=time.perf_counter() - t0)
        return row
    fit, verdict = result.fit, result.verdict
    lo, hi = fit.S_interval if fit.S_interval is not None else (math.nan, math.nan)
    j_lo, j_hi = fit.J_interval if fit.J_interval is not None else (math.nan, math.nan)
    row.update(
        seconds=time.perf_counter() - t0,
        S_hat=float(fit.S),
        S_lo=float(lo),
        S_hi=float(hi),
        covered=bool(lo <= case["S"] <= hi),
        reaches_zero=bool(lo <= 0.0),
        J_hat=float(fit.J),
        J_covered=bool(j_lo <= case["J"] <= j_hi),
        J_width=float(j_hi - j_lo),
        J_confounded=isinstance(fit.details, HammersteinDetails)
        and bool(fit.details.J_confounded_with_gain),
        verdict=verdict.status,
        support=float(verdict.evidence.support),
        improvement=float(fit.improvement) if fit.improvement is not None else math.nan,
        n_slips=int(fit.n_slips),
        # A cycle found in pv or op (a short record's unconfirmed cycle names no signal).
        oscillating=verdict.cycle is not None and verdict.cycle.signal is not None,
    )
    return row


def _median(values):
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.median(values)) if values else math.nan


def summarise(rows: list[dict], key) -> list[dict]:
    groups: dict = {}
    for r in rows:
        groups.setdefault(key(r), []).append(r)
    out = []
    for k in sorted(groups, key=lambda g: tuple(str(x) for x in g)):
        g = groups[k]
        ok = [r for r in g if "error" not in r]
        n = len(g)
        out.append(
            {
                "group": " ".join(str(x) for x in k),
                "n": n,
                "errors": n - len(ok),
                "coverage": sum(r["covered"] for r in ok) / n,
                "width": _median([r["S_hi"] - r["S_lo"] for r in ok]),
                "reaches_zero": sum(r["reaches_zero"] for r in ok) / n,
                "S_err": _median([abs(r["S_hat"] - r["S"]) for r in ok]),
                "J_coverage": sum(r["J_covered"] for r in ok) / n,
                "J_width": _median([r["J_width"] for r in ok]),
                "J_confounded": sum(r["J_confounded"] for r in ok) / n,
                "stiction": sum(r["verdict"] == "stiction" for r in ok) / n,
                "inconclusive": sum(r["verdict"] == "inconclusive" for r in ok) / n,
                "no_stiction": sum(r["verdict"] == "no_stiction" for r in ok) / n,
                "oscillating": sum(r["oscillating"] for r in ok) / n,
            }
        )
    return out


def print_table(title: str, summary: list[dict]) -> None:
    print(f"\n{title}\n")
    print(
        "| group | n | coverage of 95 % S interval | median width [%] | reaches 0 "
        "| median abs S err [%] | J coverage | J width [%] | J unbounded "
        "| stiction | inconclusive | no stiction | oscillating |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for s in summary:
        err = f" ({s['errors']} failed)" if s["errors"] else ""
        print(
            f"| {s['group']}{err} | {s['n']} | {s['coverage']:.0%} | {s['width']:.2f} "
            f"| {s['reaches_zero']:.0%} | {s['S_err']:.2f} | {s['J_coverage']:.0%} "
            f"| {s['J_width']:.2f} | {s['J_confounded']:.0%} | {s['stiction']:.0%} "
            f"| {s['inconclusive']:.0%} | {s['no_stiction']:.0%} | {s['oscillating']:.0%} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=1, help="repetitions of the full design")
    parser.add_argument("--seed", type=int, default=7, help="seed of the case draw")
    parser.add_argument("--workers", type=int, default=1, help="worker processes")
    parser.add_argument("--csv", help="also write the per-case rows to this CSV")
    args = parser.parse_args()

    cases = draw_cases(args.reps, args.seed)
    t0 = time.perf_counter()
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            rows = list(pool.map(run_case, cases))
    else:
        rows = [run_case(c) for c in cases]
    elapsed = time.perf_counter() - t0

    print(
        f"{len(rows)} records ({args.reps} rep(s), seed {args.seed}), no mv, "
        f"{elapsed:.0f} s; nominal interval level {LEVEL:.0%}"
    )
    print_table("By valve", summarise(rows, lambda r: (r["valve"],)))
    print_table(
        "By valve and disturbance", summarise(rows, lambda r: (r["valve"], r["disturbance"]))
    )
    sticky = [r for r in rows if r["S"] > 0]
    print_table("Sticky valves by template", summarise(sticky, lambda r: (r["template"],)))
    print_table("Sticky valves by record length", summarise(sticky, lambda r: (f"n={r['n']}",)))
    print_table("All sticky valves", summarise(sticky, lambda r: ("S > 0",)))
    if args.csv:
        import pandas as pd

        pd.DataFrame(rows).to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
