"""The cause model's kinds (stictiondiag.stiction.cause_model): the compiled traversal
of exported boosted trees gives scikit-learn's own probabilities, a mean model
averages its members, and the shipped model (a softmax regression) reads the evidence
the analysis computes, and says when a record lies outside the loops a cause was
learnt from (the typicality check)."""

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
    TYPICAL_QUANTILE,
    fit_boosted,
    fit_mean,
    fit_typicality,
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


def _typicality_model(X, y):
    """A model file with only what the typicality check reads."""
    names = [f"x{j}" for j in range(X.shape[1])]
    return {"classes": list(CAUSES), "features": names, "typicality": fit_typicality(X, y)}


def _row(names, x):
    return {k: float(v) for k, v in zip(names, x, strict=True)}


def test_typicality_flags_about_one_new_loop_in_a_hundred():
    # Four Gaussian causes in 20 correlated dimensions, 120 training loops each (the
    # shipped model: 21 features, 34-323 loops a cause).  The percentile is taken out
    # of fold, so a new loop of the same cause exceeds it about as often as
    # 1 - TYPICAL_QUANTILE says: 4000 new loops, 1.2 % measured, binomial spread
    # 0.17 %.  Taken over the training loops' own distances it would flag 4 %, above
    # the 2.5 % this allows.
    from stictiondiag.stiction.cause_model import atypicality

    rng = np.random.default_rng(5)
    A = rng.normal(size=(20, 20))
    centres = 3.0 * rng.normal(size=(4, 20))

    def draw(n):
        y = np.repeat(np.arange(4), n)
        return centres[y] + rng.normal(size=(4 * n, 20)) @ A, y

    X, y = draw(120)
    model = _typicality_model(X, y)
    Xn, yn = draw(1000)
    far = [
        atypicality(_row(model["features"], x), CAUSES[c], model) > 1.0
        for x, c in zip(Xn, yn, strict=True)
    ]
    assert 0.003 < np.mean(far) < 0.025
    assert 1.0 - TYPICAL_QUANTILE == pytest.approx(0.01)
    # A loop ten spreads away from every cause is atypical for each of them.
    x_far = centres[0] + 10.0 * np.abs(A).sum(axis=0)
    assert all(atypicality(_row(model["features"], x_far), c, model) > 1.0 for c in CAUSES)


def test_a_cause_whose_loops_do_not_vary_keeps_a_usable_reference():
    # A few loops constant in one feature: shrinking towards the identity keeps that
    # feature's variance at a share of its overall spread, so the percentile stays
    # finite and moderate (before, shrunk towards its own diagonal, it reached 3e6
    # and the cause could never be atypical), and a loop far off in that feature is
    # still atypical.
    from stictiondiag.stiction.cause_model import atypicality

    rng = np.random.default_rng(6)
    X = rng.normal(size=(400, 5))
    y = np.repeat(np.arange(4), 100)
    X[y == 3, 2] = 0.0
    X = X[:334]
    y = y[:334]  # 34 loops of the last cause, as the shipped model's "other"
    model = _typicality_model(X, y)
    ref = model["typicality"]["causes"]["other"]
    assert ref["n"] == 34 and ref["threshold"] < 1000
    x = X[y == 3].mean(axis=0)
    assert atypicality(_row(model["features"], x), "other", model) < 1.0
    x[2] = 8.0
    assert atypicality(_row(model["features"], x), "other", model) > 1.0


def test_the_verdict_says_when_its_call_extrapolates():
    # The shipped model carries a reference for every cause.  A simulated loop's own
    # evidence is typical of its most likely cause; the same evidence with one
    # feature pushed 30 of its training spreads out is not, and the reading's caveat
    # says the call is an extrapolation (the probabilities are the model's, unchanged).
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.apps.family_causes import cause_loop
    from stictiondiag.stiction.cause import atypical_text
    from stictiondiag.stiction.cause_model import read_causes

    model = load_cause_model()
    assert set(model["typicality"]["causes"]) == set(CAUSES)
    v = analyze(
        cause_loop(12000009).tags(),
        config=AnalysisConfig(gap=False, replay=False, compensation=False),
    ).verdict
    reading = v.evidence.cause_probabilities
    assert reading is not None and reading.atypicality is not None
    assert not reading.atypical and atypical_text(reading) is None
    assert v.to_dict()["cause_atypicality"] == pytest.approx(reading.atypicality)
    j = model["features"].index("regularity")
    pushed = dict(v.evidence.features)
    pushed["regularity"] += 30.0 * model["typicality"]["scale"][j]
    far = read_causes(pushed, model)
    assert far is not None and far.atypical
    text = atypical_text(far)
    assert text is not None and "extrapolates" in text
    assert far.p("valve") == pytest.approx(cause_probabilities(pushed, model)["valve"])
    # The findings' probability line says so too, only for the atypical reading.
    from dataclasses import replace

    from stictiondiag.apps.findings import probability_text

    assert v.by_cause and "extrapolation" not in probability_text(v)
    flagged = replace(v, cause_probabilities=replace(reading, atypicality=2.0))
    assert "extrapolation" in probability_text(flagged)
