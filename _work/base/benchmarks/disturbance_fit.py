"""The Hammerstein fit's disturbance models compared on disturbed simulated loops; prints a table.

Without mv the fit (:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`) compares
a sticky valve with a linear valve by the residual each leaves.  Loads, set-point
moves and operating-point drifts that no valve explains inflate both residuals and
pull the improvement ``1 - cost / linear_cost`` towards zero even for a plainly
sticky valve.  This benchmark runs the fit's disturbance models (``disturbance=``:
``highpass``, ``drift``, ``auto``; see "The disturbance model" in
:mod:`stictiondiag.stiction.hammerstein`) on the same records and prints, per model:

* sticky valves: median improvement, the share whose block-bootstrap support for an
  improvement above 10 % reaches 0.95 (:func:`stictiondiag.stiction.verdict.improvement_support`,
  the statistic the verdict uses), the median ``|S - S_true|`` [% of span] and the
  coverage of the 95 % S interval;
* healthy (linear) valves: median and 90th percentile of the improvement and the
  share with support >= 0.95 (false alarms of the fit; the verdict adds more checks);
* separation: the probability that a sticky record's improvement exceeds a healthy
  record's (the area under the ROC curve of the improvement), overall and per
  disturbance, and the same for the improvement with drift states refitted at the
  fit's parameters (``StictionFit.improvement_drift``).

Cases (every combination, ``--reps`` times, seeded): PI loops of
:func:`stictiondiag.models.loops.simulate_loop` sampled at 1 s, :data:`N_SAMPLES` samples
after a :data:`WARMUP_S` start-up: the concentration loop of Eq. 3 / Table 3, a faster
FOPTD loop, a slow level loop (integrating) and a cascade slave (the fast FOPTD loop
whose set point is the master's output, below); valves: Kano's data-driven valve with
S in :data:`S_TRUE` % of span, J a random 0.3-1.0 S, or a linear valve, with or
without an external sinusoidal load (an oscillation that is not the valve's); the
disturbances of :data:`DISTURBANCES` in units of the standard deviation of the
noise-free pv of the same loop with a 2 % valve:

* ``white``: white measurement noise 5 %;
* ``noisy``: white noise 30 %;
* ``drift`` and ``drift_heavy``: a random-walk load on pv whose standard deviation
  reaches 2 (heavy: 6) over the record, noise 5 %;
* ``steps`` and ``steps_heavy``: four load steps of 0.5-1.5 (heavy: 2-4) at random
  times, noise 5 %;
* ``setpoint``: set-point steps of +-1 every fifth of the record, noise 5 %;
* ``coloured``: an AR(1) load on pv (20 s time constant) of 0.5, noise 5 %;
* ``cascade``: the set point moves like a master controller's output, an AR(1)
  signal (time constant three cycles) of 1 plus a sinusoid of 0.5 at 2.3 cycles,
  noise 5 % (the slave template only; the other templates get ``drift`` here).

Usage: ``python benchmarks/disturbance_fit.py [--reps 1] [--seed 3] [--workers 1]
[--models highpass,drift] [--csv rows.csv]``; a model ``drift@0.25`` runs the drift
model with another :data:`stictiondiag.stiction.hammerstein.DRIFT_CUTOFF`.
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

TS, WARMUP_S = 1.0, 1000.0
N_SAMPLES = 2000
S_TRUE = (1.5, 3.0)
REFERENCE_S = 2.0
WHITE = 0.05
DISTURBANCES = (
    "white",
    "noisy",
    "drift",
    "drift_heavy",
    "steps",
    "steps_heavy",
    "setpoint",
    "coloured",
    "cascade",
)
VALVES = {
    "S=1.5": (1.5, False),
    "S=3": (3.0, False),
    "linear": (0.0, False),
    "linear+ext": (0.0, True),
}
EXTERNAL_AMPLITUDE, EXTERNAL_PERIOD_FACTOR = 1.0, 1.7
MIN_IMPROVEMENT, DECISION_LEVEL = 0.1, 0.95


def templates():
    """name -> (integrating, process, controller)."""
    from stictiondiag.models.processes import FOPTD, LOOP_PARAMETERS, PI, Integrating

    conc = LOOP_PARAMETERS["concentration"]
    return {
        "concentration": (False, conc["process"], conc["controller"]),
        "foptd_fast": (False, FOPTD(1.5, 20.0, 4.0), PI(0.6, 8.0)),
        "level_slow": (True, Integrating(0.1, 0.0), PI(0.4, 20.0)),
        "slave": (False, FOPTD(1.5, 20.0, 4.0), PI(0.6, 8.0)),
    }


def draw_cases(reps: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    cases = []
    for rep, template, valve, dist in itertools.product(
        range(reps), templates(), VALVES, DISTURBANCES
    ):
        if dist == "cascade" and template != "slave":
            continue
        S, external = VALVES[valve]
        cases.append(
            {
                "rep": rep,
                "template": template,
                "valve": valve,
                "S": S,
                "J": round(float(rng.uniform(0.3, 1.0)) * S, 3),
                "external": external,
                "disturbance": dist,
                "seed": int(rng.integers(0, 2**31 - 1)),
            }
        )
    return cases


_REF: dict = {}


def _reference(template: str) -> tuple[float, float]:
    """Noise-free pv standard deviation and period [s] of the loop with a 2 % valve."""
    if template not in _REF:
        from stictiondiag.models.loops import simulate_loop
        from stictiondiag.signals.oscillation import detect_oscillation

        _, process, controller = templates()[template]
        sim = simulate_loop(
            process,
            controller,
            duration=WARMUP_S + N_SAMPLES * TS,
            dt=TS,
            S=REFERENCE_S,
            J=REFERENCE_S / 2,
            valve="kano",
        )
        pv = sim.pv[int(WARMUP_S / TS) :]
        osc = detect_oscillation(pv, TS)
        _REF[template] = (float(np.std(pv)), float(osc.period_s if osc.present else 100.0))
    return _REF[template]


def _ar1(rng, n: int, std: float, tau_samples: float) -> np.ndarray:
    from scipy.signal import lfilter

    phi = math.exp(-1.0 / tau_samples)
    return lfilter([std * math.sqrt(1.0 - phi * phi)], [1.0, -phi], rng.standard_normal(n))


def disturbance(case: dict, n: int, ref_std: float, period: float, rng) -> dict:
    """Load on pv, set point and white-noise std of one case [pv units]."""
    dist = case["disturbance"]
    if dist == "cascade" and case["template"] != "slave":
        dist = "drift"
    load = np.zeros(n)
    sp = np.zeros(n)
    white = WHITE
    if dist == "noisy":
        white = 0.3
    elif dist in ("drift", "drift_heavy"):
        size = 2.0 if dist == "drift" else 6.0
        load = np.cumsum(rng.standard_normal(n)) * size / math.sqrt(n)
    elif dist in ("steps", "steps_heavy"):
        lo, hi = (0.5, 1.5) if dist == "steps" else (2.0, 4.0)
        for k in rng.integers(int(WARMUP_S / TS), n, size=4):
            load[k:] += rng.choice([-1, 1]) * rng.uniform(lo, hi)
    elif dist == "setpoint":
        first = int(WARMUP_S / TS)
        for k in range(first, n, max(1, (n - first) // 5)):
            sp[k:] += rng.choice([-1.0, 1.0])
    elif dist == "coloured":
        load = _ar1(rng, n, 0.5, 20.0 / TS)
    elif dist == "cascade":
        t = np.arange(n) * TS
        sp = _ar1(rng, n, 1.0, 3 * period / TS) + 0.5 * np.sin(
            2 * math.pi * t / (2.3 * period) + rng.uniform(0, 2 * math.pi)
        )
    if case["external"]:
        t = np.arange(n) * TS
        load = load + EXTERNAL_AMPLITUDE * math.sqrt(2) * np.sin(
            2 * math.pi * t / (EXTERNAL_PERIOD_FACTOR * period) + rng.uniform(0, 2 * math.pi)
        )
    return {"load": load * ref_std, "sp": sp * ref_std, "noise_std": white * ref_std}


def simulate(case: dict) -> tuple[np.ndarray, np.ndarray, bool]:
    from stictiondiag.models.loops import simulate_loop

    integrating, process, controller = templates()[case["template"]]
    ref_std, period = _reference(case["template"])
    n = int(WARMUP_S / TS) + N_SAMPLES
    rng = np.random.default_rng(case["seed"])
    d = disturbance(case, n, ref_std, period, rng)
    sim = simulate_loop(
        process,
        controller,
        duration=n * TS,
        dt=TS,
        valve="kano" if case["S"] > 0 else "linear",
        S=case["S"],
        J=case["J"],
        load=d["load"],
        sp=d["sp"],
        noise_std=d["noise_std"],
        seed=int(rng.integers(0, 2**31 - 1)),
    )
    keep = slice(int(WARMUP_S / TS), n)
    return sim.op[keep], sim.pv[keep], integrating


#: Disturbance models compared by default (``fit_hammerstein(disturbance=...)``).
MODELS = "highpass,drift,auto"


def run_case(args: tuple[dict, tuple[str, ...]]) -> list[dict]:
    from stictiondiag.core.errors import StictionError
    from stictiondiag.stiction.hammerstein import fit as hammerstein
    from stictiondiag.stiction.hammerstein import fit_hammerstein
    from stictiondiag.stiction.verdict import improvement_support

    case, models = args
    default_cutoff = hammerstein.DRIFT_CUTOFF
    op, pv, integrating = simulate(case)
    rows = []
    for model in models:
        row = {**case, "model": model}
        # "drift@0.25": the drift model with another DRIFT_CUTOFF.
        name, _, cutoff = model.partition("@")
        hammerstein.DRIFT_CUTOFF = float(cutoff) if cutoff else default_cutoff
        t0 = time.perf_counter()
        try:
            fit = fit_hammerstein(
                op, pv, TS, integrating=integrating, flow_loop=False, disturbance=name
            )
        except StictionError as exc:
            row.update(error=str(exc))
            rows.append(row)
            continue
        blocks = fit.details["block_sse"]
        P, f, _ = improvement_support(
            np.asarray(blocks["stiction"]), np.asarray(blocks["linear"]), MIN_IMPROVEMENT
        )
        lo, hi = fit.S_interval
        row.update(
            seconds=time.perf_counter() - t0,
            improvement=f,
            support=P,
            S_hat=fit.S,
            S_err=abs(fit.S - case["S"]),
            covered=bool(lo <= case["S"] <= hi),
            S_excludes_zero=bool(lo > 0),
        )
        row["chosen"] = fit.details["disturbance_model"]["model"]
        row["improvement_drift"] = fit.details["drift_model"]["improvement"]
        rows.append(row)
    hammerstein.DRIFT_CUTOFF = default_cutoff
    return rows


def auc(pos, neg) -> float:
    """P(a sticky record's improvement > a healthy one's), ties counting half."""
    pos, neg = np.asarray(pos, float), np.asarray(neg, float)
    if pos.size == 0 or neg.size == 0:
        return math.nan
    gt = (pos[:, None] > neg[None, :]).mean()
    eq = (pos[:, None] == neg[None, :]).mean()
    return float(gt + 0.5 * eq)


def summarise(rows: list[dict], models, key) -> None:
    groups: dict = {}
    for r in rows:
        groups.setdefault(key(r), []).append(r)
    print(
        "| group | model | n | sticky: med impr. | detect (P>=.95) | med abs S err | "
        "S cover | healthy: med impr. | p90 impr. | false (P>=.95) | AUC | AUC drift impr. "
        "| s/fit |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for g in sorted(groups):
        for m in models:
            rs = [r for r in groups[g] if r["model"] == m and "error" not in r]
            st = [r for r in rs if r["S"] > 0]
            he = [r for r in rs if r["S"] == 0]
            fs = [r["improvement"] for r in st]
            fh = [r["improvement"] for r in he]

            def med(v):
                return float(np.median(v)) if v else math.nan

            def share(v):
                return float(np.mean(v)) if v else math.nan

            n_err = sum(1 for r in groups[g] if r["model"] == m and "error" in r)
            print(
                f"| {g} | {m} | {len(rs)}{f' ({n_err} failed)' if n_err else ''} "
                f"| {med(fs):.2f} | {share([r['support'] >= DECISION_LEVEL for r in st]):.0%} "
                f"| {med([r['S_err'] for r in st]):.2f} | {share([r['covered'] for r in st]):.0%} "
                f"| {med(fh):.2f} | {np.percentile(fh, 90) if fh else math.nan:.2f} "
                f"| {share([r['support'] >= DECISION_LEVEL for r in he]):.0%} "
                f"| {auc(fs, fh):.2f} "
                f"| {auc([r['improvement_drift'] for r in st], [r['improvement_drift'] for r in he]):.2f} "
                f"| {med([r['seconds'] for r in rs]):.2f} |"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=1)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--models", default=MODELS)
    parser.add_argument("--csv")
    args = parser.parse_args()
    models = tuple(args.models.split(","))
    cases = draw_cases(args.reps, args.seed)
    t0 = time.perf_counter()
    jobs = [(c, models) for c in cases]
    if args.workers > 1:
        with ProcessPoolExecutor(args.workers) as pool:
            rows = [r for rs in pool.map(run_case, jobs) for r in rs]
    else:
        rows = [r for job in jobs for r in run_case(job)]
    print(
        f"{len(cases)} records x {len(models)} disturbance models (seed {args.seed}, "
        f"{args.reps} rep(s)), {time.perf_counter() - t0:.0f} s\n"
    )
    print("All records\n")
    summarise(rows, models, lambda r: "all")
    print("\nBy disturbance\n")
    summarise(rows, models, lambda r: r["disturbance"])
    print("\nBy template\n")
    summarise(rows, models, lambda r: r["template"])
    if args.csv:
        import pandas as pd

        pd.DataFrame(rows).to_csv(args.csv, index=False)


if __name__ == "__main__":
    main()
