"""How the controller's tuning shapes a sticky valve's cycle, against real records.

    python scripts/tuning_shapes.py [--n 60] [--seed 77] [--real ../shared/data/isdb]

Simulates the same ``--n`` valve-generator seeds of the cause family
(:func:`stictiondiag.apps.family_causes.cause_label`, seeds ``seed * 1_000_000 + i``)
under each tuning style of :data:`~stictiondiag.apps.family_causes.TUNING_STYLES`,
every other draw the same, and analyses the loops whose cycle a linear valve stops
as a user's file is analysed.  For each style it prints the quartiles of the shape
features that tell a valve's cycle from an external one (the pv-op plot's axis
ratio, the odd harmonics of pv and op) and how the shipped cause model calls the
cycles.  With ``--real``, the same features of the real records with a cycle in
that folder are printed beside them (its manifest's sample times and loop types; no
label column is read).  This is the measurement behind the integral-dominant tuning
of the cause family (``docs/history.md``, "Plants tune integral-dominant").
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The shape features compared.
SHAPES = ("ellipse_axis_ratio", "pv_odd_harmonics", "op_odd_harmonics")


def _quartiles(values: list[float]) -> str:
    return " / ".join(f"{v:.2f}" for v in np.percentile(values, [25, 50, 75]))


def style_rows(style: str, seeds: list[int]) -> list[dict]:
    """The features of the valve cycles of ``seeds`` under one tuning style."""
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.apps.family_causes import cause_label
    from stictiondiag.core.errors import StictionError

    config = AnalysisConfig(gap=False, replay=False, compensation=False)
    rows = []
    for seed in seeds:
        try:
            loop, label = cause_label(seed, "valve", style)
            if label != "valve":
                continue
            rows.append(analyze(loop.tags(), config=config).verdict.evidence.features)
        except StictionError:
            continue
    return rows


def real_rows(folder: Path) -> list[dict]:
    """The features of the real records with a cycle in ``folder`` (labels not read)."""
    import pandas as pd

    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.apps.validation import LOOP_TYPE_MAP
    from stictiondiag.core.errors import StictionError
    from stictiondiag.io.tags import read_tags

    m = pd.read_csv(folder / "manifest.csv", usecols=["file", "loop_type", "integrating", "ts_s"])
    config = AnalysisConfig(gap=False, replay=False, compensation=False)
    rows = []
    for f, lt, integ, ts in zip(
        m["file"], m["loop_type"], m["integrating"], m["ts_s"], strict=True
    ):
        try:
            tags = read_tags(
                folder / f,
                ts=float(ts),
                loop_type=LOOP_TYPE_MAP.get(str(lt).lower(), "other"),
                integrating=bool(integ),
            )
            v = analyze(tags, config=config).verdict
        except StictionError:
            continue
        if v.cycle is not None and v.cycle.present:
            rows.append(v.evidence.features)
    return rows


def line(name: str, rows: list[dict], model: dict | None) -> str:
    """One table row: the quartiles of each shape feature and the model's calls."""
    from stictiondiag.stiction.cause_model import apply_model

    cells = [_quartiles([r[k] for r in rows]) for k in SHAPES]
    calls = "-"
    if model is not None and rows:
        P = apply_model(model, np.array([[r[k] for k in model["features"]] for r in rows]))
        got = Counter(model["classes"][int(j)] for j in P.argmax(axis=1))
        calls = ", ".join(f"{c} {got.get(c, 0)}" for c in model["classes"])
    return f"| {name} | {len(rows)} | " + " | ".join(cells) + f" | {calls} |"


def main(argv=None) -> int:
    from stictiondiag.apps.family_causes import TUNING_STYLES
    from stictiondiag.stiction.cause_model import load_cause_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=60)
    ap.add_argument("--seed", type=int, default=77)
    ap.add_argument("--real", type=Path, default=None)
    a = ap.parse_args(argv)
    seeds = [a.seed * 1_000_000 + i for i in range(a.n)]
    model = load_cause_model()
    print(f"| loops | cycles | {' | '.join(f'{k} (quartiles)' for k in SHAPES)} | called |")
    print("|---" * (len(SHAPES) + 3) + "|")
    for style in TUNING_STYLES:
        print(line(f"valve cycles, {style} tuning", style_rows(style, seeds), model))
    if a.real is not None:
        print(line("real records with a cycle", real_rows(a.real), model))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
