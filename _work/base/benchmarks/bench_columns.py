"""Time to read one loop from a CSV beside many other columns: linear in the header.

A one-loop export (time, pv, op) with N further columns (``X<i>.VAL``, not a loop's
tags) and a fixed number of rows is written once per N and read by
:func:`stictiondiag.io.tags.read_tags` (only the loop's columns are parsed) and
listed by :func:`stictiondiag.io.plant.plant_loops` (what ``scan`` does with each
file).  Reading is linear in the header when the time per column stays flat as N
grows; it was quadratic before issue 31 (10 000 columns took 24 s, 5 000 took 60 s
under the profiler).

Run:  python benchmarks/bench_columns.py [--columns 1000 4000 16000] [--rows 2000]

Prints a Markdown table (columns, file MB, read_tags s, plant_loops s, us per column).
A benchmark that prints: no timed assertion.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def write_wide(path: Path, n_extra: int, n_rows: int) -> None:
    """A loop (time, pv, op) and ``n_extra`` columns of zeros, ``n_rows`` rows."""
    k = np.arange(n_rows)
    pv = np.sin(k / 30.0) + np.random.default_rng(0).normal(0.0, 0.01, n_rows)
    op = 50.0 + 10.0 * np.sign(np.sin(k / 30.0))
    tail = "," + ",".join(["0"] * n_extra) if n_extra else ""
    with open(path, "w") as handle:
        names = ["time", "pv", "op", *(f"X{i}.VAL" for i in range(n_extra))]
        handle.write(",".join(names) + "\n")
        for t, p, o in zip(k, pv, op, strict=True):
            handle.write(f"{float(t)},{p:.6f},{o:.3f}{tail}\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--columns", type=int, nargs="+", default=[1000, 4000, 16000])
    parser.add_argument("--rows", type=int, default=2000)
    args = parser.parse_args()

    from stictiondiag.io.plant import plant_loops
    from stictiondiag.io.tags import read_tags

    print("| columns | file MB | read_tags s | plant_loops s | read_tags us per column |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.columns:
            path = Path(tmp) / f"wide_{n}.csv"
            write_wide(path, n, args.rows)
            t0 = time.perf_counter()
            read_tags(path, ts=1.0)
            t_read = time.perf_counter() - t0
            t0 = time.perf_counter()
            plant_loops(path)
            t_list = time.perf_counter() - t0
            size = path.stat().st_size / 1e6
            print(
                f"| {n} | {size:.1f} | {t_read:.2f} | {t_list:.2f} | {1e6 * t_read / (n + 3):.0f} |"
            )
            path.unlink()


if __name__ == "__main__":
    main()
