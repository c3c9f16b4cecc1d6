"""``stiction simulate``: a PI loop with a sticky valve, and its limit cycle.

Numeric options are read as text and converted here, so that a bad value (``--S
abc``, ``--S -1``) gets the same one-line message and exit code 2 as every other
usage error instead of a multi-line usage box.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from stictiondiag.core.atomic import (
    atomic_path,
    write_atomic,
)
from stictiondiag.core.errors import UsageError

from .app import app
from .common import check_output_file, friendly_errors, info, write_stdout

if TYPE_CHECKING:
    from stictiondiag.models.describing import LimitCyclePrediction
    from stictiondiag.models.simulation import LimitCycle, Simulation

_VALVES = {"datadriven": "choudhury", "kano": "kano", "physical": "physical", "linear": "linear"}


def _float(option: str, text: str | None, *, minimum: float | None = None, positive=False):
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{option} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise UsageError(f"{option} must be a finite number, got {text!r}")
    if positive and value <= 0:
        raise UsageError(f"{option} must be > 0, got {text}")
    if minimum is not None and value < minimum:
        raise UsageError(f"{option} must be >= {minimum:g}, got {text}")
    return value


#: Stuck-valve guard: the valve counts as never slipping when it moved on fewer
#: than this many samples after the first third of the run.
MIN_SLIPS = 2


def stuck_valve_warning(sim, S: float) -> str | None:
    """Warn when a data-driven valve never slipped although op travelled past S.

    Choudhury's model (Section 5.1, Fig. 10) re-arms its stuck band at every change
    of sign of the input's slope.  With measurement noise on pv, op reverses at
    almost every sample, the band is re-armed each time and the valve never slips;
    the integral then winds op to a limit.  The paper asks for a filtered op
    (Section 5.1, EWMA) for noisy inputs; Kano's model keeps its stuck band through
    such reversals.  The run is reported as simulated; this says why it has no cycle.
    """
    import numpy as np

    valve = sim.settings.get("valve")
    if valve not in ("choudhury", "kano") or not sim.settings.get("noise_std"):
        return None
    start = sim.n // 3
    moves = int(np.count_nonzero(np.diff(sim.mv[start:])))
    travel = float(np.max(np.abs(sim.op[start:] - sim.mv[start:])))
    if moves >= MIN_SLIPS or travel <= S:
        return None
    name = "data-driven (Choudhury)" if valve == "choudhury" else "Kano"
    return (
        f"the {name} valve never slipped after {start * sim.dt:g} s although op moved "
        f"{travel:.3g} % from it (op ends at {float(sim.op[-1]):.3g} %): noise on pv "
        "reverses op at almost every sample and the model re-arms its stuck band at "
        "each reversal (Section 5.1 asks for a filtered op); this run is kept as "
        "simulated -- use --valve kano, which keeps the stuck band through noise, for "
        "a noisy loop"
    )


def _fmt(x, spec: str = ".3g") -> str:
    return "n/a" if x is None else format(x, spec)


def _valve_text(sim: Simulation) -> str:
    """The simulated valve and its parameters."""
    valve = sim.settings.get("valve")
    if valve in ("choudhury", "kano"):
        name = "data-driven (Choudhury et al.)" if valve == "choudhury" else "Kano et al."
        return f"{name}: S = {float(sim.settings['S']):g} %, J = {float(sim.settings['J']):g} %"
    if valve == "physical" and sim.physical is not None:
        ph = sim.physical
        eq = ph.data_driven_equivalent()
        return (
            f"physical: Fs = {float(ph.Fs):g} N, Fc = {float(ph.Fc):g} N, "
            f"Fv = {float(ph.Fv):g} N s/m, calibration x{float(ph.calibration):g} "
            f"(quasi-static S = {eq['S']:.2f} %, J = {eq['J']:.2f} %)"
        )
    return "linear (no stiction)"


def render_summary(
    loop: str,
    sim: Simulation,
    cycle: LimitCycle,
    describing: tuple[LimitCyclePrediction, dict],
    warnings: Sequence[str] = (),
) -> str:
    """Readable summary of a run for stderr: the valve, the run, the simulated
    limit cycle (``cycle``, :meth:`Simulation.limit_cycle`) and the
    describing-function prediction with its basis
    (:meth:`Simulation.describing_function`)."""
    # Here, not at the top: it brings numpy, and loading the CLI imports none.
    from stictiondiag.core.serialize import plain_float

    st = sim.settings
    prediction, basis = describing
    step, band = st.get("integration_step_s"), st.get("integral_band")
    lines = [
        f"loop         {loop}",
        f"valve        {_valve_text(sim)}",
        f"simulated    {sim.n * sim.dt:g} s, recorded every {sim.dt:g} s"
        + (f" (integrated at {step:g} s)" if step is not None and step != sim.dt else "")
        + (f", integral band {band:g}" if band is not None else ""),
    ]
    if cycle.present:
        amp = {k: plain_float(cycle.amplitude[k]) for k in ("pv", "op", "mv")}
        lines.append(
            f"limit cycle  YES: pv period {_fmt(plain_float(cycle.period_s), '.1f')} s; "
            f"amplitude pv {_fmt(amp['pv'])}, op {_fmt(amp['op'])} %, mv {_fmt(amp['mv'])} %"
        )
    else:
        lines.append(f"limit cycle  no ({cycle.oscillations['pv'].reason})")
    if prediction.limit_cycle:
        lines.append(
            f"describing   predicts a cycle: period {_fmt(plain_float(prediction.period_s), '.1f')}"
            f" s, op amplitude {_fmt(plain_float(prediction.amplitude_op))} %  "
            f"[{basis['source']}]"
        )
    else:
        lines.append(f"describing   predicts no limit cycle  [{basis['source']}]")
    lines += [f"warning      {w}" for w in warnings]
    return "\n".join(lines)


def valve_options(valve: str, S: str | None, J: str | None, case: str, friction: dict):
    """S and J [% of span] and the physical valve (or None) from the options.

    ``--S``/``--J`` belong to the data-driven valves and ``--Fs``/``--Fc``/``--Fv``/
    ``--calibration`` (``friction``, option name without dashes -> text or None) to
    the physical one: given to the other kind of valve they are refused, not
    ignored.

    Raises
    ------
    UsageError
        A value is not a number or out of range, or an option does not apply to
        the valve.
    """
    from stictiondiag.models import physical

    s_value = _float("--S", "5" if S is None else S, minimum=0.0)
    j_value = _float("--J", "2" if J is None else J, minimum=0.0)
    sj_given = [opt for opt, text in (("--S", S), ("--J", J)) if text is not None]
    if sj_given and valve in ("physical", "linear"):
        hint = (
            "set the friction with --Fs/--Fc/--Fv/--calibration or --case "
            "(the summary shows its quasi-static S and J)"
            if valve == "physical"
            else "use --valve datadriven or kano for a sticky valve"
        )
        raise UsageError(
            f"{'/'.join(sj_given)} {'apply' if len(sj_given) > 1 else 'applies'} to the "
            f"data-driven valves (datadriven, kano), not to --valve {valve}: {hint}"
        )
    given = [f"--{name}" for name, text in friction.items() if text is not None]
    if given and valve != "physical":
        raise UsageError(f"{', '.join(given)} apply to --valve physical only")
    if valve != "physical":
        return s_value, j_value, None
    overrides = {
        name: _float(f"--{name}", friction[name], minimum=0.0)
        for name in ("Fs", "Fc", "Fv")
        if friction.get(name) is not None
    }
    if friction.get("calibration") is not None:
        overrides["calibration"] = _float("--calibration", friction["calibration"], positive=True)
    return s_value, j_value, physical.PhysicalValve.from_case(case, **overrides)


#: The command's options, one alias each (Typer reads the annotations).
_SOption = Annotated[
    str | None,
    typer.Option(
        "--S",
        metavar="FLOAT",
        help="Deadband plus stickband [% of span], >= 0 (data-driven valves; default 5).",
    ),
]
_JOption = Annotated[
    str | None,
    typer.Option(
        "--J",
        metavar="FLOAT",
        help="Slip jump [% of span], >= 0 (data-driven valves; default 2).",
    ),
]
_LoopOption = Annotated[
    str | None,
    typer.Option(
        metavar="LOOP",
        help="The paper's loop (Eq. 3, Table 3): concentration (G = 3e^{-10s}/(10s+1), "
        "PI 0.2, 10 s) or level (G = 1/s, PI 0.4, 2 s). Default: concentration "
        "(stictiondiag.models.processes.DEFAULT_LOOP).",
    ),
]
_ValveOption = Annotated[
    str,
    typer.Option(
        metavar="VALVE",
        help="datadriven (Choudhury et al. 2005, uses --S/--J), kano (Kano et al. 2004), "
        "physical (Section 4, uses --case/--Fs/--Fc/--Fv/--calibration) or linear.",
    ),
]
_CaseOption = Annotated[
    str,
    typer.Option(
        metavar="CASE",
        help="Physical valve parameter set (Tables 1-2): nominal, linear, deadband, "
        "undershoot_open_loop, undershoot_closed_loop, no_offset, miscalibrated.",
    ),
]
_FsOption = Annotated[
    str | None, typer.Option("--Fs", metavar="N", help="Static friction [N] (physical).")
]
_FcOption = Annotated[
    str | None, typer.Option("--Fc", metavar="N", help="Coulomb friction [N] (physical).")
]
_FvOption = Annotated[
    str | None,
    typer.Option("--Fv", metavar="N_S_PER_M", help="Viscous friction [N s/m] (physical)."),
]
_CalibrationOption = Annotated[
    str | None,
    typer.Option(
        metavar="FACTOR",
        help="Multiplier on the calibration factor k/A (physical; 1.25 = Fig. 8).",
    ),
]
_DurationOption = Annotated[str, typer.Option(metavar="SECONDS", help="Simulated time in seconds.")]
_DtOption = Annotated[
    str | None,
    typer.Option(metavar="SECONDS", help="Sample time in seconds. Default: the loop's, 0.1."),
]
_IntegralBandOption = Annotated[
    str | None,
    typer.Option(
        metavar="PV_UNITS",
        help="Variable-integral PI (Gerry & Ruel, Section 6.4): no integral action while "
        "|sp - pv| is below this.",
    ),
]
_NoiseOption = Annotated[
    str,
    typer.Option(
        metavar="PV_UNITS",
        help="Measurement noise standard deviation on pv. The data-driven valve "
        "(Choudhury) sticks for good under noisy op (Section 5.1): the summary warns "
        "when it never slipped; --valve kano keeps its stuck band through noise.",
    ),
]
_SeedOption = Annotated[int | None, typer.Option(min=0, help="Seed of the noise (>= 0).")]
_KickOption = Annotated[
    str,
    typer.Option(
        metavar="PERCENT",
        help="The valve starts stuck this far [% of span] from the operating point.",
    ),
]
_PlotOption = Annotated[
    Path | None, typer.Option(metavar="PATH", help="Write trends and mv-op plot (png/svg/pdf).")
]
_CsvOption = Annotated[
    Path | None, typer.Option(metavar="PATH", help="Write time, sp, pv, op, mv as CSV.")
]
_JsonOption = Annotated[
    str | None,
    typer.Option("--json", metavar="PATH", help="Write the summary as JSON ('-' = stdout)."),
]


@app.command()
def simulate(
    S: _SOption = None,
    J: _JOption = None,
    loop: _LoopOption = None,
    valve: _ValveOption = "datadriven",
    case: _CaseOption = "nominal",
    Fs: _FsOption = None,
    Fc: _FcOption = None,
    Fv: _FvOption = None,
    calibration: _CalibrationOption = None,
    duration: _DurationOption = "3000",
    dt: _DtOption = None,
    integral_band: _IntegralBandOption = None,
    noise: _NoiseOption = "0",
    seed: _SeedOption = None,
    kick: _KickOption = "1",
    plot: _PlotOption = None,
    csv: _CsvOption = None,
    json_out: _JsonOption = None,
) -> None:
    """Simulate a PI loop with a sticky valve and report its limit cycle.

    Runs the loop of Choudhury, Thornhill & Shah (2005), Eq. 3 and Table 3, from a stuck valve, detects the limit cycle of pv and compares it with the describing-function prediction (Section 6; for the physical valve through its quasi-static S and J).

    The summary goes to stderr; JSON, CSV and the plot go to the files asked for (JSON to stdout with --json -). --S/--J apply to the data-driven valves only: with --valve physical or linear they are refused. Exit codes: 0 done, 2 bad option value, contradicting options or unwritable output.
    """
    from stictiondiag.models import loops, processes

    with friendly_errors():
        check_output_file("--plot", plot, figure=True)
        check_output_file("--csv", csv)
        check_output_file("--json", json_out)
        loop_name = processes.DEFAULT_LOOP if loop is None else loop
        if loop_name not in processes.LOOP_PARAMETERS:
            raise UsageError(
                f"unknown loop {loop_name!r}: use one of {', '.join(processes.LOOP_PARAMETERS)}"
            )
        if valve not in _VALVES:
            raise UsageError(f"unknown valve {valve!r}: use one of {', '.join(_VALVES)}")
        kwargs: dict = {
            "valve": _VALVES[valve],
            "duration": _float("--duration", duration, positive=True),
            "dt": _float("--dt", dt, positive=True),
            "integral_band": _float("--integral-band", integral_band, minimum=0.0),
            "noise_std": _float("--noise", noise, minimum=0.0),
            "seed": seed,
            "kick": _float("--kick", kick),
        }
        s_value, j_value, physical_valve = valve_options(
            valve, S, J, case, {"Fs": Fs, "Fc": Fc, "Fv": Fv, "calibration": calibration}
        )
        if physical_valve is not None:
            kwargs["physical"] = physical_valve
        sim = loops.simulate_paper_loop(loop_name, s_value, j_value, **kwargs)
        cycle, describing = sim.limit_cycle(), sim.describing_function()
        stuck = stuck_valve_warning(sim, s_value)
        warnings = [stuck] if stuck else []
        info(render_summary(loop_name, sim, cycle, describing, warnings))
        summary = {
            "loop": loop_name,
            **sim.summary(cycle=cycle, describing=describing),
            "warnings": warnings,
        }
        text = json.dumps(summary, indent=2, allow_nan=False) + "\n"
        if json_out == "-":
            write_stdout(text)
        elif json_out is not None:
            write_atomic(json_out, text)
        if csv is not None:
            write_atomic(csv, sim.to_pandas().to_csv(index=False))
        if plot is not None:
            from stictiondiag.plotting import pyplot

            plt = pyplot()

            fig = sim.plot()
            try:
                with atomic_path(plot) as tmp:
                    fig.savefig(tmp)
            finally:
                plt.close(fig)
