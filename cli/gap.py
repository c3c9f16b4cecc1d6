"""``stiction gap FILE``: where the replay departs from the data, and which effect explains it."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from stictiondiag.core.atomic import atomic_path

from .app import app
from .common import check_output_file, compile_if_cold, emit, friendly_errors, info
from .options import (
    ActionOption,
    CompressionOption,
    IntegratingOption,
    JsonOption,
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

if TYPE_CHECKING:
    from stictiondiag.gap.result import GapDiagnosis


def _fmt(x, spec: str = ".1f") -> str:
    """A number as ``spec``; ``n/a`` for None or a non-finite one (as the JSON's null)."""
    return "n/a" if x is None or not math.isfinite(x) else format(x, spec)


def render_gap(g: GapDiagnosis) -> str:
    """Readable summary of a :class:`~stictiondiag.gap.result.GapDiagnosis`."""
    lines = [
        f"gap         {g.metric}: before {_fmt(g.before)} %, "
        f"after {_fmt(g.after)} % ({_fmt(g.shrink_pct, '.0f')} % shrink)",
        f"effect      {g.effect}  (runner-up {g.runner_up}, margin {_fmt(g.margin)} %)",
    ]
    sig = [] if g.breakdown is None else g.breakdown.signal.items()
    if sig:
        lines.append(
            "by signal   " + ", ".join(f"{s} {_fmt(v.before)} -> {_fmt(v.after)} %" for s, v in sig)
        )
    lines.append(
        "candidates  effect                 after %  shrink %  held-out %  score %  accepted"
    )
    for c in g.candidates:
        lines.append(
            f"            {c.effect:<22} {_fmt(c.after):>7}"
            f"  {_fmt(c.shrink_pct, '.0f'):>8}"
            f"  {_fmt(c.heldout):>10}  {_fmt(c.penalised_score):>7}"
            f"  {'yes' if c.accepted else 'no'}"
        )
    if g.not_assessed:
        lines.append("not assessed " + ", ".join(g.not_assessed) + " (no valve position recorded)")
    if g.within_noise:
        lines.append("not fitted  " + ", ".join(g.within_noise) + " (mv replay within its noise)")
    return "\n".join(lines)


@app.command()
def gap(
    file: Annotated[Path, typer.Argument(help="CSV or Parquet file with one loop's tags.")],
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
    json_path: JsonOption = None,
    plot: Annotated[
        Path | None,
        typer.Option(
            help="Write where the gap lies to PATH (PNG) and the replay before and after the "
            "winning effect to PATH with '_replay' added to its name."
        ),
    ] = None,
) -> None:
    """Sim-to-real gap: measure and locate it, and name the unmodelled effect that explains it."""
    from stictiondiag.analysis import diagnose_gap_file

    with friendly_errors():
        check_output_file("--plot", plot, [file], figure=True)
        if plot is not None:
            check_output_file(
                "--plot", plot.with_name(f"{plot.stem}_replay{plot.suffix or '.png'}"), [file]
            )
        check_output_file("--json", json_path, [file])
        info(f"diagnosing the gap of {file} ...")
        options = command_read_options(locals())
        compile_if_cold()
        result = diagnose_gap_file(file, **options)
        emit(result.to_dict(), render_gap(result), json_path)
        if plot is not None:
            from stictiondiag.plotting import pyplot

            plt = pyplot()

            figs = result.figures()
            suffix = plot.suffix or ".png"
            targets = {
                "gap_breakdown": plot if plot.suffix else plot.with_suffix(suffix),
                "gap_replay": plot.with_name(f"{plot.stem}_replay{suffix}"),
            }
            for name, fig in figs.items():
                with atomic_path(targets[name]) as tmp:
                    fig.savefig(tmp, dpi=110, format=suffix.lstrip(".") or "png")
                plt.close(fig)
                info(f"wrote {targets[name]}")
