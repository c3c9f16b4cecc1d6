"""``stiction report FILE... --out DIR``: HTML per loop, an index, Markdown and JSON.

For CI: ``--fail-on-stiction [THRESHOLD]`` exits 1 when a loop is called stiction
with confidence at or above THRESHOLD (0-1; 0.5 when given without a value).
stdout carries only what is asked for (``--markdown -`` prints the summary there);
progress goes to stderr.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.errors import (
    EXIT_FINDING,
    EXIT_PARTIAL,
)

from .app import app
from .common import (
    check_output_dir,
    check_output_file,
    compile_if_cold,
    fail,
    friendly_errors,
    info,
    write_stdout,
)
from .options import (
    ActionOption,
    CompressionOption,
    IntegratingOption,
    LoopsOption,
    LoopType,
    LoopTypeOption,
    ModeOption,
    MvOption,
    OpOption,
    OpRangeOption,
    OpUnits,
    OpUnitsOption,
    PvOption,
    SpOption,
    TimeOption,
    TsOption,
    VendorOption,
    command_read_options,
)

#: Threshold used when ``--fail-on-stiction`` is given without a value.
DEFAULT_FAIL_THRESHOLD = 0.5


@app.command()
def report(
    files: Annotated[list[Path], typer.Argument(help="Loop files (CSV or Parquet).")],
    out: Annotated[Path, typer.Option(help="Report folder (updated, not wiped).")] = Path("report"),
    fail_on_stiction: Annotated[
        float | None,
        typer.Option(
            help="Exit 1 if a loop is called stiction with confidence >= THRESHOLD "
            f"(0-1; bare flag = {DEFAULT_FAIL_THRESHOLD}).",
            metavar="[THRESHOLD]",
        ),
    ] = None,
    clean: Annotated[
        bool,
        typer.Option(
            help="First remove what earlier runs of the report wrote in the folder "
            "(as listed in its manifest; nothing else, never an input)."
        ),
    ] = False,
    markdown: Annotated[
        str | None, typer.Option(help="Also write the Markdown summary to PATH ('-' = stdout).")
    ] = None,
    gap: Annotated[bool, typer.Option(help="Include the sim-to-real gap diagnosis.")] = True,
    workers: Annotated[
        int | None,
        typer.Option(
            min=1,
            help="Loops analysed side by side (default: one per core, less one, on 4+ cores; else 1).",
        ),
    ] = None,
    pv: PvOption = None,
    op: OpOption = None,
    mv: MvOption = None,
    sp: SpOption = None,
    time: TimeOption = None,
    ts: TsOption = None,
    op_units: OpUnitsOption = OpUnits.percent,
    op_range: OpRangeOption = None,
    loop_type: LoopTypeOption = LoopType.other,
    integrating: IntegratingOption = None,
    vendor: VendorOption = None,
    action: ActionOption = None,
    compression: CompressionOption = None,
    mode: ModeOption = None,
    loops: LoopsOption = None,
) -> None:
    """Write a self-contained HTML report per loop, an index page, summary.md and JSON.

    A file may hold many loops: a wide export grouped by tag prefix (FIC101.PV,
    FIC101.OP, LIC200.PV, ...) or a long timestamp, tag, value export; each loop gets
    its page, an incomplete or ambiguous one is listed with the reason.  --loops gives
    per-loop settings; the loop type comes from it, else --loop-type, else the ISA
    tag, else the data.

    Exit codes: 0 success, 1 stiction found (with --fail-on-stiction), 2 usage error,
    3 no input could be read, 4 some inputs could not be analysed.
    """
    from stictiondiag.apps.report import (
        build_report,
        render_markdown,
    )

    if fail_on_stiction is not None and not 0.0 <= fail_on_stiction <= 1.0:
        fail(f"--fail-on-stiction threshold must be in [0, 1], got {fail_on_stiction}", 2)
    with friendly_errors():
        check_output_dir("--out", out, files)
        check_output_file("--markdown", markdown, files)
        options = command_read_options(locals())
        manifest = None
        if loops is not None:
            from stictiondiag.io.plant import read_manifest

            manifest = read_manifest(loops)

        def progress(done: int, n: int, name: str) -> None:
            info(f"[{done}/{n}] {name}")

        info(f"reporting {len(files)} file(s) into {out}")
        compile_if_cold()
        result = build_report(
            [str(f) for f in files],
            out,
            read_options=options,
            gap=gap,
            clean=clean,
            workers=workers,
            manifest=manifest,
            progress=progress,
            on_note=info,
        )
        md = render_markdown(result.rows)
        if markdown == "-":
            write_stdout(md)
        elif markdown:
            write_atomic(markdown, md)
        info(f"wrote {result.outputs['index']} and {result.outputs['markdown']}")
        for f, name in result.renamed.items():
            info(f"note: two inputs share a name: {f} -> {name}")
        for f, msg in result.failed:
            info(f"failed: {f}: {msg}")
    worst = result.max_stiction_confidence()
    finding = fail_on_stiction is not None and worst is not None and worst >= fail_on_stiction
    if finding:
        info(f"stiction found (confidence {worst:.2f} >= {fail_on_stiction:g})")
    # A partial failure outranks a finding: the report is incomplete either way.
    if result.failed:
        info(f"{len(result.failed)} loop(s) could not be analysed: exit 4")
        raise typer.Exit(EXIT_PARTIAL)
    if finding:
        raise typer.Exit(EXIT_FINDING)


def normalise_argv(args: list[str]) -> list[str]:
    """Let ``--fail-on-stiction`` stand without a value (it then means the default).

    Click options cannot take an optional value, so a bare flag (last, or followed by
    something that is not a number) gets :data:`DEFAULT_FAIL_THRESHOLD` inserted.
    """
    out: list[str] = []
    for i, a in enumerate(args):
        out.append(a)
        if a == "--fail-on-stiction":
            nxt = args[i + 1] if i + 1 < len(args) else None
            try:
                float(nxt)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                out.append(str(DEFAULT_FAIL_THRESHOLD))
    return out
