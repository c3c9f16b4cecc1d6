"""Plant-wide grouping and source evidence compared on the development plants.

    python benchmarks/bench_plantwide_methods.py [--seeds 0 20] [--probability]

On the simulated plants of :mod:`stictiondiag.models.synthetic_plant` with the
given seeds (0-19 are the ones the method was developed on; the proof uses
others, ``stiction benchmark --plant``), prints:

* the share of loops in the right group for each grouping method of
  :func:`stictiondiag.signals.plantwide.plant_oscillations` (``spectral``,
  ``acf``), scored as :mod:`stictiondiag.apps.plant_benchmark` does;
* for the groups the spectral method finds with their true source among the
  members, how often each piece of evidence alone puts the true source first:
  the earliest cycle (time order), the largest harmonic content, the largest
  bicoherence nonlinearity index (NLI, counted only when significant), and with
  ``--probability`` the highest P(stiction) of each loop's own analysis (gap
  off; about 1-3 s per loop), and the combined ranking of
  :func:`stictiondiag.stiction.plantwide.rank_sources`.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stictiondiag.apps.plant_benchmark import score_plant
from stictiondiag.models.synthetic_plant import generate_plant
from stictiondiag.signals.plantwide import cycle_lag, harmonic_ratio, plant_oscillations
from stictiondiag.stiction.plantwide import rank_sources


def _probabilities(plant) -> dict:
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.io.tags import read_frame

    out = {}
    for loop in plant.truth:
        frame = plant.frame[["time", f"{loop}.PV", f"{loop}.OP", f"{loop}.SP"]]
        tags = read_frame(frame, source=loop)
        out[loop] = analyze(tags, config=AnalysisConfig(gap=False)).verdict.probability
    return out


def _nli(x: np.ndarray, dt: float, period_s: float) -> float:
    """NLI of Choudhury et al. (2004) when the record is nonlinear, else 0."""
    from stictiondiag.stiction.classic.bicoherence import auto_decimation, bicoherence_indices

    q = auto_decimation(x.size, period_s / dt)
    b = bicoherence_indices(x - x.mean(), dt=dt, decimation=q)
    return float(b.nli) if b.nonlinear else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", nargs=2, type=int, default=(0, 20), metavar=("FIRST", "STOP"))
    ap.add_argument("--probability", action="store_true", help="also rank by P(stiction)")
    args = ap.parse_args()
    right = {"spectral": 0, "acf": 0}
    loops = 0
    evidence = {
        "time order": 0,
        "harmonic content": 0,
        "bicoherence NLI": 0,
        "P(stiction)": 0,
        "combined": 0,
    }
    groups = 0
    t0 = time.perf_counter()
    for seed in range(*args.seeds):
        plant = generate_plant(seed)
        sig = {k: plant.frame[f"{k}.PV"].to_numpy() for k in plant.truth}
        loops += len(plant.truth)
        for method in right:
            res = plant_oscillations(sig, plant.ts, method=method)
            found = [{**g.to_dict(), "ranking": [{"loop": g.members[0]}]} for g in res.groups]
            right[method] += score_plant(plant, found, {}, {}).membership_right
        res = plant_oscillations(sig, plant.ts)
        probs = _probabilities(plant) if args.probability else {}
        for truth in plant.groups.values():
            g = max(
                res.groups, key=lambda g: len(set(g.members) & set(truth["members"])), default=None
            )
            if g is None or truth["source"] not in g.members:
                continue
            groups += 1
            ref = g.members[0]
            lags = {m: cycle_lag(sig[m], sig[ref], plant.ts, g.period_s) for m in g.members}
            harm = {m: harmonic_ratio(sig[m], plant.ts, g.period_s) for m in g.members}
            src = truth["source"]
            evidence["time order"] += min(lags, key=lags.get) == src
            evidence["harmonic content"] += max(harm, key=lambda m: np.nan_to_num(harm[m])) == src
            nli = {m: _nli(sig[m], plant.ts, g.period_s) for m in g.members}
            evidence["bicoherence NLI"] += max(nli, key=nli.get) == src and nli[src] > 0
            if probs:
                evidence["P(stiction)"] += max(g.members, key=lambda m: probs[m] or 0) == src
            evidence["combined"] += rank_sources(g, sig, plant.ts, probs).ranking[0].loop == src
    seconds = time.perf_counter() - t0
    print(f"plants: seeds {args.seeds[0]} to {args.seeds[1] - 1}, {loops} loops ({seconds:.0f} s)")
    print("| grouping method | loops in the right group |")
    print("|---|---:|")
    for method, n in right.items():
        print(f"| {method} | {n} / {loops} ({100 * n / loops:.1f} %) |")
    print()
    print(f"| evidence alone | true source first (of {groups} groups) |")
    print("|---|---:|")
    for name, n in evidence.items():
        if name == "P(stiction)" and not args.probability:
            continue
        print(f"| {name} | {n} ({100 * n / max(groups, 1):.0f} %) |")


if __name__ == "__main__":
    main()
