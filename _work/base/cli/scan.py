"""``stiction scan PATH``: analyse every loop of a plant and rank them for maintenance."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from stictiondiag.core.errors import EXIT_PARTIAL, UsageError

from .app import app
from .common import check_output_dir, compile_if_cold, friendly_errors, info, write_stdout
from .options import (
    ActionOption,
    CompressionOption,
    LoopsOption,
    LoopType,
    LoopTypeOption,
    OpRangeOption,
    OpUnits,
    OpUnitsOption,
    VendorOption,
    positive_seconds,
)


class Engine(str, Enum):
    local = "local"
    dask = "dask"


@app.command()
def scan(
    path: Annotated[
        Path, typer.Argument(help="Folder of per-loop CSV/Parquet files, or a Parquet dataset.")
    ],
    out: Annotated[Path, typer.Option(help="Output folder (table, pages, per-loop JSON).")] = Path(
        "scan"
    ),
    engine: Annotated[
        Engine, typer.Option(help="local process pool or a Dask cluster.")
    ] = Engine.local,
    scheduler: Annotated[
        str | None, typer.Option(help="Address of an existing Dask scheduler (engine dask).")
    ] = None,
    workers: Annotated[
        int | None, typer.Option(min=1, help="Worker processes (default: all cores).")
    ] = None,
    force: Annotated[bool, typer.Option(help="Re-analyse loops already in --out.")] = False,
    gap: Annotated[bool, typer.Option(help="Include the sim-to-real gap diagnosis.")] = True,
    plots: Annotated[
        bool, typer.Option(help="Draw each loop page's figures (about a second per loop).")
    ] = True,
    loop_column: Annotated[
        str | None, typer.Option(help="Loop-id column of a Parquet dataset.")
    ] = None,
    ts: Annotated[
        float | None,
        typer.Option(
            help="Sampling time [s] for files without a time column.", callback=positive_seconds
        ),
    ] = None,
    loops: LoopsOption = None,
    loop_type: LoopTypeOption = LoopType.other,
    op_units: OpUnitsOption = OpUnits.percent,
    op_range: OpRangeOption = None,
    vendor: VendorOption = None,
    action: ActionOption = None,
    compression: CompressionOption = None,
) -> None:
    """Scan many loops; write a ranked table (Parquet, CSV, HTML). Exit 4 if some loops failed.

    PATH may hold whole-plant exports: a wide file with many loops told apart by tag
    prefix (FIC101.PV, FIC101.OP, LIC200.PV, ...) or a long timestamp, tag, value
    file; each loop is a row, an incomplete or ambiguous one fails with the reason.
    The loop type comes from --loops, else --loop-type, else the ISA tag, else the data.
    """
    from stictiondiag.apps.scan import scan as run_scan

    with friendly_errors():
        check_output_dir("--out", out, [path])
        if scheduler is not None and engine is not Engine.dask:
            raise UsageError("--scheduler applies to --engine dask; add --engine dask")
        manifest = None
        if loops is not None:
            from stictiondiag.io.plant import read_manifest

            manifest = read_manifest(loops)
        options = _read_options(ts, loop_type, op_units, op_range, vendor, action, compression)
        with _progress_bar() as (progress, note):
            compile_if_cold()
            result = run_scan(
                path,
                out=out,
                engine=engine.value,
                workers=workers,
                scheduler=scheduler,
                force=force,
                gap=gap,
                plots=plots,
                loop_column=loop_column,
                read_options=options,
                manifest=manifest,
                exclude=(loops,) if loops is not None else (),
                progress=progress,
                on_note=note,
            )
        _summary(result, out)
        if result.n_failed:
            info(f"{result.n_failed} loop(s) failed; see the 'error' column")
            raise typer.Exit(EXIT_PARTIAL)


#: The columns of the ranked table printed on stdout, where the scan has them.
SUMMARY_COLUMNS = (
    "rank",
    "loop",
    "verdict",
    "confidence",
    "S",
    "J",
    "loop_type",
    "loop_type_source",
    "gap_effect",
    "plant_role",
)


def _read_options(ts, loop_type, op_units, op_range, vendor, action, compression) -> dict:
    """The reading options of every loop file, as :func:`stictiondiag.io.tags.read_tags`
    takes them (only those the user set)."""
    options: dict = {"ts": ts} if ts is not None else {}
    if loop_type is not None:
        options["loop_type"] = LoopType(loop_type).value
    if op_units is not OpUnits.percent:
        options["op_units"] = op_units.value
    if op_range is not None:
        options["op_range"] = tuple(op_range)
    for name, choice in (("vendor", vendor), ("action", action), ("compression", compression)):
        if choice is not None:
            options[name] = choice.value
    return options


@contextmanager
def _progress_bar() -> Iterator[tuple[Callable[[int, int, str], None], Callable[[str], None]]]:
    """A progress bar on stderr: the scan's ``progress`` and ``on_note`` callbacks.

    The bar appears once the loops are found, so a bad PATH prints one line only; a
    note goes above the bar while it runs.  The bar is stopped on the way out.
    """
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(
        TextColumn("[bold]scan"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("{task.description}"),
        console=Console(file=sys.stderr),
        transient=False,
    )
    task = bar.add_task("", total=None)

    def note(text: str) -> None:
        if bar.live.is_started:
            bar.console.print(text, markup=False, highlight=False)
        else:
            info(text)

    def progress(done: int, total: int, loop: str) -> None:
        if not bar.live.is_started:
            bar.start()
        bar.update(task, completed=done, total=total, description=loop)

    try:
        yield progress, note
    finally:
        if bar.live.is_started:
            bar.stop()


def _summary(result, out: Path) -> None:
    """What the scan did and wrote (stderr) and the top of the ranked table (stdout)."""
    for f, name in result.renamed.items():
        info(f"note: two files share a name: {f} -> {name}")
    t = result.table
    n_st = int((t["verdict"] == "stiction").sum()) if len(t) else 0
    info(
        f"{result.n_loops} loops: {n_st} stiction, {result.n_failed} failed, "
        f"{result.n_skipped} resumed from {out}"
    )
    info(
        f"wrote {result.outputs.get('html')}, {result.outputs.get('parquet')}, {result.outputs.get('csv')}"
    )
    _plant_lines(result.plantwide)
    cols = [c for c in SUMMARY_COLUMNS if c in t]
    if "error" in t:
        for _, row in t[t["verdict"] == "error"].iterrows():
            info(f"not analysed: {row['loop']}: {row['error']}")
    write_stdout(t[cols].head(20).to_string(index=False) + "\n")


def _plant_lines(plant: dict) -> None:
    """The plant-wide groups (or why there are none) on stderr."""
    if not plant:
        return
    if plant.get("status") != "on":
        info(plant.get("reason", "plant-wide grouping off"))
        return
    groups = plant.get("groups", [])
    info(f"plant-wide: {len(groups)} group(s) of loops sharing a cycle")
    for g in groups:
        source = " or ".join(g["source_candidates"])
        single = "" if g["source_clear"] else " (the evidence does not single out one)"
        info(
            f"  group {g['group']}: period {g['period_s']:.4g} s, {', '.join(g['members'])}; "
            f"source {source}{single}"
        )
