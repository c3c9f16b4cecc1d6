"""CPU seconds per loop of the gap diagnosis alone: this checkout against another.

``bench_scan_cpu.py`` measures a whole scan; this measures only
:func:`stictiondiag.gap.diagnose.diagnose_gap` as ``analyze`` calls it, so that a
change to the gap diagnosis shows undiluted.  Two plants come from
``scripts/make_plant.py`` (``--loops`` loops of ``--samples`` samples, half with a
sticky valve): one where every loop records mv and one where none does.  Each
checkout runs in its own fresh Python process with one BLAS thread: it analyses
every loop with ``analyze`` and times each call of ``diagnose_gap`` with
``time.process_time`` (user + system CPU of the process; the first loop is analysed
twice and its first diagnosis, which loads the compiled kernels, is left out).

Also prints whether the two versions named the same gap effect for every loop and
the largest relative difference of the gap before and after the effect.

Usage::

    python benchmarks/bench_gap_cpu.py --baseline /tmp/base [--loops 8]
        [--samples 10000] [--seed 5]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from _plants import make_plant as _make_plant
from _plants import run_in_checkout  # benchmarks/ is on a script's path

ROOT = Path(__file__).resolve().parents[1]

#: The measuring process: analyses every loop, timing the gap diagnosis; prints JSON.
CHILD = r"""
import json, sys, time
from pathlib import Path
import stictiondiag
import stictiondiag.analysis as A
from stictiondiag.io.tags import read_tags
cpu = []
inner = A.diagnose_gap
def timed(*args, **kwargs):
    t0 = time.process_time()
    out = inner(*args, **kwargs)
    cpu.append(time.process_time() - t0)
    return out
A.diagnose_gap = timed
files = sorted(Path(sys.argv[1]).glob("*.csv"))
A.analyze(read_tags(files[0]))  # loads the compiled kernels
cpu.clear()
rows = []
for f in files:
    res = A.analyze(read_tags(f))
    gap = res.gap
    rows.append({"loop": f.stem, "effect": None if gap is None else gap.effect,
                 "before": None if gap is None else gap.before,
                 "after": None if gap is None else gap.after})
print(json.dumps({"cpu": cpu, "rows": rows, "package": stictiondiag.__file__}))
"""


def run(code: Path, plant: Path) -> dict:
    """Analyse ``plant`` with the package of checkout ``code`` in a fresh process."""
    return run_in_checkout(code, CHILD, str(plant))


def _largest_change(a: list, b: list) -> float:
    worst = 0.0
    for x, y in zip(a, b, strict=True):
        for key in ("before", "after"):
            u, v = x[key], y[key]
            if u is not None and v is not None and max(abs(u), abs(v)) > 0:
                worst = max(worst, abs(u - v) / max(abs(u), abs(v)))
    return worst


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, required=True, help="checkout to compare with")
    ap.add_argument("--loops", type=int, default=8)
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args(argv)
    print(
        f"Gap diagnosis alone, {args.loops} loops x {args.samples} samples, seed {args.seed}; "
        "CPU s per loop (mean over the loops)\n"
    )
    print("| plant | baseline | this | ratio | results |")
    print("|---|--:|--:|--:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, share in (("with mv", 1.0), ("without mv", 0.0)):
            plant = Path(tmp) / label.replace(" ", "_")
            _make_plant(plant, args.loops, n_samples=args.samples, seed=args.seed, mv_share=share)
            base = run(args.baseline.resolve(), plant)
            this = run(ROOT, plant)
            cb = sum(base["cpu"]) / max(len(base["cpu"]), 1)
            ct = sum(this["cpu"]) / max(len(this["cpu"]), 1)
            same = [
                x["effect"] == y["effect"] for x, y in zip(base["rows"], this["rows"], strict=True)
            ]
            verdict = "same effects" if all(same) else f"{same.count(False)} effects differ"
            change = _largest_change(base["rows"], this["rows"])
            print(
                f"| {label} | {cb:.3f} | {ct:.3f} | {ct / cb:.2f} | {verdict}; "
                f"largest relative change of the gap {change:.1e} |"
            )


if __name__ == "__main__":
    main()
