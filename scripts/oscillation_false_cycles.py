"""How often the oscillation test calls noise a cycle, with and without the seeded
periods (:mod:`stictiondiag.signals.oscillation`, module doc).

    python scripts/oscillation_false_cycles.py [--seeds 60] [--n 1441 3000]

Draws ``--seeds`` records of each kind of noise and length (white noise, a random
walk, AR(1) noise with poles 0.9 and 0.99, a random walk under white noise, random
steps every 200 samples under white noise) and prints, per kind, how many
:func:`~stictiondiag.signals.oscillation.detect_oscillation` calls oscillating with
the seeds switched off (``SEED_PEAKS = 0``, the straight line and its refinement
alone) and on.  Deterministic; a few seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from stictiondiag.signals import oscillation  # noqa: E402

KINDS = ("white", "random walk", "AR(1) 0.9", "AR(1) 0.99", "walk + white", "steps + white")


def noise(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """One record of ``kind`` (module doc), ``n`` samples."""
    e = rng.standard_normal(n)
    if kind == "white":
        return e
    if kind == "random walk":
        return np.cumsum(e)
    if kind.startswith("AR(1)"):
        return lfilter([1.0], [1.0, -float(kind.split()[1])], e)
    if kind == "walk + white":
        return 0.1 * np.cumsum(e) + rng.standard_normal(n)
    return np.repeat(rng.standard_normal(n // 200 + 1), 200)[:n] + 0.3 * e


def count(kind: str, n: int, seeds: int, peaks: int) -> int:
    """Records of ``kind`` called oscillating with ``SEED_PEAKS = peaks``."""
    shipped = oscillation.SEED_PEAKS
    oscillation.SEED_PEAKS = peaks
    try:
        return sum(
            oscillation.detect_oscillation(noise(kind, n, np.random.default_rng(s)), 1.0).present
            for s in range(seeds)
        )
    finally:
        oscillation.SEED_PEAKS = shipped


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=60)
    ap.add_argument("--n", type=int, nargs="+", default=[1441, 3000])
    args = ap.parse_args(argv)
    print(f"| samples | noise | called oscillating of {args.seeds}: without seeds | with seeds |")
    print("|---|---|---|---|")
    for n in args.n:
        for kind in KINDS:
            off = count(kind, n, args.seeds, 0)
            on = count(kind, n, args.seeds, oscillation.SEED_PEAKS)
            print(f"| {n} | {kind} | {off} | {on} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
