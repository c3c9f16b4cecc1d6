"""Speed of the valve models and the closed-loop simulator; prints a table.

Measures

1. the data-driven stiction model (:func:`stictiondiag.models.valve.choudhury_model`):
   throughput compiled by numba against the very same code run as plain Python
   (``NUMBA_DISABLE_JIT=1`` in a child process, so the algorithm is identical);
   target: compiled >= 20 x faster;
2. 3000 s of the physical valve (Section 4) in the concentration loop of Eq. 3 at the
   valve's integration step (1e-4 s, 3e7 steps): the first call in a fresh process
   with an empty numba cache (compilation) and with the on-disk cache, and warm
   calls; target: < 1 s warm;
3. for scale, 3000 s of the data-driven valve in the same loop at 0.1 s.

Usage: ``python benchmarks/bench_models.py [--quick]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time

_CHILD_MODEL = textwrap.dedent(
    """
    import json, sys, time
    import numpy as np
    from stictiondiag.models.valve import choudhury_model
    n = int(sys.argv[1])
    rng = np.random.default_rng(0)
    t = np.arange(n) * 0.1
    op = 50 + 10 * np.sin(2 * np.pi * t / 50) + rng.normal(0, 0.2, n)
    choudhury_model(op[:100], 5.0, 2.0)  # compile / load cache
    elapsed = float("inf")
    for _ in range(int(sys.argv[2])):  # best of: the machine may be shared
        t0 = time.perf_counter()
        mv = choudhury_model(op, 5.0, 2.0)
        elapsed = min(elapsed, time.perf_counter() - t0)
    print(json.dumps({"seconds": elapsed, "checksum": float(np.sum(mv))}))
    """
)

_CHILD_LOOP = textwrap.dedent(
    """
    import json, time
    t0 = time.perf_counter()
    from stictiondiag.models.loops import simulate_paper_loop
    t1 = time.perf_counter()
    sim = simulate_paper_loop("concentration", valve="physical", duration=3000.0)
    t2 = time.perf_counter()
    print(json.dumps({"import": t1 - t0, "first_call": t2 - t1}))
    """
)


def _child(code: str, *args: str, disable_jit: bool = False, cache_dir: str | None = None) -> dict:
    env = dict(os.environ)
    if disable_jit:
        env["NUMBA_DISABLE_JIT"] = "1"
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir  # empty cache: compile from scratch
    out = subprocess.run(
        [sys.executable, "-c", code, *args], env=env, check=True, capture_output=True, text=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller sizes, fewer repeats")
    opts = parser.parse_args()
    n_compiled = 1_000_000 if opts.quick else 5_000_000
    n_python = 50_000 if opts.quick else 200_000
    repeat = 2 if opts.quick else 3

    rows = []
    compiled = _child(_CHILD_MODEL, str(n_compiled), str(repeat))
    python = _child(_CHILD_MODEL, str(n_python), "1", disable_jit=True)
    rate_c = n_compiled / compiled["seconds"]
    rate_p = n_python / python["seconds"]
    rows.append(("data-driven model, compiled", f"{rate_c / 1e6:.1f} M samples/s", ""))
    rows.append(("data-driven model, plain Python", f"{rate_p / 1e3:.1f} k samples/s", ""))
    rows.append(("  speed-up", f"{rate_c / rate_p:.0f} x", "target >= 20 x"))

    with tempfile.TemporaryDirectory() as empty:
        cold = _child(_CHILD_LOOP, cache_dir=empty)
    first = _child(_CHILD_LOOP)
    from stictiondiag.models.loops import simulate_paper_loop

    simulate_paper_loop("concentration", valve="physical", duration=10.0)  # warm
    warm = _best(
        lambda: simulate_paper_loop("concentration", valve="physical", duration=3000.0), repeat
    )
    steps = 3000.0 / 1e-4
    rows.append(
        (
            "physical valve loop, 3000 s at 1e-4 s, first call, cold",
            f"{cold['first_call']:.2f} s",
            "empty numba cache: compilation included",
        )
    )
    rows.append(
        (
            "physical valve loop, 3000 s at 1e-4 s, first call",
            f"{first['first_call']:.2f} s",
            f"fresh process, numba cache warm (+ {first['import']:.2f} s import)",
        )
    )
    rows.append(
        (
            "physical valve loop, 3000 s at 1e-4 s, warm",
            f"{warm:.3f} s",
            f"{steps / warm / 1e6:.0f} M steps/s; target < 1 s",
        )
    )
    dd = _best(lambda: simulate_paper_loop("concentration", 5.0, 2.0, duration=3000.0), repeat)
    rows.append(("data-driven valve loop, 3000 s at 0.1 s, warm", f"{dd * 1e3:.1f} ms", ""))

    width = max(len(r[0]) for r in rows)
    print(f"{'benchmark':<{width}}  {'result':>18}  note")
    print("-" * (width + 40))
    for name, value, note in rows:
        print(f"{name:<{width}}  {value:>18}  {note}")
    print(f"\n(python {sys.version.split()[0]}, {os.cpu_count()} cpus)")


if __name__ == "__main__":
    main()
