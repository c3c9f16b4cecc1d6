"""Cost of starting a scan's workers on a cold numba cache: compiled once, or per worker.

    python benchmarks/bench_dask_startup.py [--engine dask] [--workers 2] [--loops 2]

Each run scans the same small plant (``--loops`` loops of 2 000 samples, with the gap
diagnosis unless ``--no-gap``) in its own Python process, with ``NUMBA_CACHE_DIR`` pointing at an empty
folder, so every kernel must be compiled:

* ``per worker``: the scan as it was, each worker compiles the kernels it runs (the
  warm-up before the workers start is switched off in that process);
* ``once``: the scan as it is, the calling process fills the cache
  (:func:`stictiondiag.apps.warmup.warm_cache_once`) and the workers load it;
* ``warm``: the same scan again on the now warm cache, for reference.

Printed: CPU seconds of the whole process tree (``RUSAGE_CHILDREN``) and wall time.
Results are in docs/history.md, section "Dask".
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _plants import make_plant as _make_plant  # benchmarks/ is on a script's path

_SCAN = """
import sys
import stictiondiag.apps.workers as w
if sys.argv[6] == "per worker":
    w._warm_cache_here = lambda: None
from stictiondiag.apps.scan import scan
r = scan(sys.argv[1], out=sys.argv[2], engine=sys.argv[3], workers=int(sys.argv[4]),
         gap=sys.argv[5] == "gap")
assert r.n_failed == 0, r.n_failed
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--engine", default="dask", choices=("local", "dask"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--loops", type=int, default=2)
    parser.add_argument("--no-gap", action="store_true", help="scan without the gap diagnosis")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_startup_") as tmp:
        plant = Path(tmp) / "plant"
        _make_plant(plant, args.loops, n_samples=2000, seed=4, mv_share=0.5, sticky_model="simple")
        print(
            f"{args.engine}, {args.workers} workers, {args.loops} loops x 2000 samples, "
            f"gap {'off' if args.no_gap else 'on'}, "
            f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}"
        )
        print("| kernels compiled | CPU s (process tree) | wall s |")
        print("|---|---:|---:|")
        cache = None
        for mode in ("per worker", "once", "warm"):
            if mode != "warm":
                cache = Path(tempfile.mkdtemp(prefix="numba_", dir=tmp))
            env = os.environ | {"NUMBA_CACHE_DIR": str(cache)}
            out = Path(tmp) / f"out_{mode.replace(' ', '_')}"
            cmd = [sys.executable, "-c", _SCAN, str(plant), str(out), args.engine]
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            gap = "nogap" if args.no_gap else "gap"
            subprocess.run([*cmd, str(args.workers), gap, mode], check=True, env=env)
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            print(f"| {mode} | {cpu:.1f} | {wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
