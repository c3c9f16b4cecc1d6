"""``stiction analyze FILE``: the stiction verdict, S and J, and the closed-loop replay.

The library is imported inside the functions, as in every command: loading the CLI
(``stiction --help``, any other command) must not import numpy and the numerics.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from .app import app
from .common import (
    check_output_dir,
    check_output_file,
    compile_if_cold,
    emit,
    friendly_errors,
    info,
)
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
    from stictiondiag.replay.closed_loop import Replay
    from stictiondiag.result import Analysis


def check_outputs(out: Path | None, json_path: str | None, file: Path | None = None) -> None:
    """Refuse output locations that cannot be written before the analysis runs.

    The analysis takes seconds; a typo in ``--out`` or ``--json`` should cost none,
    and the input is never overwritten.

    Raises
    ------
    UsageError
        ``--out`` is an existing file, or ``--json`` is a directory, lies below a
        file, or is the input file.
    """
    inputs = [file] if file is not None else []
    check_output_dir("--out", out, inputs)
    check_output_file("--json", json_path, inputs)


def _param(a: Analysis, sym: str) -> str:
    """``5 % of op span (interval 4.98-5.01; 1.64 scaled)``, poorly determined
    values marked as such (:func:`stictiondiag.apps.findings.param_note`); in op's own
    units when op is not in % of span."""
    from stictiondiag.apps.findings import OWN_UNITS, estimate, param_note
    from stictiondiag.core.serialize import plain_float

    value = estimate(a.fit, sym)
    unit = OWN_UNITS if a.tags.op_scale == "unknown" else " % of op span"
    text = "n/a" if value is None else f"{value:.3g}{unit}"
    note = param_note(a.fit, sym)
    scaled = f"{_fmt(plain_float(a.fit.S_scaled if sym == 'S' else a.fit.J_scaled))} scaled"
    return f"{text} ({note}; {scaled})" if note else f"{text} ({scaled})"


def _fmt(x, spec=".2f", none="n/a") -> str:
    return none if x is None else format(x, spec)


#: The loop KPIs the summary shows, with their wording (all are in the JSON).
SUMMARY_KPIS = (
    ("op_travel_per_day", "op travel {:.4g}/day"),
    ("op_reversals_per_day", "reversals {:.3g}/day"),
    ("time_at_op_limits", "at op limits {:.3g} %"),
    ("error_std", "error std {:.3g}"),
    ("harris_index", "Harris index {:.2g}"),
    ("service_factor", "service factor {:.3g} %"),
)


def _process_kind(rep: Replay) -> str:
    """``foptd`` or ``integrating``: the structure of the replay's identified process."""
    from stictiondiag.models.processes import FOPTD

    return "foptd" if isinstance(rep.process_fit.process, FOPTD) else "integrating"


def _replay_lines(rep: Replay) -> list[str]:
    """The replay's process, its agreement with the data and the closed-loop refit."""
    from stictiondiag.core.serialize import plain_float
    from stictiondiag.replay.metrics import replay_metrics

    lines = [
        f"replay      process {_process_kind(rep)}",
        f"            {replay_metrics(rep).text()}",
    ]
    refit = rep.settings.refit
    if refit is not None and refit.accepted:
        S0, J0 = plain_float(refit.S_open_loop), plain_float(refit.J_open_loop)
        S1, J1 = plain_float(refit.S), plain_float(refit.J)
        what = (
            "process only (S and J kept)"
            if (S1, J1) == (S0, J0)
            else f"S {_fmt(S1)}, J {_fmt(J1)} (open-loop fit S {_fmt(S0)}, J {_fmt(J0)}) "
            "and the process"
        )
        lines.append(
            f"            closed-loop refit: {what}; cycle mismatch "
            f"{_fmt(plain_float(refit.cost_open_loop), '.3g')} -> "
            f"{_fmt(plain_float(refit.cost), '.3g')}"
        )
    return lines


def render_summary(a: Analysis) -> str:
    """Readable terminal summary of one loop's :class:`~stictiondiag.result.Analysis`.

    The verdict shows the probability it decided on with its decision levels, a poorly
    determined S or J says so next to its value, the replay is read by period,
    amplitude and waveform agreement, and the findings in words close the summary.
    """
    from stictiondiag.apps.findings import findings_of, probability_text
    from stictiondiag.core.serialize import plain_float

    tags, verdict, osc = a.tags, a.verdict, a.oscillation
    source = tags.loop_type_source or "user/default"
    lines = [
        f"loop        {a.loop}  ({tags.loop_type} [{source}], {int(tags.n)} samples at "
        f"{float(tags.ts):g} s, {'with' if tags.mv is not None else 'no'} mv)",
        f"verdict     {verdict.status.upper().replace('_', ' ')}  ({probability_text(verdict)})",
        f"S           {_param(a, 'S')}",
        f"J           {_param(a, 'J')}",
        f"method      {a.fit.method}",
        "oscillation "
        + (
            f"period {_fmt(plain_float(osc.period_s), '.1f')} s, "
            f"regularity {_fmt(plain_float(osc.regularity))}"
            if osc.present
            else "none detected"
        ),
    ]
    lines += [f"  - {r}" for r in verdict.reasons]
    if a.replay is not None:
        lines += _replay_lines(a.replay)
    gap = a.gap
    if gap is not None:
        lines.append(
            f"gap         {gap.metric}: before {_fmt(plain_float(gap.before), '.1f')} %, "
            f"after {_fmt(plain_float(gap.after), '.1f')} % "
            f"({_fmt(plain_float(gap.shrink_pct), '.0f')} % shrink) "
            f"-> effect {gap.effect} (runner-up {gap.runner_up})"
        )
    if a.kpis is not None and a.kpis.items:
        values = a.kpis.values()
        parts = [
            form.format(values[name]) for name, form in SUMMARY_KPIS if values.get(name) is not None
        ]
        lines.append("kpis        " + ", ".join(parts) + " (definitions in the JSON)")
    lines += [f"warning     {w}" for w in a.warnings]
    lines.append("findings")
    lines += ["  " + line for line in findings_of(a).text(width=14).splitlines()]
    return "\n".join(lines)


@app.command()
def analyze(
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
    out: Annotated[Path | None, typer.Option(help="Directory for the plots.")] = None,
    json_path: JsonOption = None,
    gap: Annotated[bool, typer.Option(help="Run the sim-to-real gap diagnosis.")] = True,
) -> None:
    """Diagnose stiction in one loop: verdict, S and J, closed-loop replay, gap."""
    import os

    from stictiondiag.analysis import AnalysisConfig, analyze_file
    from stictiondiag.stiction.hammerstein.kernels import THREADS_VARIABLE

    # One loop alone: its batch kernels may use every core (the same numbers; scan
    # and report workers keep one thread each, see kernel_threads).
    os.environ.setdefault(THREADS_VARIABLE, str(os.cpu_count() or 1))
    with friendly_errors():
        check_outputs(out, json_path, file)
        options = command_read_options(locals())
        compile_if_cold()
        info(f"analysing {file} ...")
        result = analyze_file(file, config=AnalysisConfig(gap=gap), **options)
        from stictiondiag.apps.findings import analysis_json

        emit(analysis_json(result), render_summary(result), json_path)
        if out is not None:
            for target in result.save_figures(out):
                info(f"wrote {target}")
