"""Label-free covariate shift between the simulated family and real plant loops.

    python scripts/shift_diagnosis.py [--isdb DIR] [--n-family 300] [--seed 2] \
        [--out /tmp/shift.json]

For every ISDB loop (inputs only: pv, op, sp, the manifest's sampling time, loop type
and integrating flag; the label columns are never read) and for ``--n-family`` loops
of :mod:`stictiondiag.apps.family`, computes the probability model's features and a
few record statistics (:func:`record_stats`) and prints their quantiles side by side,
so that one sees where real records fall outside the simulated ones.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from stictiondiag.analysis import estimate_loop
from stictiondiag.apps.family import family_loop
from stictiondiag.apps.validation import LOOP_TYPE_MAP, default_isdb_dir
from stictiondiag.core.errors import StictionError
from stictiondiag.io.tags import read_tags
from stictiondiag.stiction.probability import stiction_probability

#: The manifest columns read (inputs only, never a label).
INPUT_COLUMNS = ("loop", "file", "loop_type", "integrating", "ts_s")


def _hf_share(x: np.ndarray) -> float:
    """Share of x's spread that is sample-to-sample noise: robust white-noise std from
    the first differences (MAD / 0.6745 / sqrt 2) over the std of x [-]."""
    d = np.diff(x)
    s = float(np.std(x))
    if s <= 0 or d.size < 3:
        return 0.0
    return float(np.median(np.abs(d - np.median(d))) / 0.6745 / math.sqrt(2.0) / s)


def _slow_share(x: np.ndarray, window: int) -> float:
    """Share of x's spread that a moving mean over ``window`` samples keeps (drift) [-]."""
    s = float(np.std(x))
    if s <= 0 or window >= x.size:
        return 0.0
    k = np.ones(window) / window
    return float(np.std(np.convolve(x - x.mean(), k, mode="valid")) / s)


def record_stats(tags, osc_pv, osc_op) -> dict:
    """Record statistics of one loop (no label): length, cycles, noise, drift,
    quantisation."""
    pv, op = np.asarray(tags.pv, float), np.asarray(tags.op, float)
    periods = [o.period_s for o in (osc_pv, osc_op) if o is not None and o.present]
    period = periods[0] if periods else None
    q5, q95 = np.percentile(op, [5, 95])
    out = {
        "n": int(tags.n),
        "cycles": float(tags.duration / period) if period else 0.0,
        "period_samples": float(period / tags.ts) if period else 0.0,
        "pv_noise": _hf_share(pv),
        "op_noise": _hf_share(op),
        "pv_levels": float(np.unique(pv).size / pv.size),
        "op_levels": float(np.unique(op).size / op.size),
        "op_spread": float(q95 - q5),
        "pv_drift": _slow_share(pv, max(3, pv.size // 10)),
        "op_drift": _slow_share(op, max(3, op.size // 10)),
        "osc_pv": float(bool(osc_pv is not None and osc_pv.present)),
        "osc_op": float(bool(osc_op is not None and osc_op.present)),
    }
    return out


def _features(tags):
    est = estimate_loop(tags)
    stats = record_stats(est.tags, est.oscillation, est.oscillation_op)
    feats, (support, f, f_iv), _ = est.features()
    S_iv = est.fit.S_interval
    stats["s_width_share"] = (
        float((S_iv[1] - S_iv[0]) / stats["op_spread"])
        if S_iv is not None and stats["op_spread"] > 0
        else float("nan")
    )
    stats["f_width"] = float(f_iv[1] - f_iv[0])
    return feats, stats


def isdb_rows(isdb: Path) -> list[dict]:
    import pandas as pd

    m = pd.read_csv(isdb / "manifest.csv", usecols=list(INPUT_COLUMNS))
    rows = []
    for _, r in m.iterrows():
        try:
            tags = read_tags(
                str(isdb / r["file"]),
                ts=float(r["ts_s"]),
                loop_type=LOOP_TYPE_MAP.get(str(r["loop_type"]).lower(), "other"),
                integrating=bool(r["integrating"]),
            )
            feats, stats = _features(tags)
        except StictionError as exc:
            print(f"{r['loop']}: {exc}", file=sys.stderr)
            continue
        P = stiction_probability(feats, False)
        rows.append({"loop": r["loop"], "features": feats, "stats": stats, "P": P})
        print(f"{r['loop']}: P={P:.2f}", file=sys.stderr, flush=True)
    return rows


def family_rows(seed: int, n: int) -> list[dict]:
    rows = []
    for i in range(n):
        loop = family_loop(seed * 1_000_000 + i)
        if loop.mv is not None:
            continue
        try:
            feats, stats = _features(loop.tags())
        except StictionError:
            continue
        rows.append(
            {
                "seed": seed * 1_000_000 + i,
                "features": feats,
                "stats": stats,
                "P": stiction_probability(feats, False),
                "truth": loop.truth,
            }
        )
    return rows


def _q(v) -> str:
    v = np.asarray([x for x in v if x is not None and math.isfinite(x)], float)
    if v.size == 0:
        return "-"
    q = np.percentile(v, [10, 50, 90])
    return f"{q[0]:.3g} / {q[1]:.3g} / {q[2]:.3g}"


def compare(isdb: list[dict], fam: list[dict]) -> str:
    keys_f = list(isdb[0]["features"])
    keys_s = list(isdb[0]["stats"])
    lines = [
        "| quantity | ISDB 10/50/90 % | family (no mv) 10/50/90 % |",
        "|---|---|---|",
    ]
    for k in keys_s:
        lines.append(
            f"| {k} | {_q([r['stats'][k] for r in isdb])} | {_q([r['stats'][k] for r in fam])} |"
        )
    for k in keys_f:
        lines.append(
            f"| {k} (mean) | {np.mean([r['features'][k] for r in isdb]):.3f} | "
            f"{np.mean([r['features'][k] for r in fam]):.3f} |"
        )
    lines.append(f"| P | {_q([r['P'] for r in isdb])} | {_q([r['P'] for r in fam])} |")
    for name, rows in (("ISDB", isdb), ("family", fam)):
        p = np.array([r["P"] for r in rows])
        lines.append(
            f"\n{name}: {len(rows)} loops, inconclusive (0.3-0.7) {np.mean((p >= 0.3) & (p <= 0.7)):.2f}"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--isdb", type=Path, default=None)
    ap.add_argument("--n-family", type=int, default=300)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("/tmp/shift.json"))
    ap.add_argument("--skip-isdb", action="store_true")
    a = ap.parse_args(argv)

    isdb = []
    if not a.skip_isdb:
        isdb = isdb_rows(a.isdb or default_isdb_dir())
    fam = family_rows(a.seed, a.n_family)
    a.out.write_text(json.dumps({"isdb": isdb, "family": fam}))
    if isdb:
        print(compare(isdb, fam))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
