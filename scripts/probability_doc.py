"""The part of ``docs/calibration.md`` that ``scripts/train_probability.py`` writes:
how P(stiction) is trained, its reliability on the held-out simulated loops, the
choice of model and the coefficients, from :data:`GENERATED_HEADING` to
:data:`KEPT_HEADING`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from probability_features import COMPUTED, MEASURED_RUN
from probability_fit import BAND, GATE_SE, S_STRATA, TOLERANCE, C, reliability, set_name

from stictiondiag.stiction.probability import CANDIDATES, PART_FEATURES
from stictiondiag.stiction.verdict import NO_STICTION_LEVEL, STICTION_LEVEL

#: The part of the calibration doc this script writes runs from this heading to
#: :data:`KEPT_HEADING`; what stands before it (the title and the figures table) and
#: from :data:`KEPT_HEADING` on (written by hand and by ``train_cause.py``) is kept.
GENERATED_HEADING = "## How P(stiction) is trained"


KEPT_HEADING = "## Which feature set ships"


#: The head of a calibration doc written from scratch.
DEFAULT_HEAD = "# Calibration of the stiction probability\n\n"


def kept_parts(doc: Path) -> tuple[str, str]:
    """The parts of ``doc`` this script keeps: the text before
    :data:`GENERATED_HEADING` (default :data:`DEFAULT_HEAD`) and from
    :data:`KEPT_HEADING` on (default '')."""
    try:
        text = doc.read_text()
    except OSError:
        return DEFAULT_HEAD, ""
    i = text.find(GENERATED_HEADING)
    j = text.find(KEPT_HEADING)
    return (text[:i] if i >= 0 else DEFAULT_HEAD), ("\n" + text[j:] if j >= 0 else "")


def _table_lines(table) -> list[str]:
    lines = [
        "| predicted P | loops | mean prediction | observed frequency | gap |",
        "|---|---|---|---|---|",
    ]
    for r in table:
        lo, hi = r["band"]
        if r["n"]:
            gap = r["observed"] - r["mean_p"]
            lines.append(
                f"| {lo:.1f}-{hi:.1f} | {r['n']} | {r['mean_p']:.3f} | "
                f"{r['observed']:.3f} | {gap:+.3f} |"
            )
        else:
            lines.append(f"| {lo:.1f}-{hi:.1f} | 0 | | | |")
    return lines


def _choice_lines(cv, extra) -> list[str]:
    (table, n_strata), boosted, gate, (choice, same_folds), mismatch = extra
    used = {k for names in PART_FEATURES.values() for k in names}
    heads = [f"{lo:g}-{hi:g}" if math.isfinite(hi) else f"> {lo:g}" for lo, hi in S_STRATA]
    lines = [
        "Area under the ROC curve of each candidate feature alone, sticky against healthy,",
        "over the training loops without mv: all of them, then the sticky loops by S over",
        "op's 5-95 % spread (each stratum against all healthy loops; above 0.5 the feature",
        "is larger for sticky valves, below 0.5 smaller; 0.5 tells nothing):",
        "",
        "| feature | all | "
        + " | ".join(f"S/op {h} ({n})" for h, n in zip(heads, n_strata, strict=True))
        + " |",
        "|---|---|" + "---|" * len(heads),
    ]
    for k, vals in table:
        mark = "" if k in used else " (not in the model)"
        lines.append(f"| {k}{mark} | " + " | ".join(f"{v:.2f}" for v in vals) + " |")
    lines += [
        "",
        "An L2-regularised logistic regression on standardised features, one for loops",
        "with mv and one without. 5-fold cross-validated log loss on the training loops",
        "(lower is better; 0.693 is a coin), over all of them, over those without mv and",
        "over those with mv (each part fitted and cross-validated on its own loops):",
        "",
        "| features | C | log loss, all | log loss, no mv | log loss, mv |",
        "|---|---|---|---|---|",
    ]
    for (name, c), (v_all, v_nomv, v_mv) in cv.items():
        lines.append(f"| {name} | {c:g} | {v_all:.4f} | {v_nomv:.4f} | {v_mv:.4f} |")
    for name, (v_all, v_nomv) in (boosted or {}).items():
        lines.append(f"| {name} | - | {v_all:.4f} | {v_nomv:.4f} | |")
    cand = gate["candidate"]
    lines += [
        "",
        "**Which set ships.** A feature set ships only if it beats the shipped one in log",
        "loss on the held-out simulated loops, not only in cross-validation on the",
        "training loops: per part of the model, the cross-validation's choice (the set",
        f"with the lowest 5-fold log loss over that part's training loops, C = {C:g}, the"
        " same folds of all training loops for every set) is refitted on all training"
        " loops and compared with the shipped set on the held-out loops; it replaces the"
        f" shipped set only if its mean log loss is lower by more than {GATE_SE:g} standard"
        " errors of the paired per-loop difference. Within that margin simulation cannot"
        " tell the two apart and the simpler set (fewer features) is kept.",
        "",
        f"Cross-validated log loss per set, C = {C:g}, on the same folds of all training"
        " loops (the columns above for the loops with and without mv draw their own folds,"
        " which moves a log loss by about 0.005):",
        "",
        "| features | log loss, all | log loss, no mv | log loss, mv |",
        "|---|---|---|---|",
        *[f"| {k} | {a:.4f} | {b:.4f} | {m:.4f} |" for k, (a, b, m) in same_folds.items()],
        "",
        f"Cross-validation's choice: without mv {set_name(cand['op_pv'])}; with mv"
        f" {set_name(cand['mv'])}.",
        "",
        "On the held-out loops (log loss, area under the ROC curve of P, Brier score; loops",
        "without mv: also how many fall between the decision levels; all held-out loops:",
        "the calls and the share of them that is right), the shipped set and the",
        "cross-validation's choice, both refitted on the same training loops:",
        "",
        "| model | log loss, all | log loss, no mv | AUC, no mv | Brier, all |"
        " no mv: 0.3 < P < 0.7 | called stiction (sticky) | called no stiction (healthy) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for key, label in (("shipped", "shipped set"), ("candidate", "cross-validation's choice")):
        v = gate["models"][key]
        lines.append(
            f"| {label} | {v['ll']:.4f} | {v['ll_nomv']:.4f} | {v['auc_nomv']:.3f} |"
            f" {v['brier']:.3f} | {v['between']} of {v['n_nomv']} |"
            f" {v['called']} ({v['called_right']:.2f}) | {v['cleared']} ({v['cleared_right']:.2f}) |"
        )
    lines.append("")
    for part, label in (("op_pv", "without mv"), ("mv", "with mv")):
        g = gate["parts"][part]
        if gate["shipped"][part] == cand[part]:
            lines.append(
                f"* Part {label}: the cross-validation's choice is the shipped set,"
                f" {g['verdict']}; it ships."
            )
            continue
        how = (
            f"lower by more than {GATE_SE:g} standard errors"
            if g["diff"] < -GATE_SE * g["se"]
            else f"higher by more than {GATE_SE:g} standard errors"
            if g["diff"] > GATE_SE * g["se"]
            else f"within {GATE_SE:g} standard errors (simulation cannot tell them apart)"
        )
        lines.append(
            f"* Part {label} ({g['n']} held-out loops): held-out log loss"
            f" {g['ll']['candidate']:.4f} for the cross-validation's choice,"
            f" {set_name(cand[part])}, against {g['ll']['shipped']:.4f} for the shipped"
            f" {set_name(gate['shipped'][part])}: difference {g['diff']:+.4f}, standard"
            f" error {g['se']:.4f}, {how}. By the rule, {g['verdict']} ships."
        )
    lines.append("")
    if mismatch:
        lines.append(
            "**The rule's outcome differs from the features the model ships"
            f" (`PART_FEATURES` in `stictiondiag/stiction/probability.py`) for the part(s)"
            f" {', '.join(mismatch)}: change them and rerun.**"
        )
    else:
        lines.append(
            f"The model ships the rule's outcome: without mv {len(PART_FEATURES['op_pv'])}"
            f" features, with mv {len(PART_FEATURES['mv'])}; C = {C:g}."
        )
    return lines


def render(a, model, table, ok, p, y, subsets, n_train, n_test, seconds, t_feat, cv, aucs) -> str:
    brier = float(np.mean((p - y) ** 2))
    called = p > STICTION_LEVEL
    cleared = p < NO_STICTION_LEVEL
    lines = [
        GENERATED_HEADING,
        "",
        "`P(stiction)` (`stictiondiag/stiction/probability.py`) is a regularised logistic",
        "regression of the evidence of the fit, the oscillation, the classic tests' calls",
        "and the fits on each half of the record, fitted on simulated loops only",
        "(`stictiondiag/apps/family.py`: data-driven and Karnopp valves; self-regulating,",
        "integrating and cascade-slave loops; drifting, stepping and periodic loads;",
        "aggressive, normal and sluggish tuning; set-point moves; quantisation, deadband",
        "and swinging-door compression; noise from 1 % to 50 % of pv's spread, and to 150 %",
        "in a tenth of the loops; healthy",
        "and sticky valves in equal shares; mv recorded in a quarter of the loops).",
        "No real-plant record, and no ISDB label, is used to fit or choose anything.",
        "",
        "Produced by (deterministic for the given seeds and counts):",
        "",
        "```bash",
        f"python scripts/train_probability.py --n-train {a.n_train} --n-test {a.n_test} "
        f"--seed {a.seed} --test-seed {a.test_seed} --workers {a.workers}"
        + (" --compare-boosting" if a.compare_boosting else ""),
        "```",
        "",
        f"Run time: {seconds / 60:.1f} min on {a.workers} worker(s), of which"
        f" {t_feat / 60:.1f} min computing the features of {sum(COMPUTED)} loops not yet"
        " cached (under `--cache`; a fully cached run takes minutes: the cross-validation). "
        + MEASURED_RUN,
        f"Training loops: {n_train} analysed of {a.n_train} drawn (seed {a.seed}); held-out"
        f" loops: {n_test} analysed of {a.n_test} drawn (seed {a.test_seed}). Loops the"
        " analysis refuses (a record shorter than two cycles) are left out, as the tool"
        " refuses them.",
        "",
        "## Reliability on held-out simulated loops",
        "",
        f"Bands of width {BAND}; each band's observed frequency of sticky valves must lie",
        f"within {TOLERANCE} of its mean prediction: **{'met' if ok else 'NOT met'}**.",
        f"Brier score {brier:.3f}.",
        "",
        *_table_lines(table),
    ]
    for name, mask in subsets.items():
        m = np.array(mask, dtype=bool)
        if m.sum():
            lines += [
                "",
                f"Held-out loops {name} ({int(m.sum())}):",
                "",
                *_table_lines(reliability(p[m], y[m])),
            ]
    lines += [
        "",
        "## Choice of model",
        "",
        *_choice_lines(cv, aucs),
        "",
        "## Decision levels",
        "",
        f"`stiction` when P > {STICTION_LEVEL}, `no_stiction` when P < {NO_STICTION_LEVEL},",
        "`inconclusive` between (stated before any real record was analysed; see",
        "`stictiondiag/stiction/verdict.py`). On the held-out simulated loops:",
        f"{int(called.sum())} called stiction ({float(y[called].mean()) if called.any() else 0:.2f}"
        f" of them sticky), {int(cleared.sum())} called no stiction"
        f" ({float(1 - y[cleared].mean()) if cleared.any() else 0:.2f} of them healthy),"
        f" {int((~called & ~cleared).sum())} inconclusive.",
        "",
        "## Coefficients (standardised features)",
        "",
        "| feature | " + " | ".join(model["parts"]) + " |",
        "|---|" + "---|" * len(model["parts"]),
    ]
    for k in CANDIDATES:
        cells = []
        for part in model["parts"].values():
            names = part.get("features") or model["features"]
            cells.append(f"{part['coef'][names.index(k)]:+.3f}" if k in names else "")
        if any(cells):
            lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines.append(
        "| intercept | "
        + " | ".join(f"{part['intercept']:+.3f}" for part in model["parts"].values())
        + " |"
    )
    lines.append(
        "| loops (sticky) | "
        + " | ".join(f"{part['n']} ({part['n_sticky']})" for part in model["parts"].values())
        + " |"
    )
    return "\n".join(lines) + "\n"
