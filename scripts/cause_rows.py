"""The analysed loops the cause model is fitted and measured on, cached as JSON lines.

* :func:`family_rows`: loops of :mod:`stictiondiag.apps.family_causes`, seeds
  ``seed * 1_000_000 + i``, each labelled by its counterfactual twins
  (:func:`~stictiondiag.apps.family_causes.cause_label`) and analysed exactly as a
  user's file is (:func:`stictiondiag.analysis.analyze` without step 5's replay);
* :func:`real_rows`: the real records of a folder with a ``manifest.csv`` (its sample
  time, loop type and integrating flag; no label column is read), analysed the same
  way.

Each row holds the verdict's features, whether stage 1 found a cycle, and (family
loops) the label and the draws that name the loop.  Used by ``scripts/train_cause.py``
and the scripts that measure its model.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

from cause_fit import cached_map


def _one(seed: int, generator: str | None = None, varying: bool = False) -> dict | None:
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.apps.family_causes import cause_label
    from stictiondiag.core.errors import StictionError

    try:
        loop, label = cause_label(seed, generator, varying_friction=varying)
        if label is None:
            return None
        a = analyze(loop.tags(), config=AnalysisConfig(gap=False, replay=False, compensation=False))
    except StictionError:
        return None
    v = a.verdict
    t = loop.truth
    return {
        "seed": seed,
        "label": label,
        "generator": t["generator"],
        "valve": t["valve"],
        "kind": t["kind"],
        "shape": t["shape"],
        "features": v.evidence.features,
        "cycle": bool(v.cycle.present) if v.cycle is not None else None,
        "direct": v.evidence.direct_stick_slip,
        "p_friction": v.evidence.p_friction,
    }


def family_rows(
    seed: int,
    n: int,
    cache: Path,
    workers: int,
    generator: str | None = None,
    varying: bool = False,
) -> list[dict]:
    """Labelled, analysed loops ``seed * 1_000_000 + i``, i < n (cached); ``generator``
    forces the generator, ``varying`` gives the sticky valves a friction that varies
    (:func:`~stictiondiag.apps.family_causes.cause_loop`)."""
    suffix = ("_" + generator if generator else "") + ("_varying" if varying else "")
    seeds = [seed * 1_000_000 + i for i in range(n)]
    one = partial(_one, generator=generator, varying=varying)
    return cached_map(cache / f"causes_{seed}_{n}{suffix}.jsonl", one, seeds, workers)


def _real_one(args: tuple[str, float, str, bool]) -> dict | None:
    from stictiondiag.analysis import AnalysisConfig, analyze
    from stictiondiag.core.errors import StictionError
    from stictiondiag.io.tags import read_tags

    path, ts, loop_type, integrating = args
    try:
        tags = read_tags(path, ts=ts, loop_type=loop_type, integrating=integrating)
        a = analyze(tags, config=AnalysisConfig(gap=False, replay=False, compensation=False))
    except StictionError:
        return None
    v = a.verdict
    return {"features": v.evidence.features, "cycle": bool(v.cycle and v.cycle.present)}


def real_jobs(folder: Path) -> list[tuple[str, float, str, bool]]:
    """Each real record of ``folder``: path, sample time, loop type and integrating
    flag from its ``manifest.csv`` (no label column is read)."""
    import pandas as pd

    from stictiondiag.apps.validation import LOOP_TYPE_MAP

    m = pd.read_csv(folder / "manifest.csv", usecols=["file", "loop_type", "integrating", "ts_s"])
    return [
        (
            str(folder / f),
            float(ts),
            LOOP_TYPE_MAP.get(str(lt).lower(), "other"),
            bool(integ),
        )
        for f, lt, integ, ts in zip(
            m["file"], m["loop_type"], m["integrating"], m["ts_s"], strict=True
        )
    ]


def real_rows(folder: Path, cache: Path, workers: int) -> list[dict]:
    """Features of the real records of ``folder`` (its manifest's sample time, loop type
    and integrating flag; labels never read), cached."""
    return cached_map(cache / "real_features.jsonl", _real_one, real_jobs(folder), workers)
