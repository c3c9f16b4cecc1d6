"""``stiction analyze FILE``: the stiction verdict, S and J, and the closed-loop replay."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from .app import app
from .common import check_output_dir, check_output_file, emit, friendly_errors, info
from .options import (
    IntegratingOption,
    JsonOption,
    LoopType,
    LoopTypeOption,
    MvOption,
    OpOption,
    OpRangeOption,
    OpUnits,
    OpUnitsOption,
    PvOption,
    SpOption,
    TimeOption,
    TsOption,
    read_options,
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


def _fmt(x, spec=".2f", none="n/a") -> str:
    return none if x is None else format(x, spec)


def render_summary(d: dict) -> str:
    """Readable terminal summary of an :meth:`Analysis.to_dict` result."""
    st, tg = d["stiction"], d["tags"]
    osc = d["oscillation"]["pv"]
    lines = [
        f"loop        {d['loop']}  ({tg['loop_type']}, {tg['n_samples']} samples at "
        f"{tg['ts_s']:g} s, {'with' if tg['has_mv'] else 'no'} mv)",
        f"verdict     {st.get('status', '?').upper().replace('_', ' ')}"
        f"  (confidence {_fmt(st.get('confidence'), '.2f')})",
    ]
    si, ji = st.get("S_interval"), st.get("J_interval")
    s_int = f" [{si[0]:.2f}, {si[1]:.2f}]" if si and None not in si else ""
    j_int = f" [{ji[0]:.2f}, {ji[1]:.2f}]" if ji and None not in ji else ""
    lines.append(
        f"S           {_fmt(st.get('S'))}{s_int} % of op span  ({_fmt(st.get('S_scaled'))} scaled)"
    )
    lines.append(
        f"J           {_fmt(st.get('J'))}{j_int} % of op span  ({_fmt(st.get('J_scaled'))} scaled)"
    )
    lines.append(f"method      {st.get('method')}")
    lines.append(
        "oscillation "
        + (
            f"period {_fmt(osc.get('period_s'), '.1f')} s, regularity {_fmt(osc.get('regularity'))}"
            if osc.get("present")
            else "none detected"
        )
    )
    for r in st.get("reasons") or []:
        lines.append(f"  - {r}")
    rep = d.get("replay")
    if rep:
        fit = rep.get("fit") or {}
        per = rep.get("period_s") or {}
        wave = rep.get("waveform") or {}
        lines.append(
            f"replay      process {rep.get('process', {}).get('type')}, "
            f"period data {_fmt(per.get('data'), '.1f')} s / replay {_fmt(per.get('replay'), '.1f')} s"
        )
        lines.append(
            "            fit [%, 100 = exact] "
            + ", ".join(f"{k} {_fmt(v, '.0f')}" for k, v in fit.items() if not isinstance(v, dict))
            + "; cycle shape [1 = same] "
            + ", ".join(f"{k} {_fmt(v, '.2f')}" for k, v in wave.items() if not isinstance(v, dict))
        )
    gap = d.get("gap")
    if gap:
        lines.append(
            f"gap         {gap.get('metric_name', gap.get('metric'))}: before {_fmt(gap.get('before'), '.1f')} %, "
            f"after {_fmt(gap.get('after'), '.1f')} % ({_fmt(gap.get('shrink_pct'), '.0f')} % shrink) "
            f"-> effect {gap.get('effect')} (runner-up {gap.get('runner_up')})"
        )
    for w in d.get("warnings") or []:
        lines.append(f"warning     {w}")
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
    out: Annotated[Path | None, typer.Option(help="Directory for the plots.")] = None,
    json_path: JsonOption = None,
    gap: Annotated[bool, typer.Option(help="Run the sim-to-real gap diagnosis.")] = True,
) -> None:
    """Diagnose stiction in one loop: verdict, S and J, closed-loop replay, gap."""
    from stictiondiag.analysis import AnalysisConfig, analyze_file

    with friendly_errors():
        check_outputs(out, json_path, file)
        options = read_options(pv, op, mv, sp, time, ts, op_units, op_range, loop_type, integrating)
        info(f"analysing {file} ...")
        result = analyze_file(file, config=AnalysisConfig(gap=gap), **options)
        d = result.to_dict()
        emit(d, render_summary(d), json_path)
        if out is not None:
            for target in result.save_figures(out):
                info(f"wrote {target}")
