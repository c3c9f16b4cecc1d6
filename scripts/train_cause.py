"""Fit the cause model of stage 2 on simulated loops labelled by counterfactual twins.

    python scripts/train_cause.py [--n-train 400] [--n-test 200] [--seed 11 [16 ...]] \
        [--test-seed 12 [13 ...]] [--cache /tmp/stiction_causes] [--workers 1] \
        [--real ../shared/data/isdb] [--doc docs/calibration.md] [--no-describing] \
        [--no-replay] [--deadzone 0] [--varying-friction] [--halves] [--mix-varying] \
        [--kind softmax]

1. Draws ``--n-train`` and ``--n-test`` loops of :mod:`stictiondiag.apps.family_causes`
   (seeds ``seed * 1_000_000 + i``), labels each by its counterfactual twins
   (:func:`~stictiondiag.apps.family_causes.cause_label`) and analyses it exactly as a
   user's file is analysed (:func:`stictiondiag.analysis.analyze` without step 5's
   replay: the loop-type step, the oscillation test, the fit, the evidence with the
   verdict's own closed-loop reproduction); the verdict's
   features are the model's inputs.  Cached as JSON lines under ``--cache``.
2. **Shift check**: with ``--real``, the same features of the real records in that
   folder (its ``manifest.csv`` gives each file's sample time, loop type and
   integrating flag; no label column is read), restricted to the loops with a cycle,
   are compared with those of the simulated loops with a cycle by the two-sample
   Kolmogorov-Smirnov distance.  A feature whose distance exceeds
   :data:`MAX_SHIFT` is dropped (the rule was stated before any distance was seen).
3. Chooses the features (the compact set, :data:`cause_fit.COMPACT`, plus the describing-function
   features and the closed-loop reproduction features that separate on the training
   loops, :func:`describing_gate`; the full set
   if cross-validation favours it, :func:`choose_features`; ``--no-describing`` leaves
   the describing-function features out, ``--no-replay`` the reproduction features,
   the models before them), then
   fits the model on the training loops with a cycle and a cause, every stick model
   included: a softmax regression (``--kind softmax``, the default and the model
   that ships; L2, penalty by the same cross-validation as the features),
   gradient-boosted trees (``--kind boosted``; rounds by cross-validation,
   :func:`cause_fit.cv_boosted`; scikit-learn is needed here only) or the mean of
   both (``--kind mean``), and each cause's reference for the typicality check
   (:func:`cause_fit.fit_typicality`); writes
   ``stictiondiag/stiction/cause_model.json``.  The held-out-generator check refits
   the same model once per stick model of :data:`HELD_OUT` (the Karnopp physical
   valve, He et al.'s model, the band-hold valve) without that model's loops, and
   tests it on them (:func:`cause_fit.leave_one_out`).
4. Measures, on the held-out loops: accuracy, confusion, the reliability of each
   cause's probability (bands of :data:`BAND`, each within :data:`TOLERANCE` of its
   observed frequency where it holds at least :data:`MIN_BAND` loops), the held-out
   generator's accuracy; with ``--varying-friction``, accuracy, area and reliability
   on the held-out seeds' loops again with a friction that varies, which the model
   never saw; with ``--halves``, how often the two halves of a long record get the
   same call (:mod:`cause_halves`, on the held-out seeds and the real records); and
   stage 1 (how many loops without a cycle the direct
   stick-slip rule calls stiction, sticky and healthy).  Prints the section of
   ``docs/calibration.md`` and, with ``--doc``, replaces it there.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from cause_fit import (  # noqa: E402
    BAND,
    BOOST_L2,
    BOOST_MIN_LEAF,
    BOOST_RATE,
    C_GRID,
    DF_SEPARATION,
    FOLDS,
    GATE_SE,
    GATED,
    MIN_BAND,
    TOLERANCE,
    TYPICAL_QUANTILE,
    TYPICAL_SHRINK,
    choose_features,
    cv_boosted,
    describing_gate,
    expected_outside,
    fit_boosted,
    fit_mean,
    fit_softmax,
    fit_typicality,
    ks_distance,
    leave_one_out,
    refitter,
    reliability,
    roc_auc,
    xy,
)
from cause_rows import family_rows, real_jobs, real_rows  # noqa: E402

from stictiondiag.stiction.cause import CAUSES  # noqa: E402

# The describing-function consistency (stictiondiag.stiction.consistency) and the
# closed-loop reproduction (stictiondiag.replay.reproduction), the two versions of
# Section 6's check: candidates for the compact set through describing_gate, measured
# in the table this script writes.
from stictiondiag.stiction.consistency import FEATURES as DF_FEATURES  # noqa: E402
from stictiondiag.stiction.consistency import REPLAY_FEATURES  # noqa: E402

#: Largest Kolmogorov-Smirnov distance between simulated and real loops with a cycle
#: for a feature to enter the model [-].
MAX_SHIFT = 0.5
#: The stick models each left out of one refit, whose loops then measure the model's
#: generality (:func:`cause_fit.leave_one_out`): Karnopp's physical valve, the one
#: stick model not written as a data-driven rule, and He et al.'s and the band-hold
#: valve.  The model that ships is trained on every stick model.
HELD_OUT: tuple[str, ...] = ("physical", "he", "band")
#: How long computing the features took from an empty cache, as measured.
MEASURED_RUN = (
    "measured on 27 Nov 2026, after the cycle's amplitude lock joined the evidence (every"
    " loop, the 77 real records included, from an empty cache in 13.7 min of wall time"
    " with `--workers 2`), on a shared two-core machine"
)

#: Heading of the section this script writes in docs/calibration.md.
HEADING = "## Why the loop oscillates: the cause model"


def _confusion(P: np.ndarray, y: np.ndarray) -> list[str]:
    lines = ["| true \\ called | " + " | ".join(CAUSES) + " |", "|---" * (len(CAUSES) + 1) + "|"]
    called = P.argmax(axis=1)
    for j, cause in enumerate(CAUSES):
        counts = [int(((y == j) & (called == k)).sum()) for k in range(len(CAUSES))]
        lines.append(f"| {cause} | " + " | ".join(str(c) for c in counts) + " |")
    return lines


def candidate_features(describing: bool = True, replay: bool = True) -> tuple[str, ...]:
    """The evidence the cause model may use: every feature of the friction model's
    candidates (:data:`stictiondiag.stiction.probability.CANDIDATES`) that describes
    a loop without its valve position (the cause family records no mv) and is not a
    stage-1 flag (``oscillating``, ``short_record``: every loop of stage 2 has a cycle),
    with ``describing`` the describing-function consistency
    (:data:`stictiondiag.stiction.consistency.FEATURES`) and with ``replay`` the
    closed-loop reproduction (:data:`stictiondiag.stiction.consistency.REPLAY_FEATURES`)."""
    from stictiondiag.stiction.probability import CANDIDATES

    base = tuple(k for k in CANDIDATES if k not in ("oscillating", "short_record"))
    return base + (DF_FEATURES if describing else ()) + (REPLAY_FEATURES if replay else ())


def df_separation(
    test: list[dict], held: list[dict], sim: list[dict], real: list[dict]
) -> list[str]:
    """Table of each describing-function feature: the area under the ROC curve of
    "the valve causes the cycle" (higher value, more likely the valve) on the held-out
    seeds, against every other cause and against the loops of each non-valve
    generator; on the held-out stick models' valve loops against the same negatives;
    and the shift check's distance (simulated against real loops with a cycle)."""

    def col(rows, k):
        return np.array([float(r["features"][k]) for r in rows])

    pos = [r for r in test if r["label"] == "valve"]
    neg = [r for r in test if r["label"] != "valve"]
    held_pos = [r for r in held if r["label"] == "valve"]
    groups = [
        ("tuning", [r for r in neg if r["generator"] == "tuning"]),
        ("external", [r for r in neg if r["generator"] == "external"]),
        ("quantiser", [r for r in neg if r["generator"] == "quantiser"]),
        ("valve, not the valve's cycle", [r for r in neg if r["generator"] == "valve"]),
    ]

    def auc(p, n, k):
        if not p or not n:
            return math.nan
        y = np.r_[np.ones(len(p)), np.zeros(len(n))]
        return roc_auc(y.astype(int), np.r_[col(p, k), col(n, k)])

    head = ["all others", *(f"{g} ({len(n)})" for g, n in groups)]
    lines = [
        f"| feature | {' | '.join(head)} | held-out stick models | shift |",
        "|---" * (len(head) + 3) + "|",
    ]
    for k in (k for k in GATED if sim and k in sim[0]["features"]):
        cells = [auc(pos, neg, k), *(auc(pos, n, k) for _, n in groups), auc(held_pos, neg, k)]
        shift = ks_distance(col(sim, k), col(real, k)) if real else math.nan
        lines.append(f"| `{k}` | " + " | ".join(f"{c:.2f}" for c in cells) + f" | {shift:.2f} |")
    share = np.mean(col(real, "df_available")) if real else math.nan
    lines += [
        "",
        f"Positives: {len(pos)} held-out loops whose cycle a linear valve stops;"
        f" {len(held_pos)} of the held-out stick models. Share of loops with a cycle where"
        f" the loop could be identified (`df_available`): simulated"
        f" {np.mean(col(sim, 'df_available')):.2f}, real {share:.2f}.",
    ]
    return lines


#: Heading and words of the Section 6 table.
DF_INTRO = [
    "**Describing-function consistency, closed-loop reproduction and the amplitude lock**"
    " (Section 6, `stictiondiag/stiction/consistency.py`,"
    " `stictiondiag/replay/reproduction.py`; the lock in"
    " `stictiondiag/stiction/probability_evidence.py`):"
    ' area under the ROC curve of each feature for "the valve causes the cycle" on the'
    " held-out seeds' loops with a cycle and a cause, against all other causes and against"
    " the non-valve loops of each generator (how many in brackets); the held-out stick"
    " models' valve loops against the same negatives; above 0.5 a higher value means the"
    " valve, below 0.5 the other way round. Shift: Kolmogorov-Smirnov distance between the"
    " simulated and the real loops with a cycle (labels not read).",
    "",
]

#: Seed block of the dead-zone loops (generator forced, never trained on).
DEADZONE_SEED = 50


def held_out_lines(model: dict, names: tuple[str, ...], logo: list, a) -> list[str]:
    """Accuracy on each held-out stick model's loops (``logo``: the refits of
    :func:`cause_fit.leave_one_out`, each without that stick model), and of ``model``
    on ``--deadzone`` integrating loops whose controller has a dead zone, a generator
    never trained on (label counts and accuracy)."""
    from collections import Counter

    from stictiondiag.stiction.cause_model import apply_model

    lines = [
        "**Held-out generators one by one** (loops with a cycle and a cause, all seeds;"
        " each stick model by the refit that left it out):",
        "",
        "| generator | loops | accuracy | called valve, of the valve's cycles |",
        "|---|---|---|---|",
    ]
    groups = [(f"stick model `{m}`", rows, P) for m, rows, P in logo]
    dz_rows: list[dict] = []
    if a.deadzone:
        dz_rows = family_rows(DEADZONE_SEED, a.deadzone, a.cache, a.workers, "deadzone")
        rows = [r for r in dz_rows if r["label"] in CAUSES and r["cycle"]]
        P = apply_model(model, xy(rows, names)[0]) if rows else np.zeros((0, len(CAUSES)))
        groups.append(("integrating, controller dead zone", rows, P))
    for name, rows, P in groups:
        if not rows:
            lines.append(f"| {name} | 0 | - | - |")
            continue
        y = xy(rows, names)[1]
        called = P.argmax(axis=1)
        v = CAUSES.index("valve")
        nv = int((y == v).sum())
        hit_v = int(((y == v) & (called == v)).sum())
        lines.append(
            f"| {name} | {len(rows)} | {np.mean(called == y):.2f} | "
            + (f"{hit_v} of {nv} |" if nv else "- |")
        )
    if a.deadzone:
        counts = Counter(r["label"] for r in dz_rows)
        lines += [
            "",
            f"Dead-zone loops (`--deadzone {a.deadzone}`: seeds {DEADZONE_SEED}*1e6 + i,"
            f' `generator="deadzone"`, {len(dz_rows)} analysed), labels: '
            + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
            + ".",
        ]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-train", type=int, default=400)
    ap.add_argument("--n-test", type=int, default=200)
    ap.add_argument(
        "--seed", type=int, nargs="+", default=[11], help="training seeds, --n-train loops of each"
    )
    ap.add_argument(
        "--test-seed",
        type=int,
        nargs="+",
        default=[12],
        help="held-out seeds, --n-test loops of each",
    )
    ap.add_argument("--cache", type=Path, default=Path("/tmp/stiction_causes"))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--real", type=Path, default=None)
    ap.add_argument("--doc", type=Path, default=None)
    ap.add_argument(
        "--deadzone",
        type=int,
        default=0,
        help="also measure the model on this many integrating loops with a controller dead zone",
    )
    ap.add_argument(
        "--kind",
        choices=("softmax", "boosted", "mean"),
        default="softmax",
        help="the model: softmax regression (shipped), boosted trees, or the mean of both (docs/history.md)",
    )
    ap.add_argument(
        "--mix-varying",
        action="store_true",
        help="train on every training loop twice, with a constant and a varying friction",
    )
    ap.add_argument(
        "--halves",
        action="store_true",
        help="also measure how often the two halves of a long record get the same call",
    )
    ap.add_argument(
        "--varying-friction",
        action="store_true",
        help="also measure the model on the held-out seeds with a friction that varies",
    )
    ap.add_argument(
        "--no-describing",
        action="store_true",
        help="leave the describing-function features out (the model before them)",
    )
    ap.add_argument(
        "--no-replay",
        action="store_true",
        help="leave the closed-loop reproduction features out (the model before them)",
    )
    ap.add_argument(
        "--out", type=Path, default=ROOT / "stictiondiag" / "stiction" / "cause_model.json"
    )
    a = ap.parse_args(argv)
    t0 = time.time()
    train_all = [
        r
        for s in a.seed
        for varying in ((False, True) if a.mix_varying else (False,))
        for r in family_rows(s, a.n_train, a.cache, a.workers, varying=varying)
    ]
    test_all = [r for s in a.test_seed for r in family_rows(s, a.n_test, a.cache, a.workers)]
    t_feat = time.time() - t0

    def labelled(rows):
        return [r for r in rows if r["label"] in CAUSES and r["cycle"]]

    train, test = labelled(train_all), labelled(test_all)
    names = candidate_features(not a.no_describing, not a.no_replay)

    # Shift check (unlabelled real records).
    shift: dict[str, float] = {}
    real: list[dict] = []
    sim = [r for r in train_all + test_all if r["cycle"]]
    if a.real is not None:
        real = [r for r in real_rows(a.real, a.cache, a.workers) if r["cycle"]]
        for k in names:
            shift[k] = ks_distance(
                np.array([float(r["features"][k]) for r in sim]),
                np.array([float(r["features"][k]) for r in real]),
            )
    kept = tuple(k for k in names if shift.get(k, 0.0) <= MAX_SHIFT)
    X, y = xy(train, kept)
    sd = X.std(axis=0)
    kept = tuple(k for k, s in zip(kept, sd, strict=True) if s > 0)
    compact, df_gate = describing_gate(train, kept, not (a.no_describing and a.no_replay))
    kept, cv = choose_features(train, kept, compact)
    cv["df_gate"] = df_gate
    X, y = xy(train, kept)
    if a.kind == "softmax":
        fitted = {
            "kind": "softmax regression of the causes of a loop's cycle",
            "C": cv["c"],
            **fit_softmax(X, y, cv["c"]),
        }
    else:
        cv["boost"] = cv_boosted(train, kept)
        best = cv["boost"]["best"]
        fitted = fit_mean(X, y, cv["c"], *best) if a.kind == "mean" else fit_boosted(X, y, *best)
    fitted.pop("classes", None)
    kind = fitted.pop("kind")
    settings = {k: fitted.pop(k) for k in ("C", "rounds", "leaves") if k in fitted}
    model = {
        "kind": kind,
        "classes": list(CAUSES),
        "features": list(kept),
        **settings,
        "trained_on_stick_models": "all; each of these left out of one refit",
        "left_out_in_refits": list(HELD_OUT),
        "n_train": len(train),
        "trained_on": "stictiondiag.apps.family_causes seeds "
        + ", ".join(f"{s}*1e6 + i" for s in a.seed)
        + f", i < {a.n_train}"
        + (", each with a constant and a varying friction" if a.mix_varying else ""),
        **fitted,
        "typicality": fit_typicality(X, y),
    }
    from stictiondiag.stiction.cause_model import apply_model

    # Trees are thousands of nodes: one line, not one line a number.
    a.out.write_text(json.dumps(model, indent=None if a.kind != "softmax" else 1) + "\n")
    Xt, yt = xy(test, kept)
    Pt = apply_model(model, Xt)
    logo = leave_one_out(train, train + test, kept, refitter(model), HELD_OUT)
    held = [r for _, rows, _ in logo for r in rows]
    yh = np.array([CAUSES.index(r["label"]) for r in held], dtype=int)
    Ph = np.vstack([P for _, _, P in logo]) if held else np.zeros((0, len(CAUSES)))
    text = render(
        a, model, train, test, held, train_all + test_all, Pt, yt, Ph, yh, shift, t_feat, cv
    )
    text += "\n" + "\n".join(held_out_lines(model, kept, logo, a)) + "\n"
    # The held-out seeds again with a friction that varies (never trained on).
    varying = (
        labelled(
            r
            for s in a.test_seed
            for r in family_rows(s, a.n_test, a.cache, a.workers, varying=True)
        )
        if a.varying_friction
        else []
    )
    if varying:
        text += "\n" + "\n".join(varying_lines(model, kept, varying, Pt, yt)) + "\n"
    text += "\n" + "\n".join(typicality_lines(model, test, varying, real)) + "\n"
    if a.halves:
        text += "\n" + halves_text(model, a) + "\n"
    text += "\n" + "\n".join(DF_INTRO + df_separation(test, held, sim, real)) + "\n"
    print(text)
    if a.doc is not None:
        doc = a.doc.read_text()
        start = doc.find(HEADING)
        if start < 0:
            doc = doc.rstrip() + "\n\n" + text
        else:
            nxt = doc.find("\n## ", start + len(HEADING))
            rest = "\n" + doc[nxt + 1 :] if nxt >= 0 else ""
            doc = doc[:start] + text.rstrip("\n") + "\n" + rest
        a.doc.write_text(doc)
    return 0


def varying_lines(
    model: dict, names: tuple[str, ...], rows: list[dict], Pt: np.ndarray, yt: np.ndarray
) -> list[str]:
    """``model`` on the held-out seeds' loops again (``rows``, with a cycle and a
    cause), with a friction that varies over time and with the direction of travel
    (``--varying-friction``: :data:`~stictiondiag.apps.family_causes.FRICTION_VARIATION`),
    an effect it was never trained on, beside its scores on the same seeds with
    constant friction (``Pt``, ``yt``)."""
    from stictiondiag.apps.family_causes import FRICTION_VARIATION as V
    from stictiondiag.stiction.cause_model import apply_model

    X, y = xy(rows, names)
    P = apply_model(model, X)
    v = CAUSES.index("valve")
    lines = [
        "**Held-out seeds with a friction that varies** (`--varying-friction`: the same"
        f" seeds, each sticky valve but the physical one with S and J scaled by"
        f" exp(sigma w(t)), sigma up to {V.spread}, w a slow random signal of"
        f" {V.time[0]:g}-{V.time[1]:g} loop time scales, and by 1 +- a with the"
        f" direction of travel, |a| up to {V.asymmetry}; external triangles lean by up"
        f" to {V.triangle}; never trained on):",
        "",
        "| friction | loops | accuracy | area under the ROC curve of P(valve) |"
        " reliability bands outside 0.1 |",
        "|---|---|---|---|---|",
    ]
    for name, PP, yy in (("constant", Pt, yt), ("varying", P, y)):
        bands = [b for b in reliability(PP, yy) if b[4] >= MIN_BAND]
        out = sum(not b[5] for b in bands)
        lines.append(
            f"| {name} | {yy.size} | {np.mean(PP.argmax(axis=1) == yy):.2f} |"
            f" {roc_auc((yy == v).astype(int), PP[:, v]):.2f} |"
            f" {out} of {len(bands)} ({expected_outside(bands):.1f} by chance) |"
        )
    return lines


def typicality_lines(
    model: dict, test: list[dict], varying: list[dict], real: list[dict]
) -> list[str]:
    """How often the held-out loops (``test``, with a constant friction, and
    ``varying``, the same seeds with a varying one, if measured) and the real records
    lie outside 99 % of the training loops of their most likely cause
    (:func:`stictiondiag.stiction.cause_model.atypicality`), and the accuracy of the
    most likely cause on either side (simulated loops only: no real label is read)."""
    from stictiondiag.stiction.cause_model import read_causes

    def split(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
        far, right = [], []
        for r in rows:
            reading = read_causes(r["features"], model)
            assert reading is not None
            far.append(reading.atypical)
            right.append(reading.ranked()[0].value == r.get("label"))
        return np.array(far, dtype=bool), np.array(right, dtype=bool)

    groups = [("held-out seeds, constant friction", test)]
    if varying:
        groups.append(("held-out seeds, varying friction", varying))
    lines = [
        "**Is the record like the loops its cause was learnt from?** (the typicality"
        " check, `stictiondiag.stiction.cause_model.atypicality`): a loop is atypical"
        " when its squared Mahalanobis distance to the training loops of its most"
        " likely cause (standardised features, covariance shrunk by"
        f" {TYPICAL_SHRINK:g} towards the identity) exceeds the"
        f" {100 * TYPICAL_QUANTILE:g}th percentile of theirs, each measured out of"
        " fold; the verdict then says"
        " that its call is an extrapolation, and does not change.",
        "",
        "| loops with a cycle | loops | atypical | accuracy, atypical | accuracy, others |",
        "|---|---|---|---|---|",
    ]
    for name, rows in groups:
        far, right = split(rows)
        acc_far = f"{np.mean(right[far]):.2f}" if far.any() else "-"
        lines.append(
            f"| {name} | {far.size} | {int(far.sum())} ({np.mean(far):.1%}) | {acc_far}"
            f" | {np.mean(right[~far]):.2f} |"
        )
    if real:
        far, _ = split(real)
        lines.append(
            f"| real records (labels not read) | {far.size} |"
            f" {int(far.sum())} ({np.mean(far):.1%}) | - | - |"
        )
    return lines


def halves_text(model: dict, a) -> str:
    """The split-half stability of ``model``'s stage-2 call (``--halves``,
    :mod:`cause_halves`) on the held-out seeds' records and the real ones."""
    from cause_halves import agreement, family_halves, real_halves

    from stictiondiag.apps.validation import SPLIT_MIN_CYCLES

    sim = [
        r
        for s in a.test_seed
        for r in family_halves(s, family_rows(s, a.n_test, a.cache, a.workers), a.cache, a.workers)
    ]
    n_s, k_s = agreement(model, sim)
    text = (
        "**Split-half stability** (`--halves`, no label read; `scripts/cause_halves.py`):"
        f" of the records with at least {SPLIT_MIN_CYCLES:g} cycles whose two halves both"
        " have a cycle, each half analysed on its own, the cause model's call on the two"
        f" halves (P(valve) at or above 0.6, at or below 0.4, or between) agrees on {k_s}"
        f" of {n_s} held-out simulated records ({k_s / max(n_s, 1):.2f})"
    )
    if a.real is not None:
        n_r, k_r = agreement(model, real_halves(real_jobs(a.real), a.cache, a.workers))
        text += f" and on {k_r} of {n_r} real records ({k_r / max(n_r, 1):.2f})"
    return text + "."


def _gate_text(g: dict | None) -> str:
    if g is None:
        return ""
    aucs = ", ".join(f"`{k}` {v:.2f}" for k, v in g["auc"].items())
    joined = ", ".join(f"`{k}`" for k in g["joined"]) or "none"
    return (
        f" Section 6 features (describing function, closed-loop reproduction) and the"
        f" cycle's amplitude lock join the"
        f" compact set when their area under the"
        f" ROC curve for the valve on the training loops is at least {DF_SEPARATION:g}"
        f" from 0.5 ({aucs}): joined {joined}. Cross-validated log loss of the compact set"
        f" {g['compact']:.3f} without them, {g['with_df']:.3f} with them (standard error of"
        f" the paired difference {g['se']:.3f})."
    )


def _kind_text(model: dict, cv: dict) -> str:
    """How the model that ships was fitted, in words."""
    if model["kind"] == "mean":
        soft, boost = model["members"]
        return (
            " the mean of two models' probabilities over the same features: a softmax"
            f" regression, L2 with C = {soft['C']:g}, and" + _kind_text(boost, cv)
        )
    if model["kind"] != "boosted":
        return f" softmax regression, L2 with C = {model['C']:g}."
    losses = ", ".join(
        f"{r} rounds of {lv} leaves {v:.3f}" for (r, lv), v in cv["boost"]["losses"].items()
    )
    return (
        " gradient-boosted trees (scikit-learn's histogram gradient boosting on the log"
        f" loss, learning rate {BOOST_RATE:g}, L2 {BOOST_L2:g} on the leaves, at least"
        f" {BOOST_MIN_LEAF} loops a leaf; exported as node arrays, `cause_model.py`):"
        f" {model['rounds']} rounds of trees of {model['leaves']} leaves, the setting"
        f" with the lowest {FOLDS}-fold cross-validated log loss ({losses})."
    )


def _intro(a, t_feat: float) -> list[str]:
    """The section's heading, how it was written, and what stage 2 decides."""
    return [
        HEADING,
        "",
        "Written by `scripts/train_cause.py` "
        f"(`--n-train {a.n_train} --n-test {a.n_test} --seed {' '.join(map(str, a.seed))}"
        f" --test-seed {' '.join(map(str, a.test_seed))}"
        + (" --real $STICTION_ISDB" if a.real else "")
        + (" --no-describing" if a.no_describing else "")
        + (" --no-replay" if a.no_replay else "")
        + (f" --deadzone {a.deadzone}" if a.deadzone else "")
        + (f" --kind {a.kind}" if a.kind != "softmax" else "")
        + (" --varying-friction" if a.varying_friction else "")
        + (" --halves" if a.halves else "")
        + (" --mix-varying" if a.mix_varying else "")
        + f"`; features of all loops {MEASURED_RUN}; this run {t_feat / 60:.1f} min).",
        "",
        "Stage 2 of the verdict (`stictiondiag/stiction/cause.py`, `cause_model.py`): for a"
        " loop with a cycle and without mv, one probability per cause of the cycle, and the"
        " verdict: `stiction` when P(valve) >= 0.6, `no_stiction` when <= 0.4"
        " (`stictiondiag.stiction.verdict.VALVE_LEVEL`), `inconclusive` between. Why this"
        " probability, and not the friction model's P(stiction), decides a loop with a cycle:"
        " [below](#which-probability-decides-a-loop-with-a-cycle)."
        + (
            " The describing-function consistency of Section 6 is left out of this run"
            " (`--no-describing`)."
            if a.no_describing
            else " The describing-function consistency of Section 6 (do the identified loop"
            " and the fitted S, J predict the observed cycle?) is among the candidates and in"
            " the compact set (its table below)."
        )
        + (
            ""
            if a.no_replay
            else " So is its version by simulation, the closed-loop reproduction (does the"
            " identified loop replayed with the fitted S, J reproduce the cycle, and does the"
            " same loop with a linear valve settle?), by the same gate."
        ),
        "",
    ]


def render(a, model, train, test, held, all_rows, Pt, yt, Ph, yh, shift, t_feat, cv) -> str:
    from collections import Counter

    acc = float(np.mean(Pt.argmax(axis=1) == yt)) if yt.size else math.nan
    acc_h = float(np.mean(Ph.argmax(axis=1) == yh)) if yh.size else math.nan
    valve = CAUSES.index("valve")
    auc = roc_auc((yt == valve).astype(int), Pt[:, valve])
    auc_h = roc_auc((yh == valve).astype(int), Ph[:, valve]) if yh.size else math.nan
    rel = reliability(Pt, yt)
    counted = [r for r in rel if r[4] >= MIN_BAND]
    ok = all(r[5] for r in counted)
    labels = Counter((r["generator"], r["label"]) for r in all_rows)
    lines = [
        *_intro(a, t_feat),
        "Loops of `stictiondiag/apps/family_causes.py`, each analysed exactly as a user's"
        " file (`analyze` without step 5's replay and the gap; the verdict's own"
        " reproduction replay runs), labelled by the counterfactual twin that"
        " stops the cycle (`none`: no cycle; `unexplained`: no single change stops it, left"
        " out). Loops by generator and label (training and held-out seeds):",
        "",
        "| generator | " + " | ".join(["none", *CAUSES, "unexplained"]) + " |",
        "|---" * (len(CAUSES) + 3) + "|",
    ]
    for g in sorted({r["generator"] for r in all_rows}):
        lines.append(
            f"| {g} | "
            + " | ".join(str(labels.get((g, c), 0)) for c in ["none", *CAUSES, "unexplained"])
            + " |"
        )
    lines += [
        "",
        f"Trained on {len(train)} loops with a cycle and a cause (every stick model),"
        + _kind_text(model, cv)
        + f" Features: {', '.join('`' + k + '`' for k in model['features'])}, chosen by"
        f" {FOLDS}-fold cross-validation of the softmax regression on the training loops:"
        f" log loss {cv['full']:.3f}"
        f" with every feature that passed the shift check, {cv['compact']:.3f} with the"
        f" compact set (standard error of the paired difference {cv['se']:.3f}); the"
        f" larger set ships only if it wins by more than {GATE_SE:g} standard errors."
        f" The penalty C by the same cross-validation over {', '.join(f'{c:g}' for c in C_GRID)}"
        f" (log loss {', '.join(f'{v:.3f}' for v in cv['by_c'].values())}): C = {cv['c']:g}."
        + _gate_text(cv.get("df_gate")),
        "",
        f"**Held-out seeds** ({len(test)} loops with a cycle and a cause): accuracy of the"
        f" most likely cause {acc:.2f}; area under the ROC curve of P(valve) {auc:.2f}.",
        "",
        *_confusion(Pt, yt),
        "",
        f"**Held-out generators** (stick models {', '.join(f'`{m}`' for m in HELD_OUT)},"
        f" {len(held)} loops with a cycle and a cause, each by a refit of the same features"
        " and settings without that stick model's loops, so never trained on): accuracy"
        f" {acc_h:.2f}, area under the ROC curve of P(valve) {auc_h:.2f}; each stick model"
        " and the dead-zone loops after the reliability table.",
        "",
        *(_confusion(Ph, yh) if yh.size else []),
        "",
        f"**Reliability of stage 2** on the held-out seeds (bands of {BAND:g}; a band of at"
        f" least {MIN_BAND} loops must lie within {TOLERANCE:g} of its observed frequency):"
        f" {'all within' if ok else 'NOT all within'} ({sum(not r[5] for r in counted)} of"
        f" {len(counted)} outside). A perfectly calibrated model would leave"
        f" {expected_outside(counted):.1f} of these bands outside on average, by the"
        " binomial spread of as many loops (`expected_outside` in this script), and all within"
        " only rarely: the tolerance is near the sampling noise of a band.",
        "",
        "| cause | band | mean P | observed | loops | within |",
        "|---|---|---|---|---|---|",
    ]
    for cause, lo, mp, ob, n, w in rel:
        flag = ("yes" if w else "no") if n >= MIN_BAND else "(too few)"
        lines.append(f"| {cause} | {lo:.1f}-{lo + BAND:.1f} | {mp:.2f} | {ob:.2f} | {n} | {flag} |")
    no_cycle = [r for r in all_rows if r["cycle"] is False]
    sticky = [r for r in no_cycle if r["valve"] != "linear"]
    healthy = [r for r in no_cycle if r["valve"] == "linear"]
    lines += [
        "",
        f"**Stage 1** (loops without a cycle, {len(no_cycle)}): the direct stick-slip rule"
        f" called {sum(bool(r['direct']) for r in sticky)} of {len(sticky)} sticky loops and"
        f" {sum(bool(r['direct']) for r in healthy)} of {len(healthy)} healthy loops `stiction`;"
        ' the rest are `no_stiction` with the reason "no limit cycle" (no mv is recorded in'
        " this family; with mv, see the friction family above).",
    ]
    if shift:
        lines += [
            "",
            f"**Shift check** (Kolmogorov-Smirnov distance between the simulated loops with a"
            f" cycle and the real records with a cycle, labels not read; dropped above"
            f" {MAX_SHIFT:g}):",
            "",
            "| feature | distance | passed | in the model |",
            "|---|---|---|---|",
        ]
        for k, d in sorted(shift.items(), key=lambda kv: -kv[1]):
            passed = "yes" if d <= MAX_SHIFT else "no (dropped)"
            used = "yes" if k in model["features"] else "no"
            lines.append(f"| `{k}` | {d:.2f} | {passed} | {used} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
