"""The cause model's kinds (stictiondiag.stiction.cause_model): the compiled traversal
of exported boosted trees gives scikit-learn's own probabilities, a mean model
averages its members, and the shipped model (a softmax regression) reads the evidence
the analysis computes."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from stictiondiag.stiction.cause import CAUSES
from stictiondiag.stiction.cause_model import apply_model, cause_probabilities, load_cause_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from cause_fit import (  # noqa: E402
    BOOST_L2,
    BOOST_MIN_LEAF,
    BOOST_RATE,
    fit_boosted,
    fit_mean,
)


def _data(rng, n):
    X = rng.normal(size=(n, 5))
    y = np.clip((X[:, 0] > 0).astype(int) + (X[:, 1] * X[:, 2] > 0.3) + (X[:, 3] > 1.2), 0, 3)
    return X, y


def test_exported_trees_give_scikit_learns_probabilities():
    # Same trees, same leaves: only the order of the sum over trees may differ, so
    # the probabilities agree to rounding (1e-12).  A NaN follows the node's
    # missing-value branch in both.
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(0)
    X, y = _data(rng, 600)
    model = fit_boosted(X, y, 60, 4)
    clf = HistGradientBoostingClassifier(
        max_iter=60,
        learning_rate=BOOST_RATE,
        max_leaf_nodes=4,
        l2_regularization=BOOST_L2,
        min_samples_leaf=BOOST_MIN_LEAF,
        early_stopping=False,
        random_state=0,
    ).fit(X, y)
    Xt, _ = _data(rng, 300)
    Xt[::7, 2] = np.nan
    P = apply_model(model, Xt)
    assert P.shape == (300, len(CAUSES))
    assert np.max(np.abs(P - clf.predict_proba(Xt))) < 1e-12


def test_boosting_needs_every_cause():
    rng = np.random.default_rng(1)
    X, y = _data(rng, 200)
    with pytest.raises(ValueError, match="every cause"):
        fit_boosted(X, np.minimum(y, 2), 10, 4)


def test_a_mean_model_averages_its_members():
    rng = np.random.default_rng(3)
    X, y = _data(rng, 400)
    model = {"classes": list(CAUSES), **fit_mean(X, y, 0.3, 30, 4)}
    soft, boost = model["members"]
    Xt, _ = _data(rng, 50)
    P = apply_model(model, Xt)
    assert np.allclose(P, (apply_model(soft, Xt) + apply_model(boost, Xt)) / 2, atol=1e-15)
    assert np.allclose(P.sum(axis=1), 1.0, atol=1e-12)


def test_shipped_model_reads_the_verdicts_evidence():
    # The shipped file is the softmax regression (docs/history.md, "Boosted trees for
    # the cause model") over features the analysis computes: on a
    # simulated sticky loop with a cycle, every one of its features is in the
    # verdict's evidence, and the verdict's stage 2 is the model applied to them.
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.apps.family_causes import cause_loop

    model = load_cause_model()
    assert model["kind"].startswith("softmax") and tuple(model["classes"]) == CAUSES
    v = analyze(
        cause_loop(12000009).tags(),
        config=AnalysisConfig(gap=False, replay=False, compensation=False),
    ).verdict
    assert set(model["features"]) <= set(v.evidence.features)
    p = cause_probabilities(v.evidence.features, model)
    assert sum(p.values()) == pytest.approx(1.0, abs=1e-12)
    reading = v.evidence.cause_probabilities
    assert reading is not None
    for c in CAUSES:
        assert reading.p(c) == pytest.approx(p[c], abs=1e-12)


def test_split_half_agreement_counts_stage_2_calls():
    # P(valve) = e^(3x) / (e^(3x) + 3): x = 0 gives 0.25 (no stiction, at most 0.4),
    # x = 1 gives 0.87 (stiction), x = 0.3 gives 0.45 (undecided).  A record with a
    # half without a cycle is not counted.
    from cause_halves import agreement

    model = {
        "classes": list(CAUSES),
        "features": ["improvement"],
        "mean": [0.0],
        "scale": [1.0],
        "coef": [[3.0, 0.0, 0.0, 0.0]],
        "intercept": [0.0, 0.0, 0.0, 0.0],
    }

    def rec(x1, x2, cycle2=True):
        return {
            "halves": [
                {"features": {"improvement": x1}, "cycle": True},
                {"features": {"improvement": x2}, "cycle": cycle2},
            ]
        }

    records = [rec(1, 1), rec(1, 0), rec(0, 0), rec(0.3, 0.3), rec(0.3, 1), rec(1, 1, False)]
    assert agreement(model, records) == (5, 3)
    assert agreement(model, []) == (0, 0)
