"""Fit the stiction probability model on simulated loops and measure its calibration.

    python scripts/train_probability.py [--n-train 900] [--n-test 500] [--seed 1] \
        [--test-seed 2] [--cache /tmp/stiction_family] [--workers 1]

Draws ``--n-train`` loops of :mod:`stictiondiag.apps.family` from ``--seed`` and
``--n-test`` held-out loops from ``--test-seed``, computes the features of
:mod:`stictiondiag.stiction.probability` for each (cached as JSON lines under
``--cache``, one file per seed and count), fits an L2-regularised logistic
regression separately for loops with and without mv (standardised features, penalty
``||w||^2 / (2 C)`` with :data:`C`; no real-plant data anywhere), writes
``stictiondiag/stiction/probability_model.json`` and the reliability table of the
held-out loops to ``docs/calibration.md``.  Deterministic for given seeds and counts.

Which features ship is decided by a stated rule (:func:`held_out_gate`): the feature
set the cross-validation on the training loops prefers replaces the shipped one only
if it also has the lower log loss on the held-out loops, by more than
:data:`GATE_SE` standard errors; otherwise the simpler set is kept.  The script
reports both and exits with 2 when the rule's outcome differs from
:data:`~stictiondiag.stiction.probability.PART_FEATURES`.

The features and their cache are in ``probability_features.py``, the fits, the
cross-validation and the held-out rule in ``probability_fit.py``, the calibration
doc's text in ``probability_doc.py`` (all beside this script).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from probability_doc import kept_parts, render  # noqa: E402
from probability_features import family_features  # noqa: E402
from probability_fit import (  # noqa: E402
    C_GRID,
    TOLERANCE,
    C,
    auc_table,
    cross_validate,
    cross_validate_boosting,
    cv_choice,
    feature_sets,
    fit_logistic,
    held_out_gate,
    reliability,
)

from stictiondiag.stiction.probability import (  # noqa: E402
    FEATURES,
    PART_FEATURES,
    apply_part,
    design_row,
    part_name,
)

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-train", type=int, default=900)
    ap.add_argument("--n-test", type=int, default=500)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--test-seed", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stiction_family"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument(
        "--compare-boosting",
        action="store_true",
        help="also cross-validate gradient-boosted trees (needs scikit-learn)",
    )
    ap.add_argument(
        "--model", type=Path, default=ROOT / "stictiondiag" / "stiction" / "probability_model.json"
    )
    ap.add_argument("--doc", type=Path, default=ROOT / "docs" / "calibration.md")
    a = ap.parse_args(argv)
    if a.compare_boosting:
        import importlib.util

        if importlib.util.find_spec("sklearn") is None:
            ap.error("--compare-boosting needs scikit-learn (pip install scikit-learn)")
    t0 = time.time()
    train = family_features(a.seed, a.n_train, a.cache, a.workers)
    test = family_features(a.test_seed, a.n_test, a.cache, a.workers)
    t_feat = time.time() - t0
    model = {
        "features": list(FEATURES),
        "C": C,
        "train_seed": a.seed,
        "n_train_drawn": a.n_train,
        "parts": {},
    }
    for name in ("op_pv", "mv"):
        rows = [r for r in train if part_name(r["features"], r["has_mv"]) == name]
        X = np.array([design_row(r["features"], PART_FEATURES[name]) for r in rows])
        y = np.array([float(r["sticky"]) for r in rows])
        model["parts"][name] = {"features": list(PART_FEATURES[name]), **fit_logistic(X, y)}
    no_mv = [r for r in train if not r["has_mv"]]
    with_mv = [r for r in train if r["has_mv"]]
    cv = {
        (name, c): (
            cross_validate(train, c, False, names=names),
            cross_validate(no_mv, c, False, names=names),
            cross_validate(with_mv, c, False, names=names),
        )
        for name, names in feature_sets().items()
        for c in C_GRID
    }
    choice, same_folds = cv_choice(train)
    aucs = auc_table(train)
    boosted = cross_validate_boosting(train) if a.compare_boosting else None
    text = json.dumps(model, indent=1) + "\n"
    a.model.write_text(text)

    def predict(rows):
        return np.array(
            [
                float(
                    apply_part(
                        model["parts"][part_name(r["features"], r["has_mv"])],
                        design_row(
                            r["features"], PART_FEATURES[part_name(r["features"], r["has_mv"])]
                        ),
                    )[0]
                )
                for r in rows
            ]
        )

    p = predict(test)
    y = np.array([float(r["sticky"]) for r in test])
    table = reliability(p, y)
    sets = feature_sets()
    gate = held_out_gate(train, test, PART_FEATURES, {k: sets[v] for k, v in choice.items()})
    mismatch = [part for part, g in gate["parts"].items() if g["ships"] != PART_FEATURES[part]]
    for part in mismatch:
        print(
            f"note: by the held-out rule the part {part} ships {gate['parts'][part]['verdict']};"
            " PART_FEATURES in stictiondiag/stiction/probability.py differs: change it and rerun",
            file=sys.stderr,
        )
    ok = all(r["n"] == 0 or abs(r["observed"] - r["mean_p"]) <= TOLERANCE for r in table)
    subsets = {
        "without mv": [not r["has_mv"] for r in test],
        "with mv": [r["has_mv"] for r in test],
        "with a regular oscillation": [r["features"]["oscillating"] > 0.5 for r in test],
        "without": [r["features"]["oscillating"] < 0.5 for r in test],
    }
    doc = render(
        a,
        model,
        table,
        ok,
        p,
        y,
        subsets,
        len(train),
        len(test),
        time.time() - t0,
        t_feat,
        cv,
        (aucs, boosted, gate, (choice, same_folds), mismatch),
    )
    head, tail = kept_parts(a.doc)
    a.doc.write_text(head + doc + tail)
    print(doc)
    return 2 if mismatch else (0 if ok else 1)


if __name__ == "__main__":
    raise SystemExit(main())
