"""Growth of ``stiction analyze`` with record length; prints a table per step.

The loop is the concentration loop of Eq. 3 / Table 3 (Choudhury, Thornhill & Shah
2005) at 1 s, S = 5 %, J = 2 %, measurement noise 0.05: the loop of
``benchmarks/bench_analyze.py``, simulated for 10^4 .. 10^7 samples and written as
Parquet (a CSV of 10^7 rows takes longer to write than the analysis runs).  Each
record is analysed the way ``stiction analyze FILE`` does it (read, the loop type
from the data, oscillation, S and J, verdict, replay, the compensation study where
the checkout has it and,
with ``--gap``, the sim-to-real gap; no figures), in a fresh process per size that first analyses a 5000-sample loop so that the loading
of numba's cache is not counted.

Two runs per size and variant:

* ``time``: CPU time per step [s] (the wall time of a shared machine is mostly
  waiting), wall and CPU time of the analysis and the process's peak resident memory
  (``ru_maxrss``, the interpreter and libraries included);
* ``memory``: the peak of the memory the step allocates on top of what was live
  when it started [bytes], from :mod:`tracemalloc` (numpy reports its buffers to
  it); a second run because tracing slows pure-Python code.

Variants: ``mv`` (S and J from the mv-op segments) and ``nomv`` (the Hammerstein
fit of op to pv).  The growth ratio ``t(500k) / t(50k)`` of the analysis is printed
with ``--ratio`` (sizes 5e4 and 5e5; issue 19 asks for at most 11x).

Usage::

    python benchmarks/scaling.py                        # 1e4 1e5 1e6, both variants
    python benchmarks/scaling.py --sizes 5e4 5e5 --variants mv --ratio
    python benchmarks/scaling.py --sizes 1e7 --variants nomv --no-memory

Run another checkout's code with ``PYTHONPATH=/path/to/checkout python
benchmarks/scaling.py``; the children inherit the environment.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Steps of :func:`stictiondiag.analysis.analyze`, timed by wrapping the functions
#: it calls (name in ``stictiondiag.analysis`` -> step).
STEPS = {
    "read_tags": "read",
    "settle_loop_type": "loop type",
    "find_oscillations": "oscillation",
    "estimate_stiction": "fit",
    "stiction_verdict": "verdict",
    "replay": "replay",
    "compensation_from_replay": "compensation",
    "diagnose_gap": "gap",
}
#: Samples of the warm-up loop analysed before the timed run.
WARMUP_SAMPLES = 5000


def make_loop(path: Path, n: int, with_mv: bool) -> Path:
    """Write an ``n``-sample record of the benchmark loop to ``path`` (Parquet)."""
    import pandas as pd

    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.models.processes import LOOP_PARAMETERS

    loop = LOOP_PARAMETERS["concentration"]
    warmup = 500
    sim = simulate_loop(
        loop["process"],
        loop["controller"],
        duration=float(n + warmup),
        dt=1.0,
        S=5.0,
        J=2.0,
        noise_std=0.05,
        seed=11,
    )
    keep = slice(warmup, warmup + n)
    cols = {
        "time": sim.time[keep] - sim.time[warmup],
        "sp": sim.sp[keep],
        "pv": sim.pv[keep],
        "op": sim.op[keep],
    }
    if with_mv:
        cols["mv"] = sim.mv[keep]
    pd.DataFrame(cols).to_parquet(path, index=False)
    return path


def _child(path: str, gap: bool, trace: bool, warm_path: str) -> None:
    """One timed (or traced) analysis in this process; prints a JSON line."""
    import resource
    import tracemalloc

    import stiction_cli  # noqa: F401  (the command's environment: one BLAS thread)
    import stictiondiag.analysis as analysis

    seconds: dict[str, float] = {}
    cpu: dict[str, float] = {}
    peaks: dict[str, int] = {}

    def wrap(name, step, function):
        def timed(*args, **kwargs):
            if trace:
                base = tracemalloc.get_traced_memory()[0]
                tracemalloc.reset_peak()
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                seconds[step] = seconds.get(step, 0.0) + time.perf_counter() - t0
                cpu[step] = cpu.get(step, 0.0) + time.process_time() - c0
                if trace:
                    peak = tracemalloc.get_traced_memory()[1]
                    peaks[step] = max(peaks.get(step, 0), peak - base)
                    peaks["_all"] = max(peaks.get("_all", 0), peak)

        return timed

    for name, step in STEPS.items():
        if hasattr(analysis, name):  # an older checkout may lack a step
            setattr(analysis, name, wrap(name, step, getattr(analysis, name)))
    config = analysis.AnalysisConfig(gap=gap)
    analysis.analyze_file(warm_path, config=config)  # numba's cache, lazy imports
    seconds.clear()
    cpu.clear()
    peaks.clear()
    if trace:
        tracemalloc.start()
    t0, c0 = time.perf_counter(), time.process_time()
    result = analysis.analyze_file(path, config=config)
    total = time.perf_counter() - t0
    out = {
        "seconds": seconds,
        "cpu": cpu,
        "total": total,
        "total_cpu": time.process_time() - c0,
        "peak_bytes": peaks,
        "maxrss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "n": int(result.tags.n),
        "S": result.fit.S,
        "J": result.fit.J,
        "period_s": result.oscillation.period_s,
        "verdict": result.verdict.status,
    }
    if trace:
        out["total_peak_bytes"] = max(peaks.pop("_all", 0), tracemalloc.get_traced_memory()[1])
    print(json.dumps(out))


def _run_child(path: Path, gap: bool, trace: bool, warm: Path) -> dict:
    cmd = [
        sys.executable,
        __file__,
        "--child",
        str(path),
        str(int(gap)),
        str(int(trace)),
        str(warm),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    if proc.returncode != 0:
        raise SystemExit(f"child failed on {path}:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _fmt_bytes(b: float | None) -> str:
    if b is None:
        return "-"
    return f"{b / 2**20:.0f} MiB" if b >= 2**20 else f"{b / 2**10:.0f} KiB"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    parser.add_argument("--variants", nargs="+", choices=("mv", "nomv"), default=["mv", "nomv"])
    parser.add_argument("--gap", action="store_true", help="include the gap diagnosis")
    parser.add_argument("--no-memory", action="store_true", help="skip the traced run")
    parser.add_argument("--ratio", action="store_true", help="print t(5e5) / t(5e4)")
    parser.add_argument("--data", type=Path, help="folder for the records (default: a temp dir)")
    args = parser.parse_args(argv)

    import stictiondiag

    print(
        f"# stictiondiag from {Path(stictiondiag.__file__).parent}; gap={'on' if args.gap else 'off'}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.data or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        totals: dict[tuple[str, int], tuple[float, float]] = {}
        for variant in args.variants:
            warm = folder / f"warm_{variant}.parquet"
            if not warm.exists():
                make_loop(warm, WARMUP_SAMPLES, variant == "mv")
            print(f"\n## {variant}: per step CPU [s] / traced peak above the step's start")
            head = ["samples", "wall [s]", "CPU [s]", *STEPS.values()]
            head += ["max RSS", "traced peak", "bytes/sample"]
            print("| " + " | ".join(head) + " |")
            print("|" + "---|" * len(head))
            for size in args.sizes:
                n = int(size)
                path = folder / f"loop_{variant}_{n}.parquet"
                if not path.exists():
                    make_loop(path, n, variant == "mv")
                res = _run_child(path, args.gap, False, warm)
                mem = None if args.no_memory else _run_child(path, args.gap, True, warm)
                totals[(variant, n)] = (res["total"], res["total_cpu"])
                steps = [
                    f"{res['cpu'].get(s, 0.0):.2f}"
                    + ("" if mem is None else f" / {_fmt_bytes(mem['peak_bytes'].get(s))}")
                    for s in STEPS.values()
                ]
                peak = None if mem is None else mem["total_peak_bytes"]
                per = "-" if peak is None else f"{peak / n:.0f}"
                row = [f"{n:.0e}", f"{res['total']:.2f}", f"{res['total_cpu']:.2f}", *steps]
                row += [_fmt_bytes(res["maxrss_bytes"]), _fmt_bytes(peak), per]
                print("| " + " | ".join(row) + " |", flush=True)
                print(
                    f"<!-- S={res['S']:.3f} J={res['J']:.3f} period={res['period_s']} "
                    f"verdict={res['verdict']} -->",
                    flush=True,
                )
            if args.ratio and (variant, 50_000) in totals and (variant, 500_000) in totals:
                (w1, c1), (w2, c2) = totals[(variant, 50_000)], totals[(variant, 500_000)]
                print(f"\ngrowth 5e4 -> 5e5 ({variant}): wall {w2 / w1:.1f}x, CPU {c2 / c1:.1f}x")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        _child(sys.argv[2], sys.argv[3] == "1", sys.argv[4] == "1", sys.argv[5])
    else:
        main()
