"""Sim-to-real gap: where the replay departs from the data, and which effect explains it.

The two-parameter model of Choudhury, Thornhill & Shah (2005) (Section 5.1, Fig. 10,
Eq. 4) never matches a real valve exactly.  :func:`diagnose_gap` measures the gap
between the replay and the data, locates it (by signal, valve phase, frequency, time
and feature), adds each unmodelled effect of the catalogue
(:mod:`stictiondiag.gap.effects`) with its own fitted parameters, and names the effect
that explains the gap, with the runner-up and how clearly it won.

The gap measure
---------------
The replay is *driven*: every element of the loop is fed with its recorded input, so
a departure shows in the element that causes it (:mod:`stictiondiag.gap.effects`):

* mv: the valve model replayed from the recorded op (Section 5.1);
* pv: the process (Eq. 3) driven by the recorded mv, predicted ``h`` samples ahead
  (``h`` = dead time + time constant) with the unmeasured load tracked by a Kalman
  filter, because plant loads that the controller answers are as large as the
  cycle itself;
* op: the PI controller replayed from the recorded sp and pv.

For each signal ``s`` the mean squared replay error is divided by ``V_s``, the
variance of the signal's cycle-scale part (the signal minus its slow part), and its
noise floor ``N_s`` is taken off (mv: white measurement noise, ``(1.4826 MAD(diff
mv))^2 / 2``; pv: see below; op: zero, the controller replays it exactly):

    gap = 100 * sqrt( sum_s max(MSE_s / V_s - N_s / V_s, 0) )   [%]

so ``gap`` is the part of the replay error that is not noise, in % of the RMS of the
signals' cycle-scale movement; 0 means "within its noise".  For pv the floor is what a
correct replay still misses at its horizon: measurement noise plus the load it could
not foresee, from the noise model of the best process replay
(:func:`stictiondiag.identification.predictor_kernels.process_noise_floor`), and never below the best pv
replay's error on held-out data.  The winner's floor is no higher than its own error
on the record unless the base replay's floor is (a load tracking retuned to follow a
tone the effect does not model claims that tone as unforeseeable load).  A quantised signal's rounding error (``q^2/12``)
counts as explained once quantization is added, as far as the floor, measured on the
rounded signal, does not hold it already (:meth:`stictiondiag.gap.selection.Measure.rounding_left`).

Attribution
-----------
The record is cut into eight contiguous blocks; every candidate's smooth parameters
(a lag's time constant, a miscalibration's slope and offset, a disturbance's
amplitudes, the process gain and the controller) are fitted on the even blocks and
judged on the odd ones, and the other way round, so an effect wins by predicting
data it was not fitted on, not by flexibility.  Stiction thresholds (S and J, and
those of the asymmetric and time-varying valves) are taken from the whole record: a
replay is in step with the data only at the exact thresholds, and a refit on half
the record would throw the other half out of step.  So is an installed
characteristic's curvature (its form and curvature searched once, on the record; the
gain and offset it feeds are refitted on each half).

A candidate is accepted only when its improvement over the base model on the judged
blocks (best and worst block left out) exceeds a penalty: twice the robust standard
error of the block-by-block improvement, and the reduction of the base error that the
Bayesian information criterion asks of its extra parameters, ``E0 (1 - exp(-k
log(n_eff)/n_eff))`` for ``k`` parameters (``n_eff log(E0/E1) >= k log(n_eff)``; ``n_eff``:
effectively independent residuals, the judged samples over the integrated
autocorrelation time of the residual the candidate leaves, so that an oscillation
the base replay lacks does not set the charge for explaining it); when the log ratio of the blocks' errors, base against effect,
passes the same two-standard-error test (free of the blocks' differing error sizes),
the BIC reduction alone.  It must also beat that reduction, block by block, in at
least two blocks and in at least as many blocks as it falls short of the base by as
much (blocks it changes less count neither way: a change of stiction during the
record leaves the rest of it as the base has it), and its own signature must be in
the data, not only a smaller error: an external oscillation keeps its phase along the
record; an asymmetric or time-varying valve has slips that differ by direction or by
time; a miscalibrated positioner puts the valve after each slip on a line of slope
other than 1 against the demand at the breakaway; an installed characteristic
makes the loop's gain change with the operating point, which no linear process does
(:func:`stictiondiag.gap.effects.slip_slope_test`,
:func:`stictiondiag.gap.effects.gain_change_test`, whose blocks are weighted by the
inverse RMS of the base replay's error in each, so that a few blocks of unforeseen
load do not decide it).  A signature with a direction is tested one-sided, in the
direction of the fitted effect (a time-varying valve's slips must change the way its
fitted S and J do); the asymmetric valve's slips are tested two-sided, because the
slips measured per direction need not follow the fitted direction.  ``none`` wins when no
candidate is accepted.  The accepted candidates are ranked by their held-out evidence
in the units of the Bayesian information criterion: for each signal the effect
changes, ``n_eff`` times the log ratio of the base's squared error to the effect's,
less ``log(n_eff)`` per extra parameter.  A ratio, not the raw sum of squared errors:
pv carries load that no replay foresees, so a small share of a large pv error must
not outrank most of the mv error removed.  An effect is named only if adding
it lowers the gap on the record; a gap of 0 (the replay within its noise) is
``none``.  No threshold is tuned to a data
generator: the penalties come from the data's own block-to-block scatter and
residual correlation, and the signature checks are tests at 1 % (Rayleigh, rank,
and t tests whose standard errors come from the scatter between blocks of the
record, :func:`stictiondiag.gap.effects.signature_test`).
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.gap.breakdown import breakdown
from stictiondiag.gap.context import (
    build_context,
    signals_of,
    starting_point,
)
from stictiondiag.gap.effects import EFFECT_MODELS, assessable_effects
from stictiondiag.gap.effects.base import fit_base
from stictiondiag.gap.result import GapBase, GapDiagnosis, GapSeries
from stictiondiag.gap.selection import (
    N_BLOCKS,
    Score,
    candidate_share,
    choose_quantization,
    combined_predictions,
    effective_samples_of,
    evidence,
    evidence_floors,
    heldout_errors,
    heldout_gap,
    margin,
    mv_only_within_noise,
    ranked_candidates,
    score_candidate,
    select_winner,
)

METRIC_NAME = "excess_nrmse"


METRIC_DEFINITION = (
    "100 * sqrt(sum over op, mv, pv of max(MSE_s - N_s, 0) / V_s) [%]: driven replay "
    "(mv from recorded op, pv from recorded mv predicted dead time + time constant "
    "ahead with the load tracked, op from recorded sp and pv); V_s the variance of the "
    "signal's cycle-scale part, N_s its white-noise variance; 0 means within noise"
)


def diagnose_gap(
    tags,
    fit=None,
    replay=None,
    *,
    n_blocks: int = N_BLOCKS,
    effects: tuple[str, ...] | None = None,
    fit_all: bool = False,
    segments=None,
) -> GapDiagnosis:
    """Measure and locate the sim-to-real gap and name the effect that explains it.

    Parameters
    ----------
    tags : Tags
        Loop data (:class:`stictiondiag.io.tags.Tags` or any object with ``op``, ``pv``,
        ``mv``, ``sp`` arrays and ``ts``): op and mv in % of span, uniformly sampled.
    fit : StictionFit, optional
        Stiction estimate (:func:`stictiondiag.stiction.segments.estimate_from_mv` or
        :func:`stictiondiag.stiction.hammerstein.fit_hammerstein`): S and J start the
        searches; without mv its ``mv_model`` drives the process replay.
    replay : Replay, optional
        Closed-loop replay (:func:`stictiondiag.replay.closed_loop.replay`): its period and
        amplitudes join the feature breakdown.
    n_blocks : int
        Validation blocks (even against odd), >= 4.
    effects : tuple of str, optional
        Effects to assess (default: all of :data:`stictiondiag.gap.effects.EFFECTS`
        that the data allow).
    fit_all : bool
        Fit every assessable effect, also those that cannot lower the gap (by default
        the effects acting on mv alone are skipped when the base replay of mv is
        within its noise; the winner, the gap before and after and the shrink are the
        same either way, only the losing candidates listed differ).
    segments : Segments, optional
        The stick and slip segments of the mv-op plot
        (:func:`stictiondiag.stiction.segments.segment_valve` of the tags' op, mv and
        ts) when the caller has them already, e.g. from the stiction estimate; they
        are not computed again.

    Returns
    -------
    GapDiagnosis

    Raises
    ------
    DataError
        Too short, gaps, constant op or pv.
    """
    sig = signals_of(tags)
    n_blocks = max(int(n_blocks), 4)
    start = starting_point(fit, sig)
    ctx = build_context(sig, segments=segments, **start)
    assessable, not_assessed = assessable_effects(sig.mv is not None, effects)

    # Whole-record fits.
    base = fit_base(ctx, ctx.w_eval)
    within_noise = [] if fit_all else mv_only_within_noise(ctx, base, assessable)
    fits = {}
    for name in assessable:
        if name in within_noise:
            continue
        ef = EFFECT_MODELS[name](ctx, ctx.w_eval, base)
        if ef is not None:
            fits[name] = ef

    # Held-out errors, the per-parameter penalty of each signal (as for the Bayesian
    # information criterion, with the effectively independent residuals of the base
    # replay), penalised scores and evidence.
    held = heldout_errors(ctx, base, fits, n_blocks, EFFECT_MODELS)
    n_eff = effective_samples_of(ctx, base)
    share = {s: math.log(v) / v for s, v in n_eff.items()}
    choose_quantization(fits, held, share)
    errors = held.errors
    base_total = float(sum(v for v in errors["none"].values()).sum())
    scores = {"none": Score(base_total, True, 0.0, np.zeros(n_blocks))}
    evidences = {"none": 0.0}
    floors = evidence_floors(ctx, held.blocks, n_blocks)
    white = evidence_floors(ctx, held.blocks, n_blocks, rounding=False)
    for name, ef in fits.items():
        scores[name] = score_candidate(name, ef, errors, ctx, base, candidate_share(ctx, ef, share))
        evidences[name] = evidence(
            ef, name, errors, n_eff, scores[name].gain_by_block, floors, white
        )

    sel = select_winner(ctx, base, fits, errors, scores, evidences)
    winner = sel.winner
    runner = sel.order[1] if len(sel.order) > 1 else None
    cands = ranked_candidates(ctx, sel, fits, errors, scores, evidences)
    heldout_before = heldout_gap(ctx, sel.measure, errors["none"])
    after, shrink = sel.before, 0.0
    if winner != "none":
        win = next(c for c in cands if c.effect == winner)
        after, shrink = win.after, win.shrink_pct

    preds_before = base.predictions
    preds_after = combined_predictions(base, None if winner == "none" else fits[winner])
    return GapDiagnosis(
        metric=METRIC_NAME,
        definition=METRIC_DEFINITION,
        before=sel.before,
        after=after,
        shrink_pct=shrink,
        effect=winner,
        runner_up=runner,
        margin=margin(winner, runner, scores, evidences),
        candidates=tuple(cands),
        breakdown=breakdown(sig, sel.measure, base, preds_before, preds_after, replay),
        not_assessed=tuple(not_assessed),
        within_noise=tuple(within_noise),
        heldout_before=heldout_before,
        base=GapBase.of(ctx, base, sel.measure.floor),
        series=GapSeries.of(sig, preds_before, preds_after),
    )
