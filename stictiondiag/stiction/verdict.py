"""The stiction verdict (Section 5.3): is there an oscillation, and does the stiction
model explain it better than a linear valve, by how much, and how consistently over
the cycles; answered with one calibrated probability.

The evidence (the fit's improvement over a linear valve and its bootstrap support
over the cycles, the S interval, the oscillation and its regularity, the classic
tests' calls) is combined into ``P(stiction)`` by
:mod:`stictiondiag.stiction.probability`, a model fitted on simulated loops only.
The verdict is asked in two stages (:mod:`stictiondiag.stiction.cause`):

1. Is there a cycle to explain?  A loop without a limit cycle is ``no_stiction``
   (cause ``none``: the valve is not driving an oscillation), unless its valve
   shows stick-slip directly (recorded mv, Kano's stuck sections, a Hammerstein
   improvement that holds over the record).
2. What causes the cycle?  A loop with a cycle and without mv follows the cause
   model (:mod:`stictiondiag.stiction.cause_model`: P of the valve, the tuning, an
   external oscillation or another nonlinearity causing the cycle, trained on
   counterfactual twins of simulated loops): ``stiction`` when P(the valve causes
   the cycle) is at least :data:`VALVE_LEVEL`, ``no_stiction`` with the most likely
   other cause when it is at most ``1 - VALVE_LEVEL``, ``inconclusive`` between.
   On held-out simulated loops with a cycle it answers that question better than
   P(stiction), which asks whether the valve has any friction
   (``scripts/verdict_rule.py``, docs/calibration.md, "Which probability decides a
   loop with a cycle").  A loop with mv, or without the cause model installed,
   follows P(stiction): ``stiction`` above :data:`STICTION_LEVEL`, ``no_stiction``
   below :data:`NO_STICTION_LEVEL`, ``inconclusive`` between, each with the
   evidence that weighed most for and against.

The two estimators (:func:`stictiondiag.stiction.segments.estimate_from_mv` and
:func:`stictiondiag.stiction.hammerstein.fit_hammerstein`) each return a
:class:`~stictiondiag.stiction.valvefit.StictionFit`; :func:`stiction_verdict` turns one
into a :class:`Verdict`.
"""

from __future__ import annotations

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.stiction.cause import (
    ACTIONS,
    CAUSE_WORDS,
    NO_CYCLE_REASON,
    Cause,
    CauseReading,
    Cycle,
    atypical_text,
    cycle_text,
    direct_stick_slip,
    friction_text,
)
from stictiondiag.stiction.cause_model import read_causes
from stictiondiag.stiction.consistency import FILL as DF_FILL
from stictiondiag.stiction.consistency import REPLAY_FEATURES, REPLAY_FILL, describing_features
from stictiondiag.stiction.fit_result import StictionFit
from stictiondiag.stiction.hammerstein import fit_hammerstein
from stictiondiag.stiction.probability import (
    classic_votes,
    contributions,
    evidence_features,
    evidence_words,
    load_model,
    stiction_probability,
)
from stictiondiag.stiction.verdict_result import (
    CONFIDENCE_FORMULA,
    Verdict,
    VerdictEvidence,
    VerdictStatus,
)

# --------------------------------------------------------------------------------------
# The verdict
# --------------------------------------------------------------------------------------

#: Smallest share of the linear valve's residual the stiction model must remove for
#: the improvement to count as material [-].
MIN_IMPROVEMENT = 0.1

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


#: Size of stiction the paper's industrial loops show, a few % of span (Section 3)
#: [% of span]: a ``no_stiction`` verdict whose S interval reaches beyond it says so.
RULE_OUT_S = 2.0

#: P(stiction) above which the verdict is ``stiction`` [-].
STICTION_LEVEL = 0.7

#: P(stiction) below which the verdict is ``no_stiction`` [-].
NO_STICTION_LEVEL = 0.3

# The levels are stated before any real-plant record is seen, from the cost of the
# two errors: a loop is called only when the calibrated probability favours its
# verdict at least 7 to 3 (odds above 2.3), so that a called loop is wrong at most
# three times in ten by the model's own, calibrated account; between the levels the
# evidence is too even to send a technician or to strike the valve off the list.


def _fit_text(fit: StictionFit, has_mv: bool, op_scale: str = "percent") -> str:
    """S and J with their intervals, in % of span, or in op's own units where op's
    scale is unknown (``Tags.op_scale``)."""
    S_iv = fit.S_interval
    unit = " %" if op_scale == "percent" else ""
    where = "of span" if op_scale == "percent" else "in op's own units (scale unknown)"
    return (
        f"S = {fit.S:.3g}{unit}"
        + (f" [{S_iv[0]:.3g}, {S_iv[1]:.3g}]" if S_iv else "")
        + f", J = {fit.J:.3g}{unit}"
        + (f" [{fit.J_interval[0]:.3g}, {fit.J_interval[1]:.3g}]" if fit.J_interval else "")
        + f" {where} ({'valve position' if has_mv else 'op and pv'})"
    )


def hidden_text(fit: StictionFit) -> str | None:
    """Why S and J cannot be told from the record: they lie within what its resolution
    (a quantised mv, the deadband of a compressed archive) makes of a healthy valve
    (:func:`stictiondiag.stiction.resolution.hidden_by_resolution`); None otherwise."""
    res = fit.resolution
    if res is None or not res.within:
        return None
    # The quantum is named where it, not the archive, sets mv's resolution.
    quantised = res.mv_quantum > res.mv_deadband
    parts = [f"mv quantised in steps of {res.mv_quantum:.3g} %"] if quantised else []
    parts += [
        f"{role} archived with a {band:.3g} % deadband"
        for role, band in (("mv", res.mv_deadband), ("op", res.op_deadband))
        if band
    ]
    return (
        f"S = {fit.S:.2g} % and J = {fit.J:.2g} % of span are within what the record can "
        f"hide ({', '.join(parts)}: a healthy valve recorded so shows stick-slip up to "
        f"S = {res.S_hidden:.2g} % and J = {res.J_hidden:.2g} %); stiction this small "
        "cannot be told from these data: export every sample (no compression) to decide"
    )


#: Loop types fitted as flow loops (``stictiondiag.analysis.FLOW_LIKE``, which this
#: layer cannot import).
_FLOW_TYPES = frozenset({"flow"})

#: Fewest cycles each half of the record must hold for the split-half fit [-] (the
#: analysis refuses a record of fewer, ``stictiondiag.analysis.MIN_ANALYSIS_CYCLES``).
HALF_MIN_CYCLES = 2.0


def split_half_estimates(fit: StictionFit, data) -> tuple[float, float, float, float] | None:
    """The S the data insist on [% of span] (lower end of the S interval, 0 without
    one) and the improvement over a linear valve [-] of the Hammerstein fit repeated on
    each half of the record: ``(S_1, S_2, improvement_1, improvement_2)``.

    The friction of a valve does not change within a record (Choudhury, Thornhill &
    Shah 2005, Section 5.1: S and J are properties of the valve), so a sticky valve
    gives the same S in both halves, while the S a linear valve's data lend the fit
    wanders with the noise and the loads.  Only the lower end of each half's S
    interval counts: against an op that hardly moves any S fits, and the point
    estimate is then arbitrary (as for ``s_low_share`` of the whole record).  Both
    halves are fitted with the whole record's cycle period, so they use the same
    time scales.

    None when there is no Hammerstein fit (the valve position is recorded), when a
    half holds fewer than :data:`HALF_MIN_CYCLES` cycles, or when a half cannot be
    fitted.
    """
    if data is None or getattr(data, "mv", None) is not None or fit.method != "hammerstein":
        return None
    op = np.asarray(data.op, dtype=float)
    pv = np.asarray(data.pv, dtype=float)
    dt = float(data.ts)
    h = op.size // 2
    period = fit.period_samples
    if not period or not period > 0 or h < HALF_MIN_CYCLES * float(period):
        return None
    out = []
    for sl in (slice(0, h), slice(h, 2 * h)):
        try:
            half = fit_hammerstein(
                op[sl],
                pv[sl],
                dt,
                integrating=bool(getattr(data, "integrating", False)),
                flow_loop=str(getattr(data, "loop_type", "")) in _FLOW_TYPES,
                period_s=float(period) * dt,
                gain_sign=0 if fit.gain_sign is None else int(fit.gain_sign.required),
            )
        except (StictionError, ValueError, FloatingPointError, np.linalg.LinAlgError):
            return None
        f = 1.0 - half.cost / half.linear_cost if half.linear_cost > 0 else 0.0
        s_low = float(half.S_interval[0]) if half.S_interval is not None else 0.0
        out.append((max(s_low, 0.0), float(f)))
    (s1, f1), (s2, f2) = out
    return s1, s2, f1, f2


def verdict_features(
    fit: StictionFit,
    oscillation,
    oscillation_op,
    *,
    short_record: bool,
    data=None,
    min_improvement: float = MIN_IMPROVEMENT,
    seed: int = 0,
    cycle: Cycle,
    reproduction: dict | None = None,
) -> tuple[dict, tuple[float, float, tuple[float, float]], dict]:
    """The probability model's features of one loop, the improvement's support
    (:func:`improvement_support`: support, improvement, interval) and the classic
    tests' votes; what :func:`stiction_verdict` decides on, and what the model is
    trained on (``scripts/train_probability.py``).  A loop with a cycle and without
    mv also gets the describing-function consistency of
    :mod:`stictiondiag.stiction.consistency` (the others its "no prediction" values).
    ``cycle`` is :func:`~stictiondiag.stiction.cause.find_cycle`'s (stage 1).
    ``reproduction``: the closed-loop reproduction's features
    (:data:`~stictiondiag.stiction.consistency.REPLAY_FEATURES`), which the chain
    computes with the replay (:func:`stictiondiag.replay.reproduction.reproduction_features`,
    in :meth:`stictiondiag.analysis.LoopEstimate.verdict`); without them, and for a
    loop without a cycle, their "no replay" values."""
    blocks = fit.block_costs
    bs = np.asarray([] if blocks is None else blocks.stiction, dtype=float)
    bl = np.asarray([] if blocks is None else blocks.linear, dtype=float)
    if bs.size == 0:
        bs, bl = np.array([fit.cost]), np.array([fit.linear_cost])
    support, f, f_iv = improvement_support(bs, bl, min_improvement, seed=seed)
    if data is not None:
        classic = classic_votes(
            data.op,
            data.pv,
            data.sp,
            float(data.ts),
            bool(data.integrating),
            getattr(data, "loop_type", None),
            getattr(data, "mv", None),
        )
        op = data.op
    else:
        classic, op = {}, fit.mv_model
    halves = split_half_estimates(fit, data)
    # Only a loop with a cycle has one to predict (a fit on mv gets the fill values).
    df = describing_features(fit, data, cycle.period_s) if cycle.present else dict(DF_FILL)
    features = evidence_features(
        fit,
        oscillation,
        oscillation_op,
        improvement=f,
        support=support,
        op=op,
        classic=classic,
        short_record=short_record,
        halves=halves,
    )
    features.update(df)
    features.update(REPLAY_FILL)
    if cycle.present and reproduction is not None:
        features.update({k: float(reproduction[k]) for k in REPLAY_FEATURES})
    return features, (support, f, f_iv), classic


#: P(the valve causes the cycle) at or above which stage 2 calls ``stiction``, and at
#: or below ``1 - VALVE_LEVEL`` of which it calls ``no_stiction`` [-].  Stated before
#: any real record was scored: with four causes, a loop is called when the valve is
#: more likely than all other causes together by 3 to 2 (or they than it); the band
#: between is narrow because stage 2 is asked only of loops with a cycle to explain,
#: where maintenance must act either way (inspect the valve, or act on the cause named).
VALVE_LEVEL = 0.6


def _stage2_call(
    stage2: CauseReading, short_record: bool = False
) -> tuple[VerdictStatus, bool | None, float, Cause | None, str]:
    """Stage 2's decision (:data:`VALVE_LEVEL`): status, detected, confidence, the
    cause named and the headline reason, naming the most likely cause and the
    runner-up and what to do.

    A ``short_record`` (fewer periods than the oscillation test needs) does not clear
    the valve: the shape statistics that tell the causes apart need three cycles
    (:data:`~stictiondiag.stiction.probability_evidence.SHAPE_MIN_CYCLES`) and take
    their neutral values without them, and the cause model's family holds almost no
    such records, so a low P(valve) there is missing evidence, not evidence against
    the valve; the loop is ``inconclusive``."""
    p_valve = stage2.valve
    cleared = p_valve <= 1.0 - VALVE_LEVEL
    if p_valve >= VALVE_LEVEL:
        status, detected, confidence, cause = VerdictStatus.STICTION, True, p_valve, Cause.VALVE
    elif cleared and not short_record:
        cause = stage2.runner_up(Cause.VALVE)[0]
        status, detected, confidence = VerdictStatus.NO_STICTION, False, 1.0 - p_valve
    else:
        status, detected, confidence, cause = VerdictStatus.INCONCLUSIVE, None, p_valve, None
    named = cause or stage2.ranked()[0]
    second, p2 = stage2.runner_up(named)
    if cause is not None:
        todo = ACTIONS[named.value]
    elif cleared:
        todo = (
            "the record holds fewer than three cycles, too few to clear the valve:"
            " export a longer record"
        )
    else:
        todo = "too close to call: the valve is about as likely to cause the cycle as not"
    # Below the level the valve may still lead three others that share the rest.
    which = "most likely cause" if named is stage2.ranked()[0] else "most likely other cause"
    head = (
        f"P(the valve causes the cycle) = {p_valve:.2f}; {which}: "
        f"{CAUSE_WORDS[named.value]} ({stage2.p(named):.2f}), runner-up: "
        f"{CAUSE_WORDS[second.value]} ({p2:.2f}); {todo}"
    )
    return status, detected, float(confidence), cause, head


def _decide(
    P: float, cycle, direct: str | None, stage2: CauseReading | None, contrib, fit, has_mv: bool
) -> tuple[VerdictStatus, bool | None, float, Cause | None, str]:
    """The decision: status, detected, confidence, cause and the headline reason.

    Without a limit cycle, stick-slip seen directly (``direct``) calls stiction and
    anything else no stiction; with one and without mv, stage 2 (:func:`_stage2_call`);
    otherwise P(stiction) against the two levels.  A stiction call whose S and J lie
    within what the record's resolution can hide (:func:`hidden_text`) becomes
    inconclusive, saying why (its probability kept).
    """
    status, detected, confidence, cause, head = _call(P, cycle, direct, stage2, contrib, has_mv)
    hidden = hidden_text(fit) if status is VerdictStatus.STICTION else None
    if hidden:
        return VerdictStatus.INCONCLUSIVE, None, confidence, None, f"{hidden}; {head}"
    return status, detected, confidence, cause, head


def _call(
    P: float, cycle, direct: str | None, stage2: CauseReading | None, contrib, has_mv: bool
) -> tuple[VerdictStatus, bool | None, float, Cause | None, str]:
    """:func:`_decide` on the evidence alone, before the record's resolution."""
    for_text = evidence_words(contrib, +1)
    against_text = evidence_words(contrib, -1)
    if not cycle.present and direct:
        head = f"stick-slip without a limit cycle: {direct} (P(stiction) = {P:.2f})"
        return VerdictStatus.STICTION, True, P, Cause.VALVE, head
    if not cycle.present:
        head = f"{NO_CYCLE_REASON} (P that the valve has friction = {P:.2f})"
        return VerdictStatus.NO_STICTION, False, 1.0 - min(P, 0.5), Cause.NONE, head
    if stage2 is not None and not has_mv:
        return _stage2_call(stage2, bool(cycle.short_record))
    if P > STICTION_LEVEL:
        head = f"P(stiction) = {P:.2f} (above {STICTION_LEVEL:g}): {for_text}"
        return VerdictStatus.STICTION, True, P, Cause.VALVE, head
    if P < NO_STICTION_LEVEL:
        cause = stage2.runner_up(Cause.VALVE)[0] if stage2 is not None else None
        head = f"P(stiction) = {P:.2f} (below {NO_STICTION_LEVEL:g}): {against_text}"
        return VerdictStatus.NO_STICTION, False, 1.0 - P, cause, head
    levels = f"levels {NO_STICTION_LEVEL:g} and {STICTION_LEVEL:g}"
    head = (
        f"P(stiction) = {P:.2f}, between the {levels}: the evidence is split "
        f"(for: {for_text}; against: {against_text})"
    )
    return VerdictStatus.INCONCLUSIVE, None, P, None, head


def _decided_probability(
    P: float, stage2: CauseReading | None, cycle: Cycle, direct: str | None, has_mv: bool
) -> float:
    """The probability the verdict decided on (:attr:`Verdict.probability`): stage 2's
    P(the valve causes the cycle) where it decides (a cycle, no mv), P(stiction) for a
    loop with mv or with stick-slip seen directly, and 0 for a loop without a cycle
    and without it: the valve causes none (P(friction) stays in the evidence)."""
    if cycle.present and stage2 is not None and not has_mv:
        return stage2.valve
    return P if cycle.present or direct else 0.0


def _improvement_text(
    f: float, f_iv: tuple[float, float], support: float, min_improvement: float, n_blocks: int
) -> str:
    """The stiction model's improvement over a linear valve, and its support, in words."""
    return (
        f"the stiction model removes {100 * f:.0f} % of the linear valve's residual "
        f"(95 % interval over cycles {100 * f_iv[0]:.0f} to {100 * f_iv[1]:.0f} %; "
        f"support {support:.2f} for more than {100 * min_improvement:.0f} %"
        + (
            f"; only {n_blocks} cycle block(s), too few to measure consistency"
            if n_blocks < 3
            else ""
        )
        + ")"
    )


def _unbounded_s_notes(status: VerdictStatus, fit: StictionFit) -> tuple[str, ...]:
    """A no-stiction verdict's caveat when the record does not bound S from above."""
    if (
        status is VerdictStatus.NO_STICTION
        and fit.S_interval is not None
        and fit.S_interval[1] >= RULE_OUT_S
    ):
        return (
            f"the record does not bound S: stiction up to {fit.S_interval[1]:.3g} % of span "
            "cannot be excluded from these data alone",
        )
    return ()


def _reasons(
    head: str,
    status: VerdictStatus,
    ev: VerdictEvidence,
    fit: StictionFit,
    op_scale: str,
    oscillation,
    oscillation_op,
) -> tuple[str, ...]:
    """The verdict in words: the decision, its caveats, the two stages, the
    improvement, S and J, and the oscillations found."""
    stage2 = ev.cause_probabilities
    caveat = atypical_text(stage2) if stage2 is not None and not ev.has_mv else None
    return (
        head,
        *((caveat,) if caveat else ()),
        *_unbounded_s_notes(status, fit),
        *((friction_text(ev.p_friction),) if stage2 is not None and not ev.has_mv else ()),
        cycle_text(ev.cycle),
        _improvement_text(
            ev.improvement, ev.improvement_interval, ev.support, ev.min_improvement, ev.n_blocks
        ),
        _fit_text(fit, ev.has_mv, op_scale),
        _osc_text("pv", oscillation),
        *((_osc_text("op", oscillation_op),) if oscillation_op is not None else ()),
    )


def stiction_verdict(
    fit: StictionFit,
    oscillation,
    *,
    cycle: Cycle,
    oscillation_op=None,
    has_mv: bool | None = None,
    short_record: bool = False,
    data=None,
    min_improvement: float = MIN_IMPROVEMENT,
    seed: int = 0,
    model: dict | None = None,
    cause_model: dict | None = None,
    reproduction: dict | None = None,
) -> Verdict:
    """Does valve stiction explain the loop's oscillation, and how probably?

    The question of Section 5.3 of Choudhury, Thornhill & Shah (2005), asked of
    the data and answered with a calibrated probability
    (:mod:`stictiondiag.stiction.probability`): the stiction model's improvement
    over a linear valve and its consistency over the cycles (:func:`improvement_support`),
    the S interval, the oscillation and its regularity, and the classic tests
    (Horch 1999; Choudhury, Shah & Thornhill 2004) run on ``data``.

    Parameters
    ----------
    fit : StictionFit
        From :func:`stictiondiag.stiction.segments.estimate_from_mv` or
        :func:`stictiondiag.stiction.hammerstein.fit_hammerstein`.
    oscillation, oscillation_op : Oscillation
        :func:`stictiondiag.signals.oscillation.detect_oscillation` of pv (or the
        control error) and of op.
    cycle : Cycle
        Stage 1 (:func:`~stictiondiag.stiction.cause.find_cycle`), found once by the
        chain (:attr:`stictiondiag.analysis.LoopEstimate.cycle`).
    has_mv : bool, optional
        Whether the valve position was recorded; default from ``fit.method``.
    short_record : bool
        The record holds fewer cycles than the oscillation test needs
        (:func:`stictiondiag.analysis.check_record_length`).
    data : Tags, optional
        The loop's record (``op``, ``pv``, ``sp``, ``ts``, ``integrating``) for the
        classic tests; without it they count as undecided.
    min_improvement : float
        Share of the linear valve's residual that counts as a material improvement [-].
    seed : int
        Seed of the bootstrap.
    model : dict, optional
        A fitted probability model; default the packaged one.
    cause_model : dict, optional
        A fitted cause model (:mod:`~stictiondiag.stiction.cause_model`); default ours.
    reproduction : dict, optional
        The closed-loop reproduction's features (:func:`verdict_features`).

    Returns
    -------
    Verdict
        Decided in two stages (module docstring): without a cycle, ``stiction`` on
        direct stick-slip, else ``no_stiction``; with one, by stage 2 (no mv) or P.
    """
    has_mv = fit.method == "mv_segments" if has_mv is None else bool(has_mv)
    model = model or load_model()
    features, (support, f, f_iv), classic = verdict_features(
        fit,
        oscillation,
        oscillation_op,
        short_record=short_record,
        data=data,
        min_improvement=min_improvement,
        seed=seed,
        cycle=cycle,
        reproduction=reproduction,
    )
    P = stiction_probability(features, has_mv, model)
    contrib = contributions(features, has_mv, model)
    n_blocks = (0 if fit.block_costs is None else len(fit.block_costs.stiction)) or 1
    # Stage 2, the cause of the cycle, where stage 1 found one; without a cycle only
    # stick-slip seen directly calls stiction.
    stage2 = read_causes(features, cause_model) if cycle.present else None
    direct = None
    if not cycle.present:
        direct = direct_stick_slip(features, has_mv, P, min_improvement=min_improvement)
    status, detected, confidence, cause, head = _decide(
        P, cycle, direct, stage2, contrib, fit, has_mv
    )
    evidence = VerdictEvidence(
        p_friction=P,
        cause_probabilities=stage2,
        features=features,
        contributions={k: t for k, t, _ in contrib},
        improvement=f,
        improvement_interval=(f_iv[0], f_iv[1]),
        support=support,
        min_improvement=min_improvement,
        n_blocks=int(n_blocks),
        has_mv=has_mv,
        short_record=bool(short_record),
        cycle=cycle,
        direct_stick_slip=direct,
        classic=classic,
        stiction_level=STICTION_LEVEL,
        no_stiction_level=NO_STICTION_LEVEL,
        valve_level=VALVE_LEVEL,
        confidence_formula=CONFIDENCE_FORMULA,
    )
    op_scale = str(getattr(data, "op_scale", "percent"))
    return Verdict(
        status,
        detected,
        float(confidence),
        _reasons(head, status, evidence, fit, op_scale, oscillation, oscillation_op),
        evidence,
        probability=_decided_probability(P, stage2, cycle, direct, has_mv),
        cause=cause,
        cycle=cycle,
        cause_probabilities=stage2,
        # Undecided: the alternative to the valve is the most likely other cause.
        runner_up=stage2.runner_up(cause or Cause.VALVE)[0] if stage2 is not None else None,
    )
