"""CPU per loop of a Dask scan against the local process pool, on the same plant.

    python benchmarks/bench_dask.py [--loops 20] [--samples 10000] [--workers 2]
        [--no-gap] [--with-trim]

Generates a plant (``scripts/make_plant.py``: half the loops sticky, half with mv
recorded), fills the numba cache with a scan of two loops first, then scans the
plant once per engine, each scan in its own Python process started from this one
and writing to an empty output folder.  The CPU time of a scan is that of its
process and all its descendants (worker processes, Dask nannies and scheduler
included: ``RUSAGE_CHILDREN``; the calling process's own share, which holds
Dask's scheduler and nannies, is printed apart), so it holds start-up and teardown as well as the
loops; it is divided by the number of loops.  The same scan of the first ``--small``
loops separates the two: the CPU of the further loops, divided by their number, is
the cost per loop of a long scan; the rest is the fixed cost of starting and
stopping the workers (and, for Dask, the scheduler and nannies).  Minor page faults are counted the
same way.  On a machine shared with other work CPU time is the figure to compare;
wall time grows with the load.

``--with-trim`` adds a Dask scan whose workers get ``MALLOC_TRIM_THRESHOLD_=65536``
(Dask's default, which the scan now removes): the cost before the fix.
Results are in docs/performance.md, section "Dask" (latest), and
docs/history.md, section "Dask" (every run).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _plants import make_plant as _make_plant  # benchmarks/ is on a script's path

_SCAN = """
import sys
from stictiondiag.apps.scan import scan
r = scan(sys.argv[1], out=sys.argv[2], engine=sys.argv[3], workers=int(sys.argv[4]),
         gap=sys.argv[5] == "gap")
assert r.n_failed == 0, r.n_failed
import resource
own = resource.getrusage(resource.RUSAGE_SELF)
print("caller CPU s:", own.ru_utime + own.ru_stime, file=sys.stderr)
"""


def run_scan(plant: Path, out: Path, engine: str, workers: int, gap: bool, env: dict) -> dict:
    """Scan in a child process; its CPU seconds, page faults and wall time."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    args = [str(plant), str(out), engine, str(workers), "gap" if gap else "nogap"]
    done = subprocess.run(
        [sys.executable, "-c", _SCAN, *args], check=True, env=env, stderr=subprocess.PIPE, text=True
    )
    caller = float(done.stderr.rsplit("caller CPU s:", 1)[1].split()[0])
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {
        "cpu": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
        "sys": after.ru_stime - before.ru_stime,
        "faults": after.ru_minflt - before.ru_minflt,
        "wall": wall,
        "caller": caller,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loops", type=int, default=20)
    parser.add_argument("--small", type=int, default=4, help="loops of the start-up run")
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-gap", action="store_true", help="scan without the gap diagnosis")
    parser.add_argument("--with-trim", action="store_true", help="also Dask with the trim setting")
    args = parser.parse_args()
    gap = not args.no_gap
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    runs = [("local", "local", env), ("dask", "dask", env)]
    if args.with_trim:
        trim = env | {"MALLOC_TRIM_THRESHOLD_": "65536"}
        runs.append(("dask, MALLOC_TRIM_THRESHOLD_=65536", "dask", trim))
    n, m = args.loops, args.small
    with tempfile.TemporaryDirectory(prefix="bench_dask_") as tmp:
        plant, small = Path(tmp) / "plant", Path(tmp) / "small"
        _make_plant(plant, n, n_samples=args.samples, seed=11, mv_share=0.5)
        _make_plant(small, m, n_samples=args.samples, seed=11, mv_share=0.5)
        # A scan of two loops in one process fills the numba cache first, as any
        # installation's first run does; the timed scans then load the kernels.
        _make_plant(Path(tmp) / "warm", 2, n_samples=args.samples, seed=12, mv_share=0.5)
        run_scan(Path(tmp) / "warm", Path(tmp) / "warm_out", "local", 1, gap, env)
        print(
            f"machine: {platform.machine()}, {os.cpu_count()} cores, load average "
            f"{os.getloadavg()[0]:.1f}; {n} loops x {args.samples} samples, "
            f"{args.workers} workers, gap {'on' if gap else 'off'}"
        )
        print(
            f"| engine | CPU s per loop ({n} loops) | per further loop | start-up CPU s "
            f"| calling process CPU s ({n} loops) | page faults per loop | wall s |"
        )
        print("|---|---:|---:|---:|---:|---:|---:|")
        per_loop = {}
        for i, (label, engine, run_env) in enumerate(runs):
            big = run_scan(plant, Path(tmp) / f"out{i}", engine, args.workers, gap, run_env)
            part = run_scan(small, Path(tmp) / f"sm{i}", engine, args.workers, gap, run_env)
            # Marginal cost of a loop, and what is left: starting and stopping.
            marginal = (big["cpu"] - part["cpu"]) / (n - m)
            per_loop[label] = (big["cpu"] / n, marginal)
            print(
                f"| {label} | {big['cpu'] / n:.2f} | {marginal:.2f} | "
                f"{part['cpu'] - m * marginal:.1f} | {big['caller']:.1f} | "
                f"{big['faults'] / n:,.0f} | "
                f"{big['wall']:.0f} |",
                flush=True,
            )
        (dask_all, dask_m), (local_all, local_m) = per_loop["dask"], per_loop["local"]
        print(
            f"Dask / local: {dask_all / local_all:.2f} per loop of this scan, "
            f"{dask_m / local_m:.2f} per further loop; load average {os.getloadavg()[0]:.1f}"
        )


if __name__ == "__main__":
    main()
