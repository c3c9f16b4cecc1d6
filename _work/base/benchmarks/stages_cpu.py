"""CPU per loop of each step of a scan with the gap diagnosis; prints a table.

Generates the plants of ``benchmarks/bench_scan_cpu.py`` (``scripts/make_plant.py``:
``--loops`` loops of ``--samples`` samples, half with a sticky valve; one plant with
mv recorded in every loop, one without), scans each with one local worker after a
warm-up scan of one loop, and times the steps of the analysis by wrapping them
(CPU seconds, ``time.process_time``; the wrappers cost microseconds, unlike a
profiler, which inflates Python-level code against compiled kernels).  Steps nest:
the split-half fits are part of the verdict, the base fit and the effects part of
the gap diagnosis.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/stages_cpu.py [--loops 8] [--samples 10000] [--seed 5]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from _plants import make_plant as _make_plant  # benchmarks/ is on a script's path

#: (module, function) pairs timed, by the name the analysis calls them under.
STEPS = {
    "stictiondiag.analysis": (
        "settle_loop_type",
        "find_oscillations",
        "estimate_stiction",
        "stiction_verdict",
        "replay",
        "diagnose_gap",
    ),
    "stictiondiag.stiction.verdict": ("split_half_estimates", "classic_votes"),
    "stictiondiag.gap.diagnose": ("fit_base", "heldout_errors", "breakdown"),
}


def _timed(acc: dict, func, label: str):
    def timed(*args, **kwargs):
        t0 = time.process_time()
        try:
            return func(*args, **kwargs)
        finally:
            acc[label] += time.process_time() - t0

    return timed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--loops", type=int, default=8)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=5)
    a = parser.parse_args()

    import importlib

    from stictiondiag.apps.scan import scan
    from stictiondiag.gap.effects import EFFECT_MODELS

    acc: dict[str, float] = defaultdict(float)
    for mod_name, names in STEPS.items():
        module = importlib.import_module(mod_name)
        for name in names:
            label = f"{mod_name.rsplit('.', 1)[-1]}.{name}"
            setattr(module, name, _timed(acc, getattr(module, name), label))
    # The effects' fits (the whole record's and the held-out blocks').
    for effect, fit in list(EFFECT_MODELS.items()):
        EFFECT_MODELS[effect] = _timed(acc, fit, f"effect.{effect}")
    with tempfile.TemporaryDirectory(prefix="stages_cpu-") as tmp:
        scratch = Path(tmp)
        for label, mv_share in (("with mv", 1.0), ("without mv", 0.0)):
            plant = scratch / label.replace(" ", "_")
            _make_plant(plant, a.loops, n_samples=a.samples, seed=a.seed, mv_share=mv_share)
            warm = scratch / f"warm_{plant.name}"
            warm.mkdir()
            first = sorted(plant.glob("*.csv"))[0]
            shutil.copy(first, warm / first.name)
            scan(warm, out=scratch / f"warm_out_{plant.name}", workers=1, gap=True)
            acc.clear()
            t0 = time.process_time()
            result = scan(plant, out=scratch / f"out_{plant.name}", workers=1, gap=True)
            total = time.process_time() - t0
            n = max(result.n_loops, 1)
            print(f"\n{label}: {1000 * total / n:.0f} ms of CPU per loop ({n} loops)\n")
            print("| step | ms per loop | share |\n|---|--:|--:|")
            for step, cpu in sorted(acc.items(), key=lambda kv: -kv[1]):
                print(f"| `{step}` | {1000 * cpu / n:.0f} | {100 * cpu / total:.0f} % |")


if __name__ == "__main__":
    main()
