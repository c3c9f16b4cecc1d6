"""Diagnose generated quantisation loops from their CSV files, as ``stiction benchmark`` does.

    python scripts/quantization_loops.py              # s = 8001-8060
    python scripts/quantization_loops.py --first 8001 --count 60

Each loop is ``generate_case("quantization", s)``, written to a temporary CSV file and
diagnosed through ``analyze_file``; prints one line per loop (seed, named effect, gap
before and after [%], shrink [%]), then how many are named ``quantization`` and the
median shrink of those.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

from stictiondiag.apps.benchmark import _diagnose_path
from stictiondiag.core.atomic import write_atomic
from stictiondiag.models.synthetic import _csv_bytes, generate_case


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", type=int, default=8001)
    ap.add_argument("--count", type=int, default=60)
    args = ap.parse_args()
    named, shrinks = 0, []
    with tempfile.TemporaryDirectory() as td:
        for s in range(args.first, args.first + args.count):
            path = Path(td) / f"quantization_{s}.csv"
            write_atomic(path, _csv_bytes(generate_case("quantization", s).data))
            g, _ = _diagnose_path(path)
            if g.effect == "quantization":
                named += 1
                shrinks.append(g.shrink_pct)
            print(f"{s} {g.effect} {g.before:.2f} {g.after:.2f} {g.shrink_pct:.1f}", flush=True)
    med = statistics.median(shrinks) if shrinks else float("nan")
    print(f"named {named} of {args.count}, median shrink {med:.1f} %")


if __name__ == "__main__":
    main()
