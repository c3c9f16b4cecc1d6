"""Plant-wide benchmark: simulated plants, scanned from their files, scored.

Each plant comes from :func:`stictiondiag.models.synthetic_plant.generate_plant`
(seeds ``seed, seed + 1, ...``), is written as one wide export
(``plant_<seed>/plant.csv``: ``time, FIC101.PV, FIC101.OP, FIC101.SP, ...``) and is
scanned as a user would (:func:`stictiondiag.apps.scan.scan`, gap diagnosis off):
every loop's own analysis, then the plant-wide step.  The scorer reads the scan's
table and ``plantwide.json`` and compares them with the truth, which the scan
never sees.

Scores
------
* **membership**: share of loops in the right group.  Found groups are matched
  one to one with true groups by the number of loops they share (largest first);
  a loop of a true group is right when one of its found groups is matched to that
  group, a loop of no true group when it is in no found group.
* **source first**: share of true groups whose matched found group ranks the true
  source first (a true group without a match counts as a miss).
* **propagated called stiction**: share of the propagated loops whose final
  verdict in the table is ``stiction``; the share before the plant-wide step (their
  own analysis) is given beside it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from stictiondiag.apps import scan as scan_app
from stictiondiag.core.atomic import write_atomic
from stictiondiag.models.synthetic_plant import generate_plant

__all__ = ["PlantScore", "PlantBenchmark", "run_plant_benchmark", "score_plant"]


@dataclass(frozen=True)
class PlantScore:
    """Scores of one plant.

    Attributes
    ----------
    seed : int
    n_loops, n_groups : int
        Loops and true groups.
    membership_right : int
        Loops in the right group.
    sources_first : int
        True groups whose source is ranked first.
    n_propagated : int
        Truly propagated loops.
    propagated_stiction, propagated_stiction_own : int
        Of those, called ``stiction`` after the plant-wide step, and by their own analysis.
    groups_found : list
        ``[period_s, members, first-ranked]`` of each found group.
    seconds : float
        Wall time of the scan [s].
    """

    seed: int
    n_loops: int
    n_groups: int
    membership_right: int
    sources_first: int
    n_propagated: int
    propagated_stiction: int
    propagated_stiction_own: int
    groups_found: list = field(default_factory=list)
    seconds: float = 0.0


def _match(found: list[dict], truth_groups: dict) -> dict[int, int]:
    """Found group number -> true group id, one to one, largest overlap first."""
    pairs = sorted(
        (
            (len(set(g["members"]) & set(t["members"])), g["group"], gid)
            for g in found
            for gid, t in truth_groups.items()
        ),
        reverse=True,
    )
    mapping: dict[int, int] = {}
    used: set[int] = set()
    for overlap, fg, tg in pairs:
        if overlap and fg not in mapping and tg not in used:
            mapping[fg] = tg
            used.add(tg)
    return mapping


def score_plant(plant, found: list[dict], verdicts: dict, own: dict, seconds: float = 0.0):
    """Score one plant (see the module docstring).

    ``found`` are the groups of ``plantwide.json`` (``group``, ``members``,
    ``ranking``); ``verdicts`` and ``own`` the final and own verdict of each loop.
    """
    mapping = _match(found, plant.groups)
    groups_of: dict[str, list[int]] = {}
    for g in found:
        for m in g["members"]:
            groups_of.setdefault(m, []).append(g["group"])
    right = 0
    for loop, t in plant.truth.items():
        mine = groups_of.get(loop, [])
        if t["group"] is None:
            right += not mine
        else:
            right += any(mapping.get(g) == t["group"] for g in mine)
    first = 0
    for gid, t in plant.groups.items():
        match = [g for g in found if mapping.get(g["group"]) == gid]
        first += bool(match) and match[0]["ranking"][0]["loop"] == t["source"]
    propagated = [k for k, t in plant.truth.items() if t["role"] == "propagated"]
    return PlantScore(
        seed=plant.seed,
        n_loops=len(plant.truth),
        n_groups=len(plant.groups),
        membership_right=right,
        sources_first=first,
        n_propagated=len(propagated),
        propagated_stiction=sum(verdicts.get(k) == "stiction" for k in propagated),
        propagated_stiction_own=sum(own.get(k) == "stiction" for k in propagated),
        groups_found=[
            [round(g["period_s"], 1), g["members"], g["ranking"][0]["loop"]] for g in found
        ],
        seconds=seconds,
    )


@dataclass(frozen=True)
class PlantBenchmark:
    """Outcome of :func:`run_plant_benchmark`: one :class:`PlantScore` per plant."""

    scores: tuple[PlantScore, ...]
    seed: int

    def totals(self) -> dict:
        """The three figures of the module docstring, with their counts."""
        s = self.scores
        loops = sum(p.n_loops for p in s)
        groups = sum(p.n_groups for p in s)
        prop = sum(p.n_propagated for p in s)
        return {
            "plants": len(s),
            "seeds": [s[0].seed, s[-1].seed] if s else [],
            "loops": loops,
            "membership_right": sum(p.membership_right for p in s),
            "membership_pct": 100.0 * sum(p.membership_right for p in s) / max(loops, 1),
            "groups": groups,
            "sources_first": sum(p.sources_first for p in s),
            "source_first_pct": 100.0 * sum(p.sources_first for p in s) / max(groups, 1),
            "propagated": prop,
            "propagated_stiction": sum(p.propagated_stiction for p in s),
            "propagated_stiction_pct": 100.0 * sum(p.propagated_stiction for p in s) / max(prop, 1),
            "propagated_stiction_own_pct": 100.0
            * sum(p.propagated_stiction_own for p in s)
            / max(prop, 1),
        }

    def table(self) -> str:
        """The totals as a small Markdown table."""
        t = self.totals()
        return "\n".join(
            [
                "| measure | value | count |",
                "|---|---:|---:|",
                f"| loops in the right group | {t['membership_pct']:.1f} % | "
                f"{t['membership_right']} / {t['loops']} |",
                f"| true source ranked first | {t['source_first_pct']:.1f} % | "
                f"{t['sources_first']} / {t['groups']} |",
                f"| propagated loops called stiction | {t['propagated_stiction_pct']:.1f} % | "
                f"{t['propagated_stiction']} / {t['propagated']} |",
                f"| (by their own analysis, before) | {t['propagated_stiction_own_pct']:.1f} % | |",
            ]
        )

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "totals": self.totals(),
            "plants": [p.__dict__ for p in self.scores],
        }


def run_plant_benchmark(
    out: str | Path,
    *,
    n_plants: int = 40,
    seed: int = 2026,
    workers: int = 1,
    progress: Callable[[int, int, PlantScore], None] | None = None,
) -> PlantBenchmark:
    """Generate ``n_plants`` plants, scan each from its file, score, write the results.

    Writes ``out/plant_<seed>/plant.csv``, its scan in ``out/plant_<seed>/scan/``,
    and ``out/plant_results.json`` and ``out/plant_results.md``.
    """
    out = Path(out)
    scores = []
    for i in range(int(n_plants)):
        plant = generate_plant(int(seed) + i)
        folder = out / f"plant_{plant.seed}"
        folder.mkdir(parents=True, exist_ok=True)
        write_atomic(folder / "plant.csv", plant.frame.to_csv(index=False))
        t0 = time.perf_counter()
        result = scan_app.scan(
            folder / "plant.csv", out=folder / "scan", gap=False, workers=workers
        )
        seconds = time.perf_counter() - t0
        table: pd.DataFrame = result.table
        verdicts = dict(zip(table["loop"], table["verdict"], strict=True))
        own_col = table["own_verdict"] if "own_verdict" in table else table["verdict"]
        own = {
            k: (o if isinstance(o, str) else v)
            for k, o, v in zip(table["loop"], own_col, table["verdict"], strict=True)
        }
        found = result.plantwide.get("groups", [])
        score = score_plant(plant, found, verdicts, own, seconds)
        scores.append(score)
        if progress:
            progress(i, int(n_plants), score)
    bench = PlantBenchmark(tuple(scores), int(seed))
    write_atomic(out / "plant_results.json", json.dumps(bench.to_dict(), indent=1))
    write_atomic(out / "plant_results.md", bench.table() + "\n")
    return bench
