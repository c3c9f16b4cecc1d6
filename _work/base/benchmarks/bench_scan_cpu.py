"""CPU seconds per loop of a scan with the gap diagnosis: this checkout against another.

Generates two plants with ``scripts/make_plant.py`` (``--loops`` loops of
``--samples`` samples, half with a sticky valve): one where every loop records the
valve position (mv) and one where none does.  Each plant is scanned with one local
worker (``stiction scan``'s :func:`stictiondiag.apps.scan.scan`, gap diagnosis on)
by the code of this checkout and by the code of ``--baseline`` (a checkout of the
code to compare with, e.g. ``git worktree add --detach /tmp/base main``), each in
its own fresh Python process, the two alternating ``--repeat`` times.

CPU time, not wall time, is the measure: the machine may be shared, and wall time
grows with the load while CPU time hardly does.  Each process first scans one loop
(loading or compiling the numba kernels, as any first run does), then measures the
CPU time (user + system, ``time.process_time``; with one worker the scan runs in
that process) of the scan of the whole plant, divided by the number of loops.  The
figures therefore leave out the interpreter's start-up and the imports, which a
scan pays once.

Also prints whether the two versions gave the same verdicts and named the same
gap effect for every loop, and the largest difference in S and J [% of span].

Usage::

    python benchmarks/bench_scan_cpu.py --baseline /tmp/base [--loops 8]
        [--samples 10000] [--seed 5] [--repeat 1]
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

from _plants import make_plant as _make_plant
from _plants import run_in_checkout  # benchmarks/ is on a script's path

ROOT = Path(__file__).resolve().parents[1]

#: The measuring process: scans one loop to warm up, then the plant; prints JSON.
CHILD = r"""
import json, sys, time
from pathlib import Path
import stictiondiag
from stictiondiag.apps.scan import scan
plant, out = Path(sys.argv[1]), Path(sys.argv[2])
warm = out / "warm"
warm.mkdir(parents=True)
first = sorted(plant.glob("*.csv"))[0]
(warm / first.name).write_bytes(first.read_bytes())
scan(warm, out=out / "warm_out", workers=1, gap=True)
t0 = time.process_time()
result = scan(plant, out=out / "scan", workers=1, gap=True)
cpu = time.process_time() - t0
cols = [c for c in ("loop", "verdict", "S", "J", "gap_effect") if c in result.table.columns]
rows = result.table[cols].to_dict(orient="records")
print(json.dumps({"cpu": cpu, "loops": result.n_loops, "failed": result.n_failed, "rows": rows,
                  "package": stictiondiag.__file__}))
"""


def run(code: Path, plant: Path, out: Path) -> dict:
    """Scan ``plant`` with the package of checkout ``code`` in a fresh process."""
    return run_in_checkout(code, CHILD, str(plant), str(out))


def compare(a: list[dict], b: list[dict]) -> str:
    """Loops whose verdict or named effect differ, and the largest S and J change."""
    ra = {r["loop"]: r for r in a}
    rb = {r["loop"]: r for r in b}
    diff = [
        k
        for k in ra
        if any(ra[k].get(c) != rb.get(k, {}).get(c) for c in ("verdict", "gap_effect"))
    ]
    dmax = 0.0
    for k in ra:
        for c in ("S", "J"):
            x, y = ra[k].get(c), rb.get(k, {}).get(c)
            if isinstance(x, float) and isinstance(y, float) and x == x and y == y:
                dmax = max(dmax, abs(x - y))
    same = "same verdicts and effects" if not diff else f"differ on {', '.join(map(str, diff))}"
    return f"{same}; largest S/J change {dmax:.2g} % of span"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--baseline", type=Path, required=True, help="checkout to compare with")
    parser.add_argument("--loops", type=int, default=8)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--repeat", type=int, default=1)
    a = parser.parse_args(argv)
    versions = {"baseline": a.baseline.resolve(), "this": ROOT}
    table = []
    with tempfile.TemporaryDirectory(prefix="bench_scan_cpu-") as tmp:
        scratch = Path(tmp)
        for label, mv_share in (("with mv", 1.0), ("without mv", 0.0)):
            plant = scratch / label.replace(" ", "_")
            _make_plant(plant, a.loops, n_samples=a.samples, seed=a.seed, mv_share=mv_share)
            cpu = {k: [] for k in versions}
            rows = {}
            for rep in range(a.repeat):
                order = list(versions) if rep % 2 == 0 else list(versions)[::-1]
                for name in order:
                    out = scratch / f"{plant.name}-{name}-{rep}"
                    r = run(versions[name], plant, out)
                    per_loop = r["cpu"] / r["loops"]
                    cpu[name].append(per_loop)
                    rows[name] = r["rows"]
                    print(
                        f"{label}, {name}: {per_loop:.2f} CPU-s/loop "
                        f"({r['loops']} loops, {r['failed']} failed, load {os.getloadavg()[0]:.1f})",
                        flush=True,
                    )
            table.append((label, cpu, compare(rows["baseline"], rows["this"])))
    print()
    print(
        f"Scan, one local worker, gap diagnosis on, {a.loops} loops x {a.samples} samples, "
        f"seed {a.seed}; CPU s per loop (min of {a.repeat}); {os.cpu_count()} cores"
    )
    print()
    print("| plant | baseline | this | ratio | results |")
    print("|---|--:|--:|--:|---|")
    for label, cpu, same in table:
        old, new = min(cpu["baseline"]), min(cpu["this"])
        print(f"| {label} | {old:.2f} | {new:.2f} | {new / old:.2f} | {same} |")


if __name__ == "__main__":
    main()
