"""``stiction benchmark``: withheld-effect benchmark of the gap diagnosis."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .app import app
from .common import friendly_errors, info


@app.command()
def benchmark(
    cases: Annotated[int, typer.Option(min=1, help="Number of generated loops.")] = 40,
    seed: Annotated[int, typer.Option(help="Benchmark seed (same seed, same cases).")] = 2026,
    out: Annotated[
        Path, typer.Option(help="Directory for the case files and results.json / .csv / .md.")
    ] = Path("benchmark_out"),
) -> None:
    """Generate loops with one hidden effect each, diagnose them from their files, score.

    Prints top-1 accuracy, median shrink on the correctly named cases, none
    specificity and the confusion matrix; progress goes to stderr.
    """
    from stictiondiag.apps.benchmark import run_benchmark
    from stictiondiag.core.errors import UsageError

    with friendly_errors():
        if out.exists() and not out.is_dir():
            raise UsageError(f"cannot write to {out}: it is a file; give a directory for --out")

        def progress(i: int, total: int, r) -> None:
            named = r.named if r.named is not None else f"failed ({r.error})"
            shrink = "" if r.shrink_pct is None else f", shrink {r.shrink_pct:.0f} %"
            info(
                f"[{i + 1}/{total}] {r.file}: hidden {r.truth}, named {named}{shrink} ({r.seconds:.1f} s)"
            )

        info(f"benchmark: {cases} cases, seed {seed}, files in {out}")
        result = run_benchmark(out, n_cases=cases, seed=seed, progress=progress)
        typer.echo(result.table())
        info(f"wrote {out / 'results.json'}, {out / 'results.csv'}, {out / 'results.md'}")
