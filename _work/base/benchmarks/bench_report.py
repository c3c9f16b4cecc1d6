"""Wall time of a report over the bundled sample loops; prints a table.

Measures

1. ``stiction report sample_data/*.csv --out DIR`` as a CI job runs it: a fresh
   process (imports, numba's on-disk cache, analysis, figures, HTML), timed from the
   outside, with the default workers (one per core) and with ``--workers 1``;
   target: < 30 s with the gap diagnosis;
2. :func:`stictiondiag.apps.report.build_report` over the same files in this process with
   one worker, per loop (analysis + figures + page), with and without the gap
   diagnosis; the first pass pays this process's imports and cache loading.

Usage: ``python benchmarks/bench_report.py [--files GLOB] [--skip-cli]``.
"""

from __future__ import annotations

import argparse
import glob
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 30.0


def time_cli(files: list[str], gap: bool, workers: int | None) -> tuple[float, int]:
    """Seconds and exit code of the ``stiction report`` command in a fresh process."""
    out = tempfile.mkdtemp(prefix="bench_report_cli_")
    try:
        # The console-script entry point, run by this interpreter.
        entry = "from stiction_cli.main import main; main()"
        cmd = [sys.executable, "-c", entry, "report", *files, "--out", out]
        if not gap:
            cmd.append("--no-gap")
        if workers is not None:
            cmd += ["--workers", str(workers)]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        elapsed = time.perf_counter() - t0
        if proc.returncode not in (0, 1):
            print(proc.stderr[-2000:], file=sys.stderr)
        return elapsed, proc.returncode
    finally:
        shutil.rmtree(out, ignore_errors=True)


def time_library(files: list[str], gap: bool) -> tuple[float, dict[str, float], list]:
    """Total seconds, seconds per loop, and the index rows of one :func:`build_report`."""
    from stictiondiag.apps.report import build_report

    marks: list[tuple[float, str]] = []

    def progress(i: int, n: int, name: str) -> None:
        marks.append((time.perf_counter(), name))

    out = tempfile.mkdtemp(prefix="bench_report_lib_")
    try:
        t0 = time.perf_counter()
        marks.append((time.perf_counter(), ""))
        result = build_report(files, out, gap=gap, workers=1, progress=progress)
        total = time.perf_counter() - t0
    finally:
        shutil.rmtree(out, ignore_errors=True)
    # progress() is called after each loop: a loop's time runs from the previous mark.
    per_loop = {name: t - marks[k][0] for k, (t, name) in enumerate(marks[1:])}
    return total, per_loop, result.rows


def main() -> None:
    from stictiondiag.apps.report import default_workers

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", default=str(ROOT / "sample_data" / "*.csv"))
    parser.add_argument("--skip-cli", action="store_true", help="only the in-process timing")
    args = parser.parse_args()
    files = sorted(glob.glob(args.files))
    if not files:
        sys.exit(f"no files match {args.files}")
    print(f"{len(files)} loops: {', '.join(Path(f).stem for f in files)}\n")

    if not args.skip_cli:
        print("| stiction report (fresh process) | wall [s] | exit | target |")
        print("|---|---|---|---|")
        for gap, workers in ((True, None), (True, 1), (False, None)):
            seconds, code = time_cli(files, gap, workers)
            flag = ("" if gap else " --no-gap") + (
                "" if workers is None else f" --workers {workers}"
            )
            verdict = "ok" if seconds < TARGET_S else "OVER"
            print(
                f"| `report sample_data/*.csv{flag}` | {seconds:.1f} | {code} | "
                f"< {TARGET_S:.0f} s {verdict} |"
            )
        print(f"\n(default workers here: {default_workers(len(files))})\n")

    runs = {}
    for label, gap in (("gap, first pass", True), ("no gap", False)):
        runs[label] = time_library(files, gap)
    print("| loop | verdict | " + " | ".join(f"{k} [s]" for k in runs) + " |")
    print("|---|---|" + "---|" * len(runs))
    rows = {r["loop"]: r for r in runs["gap, first pass"][2]}
    for f in files:
        name = Path(f).stem
        cells = " | ".join(f"{runs[k][1].get(name, float('nan')):.2f}" for k in runs)
        print(f"| {name} | {rows.get(name, {}).get('verdict', '?')} | {cells} |")
    totals = " | ".join(f"**{runs[k][0]:.1f}**" for k in runs)
    print(f"| total build_report, 1 worker | | {totals} |")


if __name__ == "__main__":
    main()
