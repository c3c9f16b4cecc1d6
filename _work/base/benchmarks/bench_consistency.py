"""Cost of the describing-function consistency (stictiondiag.stiction.consistency)
against steps 1-3 of the analysis (loop type, oscillation test, Hammerstein fit), per
loop with a cycle of the cause family; prints the figures.

Usage::

    python benchmarks/bench_consistency.py [--seed 13] [--loops 60]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from stictiondiag.analysis import estimate_loop
from stictiondiag.apps.family_causes import cause_loop
from stictiondiag.core.errors import StictionError
from stictiondiag.stiction.cause import find_cycle
from stictiondiag.stiction.consistency import describing_features


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--loops", type=int, default=60)
    a = ap.parse_args(argv)
    fits, dfs, ns = [], [], []
    for seed in range(a.seed * 1_000_000, a.seed * 1_000_000 + a.loops):
        loop = cause_loop(seed)
        try:
            t = time.perf_counter()
            est = estimate_loop(loop.tags())
            tf = time.perf_counter() - t
        except StictionError:
            continue
        cyc = find_cycle(est.oscillation, est.oscillation_op, short_record=bool(est.short_record))
        if not cyc.present:
            continue  # loops without a cycle skip the consistency
        t = time.perf_counter()
        describing_features(est.fit, est.tags, cyc.period_s)
        dfs.append(time.perf_counter() - t)
        fits.append(tf)
        ns.append(loop.pv.size)
    f, d = np.array(fits), np.array(dfs)
    print(
        f"{f.size} loops with a cycle of {a.loops} (records of {min(ns)}-{max(ns)} samples):"
        f" steps 1-3 median {np.median(f):.3f} s; describing-function consistency median"
        f" {np.median(d):.3f} s, 90th percentile {np.percentile(d, 90):.3f} s;"
        f" its share of steps 1-3, median {np.median(d / f):.3f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
