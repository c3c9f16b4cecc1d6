"""Withheld-effect benchmark of the gap diagnosis: generate, diagnose from files, score.

The cases come from :mod:`stictiondiag.models.synthetic`, a simulator written apart from the
diagnosis (it shares none of :mod:`stictiondiag.gap.effects`' models).  Each case is
written to a CSV file with the columns ``time, sp, pv, op, mv``; the diagnosis reads
the file through :func:`stictiondiag.analysis.analyze_file`, the code path of
``stiction analyze FILE``, and never sees the truth.  The scorer then compares the
named effect with the hidden one.

Scores
------
* top-1 accuracy: share of cases whose named effect is the hidden one;
* confusion matrix: hidden effect (rows) against named effect (columns);
* shrink: median gap reduction [%] on the cases named correctly (``none`` excluded);
* none specificity: share of the ``none`` cases reported as ``none``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from stictiondiag.core.atomic import write_atomic
from stictiondiag.core.csvsafe import safe_cell
from stictiondiag.core.errors import (
    StictionError,
    UsageError,
)
from stictiondiag.gap.effects import EFFECTS
from stictiondiag.models import synthetic


@dataclass(frozen=True)
class CaseResult:
    """Outcome of one benchmark case.

    Attributes
    ----------
    file : str
        CSV file name.
    truth : str
        Hidden effect.
    named : str or None
        Effect the diagnosis named (None when it failed).
    runner_up : str or None
        Its runner-up.
    before, after, shrink_pct : float or None
        Gap before and after the named effect [%] and its reduction [%].
    seconds : float
        Wall time of the diagnosis [s].
    error : str or None
        Message when the diagnosis failed.
    """

    file: str
    truth: str
    named: str | None
    runner_up: str | None
    before: float | None
    after: float | None
    shrink_pct: float | None
    seconds: float
    error: str | None = None

    def to_dict(self) -> dict:
        return {k: _num(v) for k, v in self.__dict__.items()}


def _num(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


@dataclass(frozen=True)
class BenchmarkResult:
    """Scores of a withheld-effect benchmark.

    Attributes
    ----------
    seed : int
        Benchmark seed.
    cases : tuple of CaseResult
        One per case, in file order.
    effects : tuple of str
        Effect names (rows and columns of the confusion matrix).
    path : str
        How the files were diagnosed (``analyze_file``).
    """

    seed: int
    cases: tuple
    effects: tuple = EFFECTS
    path: str = "analyze_file"
    settings: dict = field(default_factory=dict)

    @property
    def accuracy(self) -> float:
        """Top-1 accuracy [-]."""
        return float(np.mean([c.named == c.truth for c in self.cases])) if self.cases else 0.0

    @property
    def confusion(self) -> list[list[int]]:
        """Counts: hidden effect (row) named as effect (column); failed cases are only
        in :attr:`failures`."""
        idx = {e: i for i, e in enumerate(self.effects)}
        m = [[0] * len(self.effects) for _ in self.effects]
        for c in self.cases:
            if c.named in idx:
                m[idx[c.truth]][idx[c.named]] += 1
        return m

    @property
    def failures(self) -> int:
        """Cases the diagnosis could not run on."""
        return sum(c.named is None for c in self.cases)

    @property
    def median_shrink(self) -> float | None:
        """Median gap reduction on correctly named cases with an effect [%]."""
        vals = [
            c.shrink_pct
            for c in self.cases
            if c.named == c.truth and c.truth != "none" and c.shrink_pct is not None
        ]
        return float(np.median(vals)) if vals else None

    @property
    def none_specificity(self) -> float | None:
        """Share of ``none`` cases reported as ``none`` [-]."""
        nones = [c for c in self.cases if c.truth == "none"]
        return float(np.mean([c.named == "none" for c in nones])) if nones else None

    def per_effect(self) -> dict:
        """Cases, correct, accuracy and median shrink of each hidden effect."""
        out = {}
        for e in self.effects:
            cs = [c for c in self.cases if c.truth == e]
            if not cs:
                continue
            ok = [c for c in cs if c.named == e]
            shr = [c.shrink_pct for c in ok if c.shrink_pct is not None and e != "none"]
            out[e] = {
                "cases": len(cs),
                "correct": len(ok),
                "accuracy": len(ok) / len(cs),
                "median_shrink_pct": float(np.median(shr)) if shr else None,
            }
        return out

    def to_dict(self) -> dict:
        return {
            "seed": self.seed,
            "n_cases": len(self.cases),
            "path": self.path,
            "settings": self.settings,
            "accuracy": self.accuracy,
            "median_shrink_pct": self.median_shrink,
            "none_specificity": self.none_specificity,
            "failures": self.failures,
            "effects": list(self.effects),
            "confusion": self.confusion,
            "per_effect": self.per_effect(),
            "seconds_total": float(sum(c.seconds for c in self.cases)),
            "cases": [c.to_dict() for c in self.cases],
        }

    def to_csv(self) -> str:
        """One row per case."""
        buf = io.StringIO()
        fields = [
            "file",
            "truth",
            "named",
            "runner_up",
            "before",
            "after",
            "shrink_pct",
            "seconds",
            "error",
        ]
        w = csv.DictWriter(buf, fieldnames=fields)
        w.writeheader()
        for c in self.cases:
            # Spreadsheet-safe text cells (an error message may start with "-").
            w.writerow({k: safe_cell(v) for k, v in c.to_dict().items()})
        return buf.getvalue()

    def table(self) -> str:
        """Markdown tables: the scores, per effect, and the confusion matrix."""
        ms = self.median_shrink
        ns = self.none_specificity
        lines = [
            "| cases | seed | top-1 accuracy | median shrink (correct) | none specificity | failures |",
            "|---|---|---|---|---|---|",
            f"| {len(self.cases)} | {self.seed} | {self.accuracy:.3f} | "
            f"{'n/a' if ms is None else f'{ms:.0f} %'} | {'n/a' if ns is None else f'{ns:.2f}'} | {self.failures} |",
            "",
            "| hidden effect | cases | correct | median shrink |",
            "|---|---|---|---|",
        ]
        for e, v in self.per_effect().items():
            shr = v["median_shrink_pct"]
            lines.append(
                f"| {e} | {v['cases']} | {v['correct']} | {'-' if shr is None else f'{shr:.0f} %'} |"
            )
        short = [e.replace("_", " ") for e in self.effects]
        lines += ["", "Confusion (rows: hidden, columns: named)", ""]
        lines.append("| hidden \\ named | " + " | ".join(short) + " |")
        lines.append("|---" * (len(short) + 1) + "|")
        for e, row in zip(short, self.confusion, strict=True):
            lines.append(f"| {e} | " + " | ".join(str(v) for v in row) + " |")
        return "\n".join(lines)


def _diagnose_path(path: Path):
    """Diagnose one file the way ``stiction analyze FILE`` does; returns (gap, how)."""
    # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
    from stictiondiag.analysis import AnalysisConfig, analyze_file

    analysis = analyze_file(path, config=AnalysisConfig())
    if analysis.gap is None:
        reasons = "; ".join(analysis.warnings) or "no gap diagnosis"
        raise UsageError(f"analysis gave no gap diagnosis: {reasons}")
    return analysis.gap, "analyze_file"


def run_benchmark(
    out_dir: str | Path,
    *,
    n_cases: int = 40,
    seed: int = 2026,
    progress: Callable[[int, int, CaseResult], None] | None = None,
    diagnose: Callable | None = None,
) -> BenchmarkResult:
    """Generate ``n_cases`` loops with one hidden effect each, diagnose them, score.

    Parameters
    ----------
    out_dir : str or Path
        Directory for the case files (``cases/``), ``results.json`` and
        ``results.csv``.
    n_cases : int
        Number of cases (>= 1), balanced over the effects.
    seed : int
        Benchmark seed (the same seed writes the same cases).
    progress : callable, optional
        Called after each case with (index, total, CaseResult).
    diagnose : callable, optional
        ``f(path) -> GapDiagnosis`` replacing the analysis (for tests).

    Returns
    -------
    BenchmarkResult
    """
    n_cases, seed = synthetic.check_benchmark(n_cases, seed)
    out = Path(out_dir)
    cases_dir = out / "cases"
    results = []
    truths: list[dict] = []
    how = "custom" if diagnose is not None else None
    # Each case is generated (and its file written whole) just before it is
    # diagnosed: memory does not grow with the number of cases.
    for i, (path, truth) in enumerate(synthetic.iter_benchmark(cases_dir, n_cases, seed)):
        truths.append(truth)
        t0 = time.perf_counter()
        try:
            if diagnose is not None:
                g = diagnose(path)
            else:
                g, how = _diagnose_path(path)
            r = CaseResult(
                file=Path(path).name,
                truth=truth["effect"],
                named=g.effect,
                runner_up=g.runner_up,
                before=g.before,
                after=g.after,
                shrink_pct=g.shrink_pct,
                seconds=time.perf_counter() - t0,
            )
        except StictionError as exc:
            r = CaseResult(
                file=Path(path).name,
                truth=truth["effect"],
                named=None,
                runner_up=None,
                before=None,
                after=None,
                shrink_pct=None,
                seconds=time.perf_counter() - t0,
                error=str(exc).splitlines()[0],
            )
        results.append(r)
        if progress is not None:
            progress(i, n_cases, r)
    synthetic.write_benchmark_truth(cases_dir, seed, truths)
    res = BenchmarkResult(
        seed=int(seed),
        cases=tuple(results),
        path=how or "analyze_file",
        settings={"n_cases": int(n_cases)},
    )
    write_atomic(out / "results.json", json.dumps(res.to_dict(), indent=1) + "\n")
    write_atomic(out / "results.csv", res.to_csv())
    write_atomic(out / "results.md", res.table() + "\n")
    return res
