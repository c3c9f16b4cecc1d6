"""Validation on real plant data: the International Stiction Database (ISDB).

Jelali & Huang (eds., 2010), *Detection and Diagnosis of Stiction in Control Loops*,
Springer, publish industrial loops (pv, op, sp; no mv) with expert comments.  This
module runs :func:`stictiondiag.analysis.analyze` on each loop, using the loop type,
integrating flag and sampling time of the manifest as an engineer would (several
files' own time columns are not clocks), runs the classic baselines beside it (Horch's
cross-correlation test; the bicoherence-based procedure of Choudhury, Shah &
Thornhill 2004: non-Gaussianity and nonlinearity indices, then the pv-op ellipse)
and compares every verdict with the published labels.

Labels are read from the manifest's ``stiction_published`` and
``other_fault_published`` columns, mechanically:

* ``stated``: the comment states stiction (``yes``), states no stiction (``no``), or
  states another diagnosis without "(likely)" (quantisation, external disturbance,
  no oscillation, faulty sensor, tuning problem, dead zone + tight tuning);
* ``likely``: "with stiction (likely)" or "with disturbance (likely)";
* ``none``: no published diagnosis.

Accuracy counts an ``inconclusive`` verdict as wrong for a stiction loop (it was not
found) and as right for a non-stiction loop only if ``inconclusive_as`` says so; the
default counts it as "not called stiction", which is what a maintenance list does.

The data have no open licence: they are read from their folder, never copied.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from stictiondiag.apps.scan import LoopSource, analyse_source, run_local
from stictiondiag.apps.scan_output import ScannedLoop
from stictiondiag.apps.sources import load_source
from stictiondiag.core.errors import DataError, StictionError
from stictiondiag.core.serialize import plain_float
from stictiondiag.io.tags import Tags

#: ISDB loop types that behave as the paper's loop types.
LOOP_TYPE_MAP = {
    "flow": "flow",
    "pressure": "pressure",
    "level": "level",
    "temperature": "temperature",
    "concentration": "composition",
    "analyser": "composition",
    "thickness": "other",
}


def default_isdb_dir() -> Path:
    """``../shared/data/isdb`` next to the project checkout (or ``$STICTION_ISDB``)."""
    env = os.environ.get("STICTION_ISDB")
    if env:
        return Path(env)
    checkout = Path(__file__).resolve().parents[2]  # stictiondiag/apps/ -> checkout
    return checkout.parent / "shared" / "data" / "isdb"


def expert_label(stiction_published: str, other_fault: str | None) -> tuple[str | None, str]:
    """(label, group) of a loop from its published ISDB comment (see module doc)."""
    s = str(stiction_published or "").strip().lower()
    other = "" if other_fault is None or (isinstance(other_fault, float)) else str(other_fault)
    if s == "yes":
        return "stiction", "stated"
    if s == "yes_likely":
        return "stiction", "likely"
    if s == "no":
        return "no_stiction", "stated"
    if other.strip():
        return "no_stiction", ("likely" if "likely" in other.lower() else "stated")
    return None, "none"


def load_manifest(isdb_dir: str | os.PathLike | None = None) -> pd.DataFrame:
    """The ISDB manifest with ``label`` and ``label_group`` columns added."""
    d = Path(isdb_dir) if isdb_dir else default_isdb_dir()
    path = d / "manifest.csv"
    if not path.is_file():
        raise DataError(f"{path}: ISDB manifest not found; pass --isdb PATH to the isdb folder")
    m = pd.read_csv(path)
    labels = [
        expert_label(s, o)
        for s, o in zip(m["stiction_published"], m["other_fault_published"], strict=True)
    ]
    m["label"] = [lab for lab, _ in labels]
    m["label_group"] = [g for _, g in labels]
    m["path"] = [str(d / f) for f in m["file"]]
    return m


#: The classic tests reported beside the combined verdict
#: (:data:`stictiondiag.stiction.probability.CLASSIC_TESTS`).
CLASSIC_COLUMNS = ("horch", "choudhury", "he", "rossi_scali", "kano")

_CALL_TEXT = {1.0: "stiction", -1.0: "no_stiction", 0.0: "inconclusive"}


def _baselines(path: str, ts: float, integrating: bool, loop_type: str | None = None) -> dict:
    """Each classic test's own call on the raw record (``stiction``, ``no_stiction``,
    ``inconclusive``, or ``n/a`` where the test does not apply or could not run)."""
    # Imported here: it brings numba, which only the analysing process needs.
    from stictiondiag.stiction.probability import classic_votes

    frame = pd.read_csv(path)
    pv = frame["pv"].to_numpy(float)
    op = frame["op"].to_numpy(float)
    sp = frame["sp"].to_numpy(float) if "sp" in frame else None
    ok = np.isfinite(pv) & np.isfinite(op)
    if sp is not None:
        ok &= np.isfinite(sp)
    pv, op = pv[ok], op[ok]
    sp = sp[ok] if sp is not None else None
    try:
        votes = classic_votes(op, pv, sp, ts, integrating, loop_type)
    except Exception as exc:  # a classic test failing must not hide ours
        return dict.fromkeys(CLASSIC_COLUMNS, f"error: {type(exc).__name__}")
    out = {}
    for test in CLASSIC_COLUMNS:
        raw = votes.get(f"{test}_call", votes.get(test))
        out[test] = _CALL_TEXT.get(raw, "n/a") if raw is not None else "n/a"
    return out


#: Fewest cycles a record must hold to be cut into two halves for the repeatability
#: check (each half then holds three, what the oscillation test needs) [-].
SPLIT_MIN_CYCLES = 6.0


def _half_summary(tags) -> dict:
    """Verdict, P(stiction) and S interval of one half-record (no replay, no gap)."""
    # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
    from stictiondiag.analysis import AnalysisConfig, analyze

    try:
        a = analyze(tags, config=AnalysisConfig(gap=False, replay=False))
    except StictionError as exc:
        return {"verdict": "error", "error": str(exc).splitlines()[0]}
    fit = a.fit
    return {
        "verdict": a.verdict.status.value,
        "probability": a.verdict.probability,
        "S": float(fit.S),
        "S_interval": None if fit.S_interval is None else [float(v) for v in fit.S_interval],
    }


def record_halves(tags, period_s: float | None) -> tuple | None:
    """The two halves of a record holding at least :data:`SPLIT_MIN_CYCLES` cycles of
    ``period_s``, each as tags of its own; None for a shorter record or one without a
    cycle."""
    if not period_s or not period_s > 0 or tags.duration < SPLIT_MIN_CYCLES * period_s:
        return None
    h = tags.n // 2
    return tuple(
        Tags.from_arrays(
            tags.pv[sl],
            tags.op[sl],
            mv=None if tags.mv is None else tags.mv[sl],
            sp=None if tags.sp is None else tags.sp[sl],
            ts=float(tags.ts),
            loop_type=tags.loop_type,
            integrating=bool(tags.integrating),
            source=f"{tags.source}[{sl.start}:{sl.stop}]",
        )
        for sl in (slice(0, h), slice(h, 2 * h))
    )


def split_half(tags, period_s: float | None) -> dict | None:
    """Analyse the two halves of a record (:func:`record_halves`); None for a record
    too short to split or one without a cycle.

    Returns the two halves' summaries, whether their verdicts agree, and whether each
    half's S lies inside the other half's S interval.
    """
    parts = record_halves(tags, period_s)
    if parts is None:
        return None
    halves = [_half_summary(part) for part in parts]
    a, b = halves

    def inside(x, iv):
        return iv is not None and x is not None and iv[0] <= x <= iv[1]

    s_mutual = None
    if "S" in a and "S" in b:
        s_mutual = bool(inside(a["S"], b["S_interval"]) and inside(b["S"], a["S_interval"]))
    return {
        "halves": halves,
        "agree": a["verdict"] == b["verdict"],
        "S_within_intervals": s_mutual,
    }


@dataclass(frozen=True)
class ValidatedLoop:
    """One ISDB loop validated (:func:`validate_one`).

    Attributes
    ----------
    scanned : ScannedLoop
        Its analysis and table row (:func:`stictiondiag.apps.scan.analyse_source`).
    baselines : dict
        The classic tests' calls, by test.
    split : dict or None
        The split-half check (:func:`split_half`), None when not run.
    """

    scanned: ScannedLoop
    baselines: dict
    split: dict | None = None


def validate_one(source, gap: bool) -> ValidatedLoop:
    """Analyse one ISDB loop, run the classic tests beside it and, for a record of at
    least :data:`SPLIT_MIN_CYCLES` cycles, each of its halves (for a worker process)."""
    scanned = analyse_source(source, {}, gap)
    opts = source.read_options or {}
    baselines = _baselines(
        source.path,
        opts.get("ts") or 1.0,
        bool(opts.get("integrating")),
        opts.get("loop_type"),
    )
    split = None
    analysis = scanned.analysis
    if scanned.row.get("verdict") not in (None, "error"):
        period = None
        if analysis is not None:
            period = plain_float(analysis.oscillation.period_s) or plain_float(
                analysis.oscillation_op.period_s
            )
        try:
            split = split_half(load_source(source, **opts), period)
        except Exception as exc:  # the check must not hide the main result
            split = {"error": f"{type(exc).__name__}: {exc}"}
    return ValidatedLoop(scanned, baselines, split)


@dataclass(frozen=True)
class ValidationResult:
    """Per-loop table and scores of :func:`validate_isdb`.

    Attributes
    ----------
    table : DataFrame
        One row per loop: label, label_group, our verdict, S, J, gap effect,
        baselines' verdicts, reasons.
    scores : dict
        For each group (``stated``, ``likely``, ``none``) and method: counts,
        accuracy, false positives, confusion matrix.
    split : dict
        Split-half repeatability (:func:`split_summary`).
    causes : dict
        The gap's cause against the expert's (:func:`cause_agreement`), empty
        without the gap diagnosis.
    """

    table: pd.DataFrame
    scores: dict = field(default_factory=dict)
    split: dict = field(default_factory=dict)
    causes: dict = field(default_factory=dict)


def _called_stiction(verdict: str) -> bool:
    return verdict == "stiction"


def score(table: pd.DataFrame, column: str, positive: Callable[[str], bool]) -> dict:
    """Confusion counts of one method's verdicts against the labels, per label group."""
    out: dict = {}
    for group in ("stated", "likely", "none"):
        g = table[table["label_group"] == group]
        # Plain booleans even for an empty group (an empty map has no bool dtype).
        called = g[column].map(lambda v: positive(str(v))).astype(bool)
        if group == "none":
            out[group] = {"n": int(len(g)), "called_stiction": int(called.sum())}
            continue
        truth = (g["label"] == "stiction").astype(bool)
        tp = int((called & truth).sum())
        fn = int((~called & truth).sum())
        fp = int((called & ~truth).sum())
        tn = int((~called & ~truth).sum())
        n = tp + fn + fp + tn
        out[group] = {
            "n": n,
            "tp": tp,
            "fn": fn,
            "fp": fp,
            "tn": tn,
            "accuracy": (tp + tn) / n if n else None,
            "inconclusive": int((g[column] == "inconclusive").sum()),
        }
    return out


def validate_isdb(
    isdb_dir: str | os.PathLike | None = None,
    *,
    workers: int | None = None,
    gap: bool = True,
    loops: list[str] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> ValidationResult:
    """Analyse every ISDB loop and compare verdicts with the published labels."""
    m = load_manifest(isdb_dir)
    if loops:
        m = m[m["loop"].isin(loops)]
    sources = []
    for _, r in m.iterrows():
        lt = LOOP_TYPE_MAP.get(str(r["loop_type"]).lower(), "other")
        sources.append(
            LoopSource(
                str(r["loop"]),
                str(r["path"]),
                read_options={
                    # The manifest's Ts is the published one; several files' time columns
                    # are sample counters or irregular stamps (see the manifest notes).
                    "ts": float(r["ts_s"]),
                    "loop_type": lt,
                    "integrating": bool(r["integrating"]),
                },
            )
        )
    workers = int(workers or os.cpu_count() or 1)
    rows = []
    for i, res in enumerate(run_local(sources, validate_one, (gap,), workers)):
        row = dict(res.scanned.row)
        row.update({f"baseline_{k}": v for k, v in res.baselines.items()})
        analysis = res.scanned.analysis
        reasons = () if analysis is None else analysis.verdict.reasons
        row["reasons"] = "; ".join(str(x) for x in reasons)
        if analysis is not None and analysis.gap is not None:
            # Imported here: the gap's effects bring numba, which the table does not need.
            from stictiondiag.gap.attribution import attribute_gap

            refit = None if analysis.replay is None else analysis.replay.settings.refit
            row["gap_cause"] = attribute_gap(refit, analysis.gap).cause.value
            row["gap_before"] = plain_float(analysis.gap.before)
        row.update(_split_columns(res.split))
        rows.append(row)
        if progress:
            progress(i + 1, len(sources), row["loop"])
    table = pd.DataFrame(rows)
    table = m[
        [
            "loop",
            "loop_type",
            "integrating",
            "ts_s",
            "n_samples",
            "label",
            "label_group",
            "stiction_published",
            "other_fault_published",
        ]
    ].merge(table.drop(columns=["loop_type", "n_samples"], errors="ignore"), on="loop", how="left")
    scores = {"ours": score(table, "verdict", _called_stiction)}
    for test in CLASSIC_COLUMNS:
        scores[test] = score(table, f"baseline_{test}", _called_stiction)
    causes = cause_agreement(table) if gap else {}
    return ValidationResult(table, scores, split_summary(table), causes)


#: Causes named in the ISDB comments (``other_fault_published``) and the effect of the
#: gap's catalogue (:mod:`stictiondiag.gap.effects`) each corresponds to; None where
#: the catalogue has no such effect (the comparison is then listed, not scored).
EXPERT_CAUSES = {
    "quantisation": "quantization",
    "external disturbance": "external_disturbance",
    "tuning": None,
    "dead zone": None,
}


def catalogue_cause(other_fault) -> tuple[str | None, str | None]:
    """(the cause a published comment names, the catalogue effect it is) of the
    manifest's ``other_fault_published`` text; (None, None) when it names none of
    :data:`EXPERT_CAUSES`."""
    text = "" if other_fault is None or isinstance(other_fault, float) else str(other_fault)
    text = text.lower()
    for cause, effect in EXPERT_CAUSES.items():
        if cause in text:
            return cause, effect
    return None, None


def cause_agreement(table: pd.DataFrame) -> dict:
    """The gap's named effect against the cause the expert names, per loop.

    Rows: ``loop``, ``expert`` (the comment's cause), ``expected`` (the catalogue
    effect, None when the catalogue has none), ``named`` (the gap's effect),
    ``cause`` (:func:`stictiondiag.gap.attribution.attribute_gap`), ``agrees``
    (None when not scored).  ``n`` scored loops, ``agree`` of them.
    """
    rows = []
    for r in table.itertuples():
        cause, effect = catalogue_cause(getattr(r, "other_fault_published", None))
        if cause is None:
            continue
        named = getattr(r, "gap_effect", None)
        named = named if isinstance(named, str) else None
        rows.append(
            {
                "loop": r.loop,
                "expert": str(r.other_fault_published),
                "expected": effect,
                "named": named,
                "cause": getattr(r, "gap_cause", None),
                "gap_before": getattr(r, "gap_before", None),
                "agrees": None if effect is None else named == effect,
            }
        )
    scored = [x for x in rows if x["agrees"] is not None]
    return {
        "rows": rows,
        "n": len(scored),
        "agree": sum(bool(x["agrees"]) for x in scored),
    }


def _split_columns(split: dict | None) -> dict:
    """Flat columns of :func:`split_half`'s result for the per-loop table."""
    if not split or "halves" not in split:
        return {
            "split_first": None,
            "split_second": None,
            "split_agree": None,
            "split_S_within": None,
        }
    a, b = split["halves"]
    return {
        "split_first": a.get("verdict"),
        "split_second": b.get("verdict"),
        "split_agree": bool(split["agree"]),
        "split_S_within": split.get("S_within_intervals"),
    }


def split_summary(table: pd.DataFrame) -> dict:
    """How often the two halves' verdicts agree, and their S estimates lie within
    each other's intervals, over the records long enough to be split."""
    if "split_agree" not in table:
        return {"n": 0}
    done = table[table["split_agree"].notna()]
    n = int(len(done))
    within = done["split_S_within"].dropna()
    return {
        "n": n,
        "agree": int(done["split_agree"].astype(bool).sum()),
        "agreement": float(done["split_agree"].astype(bool).mean()) if n else None,
        "n_S": int(len(within)),
        "S_within": int(within.astype(bool).sum()),
        "S_within_share": float(within.astype(bool).mean()) if len(within) else None,
    }
