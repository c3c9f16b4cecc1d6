"""Options shared by the commands that read loop files (analyze, gap, report).

One definition each, so every command names its columns, units and loop type alike.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from enum import Enum
from pathlib import Path
from typing import Annotated, Any

import typer


class LoopType(str, Enum):
    flow = "flow"
    pressure = "pressure"
    level = "level"
    temperature = "temperature"
    composition = "composition"
    other = "other"


class OpUnits(str, Enum):
    percent = "percent"
    mA = "mA"


class Vendor(str, Enum):
    yokogawa = "yokogawa"
    honeywell = "honeywell"
    deltav = "deltav"
    pi = "pi"
    generic = "generic"


class Action(str, Enum):
    direct = "direct"
    reverse = "reverse"


class Compression(str, Enum):
    hold = "hold"
    linear = "linear"
    band = "band"


VendorOption = Annotated[
    Vendor | None,
    typer.Option(
        "--vendor",
        help="Tag convention of the control system: yokogawa reads .MV as op (the "
        "controller output); the others read MV as the valve position. Default: .MV is "
        "op only when no op tag is beside it (said in the output).",
    ),
]
ActionOption = Annotated[
    Action | None,
    typer.Option(
        "--action",
        help="Controller action (direct: op rises with pv; reverse: op falls), used by "
        "the replay and the compensation. Default: from the data.",
    ),
]
CompressionOption = Annotated[
    Compression | None,
    typer.Option(
        "--compression",
        help="How a compressed historian archive (recorded values) is rebuilt: hold "
        "(exception reporting), linear (swinging door) or band (linear within the "
        "deadband). Default: told per tag, op of an exception archive banded.",
    ),
]


PvOption = Annotated[str | None, typer.Option("--pv", help="Column holding pv.")]
OpOption = Annotated[
    str | None, typer.Option("--op", help="Column holding op (controller output).")
]
MvOption = Annotated[str | None, typer.Option("--mv", help="Column holding mv (valve position).")]
SpOption = Annotated[str | None, typer.Option("--sp", help="Column holding sp (setpoint).")]
TimeOption = Annotated[
    str | None, typer.Option("--time", help="Time column (seconds or timestamps).")
]
ModeOption = Annotated[
    str | None,
    typer.Option(
        "--mode",
        help="Column holding the controller's mode (MAN/AUTO/CAS ...). Default: found by "
        "name (.MODE, .MD, MODE.ACTUAL, STATUS). The service factor is taken from it and "
        "the longest stretch in automatic or cascade is analysed.",
    ),
]


def positive_seconds(value: float | None) -> float | None:
    """Option callback: a sample time must be a finite number of seconds above zero."""
    if value is not None and not (math.isfinite(value) and value > 0.0):
        raise typer.BadParameter(f"must be a positive number of seconds, got {value:g}")
    return value


def op_range_check(value: tuple[float, float] | None) -> tuple[float, float] | None:
    """Option callback: LO HI finite with LO < HI."""
    if value is not None:
        low, high = value
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise typer.BadParameter(f"must be LO HI with finite LO < HI, got {low:g} {high:g}")
    return value


TsOption = Annotated[
    float | None,
    typer.Option(
        "--ts",
        help="Sampling time in seconds, for files without a time column.",
        callback=positive_seconds,
    ),
]
OpUnitsOption = Annotated[OpUnits, typer.Option("--op-units", help="Units of op and mv.")]
OpRangeOption = Annotated[
    tuple[float, float] | None,
    typer.Option(
        "--op-range",
        help="LO HI of op in its own units, mapped to 0-100 % of span.",
        callback=op_range_check,
    ),
]


def given_only(ctx: typer.Context, param: typer.CallbackParam, value):
    """Option callback: the value when given on the command line, else None.

    ``--loop-type`` left at its default must not hide the ISA tag or the data.
    """
    source = ctx.get_parameter_source(param.name) if param.name else None
    # By name: the click that typer runs on may not be the one installed as "click".
    return None if getattr(source, "name", "DEFAULT") in ("DEFAULT", "DEFAULT_MAP") else value


LoopTypeOption = Annotated[
    LoopType,
    typer.Option(
        "--loop-type",
        callback=given_only,
        help="What the loop controls (level implies integrating). Default: from the ISA "
        "tag (FIC flow, LIC level, PIC pressure, TIC temperature, AIC/QIC composition), "
        "else the data tell integrating from self-regulating.",
    ),
]
LoopsOption = Annotated[
    Path | None,
    typer.Option(
        "--loops",
        help="Loops manifest CSV: one row per loop (column file or loop) with any of "
        "loop_type, ts, op_units, op_range, pv, op, mv, sp, time, mode.",
    ),
]
IntegratingOption = Annotated[
    bool | None,
    typer.Option("--integrating/--self-regulating", help="Process type; default from --loop-type."),
]
JsonOption = Annotated[
    str | None, typer.Option("--json", help="Write the result as JSON to PATH ('-' = stdout).")
]


def read_options(
    pv: str | None,
    op: str | None,
    mv: str | None,
    sp: str | None,
    time: str | None,
    ts: float | None,
    op_units: OpUnits,
    op_range: tuple[float, float] | None,
    loop_type: LoopType | None,
    integrating: bool | None,
    vendor: Vendor | None = None,
    action: Action | None = None,
    compression: Compression | None = None,
    mode: str | None = None,
) -> dict:
    """Keyword arguments for :func:`stictiondiag.io.tags.read_tags` from CLI options.

    ``--loop-type`` left at its default becomes ``loop_type=None``: the ISA tag, else
    the data, decide (:mod:`stictiondiag.io.looptype`).
    """
    extra = {
        name: value.value
        for name, value in (("vendor", vendor), ("action", action), ("compression", compression))
        if value is not None
    }
    return {
        **extra,
        "pv": pv,
        "op": op,
        "mv": mv,
        "sp": sp,
        "time": time,
        "ts": ts,
        "op_units": op_units.value,
        "op_range": op_range,
        "loop_type": None if loop_type is None else LoopType(loop_type).value,
        "integrating": integrating,
        "mode": mode,
    }


#: The parameters of a command that become read options, in :func:`read_options`' order.
READ_OPTION_NAMES = (
    "pv",
    "op",
    "mv",
    "sp",
    "time",
    "ts",
    "op_units",
    "op_range",
    "loop_type",
    "integrating",
    "vendor",
    "action",
    "compression",
    "mode",
)


def command_read_options(params: Mapping[str, Any]) -> dict:
    """:func:`read_options` from a command's parameters, picked by name.

    The commands that read loop files (analyze, gap, report) pass ``locals()``, so the
    read options have one list (:data:`READ_OPTION_NAMES`) instead of one call per
    command; a command that lacks one of them is a programming error (KeyError).
    """
    return read_options(**{name: params[name] for name in READ_OPTION_NAMES})
