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
    " (load about 10): the 1200 training loops (in thirds) and the 400 held-out loops"
    " took 12 min of wall time in four one-worker processes side by side, about 0.3 s"
    " of CPU per loop."
)

#: Width of the reliability bands [-].
BAND = 0.2

#: Largest allowed gap between a band's observed frequency and its mean prediction [-].
TOLERANCE = 0.1


def _one(seed: int) -> dict | None:
    from stictiondiag.apps.family import family_loop, loop_features

    loop = family_loop(seed)
    feats = loop_features(loop)
    if feats is None:
        return None
    return {
        "seed": seed,
        "sticky": loop.sticky,
        "has_mv": loop.mv is not None,
        "features": feats,
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


#: The split-half features (:mod:`stictiondiag.stiction.probability`), kept only if
#: they lower the cross-validated log loss on the simulated training loops.
HALVES = ("halves_s_low", "halves_s_agree", "halves_improvement", "halves_missing")


def cross_validate(
    rows: list[dict], c: float, by_cycle: bool, k: int = 5, names: tuple | None = None
) -> float:
    """k-fold cross-validated log loss of the model on the training loops [-], on the
    features ``names`` (default all of :data:`FEATURES`)."""
    from stictiondiag.stiction.probability import FEATURES, apply_part, design_row

    names_f = tuple(names or FEATURES)
    fold = np.random.default_rng(0).integers(0, k, len(rows))
    p = np.zeros(len(rows))
    y = np.array([float(r["sticky"]) for r in rows])
    X = np.array([design_row(r["features"], names_f) for r in rows])
    names = np.array([_partition(r, by_cycle) for r in rows])
    for f in range(k):
        for name in set(names):
            tr = (fold != f) & (names == name)
            te = (fold == f) & (names == name)
            if te.any():
                p[te] = apply_part(fit_logistic(X[tr], y[tr], c), X[te])
    p = np.clip(p, 1e-9, 1 - 1e-9)
    return float(-np.mean(y * np.log(p) + (1 - y) * np.log(1 - p)))


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
        "--model", type=Path, default=ROOT / "stictiondiag" / "stiction" / "probability_model.json"
    )
    ap.add_argument("--doc", type=Path, default=ROOT / "docs" / "calibration.md")
    a = ap.parse_args(argv)
    from stictiondiag.stiction.probability import FEATURES, apply_part, design_row, part_name

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
        X = np.array([design_row(r["features"]) for r in rows])
        y = np.array([float(r["sticky"]) for r in rows])
        model["parts"][name] = fit_logistic(X, y)
    cv = {
        (c, by_cycle): cross_validate(train, c, by_cycle)
        for c in (0.1, 1.0, 10.0)
        for by_cycle in (False, True)
    }
    without = tuple(k for k in FEATURES if k not in HALVES)
    for c in (0.1, 1.0, 10.0):
        cv[(c, "without halves")] = cross_validate(train, c, False, names=without)
    text = json.dumps(model, indent=1) + "\n"
    a.model.write_text(text)

    def predict(rows):
        return np.array(
            [
                float(
                    apply_part(
                        model["parts"][part_name(r["features"], r["has_mv"])],
                        design_row(r["features"]),
                    )[0]
                )
                for r in rows
            ]
        )

    p = predict(test)
    y = np.array([float(r["sticky"]) for r in test])
    table = reliability(p, y)
    ok = all(r["n"] == 0 or abs(r["observed"] - r["mean_p"]) <= TOLERANCE for r in table)
    subsets = {
        "without mv": [not r["has_mv"] for r in test],
        "with mv": [r["has_mv"] for r in test],
        "with a regular oscillation": [r["features"]["oscillating"] > 0.5 for r in test],
        "without": [r["features"]["oscillating"] < 0.5 for r in test],
    }
    doc = render(
        a, model, table, ok, p, y, subsets, len(train), len(test), time.time() - t0, t_feat, cv
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


def render(a, model, table, ok, p, y, subsets, n_train, n_test, seconds, t_feat, cv) -> str:
    from stictiondiag.stiction.probability import FEATURES
    from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

    brier = float(np.mean((p - y) ** 2))
    called = p > STICTION_LEVEL
    cleared = p < NO_STICTION_LEVEL
    lines = [
        "# Calibration of the stiction probability",
        "",
        "`P(stiction)` (`stictiondiag/stiction/probability.py`) is a regularised logistic",
        "regression of a handful of features, fitted on simulated loops only",
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
        f"--seed {a.seed} --test-seed {a.test_seed} --workers {a.workers}",
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
        "An L2-regularised logistic regression on standardised features (C = 1), one for",
        "loops with mv and one without. 5-fold cross-validated log loss on the training",
        "loops (lower is better; 0.693 is a coin):",
        "",
        "| C | two parts (mv or not) | four parts (also: regular oscillation or not) |"
        " two parts, without the split-half features |",
        "|---|---|---|---|",
        *[
            f"| {c:g} | {cv[(c, False)]:.4f} | {cv[(c, True)]:.4f} |"
            f" {cv[(c, 'without halves')]:.4f} |"
            for c in (0.1, 1.0, 10.0)
        ],
        "",
        "The four-part variant gains little and, on an earlier feature set, missed the",
        "held-out calibration (observed 0.47 against a mean prediction of 0.35 in the",
        "0.2-0.4 band); the simpler two-part model is kept.",
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
    for i, k in enumerate(FEATURES):
        lines.append(
            f"| {k} | "
            + " | ".join(f"{part['coef'][i]:+.3f}" for part in model["parts"].values())
            + " |"
        )
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
