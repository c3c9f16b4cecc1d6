"""Which rule should decide a loop with a cycle: P(stiction) or the cause model's P(valve)?

    python scripts/verdict_rule.py --cache DIR [--seed 11 [16 ...]] [--n-train 1500] \
        [--test-seed 12 13] [--n-test 250] [--model stictiondiag/stiction/cause_model.json]

Reads the simulated loops that ``scripts/train_cause.py`` analysed and cached under
``--cache`` (no real record, no label of one) and scores two decision rules on the
question plant experts ask of a loop with a cycle, "does the valve cause it?" (the
counterfactual label of :mod:`stictiondiag.apps.family_causes`):

* **friction**: P(stiction) of :mod:`stictiondiag.stiction.probability` (the valve has
  any friction), ``stiction`` above 0.7, ``no_stiction`` below 0.3;
* **cause**: P(valve) of :mod:`stictiondiag.stiction.cause_model`, ``stiction`` at or
  above :data:`~stictiondiag.stiction.verdict.VALVE_LEVEL`, ``no_stiction`` at or
  below one minus it.

On the held-out seeds' loops with a cycle and a cause, and on the loops of each
stick model of ``HELD_OUT`` as scored by the refit of the cause model that left that
stick model out of its training (``scripts/cause_fit.py``, ``leave_one_out``), it prints for each rule the loops it calls each way,
the accuracy of its calls, its accuracy scored as ``stiction validate`` scores the
ISDB (an undecided loop counts as not called stiction), the share it leaves
undecided and the area under the ROC curve of its probability.  The rule (``docs/calibration.md``, "Which probability
decides a loop with a cycle"): the cause model decides when, on both sets, its
probability ranks better (area under the ROC curve), it makes no more wrong stiction
calls and it leaves fewer loops undecided.  The accuracy of the calls is printed but
not compared: the two rules call different loops, and a rule that calls only the
plainest loops is accurate on them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cause_fit import leave_one_out, refitter, roc_auc  # noqa: E402
from train_cause import HELD_OUT  # noqa: E402

from stictiondiag.stiction.cause import CAUSES  # noqa: E402
from stictiondiag.stiction.cause_model import apply_model, load_cause_model  # noqa: E402
from stictiondiag.stiction.verdict import (  # noqa: E402
    NO_STICTION_LEVEL,
    STICTION_LEVEL,
    VALVE_LEVEL,
)


def _rows(cache: Path, seed: int, n: int) -> list[dict]:
    path = cache / f"causes_{seed}_{n}.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line]


def score(p: np.ndarray, valve: np.ndarray, hi: float, lo: float, strict: bool) -> dict:
    """Calls of a rule on probabilities ``p`` against the labels ``valve`` (True: the
    valve causes the cycle); ``strict`` levels (``>``/``<``) or inclusive ones."""
    yes = p > hi if strict else p >= hi
    no = p < lo if strict else p <= lo
    called = yes | no
    right = (yes & valve) | (no & ~valve)
    return {
        "stiction": int(yes.sum()),
        "no_stiction": int(no.sum()),
        "undecided": float(1.0 - called.mean()),
        "accuracy": float(right.sum() / max(1, called.sum())),
        # As the ISDB validation scores a verdict: only a stiction call is a call.
        "as_validated": float(np.mean(yes == valve)),
        "wrong stiction": int((yes & ~valve).sum()),
        "auc": roc_auc(valve.astype(int), p),
    }


def table(sets: list[tuple[str, list[dict], np.ndarray]]) -> list[str]:
    """Markdown lines: each rule on each set of (name, loops, the cause model's P(valve)
    of each loop)."""
    out = [
        "| loops | rule | n | called stiction | called no stiction | accuracy of calls"
        " | accuracy, undecided as not stiction | undecided | wrong stiction calls"
        " | area under ROC |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, sel, p_cause in sets:
        valve = np.array([r["label"] == "valve" for r in sel])
        p_fric = np.array([float(r["p_friction"]) for r in sel])
        for rule, p, hi, lo, strict in (
            ("friction P", p_fric, STICTION_LEVEL, NO_STICTION_LEVEL, True),
            ("cause P(valve)", p_cause, VALVE_LEVEL, 1.0 - VALVE_LEVEL, False),
        ):
            s = score(p, valve, hi, lo, strict)
            out.append(
                f"| {name} | {rule} | {len(sel)} | {s['stiction']} | {s['no_stiction']}"
                f" | {s['accuracy']:.2f} | {s['as_validated']:.2f} | {s['undecided']:.2f}"
                f" | {s['wrong stiction']}"
                f" | {s['auc']:.2f} |"
            )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--seed", type=int, nargs="+", default=[11])
    ap.add_argument("--n-train", type=int, default=1500)
    ap.add_argument("--test-seed", type=int, nargs="+", default=[12, 13])
    ap.add_argument("--n-test", type=int, default=250)
    ap.add_argument("--model", type=str, default=None)
    a = ap.parse_args(argv)
    model = load_cause_model(a.model)
    names = tuple(model["features"])

    def cycles(rows):
        return [r for r in rows if r["cycle"] and r["label"] in CAUSES]

    train = cycles(r for s in a.seed for r in _rows(a.cache, s, a.n_train))
    test = cycles(r for s in a.test_seed for r in _rows(a.cache, s, a.n_test))
    test = [r for r in test if r["direct"] is None]
    X = np.array([[float(r["features"][k]) for k in names] for r in test])
    sets = [("held-out seeds", test, apply_model(model, X)[:, 0])]
    # Each held-out stick model's loops (training and held-out seeds) by the refit that
    # left that stick model out.
    tested = [r for r in train if r["direct"] is None] + test
    logo = leave_one_out(train, tested, names, refitter(model), HELD_OUT)
    held = [r for _, rows, _ in logo for r in rows]
    sets.append(("held-out stick models", held, np.concatenate([P[:, 0] for _, _, P in logo])))
    print("\n".join(table(sets)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
