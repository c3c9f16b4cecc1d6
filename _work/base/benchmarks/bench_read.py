"""Time and peak memory of reading one loop file, from 1e4 to 1e7 rows.

Each size is written once as a CSV (time, sp, pv, op, mv; a clock with jitter so the
rows go through the uniform-grid step, and one stamp mistyped far in the future, the
case that used to size the grid by its worst stamp) and read by
:func:`stictiondiag.io.tags.read_tags` in a fresh process, so that the peak resident
memory (``ru_maxrss``) is that of the read alone.  The baseline is the same fresh
process after importing the reader, before reading.

Run:  python benchmarks/bench_read.py [--sizes 1e4 1e5 1e6 1e7] [--dir /tmp/bench_read]

Prints a Markdown table (rows, file MB, read s, peak MB, peak above baseline MB,
bytes per row); docs/scaling.md quotes it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, resource, sys, time
from stictiondiag.io.tags import read_tags
import pandas, numpy  # noqa: F401  (imports counted in the baseline)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
tags = read_tags(sys.argv[1])
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"n": tags.n, "seconds": dt, "base_kb": base, "peak_kb": peak,
                  "warnings": list(tags.warnings)}))
"""


def write_csv(path: Path, rows: int, seed: int = 1) -> None:
    """A loop record of ``rows`` rows at about 1 s, written in blocks (bounded memory)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    block = 1_000_000
    with open(path, "w") as handle:
        handle.write("time,sp,pv,op,mv\n")
        for start in range(0, rows, block):
            k = np.arange(start, min(rows, start + block))
            t = k + rng.uniform(-0.05, 0.05, k.size)
            if start == 0:
                t[k.size // 2] = 4.0e9  # one stamp mistyped far in the future
            pv = 50 + 5 * np.sin(2 * np.pi * k / 120) + rng.normal(0, 0.1, k.size)
            op = 40 + 10 * np.sign(np.sin(2 * np.pi * k / 120 + 0.5))
            block_text = "\n".join(
                f"{a:.3f},50,{b:.4f},{c:.4f},{c:.4f}" for a, b, c in zip(t, pv, op, strict=True)
            )
            handle.write(block_text + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6, 1e7])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/bench_read"))
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    print("| rows | file MB | read s | peak MB | above baseline MB | bytes/row |")
    print("|---:|---:|---:|---:|---:|---:|")
    for size in args.sizes:
        rows = int(size)
        path = args.dir / f"loop_{rows}.csv"
        if not path.exists():
            t0 = time.perf_counter()
            write_csv(path, rows)
            print(f"(wrote {path} in {time.perf_counter() - t0:.0f} s)", file=sys.stderr)
        # This checkout's package, whatever is installed.
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
        }
        out = subprocess.run(
            [sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, env=env
        )
        if out.returncode:
            sys.exit(f"reading {path} failed: {out.stderr.strip().splitlines()[-1:]}")
        r = json.loads(out.stdout)
        above = (r["peak_kb"] - r["base_kb"]) / 1024
        print(
            f"| {rows:,} | {path.stat().st_size / 1e6:.0f} | {r['seconds']:.2f} | "
            f"{r['peak_kb'] / 1024:.0f} | {above:.0f} | {above * 1024 * 1024 / rows:.0f} |",
            flush=True,
        )
        print(f"  {r['n']} samples; " + " | ".join(r["warnings"])[:300], file=sys.stderr)


if __name__ == "__main__":
    main()
