"""Scan throughput: loops per second on the local process pool and on Dask.

Generates a plant (``scripts/make_plant.py``: by default 100 loops of 10 000 samples,
half with a sticky valve) and scans it with :func:`stictiondiag.apps.scan.scan` on the
local engine with 1, 2 and all cores, and on a Dask LocalCluster with all cores.
Each run starts from an empty output folder, so the wall time includes starting the
worker processes (and the cluster). A warm-up scan of a few loops first fills the
numba cache, as any installation does on its first run.

Prints a Markdown table: wall time, loops/s, speed-up over one worker, CPU time
per loop (this process and its worker processes, which on a machine shared with
other work is the figure that extrapolates: wall time grows with the load, CPU time
hardly), the load average during the run, the peak resident memory of the whole
process tree, and whether every run gave the same ranked table.

Usage::

    python benchmarks/bench_scan.py [--loops 100] [--samples 10000] [--no-gap]
        [--plant DIR] [--engines local,dask] [--workers 1,2,all]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import threading
import time
from pathlib import Path

import pandas as pd
import psutil
from _plants import make_plant as _make_plant  # benchmarks/ is on a script's path

from stictiondiag.apps.scan import scan


class PeakMemory:
    """Samples the resident memory of this process and all its descendants [MB]."""

    def __init__(self, interval_s: float = 0.2):
        self.interval_s = interval_s
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        me = psutil.Process()
        while not self._stop.is_set():
            total = 0
            for proc in [me, *me.children(recursive=True)]:
                try:
                    total += proc.memory_info().rss
                except psutil.Error:
                    pass  # a worker that just exited
            self.peak_mb = max(self.peak_mb, total / 2**20)
            self._stop.wait(self.interval_s)

    def __enter__(self) -> PeakMemory:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _cpu_seconds() -> float:
    """User + system CPU time of this process and its reaped children [s]."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def run(plant: Path, engine: str, workers: int, gap: bool, scratch: Path) -> dict:
    out = Path(tempfile.mkdtemp(prefix=f"{engine}{workers}-", dir=scratch))
    cpu0 = _cpu_seconds()
    with PeakMemory() as memory:
        start = time.perf_counter()
        result = scan(plant, out=out, engine=engine, workers=workers, gap=gap)
        wall = time.perf_counter() - start
    # Pool workers and the LocalCluster's worker processes are children of this
    # process and have exited (been reaped) when scan returns.
    cpu = _cpu_seconds() - cpu0
    return {
        "cpu_s_per_loop": cpu / result.n_loops,
        "load": os.getloadavg()[0],
        "engine": engine,
        "workers": workers,
        "loops": result.n_loops,
        "failed": result.n_failed,
        "wall_s": wall,
        "loops_per_s": result.n_loops / wall,
        "peak_mb": memory.peak_mb,
        "table": result.table,
        "verdicts": result.table["verdict"].value_counts().to_dict(),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--loops", type=int, default=100)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-gap", action="store_true", help="skip the gap diagnosis")
    parser.add_argument("--plant", type=Path, help="existing plant folder (else generated)")
    parser.add_argument("--engines", default="local,dask")
    parser.add_argument("--workers", default="1,2,all")
    a = parser.parse_args(argv)
    cores = os.cpu_count() or 1
    counts = sorted({cores if w == "all" else int(w) for w in a.workers.split(",")})
    engines = a.engines.split(",")
    gap = not a.no_gap

    with tempfile.TemporaryDirectory(prefix="bench_scan-") as tmp:
        scratch = Path(tmp)
        plant = a.plant
        if plant is None:
            plant = scratch / "plant"
            t0 = time.perf_counter()
            _make_plant(plant, a.loops, n_samples=a.samples, seed=a.seed, fmt="csv")
            print(
                f"generated {a.loops} loops x {a.samples} samples in "
                f"{time.perf_counter() - t0:.1f} s",
                flush=True,
            )
        warm = scratch / "warm"
        warm.mkdir()
        for f in sorted(plant.glob("*.csv"))[:2]:
            (warm / f.name).write_bytes(f.read_bytes())
        scan(warm, out=scratch / "warm_out", workers=1, gap=gap)

        results = []
        for engine in engines:
            for workers in counts if engine == "local" else [cores]:
                r = run(plant, engine, workers, gap, scratch)
                results.append(r)
                print(
                    f"{engine:5s} workers={workers}: {r['wall_s']:.1f} s, "
                    f"{r['loops_per_s']:.3f} loops/s, {r['cpu_s_per_loop']:.2f} CPU s/loop, "
                    f"load {r['load']:.1f}, peak {r['peak_mb']:.0f} MB, "
                    f"{r['failed']} failed, verdicts {r['verdicts']}",
                    flush=True,
                )

    base = next((r for r in results if r["engine"] == "local" and r["workers"] == 1), None)
    reference = results[0]["table"].sort_index(axis=1)
    print()
    print(
        f"Scan of {results[0]['loops']} loops x {a.samples} samples, gap diagnosis "
        f"{'on' if gap else 'off'}, {cores} cores ({os.uname().machine})"
    )
    print()
    print(
        "| engine | workers | wall [s] | loops/s | speed-up | CPU s/loop | load avg "
        "| peak memory [MB] | same table |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in results:
        speedup = f"{base['wall_s'] / r['wall_s']:.2f}" if base else "n/a"
        try:
            pd.testing.assert_frame_equal(r["table"].sort_index(axis=1), reference)
            same = "yes"
        except AssertionError:
            same = "NO"
        label = f"{r['workers']}" + (" (all)" if r["workers"] == cores else "")
        print(
            f"| {r['engine']} | {label} | {r['wall_s']:.1f} | {r['loops_per_s']:.3f} | "
            f"{speedup} | {r['cpu_s_per_loop']:.2f} | {r['load']:.1f} | {r['peak_mb']:.0f} "
            f"| {same} |"
        )


if __name__ == "__main__":
    main()
