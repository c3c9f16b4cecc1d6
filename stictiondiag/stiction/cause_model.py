"""Stage 2 of the verdict: one probability per cause of a loop's cycle.

A multinomial logistic regression (softmax over :data:`~stictiondiag.stiction.cause.CAUSES`,
L2-regularised, standardised features) of the evidence the analysis computes for
every loop (:func:`stictiondiag.stiction.verdict.verdict_features`), fitted by
``scripts/train_cause.py`` on simulated loops only: the family of
:mod:`stictiondiag.apps.family_causes`, each oscillating loop labelled by the
counterfactual twin that stops its cycle.  It ships as :data:`MODEL_FILE`; its
features, their choice (separation on simulation, then the shift check against
unlabelled real records) and its calibration on held-out simulated loops are in
``docs/calibration.md`` ("Why the loop oscillates").  Real-plant labels are never
used.

A softmax was preferred to boosted trees or a random forest: with a few hundred
labelled loops and about ten features it is as accurate on held-out simulated loops
and its probabilities need no separate calibration; it needs numpy and scipy only.
"""

from __future__ import annotations

import json
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from stictiondiag.core.errors import StictionError
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


def apply_model(model: dict, X: np.ndarray) -> np.ndarray:
    """P of each cause (columns in :data:`CAUSES` order) for the rows of X."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    Z = (X - np.asarray(model["mean"])) / np.asarray(model["scale"])
    W = np.asarray(model["coef"])  # (n_features, n_classes)
    return softmax(Z @ W + np.asarray(model["intercept"]))


def cause_probabilities(features: dict, model: dict | None = None) -> dict[str, float]:
    """P of each cause of the loop's cycle [-], summing to 1."""
    model = model or load_cause_model()
    p = apply_model(model, design(features, model["features"]))[0]
    return {c: float(v) for c, v in zip(CAUSES, p, strict=True)}


def read_causes(features: dict, model: dict | None = None) -> CauseReading | None:
    """Stage 2's reading of a loop with a cycle; None when no cause model is installed."""
    try:
        return CauseReading.of(cause_probabilities(features, model))
    except StictionError:
        return None
