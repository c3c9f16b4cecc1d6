"""The Markdown page of ``stiction validate``: scores against the ISDB labels, the
targets, the confusion tables, the gap's causes against the experts', split-half
repeatability and every loop (:func:`render_markdown` of a
:class:`~stictiondiag.apps.validation.ValidationResult`).

Split from :mod:`stictiondiag.apps.validation`, which runs the validation.
"""

from __future__ import annotations

import math

import pandas as pd

from stictiondiag.apps.validation import CLASSIC_COLUMNS, SPLIT_MIN_CYCLES, ValidationResult

__all__ = ["cause_table", "render_causes", "render_markdown", "stated_auc", "targets"]


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
        "held-out simulated loops in `docs/calibration.md`), which decides: `stiction` at",
        "P(the valve causes the cycle) 0.6 or above, `no_stiction` at 0.4 or below, naming",
        "the most likely other cause, `inconclusive` between. *P* in the tables is that",
        "probability (0 for a loop without a cycle; these records have no mv, where the",
        "friction model's P(stiction) would decide instead). No threshold, weight,",
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
            "The cause model's most likely cause of the cycle (`stictiondiag/stiction/",
            "cause_model.py`), for every loop with a cycle, the undecided ones included (the",
            "verdict names the valve only at P(valve) 0.6 or above, another cause only at",
            "0.4 or below):",
            "",
            *cause_table(t, "cause_model"),
        ]
    return lines


def _typicality_lines(t: pd.DataFrame) -> list[str]:
    """How many loops read by the cause model (a cycle, no mv) lie outside 99 % of the
    simulated loops of their most likely cause (``cause_atypicality`` above 1), and
    the accuracy of the verdict on either side, per label group (reported, never
    fitted)."""
    if "cause_atypicality" not in t:
        return []
    decided = t[t["p_valve_cause"].notna() & ~t["has_mv"].astype(bool)]
    far = decided["cause_atypicality"].astype(float) > 1.0
    lines = [
        "",
        "## Records unlike the simulated loops of their cause",
        "",
        "A loop whose evidence lies outside 99 % of the simulated loops of its most likely",
        "cause (`stictiondiag.stiction.cause_model.atypicality`) gets a verdict that says",
        "its call is an extrapolation; the call itself is unchanged. Of the"
        f" {len(decided)} loops with a cycle that the cause model read,"
        f" {int(far.sum())} are atypical"
        + (": " + ", ".join(decided.loc[far, "loop"]) if far.any() else "")
        + ".",
        "",
        "| group | atypical: loops, right | others: loops, right |",
        "|---|---|---|",
    ]
    for group in ("stated", "likely"):
        g = decided["label_group"] == group
        right = (decided["label"] == "stiction") == (decided["verdict"] == "stiction")
        a, b = g & far, g & ~far
        lines.append(
            f"| {group} | {int(a.sum())}, {int((a & right).sum())} |"
            f" {int(b.sum())}, {int((b & right).sum())} |"
        )
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
        *_typicality_lines(t),
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
