"""Closed-loop reproduction as evidence of the cause of a cycle, measured on simulation.

    python scripts/replay_cause_probe.py [--seed 12] [--n 250] [--offset 0] \
        [--cache replay_probe] [--real ../shared/data/isdb] [--out probe.json] \
        [--refit] [--train-seed 11 --n-train 250]

Section 6 of Choudhury, Thornhill & Shah (2005) and the replay
(:mod:`stictiondiag.replay`) offer a test of the cause of a loop's cycle: replay the
identified loop with the fitted valve, replay the same identified loop with a linear
valve, and compare both with the recorded cycle
(:mod:`stictiondiag.replay.reproduction`, its features and its call: the valve when
the fitted loop reproduces the cycle and its linear twin settles, the tuning when the
twin cycles too, an external cause when neither reproduces it).

For each loop of :mod:`stictiondiag.apps.family_causes` (seeds ``seed * 1_000_000 +
offset + i``, i < n) with a cycle and a cause, analysed as a user's file is (the
chain's head and verdict, :func:`stictiondiag.analysis.estimate_loop`), this script
prints the area under the ROC curve of each feature for "the valve causes the cycle"
against every other cause (and against each non-valve generator's loops), that of
``df_amplitude_ratio`` (the describing-function version) on the same loops, the
confusion of the call, and the cost: the two replays per loop against steps 1-4 of
the analysis, and per sample.  With ``--real``, the same features of the real records
of that folder (its manifest's sample time, loop type and integrating flag; no label
column is read), loops with a cycle only, and the Kolmogorov-Smirnov distance between
simulated and real (the shift check of ``scripts/train_cause.py``).  With
``--train-seed``, the cause model's documented gate on those training seeds and the
cause model with and without the features that pass it (:func:`model_lines`).
``--refit`` replays the refitted loop (the replay of ``analyze``) instead of the
open-loop fit: the variant measured and not taken.  Rows are cached as JSON lines
under ``--cache``.
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

from stictiondiag.analysis import estimate_loop  # noqa: E402
from stictiondiag.apps.family_causes import cause_label  # noqa: E402
from stictiondiag.apps.validation import LOOP_TYPE_MAP  # noqa: E402
from stictiondiag.core.errors import StictionError  # noqa: E402
from stictiondiag.io.tags import read_tags  # noqa: E402
from stictiondiag.replay.reproduction import (  # noqa: E402
    reproduction_call,
    reproduction_features,
)
from stictiondiag.stiction.cause import CAUSES  # noqa: E402
from stictiondiag.stiction.cause_model import apply_model  # noqa: E402
from stictiondiag.stiction.consistency import REPLAY_FEATURES as FEATURES  # noqa: E402


def head_verdict(est):
    """Step 4 without the reproduction (its cost is measured apart): the verdict the
    chain gives, its replay features left at their "no replay" values."""
    return est.verdict(with_reproduction=False)


def replay_features(est, refit: bool = False) -> tuple[dict, dict]:
    """The features of one analysed loop (its chain head ``est``) and the CPU seconds
    of each replay: :func:`~stictiondiag.replay.reproduction.reproduction_features`."""
    return reproduction_features(est.tags, est.fit, known=est.structure, refit=refit)


replay_call = reproduction_call


def _sim_one(seed: int, refit: bool = False) -> dict | None:
    try:
        loop, label = cause_label(seed)
        if label not in CAUSES:
            return None
        tags = loop.tags()
        t0 = time.process_time()
        est = estimate_loop(tags)
        v = head_verdict(est)
        t_head = time.process_time() - t0
    except StictionError:
        return None
    if v.cycle is None or not v.cycle.present:
        return None
    feats, cost = replay_features(est, refit)
    return {
        "seed": seed,
        "label": label,
        "generator": loop.truth["generator"],
        "valve": loop.truth["valve"],
        "n": int(est.tags.n),
        "df_amplitude_ratio": float(v.evidence.features["df_amplitude_ratio"]),
        "features": feats,
        "evidence": {k: float(x) for k, x in v.evidence.features.items()},
        "head_s": t_head,
        **cost,
    }


def _real_one(args: tuple[str, float, str, bool], refit: bool = False) -> dict | None:
    path, ts, loop_type, integrating = args
    try:
        tags = read_tags(path, ts=ts, loop_type=loop_type, integrating=integrating)
        est = estimate_loop(tags)
        v = head_verdict(est)
    except StictionError:
        return None
    if v.cycle is None or not v.cycle.present:
        return None
    feats, cost = replay_features(est, refit)
    return {
        "file": Path(path).name,
        "n": int(est.tags.n),
        "df_amplitude_ratio": float(v.evidence.features["df_amplitude_ratio"]),
        "features": feats,
        **cost,
    }


def _cached(path: Path, make) -> list[dict]:
    if path.is_file():
        return [json.loads(line) for line in path.read_text().splitlines() if line]
    rows = [r for r in make() if r is not None]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
    tmp.replace(path)
    return rows


def sim_rows(seed: int, n: int, offset: int, cache: Path, refit: bool = False) -> list[dict]:
    def make():
        for i in range(n):
            if (i + 1) % 25 == 0:
                print(f"  {i + 1}/{n}", file=sys.stderr, flush=True)
            yield _sim_one(seed * 1_000_000 + offset + i, refit)

    tag = "_refit" if refit else ""
    return _cached(cache / f"sim_{seed}_{offset}_{n}{tag}.jsonl", make)


def real_rows(folder: Path, cache: Path, refit: bool = False) -> list[dict]:
    import pandas as pd

    m = pd.read_csv(folder / "manifest.csv", usecols=["file", "loop_type", "integrating", "ts_s"])
    jobs = [
        (str(folder / f), float(ts), LOOP_TYPE_MAP.get(str(lt).lower(), "other"), bool(integ))
        for f, lt, integ, ts in zip(
            m["file"], m["loop_type"], m["integrating"], m["ts_s"], strict=True
        )
    ]
    tag = "_refit" if refit else ""
    return _cached(cache / f"real{tag}.jsonl", lambda: (_real_one(j, refit) for j in jobs))


#: Bootstrap resamples of the paired difference of areas, and their seed.
BOOTSTRAPS = 2000
BOOT_SEED = 0


def _auc(pos: np.ndarray, neg: np.ndarray) -> float:
    if pos.size == 0 or neg.size == 0:
        return math.nan
    gt = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(gt / (pos.size * neg.size))


def _ks(a: np.ndarray, b: np.ndarray) -> float:
    grid = np.union1d(a, b)
    fa = np.searchsorted(np.sort(a), grid, side="right") / a.size
    fb = np.searchsorted(np.sort(b), grid, side="right") / b.size
    return float(np.max(np.abs(fa - fb)))


def report(rows: list[dict], real: list[dict]) -> list[str]:
    """The tables (markdown) of the module docstring."""

    def col(rs, k):
        return np.array([float(r["features"][k] if k in r["features"] else r[k]) for r in rs])

    pos = [r for r in rows if r["label"] == "valve"]
    neg = [r for r in rows if r["label"] != "valve"]
    groups = [
        (g, [r for r in neg if r["generator"] == g])
        for g in ("tuning", "external", "quantiser", "valve")
    ]
    head = ["all others", *(f"{g} ({len(n)})" for g, n in groups)]
    lines = [
        f"{len(rows)} loops with a cycle and a cause, {len(pos)} of them the valve's.",
        "",
        f"| feature | {' | '.join(head)} | shift |",
        "|---" * (len(head) + 2) + "|",
    ]
    for k in (*FEATURES, "df_amplitude_ratio"):
        cells = [_auc(col(pos, k), col(neg, k))]
        cells += [_auc(col(pos, k), col(n, k)) for _, n in groups]
        shift = _ks(col(rows, k), col(real, k)) if real else math.nan
        lines.append(f"| `{k}` | " + " | ".join(f"{c:.2f}" for c in cells) + f" | {shift:.2f} |")
    y = np.r_[np.ones(len(pos)), np.zeros(len(neg))].astype(int)
    c = np.r_[col(pos, "replay_contrast"), col(neg, "replay_contrast")]
    d = np.r_[col(pos, "df_amplitude_ratio"), col(neg, "df_amplitude_ratio")]
    rng = np.random.default_rng(BOOT_SEED)
    diffs = []
    for _ in range(BOOTSTRAPS):
        i = rng.integers(0, y.size, y.size)
        yi = y[i]
        diffs.append(_auc(c[i][yi == 1], c[i][yi == 0]) - _auc(d[i][yi == 1], d[i][yi == 0]))
    lo, hi = np.nanpercentile(diffs, [2.5, 97.5])
    lines += [
        "",
        "Area under the ROC curve of `replay_contrast` less that of `df_amplitude_ratio`,"
        f" same loops: {_auc(c[y == 1], c[y == 0]) - _auc(d[y == 1], d[y == 0]):+.2f}"
        f" (95 % interval over {BOOTSTRAPS} bootstrap resamples of the loops"
        f" {lo:+.2f} to {hi:+.2f}).",
    ]
    lines += ["", "| true \\ replay call | valve | tuning | external |", "|---|---|---|---|"]
    for c in CAUSES:
        rs = [r for r in rows if r["label"] == c]
        calls = [replay_call(r["features"]) for r in rs]
        lines.append(
            f"| {c} ({len(rs)}) | "
            + " | ".join(str(calls.count(k)) for k in ("valve", "tuning", "external"))
            + " |"
        )
    head_s = np.array([r["head_s"] for r in rows])
    rep_s = np.array([r["replay_s"] for r in rows])
    lin_s = np.array([r["linear_s"] for r in rows])
    n = np.array([r["n"] for r in rows], dtype=float)
    both = rep_s + lin_s
    lines += [
        "",
        "Cost per loop with a cycle (CPU seconds): steps 1-4 median "
        f"{np.median(head_s):.3f}; replay median {np.median(rep_s):.3f} (90th percentile "
        f"{np.percentile(rep_s, 90):.3f}); linear twin median {np.median(lin_s):.3f}; "
        f"both over steps 1-4: median {np.median(both / head_s):.2f}; per 1000 samples: "
        f"{1000 * np.median(both / n):.3f} s (records of {int(n.min())}-{int(n.max())} "
        "samples; correlation of seconds with samples "
        f"{np.corrcoef(both, n)[0, 1]:.2f}).",
    ]
    if real:
        avail = np.mean(col(real, "replay_available"))
        lines.append(
            f"Real records with a cycle: {len(real)}; replay available on {avail:.2f}"
            f" (simulated {np.mean(col(rows, 'replay_available')):.2f}); reproduced on"
            f" {np.mean(col(real, 'replay_reproduces')):.2f} (simulated"
            f" {np.mean(col(rows, 'replay_reproduces')):.2f}); linear twin cycles on"
            f" {np.mean(col(real, 'linear_cycles')):.2f} (simulated"
            f" {np.mean(col(rows, 'linear_cycles')):.2f})."
        )
    return lines


#: The shipped cause model's penalty (``docs/calibration.md``, cause model) [-].
CAUSE_C = 0.1


def model_lines(train: list[dict], test: list[dict]) -> list[str]:
    """Would the probe's features help the cause model?  The documented gate
    (``scripts/train_cause.py``, :func:`describing_gate`: a candidate joins the
    compact set when its area under the ROC curve for the valve on the *training*
    loops lies at least 0.1 from 0.5), then the softmax model of the compact set and
    ``df_amplitude_ratio`` (the shipped set) fitted on the training loops without and
    with the features that pass, both measured on the held-out loops: accuracy of the
    most likely cause and area under the ROC curve of P(valve).  The held-out stick
    models (``HELD_OUT`` of ``scripts/train_cause.py``) are left out of both, as that
    script did when this probe was run."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from cause_fit import COMPACT, DF_SEPARATION, fit_softmax, roc_auc
    from train_cause import HELD_OUT

    train = [r for r in train if r["valve"] not in HELD_OUT and "evidence" in r]
    test = [r for r in test if r["valve"] not in HELD_OUT and "evidence" in r]
    if not train or not test:
        return []
    y_tr = np.array([r["label"] == "valve" for r in train], dtype=int)
    gate = {k: roc_auc(y_tr, np.array([r["features"][k] for r in train])) for k in FEATURES}
    joined = tuple(k for k, v in gate.items() if abs(v - 0.5) >= DF_SEPARATION)
    base = (*COMPACT, "df_amplitude_ratio")

    def xy(rows, names):
        X = np.array([[float({**r["evidence"], **r["features"]}[k]) for k in names] for r in rows])
        return X, np.array([CAUSES.index(r["label"]) for r in rows], dtype=int)

    lines = [
        "",
        f"Gate on the training loops ({len(train)}): "
        + ", ".join(f"`{k}` {v:.2f}" for k, v in gate.items())
        + f"; joined: {', '.join(joined) or 'none'}.",
        "",
        "| cause model (C = 0.1) | held-out accuracy | held-out AUC of P(valve) |",
        "|---|---|---|",
    ]
    for label, names in (("shipped set", base), ("shipped set + joined", base + joined)):
        Xtr, ytr = xy(train, names)
        Xte, yte = xy(test, names)
        P = apply_model(fit_softmax(Xtr, ytr, CAUSE_C), Xte)
        acc = float(np.mean(P.argmax(axis=1) == yte))
        auc = roc_auc((yte == 0).astype(int), P[:, 0])
        lines.append(f"| {label} ({len(names)} features) | {acc:.2f} | {auc:.2f} |")
    lines.append(f"Held-out loops (stick models {', '.join(HELD_OUT)} left out): {len(test)}.")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--n", type=int, default=250)
    ap.add_argument("--offset", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path("replay_probe"))
    ap.add_argument("--real", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--train-seed", type=int, default=None)
    ap.add_argument("--n-train", type=int, default=250)
    ap.add_argument(
        "--refit",
        action="store_true",
        help="replay the refitted loop (closed-loop refit of S, J and the process): the "
        "variant measured and not taken",
    )
    a = ap.parse_args(argv)
    t0 = time.time()
    rows = sim_rows(a.seed, a.n, a.offset, a.cache, a.refit)
    real = real_rows(a.real, a.cache, a.refit) if a.real else []
    lines = report(rows, real)
    if a.train_seed is not None:
        train = sim_rows(a.train_seed, a.n_train, 0, a.cache, a.refit)
        lines += model_lines(train, rows)
    print("\n".join(lines))
    print(f"({(time.time() - t0) / 60:.1f} min)")
    if a.out:
        a.out.write_text(json.dumps({"sim": rows, "real": real}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
