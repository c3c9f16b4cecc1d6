"""Cost of the plant-wide step against the number of loops in one group.

    python benchmarks/bench_plantwide_cost.py [--samples 3000] [--sizes 10 20 50 100 200]

Builds plants of N loops that all share one cycle (a filtered square wave, each
loop a further delayed and filtered copy with its own noise, so that every loop
is a member of the one group) and times
:func:`stictiondiag.stiction.plantwide.diagnose_plant` (grouping and source
ranking; the per-loop analyses are not included).  Prints the wall time, the
time per loop (flat when the cost grows linearly with the group), and the group
size found.  Best of three runs per size.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stictiondiag.stiction.plantwide import diagnose_plant


def _group(n_loops: int, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    base = np.sign(np.sin(2 * np.pi * t / 97.0))
    out = {}
    for i in range(n_loops):
        shift = int(rng.integers(0, 20))
        x = np.roll(base, shift)
        a = np.exp(-1.0 / rng.uniform(2.0, 10.0))
        y = np.empty(n)
        s = 0.0
        for k in range(n):
            s = a * s + (1 - a) * x[k]
            y[k] = s
        out[f"L{i:03d}"] = y + 0.1 * rng.normal(size=n)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=3000)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 50, 100, 200])
    args = ap.parse_args()
    print("| loops in the group | samples | wall [s] | per loop [ms] | group size found |")
    print("|---:|---:|---:|---:|---:|")
    for size in args.sizes:
        signals = _group(size, args.samples)
        best = float("inf")
        found = 0
        for _ in range(3):
            t0 = time.perf_counter()
            d = diagnose_plant(signals, 1.0)
            best = min(best, time.perf_counter() - t0)
            found = max((len(g.group.members) for g in d.groups), default=0)
        print(f"| {size} | {args.samples} | {best:.3f} | {1000 * best / size:.1f} | {found} |")


if __name__ == "__main__":
    main()
