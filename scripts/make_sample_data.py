"""Write the bundled sample loops in ``sample_data/`` and their README.

Six closed loops, simulated with the project's data-driven valve
(:func:`stictiondiag.models.valve.choudhury_step`, Section 5.1 of Choudhury, Thornhill &
Shah 2005) so that a replay with the true S and J is the generating model. Four
mirror the industrial examples of Section 3; one is healthy and one has no valve
position record::

    python scripts/make_sample_data.py            # writes sample_data/
    python scripts/make_sample_data.py --out DIR  # elsewhere

The seed is fixed (:data:`SEED`), so the files are reproducible; values are
rounded to 4 decimals to keep each CSV small.

Each loop is a PI (or P-only) controller acting on a first-order filtered
measurement, the sticky valve, and a first-order plus dead time or integrating
process sampled with a zero-order hold. Measurement noise, load steps and a slow
random-walk load make the records look like plant data; the filter keeps the
controller output smooth enough that noise alone does not hold the valve (the
data-driven model re-arms its stuck point at every reversal of its input, Fig. 10).
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from stictiondiag.core.jit import jit
from stictiondiag.models.valve import (
    choudhury_step,
    valve_state,
)
from stictiondiag.signals.oscillation import detect_oscillation

#: Seed of every random choice below (the paper's year and volume).
SEED = 2005_13

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class LoopSpec:
    """One sample loop: process, controller, valve and disturbances.

    Gains are in pv units per % of span (per % s for an integrating process); times
    in seconds; S and J in % of span. ``J_low``/``S_low`` apply while the valve is
    below ``split_position`` [% of travel] (set ``split_position`` to 0 for one
    S, J everywhere). With ``master_gain`` > 0 the loop is the slave of a cascade:
    a PI level controller sets its set point, the slave's flow drains a tank whose
    level is the master's measurement.
    """

    file: str
    loop_type: str
    mirrors: str
    ts: float
    n: int
    integrating: bool
    gain: float
    time_constant: float
    dead_time: float
    Kc: float
    Ti: float  # 0 = proportional only
    filter_time: float
    op_bias: float
    pv_bias: float
    S: float
    J: float
    noise_std: float
    units: str
    S_low: float | None = None
    J_low: float | None = None
    split_position: float = 0.0
    load_steps: tuple[tuple[float, float], ...] = ()  # (time [s], size [% of span])
    walk_std: float = 0.0  # random-walk load per sample [% of span]
    sp_steps: tuple[tuple[float, float], ...] = ()  # (time [s], size [pv units])
    mv_quantum: float = 0.0
    drop_mv: bool = False
    tags: dict = field(default_factory=dict)
    timestamps: bool = False
    master_gain: float = 0.0  # level per (flow unit s)
    master_Kc: float = 0.0
    master_Ti: float = 0.0
    master_sp: float = 0.0
    master_inflow: float = 0.0
    master_noise_std: float = 0.0
    notes: str = ""


@jit
def _simulate(
    n,
    ts,
    integrating,
    gain,
    time_constant,
    delay,
    Kc,
    Ti,
    filter_weight,
    op_bias,
    pv_bias,
    S_high,
    J_high,
    S_low,
    J_low,
    split,
    sp,
    load,
    noise,
    master_gain,
    master_Kc,
    master_Ti,
    master_sp,
    inflow,
    master_noise,
):
    pv = np.empty(n)
    op = np.empty(n)
    mv = np.empty(n)
    sp_out = np.empty(n)
    level = np.empty(n)
    a = 1.0 if integrating else math.exp(-ts / time_constant)
    b = gain * ts if integrating else gain * (1.0 - a)
    buf = np.zeros(delay + 1)
    y = 0.0
    integral = 0.0
    pvf = pv_bias
    st = valve_state(op_bias, True)
    position = op_bias
    h = master_sp  # tank level (cascade only)
    m_integral = 0.0
    for k in range(n):
        meas = pv_bias + y + noise[k]
        pv[k] = meas
        pvf += filter_weight * (meas - pvf)
        if master_gain > 0.0:
            # Master level PI, reverse acting: a high level asks for more outflow.
            level[k] = h + master_noise[k]
            e_m = level[k] - master_sp
            m_integral += e_m * ts
            spk = pv_bias + master_Kc * (e_m + m_integral / master_Ti)
        else:
            level[k] = math.nan
            spk = sp[k]
        sp_out[k] = spk
        e = spk - pvf
        if Ti > 0.0:
            trial = integral + e * ts
            u = op_bias + Kc * (e + trial / Ti)
            if 0.0 <= u <= 100.0:
                integral = trial
            else:
                u = op_bias + Kc * (e + integral / Ti)
        else:
            u = op_bias + Kc * e
        # The output is resolved to 1e-4 % (the files' 4 decimals), so the recorded
        # op is exactly what drove the valve and a replay from the file is exact.
        u = math.floor(min(max(u, 0.0), 100.0) * 10000.0 + 0.5) / 10000.0
        op[k] = u
        if position < split:
            position = choudhury_step(u, st, S_low, J_low)
        else:
            position = choudhury_step(u, st, S_high, J_high)
        mv[k] = position
        for j in range(delay):
            buf[j] = buf[j + 1]
        buf[delay] = position - op_bias + load[k]
        y = a * y + b * buf[0]
        if master_gain > 0.0:
            h += master_gain * ts * (inflow - (pv_bias + y))
    return sp_out, pv, op, mv, level


def simulate(spec: LoopSpec, rng: np.random.Generator) -> pd.DataFrame:
    """Closed-loop record of ``spec``: columns time, sp, pv, op, mv [% for op, mv]."""
    n_warm = 2000
    n_total = spec.n + n_warm
    t = (np.arange(n_total) - n_warm) * spec.ts
    load = np.zeros(n_total)
    for when, size in spec.load_steps:
        load[t >= when] += size
    if spec.walk_std > 0.0:
        load += np.cumsum(rng.standard_normal(n_total)) * spec.walk_std
    sp = np.full(n_total, spec.pv_bias)
    for when, size in spec.sp_steps:
        sp[t >= when] += size
    noise = rng.standard_normal(n_total) * spec.noise_std
    master_noise = rng.standard_normal(n_total) * spec.master_noise_std
    S_low = spec.S if spec.S_low is None else spec.S_low
    J_low = spec.J if spec.J_low is None else spec.J_low
    sp_out, pv, op, mv, _level = _simulate(
        n_total,
        spec.ts,
        spec.integrating,
        spec.gain,
        spec.time_constant,
        int(round(spec.dead_time / spec.ts)),
        spec.Kc,
        spec.Ti,
        spec.ts / (spec.filter_time + spec.ts),
        spec.op_bias,
        spec.pv_bias,
        spec.S,
        spec.J,
        S_low,
        J_low,
        spec.split_position,
        sp,
        load,
        noise,
        spec.master_gain,
        spec.master_Kc,
        spec.master_Ti,
        spec.master_sp,
        spec.master_inflow,
        master_noise,
    )
    keep = slice(n_warm, n_total)
    mv = mv[keep]
    if spec.mv_quantum > 0.0:
        mv = spec.mv_quantum * np.round(mv / spec.mv_quantum)
    data = pd.DataFrame(
        {
            "time": np.arange(spec.n) * spec.ts,
            "sp": sp_out[keep],
            "pv": pv[keep],
            "op": op[keep],
            "mv": mv,
        }
    )
    return data.round(4)


def _export(spec: LoopSpec, data: pd.DataFrame) -> pd.DataFrame:
    """The file's columns: historian tag names and timestamps where asked, no mv
    where the loop has no valve position record."""
    out = data.copy()
    if spec.drop_mv:
        out = out.drop(columns="mv")
    if spec.timestamps:
        start = pd.Timestamp("2004-03-01 00:00:00")
        stamps = start + pd.to_timedelta(out["time"], unit="s")
        out["time"] = stamps.dt.strftime("%Y-%m-%d %H:%M:%S")
    if spec.tags:
        out = out.rename(columns=spec.tags)
    return out


LOOPS: tuple[LoopSpec, ...] = (
    LoopSpec(
        file="level_undershoot.csv",
        loop_type="level",
        mirrors="Loop 1 (Fig. 3): condensate level, undershoot: mv never reaches op",
        ts=5.0,
        n=8640,
        integrating=True,
        gain=0.004,
        time_constant=1.0,
        dead_time=5.0,
        Kc=2.0,
        Ti=400.0,
        filter_time=30.0,
        op_bias=45.0,
        pv_bias=50.0,
        S=5.0,
        J=2.5,
        noise_std=0.005,
        units="level [%]",
        load_steps=((9000.0, -4.0), (27000.0, 6.0)),
        walk_std=0.01,
        tags={
            "time": "Timestamp",
            "sp": "LIC101.SV",
            "pv": "LIC101.PV",
            "op": "LIC101.OP",
            "mv": "LIC101.MV",
        },
        timestamps=True,
        notes="historian export: tags LIC101.SV/PV/OP/MV, timestamps every 5 s",
    ),
    LoopSpec(
        file="flow_mixed.csv",
        loop_type="flow",
        mirrors="Loop 2 (Fig. 4): refinery flow, undershoot and overshoot mixed",
        ts=10.0,
        n=4000,
        integrating=False,
        gain=1.2,
        time_constant=10.0,
        dead_time=20.0,
        Kc=0.3,
        Ti=30.0,
        filter_time=20.0,
        op_bias=50.0,
        pv_bias=60.0,
        S=4.0,
        J=2.0,
        S_low=3.0,
        J_low=4.5,
        split_position=50.0,
        noise_std=0.01,
        units="flow [m3/h]",
        walk_std=0.02,
        sp_steps=((-15000.0, 7.0), (20000.0, -14.0)),
        notes="S = 3, J = 4.5 (overshoot) below 50 % travel, S = 4, J = 2 (undershoot) "
        "above; the set point drops at 20 000 s and moves the valve from the upper "
        "region to the lower one, so each half of the record has its own cycle",
    ),
    LoopSpec(
        file="slave_flow_stickslip.csv",
        loop_type="flow",
        mirrors="Loop 3 (Fig. 5): slave flow of a level cascade, pure stick-slip",
        ts=6.0,
        n=5000,
        integrating=False,
        gain=1.5,
        time_constant=3.0,
        dead_time=0.0,
        Kc=0.5,
        Ti=0.0,
        filter_time=18.0,
        op_bias=50.0,
        pv_bias=75.0,
        S=3.0,
        J=3.0,
        noise_std=0.01,
        units="flow [m3/h]",
        master_gain=0.002,
        master_Kc=4.0,
        master_Ti=900.0,
        master_sp=50.0,
        master_inflow=76.0,
        master_noise_std=0.002,
        notes="P-only slave (Kc 0.5); its set point is the output of a PI level master "
        "(Kc 4 m3/h per %, Ti 900 s) on a tank filled at 76 m3/h",
    ),
    LoopSpec(
        file="temperature_quantised.csv",
        loop_type="temperature",
        mirrors="Loop 4 (Fig. 6): dryer temperature on gas flow, flow indicator quantised",
        ts=60.0,
        n=3000,
        integrating=False,
        gain=4.0,
        time_constant=900.0,
        dead_time=120.0,
        Kc=0.12,
        Ti=900.0,
        filter_time=240.0,
        op_bias=40.0,
        pv_bias=650.0,
        S=2.0,
        J=2.5,
        noise_std=0.05,
        units="temperature [degC]",
        load_steps=((60000.0, 3.0),),
        walk_std=0.02,
        mv_quantum=1.0,
        notes="mv is a gas flow indicator read to 1 % of span; slip jump above the "
        "band, so the moving phase is almost absent",
    ),
    LoopSpec(
        file="healthy_flow.csv",
        loop_type="flow",
        mirrors="healthy reference: linear valve",
        ts=1.0,
        n=6000,
        integrating=False,
        gain=0.8,
        time_constant=5.0,
        dead_time=1.0,
        Kc=0.6,
        Ti=6.0,
        filter_time=1.0,
        op_bias=55.0,
        pv_bias=80.0,
        S=0.0,
        J=0.0,
        noise_std=0.2,
        units="flow [m3/h]",
        load_steps=((1500.0, 4.0), (4200.0, -6.0)),
        walk_std=0.02,
        sp_steps=((800.0, 5.0), (2500.0, -8.0), (5000.0, 4.0)),
        notes="no stiction: mv follows op",
    ),
    LoopSpec(
        file="level_no_mv.csv",
        loop_type="level",
        mirrors="level loop without a valve position record",
        ts=1.0,
        n=5000,
        integrating=True,
        gain=0.01,
        time_constant=1.0,
        dead_time=2.0,
        Kc=3.0,
        Ti=100.0,
        filter_time=5.0,
        op_bias=50.0,
        pv_bias=60.0,
        S=3.0,
        J=1.5,
        noise_std=0.003,
        units="level [%]",
        load_steps=((2000.0, 5.0),),
        walk_std=0.01,
        drop_mv=True,
        notes="no mv column: S and J must come from pv and op",
    ),
)


def _period(x: np.ndarray, ts: float) -> float | None:
    """Oscillation period [s] of ``x`` by the project's detector, if it finds one."""
    found = detect_oscillation(np.asarray(x, dtype=float), ts)
    return float(found.period_s) if found.present else None


def _process_text(spec: LoopSpec) -> str:
    dead = f" e^(-{spec.dead_time:g}s)" if spec.dead_time > 0 else ""
    if spec.integrating:
        return f"{spec.gain:g}{dead}/s"
    return f"{spec.gain:g}{dead}/({spec.time_constant:g}s+1)"


def _controller_text(spec: LoopSpec) -> str:
    if spec.Ti <= 0.0:
        return f"P, Kc {spec.Kc:g}"
    return f"PI, Kc {spec.Kc:g}, Ti {spec.Ti:g} s"


def _sj_text(spec: LoopSpec) -> str:
    if spec.S == 0.0 and spec.J == 0.0:
        return "0 / 0 (linear)"
    if spec.split_position > 0.0:
        return (
            f"{spec.S_low:g} / {spec.J_low:g} below {spec.split_position:g} %, "
            f"{spec.S:g} / {spec.J:g} above"
        )
    return f"{spec.S:g} / {spec.J:g}"


def _readme(rows: list[tuple[LoopSpec, pd.DataFrame]]) -> str:
    lines = [
        "# Sample data",
        "",
        "Six simulated control loops, written by `scripts/make_sample_data.py` "
        f"(fixed seed {SEED}; run `python scripts/make_sample_data.py` to rewrite them).",
        "Four mirror the industrial examples of Section 3 of Choudhury, Thornhill & Shah",
        '(2005), "Modelling valve stiction"; one is a healthy loop and one has no valve',
        "position record. The valve is the data-driven stiction model of Section 5.1",
        "(`stictiondiag.models.valve.choudhury_step`), so the true S and J below are exactly the",
        "parameters that generated `mv` from `op`.",
        "",
        "Columns: `time` [s] (timestamps in `level_undershoot.csv`), `sp`, `pv` [units",
        "below], `op` (controller output) and `mv` (valve position) in % of span.",
        "`level_undershoot.csv` is laid out like a historian export, with tags",
        "`Timestamp`, `LIC101.SV`, `LIC101.PV`, `LIC101.OP`, `LIC101.MV`.",
        "",
        "| file | loop type | process | controller | valve | true S / J [% of span] "
        "| mirrors in the paper | sampling time [s] | samples | pv period [s] |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for spec, data in rows:
        valve = "linear" if spec.S == 0.0 and spec.J == 0.0 else "data-driven (Choudhury)"
        if spec.mv_quantum > 0.0:
            valve += f", mv quantised to {spec.mv_quantum:g} %"
        if spec.drop_mv:
            valve += ", mv not recorded"
        if spec.split_position > 0.0:
            # Two operating regions, one per half of the record, each with its cycle.
            half = len(data) // 2
            periods = [_period(part, spec.ts) for part in np.split(data["pv"].to_numpy(), [half])]
            period_text = " / ".join(f"{p:.0f}" if p is not None else "none" for p in periods)
            period_text += " (halves)"
        else:
            period = _period(data["pv"].to_numpy(), spec.ts)
            period_text = f"{period:.0f}" if period is not None else "none"
        lines.append(
            f"| `{spec.file}` | {spec.loop_type} ({spec.units}) | {_process_text(spec)} "
            f"| {_controller_text(spec)} | {valve} | {_sj_text(spec)} | {spec.mirrors} "
            f"| {spec.ts:g} | {spec.n} | {period_text} |"
        )
    lines += [
        "",
        "Process gains are in pv units per % of valve span (per % and second for the",
        "integrating level loops); the controller acts on a first-order filtered pv",
        "(`pv filter` below, backward-Euler discretisation, as a distributed control",
        "system filters its measurement). `pv period` is the oscillation period of the",
        "recorded pv found by `stictiondiag.signals.oscillation.detect_oscillation`.",
        "",
        "pv filter time constants [s]: "
        + ", ".join(f"`{spec.file}` {spec.filter_time:g}" for spec, _ in rows)
        + ".",
        "",
        "Notes per file:",
        "",
    ]
    for spec, _ in rows:
        lines.append(f"- `{spec.file}`: {spec.notes}.")
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "sample_data", help="output folder")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    streams = np.random.SeedSequence(SEED).spawn(len(LOOPS))
    rows = []
    for spec, stream in zip(LOOPS, streams, strict=True):
        data = simulate(spec, np.random.default_rng(stream))
        _export(spec, data).to_csv(args.out / spec.file, index=False)
        rows.append((spec, data))
        print(f"wrote {args.out / spec.file} ({len(data)} samples)")
    (args.out / "README.md").write_text(_readme(rows))
    print(f"wrote {args.out / 'README.md'}")


if __name__ == "__main__":
    main()
