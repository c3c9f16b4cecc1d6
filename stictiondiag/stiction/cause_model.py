"""Stage 2 of the verdict: one probability per cause of a loop's cycle.

A classifier over :data:`~stictiondiag.stiction.cause.CAUSES` of the evidence the
analysis computes for every loop (:func:`stictiondiag.stiction.verdict.verdict_features`),
fitted by ``scripts/train_cause.py`` on simulated loops only: the family of
:mod:`stictiondiag.apps.family_causes`, each oscillating loop labelled by the
counterfactual twin that stops its cycle.  It ships as :data:`MODEL_FILE`; its
features, their choice (separation on simulation, then the shift check against
unlabelled real records) and its calibration on held-out simulated loops are in
``docs/calibration.md`` ("Why the loop oscillates").  Real-plant labels are never
used.

Two kinds of model are read (the file's ``kind``):

``softmax``
    A multinomial logistic regression (L2-regularised, standardised features):
    ``P = softmax(z W + b)``.
``boosted``
    Gradient-boosted regression trees (one tree per cause and boosting round, fitted
    by scikit-learn's histogram gradient boosting on the log loss, exported as flat
    node arrays): ``P = softmax(baseline + sum of the trees' leaves)``.  Evaluated
    here by a compiled traversal (:func:`_tree_scores`), so using the model needs
    neither scikit-learn nor a pickle.
``mean``
    The mean of its ``members``' probabilities (a softmax regression and boosted trees
    over the same features): the trees learn how the evidence combines, the softmax
    keeps adding it up where the training loops are few and a tree's leaf would say
    anything (``docs/history.md``, "Boosted trees for the cause model").

**Is the record like the loops the cause was learnt from?**  A classifier gives a
probability to any point, however far it lies from its training loops.  The file
also carries, under ``typicality``, each cause's reference: the centre and the
inverse covariance (shrunk by the block's ``shrink`` towards the identity) of the
standardised features of the training loops of that cause, and the 99th percentile
of their squared Mahalanobis distances, each measured out of fold (to a reference
fitted without it).  :func:`atypicality` is a
record's squared distance to its most likely cause over that percentile: above 1 the
record is unlike 99 % of the simulated loops the call was learnt from, and the
verdict says that the call is an extrapolation (it does not change the call;
``docs/history.md``, "Is the record like the loops the cause was learnt from?").

The model that ships is the softmax regression: boosted trees and the mean of the two
ranked held-out simulated loops better, but the trees left the paper's concentration
loop undecided and both made the verdicts on the two halves of real records agree less
often, so neither met the rule stated before it was measured (``docs/history.md``,
"Boosted trees for the cause model").  ``scripts/train_cause.py --kind`` fits each.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.core.jit import jit
from stictiondiag.stiction.cause import CAUSES, CauseReading

#: The fitted model, written by ``scripts/train_cause.py``.
MODEL_FILE = Path(__file__).with_name("cause_model.json")


@lru_cache(maxsize=4)
def load_cause_model(path: str | None = None) -> dict:
    """The fitted cause model (JSON), cached."""
    p = Path(path) if path else MODEL_FILE
    try:
        model = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise StictionError(
            f"cause model {p} missing or unreadable ({exc}); run scripts/train_cause.py"
        ) from None
    if tuple(model.get("classes", ())) != CAUSES:
        raise StictionError(f"{p}: its causes differ from this version's; retrain it")
    return model


def softmax(Z: np.ndarray) -> np.ndarray:
    """Row-wise softmax without overflow."""
    Z = np.atleast_2d(np.asarray(Z, dtype=float))
    Z = Z - Z.max(axis=1, keepdims=True)
    E = np.exp(Z)
    return E / E.sum(axis=1, keepdims=True)


def design(features: dict, names) -> np.ndarray:
    """The features as one row in the order of ``names``; a missing or non-finite
    value is an error of the caller (the analysis computes every feature)."""
    row = np.array([float(features[k]) for k in names])
    if not np.all(np.isfinite(row)):
        bad = [k for k, v in zip(names, row, strict=True) if not math.isfinite(v)]
        raise StictionError(f"cause features not finite: {', '.join(bad)}")
    return row


@jit
def _tree_scores(X, feature, threshold, left, right, value, leaf, missing_left, root, cls, k):
    """Sum of the leaves each row of ``X`` reaches, per class: one tree per entry of
    ``root`` (its first node) and ``cls`` (its class); a node sends a row left when
    its feature is at or below ``threshold`` (a NaN by ``missing_left``)."""
    n = X.shape[0]
    out = np.zeros((n, k))
    for i in range(n):
        for t in range(root.shape[0]):
            j = root[t]
            while not leaf[j]:
                x = X[i, feature[j]]
                go_left = missing_left[j] if np.isnan(x) else x <= threshold[j]
                j = left[j] if go_left else right[j]
            out[i, cls[t]] += value[j]
    return out


def boosted_scores(model: dict, X: np.ndarray) -> np.ndarray:
    """The boosted model's scores (before the softmax), one column per cause, for the
    rows of X."""
    t = model["trees"]
    return np.asarray(model["baseline"]) + _tree_scores(
        np.ascontiguousarray(X, dtype=float),
        np.asarray(t["feature"], dtype=np.int64),
        np.asarray(t["threshold"], dtype=float),
        np.asarray(t["left"], dtype=np.int64),
        np.asarray(t["right"], dtype=np.int64),
        np.asarray(t["value"], dtype=float),
        np.asarray(t["leaf"], dtype=np.bool_),
        np.asarray(t["missing_left"], dtype=np.bool_),
        np.asarray(t["root"], dtype=np.int64),
        np.asarray(t["cls"], dtype=np.int64),
        len(model["classes"]),
    )


def apply_model(model: dict, X: np.ndarray) -> np.ndarray:
    """P of each cause (columns in :data:`CAUSES` order) for the rows of X."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    if model.get("kind") == "mean":
        return np.mean([apply_model(m, X) for m in model["members"]], axis=0)
    if model.get("kind") == "boosted":
        return softmax(boosted_scores(model, X))
    Z = (X - np.asarray(model["mean"])) / np.asarray(model["scale"])
    W = np.asarray(model["coef"])  # (n_features, n_classes)
    return softmax(Z @ W + np.asarray(model["intercept"]))


def cause_probabilities(features: dict, model: dict | None = None) -> dict[str, float]:
    """P of each cause of the loop's cycle [-], summing to 1."""
    model = model or load_cause_model()
    p = apply_model(model, design(features, model["features"]))[0]
    return {c: float(v) for c, v in zip(CAUSES, p, strict=True)}


def atypicality(features: dict, cause: str, model: dict | None = None) -> float | None:
    """The squared Mahalanobis distance of ``features`` to the training loops of
    ``cause``, over the 99th percentile of theirs [-] (module doc); None when the
    model carries no reference."""
    model = model or load_cause_model()
    ref = model.get("typicality")
    if not ref:
        return None
    z = (design(features, model["features"]) - np.asarray(ref["mean"])) / np.asarray(ref["scale"])
    c = ref["causes"][cause]
    d = z - np.asarray(c["centre"])
    return float(d @ np.asarray(c["precision"]) @ d) / float(c["threshold"])


def read_causes(features: dict, model: dict | None = None) -> CauseReading | None:
    """Stage 2's reading of a loop with a cycle; None when no cause model is installed."""
    try:
        model = model or load_cause_model()
        probs = cause_probabilities(features, model)
        first = CauseReading.of(probs).ranked()[0].value
        return CauseReading.of(probs, atypicality(features, first, model))
    except StictionError:
        return None
