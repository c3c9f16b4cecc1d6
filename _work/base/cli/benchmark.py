"""``stiction benchmark``: withheld-effect benchmark of the gap diagnosis, or with
``--plant`` the plant-wide benchmark (groups of loops sharing a cycle, their source)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from stictiondiag.core.errors import UsageError

from .app import app
from .common import friendly_errors, info, write_stdout

#: Most cases (or plants) one benchmark run takes: each costs seconds of CPU, so
#: more would run for days; the cases are drawn one at a time whatever the number.
MAX_CASES = 100_000

#: Seeds are 32-bit unsigned integers (numpy's SeedSequence entropy).
MAX_SEED = 2**32 - 1


@app.command()
def benchmark(
    cases: Annotated[
        int,
        typer.Option(min=1, max=MAX_CASES, help="Number of generated loops (plants with --plant)."),
    ] = 40,
    seed: Annotated[
        int,
        typer.Option(min=0, max=MAX_SEED, help="Benchmark seed (same seed, same cases)."),
    ] = 2026,
    out: Annotated[
        Path, typer.Option(help="Directory for the case files and results.json / .csv / .md.")
    ] = Path("benchmark_out"),
    plant: Annotated[
        bool,
        typer.Option(
            "--plant",
            help="Simulated plants (5-15 loops, sticky sources whose cycles propagate): "
            "scan each, score the groups, sources and propagated calls.",
        ),
    ] = False,
) -> None:
    """Generate loops with one hidden effect each, diagnose them from their files, score.

    Prints top-1 accuracy, median shrink on the correctly named cases, none
    specificity and the confusion matrix; progress goes to stderr.  With --plant:
    generate plants, scan each from its file (gap diagnosis off) and print the
    share of loops in the right group, of groups whose true source is ranked
    first, and of propagated loops called stiction.
    """
    from stictiondiag.apps.benchmark import run_benchmark

    with friendly_errors():
        if out.exists() and not out.is_dir():
            raise UsageError(f"cannot write to {out}: it is a file; give a directory for --out")
        if plant:
            _plant_benchmark(cases, seed, out)
            return

        def progress(i: int, total: int, r) -> None:
            named = r.named if r.named is not None else f"failed ({r.error})"
            shrink = "" if r.shrink_pct is None else f", shrink {r.shrink_pct:.0f} %"
            info(
                f"[{i + 1}/{total}] {r.file}: hidden {r.truth}, named {named}{shrink} ({r.seconds:.1f} s)"
            )

        info(f"benchmark: {cases} cases, seed {seed}, files in {out}")
        result = run_benchmark(out, n_cases=cases, seed=seed, progress=progress)
        write_stdout(result.table() + "\n")
        info(f"wrote {out / 'results.json'}, {out / 'results.csv'}, {out / 'results.md'}")


def _plant_benchmark(plants: int, seed: int, out: Path) -> None:
    from stictiondiag.apps.plant_benchmark import run_plant_benchmark

    def progress(i: int, total: int, s) -> None:
        info(
            f"[{i + 1}/{total}] plant {s.seed}: {s.n_loops} loops, "
            f"{s.membership_right} in the right group, sources first {s.sources_first}/"
            f"{s.n_groups}, propagated called stiction {s.propagated_stiction}/"
            f"{s.n_propagated} ({s.seconds:.1f} s)"
        )

    info(f"plant benchmark: {plants} plants, seeds {seed} to {seed + plants - 1}, files in {out}")
    result = run_plant_benchmark(out, n_plants=plants, seed=seed, workers=1, progress=progress)
    write_stdout(result.table() + "\n")
    info(f"wrote {out / 'plant_results.json'}, {out / 'plant_results.md'}")
