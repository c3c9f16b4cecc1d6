"""The features of the simulated loops that ``scripts/train_probability.py`` fits on,
computed once and cached.

Each loop of :mod:`stictiondiag.apps.family` (its seed, whether its valve is sticky,
whether mv is recorded, its truth) with the features of
:mod:`stictiondiag.stiction.probability` and the classic tests' statistics, cached as
JSON lines under ``--cache``, one file per seed and count; a cache of fewer loops of
the same seed is extended.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
from jobs import map_jobs

from stictiondiag.apps.family import family_loop, loop_features

#: Loops whose features each call of :func:`family_features` computed (not cached).
COMPUTED: list[int] = []


#: How long computing the features took from an empty cache, as measured (the split-half
#: fits triple the work per loop without mv).
MEASURED_RUN = (
    "Measured from scratch (empty cache) on 24 Nov 2026 on a shared two-core machine"
    " (load 3 to 7): the 1200 training loops (in halves) and the 400 held-out loops"
    " took 10 min of wall time in three one-worker processes side by side, 491 s of"
    " CPU in all, about 0.3 s of CPU per loop."
)


def _one(seed: int) -> dict | None:
    loop = family_loop(seed)
    out = loop_features(loop, with_classic=True)
    if out is None:
        return None
    feats, classic = out
    q5, q95 = np.percentile(loop.op, [5.0, 95.0])
    return {
        "seed": seed,
        "sticky": loop.sticky,
        "has_mv": loop.mv is not None,
        "features": feats,
        "classic": classic,
        "op_spread": float(q95 - q5),
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
    rows = map_jobs(_one, seeds, workers, every=50)
    done.update(zip(seeds, rows, strict=True))
    rows = [done[k] for k in sorted(done) if done[k] is not None]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
    os.replace(tmp, path)
    return rows
