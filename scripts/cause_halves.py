"""Split-half stability of the cause model's call, on simulated and real records
(used by ``scripts/train_cause.py --halves``).

A model that decides a loop should decide each half of a long record the same way:
the halves hold the same valve, tuning and disturbance.  For every record with at
least :data:`~stictiondiag.apps.validation.SPLIT_MIN_CYCLES` cycles (the held-out
seeds' loops with a cycle, and the real records of ``--real``; no label read), each
half is analysed exactly as a user's file (:func:`stictiondiag.apps.validation.record_halves`)
and its evidence cached.  :func:`agreement` then applies any cause model to both
halves: where both halves have a cycle, stage 2's call on each (``stiction`` at
P(valve) >= :data:`~stictiondiag.stiction.verdict.VALVE_LEVEL`, ``no_stiction`` at
or below one minus it, ``undecided`` between) must be the same.  The validation
page's split-half agreement counts whole verdicts with the shipped model; this counts
stage 2's calls of any model, so that a candidate model can be held to it before any
label is read (``docs/history.md``, "Boosted trees for the cause model").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from cause_fit import cached_map

#: The analysis of a half: as the training loops' (no replay, gap or compensation).
_CONFIG = {"gap": False, "replay": False, "compensation": False}


def _halves_of(tags) -> list[dict] | None:
    """Each half's evidence (features, cycle) of a record long enough to split."""
    from stictiondiag.analysis import AnalysisConfig, analyze, find_oscillations
    from stictiondiag.apps.validation import record_halves
    from stictiondiag.core.errors import StictionError

    try:
        osc_pv, osc_op = find_oscillations(tags, [])
        period = osc_pv.period_s if osc_pv.present else osc_op.period_s
        parts = record_halves(tags, period if period else None)
    except StictionError:  # a half the analysis refuses (a stuck or saturated op)
        return None
    if parts is None:
        return None
    out = []
    for part in parts:
        try:
            v = analyze(part, config=AnalysisConfig(**_CONFIG)).verdict
        except StictionError:
            return None
        out.append({"features": v.evidence.features, "cycle": bool(v.cycle and v.cycle.present)})
    return out


def _family_one(args: tuple[int, bool]) -> dict | None:
    from stictiondiag.apps.family_causes import cause_loop

    seed, varying = args
    halves = _halves_of(cause_loop(seed, varying_friction=varying).tags())
    return None if halves is None else {"seed": seed, "halves": halves}


def _real_one(args: tuple[str, float, str, bool]) -> dict | None:
    from stictiondiag.core.errors import StictionError
    from stictiondiag.io.tags import read_tags

    path, ts, loop_type, integrating = args
    try:
        tags = read_tags(path, ts=ts, loop_type=loop_type, integrating=integrating)
    except StictionError:
        return None
    halves = _halves_of(tags)
    return None if halves is None else {"record": Path(path).name, "halves": halves}


def family_halves(seed: int, rows: list[dict], cache: Path, workers: int) -> list[dict]:
    """The halves of the loops among ``rows`` (one seed's cache rows) that have a
    cycle, cached by seed."""
    jobs = [(int(r["seed"]), False) for r in rows if r["cycle"]]
    return cached_map(cache / f"halves_{seed}_{len(rows)}.jsonl", _family_one, jobs, workers)


def real_halves(jobs: list[tuple[str, float, str, bool]], cache: Path, workers: int):
    """The halves of the real records of ``jobs`` (path, sample time, loop type,
    integrating flag; no label), cached."""
    return cached_map(cache / "real_halves.jsonl", _real_one, jobs, workers)


def agreement(model: dict, records: list[dict]) -> tuple[int, int]:
    """Records whose two halves both have a cycle, and how many of them get the same
    stage-2 call from ``model`` (module docstring)."""
    from stictiondiag.stiction.cause_model import apply_model
    from stictiondiag.stiction.verdict import VALVE_LEVEL

    both = [r for r in records if all(h["cycle"] for h in r["halves"])]
    if not both:
        return 0, 0
    names = tuple(model["features"])
    X = np.array([[float(h["features"][k]) for k in names] for r in both for h in r["halves"]])
    p = apply_model(model, X)[:, 0]
    call = np.where(p >= VALVE_LEVEL, 1, np.where(p <= 1.0 - VALVE_LEVEL, -1, 0))
    return len(both), int(np.sum(call[0::2] == call[1::2]))
