"""P(stiction) fitted on loops with a cycle only, against the shipped model, on
held-out simulated loops.

    python scripts/cycle_only_probability.py --cache DIR [--train family_1_1200.jsonl] \
        [--test family_2_400.jsonl]

The verdict decides a loop by P(stiction) only when stage 1 finds a cycle
(:mod:`stictiondiag.stiction.cause`), so a model fitted on that population alone
might decide more of it.  This reads the feature rows that
``scripts/train_probability.py --cache DIR`` wrote (simulated loops only), fits the
same regularised logistic regression (:func:`probability_fit.fit_logistic`, the
shipped features) on the training loops with a cycle, and prints, for the held-out
loops with a cycle, with and without mv: the area under the ROC curve, the Brier
score, the share left between the levels 0.3 and 0.7, and how often each call is
right, for the shipped model and the cycle-only one.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT))

from probability_fit import fit_logistic, roc_auc  # noqa: E402

from stictiondiag.stiction.probability import (  # noqa: E402
    BASE_FEATURES,
    apply_part,
    design_row,
    load_model,
    stiction_probability,
)


def _rows(path: Path) -> list[dict]:
    return [r for r in (json.loads(line) for line in path.open()) if r]


def _with_cycle(rows: list[dict], has_mv: bool) -> list[dict]:
    return [r for r in rows if r["has_mv"] == has_mv and r["features"]["oscillating"] > 0.5]


def _line(name: str, p: np.ndarray, y: np.ndarray) -> str:
    brier = float(np.mean((p - y) ** 2))
    between = float(np.mean((p >= 0.3) & (p <= 0.7)))
    st, ns = p > 0.7, p < 0.3
    right_st = f"{y[st].mean():.2f}" if st.any() else "-"
    right_ns = f"{(1 - y[ns]).mean():.2f}" if ns.any() else "-"
    return (
        f"  {name:10s} area {roc_auc(y, p):.3f}  Brier {brier:.3f}  undecided {between:.2f}  "
        f"called stiction {int(st.sum())} ({right_st} right)  "
        f"called no stiction {int(ns.sum())} ({right_ns} right)"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True, help="train_probability's --cache")
    ap.add_argument("--train", default="family_1_1200.jsonl")
    ap.add_argument("--test", default="family_2_400.jsonl")
    args = ap.parse_args(argv)
    train, test = _rows(args.cache / args.train), _rows(args.cache / args.test)
    model = load_model()
    for has_mv in (False, True):
        tr, te = _with_cycle(train, has_mv), _with_cycle(test, has_mv)
        X = np.array([design_row(r["features"], BASE_FEATURES) for r in tr])
        y = np.array([r["sticky"] for r in tr], dtype=float)
        part = fit_logistic(X, y)
        Xt = np.array([design_row(r["features"], BASE_FEATURES) for r in te])
        yt = np.array([r["sticky"] for r in te], dtype=float)
        shipped = np.array([stiction_probability(r["features"], has_mv, model) for r in te])
        print(f"{'with' if has_mv else 'without'} mv: {len(tr)} training, {len(te)} held-out loops")
        print(_line("shipped", shipped, yt))
        print(_line("cycle only", apply_part(part, Xt), yt))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
