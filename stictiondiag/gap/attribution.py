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
:func:`attribute_gap` puts the two side by side and says which, in words
(:class:`GapAttribution`, its cause a :class:`GapCause`); where effects could not be
assessed (no mv), it says how much of the gap is left open to them, and a gap over
:data:`LARGE_GAP_PCT` left without an effect is explained.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

from stictiondiag.core.serialize import plain_float, to_plain
from stictiondiag.gap.effects.signatures import SIGNATURE_P

if TYPE_CHECKING:
    from stictiondiag.gap.result import Candidate, GapDiagnosis
    from stictiondiag.replay.refit import ClosedLoopRefit

#: A gap above this, left without an effect, is explained in words [%].
LARGE_GAP_PCT = 50.0
#: Share of the closed-loop cycle mismatch a refit must remove to call the fitted
#: loop's parameters a cause [%] (the refit's own acceptance threshold is lower).
IDENTIFICATION_SHARE_PCT = 50.0


def _f(v: Any, spec: str = ".3g") -> str:
    return "n/a" if v is None else format(float(v), spec)


class GapCause(str, Enum):
    """Which cause a departure of the replay from the data has."""

    #: The fitted loop: the closed-loop refit removes most of the cycle mismatch.
    FITTED_LOOP = "fitted_loop"
    #: An unmodelled effect of the catalogue, named by the gap diagnosis.
    EFFECT = "effect"
    #: Both of them.
    BOTH = "both"
    #: Neither explains the gap.
    UNEXPLAINED = "unexplained"
    #: There is no gap beyond the data's noise.
    NONE = "none"


@dataclass(frozen=True)
class RefitShare:
    """The closed-loop refit's part in a departure.

    Attributes
    ----------
    refit_accepted : bool
        The refit replaced the open-loop fit.
    mismatch_open_loop, mismatch_refit : float or None
        Cycle mismatch of the replay before and after the refit [-]; None where not
        measured (no refit, or no cycle).
    removed_pct : float or None
        Share of the mismatch the refit removed [%].
    S_open_loop, J_open_loop, S_refit, J_refit : float or None
        S and J before and after the refit [% of span].
    reason : str or None
        Why the refit was or was not run or kept, in words.
    """

    refit_accepted: bool = False
    mismatch_open_loop: float | None = None
    mismatch_refit: float | None = None
    removed_pct: float | None = None
    S_open_loop: float | None = None
    J_open_loop: float | None = None
    S_refit: float | None = None
    J_refit: float | None = None
    reason: str | None = None


@dataclass(frozen=True)
class GapAttribution:
    """The cause of a departure, the figures behind it and a sentence saying which.

    Attributes
    ----------
    identification : RefitShare
        The closed-loop refit's mismatch before and after and the share removed.
    effect : str or None
        The effect the gap diagnosis named (``none`` for none); None without one.
    before, after : float or None
        The driven replay's gap before and after the effect [%].
    not_assessed : tuple of str
        Effects that could not be assessed (no mv).
    open_gap_pct : float or None
        The gap left open to the effects not assessed [%].
    cause : GapCause
    text : str
        The attribution in words.
    """

    identification: RefitShare
    effect: str | None
    before: float | None
    after: float | None
    not_assessed: tuple[str, ...]
    open_gap_pct: float | None
    cause: GapCause
    text: str

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict."""
        return to_plain(
            {
                "identification": vars(self.identification),
                "effect": self.effect,
                "before": self.before,
                "after": self.after,
                "not_assessed": list(self.not_assessed),
                "open_gap_pct": self.open_gap_pct,
                "cause": self.cause,
                "text": self.text,
            }
        )


def _identification(refit: ClosedLoopRefit | None) -> RefitShare:
    """The closed-loop refit's part: mismatch before and after, share removed."""
    if refit is None:
        return RefitShare()
    c0, c1 = plain_float(refit.cost_open_loop), plain_float(refit.cost)
    removed = None
    if c0 is not None and c1 is not None and c0 > 0:
        removed = 100.0 * (1.0 - c1 / c0)
    return RefitShare(
        refit_accepted=bool(refit.accepted),
        mismatch_open_loop=c0,
        mismatch_refit=c1,
        removed_pct=removed,
        S_open_loop=plain_float(refit.S_open_loop),
        J_open_loop=plain_float(refit.J_open_loop),
        S_refit=plain_float(refit.S),
        J_refit=plain_float(refit.J),
        reason=refit.reason,
    )


def _largest_signal(gap: GapDiagnosis) -> str | None:
    """The signal that holds most of the gap before, from the breakdown."""
    return None if gap.breakdown is None else gap.breakdown.largest_signal()


def _why_rejected(c: Candidate, heldout_before: float | None) -> str:
    """Which test a candidate failed, in words, from its reported results."""
    test, v = c.params.SIGNATURE, plain_float(c.params.signature_p())
    if test is not None and v is not None and v >= SIGNATURE_P:
        return (
            f"its own signature is not in the data ({test.removesuffix('_p')}: p = "
            f"{_f(v, '.2g')}, above {SIGNATURE_P:g})"
        )
    held = plain_float(c.heldout)
    if held is not None and heldout_before is not None and held >= heldout_before:
        return (
            f"on held-out blocks it does no better than the two-parameter replay "
            f"({_f(held)} % against {_f(heldout_before)} %)"
        )
    k = c.n_params
    what = "extra parameters" if k is None else f"{k} extra parameter{'' if k == 1 else 's'}"
    return (
        f"its gain on held-out blocks does not pay for its {what}, or the blocks do not bear it out"
    )


def _why_none(gap: GapDiagnosis) -> str:
    """Why no effect is named on a large gap, from the candidates' results: where
    the gap lies, the closest candidate and the test it failed."""
    cands = [c for c in gap.candidates if plain_float(c.after) is not None]
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
    best = min(cands, key=lambda c: c.after)
    before = plain_float(gap.before)
    if before is not None and best.after >= before:
        return lead + (
            f"no candidate lowers it on the record (the closest, {best.effect}, "
            f"leaves {_f(best.after)} %)"
        )
    return lead + (
        f"the closest candidate, {best.effect}, lowers it to "
        f"{_f(best.after)} % on the record but is not named: "
        + _why_rejected(best, plain_float(gap.heldout_before))
    )


def attribute_gap(refit: ClosedLoopRefit | None, gap: GapDiagnosis | None) -> GapAttribution:
    """The cause of the departure, the figures behind it and a sentence saying which.

    ``refit`` is the replay's closed-loop refit (``Replay.settings.refit``) and
    ``gap`` the gap diagnosis (either may be None).
    """
    ident = _identification(refit)
    effect = None if gap is None else gap.effect
    before = None if gap is None else plain_float(gap.before)
    after = None if gap is None else plain_float(gap.after)
    not_assessed = () if gap is None else tuple(gap.not_assessed)
    named = bool(effect) and effect != "none"
    removed = ident.removed_pct
    loop_wrong = ident.refit_accepted and (removed or 0.0) >= IDENTIFICATION_SHARE_PCT
    parts: list[str] = []
    if ident.refit_accepted:
        same_valve = (ident.S_open_loop, ident.J_open_loop) == (ident.S_refit, ident.J_refit)
        what = (
            "the process (S and J kept)"
            if same_valve
            else (
                f"S, J and the process (S {_f(ident.S_open_loop, '.2f')} to "
                f"{_f(ident.S_refit, '.2f')}, J {_f(ident.J_open_loop, '.2f')} to "
                f"{_f(ident.J_refit, '.2f')} % of span)"
            )
        )
        parts.append(
            f"the fitted loop is {'the main' if loop_wrong else 'a minor'} cause: refitting "
            f"{what} in closed loop removes {_f(removed, '.0f')} % of the replay's cycle "
            f"mismatch ({_f(ident.mismatch_open_loop)} to {_f(ident.mismatch_refit)})"
        )
    elif ident.mismatch_open_loop is not None:
        parts.append(
            "the fitted loop is not the cause: "
            + (ident.reason or "the closed-loop refit does not improve its replay")
        )
    if gap is None:
        cause = GapCause.FITTED_LOOP if loop_wrong else GapCause.UNEXPLAINED
    elif named:
        parts.append(
            f"an unmodelled effect, {effect}, shrinks the driven replay's gap from "
            f"{_f(before)} % to {_f(after)} % ({_f(plain_float(gap.shrink_pct), '.0f')} %)"
        )
        cause = GapCause.BOTH if loop_wrong else GapCause.EFFECT
    elif not before:
        parts.append("the replay of the fitted loop is within the data's noise")
        cause = GapCause.FITTED_LOOP if loop_wrong else GapCause.NONE
    else:
        text = (
            f"no unmodelled effect of the catalogue explains the driven replay's gap of "
            f"{_f(before)} %"
        )
        if before is not None and before > LARGE_GAP_PCT:
            text += ": " + _why_none(gap)
        parts.append(text)
        cause = GapCause.FITTED_LOOP if loop_wrong else GapCause.UNEXPLAINED
    open_gap = None
    if gap is not None and not_assessed:
        open_gap = after if after is not None else before
        parts.append(
            f"{len(not_assessed)} effects could not be assessed without mv "
            f"({', '.join(not_assessed)}): the {_f(open_gap)} % left is open to them"
        )
    return GapAttribution(
        identification=ident,
        effect=effect,
        before=before,
        after=after,
        not_assessed=not_assessed,
        open_gap_pct=open_gap,
        cause=cause,
        text="; ".join(parts),
    )
