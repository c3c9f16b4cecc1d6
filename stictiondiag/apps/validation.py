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

from stictiondiag.core.errors import DataError

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
    return Path(__file__).resolve().parents[1].parent / "shared" / "data" / "isdb"


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


def _baselines(path: str, ts: float, integrating: bool) -> dict:
    from stictiondiag.stiction import classic

    frame = pd.read_csv(path)
    pv = frame["pv"].to_numpy(float)
    op = frame["op"].to_numpy(float)
    sp = frame["sp"].to_numpy(float) if "sp" in frame else None
    ok = np.isfinite(pv) & np.isfinite(op)
    pv, op = pv[ok], op[ok]
    sp = sp[ok] if sp is not None else None
    out: dict = {}
    try:
        h = classic.horch_cross_correlation(op, pv, ts, integrating=integrating)
        out["horch"] = h.verdict
    except Exception as exc:  # a baseline failing must not hide ours
        out["horch"] = f"error: {type(exc).__name__}"
    try:
        hos = classic.choudhury_hos(op, pv, sp, ts)
        out["bicoherence"] = hos.verdict
    except Exception as exc:
        out["bicoherence"] = f"error: {type(exc).__name__}"
    return out


def validate_one(source, gap: bool) -> dict:
    """Analyse one ISDB loop and run the baselines (for a worker process)."""
    from stictiondiag.apps.scan import analyse_source

    res = analyse_source(source, {}, gap)
    opts = source.read_options or {}
    res["baselines"] = _baselines(source.path, opts.get("ts") or 1.0, bool(opts.get("integrating")))
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
    """

    table: pd.DataFrame
    scores: dict = field(default_factory=dict)


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
    scores = {
        "ours": score(table, "verdict", _called_stiction),
        "horch": score(table, "baseline_horch", _called_stiction),
        "bicoherence": score(table, "baseline_bicoherence", _called_stiction),
    }
    return ValidationResult(table, scores)


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


def render_markdown(result: ValidationResult, *, command: str) -> str:
    """The results page (``docs/isdb_validation.md``)."""
    t, sc = result.table, result.scores
    lines = [
        "# Validation on the International Stiction Database",
        "",
        "Real industrial loops (pv, op, sp; no mv) from Jelali & Huang (2010), read from",
        "`../shared/data/isdb/` (no open licence: never copied here). Produced by:",
        "",
        f"```bash\n{command}\n```",
        "",
        "Labels are the published ISDB comments (see `stictiondiag/validation.py`):",
        "*stated* (stiction stated, no stiction stated, or another diagnosis stated),",
        '*likely* ("with stiction (likely)", "with disturbance (likely)"), and *none*.',
        "A loop counts as *called stiction* only when the verdict is `stiction`;",
        "`inconclusive` counts as not called.",
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
                f"| {method} | {group} | {s['n']} | {s['tp']} | {s['fn']} | {s['fp']} | {s['tn']} | "
                f"{_f(s['accuracy'])} | {s['inconclusive'] if method == 'ours' else ''} |"
            )
        lines.append(
            f"| {method} | none | {groups['none']['n']} | called stiction: "
            f"{groups['none']['called_stiction']} | | | | | |"
        )
    lines += [
        "",
        "*inconclusive* is the tool declining to call a loop: the oscillation is there",
        "but the record does not pin S down (its interval reaches 0), or it does not",
        "bound S below 2 % of span. Each such loop carries its reason below. In the",
        "per-loop table, *not run* in the gap column means the record is too short for",
        "the gap diagnosis or the loop could not be replayed (the flag says which).",
    ]
    stated = t[t["label_group"] == "stated"]
    lines += [
        "",
        "## Confusion matrix, stated labels (ours)",
        "",
        "| expert \\ ours | stiction | inconclusive | no stiction | error |",
        "|---|---|---|---|---|",
    ]
    for lab in ("stiction", "no_stiction"):
        g = stated[stated["label"] == lab]
        counts = [
            int((g["verdict"] == v).sum())
            for v in ("stiction", "inconclusive", "no_stiction", "error")
        ]
        lines.append(f"| {lab.replace('_', ' ')} | " + " | ".join(str(c) for c in counts) + " |")
    lines.append("")
    lines.append(
        "Loops counted (stated labels): "
        + ", ".join(f"{r.loop} ({r.label.replace('_', ' ')})" for r in stated.itertuples())
    )
    wrong = t[
        (t["label_group"] != "none") & ((t["label"] == "stiction") != (t["verdict"] == "stiction"))
    ]
    lines += [
        "",
        "## Loops we get wrong",
        "",
        "| loop | group | expert | ours | why, from the data |",
        "|---|---|---|---|---|",
    ]
    for r in wrong.itertuples():
        why = r.error if isinstance(r.error, str) and r.error else r.reasons
        lines.append(
            f"| {r.loop} | {r.label_group} | {r.label.replace('_', ' ')}"
            f"{' (' + str(r.other_fault_published) + ')' if isinstance(r.other_fault_published, str) else ''}"
            f" | {r.verdict} | {str(why).replace('|', '/')} |"
        )
    lines += [
        "",
        "## Every loop",
        "",
        "| loop | type | Ts [s] | expert | group | ours | conf. | S [%] | J [%] | gap effect | Horch | bicoherence |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in t.itertuples():
        lines.append(
            f"| {r.loop} | {r.loop_type} | {_f(r.ts_s, 'g')} | {_text(r.label, '-')} | {r.label_group} | "
            f"{r.verdict} | {_f(getattr(r, 'confidence', None))} | {_f(getattr(r, 'S', None))} | "
            f"{_f(getattr(r, 'J', None))} | {_text(getattr(r, 'gap_effect', None), 'not run')} | "
            f"{getattr(r, 'baseline_horch', '')} | {getattr(r, 'baseline_bicoherence', '')} |"
        )
    return "\n".join(lines) + "\n"
