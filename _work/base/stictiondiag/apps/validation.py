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

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from stictiondiag.apps.sources import load_source
from stictiondiag.core.errors import DataError, StictionError

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
    # Imported here, as Tags below: they bring numba, which only the analysing process needs.
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
        "verdict": a.verdict.status,
        "probability": a.verdict.probability,
        "S": float(fit.S),
        "S_interval": None if fit.S_interval is None else [float(v) for v in fit.S_interval],
    }


def split_half(tags, period_s: float | None) -> dict | None:
    """Analyse the two halves of a record holding at least :data:`SPLIT_MIN_CYCLES`
    cycles of ``period_s``; None for a shorter record or one without a cycle.

    Returns the two halves' summaries, whether their verdicts agree, and whether each
    half's S lies inside the other half's S interval.
    """
    from stictiondiag.io.tags import Tags

    if not period_s or not period_s > 0 or tags.duration < SPLIT_MIN_CYCLES * period_s:
        return None
    h = tags.n // 2
    halves = []
    for sl in (slice(0, h), slice(h, 2 * h)):
        part = Tags.from_arrays(
            tags.pv[sl],
            tags.op[sl],
            mv=None if tags.mv is None else tags.mv[sl],
            sp=None if tags.sp is None else tags.sp[sl],
            ts=float(tags.ts),
            loop_type=tags.loop_type,
            integrating=bool(tags.integrating),
            source=f"{tags.source}[{sl.start}:{sl.stop}]",
        )
        halves.append(_half_summary(part))
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


def validate_one(source, gap: bool) -> dict:
    """Analyse one ISDB loop, run the classic tests beside it and, for a record of at
    least :data:`SPLIT_MIN_CYCLES` cycles, each of its halves (for a worker process)."""
    from stictiondiag.apps.scan import analyse_source

    res = analyse_source(source, {}, gap)
    opts = source.read_options or {}
    res["baselines"] = _baselines(
        source.path,
        opts.get("ts") or 1.0,
        bool(opts.get("integrating")),
        opts.get("loop_type"),
    )
    res["split"] = None
    row = res["row"]
    if row.get("verdict") not in (None, "error"):
        osc = ((res.get("analysis") or {}).get("oscillation")) or {}
        period = (osc.get("pv") or {}).get("period_s") or (osc.get("op") or {}).get("period_s")
        try:
            res["split"] = split_half(load_source(source, **opts), period)
        except Exception as exc:  # the check must not hide the main result
            res["split"] = {"error": f"{type(exc).__name__}: {exc}"}
    return res


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
    from stictiondiag.apps.scan import (
        LoopSource,
        run_local,
    )

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
        row = dict(res["row"])
        row.update({f"baseline_{k}": v for k, v in res["baselines"].items()})
        reasons = ((res.get("analysis") or {}).get("stiction") or {}).get("reasons") or []
        row["reasons"] = "; ".join(str(x) for x in reasons)
        full = res.get("analysis") or {}
        if full.get("gap") is not None:
            # Imported here: the gap's effects bring numba, which the table does not need.
            from stictiondiag.gap.attribution import attribute_gap

            row["gap_cause"] = attribute_gap(full.get("replay"), full.get("gap"))["cause"]
            row["gap_before"] = full["gap"].get("before")
        row.update(_split_columns(res.get("split")))
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


def render_causes(causes: dict) -> list[str]:
    """Markdown lines: the cause table of :func:`cause_agreement`."""
    lines = [
        f"The gap names the expert's cause in {causes.get('agree', 0)} of "
        f"{causes.get('n', 0)} loops whose comment names a cause the catalogue covers.",
        "",
        "| loop | expert's comment | catalogue effect | gap names | cause | agrees |",
        "|---|---|---|---|---|---|",
    ]
    for x in causes.get("rows", []):
        agrees = "-" if x["agrees"] is None else ("yes" if x["agrees"] else "no")
        lines.append(
            f"| {x['loop']} | {x['expert']} | {x['expected'] or '(not in the catalogue)'} | "
            f"{x['named'] or 'no gap diagnosis'} | {x['cause'] or '-'} | {agrees} |"
        )
    return lines


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


def _f(v, spec=".2f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _text(v, missing: str) -> str:
    """A table cell for a text field; ``missing`` where the field is None or NaN."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)) or v == "":
        return missing
    return str(v)


_OUTCOMES = ("stiction", "inconclusive", "no_stiction")


def _confusion_lines(t: pd.DataFrame, column: str, method: str) -> list[str]:
    lines = []
    for group in ("stated", "likely"):
        g = t[t["label_group"] == group]
        for lab in ("stiction", "no_stiction"):
            h = g[g["label"] == lab]
            v = h[column].astype(str)
            counts = [int((v == o).sum()) for o in _OUTCOMES]
            other = int(len(h)) - sum(counts)
            lines.append(
                f"| {method} | {group} | {lab.replace('_', ' ')} | "
                + " | ".join(str(c) for c in counts)
                + f" | {other} |"
            )
    return lines


def targets(result: ValidationResult) -> list[tuple[str, str, bool | None]]:
    """The issue's targets: (target, measured, met)."""
    sc, t, sp = result.scores["ours"], result.table, result.split
    st, lk = sc["stated"], sc["likely"]
    n_all = int(len(t))
    n_inc = int((t["verdict"] == "inconclusive").sum())
    share = n_inc / n_all if n_all else None
    out = [
        ("stated accuracy >= 0.85", _f(st["accuracy"]), _ge(st["accuracy"], 0.85)),
        ("stated: at most 2 healthy loops called stiction", str(st["fp"]), st["fp"] <= 2),
        ("stated: at most 3 inconclusive", str(st["inconclusive"]), st["inconclusive"] <= 3),
        ("likely accuracy >= 0.80", _f(lk["accuracy"]), _ge(lk["accuracy"], 0.80)),
        (
            "inconclusive <= 15 % of all loops",
            f"{n_inc} of {n_all} ({_f(None if share is None else 100 * share, '.0f')} %)",
            None if share is None else share <= 0.15,
        ),
        (
            "area under the ROC curve of P, stated labels, >= 0.85",
            _f(auc := stated_auc(t)),
            _ge(auc, 0.85),
        ),
        (
            "split-half verdict agreement >= 0.85",
            f"{_f(sp.get('agreement'))} ({sp.get('agree', 0)} of {sp.get('n', 0)})",
            _ge(sp.get("agreement"), 0.85),
        ),
    ]
    return out


def stated_auc(t: pd.DataFrame) -> float | None:
    """Area under the ROC curve of our ``probability`` (P that the valve causes the
    cycle) on the stated loops: stiction against the others (a Mann-Whitney count,
    ties half); None when a class is empty or no P is known."""
    g = t[(t["label_group"] == "stated")]
    if "probability" not in g:
        return None
    p = pd.to_numeric(g["probability"], errors="coerce")
    ok = p.notna()
    y = (g["label"] == "stiction")[ok].to_numpy(bool)
    s = p[ok].to_numpy(float)
    pos, neg = s[y], s[~y]
    if pos.size == 0 or neg.size == 0:
        return None
    gt = (pos[:, None] > neg[None, :]).sum() + 0.5 * (pos[:, None] == neg[None, :]).sum()
    return float(gt / (pos.size * neg.size))


#: Our causes as columns of the per-cause table (``inconclusive`` verdicts too).
_CAUSE_COLUMNS = ("valve", "tuning", "external", "other", "none")


def expert_cause(stiction_published: str, other_fault: str | None) -> str | None:
    """The expert's named cause, as published (stiction first; the other diagnosis as
    written, "(likely)" kept), None when nothing is named."""
    s = str(stiction_published or "").strip().lower()
    if s in ("yes", "yes_likely"):
        return "stiction" + (" (likely)" if s == "yes_likely" else "")
    if isinstance(other_fault, str) and other_fault.strip():
        return other_fault.strip()
    if s == "no":
        return "no stiction"
    return None


def cause_table(t: pd.DataFrame, column: str = "cause") -> list[str]:
    """Markdown rows: each published cause against the cause we name in ``column``
    (the verdict's ``cause``, or ``cause_model``, the cause model's reading), and how
    many of those loops our verdict left inconclusive."""
    named = [
        (expert_cause(a, b), r)
        for a, b, r in zip(
            t["stiction_published"], t["other_fault_published"], t.itertuples(), strict=True
        )
    ]
    order: list[str] = []
    for c, _ in named:
        if c is not None and c not in order:
            order.append(c)
    lines = [
        "| expert's cause | loops | "
        + " | ".join(_CAUSE_COLUMNS)
        + " | no cause | of which inconclusive |",
        "|---|---|" + "---|" * (len(_CAUSE_COLUMNS) + 2),
    ]
    for c in order:
        rows = [r for e, r in named if e == c]
        ours = [str(getattr(r, column, None)) for r in rows]
        counts = [ours.count(k) for k in _CAUSE_COLUMNS]
        inc = sum(str(getattr(r, "verdict", "")) == "inconclusive" for r in rows)
        lines.append(
            f"| {c} | {len(rows)} | "
            + " | ".join(str(k) for k in counts)
            + f" | {len(rows) - sum(counts)} | {inc} |"
        )
    return lines


def _with_cause(r) -> str:
    """``verdict (cause)`` of a row of the table."""
    cause = getattr(r, "cause", None)
    return f"{r.verdict} ({cause})" if isinstance(cause, str) else str(r.verdict)


def _ge(v, level) -> bool | None:
    return None if v is None else bool(v >= level)


def _intro_lines(command: str) -> list[str]:
    """The page's head: where the data come from, the command, and how to read it."""
    return [
        "# Validation on the International Stiction Database",
        "",
        "Real industrial loops (pv, op, sp; no mv) from Jelali & Huang (2010), read from",
        "`../shared/data/isdb/` (no open licence: never copied here). Produced by:",
        "",
        f"```bash\n{command}\n```",
        "",
        "**The ISDB labels are a test set, never a training set.** The verdict asks",
        "why the loop oscillates, in two stages (`stictiondiag/stiction/cause.py`):",
        "stage 1, is there a limit cycle to explain (a loop without one is `no_stiction`,",
        "cause `none`, unless its valve shows stick-slip directly); stage 2, one",
        "probability per cause of the cycle (valve, tuning, external disturbance, other),",
        "a softmax model fitted on simulated loops labelled by counterfactual twins",
        "(`stictiondiag/apps/family_causes.py`, `scripts/train_cause.py`; calibration on",
        "held-out simulated loops in `docs/calibration.md`), reported beside the verdict.",
        "A loop with a cycle is decided by P(stiction) of the friction model",
        "(`stictiondiag/stiction/probability.py`, fitted on simulated loops only):",
        "`stiction` above 0.7, `no_stiction` below 0.3, `inconclusive` between. *P* in the",
        "tables is that probability (0 for a loop without a cycle). No threshold, weight,",
        "feature or level is fitted or tuned on these loops: the models and the levels are",
        "fixed first, and the ISDB is then measured. Every run is reported, with any",
        'decision taken after one was seen (under "What the data show").',
        "",
        "Labels are the published ISDB comments (see `stictiondiag/apps/validation.py`):",
        "*stated* (stiction stated, no stiction stated, or another diagnosis stated),",
        '*likely* ("with stiction (likely)", "with disturbance (likely)"), and *none*.',
        "A loop counts as *called stiction* only when the verdict is `stiction`;",
        "`inconclusive` counts as not called. Each classic test is run on its own, with",
        "its own published decision rule (`stictiondiag/stiction/classic/`), on the same",
        "loops; *n/a* is a test that does not apply to the loop or could not run.",
    ]


def _target_lines(result: ValidationResult) -> list[str]:
    """The targets section: each target, the measured figure and whether it is met."""
    lines = ["", "## Targets", "", "| target | measured | met |", "|---|---|---|"]
    for name, measured, met in targets(result):
        lines.append(
            f"| {name} | {measured} | {'-' if met is None else ('yes' if met else 'no')} |"
        )
    return lines


def _score_lines(sc: dict) -> list[str]:
    """The scores section: each method's counts and accuracy per label group."""
    lines = [
        "",
        "## Scores",
        "",
        "| method | group | n | TP | FN | FP | TN | accuracy | inconclusive |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method, groups in sc.items():
        for group in ("stated", "likely"):
            s = groups[group]
            lines.append(
                f"| {method} | {group} | {s['n']} | {s['tp']} | {s['fn']} | {s['fp']} | "
                f"{s['tn']} | {_f(s['accuracy'])} | {s['inconclusive']} |"
            )
        lines.append(
            f"| {method} | none | {groups['none']['n']} | called stiction: "
            f"{groups['none']['called_stiction']} | | | | | |"
        )
    return lines


def _confusion_section(t: pd.DataFrame) -> list[str]:
    """The confusion matrices of our verdict and of each classic test."""
    lines = [
        "",
        "## Confusion matrices",
        "",
        "| method | group | expert | stiction | inconclusive | no stiction | n/a or error |",
        "|---|---|---|---|---|---|---|",
        *_confusion_lines(t, "verdict", "ours"),
    ]
    for test in CLASSIC_COLUMNS:
        col = f"baseline_{test}"
        if col in t:
            lines += _confusion_lines(t, col, test)
    return lines


def _cause_sections(t: pd.DataFrame) -> list[str]:
    """Each published cause against the cause our verdict names and, where present,
    against the cause model's reading."""
    lines: list[str] = []
    if "cause" in t:
        lines += [
            "",
            "## Per cause",
            "",
            "Each published cause (the ISDB comment, as written) against the cause our",
            "verdict names (`stictiondiag/stiction/cause.py`): the valve, the tuning, an",
            "external disturbance, quantisation or another nonlinearity (`other`), or no",
            "limit cycle (`none`); an `inconclusive` verdict names none.",
            "",
            *cause_table(t),
        ]
    if "cause_model" in t:
        lines += [
            "",
            "The cause model's reading (`stictiondiag/stiction/cause_model.py`: its most",
            "likely cause of the cycle, for loops with a cycle; reported beside the",
            "verdict, not decided on):",
            "",
            *cause_table(t, "cause_model"),
        ]
    return lines


def _split_half_lines(sp: dict) -> list[str]:
    """The split-half repeatability section (no labels needed)."""
    return [
        "",
        "## Split-half repeatability (no labels needed)",
        "",
        f"Every record holding at least {SPLIT_MIN_CYCLES:g} cycles of its oscillation",
        "(period from pv, else op) is cut into two halves, each analysed on its own",
        "(no replay, no gap diagnosis).",
        "",
        f"* records split: {sp.get('n', 0)}",
        f"* verdicts agree: {sp.get('agree', 0)} of {sp.get('n', 0)} ({_f(sp.get('agreement'))})",
        f"* each half's S inside the other half's S interval: {sp.get('S_within', 0)} of"
        f" {sp.get('n_S', 0)} ({_f(sp.get('S_within_share'))})",
    ]


def _wrong_loop_lines(t: pd.DataFrame) -> list[str]:
    """The labelled loops whose verdict disagrees with the expert's, with the reasons."""
    wrong = t[
        (t["label_group"] != "none") & ((t["label"] == "stiction") != (t["verdict"] == "stiction"))
    ]
    lines = [
        "",
        "## Loops we get wrong or leave inconclusive",
        "",
        "| loop | group | expert | ours | P | why, from the data |",
        "|---|---|---|---|---|---|",
    ]
    for r in wrong.itertuples():
        why = r.error if isinstance(r.error, str) and r.error else r.reasons
        lines.append(
            f"| {r.loop} | {r.label_group} | {r.label.replace('_', ' ')}"
            f"{' (' + str(r.other_fault_published) + ')' if isinstance(r.other_fault_published, str) else ''}"
            f" | {_with_cause(r)} | {_f(getattr(r, 'probability', None))} | {str(why).replace('|', '/')} |"
        )
    return lines


def _every_loop_lines(t: pd.DataFrame) -> list[str]:
    """One row per loop: the expert's label, our verdict, S and J, each classic test's
    call and the split halves' verdicts."""
    cols = " | ".join(CLASSIC_COLUMNS)
    lines = [
        "",
        "## Every loop",
        "",
        f"| loop | type | Ts [s] | expert | group | ours | P | conf. | S [%] | J [%] | {cols} | halves |",
        "|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(CLASSIC_COLUMNS) + "---|",
    ]
    for r in t.itertuples():
        halves = ""
        if isinstance(getattr(r, "split_first", None), str):
            halves = f"{r.split_first} / {r.split_second}"
        classic = " | ".join(str(getattr(r, f"baseline_{c}", "")) for c in CLASSIC_COLUMNS)
        lines.append(
            f"| {r.loop} | {r.loop_type} | {_f(r.ts_s, 'g')} | {_text(r.label, '-')} | "
            f"{r.label_group} | {_with_cause(r)} | {_f(getattr(r, 'probability', None))} | "
            f"{_f(getattr(r, 'confidence', None))} | {_f(getattr(r, 'S', None))} | "
            f"{_f(getattr(r, 'J', None))} | {classic} | {halves} |"
        )
    return lines


def render_markdown(result: ValidationResult, *, command: str) -> str:
    """The results page (``docs/isdb_validation.md``)."""
    t = result.table
    lines = [
        *_intro_lines(command),
        *_target_lines(result),
        *_score_lines(result.scores),
        *_confusion_section(t),
        *_cause_sections(t),
        *_split_half_lines(result.split),
    ]
    if result.causes:
        lines += ["", "## Gap causes against the experts", "", *render_causes(result.causes)]
    stated = t[t["label_group"] == "stated"]
    lines.append("")
    lines.append(
        "Loops counted (stated labels): "
        + ", ".join(f"{r.loop} ({r.label.replace('_', ' ')})" for r in stated.itertuples())
    )
    lines += [*_wrong_loop_lines(t), *_every_loop_lines(t)]
    return "\n".join(lines) + "\n"
