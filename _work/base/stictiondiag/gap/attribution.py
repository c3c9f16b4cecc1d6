"""Which cause a departure of the replay from the data has: the fitted loop, or an effect.

A replay departs from the data for two kinds of reason:

* the fitted loop is wrong: S, J or the process were identified off (each block of
  the open-loop fit is fitted with its own recorded input, and small errors add up
  in the loop);
* an effect the two-parameter model lacks (the catalogue of
  :mod:`stictiondiag.gap.effects`).

The first shows in the closed-loop replay: how far the closed-loop refit
(:mod:`stictiondiag.replay.refit`), which changes only S, J and the process, brings
the replay's cycle (period, amplitudes, shape) back to the data's.  The second shows
in the gap diagnosis (:mod:`stictiondiag.gap.diagnose`): how far adding the effect
shrinks the gap of the driven replay, whose base is fitted to the record (so its
gap is what no change of the two-parameter loop's own parameters removes).
:func:`attribute_gap` puts the two side by side and says which, in words; where
effects could not be assessed (no mv), it says how much of the gap is left open to
them, and a gap over :data:`LARGE_GAP_PCT` left without an effect is explained.
"""

from __future__ import annotations

from typing import Any

from stictiondiag.gap.effects.signatures import SIGNATURE_P

#: A gap above this, left without an effect, is explained in words [%].
LARGE_GAP_PCT = 50.0
#: Share of the closed-loop cycle mismatch a refit must remove to call the fitted
#: loop's parameters a cause [%] (the refit's own acceptance threshold is lower).
IDENTIFICATION_SHARE_PCT = 50.0


def _f(v: Any, spec: str = ".3g") -> str:
    return "n/a" if v is None else format(float(v), spec)


def _identification(replay: dict | None) -> dict:
    """The closed-loop refit's part: mismatch before and after, share removed."""
    refit = ((replay or {}).get("settings") or {}).get("refit") or {}
    c0, c1 = refit.get("cost_open_loop"), refit.get("cost")
    out: dict[str, Any] = {
        "refit_accepted": bool(refit.get("accepted")),
        "mismatch_open_loop": c0,
        "mismatch_refit": c1,
        "removed_pct": None,
        "S_open_loop": refit.get("S_open_loop"),
        "J_open_loop": refit.get("J_open_loop"),
        "S_refit": refit.get("S"),
        "J_refit": refit.get("J"),
        "reason": refit.get("reason"),
    }
    if c0 is not None and c1 is not None and c0 > 0:
        out["removed_pct"] = 100.0 * (1.0 - c1 / c0)
    return out


def _largest_signal(gap: dict) -> str | None:
    """The signal that holds most of the gap before, from the breakdown."""
    per = ((gap.get("breakdown") or {}).get("signal")) or {}
    vals = {s: v.get("before") for s, v in per.items() if v.get("before") is not None}
    return max(vals, key=lambda s: vals[s]) if vals else None


def _why_rejected(c: dict, heldout_before: float | None) -> str:
    """Which test a candidate failed, in words, from its reported results."""
    failed_sig = [
        (k, v)
        for k, v in (c.get("params") or {}).items()
        if k.endswith("_p") and v is not None and float(v) >= SIGNATURE_P
    ]
    if failed_sig:
        k, v = failed_sig[0]
        return (
            f"its own signature is not in the data ({k.removesuffix('_p')}: p = "
            f"{_f(v, '.2g')}, above {SIGNATURE_P:g})"
        )
    held = c.get("heldout")
    if held is not None and heldout_before is not None and held >= heldout_before:
        return (
            f"on held-out blocks it does no better than the two-parameter replay "
            f"({_f(held)} % against {_f(heldout_before)} %)"
        )
    k = c.get("n_params")
    what = "extra parameters" if k is None else f"{k} extra parameter{'' if k == 1 else 's'}"
    return (
        f"its gain on held-out blocks does not pay for its {what}, or the blocks do not bear it out"
    )


def _why_none(gap: dict) -> str:
    """Why no effect is named on a large gap, from the candidates' results: where
    the gap lies, the closest candidate and the test it failed."""
    cands = [c for c in gap.get("candidates") or [] if c.get("after") is not None]
    where = _largest_signal(gap)
    lead = ""
    if where == "op":
        lead = (
            "most of it is in op, the controller's replay, which no effect of the "
            "catalogue changes; "
        )
    elif where is not None:
        lead = f"most of it is in {where}; "
    if not cands:
        return lead + "no effect of the catalogue could be fitted to this record"
    best = min(cands, key=lambda c: c["after"])
    before = gap.get("before")
    if before is not None and best["after"] >= before:
        return lead + (
            f"no candidate lowers it on the record (the closest, {best.get('effect')}, "
            f"leaves {_f(best['after'])} %)"
        )
    return lead + (
        f"the closest candidate, {best.get('effect')}, lowers it to "
        f"{_f(best.get('after'))} % on the record but is not named: "
        + _why_rejected(best, gap.get("heldout_before"))
    )


def attribute_gap(replay: dict | None, gap: dict | None) -> dict:
    """The cause of the departure, the figures behind it and a sentence saying which.

    ``replay`` and ``gap`` are the ``replay`` and ``gap`` entries of
    :meth:`stictiondiag.analysis.Analysis.to_dict` (either may be None).  Returns
    ``identification`` (the closed-loop refit's mismatch before and after [-] and
    the share removed [%]), ``effect``, ``before`` and ``after`` [%] of the gap,
    ``not_assessed`` (effects) with ``open_gap_pct`` (the gap they are left [%]),
    ``cause`` (``fitted_loop``, ``effect``, ``both`` or ``unexplained``; ``none``
    for a gap of 0) and ``text``.
    """
    ident = _identification(replay)
    gap = gap or {}
    effect = gap.get("effect")
    before, after = gap.get("before"), gap.get("after")
    not_assessed = list(gap.get("not_assessed") or [])
    named = bool(effect) and effect != "none"
    removed = ident["removed_pct"]
    loop_wrong = bool(ident["refit_accepted"]) and (removed or 0.0) >= IDENTIFICATION_SHARE_PCT
    parts: list[str] = []
    if ident["refit_accepted"]:
        same_valve = (ident["S_open_loop"], ident["J_open_loop"]) == (
            ident["S_refit"],
            ident["J_refit"],
        )
        what = (
            "the process (S and J kept)"
            if same_valve
            else (
                f"S, J and the process (S {_f(ident['S_open_loop'], '.2f')} to "
                f"{_f(ident['S_refit'], '.2f')}, J {_f(ident['J_open_loop'], '.2f')} to "
                f"{_f(ident['J_refit'], '.2f')} % of span)"
            )
        )
        parts.append(
            f"the fitted loop is {'the main' if loop_wrong else 'a minor'} cause: refitting "
            f"{what} in closed loop removes {_f(removed, '.0f')} % of the replay's cycle "
            f"mismatch ({_f(ident['mismatch_open_loop'])} to {_f(ident['mismatch_refit'])})"
        )
    elif ident["mismatch_open_loop"] is not None:
        parts.append(
            "the fitted loop is not the cause: "
            + (ident["reason"] or "the closed-loop refit does not improve its replay")
        )
    if not gap:
        cause = "fitted_loop" if loop_wrong else "unexplained"
    elif named:
        parts.append(
            f"an unmodelled effect, {effect}, shrinks the driven replay's gap from "
            f"{_f(before)} % to {_f(after)} % ({_f(gap.get('shrink_pct'), '.0f')} %)"
        )
        cause = "both" if loop_wrong else "effect"
    elif not before:
        parts.append("the replay of the fitted loop is within the data's noise")
        cause = "fitted_loop" if loop_wrong else "none"
    else:
        text = (
            f"no unmodelled effect of the catalogue explains the driven replay's gap of "
            f"{_f(before)} %"
        )
        if before is not None and before > LARGE_GAP_PCT:
            text += ": " + _why_none(gap)
        parts.append(text)
        cause = "fitted_loop" if loop_wrong else "unexplained"
    open_gap = None
    if gap and not_assessed:
        open_gap = after if after is not None else before
        parts.append(
            f"{len(not_assessed)} effects could not be assessed without mv "
            f"({', '.join(not_assessed)}): the {_f(open_gap)} % left is open to them"
        )
    return {
        "identification": ident,
        "effect": effect,
        "before": before,
        "after": after,
        "not_assessed": not_assessed,
        "open_gap_pct": open_gap,
        "cause": cause,
        "text": "; ".join(parts),
    }
