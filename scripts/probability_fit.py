"""Fitting and measuring the stiction probability model of
``scripts/train_probability.py``: the regularised logistic regression, its
cross-validation over feature sets and penalties, the areas under the ROC curve, the
reliability bands, and the held-out rule by which a feature set ships
(:func:`held_out_gate`).  On simulated loops only.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize
from scipy.stats import rankdata

from stictiondiag.stiction.probability import (
    BASE_FEATURES,
    CANDIDATES,
    CLASSIC_TESTS,
    FEATURES,
    apply_part,
    design_row,
    part_name,
)
from stictiondiag.stiction.probability_evidence import CONTINUOUS, SHAPE_FEATURES
from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

#: Inverse strength of the L2 penalty on the standardised coefficients [-].
C = 1.0


#: Width of the reliability bands [-].
BAND = 0.2


#: Largest allowed gap between a band's observed frequency and its mean prediction [-].
TOLERANCE = 0.1


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
    name = part_name(r["features"], r["has_mv"])
    return name + ("_cycle" if r["features"]["oscillating"] > 0.5 else "_no_cycle") * by_cycle


def feature_sets() -> dict[str, tuple[str, ...]]:
    """The nested feature sets compared by cross-validated log loss; the one that
    ships is decided by the held-out rule (:func:`held_out_gate`)."""
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
            "verdict": set_name(sets[pick]),
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


def set_name(names: tuple) -> str:
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
    # Imported here: scikit-learn is optional, needed only for --compare-boosting.
    from sklearn.calibration import CalibratedClassifierCV
    from sklearn.ensemble import HistGradientBoostingClassifier

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
