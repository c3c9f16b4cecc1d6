"""The stiction verdict (Section 5.3): is there an oscillation, and does the stiction
model explain it better than a linear valve, by how much, and how consistently over
the cycles.

The two estimators (:func:`stictiondiag.stiction.segments.estimate_from_mv` and
:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`) each return a
:class:`~stictiondiag.stiction.valvefit.StictionFit`; :func:`stiction_verdict` turns one
into a :class:`Verdict`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.serialize import to_plain as _plain
from stictiondiag.stiction.valvefit import StictionFit


@dataclass(frozen=True)
class Verdict:
    """Is the oscillation caused by valve stiction?

    Attributes
    ----------
    status : str
        ``"stiction"``, ``"no_stiction"`` or ``"inconclusive"``.
    detected : bool or None
        True for stiction, False for no stiction, None when inconclusive.
    confidence : float
        Support for ``status`` in [0, 1], measured from the data (see
        :func:`stiction_verdict` for the formula); for ``"inconclusive"`` it is the
        support for stiction, which fell between the decision levels.
    reasons : tuple of str
        Human-readable reasons, most important first.
    evidence : dict
        The measured quantities behind the decision (JSON-able).
    """

    status: str
    detected: bool | None
    confidence: float
    reasons: tuple[str, ...]
    evidence: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        return _plain(
            {
                "status": self.status,
                "verdict": self.status,
                "detected": self.detected,
                "confidence": self.confidence,
                "reasons": list(self.reasons),
                "evidence": self.evidence,
            }
        )



# --------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------

#: Smallest share of the linear valve's residual the stiction model must remove for
#: the improvement to count as material [-].
MIN_IMPROVEMENT = 0.1

#: Bootstrap support needed to call stiction (and 1 minus it to call no stiction).
DECISION_LEVEL = 0.95

#: "No stiction" is said only when the record bounds S below this [% of span]: a
#: linear valve that explains the data as well as a sticky one is no evidence of a
#: healthy valve when the fit leaves S anywhere up to several % (a record without
#: clear cycles, disturbed by loads and set-point changes).  Stiction of a few % of
#: span is what the paper's industrial loops show (Section 3).
RULE_OUT_S = 2.0

#: Bootstrap resamples of the per-cycle costs.
N_BOOTSTRAP = 2000


def improvement_support(
    block_stiction: np.ndarray,
    block_linear: np.ndarray,
    min_improvement: float = MIN_IMPROVEMENT,
    n_boot: int = N_BOOTSTRAP,
    seed: int = 0,
) -> tuple[float, float, tuple[float, float]]:
    """Bootstrap support that the stiction model beats the linear valve materially.

    The residual sums of squares of both models are cut into blocks about one cycle
    long; blocks are resampled with replacement (a block bootstrap, so the
    correlation within a cycle is kept) and for each resample the improvement
    ``1 - sum(SSE_stiction) / sum(SSE_linear)`` is recomputed.

    Returns
    -------
    support : float
        Share of resamples with an improvement above ``min_improvement`` [-].
    improvement : float
        Improvement on the whole record [-].
    interval : (float, float)
        2.5 and 97.5 percentiles of the resampled improvement [-].
    """
    bs = np.asarray(block_stiction, dtype=float)
    bl = np.asarray(block_linear, dtype=float)
    tot = float(bl.sum())
    if bs.size == 0 or bs.size != bl.size or not tot > 0:
        return 0.0, 0.0, (0.0, 0.0)
    f = 1.0 - float(bs.sum()) / tot
    if bs.size < 2:
        return float(f > min_improvement), f, (f, f)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, bs.size, size=(n_boot, bs.size))
    num = bs[idx].sum(axis=1)
    den = bl[idx].sum(axis=1)
    fb = 1.0 - num / np.where(den > 0, den, np.inf)
    lo, hi = np.percentile(fb, [2.5, 97.5])
    return float(np.mean(fb > min_improvement)), f, (float(lo), float(hi))


def _osc_text(name: str, osc) -> str:
    if osc is None:
        return f"{name}: not analysed"
    if getattr(osc, "present", False):
        per = getattr(osc, "period_s", None)
        reg = getattr(osc, "regularity", None)
        per_s = f"period {per:.4g} s" if per is not None else "period unknown"
        reg_s = f", regularity {reg:.2g}" if reg is not None else ""
        return f"{name} oscillates ({per_s}{reg_s})"
    why = getattr(osc, "reason", None)
    return f"no oscillation in {name}" + (f" ({why})" if why else "")


def stiction_verdict(
    fit: StictionFit,
    oscillation,
    *,
    oscillation_op=None,
    has_mv: bool | None = None,
    short_record: bool = False,
    min_improvement: float = MIN_IMPROVEMENT,
    decision_level: float = DECISION_LEVEL,
    seed: int = 0,
) -> Verdict:
    """Does valve stiction explain the loop's oscillation?

    The question of Section 5.3 of Choudhury, Thornhill & Shah (2005), asked of
    the data: is there an oscillation at all (Sections 4.2.2 and 5.3: stiction shows
    as a limit cycle), does the stiction model explain the data better than a linear
    valve, by how much, consistently over the cycles, and are S and J determined.

    Parameters
    ----------
    fit : StictionFit
        From :func:`stictiondiag.stiction.segments.estimate_from_mv` or
        :func:`stictiondiag.stiction.hammerstein.fit_hammerstein`.
    oscillation : Oscillation
        :func:`stictiondiag.signals.oscillation.detect_oscillation` of pv.
    oscillation_op : Oscillation, optional
        The same for op; an oscillation in either counts.
    has_mv : bool, optional
        Whether the valve position was recorded; default from ``fit.method``.
    short_record : bool
        The record shows a regular cycle but holds fewer periods of it than the
        oscillation test needs (:func:`stictiondiag.analysis.check_record_length`):
        the missing oscillation is then no evidence against stiction.
    min_improvement : float
        Share of the linear valve's residual the stiction model must remove to count
        as a material improvement [-].
    decision_level : float
        Support needed for a decision [-].
    seed : int
        Seed of the bootstrap.

    Returns
    -------
    Verdict

    Notes
    -----
    The evidence is the bootstrap support ``P`` of :func:`improvement_support`: the
    share of block resamples (blocks about one cycle long) in which the stiction
    model removes more than ``min_improvement`` of the residual the linear valve
    leaves.  It measures at once *how much* (the threshold) and *how consistently*
    (the resampling over cycles) the stiction model does better.

    * An oscillation, ``P >= decision_level`` and S determined (its interval excludes
      0 and stays inside the search range): **stiction**, confidence ``P``.
    * An oscillation and ``P <= 1 - decision_level``, or ``P < 0.5`` with a linear
      valve (S = 0) inside the S interval: **no stiction**, confidence ``1 - P``.
    * No regular oscillation in pv or op: **no stiction**, confidence ``1 - P``,
      unless the valve evidence itself shows repeated stick-slip
      (``P >= decision_level``, at least three slips, S determined; on a short
      record the support over at least three blocks): then
      **stiction**, confidence ``P`` (or **inconclusive** when ``P`` is that high
      but S is not determined).  With mv recorded that is the valve seen
      sticking; without, a valve model that explains pv by its slips.  When the
      record is merely too short to confirm its cycle (``short_record``), the
      missing oscillation proves nothing: **no stiction** then needs
      ``P <= 1 - decision_level`` (a linear valve explains pv as well), and
      anything between is **inconclusive**.  Plant
      stiction cycles are often too irregular for the regularity test of
      :func:`stictiondiag.signals.oscillation.detect_oscillation` (its r > 1), and a fit
      whose band excludes zero and beats a linear valve in 95 % of the cycle
      resamples is evidence of its own.
    * Otherwise **inconclusive** (weak or inconsistent improvement, or S poorly
      determined), confidence ``P`` (the support for stiction).
    * Every **no stiction** above also needs the S interval to end below
      :data:`RULE_OUT_S`; where the record leaves a larger S open the verdict is
      **inconclusive** and says how much stiction is not ruled out.

    The confidence is therefore never set by hand: it is a bootstrap share computed
    from the fit's residuals.
    """
    if has_mv is None:
        has_mv = fit.method == "mv_segments"
    d = fit.details or {}
    blocks = d.get("block_sse") or {}
    bs = np.asarray(blocks.get("stiction", []), dtype=float)
    bl = np.asarray(blocks.get("linear", []), dtype=float)
    if bs.size == 0:
        bs, bl = np.array([fit.cost]), np.array([fit.linear_cost])
    P, f, f_iv = improvement_support(bs, bl, min_improvement, seed=seed)

    osc_pv = bool(getattr(oscillation, "present", False))
    osc_op = bool(getattr(oscillation_op, "present", False)) if oscillation_op else False
    oscillating = osc_pv or osc_op

    S_iv = fit.S_interval
    S_open = "reaches the search limit" in str((d.get("determinacy") or {}).get("S", ""))
    S_excludes_zero = S_iv is not None and S_iv[0] > 0.0
    S_determined = S_excludes_zero and not S_open
    n_slips = int((d.get("segments") or {}).get("n_slips", fit.n_slips))

    fit_text = (
        f"S = {fit.S:.3g} %"
        + (f" [{S_iv[0]:.3g}, {S_iv[1]:.3g}]" if S_iv else "")
        + f", J = {fit.J:.3g} %"
        + (f" [{fit.J_interval[0]:.3g}, {fit.J_interval[1]:.3g}]" if fit.J_interval else "")
        + f" of span ({'valve position' if has_mv else 'op and pv'})"
    )
    improve_text = (
        f"the stiction model removes {100 * f:.0f} % of the linear valve's residual "
        f"(95 % interval over cycles {100 * f_iv[0]:.0f} to {100 * f_iv[1]:.0f} %; "
        f"support {P:.2f} for more than {100 * min_improvement:.0f} %"
        + (
            f"; only {bs.size} cycle block(s), too few to measure consistency"
            if bs.size < 3
            else ""
        )
        + ")"
    )
    osc_texts = [_osc_text("pv", oscillation)]
    if oscillation_op is not None:
        osc_texts.append(_osc_text("op", oscillation_op))
    det_texts = []
    if not S_excludes_zero:
        det_texts.append("S cannot be told apart from 0 (no stick band)")
    elif S_open:
        det_texts.append("S poorly determined: its interval reaches the search limit")
    if d.get("J_confounded_with_gain"):
        det_texts.append(
            "J not determined without mv: the fitted valve never moves smoothly, so its "
            "jump trades off against the process gain"
        )

    evidence = {
        "oscillation_pv": osc_pv,
        "oscillation_op": osc_op,
        "improvement": f,
        "improvement_interval": list(f_iv),
        "support": P,
        "min_improvement": min_improvement,
        "decision_level": decision_level,
        "n_blocks": int(bs.size),
        "S_determined": bool(S_determined),
        "n_slips": n_slips,
        "has_mv": bool(has_mv),
        "short_record": bool(short_record),
        "confidence_formula": (
            "support = share of block-bootstrap resamples (one-cycle blocks) in which the "
            "stiction model removes more than min_improvement of the linear valve's "
            "residual; confidence = support (stiction, inconclusive) or 1 - support "
            "(no stiction)"
        ),
    }

    if not oscillating:
        # A record too short to confirm its cycle must show the improvement over at
        # least three blocks: a bootstrap over fewer measures no consistency.
        enough_blocks = bs.size >= 3 or not short_record
        if P >= decision_level and n_slips >= 3 and S_determined and enough_blocks:
            source = (
                "the recorded valve position sticks and slips"
                if has_mv
                else "the valve model explains pv by repeated slips"
            )
            return Verdict(
                "stiction",
                True,
                P,
                (
                    f"{source} ({n_slips} slips) although the cycle is not regular",
                    *osc_texts,
                    improve_text,
                    fit_text,
                ),
                evidence,
            )
        if P >= decision_level:
            return Verdict(
                "inconclusive",
                None,
                P,
                (
                    "no regular oscillation, but the valve model fits better than a linear "
                    "valve: " + improve_text,
                    *det_texts,
                    *osc_texts,
                    fit_text,
                ),
                evidence,
            )
        if short_record and P > 1.0 - decision_level:
            return Verdict(
                "inconclusive",
                None,
                P,
                (
                    "the record is too short to confirm or rule out a limit cycle, and the "
                    "valve model's evidence is not decisive: " + improve_text,
                    *det_texts,
                    *osc_texts,
                    fit_text,
                ),
                evidence,
            )
        if short_record:
            reasons = (
                "a linear valve explains pv as well (the record is too short to confirm "
                "its cycle): " + improve_text,
                *osc_texts,
                fit_text,
            )
        else:
            reasons = (*osc_texts, "nothing for stiction to explain", improve_text)
        return _no_stiction_unless_open(P, reasons, S_iv, fit_text, evidence)

    if P >= decision_level and S_determined:
        return Verdict(
            "stiction", True, P, (improve_text, fit_text, *osc_texts, *det_texts), evidence
        )
    if P <= 1.0 - decision_level or (not S_excludes_zero and P < 0.5):
        return _no_stiction_unless_open(
            P,
            ("a linear valve explains the oscillation as well: " + improve_text, *osc_texts),
            S_iv,
            fit_text,
            evidence,
        )
    why = (
        "the improvement over a linear valve is weak or not consistent over the cycles"
        if P < decision_level
        else "the stiction parameters are poorly determined"
    )
    return Verdict(
        "inconclusive", None, P, (why, improve_text, *det_texts, fit_text, *osc_texts), evidence
    )


def _no_stiction_unless_open(P, reasons, S_iv, fit_text, evidence) -> Verdict:
    """**No stiction** (confidence ``1 - P``) when the S interval's upper end is below
    :data:`RULE_OUT_S`; otherwise **inconclusive** (confidence ``P``): the record does
    not rule out a sticky valve of that size."""
    upper = None if S_iv is None else float(S_iv[1])
    evidence = {**evidence, "S_upper": upper, "rule_out_S": RULE_OUT_S}
    if upper is not None and upper >= RULE_OUT_S:
        return Verdict(
            "inconclusive",
            None,
            P,
            (
                f"stiction up to S = {upper:.3g} % of span is not ruled out by the record "
                f"(no stiction needs S bounded below {RULE_OUT_S:g} %)",
                *reasons,
                fit_text,
            ),
            evidence,
        )
    return Verdict("no_stiction", False, 1.0 - P, (*reasons, fit_text), evidence)
