"""Write a generated plant: N closed control loops, one file per loop, for ``stiction scan``.

About ``sticky_share`` of the loops have a sticky valve, the others a healthy one.

Sticky loops (``--sticky-model``):

``synthetic`` (default)
    Cases of :func:`stictiondiag.models.synthetic.generate_case` with no further effect:
    self-regulating or integrating process, data-driven or Karnopp valve with S
    0.8-6 % of span, load and set-point changes, noise (Choudhury et al. 2005,
    Sections 4 and 5). Their cycles last up to about 1 500 samples, so records need
    5 000 samples or more for three cycles.
``simple``
    The PI loop below with the Kano et al. (2004) data-driven valve, S 2-6 % of span
    and J 0.2-1 x S; cycles of a few hundred samples, for short test records. (The
    Choudhury model of Section 5.1 re-sticks at every reversal of op, so with noise
    on pv the simulated valve would never slip.)

Healthy loops: a PI-controlled first-order-plus-dead-time process
(:func:`stictiondiag.models.loops.simulate_loop`, S = J = 0) moved by a coloured-noise
load, with white measurement noise on pv. Process, tuning and noise differ per loop.

The truth (S, J, process, controller) goes to ``truth.json``, which ``stiction scan``
does not read.

Usage::

    python scripts/make_plant.py OUT_DIR [--loops 100] [--samples 10000] [--seed 0]
        [--format csv|parquet|mixed|dataset] [--sticky-share 0.5] [--mv-share 0.0]
        [--sticky-model synthetic|simple]

``--format dataset`` writes one Parquet file ``plant.parquet`` with a ``loop_id``
column instead of one file per loop. ``--mv-share`` is the share of loops whose valve
position (mv) is recorded as well.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import (
    FOPTD,
    PI,
)
from stictiondiag.models.synthetic import generate_case

#: Sample time of the PI loops of :func:`pi_loop` [s] (the synthetic cases draw theirs).
SAMPLE_TIME_S = 1.0

#: Generators of sticky loops (see the module docstring).
STICKY_MODELS = ("synthetic", "simple")


def make_loop(
    seed: int,
    *,
    n_samples: int,
    sticky: bool,
    record_mv: bool,
    sticky_model: str = "synthetic",
) -> tuple[pd.DataFrame, dict]:
    """Simulate one loop.

    Parameters
    ----------
    seed : int
        Seed of the random process, tuning, valve and noise choices.
    n_samples : int
        Samples in the record.
    sticky : bool
        Sticky or healthy valve.
    record_mv : bool
        Whether the valve position column ``mv`` is written.
    sticky_model : {"synthetic", "simple"}
        Generator of the sticky loops (module docstring).

    Returns
    -------
    (DataFrame, dict)
        Columns ``time`` [s], ``sp``, ``pv`` [pv units], ``op`` (and ``mv``) [% of
        span]; the truth as a JSON-able dict.
    """
    if sticky and sticky_model == "synthetic":
        case = generate_case("none", seed, n_samples=n_samples)
        frame = case.data[["time", "sp", "pv", "op", "mv"]].copy()
        truth = {"sticky": True, **case.truth}
    else:
        frame, truth = pi_loop(seed, n_samples, sticky=sticky)
    if not record_mv:
        frame = frame.drop(columns="mv")
    truth["has_mv"] = record_mv
    return frame, truth


def pi_loop(seed: int, n_samples: int, *, sticky: bool) -> tuple[pd.DataFrame, dict]:
    """PI loop on a FOPTD process, healthy (S = J = 0) or with a Kano sticky valve."""
    rng = np.random.default_rng(seed)
    gain = float(rng.uniform(0.5, 3.0))  # pv units per % of span
    time_constant = float(rng.uniform(10.0, 60.0))  # [s]
    dead_time = float(np.round(rng.uniform(2.0, 15.0)))  # [s], whole samples
    # SIMC tuning with the closed-loop time equal to the dead time.
    Kc = time_constant / (gain * 2.0 * dead_time)
    Ti = min(time_constant, 8.0 * dead_time)
    process = FOPTD(gain=gain, time_constant=time_constant, dead_time=dead_time)
    controller = PI(gain=Kc, integral_time=Ti)
    S = float(rng.uniform(2.0, 6.0)) if sticky else 0.0
    J = float(S * rng.uniform(0.2, 1.0)) if sticky else 0.0
    pv_bias = float(np.round(rng.uniform(20.0, 80.0), 1))
    noise_std = float(rng.uniform(0.01, 0.05) * gain)
    # Coloured noise (first-order filtered, time constant 5-30 s) keeps a healthy loop
    # moving, as real loops never are still, without a slow pattern of its own.
    pole = float(np.exp(-SAMPLE_TIME_S / rng.uniform(5.0, 30.0)))
    load = lfilter([1.0 - pole], [1.0, -pole], rng.standard_normal(n_samples)) * gain
    sim = simulate_loop(
        process,
        controller,
        duration=n_samples * SAMPLE_TIME_S,
        dt=SAMPLE_TIME_S,
        valve="kano" if sticky else "linear",
        S=S,
        J=J,
        sp=pv_bias,
        load=load,
        noise_std=noise_std,
        seed=seed,
        op_bias=float(rng.uniform(35.0, 65.0)),
        pv_bias=pv_bias,
    )
    frame = pd.DataFrame({"time": sim.time, "sp": sim.sp, "pv": sim.pv, "op": sim.op, "mv": sim.mv})
    truth = {
        "sticky": sticky,
        "S": S,
        "J": J,
        "process": {"gain": gain, "time_constant_s": time_constant, "dead_time_s": dead_time},
        "controller": {"gain": Kc, "integral_time_s": Ti},
        "noise_std": noise_std,
    }
    return frame, truth


def make_plant(
    out_dir: str | Path,
    n_loops: int,
    *,
    n_samples: int = 10_000,
    seed: int = 0,
    fmt: str = "csv",
    sticky_share: float = 0.5,
    mv_share: float = 0.0,
    sticky_model: str = "synthetic",
) -> list[Path]:
    """Write ``n_loops`` generated loops to ``out_dir``; return the files written.

    Parameters
    ----------
    out_dir : path
        Folder (created).
    n_loops : int
        Number of loops, named ``L0000``, ``L0001``, ...
    n_samples : int
        Samples per loop.
    seed : int
        Plant seed; loop ``i`` uses seed ``seed * 100 003 + i``.
    fmt : {"csv", "parquet", "mixed", "dataset"}
        One CSV or Parquet file per loop, alternating CSV and Parquet, or one Parquet
        file ``plant.parquet`` with a ``loop_id`` column.
    sticky_share, mv_share : float
        Share of loops with a sticky valve, and with a recorded valve position.
    sticky_model : {"synthetic", "simple"}
        Generator of the sticky loops (module docstring).
    """
    if fmt not in ("csv", "parquet", "mixed", "dataset"):
        raise ValueError(f"unknown format {fmt!r}: use csv, parquet, mixed or dataset")
    if sticky_model not in STICKY_MODELS:
        raise ValueError(f"unknown sticky model {sticky_model!r}: use synthetic or simple")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    picker = np.random.default_rng(seed)
    sticky = picker.random(n_loops) < sticky_share
    record_mv = picker.random(n_loops) < mv_share
    written: list[Path] = []
    truths: dict[str, dict] = {}
    frames: list[pd.DataFrame] = []
    for i in range(n_loops):
        name = f"L{i:04d}"
        frame, truth = make_loop(
            seed * 100_003 + i,
            n_samples=n_samples,
            sticky=bool(sticky[i]),
            record_mv=bool(record_mv[i]),
            sticky_model=sticky_model,
        )
        truths[name] = truth
        if fmt == "dataset":
            frames.append(frame.assign(loop_id=name))
            continue
        parquet = fmt == "parquet" or (fmt == "mixed" and i % 2 == 1)
        path = out / f"{name}.{'parquet' if parquet else 'csv'}"
        if parquet:
            frame.to_parquet(path, index=False)
        else:
            frame.to_csv(path, index=False, float_format="%.6g")
        written.append(path)
    if fmt == "dataset":
        path = out / "plant.parquet"
        pd.concat(frames, ignore_index=True).to_parquet(path, index=False)
        written.append(path)
    (out / "truth.json").write_text(json.dumps(truths, indent=1))
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--loops", type=int, default=100)
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--format", default="csv", choices=("csv", "parquet", "mixed", "dataset"), dest="fmt"
    )
    parser.add_argument("--sticky-share", type=float, default=0.5)
    parser.add_argument("--mv-share", type=float, default=0.0)
    parser.add_argument("--sticky-model", default="synthetic", choices=STICKY_MODELS)
    a = parser.parse_args(argv)
    files = make_plant(
        a.out_dir,
        a.loops,
        n_samples=a.samples,
        seed=a.seed,
        fmt=a.fmt,
        sticky_share=a.sticky_share,
        mv_share=a.mv_share,
        sticky_model=a.sticky_model,
    )
    print(f"wrote {a.loops} loops in {len(files)} file(s) to {a.out_dir}")


if __name__ == "__main__":
    main()
