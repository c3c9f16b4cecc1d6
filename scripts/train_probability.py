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
    """The nested feature sets compared by cross-validated log loss (the model's
    :data:`~stictiondiag.stiction.probability.FEATURES` is the one chosen)."""
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
    from stictiondiag.stiction.probability import (
        BASE_FEATURES,
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
    mv_mask = np.array([bool(r["has_mv"]) for r in train])
    shipped = {}
    for label, names in (
        ("earlier features in both parts", {"op_pv": BASE_FEATURES, "mv": BASE_FEATURES}),
        ("shipped (per part)", PART_FEATURES),
    ):
        loss = cross_validate(train, C, False, names=names, per_loop=True)
        shipped[label] = (loss.mean(), loss[~mv_mask].mean(), loss[mv_mask].mean())
    best = min(cv, key=lambda k: cv[k][0])
    chosen = feature_sets()[best[0]] == FEATURES and best[1] == C
    if not chosen:
        print(
            f"note: lowest CV log loss is {best}, not the model's features and C", file=sys.stderr
        )
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
    compare = held_out_comparison(train, test, p)
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
        (aucs, boosted, compare, shipped),
    )
    a.doc.write_text(doc + kept_sections(a.doc))
    print(doc)
    return 0 if ok else 1


#: Heading from which the written-by-hand part of the calibration doc starts; the
#: script rewrites what comes before it and keeps the rest.
KEPT_HEADING = "## Why real loops came out inconclusive"


def kept_sections(doc: Path) -> str:
    """The hand-written part of ``doc`` (from :data:`KEPT_HEADING` on), or ''."""
    try:
        text = doc.read_text()
    except OSError:
        return ""
    i = text.find(KEPT_HEADING)
    return "\n" + text[i:] if i >= 0 else ""


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

    (table, n_strata), boosted, compare, shipped = extra
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
    best = min(cv, key=lambda k: cv[k][0])
    best_mv = min(cv, key=lambda k: cv[k][2])
    lines += [
        "",
        f"The shipped combination against the earlier model, C = {C:g}, on the same folds"
        " of all training loops (the columns above for the loops with and without mv"
        " draw their own folds, which moves a log loss by about 0.005):",
        "",
        "| model | log loss, all | log loss, no mv | log loss, mv |",
        "|---|---|---|---|",
        *[f"| {k} | {a:.4f} | {b:.4f} | {m:.4f} |" for k, (a, b, m) in shipped.items()],
    ]
    lines += [
        "",
        "On the held-out loops (log loss, area under the ROC curve of P, Brier score; loops",
        "without mv: also how many fall between the decision levels), the shipped model",
        "against the earlier feature set refitted on the same training loops:",
        "",
        "| model | log loss, all | log loss, no mv | AUC, no mv | Brier, all |"
        " no mv: 0.3 < P < 0.7 |",
        "|---|---|---|---|---|---|",
        *[
            f"| {name} | {v['ll']:.4f} | {v['ll_nomv']:.4f} | {v['auc_nomv']:.3f} |"
            f" {v['brier']:.3f} | {v['between']} of {v['n_nomv']} |"
            for name, v in compare.items()
        ],
    ]
    lines += [
        "",
        f"Lowest log loss of the logistic models over all loops: {best[0]}, C = {best[1]:g}"
        f" ({cv[best][0]:.4f}); over the loops with mv: {best_mv[0]}, C = {best_mv[1]:g}"
        f" ({cv[best_mv][2]:.4f}). The part for loops without mv uses"
        f" {len(PART_FEATURES['op_pv'])} features (all but the calls), the part for loops"
        f" with mv the {len(PART_FEATURES['mv'])} earlier ones; C = {C:g}.",
    ]
    return lines


def held_out_comparison(train: list[dict], test: list[dict], p: np.ndarray) -> dict:
    """Held-out log loss, AUC and Brier score of the shipped model's predictions ``p``
    and of the earlier feature set (:data:`~stictiondiag.stiction.probability.BASE_FEATURES`)
    refitted on ``train``."""
    from stictiondiag.stiction.probability import BASE_FEATURES, apply_part, design_row

    y = np.array([float(r["sticky"]) for r in test])
    mv = np.array([bool(r["has_mv"]) for r in test])
    p0 = np.zeros(len(test))
    for part in (False, True):
        rows = [r for r in train if bool(r["has_mv"]) == part]
        fit = fit_logistic(
            np.array([design_row(r["features"], BASE_FEATURES) for r in rows]),
            np.array([float(r["sticky"]) for r in rows]),
        )
        idx = np.flatnonzero(mv == part)
        if idx.size:
            X = np.array([design_row(test[i]["features"], BASE_FEATURES) for i in idx])
            p0[idx] = apply_part(fit, X)
    out = {}
    for name, q in (("earlier features", p0), ("shipped", np.asarray(p, dtype=float))):
        q = np.clip(q, 1e-9, 1 - 1e-9)
        loss = -(y * np.log(q) + (1 - y) * np.log(1 - q))
        out[name] = {
            "ll": float(loss.mean()),
            "ll_nomv": float(loss[~mv].mean()),
            "auc_nomv": roc_auc(y[~mv], q[~mv]),
            "brier": float(np.mean((q - y) ** 2)),
            "between": int(np.sum((q[~mv] > 0.3) & (q[~mv] < 0.7))),
            "n_nomv": int((~mv).sum()),
        }
    return out


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
        "# Calibration of the stiction probability",
        "",
        "`P(stiction)` (`stictiondiag/stiction/probability.py`) is a regularised logistic",
        "regression of the evidence of the fit, the oscillation and its shape, and the",
        "classic tests' statistics, fitted on simulated loops only",
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
        " cached (under `--cache`; a fully cached run takes seconds). " + MEASURED_RUN,
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
