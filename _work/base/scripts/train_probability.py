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
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

ROOT = Path(__file__).resolve().parents[1]

#: Inverse strength of the L2 penalty on the standardised coefficients [-].
C = 1.0

#: Loops whose features each call of :func:`family_features` computed (not cached).
COMPUTED: list[int] = []

#: How long computing the features took from an empty cache, as measured (the split-half
#: fits triple the work per loop without mv).
MEASURED_RUN = (
    "Measured from scratch (empty cache) on 24 Nov 2026 on a shared two-core machine"
    " (load 3 to 7): the 1200 training loops (in halves) and the 400 held-out loops"
    " took 10 min of wall time in three one-worker processes side by side, 491 s of"
    " CPU in all, about 0.3 s of CPU per loop."
)

#: Width of the reliability bands [-].
BAND = 0.2

#: Largest allowed gap between a band's observed frequency and its mean prediction [-].
TOLERANCE = 0.1


def _one(seed: int) -> dict | None:
    from stictiondiag.apps.family import family_loop, loop_features

    loop = family_loop(seed)
    out = loop_features(loop, with_classic=True)
    if out is None:
        return None
    feats, classic = out
    q5, q95 = np.percentile(loop.op, [5.0, 95.0])
    return {
        "seed": seed,
        "sticky": loop.sticky,
        "has_mv": loop.mv is not None,
        "features": feats,
        "classic": classic,
        "op_spread": float(q95 - q5),
        "truth": loop.truth,
    }


def family_features(seed: int, n: int, cache: Path, workers: int) -> list[dict]:
    """Features of loops ``seed * 1_000_000 + i``, i < n (cached; a cache of fewer
    loops of the same seed is extended)."""
    cache.mkdir(parents=True, exist_ok=True)
    path = cache / f"family_{seed}_{n}.jsonl"
    if path.is_file():
        COMPUTED.append(0)
        return [json.loads(line) for line in path.read_text().splitlines() if line]
    done: dict[int, dict | None] = {}
    for old in sorted(cache.glob(f"family_{seed}_*.jsonl")):
        m = int(old.stem.rsplit("_", 1)[1])
        if m <= n:
            done = dict.fromkeys(range(seed * 1_000_000, seed * 1_000_000 + m))
            for line in old.read_text().splitlines():
                if line:
                    r = json.loads(line)
                    done[r["seed"]] = r
    seeds = [seed * 1_000_000 + i for i in range(n) if seed * 1_000_000 + i not in done]
    COMPUTED.append(len(seeds))
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            rows = list(pool.map(_one, seeds, chunksize=4))
    else:
        rows = []
        for i, s in enumerate(seeds):
            rows.append(_one(s))
            if (i + 1) % 50 == 0:
                print(f"  {i + 1}/{len(seeds)}", file=sys.stderr, flush=True)
    done.update(zip(seeds, rows, strict=True))
    rows = [done[k] for k in sorted(done) if done[k] is not None]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
    os.replace(tmp, path)
    return rows


def fit_logistic(X: np.ndarray, y: np.ndarray, c: float = C) -> dict:
    """L2-regularised logistic regression on standardised X (intercept not penalised)."""
    mean = X.mean(axis=0)
    scale = X.std(axis=0)
    scale[scale == 0] = 1.0
    Z = (X - mean) / scale

    def nll(w):
        z = Z @ w[1:] + w[0]
        loss = np.sum(np.logaddexp(0.0, z) - y * z) + 0.5 * np.dot(w[1:], w[1:]) / c
        p = 1.0 / (1.0 + np.exp(-z))
        g = np.concatenate([[np.sum(p - y)], Z.T @ (p - y) + w[1:] / c])
        return loss, g

    res = minimize(
        nll,
        np.zeros(Z.shape[1] + 1),
        jac=True,
        method="L-BFGS-B",
        options={"maxiter": 2000, "gtol": 1e-9},
    )
    return {
        "mean": mean.tolist(),
        "scale": scale.tolist(),
        "coef": res.x[1:].tolist(),
        "intercept": float(res.x[0]),
        "n": int(y.size),
        "n_sticky": int(y.sum()),
    }


def _partition(r: dict, by_cycle: bool) -> str:
    from stictiondiag.stiction.probability import part_name

    name = part_name(r["features"], r["has_mv"])
    return name + ("_cycle" if r["features"]["oscillating"] > 0.5 else "_no_cycle") * by_cycle


def feature_sets() -> dict[str, tuple[str, ...]]:
    """The nested feature sets compared by cross-validated log loss; the one that
    ships is decided by the held-out rule (:func:`held_out_gate`)."""
    from stictiondiag.stiction.probability import BASE_FEATURES, CANDIDATES, CLASSIC_TESTS
    from stictiondiag.stiction.probability_evidence import CONTINUOUS, SHAPE_FEATURES

    classic_stats = tuple(k for k in CONTINUOUS if k not in SHAPE_FEATURES)
    return {
        "earlier (fit, oscillation, calls, halves)": BASE_FEATURES,
        "earlier + classic statistics": BASE_FEATURES + classic_stats,
        "earlier + classic statistics + shape": CANDIDATES,
        "all but the calls": tuple(k for k in CANDIDATES if k not in CLASSIC_TESTS),
    }


#: Values of C compared by cross-validation.
C_GRID = (0.1, 1.0, 10.0)

#: Strata of the sticky loops by S over op's 5-95 % spread, for the per-feature
#: areas under the ROC curve (each stratum against all healthy loops).
S_STRATA = ((0.0, 0.1), (0.1, 0.2), (0.2, 0.4), (0.4, 0.8), (0.8, math.inf))


def roc_auc(y: np.ndarray, s: np.ndarray) -> float:
    """Area under the ROC curve of score ``s`` for labels ``y`` (ties counted half;
    Mann-Whitney) [-]; NaN without both classes."""
    from scipy.stats import rankdata

    y = np.asarray(y, dtype=bool)
    n1 = int(y.sum())
    n0 = y.size - n1
    if n1 == 0 or n0 == 0:
        return math.nan
    r = rankdata(np.asarray(s, dtype=float))
    return float((r[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def auc_table(rows: list[dict]) -> tuple[list[tuple[str, list[float]]], list[int]]:
    """Per candidate feature, the area under the ROC curve (sticky against healthy)
    over the loops without mv, then per stratum of :data:`S_STRATA`; and the number
    of sticky loops per stratum.  Above 0.5: the feature is larger for sticky valves."""
    from stictiondiag.stiction.probability import CANDIDATES

    R = [r for r in rows if not r["has_mv"] and "op_spread" in r]
    y = np.array([bool(r["sticky"]) for r in R])
    ratio = np.array([r["truth"]["S"] / max(r["op_spread"], 1e-9) for r in R])
    masks = [(y & (ratio >= lo) & (ratio < hi)) for lo, hi in S_STRATA]
    table = []
    for k in CANDIDATES:
        x = np.array([float(r["features"][k]) for r in R])
        vals = [roc_auc(y, x)] + [roc_auc(y[m | ~y], x[m | ~y]) for m in masks]
        table.append((k, vals))
    return table, [int(m.sum()) for m in masks]


def cross_validate(
    rows: list[dict],
    c: float,
    by_cycle: bool,
    k: int = 5,
    names: tuple | dict | None = None,
    per_loop: bool = False,
):
    """k-fold cross-validated log loss of the model on the training loops [-], on the
    features ``names`` (default all of :data:`FEATURES`; a dict gives each part its
    own, as :data:`~stictiondiag.stiction.probability.PART_FEATURES`).  With
    ``per_loop`` the array of each loop's log loss."""
    from stictiondiag.stiction.probability import FEATURES, apply_part, design_row

    fold = np.random.default_rng(0).integers(0, k, len(rows))
    p = np.zeros(len(rows))
    y = np.array([float(r["sticky"]) for r in rows])
    parts = np.array([_partition(r, by_cycle) for r in rows])
    for name in set(parts):
        names_f = tuple((names.get(name) if isinstance(names, dict) else names) or FEATURES)
        X = np.array([design_row(r["features"], names_f) for r in rows])
        for f in range(k):
            tr = (fold != f) & (parts == name)
            te = (fold == f) & (parts == name)
            if te.any():
                p[te] = apply_part(fit_logistic(X[tr], y[tr], c), X[te])
    p = np.clip(p, 1e-9, 1 - 1e-9)
    loss = -(y * np.log(p) + (1 - y) * np.log(1 - p))
    return loss if per_loop else float(loss.mean())


def reliability(p: np.ndarray, y: np.ndarray, band: float = BAND) -> list[dict]:
    """Per band of predicted probability: count, mean prediction, observed frequency."""
    edges = np.arange(0.0, 1.0 + 1e-9, band)
    rows = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        m = (p >= lo) & ((p < hi) | ((hi >= 1.0) & (p <= 1.0)))
        n = int(m.sum())
        rows.append(
            {
                "band": (float(lo), float(hi)),
                "n": n,
                "mean_p": float(p[m].mean()) if n else None,
                "observed": float(y[m].mean()) if n else None,
            }
        )
    return rows


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
    from stictiondiag.stiction.probability import (
        FEATURES,
        PART_FEATURES,
        apply_part,
        design_row,
        part_name,
    )

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


#: The part of the calibration doc this script writes runs from this heading to
#: :data:`KEPT_HEADING`; what stands before it (the title and the figures table) and
#: from :data:`KEPT_HEADING` on (written by hand and by ``train_cause.py``) is kept.
GENERATED_HEADING = "## How P(stiction) is trained"
KEPT_HEADING = "## Which feature set ships"

#: The head of a calibration doc written from scratch.
DEFAULT_HEAD = "# Calibration of the stiction probability\n\n"


def kept_parts(doc: Path) -> tuple[str, str]:
    """The parts of ``doc`` this script keeps: the text before
    :data:`GENERATED_HEADING` (default :data:`DEFAULT_HEAD`) and from
    :data:`KEPT_HEADING` on (default '')."""
    try:
        text = doc.read_text()
    except OSError:
        return DEFAULT_HEAD, ""
    i = text.find(GENERATED_HEADING)
    j = text.find(KEPT_HEADING)
    return (text[:i] if i >= 0 else DEFAULT_HEAD), ("\n" + text[j:] if j >= 0 else "")


def _table_lines(table) -> list[str]:
    lines = [
        "| predicted P | loops | mean prediction | observed frequency | gap |",
        "|---|---|---|---|---|",
    ]
    for r in table:
        lo, hi = r["band"]
        if r["n"]:
            gap = r["observed"] - r["mean_p"]
            lines.append(
                f"| {lo:.1f}-{hi:.1f} | {r['n']} | {r['mean_p']:.3f} | "
                f"{r['observed']:.3f} | {gap:+.3f} |"
            )
        else:
            lines.append(f"| {lo:.1f}-{hi:.1f} | 0 | | | |")
    return lines


def _choice_lines(cv, extra) -> list[str]:
    from stictiondiag.stiction.probability import PART_FEATURES

    (table, n_strata), boosted, gate, (choice, same_folds), mismatch = extra
    used = {k for names in PART_FEATURES.values() for k in names}
    heads = [f"{lo:g}-{hi:g}" if math.isfinite(hi) else f"> {lo:g}" for lo, hi in S_STRATA]
    lines = [
        "Area under the ROC curve of each candidate feature alone, sticky against healthy,",
        "over the training loops without mv: all of them, then the sticky loops by S over",
        "op's 5-95 % spread (each stratum against all healthy loops; above 0.5 the feature",
        "is larger for sticky valves, below 0.5 smaller; 0.5 tells nothing):",
        "",
        "| feature | all | "
        + " | ".join(f"S/op {h} ({n})" for h, n in zip(heads, n_strata, strict=True))
        + " |",
        "|---|---|" + "---|" * len(heads),
    ]
    for k, vals in table:
        mark = "" if k in used else " (not in the model)"
        lines.append(f"| {k}{mark} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")
    lines += [
        "",
        "An L2-regularised logistic regression on standardised features, one for loops",
        "with mv and one without. 5-fold cross-validated log loss on the training loops",
        "(lower is better; 0.693 is a coin), over all of them, over those without mv and",
        "over those with mv (each part fitted and cross-validated on its own loops):",
        "",
        "| features | C | log loss, all | log loss, no mv | log loss, mv |",
        "|---|---|---|---|---|",
    ]
    for (name, c), (v_all, v_nomv, v_mv) in cv.items():
        lines.append(f"| {name} | {c:g} | {v_all:.4f} | {v_nomv:.4f} | {v_mv:.4f} |")
    for name, (v_all, v_nomv) in (boosted or {}).items():
        lines.append(f"| {name} | - | {v_all:.4f} | {v_nomv:.4f} | |")
    cand = gate["candidate"]
    lines += [
        "",
        "**Which set ships.** A feature set ships only if it beats the shipped one in log",
        "loss on the held-out simulated loops, not only in cross-validation on the",
        "training loops: per part of the model, the cross-validation's choice (the set",
        f"with the lowest 5-fold log loss over that part's training loops, C = {C:g}, the"
        " same folds of all training loops for every set) is refitted on all training"
        " loops and compared with the shipped set on the held-out loops; it replaces the"
        f" shipped set only if its mean log loss is lower by more than {GATE_SE:g} standard"
        " errors of the paired per-loop difference. Within that margin simulation cannot"
        " tell the two apart and the simpler set (fewer features) is kept.",
        "",
        f"Cross-validated log loss per set, C = {C:g}, on the same folds of all training"
        " loops (the columns above for the loops with and without mv draw their own folds,"
        " which moves a log loss by about 0.005):",
        "",
        "| features | log loss, all | log loss, no mv | log loss, mv |",
        "|---|---|---|---|",
        *[f"| {k} | {a:.4f} | {b:.4f} | {m:.4f} |" for k, (a, b, m) in same_folds.items()],
        "",
        f"Cross-validation's choice: without mv {_set_name(cand['op_pv'])}; with mv"
        f" {_set_name(cand['mv'])}.",
        "",
        "On the held-out loops (log loss, area under the ROC curve of P, Brier score; loops",
        "without mv: also how many fall between the decision levels; all held-out loops:",
        "the calls and the share of them that is right), the shipped set and the",
        "cross-validation's choice, both refitted on the same training loops:",
        "",
        "| model | log loss, all | log loss, no mv | AUC, no mv | Brier, all |"
        " no mv: 0.3 < P < 0.7 | called stiction (sticky) | called no stiction (healthy) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key, label in (("shipped", "shipped set"), ("candidate", "cross-validation's choice")):
        v = gate["models"][key]
        lines.append(
            f"| {label} | {v['ll']:.4f} | {v['ll_nomv']:.4f} | {v['auc_nomv']:.3f} |"
            f" {v['brier']:.3f} | {v['between']} of {v['n_nomv']} |"
            f" {v['called']} ({v['called_right']:.2f}) | {v['cleared']} ({v['cleared_right']:.2f}) |"
        )
    lines.append("")
    for part, label in (("op_pv", "without mv"), ("mv", "with mv")):
        g = gate["parts"][part]
        if gate["shipped"][part] == cand[part]:
            lines.append(
                f"* Part {label}: the cross-validation's choice is the shipped set,"
                f" {g['verdict']}; it ships."
            )
            continue
        how = (
            f"lower by more than {GATE_SE:g} standard errors"
            if g["diff"] < -GATE_SE * g["se"]
            else f"higher by more than {GATE_SE:g} standard errors"
            if g["diff"] > GATE_SE * g["se"]
            else f"within {GATE_SE:g} standard errors (simulation cannot tell them apart)"
        )
        lines.append(
            f"* Part {label} ({g['n']} held-out loops): held-out log loss"
            f" {g['ll']['candidate']:.4f} for the cross-validation's choice,"
            f" {_set_name(cand[part])}, against {g['ll']['shipped']:.4f} for the shipped"
            f" {_set_name(gate['shipped'][part])}: difference {g['diff']:+.4f}, standard"
            f" error {g['se']:.4f}, {how}. By the rule, {g['verdict']} ships."
        )
    lines.append("")
    if mismatch:
        lines.append(
            "**The rule's outcome differs from the features the model ships"
            f" (`PART_FEATURES` in `stictiondiag/stiction/probability.py`) for the part(s)"
            f" {', '.join(mismatch)}: change them and rerun.**"
        )
    else:
        lines.append(
            f"The model ships the rule's outcome: without mv {len(PART_FEATURES['op_pv'])}"
            f" features, with mv {len(PART_FEATURES['mv'])}; C = {C:g}."
        )
    return lines


#: Parts of the model, by :func:`~stictiondiag.stiction.probability.part_name`.
PARTS = ("op_pv", "mv")

#: A feature set counts as better than another on the held-out loops only when its
#: mean log loss is lower by more than this many standard errors of the paired
#: per-loop difference (about a 95 % two-sided margin); within it simulation cannot
#: tell the two apart and the simpler set (fewer features) is kept.
GATE_SE = 2.0


def _log_loss(y: np.ndarray, q: np.ndarray) -> np.ndarray:
    q = np.clip(np.asarray(q, dtype=float), 1e-9, 1 - 1e-9)
    return -(y * np.log(q) + (1 - y) * np.log(1 - q))


def cv_choice(train: list[dict], c: float = C) -> tuple[dict, dict]:
    """The cross-validation's choice: per part of the model, the set of
    :func:`feature_sets` with the lowest 5-fold cross-validated log loss over that
    part's training loops (the same folds of all training loops for every set, C =
    ``c``); and each set's log loss over all, without mv and with mv."""
    mv = np.array([bool(r["has_mv"]) for r in train])
    losses = {}
    for name, names in feature_sets().items():
        loss = cross_validate(train, c, False, names=names, per_loop=True)
        losses[name] = (float(loss.mean()), float(loss[~mv].mean()), float(loss[mv].mean()))
    choice = {
        "op_pv": min(losses, key=lambda k: losses[k][1]),
        "mv": min(losses, key=lambda k: losses[k][2]),
    }
    return choice, losses


def _fit_predict(train: list[dict], test: list[dict], sets: dict, label=None) -> np.ndarray:
    """P of the ``test`` loops by a model fitted on ``train`` with the features
    ``sets[part]`` in each part (C = :data:`C`); ``label(row)`` is the training target
    (default: the simulated valve's ``sticky``)."""
    from stictiondiag.stiction.probability import apply_part, design_row, part_name

    p = np.full(len(test), 0.5)
    for part in PARTS:
        rows = [r for r in train if part_name(r["features"], r["has_mv"]) == part]
        idx = [i for i, r in enumerate(test) if part_name(r["features"], r["has_mv"]) == part]
        if not rows or not idx:
            continue
        fit = fit_logistic(
            np.array([design_row(r["features"], sets[part]) for r in rows]),
            np.array([float(r["sticky"] if label is None else label(r)) for r in rows]),
        )
        X = np.array([design_row(test[i]["features"], sets[part]) for i in idx])
        p[idx] = apply_part(fit, X)
    return p


def gate_part(
    loss_shipped: np.ndarray, loss_candidate: np.ndarray, n_shipped: int, n_candidate: int
) -> tuple[str, float, float]:
    """The held-out rule for one part: ``shipped`` or ``candidate``, from the per-loop
    held-out log losses of the two sets (same loops) and their numbers of features;
    with the mean difference (candidate minus shipped) and its standard error.

    A set wins when its mean log loss is lower by more than :data:`GATE_SE` standard
    errors of the paired difference; otherwise simulation cannot tell them apart and
    the set with fewer features is kept (the shipped one on a tie)."""
    d = np.asarray(loss_candidate, dtype=float) - np.asarray(loss_shipped, dtype=float)
    mean = float(d.mean()) if d.size else 0.0
    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
    if mean < -GATE_SE * se:
        return "candidate", mean, se
    if mean > GATE_SE * se:
        return "shipped", mean, se
    return ("candidate" if n_candidate < n_shipped else "shipped"), mean, se


def held_out_gate(train: list[dict], test: list[dict], shipped: dict, candidate: dict) -> dict:
    """The rule by which a feature set ships, on the held-out loops: per part, the
    shipped set and the candidate (the cross-validation's choice) refitted on
    ``train`` and compared by their log loss on ``test`` (:func:`gate_part`); with
    each model's held-out log loss, area under the ROC curve, Brier score and calls."""
    from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

    y = np.array([float(r["sticky"]) for r in test])
    mv = np.array([bool(r["has_mv"]) for r in test])
    p = {"shipped": _fit_predict(train, test, shipped)}
    p["candidate"] = p["shipped"] if candidate == shipped else _fit_predict(train, test, candidate)
    loss = {k: _log_loss(y, q) for k, q in p.items()}
    parts = {}
    for part, m in (("op_pv", ~mv), ("mv", mv)):
        if shipped[part] == candidate[part]:
            pick, mean, se = "shipped", 0.0, 0.0
        else:
            pick, mean, se = gate_part(
                loss["shipped"][m], loss["candidate"][m], len(shipped[part]), len(candidate[part])
            )
        sets = {"shipped": shipped[part], "candidate": candidate[part]}
        parts[part] = {
            "pick": pick,
            "ships": sets[pick],
            "verdict": _set_name(sets[pick]),
            "n": int(m.sum()),
            "ll": {k: float(v[m].mean()) if m.any() else math.nan for k, v in loss.items()},
            "diff": mean,
            "se": se,
        }
    models = {}
    for k, q in p.items():
        called, cleared = q > STICTION_LEVEL, q < NO_STICTION_LEVEL
        models[k] = {
            "ll": float(loss[k].mean()),
            "ll_nomv": float(loss[k][~mv].mean()),
            "auc_nomv": roc_auc(y[~mv], q[~mv]),
            "brier": float(np.mean((q - y) ** 2)),
            "between": int(np.sum((q[~mv] > NO_STICTION_LEVEL) & (q[~mv] < STICTION_LEVEL))),
            "n_nomv": int((~mv).sum()),
            "called": int(called.sum()),
            "called_right": float(y[called].mean()) if called.any() else math.nan,
            "cleared": int(cleared.sum()),
            "cleared_right": float(1 - y[cleared].mean()) if cleared.any() else math.nan,
        }
    return {"parts": parts, "models": models, "shipped": shipped, "candidate": candidate}


def _set_name(names: tuple) -> str:
    """The name of a feature set in :func:`feature_sets` (or its size)."""
    for k, v in feature_sets().items():
        if tuple(v) == tuple(names):
            return f"{k} ({len(names)} features)"
    return f"{len(names)} features"


def cross_validate_boosting(rows: list[dict], k: int = 5) -> dict[str, tuple[float, float]]:
    """k-fold log loss (all loops, loops without mv) of gradient-boosted trees
    (scikit-learn's HistGradientBoostingClassifier, depth 3, 150 iterations of 0.05,
    leaves of at least 40 loops; then the same with Platt scaling by 3-fold
    cross-validation), one per part as the logistic model, on the earlier features
    and on all candidates; the same folds as :func:`cross_validate`.  Only compared,
    never shipped (``docs/calibration.md``)."""
    from sklearn.calibration import CalibratedClassifierCV
    from sklearn.ensemble import HistGradientBoostingClassifier

    from stictiondiag.stiction.probability import BASE_FEATURES, CANDIDATES, design_row

    def trees():
        return HistGradientBoostingClassifier(
            max_depth=3, learning_rate=0.05, max_iter=150, min_samples_leaf=40, random_state=0
        )

    makers = {
        "boosted trees": trees,
        "boosted trees, Platt-scaled": lambda: CalibratedClassifierCV(
            trees(), method="sigmoid", cv=3
        ),
    }
    fold = np.random.default_rng(0).integers(0, k, len(rows))
    y = np.array([float(r["sticky"]) for r in rows])
    mv = np.array([bool(r["has_mv"]) for r in rows])
    out = {}
    for set_name, names in (("earlier", BASE_FEATURES), ("all candidates", CANDIDATES)):
        X = np.array([design_row(r["features"], names) for r in rows])
        for name, make in makers.items():
            p = np.zeros(len(rows))
            for f in range(k):
                for part in (False, True):
                    tr, te = (fold != f) & (mv == part), (fold == f) & (mv == part)
                    if te.any():
                        p[te] = make().fit(X[tr], y[tr]).predict_proba(X[te])[:, 1]
            p = np.clip(p, 1e-9, 1 - 1e-9)
            loss = -(y * np.log(p) + (1 - y) * np.log(1 - p))
            out[f"{name}, {set_name}"] = (float(loss.mean()), float(loss[~mv].mean()))
    return out


def render(a, model, table, ok, p, y, subsets, n_train, n_test, seconds, t_feat, cv, aucs) -> str:
    from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

    brier = float(np.mean((p - y) ** 2))
    called = p > STICTION_LEVEL
    cleared = p < NO_STICTION_LEVEL
    lines = [
        GENERATED_HEADING,
        "",
        "`P(stiction)` (`stictiondiag/stiction/probability.py`) is a regularised logistic",
        "regression of the evidence of the fit, the oscillation, the classic tests' calls",
        "and the fits on each half of the record, fitted on simulated loops only",
        "(`stictiondiag/apps/family.py`: data-driven and Karnopp valves; self-regulating,",
        "integrating and cascade-slave loops; drifting, stepping and periodic loads;",
        "aggressive, normal and sluggish tuning; set-point moves; quantisation, deadband",
        "and swinging-door compression; noise from 1 % to 50 % of pv's spread, and to 150 %",
        "in a tenth of the loops; healthy",
        "and sticky valves in equal shares; mv recorded in a quarter of the loops).",
        "No real-plant record, and no ISDB label, is used to fit or choose anything.",
        "",
        "Produced by (deterministic for the given seeds and counts):",
        "",
        "```bash",
        f"python scripts/train_probability.py --n-train {a.n_train} --n-test {a.n_test} "
        f"--seed {a.seed} --test-seed {a.test_seed} --workers {a.workers}"
        + (" --compare-boosting" if a.compare_boosting else ""),
        "```",
        "",
        f"Run time: {seconds / 60:.1f} min on {a.workers} worker(s), of which"
        f" {t_feat / 60:.1f} min computing the features of {sum(COMPUTED)} loops not yet"
        " cached (under `--cache`; a fully cached run takes minutes: the cross-validation). "
        + MEASURED_RUN,
        f"Training loops: {n_train} analysed of {a.n_train} drawn (seed {a.seed}); held-out"
        f" loops: {n_test} analysed of {a.n_test} drawn (seed {a.test_seed}). Loops the"
        " analysis refuses (a record shorter than two cycles) are left out, as the tool"
        " refuses them.",
        "",
        "## Reliability on held-out simulated loops",
        "",
        f"Bands of width {BAND}; each band's observed frequency of sticky valves must lie",
        f"within {TOLERANCE} of its mean prediction: **{'met' if ok else 'NOT met'}**.",
        f"Brier score {brier:.3f}.",
        "",
        *_table_lines(table),
    ]
    for name, mask in subsets.items():
        m = np.array(mask, dtype=bool)
        if m.sum():
            lines += [
                "",
                f"Held-out loops {name} ({int(m.sum())}):",
                "",
                *_table_lines(reliability(p[m], y[m])),
            ]
    lines += [
        "",
        "## Choice of model",
        "",
        *_choice_lines(cv, aucs),
        "",
        "## Decision levels",
        "",
        f"`stiction` when P > {STICTION_LEVEL}, `no_stiction` when P < {NO_STICTION_LEVEL},",
        "`inconclusive` between (stated before any real record was analysed; see",
        "`stictiondiag/stiction/verdict.py`). On the held-out simulated loops:",
        f"{int(called.sum())} called stiction ({float(y[called].mean()) if called.any() else 0:.2f}"
        f" of them sticky), {int(cleared.sum())} called no stiction"
        f" ({float(1 - y[cleared].mean()) if cleared.any() else 0:.2f} of them healthy),"
        f" {int((~called & ~cleared).sum())} inconclusive.",
        "",
        "## Coefficients (standardised features)",
        "",
        "| feature | " + " | ".join(model["parts"]) + " |",
        "|---|" + "---|" * len(model["parts"]),
    ]
    from stictiondiag.stiction.probability import CANDIDATES

    for k in CANDIDATES:
        cells = []
        for part in model["parts"].values():
            names = part.get("features") or model["features"]
            cells.append(f"{part['coef'][names.index(k)]:+.3f}" if k in names else "")
        if any(cells):
            lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines.append(
        "| intercept | "
        + " | ".join(f"{part['intercept']:+.3f}" for part in model["parts"].values())
        + " |"
    )
    lines.append(
        "| loops (sticky) | "
        + " | ".join(f"{part['n']} ({part['n_sticky']})" for part in model["parts"].values())
        + " |"
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
