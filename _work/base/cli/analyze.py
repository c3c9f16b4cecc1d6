"""``stiction analyze FILE``: the stiction verdict, S and J, and the closed-loop replay."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

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


def _param(st: dict, sym: str, unknown_scale: bool = False) -> str:
    """``5 % of op span (interval 4.98-5.01; 1.64 scaled)``, poorly determined
    values marked as such (:func:`stictiondiag.apps.findings.param_note`); in op's own
    units when op is not in % of span."""
    from stictiondiag.apps.findings import OWN_UNITS, param_note

    value = st.get(sym)
    unit = OWN_UNITS if unknown_scale else " % of op span"
    text = "n/a" if value is None else f"{value:.3g}{unit}"
    note = param_note(st, sym)
    scaled = f"{_fmt(st.get(f'{sym}_scaled'))} scaled"
    return f"{text} ({note}; {scaled})" if note else f"{text} ({scaled})"


def _fmt(x, spec=".2f", none="n/a") -> str:
    return none if x is None else format(x, spec)


def render_summary(d: dict) -> str:
    """Readable terminal summary of an :meth:`Analysis.to_dict` result.

    The verdict shows the calibrated P(stiction) with its decision levels, a poorly
    determined S or J says so next to its value, the replay is read by period,
    amplitude and waveform agreement, and the findings in words close the summary.
    """
    from stictiondiag.apps.findings import findings_from_dict, probability_text
    from stictiondiag.replay.metrics import render_metrics

    st, tg = d["stiction"], d["tags"]
    osc = d["oscillation"]["pv"]
    source = tg.get("loop_type_source") or "user/default"
    lines = [
        f"loop        {d['loop']}  ({tg['loop_type']} [{source}], {tg['n_samples']} samples at "
        f"{tg['ts_s']:g} s, {'with' if tg['has_mv'] else 'no'} mv)",
        f"verdict     {st.get('status', '?').upper().replace('_', ' ')}  ({probability_text(st)})",
        f"S           {_param(st, 'S', tg.get('op_scale') == 'unknown')}",
        f"J           {_param(st, 'J', tg.get('op_scale') == 'unknown')}",
        f"method      {st.get('method')}",
        "oscillation "
        + (
            f"period {_fmt(osc.get('period_s'), '.1f')} s, regularity {_fmt(osc.get('regularity'))}"
            if osc.get("present")
            else "none detected"
        ),
    ]
    for r in st.get("reasons") or []:
        lines.append(f"  - {r}")
    rep = d.get("replay")
    if rep:
        lines.append(f"replay      process {rep.get('process', {}).get('type')}")
        if rep.get("metrics"):
            lines.append(f"            {render_metrics(rep['metrics'])}")
        refit = (rep.get("settings") or {}).get("refit") or {}
        if refit.get("accepted"):
            same = (refit.get("S"), refit.get("J")) == (
                refit.get("S_open_loop"),
                refit.get("J_open_loop"),
            )
            what = (
                "process only (S and J measured from mv kept)"
                if same
                else f"S {_fmt(refit.get('S'))}, J {_fmt(refit.get('J'))} "
                f"(open-loop fit S {_fmt(refit.get('S_open_loop'))}, "
                f"J {_fmt(refit.get('J_open_loop'))}) and the process"
            )
            lines.append(
                f"            closed-loop refit: {what}; cycle mismatch "
                f"{_fmt(refit.get('cost_open_loop'), '.3g')} -> {_fmt(refit.get('cost'), '.3g')}"
            )
    gap = d.get("gap")
    if gap:
        lines.append(
            f"gap         {gap.get('metric_name', gap.get('metric'))}: before {_fmt(gap.get('before'), '.1f')} %, "
            f"after {_fmt(gap.get('after'), '.1f')} % ({_fmt(gap.get('shrink_pct'), '.0f')} % shrink) "
            f"-> effect {gap.get('effect')} (runner-up {gap.get('runner_up')})"
        )
    kp = d.get("kpis") or {}
    if kp:
        shown = [
            ("op_travel_per_day", "op travel {:.4g}/day"),
            ("op_reversals_per_day", "reversals {:.3g}/day"),
            ("time_at_op_limits", "at op limits {:.3g} %"),
            ("error_std", "error std {:.3g}"),
            ("harris_index", "Harris index {:.2g}"),
            ("service_factor", "service factor {:.3g} %"),
        ]
        parts = [
            form.format(kp[name]["value"])
            for name, form in shown
            if (kp.get(name) or {}).get("value") is not None
        ]
        lines.append("kpis        " + ", ".join(parts) + " (definitions in the JSON)")
    for w in d.get("warnings") or []:
        lines.append(f"warning     {w}")
    lines.append("findings")
    lines += ["  " + line for line in findings_from_dict(d).text(width=14).splitlines()]
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
        from stictiondiag.apps.findings import with_findings

        d = with_findings(result.to_dict())
        emit(d, render_summary(d), json_path)
        if out is not None:
            for target in result.save_figures(out):
                info(f"wrote {target}")
