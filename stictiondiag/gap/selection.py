"""Selection of the effect that explains the gap: held-out blocks, penalty, evidence, ranking.

The record is cut into contiguous blocks; every candidate is fitted on the even blocks
and judged on the odd ones, and the other way round (:func:`heldout_errors`).  A
candidate is accepted when its held-out improvement over the base replay beats a
penalty: the block-to-block scatter and the reduction the Bayesian information
criterion asks of its extra parameters (:func:`bic_gain`, :func:`score_candidate`).
The accepted candidates are ranked by their held-out evidence (:func:`evidence`);
a winner that does not lower the gap on the record is excluded and the next one
taken (:func:`select_winner`).  The noise floors the gap is measured against live here
too (:func:`noise_variance`, :func:`noise_floors`, :func:`evidence_floors`,
:func:`mv_within_noise`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.robust import robust_std
from stictiondiag.gap.context import LoopSignals, ReplayContext
from stictiondiag.gap.effects import REGISTRY
from stictiondiag.gap.effects.base import (
    BaseFit,
    EffectFit,
    fit_base,
)
from stictiondiag.gap.effects.quantization import detect_quantization, quantization_subsets
from stictiondiag.gap.result import Candidate

#: Blocks of the record for validation (even blocks against odd ones).
N_BLOCKS = 8


#: Standard errors of the block-by-block improvement a candidate must exceed [-].
SIGNIFICANCE = 2.0


#: Fewest effectively independent residuals assumed for the per-parameter penalty [-].
MIN_EFFECTIVE_SAMPLES = 10


def noise_variance(x: np.ndarray) -> float:
    """White measurement-noise variance of a signal from its sample-to-sample changes.

    ``(1.4826 MAD(diff x))^2 / 2``: the median ignores the few large changes (slips,
    steps), and a still or slowly moving signal changes by its noise alone.
    """
    d = np.diff(np.asarray(x, dtype=float))
    if d.size == 0:
        return 0.0
    return robust_std(d) ** 2 / 2.0


@dataclass(frozen=True)
class Measure:
    """Normalisers, noise floors and judged samples of one loop."""

    norm: dict
    floor: dict
    w: np.ndarray

    def nmse(
        self, name: str, pred: np.ndarray, data: np.ndarray, w: np.ndarray | None = None
    ) -> float:
        ww = self.w if w is None else w
        r = pred - data
        return float(np.dot(ww, r * r)) / max(float(ww.sum()), 1.0) / self.norm[name]

    def excess(self, name: str, value: float) -> float:
        return max(value - self.floor[name] / self.norm[name], 0.0)

    def rounding_left(self, name: str, explained: float) -> float:
        """The part of a signal's rounding variance ``explained`` [units^2] that its
        noise floor does not hold already, normalised [-].

        Each floor is measured on the recorded, rounded signal.  mv's white noise
        (:func:`noise_variance`) holds all of ``q^2/12`` when mv moves by a step or
        more nearly every sample (independent rounding errors) and none when it is
        held between steps (its floor is 0); pv's floor, from the noise model of the
        process replay fitted to the rounded pv, rises with the rounding by about
        ``q^2/12`` whether pv moves every sample or is held between steps.  The floor
        is taken to hold as much of the rounding as it can, up to ``q^2/12``, so the
        rounding counts once: the signal's error is floored at the larger of the two,
        never at their sum.
        """
        return max(explained - self.floor.get(name, 0.0), 0.0) / self.norm[name]

    def gap(self, per_signal: dict) -> float:
        """Gap [%] from each signal's normalised mean squared error."""
        return 100.0 * math.sqrt(sum(self.excess(s, v) for s, v in per_signal.items()))


def mv_within_noise(ctx: ReplayContext, base: BaseFit) -> bool:
    """True when the base replay of mv is within its noise: its excess in the gap
    (mean squared error on the judged samples less the white-noise variance of mv) is 0.

    Computed as :func:`stictiondiag.gap.selection.record_gaps` computes it, so the
    answer is exact: an effect that acts on mv alone then leaves every signal's excess
    as the base has it or raises mv's, so its gap on the record is never below the
    base's and :func:`select_winner` can never name it.
    """
    sig = ctx.sig
    if sig.mv is None or base.valve is None:
        return False
    meas = Measure(norm=ctx.norm, floor={"mv": noise_variance(sig.mv)}, w=ctx.w_eval)
    return meas.excess("mv", meas.nmse("mv", base.valve.mv, sig.mv)) == 0.0


def mv_only_within_noise(ctx: ReplayContext, base: BaseFit, names) -> list[str]:
    """The effects among ``names`` that act on mv alone (and explain no measurement
    error), when the base replay of mv is within its noise (:func:`mv_within_noise`):
    their fits cannot lower the gap, so they need not be made (their threshold
    searches are most of the work of a loop with mv)."""
    mv_only = [n for n in names if tuple(REGISTRY[n].acts_on) == ("mv",) and n != "quantization"]
    if not mv_only or not mv_within_noise(ctx, base):
        return []
    return mv_only


def block_index(n: int, n_blocks: int) -> np.ndarray:
    """Block index of every sample (contiguous blocks of equal length)."""
    return np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)


def combined_predictions(base: BaseFit, ef: EffectFit | None) -> dict:
    preds = dict(base.predictions)
    if ef is not None:
        preds.update(ef.predictions)
    return preds


def block_errors(
    preds: dict,
    sig: LoopSignals,
    meas: Measure,
    blocks: np.ndarray,
    mask: np.ndarray,
    n_blocks: int,
    explained: dict | None = None,
) -> dict:
    """Normalised squared error of each signal, per block, on the samples in ``mask``,
    less any variance the effect accounts for as a known measurement error."""
    out = {}
    for name, pred in preds.items():
        r = pred - getattr(sig, name)
        e = meas.w * mask * r * r
        if explained and name in explained:
            e = e - meas.w * mask * explained[name]
        out[name] = np.bincount(blocks, e / meas.norm[name], minlength=n_blocks)
    return out


def accumulate(acc: dict | None, new: dict) -> dict:
    if acc is None:
        return {k: v.copy() for k, v in new.items()}
    for k, v in new.items():
        acc[k] += v
    return acc


def bic_gain(base_error, n_params: float, share: float):
    """Least reduction of a squared error ``base_error`` that pays for ``n_params``
    extra parameters under the Bayesian information criterion.

    BIC asks ``n_eff log(E0 / E1) >= k log(n_eff)``, that is ``E1 <= E0 exp(-k s)`` with
    ``s = log(n_eff) / n_eff``: the reduction ``E0 - E1`` must reach
    ``E0 (1 - exp(-k s))``.  For a small ``k s`` this is ``k s E0``; for a large one
    (few effectively independent residuals) it stays below ``E0``, so an effect that
    removes most of the error is never asked for more than all of it.
    """
    return base_error * -math.expm1(-n_params * share)


def signals_charge(gains: dict, charges: dict) -> float:
    """The reduction of the summed error that pays for a candidate's parameters when
    it acts on several signals, each charged in the units of its own error.

    ``charges[s]`` is what the parameters must take off signal ``s``'s error on its own
    (:func:`bic_gain`), ``gains[s]`` what they do.  The criterion with one variance
    per signal (each signal's error its own Gaussian likelihood) asks
    ``sum_s n_s log(E0_s / E1_s) >= k log n``, to first order
    ``sum_s gains[s] / charges[s] >= 1``; as a least total gain, that is the gains'
    sum over that ratio (a gain-weighted harmonic mean of the charges).  With one
    signal it is that signal's charge.  The sum of the charges instead would charge a
    signal the candidate changes little with the share of the error of another: a
    historian's rounding of pv, which moves the controller replay's op by as much as
    op's whole error, was asked for a tenth of pv's load error as well.  When the
    signals' gains do not pass, the charges' sum (the candidate fails either way).
    """
    names = [s for s in charges if s in gains]
    total = float(sum(charges[s] for s in names))
    if len(names) < 2:
        return total
    ratio = sum(gains[s] / charges[s] for s in names if charges[s] > 0.0)
    gain = float(sum(gains[s] for s in names))
    if ratio < 1.0 or gain <= 0.0:
        return total
    return gain / ratio


def effective_samples(residual: np.ndarray, w: np.ndarray) -> float:
    """Effectively independent residuals: the judged samples over the integrated
    autocorrelation time of the residual (summed until the autocorrelation first
    turns negative), at least :data:`MIN_EFFECTIVE_SAMPLES`."""
    r = residual[w > 0]
    n = r.size
    r = r - r.mean()
    var = float(np.dot(r, r))
    if n < 4 or var <= 0.0:
        return float(MIN_EFFECTIVE_SAMPLES)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(r, nfft)
    acf = np.fft.irfft(f * np.conj(f), nfft)[: n // 4] / var
    neg = np.where(acf[1:] <= 0.0)[0]
    stop = int(neg[0]) + 1 if neg.size else acf.size
    tau = 1.0 + 2.0 * float(np.sum(acf[1:stop]))
    return max(n / max(tau, 1.0), MIN_EFFECTIVE_SAMPLES)


def blocks_agree(gain: np.ndarray, threshold: np.ndarray) -> bool:
    """Whether the blocks bear out an effect: it is better by more than ``threshold``
    in at least two blocks and in at least as many blocks as it is worse by as much.

    A block the effect changes by less than the threshold counts neither way: a
    change of stiction during the record, or an effect that shows only where the
    operating point goes, leaves the rest of the record as the base model has it.
    """
    better = int(np.sum(gain > threshold))
    worse = int(np.sum(gain < -threshold))
    return better >= max(worse, 2)


# --------------------------------------------------------------------------------------
# Held-out errors
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HeldOut:
    """Normalised squared errors on held-out blocks, per candidate, signal and block.

    Attributes
    ----------
    blocks : ndarray of int
        Block index of every sample.
    errors : dict
        ``errors[name][signal]``: per-block sums of the normalised squared error of
        the candidate (``none``: the base replay) fitted on the other parity [-].
    quantization_subsets : dict
        The same for the quantization fit restricted to each proper subset of its
        quantised signals (a tuple of names).
    quantization_fits : dict
        The whole-record quantization fit restricted to each of those subsets
        (:func:`stictiondiag.gap.effects.quantization.quantization_subsets`).
    """

    blocks: np.ndarray
    errors: dict
    quantization_subsets: dict
    quantization_fits: dict


def heldout_errors(
    ctx: ReplayContext, base: BaseFit, fits: dict, n_blocks: int, models: dict
) -> HeldOut:
    """Fit on the even blocks and judge on the odd ones, and the other way round.

    Smooth parameters are refitted on each half (``models[name](ctx, w, base,
    init=full_fit)``); a fitter that returns None keeps the whole-record fit.  For
    quantization every proper subset of the quantised signals is judged too (each
    step is one parameter).
    """
    sig = ctx.sig
    norm_only = Measure(norm=ctx.norm, floor=dict.fromkeys(ctx.norm, 0.0), w=ctx.w_eval)
    blocks = block_index(sig.n, n_blocks)
    q_fits = quantization_subsets(fits["quantization"]) if "quantization" in fits else {}
    held: dict = dict.fromkeys(["none", *fits])
    q_held: dict = dict.fromkeys(q_fits)
    for parity in (0, 1):
        train = (blocks % 2 == parity).astype(float)
        test = 1.0 - train
        w_train = ctx.w_eval * train
        # The base and every candidate refitted on the training half, then judged on
        # the other half.
        base_f = fit_base(ctx, w_train, like=base)
        half = {}
        for name, ef_full in fits.items():
            ef = models[name](ctx, w_train, base_f, init=ef_full)
            half[name] = ef_full if ef is None else ef
        q_half = quantization_subsets(half["quantization"]) if q_fits else {}
        errs = block_errors(base_f.predictions, sig, norm_only, blocks, test, n_blocks)
        held["none"] = accumulate(held["none"], errs)
        for judged, candidates in ((held, half), (q_held, q_half)):
            for key, ef in candidates.items():
                errs = block_errors(
                    combined_predictions(base_f, ef),
                    sig,
                    norm_only,
                    blocks,
                    test,
                    n_blocks,
                    ef.explained,
                )
                judged[key] = accumulate(judged[key], errs)
    return HeldOut(
        blocks=blocks, errors=held, quantization_subsets=q_held, quantization_fits=q_fits
    )


def effective_samples_of(ctx: ReplayContext, base: BaseFit) -> dict:
    """Effectively independent residuals of each signal's base replay on the judged
    samples (:func:`effective_samples`)."""
    return {
        s: effective_samples(p - getattr(ctx.sig, s), ctx.w_eval)
        for s, p in base.predictions.items()
    }


def candidate_share(ctx: ReplayContext, ef: EffectFit, share: dict) -> dict:
    """The per-parameter share ``log(n_eff) / n_eff`` of the Bayesian information
    criterion for one candidate: on the signals it changes, ``n_eff`` from the
    residual the candidate leaves (:func:`effective_samples`); elsewhere ``share``
    (the base replay's).

    The charge per parameter counts the effectively independent residuals of the
    noise the model leaves.  The base replay's residual holds whatever effect it
    lacks: an oscillation from outside the loop left in it is correlated over a
    quarter of its period, so its ``n_eff`` counts the cycles rather than the noise,
    and the charge it sets grows with the very oscillation the candidate explains
    (a disturbance removing most of pv's error was charged half of it for its five
    parameters).  On a loop without the effect the candidate leaves the base's
    residual, and the share is the base's.
    """
    out = dict(share)
    for s, pred in ef.predictions.items():
        if s in out:
            v = effective_samples(pred - getattr(ctx.sig, s), ctx.w_eval)
            out[s] = math.log(v) / v
    return out


def choose_quantization(fits: dict, held: HeldOut, share: dict) -> None:
    """Keep all quantised signals when their steps together pay for themselves on
    held-out data, else the subset that pays best (``fits`` and ``held`` updated).

    A step is one parameter on its own signal, and a pv rounded too finely to matter
    must not charge an mv rounding the BIC share of pv's error (pv carries load no
    replay foresees).
    """
    errors = held.errors
    if "quantization" not in fits or not held.quantization_subsets:
        return

    def q_net(h: dict, ef: EffectFit) -> float:
        sigs = [s for s in ef.predictions if s in errors["none"]]
        gains = {s: float((errors["none"][s] - h[s]).sum()) for s in sigs}
        charges = {s: bic_gain(float(errors["none"][s].sum()), ef.n_params, share[s]) for s in sigs}
        return sum(gains.values()) - signals_charge(gains, charges)

    full_net = q_net(errors["quantization"], fits["quantization"])
    best_q = (full_net, None)
    for sub in held.quantization_subsets if full_net <= 0.0 else ():
        net = q_net(held.quantization_subsets[sub], held.quantization_fits[sub])
        if net > best_q[0]:
            best_q = (net, sub)
    if best_q[1] is not None:
        fits["quantization"] = held.quantization_fits[best_q[1]]
        errors["quantization"] = held.quantization_subsets[best_q[1]]


# --------------------------------------------------------------------------------------
# Penalised scores and evidence
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """Held-out judgement of one candidate.

    Attributes
    ----------
    score : float
        Penalised held-out error, normalised and summed over signals and blocks [-].
    accepted : bool
        The improvement over the base replay beats the penalty, the blocks bear it
        out and the effect's signature is in the data.
    penalty_excess : float
        ``score`` less the candidate's own held-out error [-].
    gain_by_block : ndarray
        The base's held-out error less the candidate's, per block [-].
    """

    score: float
    accepted: bool
    penalty_excess: float
    gain_by_block: np.ndarray


def _kept_blocks(ef: EffectFit, d: np.ndarray) -> np.ndarray:
    """Blocks that judge a candidate: for effects on the valve, all but the best and
    the worst block (one block where the valve replay happens to fall in or out of
    step with the data must not decide); process-side replays are not thrown out of
    step by a lucky or unlucky block, so all."""
    kept = np.ones(d.size, dtype=bool)
    if "mv" in ef.predictions:
        kept[int(np.argmax(d))] = False
        kept[int(np.argmin(d))] = False
    return kept


def score_candidate(
    name: str, ef: EffectFit, held: dict, ctx: ReplayContext, base: BaseFit, share: dict
) -> Score:
    """Penalised held-out score of one candidate and whether it is accepted.

    The improvement over the base replay on the judged blocks (best and worst block
    left out for valve effects, scaled back to the whole record) must exceed a
    penalty: twice the robust standard error of the block-by-block improvement and the
    reduction :func:`bic_gain` asks of the extra parameters (the latter alone when the
    log ratio of the blocks' errors passes the same test); the blocks must bear it out
    (:func:`blocks_agree`), the whole-record fit must show it too and the effect's
    signature must be in the data (``ef.supported``).
    """
    sig = ctx.sig
    total0 = sum(v for v in held["none"].values())
    total1 = sum(v for v in held[name].values())
    n_blocks = total0.size
    base_total = float(total0.sum())
    base_preds = base.predictions
    d = total0 - total1
    # Process-side replays: an installed characteristic may show in the one block
    # where the valve travels far from its operating point (all blocks count).
    if "mv" in ef.predictions:
        trimmed = (float(d.sum()) - float(d.max()) - float(d.min())) * n_blocks / (n_blocks - 2)
    else:
        trimmed = float(d.sum())
    # Scatter of the block improvements, robust to a few blocks where a real effect
    # matters most (a characteristic away from the operating point).
    se = robust_std(d) * math.sqrt(n_blocks)
    # The per-parameter share is of the base error on the signals the effect changes:
    # a valve effect is not asked to beat the process replay's error.
    sigs = [s for s in ef.predictions if s in held["none"]]
    per_param = signals_charge(
        {s: float((held["none"][s] - held[name][s]).sum()) for s in sigs},
        {s: bic_gain(float(held["none"][s].sum()), ef.n_params, share[s]) for s in sigs},
    )
    penalty = max(SIGNIFICANCE * se, per_param)
    # The scatter in absolute terms overstates the uncertainty when the blocks' errors
    # differ in size (a valve replay far out of step in some blocks): the same test on
    # the log ratio of each block's errors is free of that scale.  When it passes, the
    # penalty is the per-parameter share alone.
    if sigs:
        e0_b = sum(held["none"][s] for s in sigs)
        e1_b = sum(held[name][s] for s in sigs)
        # A block without judged samples (the start of the record) counts as even.
        both = (e0_b > 0.0) & (e1_b > 0.0)
        lr = np.where(both, np.log(np.where(both, e0_b, 1.0) / np.where(both, e1_b, 1.0)), 0.0)
        if "mv" in ef.predictions:
            keep_b = _kept_blocks(ef, d)
            lr_sum = float(lr[keep_b].sum()) * n_blocks / (n_blocks - 2)
        else:
            lr_sum = float(lr.sum())
        se_lr = robust_std(lr) * math.sqrt(n_blocks)
        if lr_sum > SIGNIFICANCE * se_lr:
            penalty = per_param
    # Better in at least as many blocks as worse, and in two at least, each time by
    # more than the per-parameter share of the base error on those signals.
    per_param_b = sum(
        bic_gain(np.abs(held["none"][s]), max(ef.n_params, 1), share[s]) for s in sigs
    )
    # A real effect also explains the whole record it was fitted on: a held-out gain
    # that the in-sample fit does not show comes from a poor fit of the base on a
    # half, not from the effect.
    in_gain_norm = sum(
        (
            float(np.dot(ctx.w_eval, (base_preds[s] - getattr(sig, s)) ** 2))
            - float(np.dot(ctx.w_eval, (ef.predictions[s] - getattr(sig, s)) ** 2))
            + float(ctx.w_eval.sum()) * ef.explained.get(s, 0.0)
        )
        / ctx.norm[s]
        for s in sigs
    )
    consistent = blocks_agree(d, per_param_b) and ef.supported and in_gain_norm > penalty
    accepted = trimmed > penalty and consistent
    score = base_total - trimmed + penalty if consistent else base_total + penalty
    return Score(score, accepted, score - float(total1.sum()), d)


#: Relative standard error of a mean of squared rounding errors, per effectively
#: independent error: ``sqrt(Var(e^2)) / E(e^2)`` for ``e`` uniform on a step,
#: ``sqrt(q^4 (1/80 - 1/144)) / (q^2/12) = sqrt(4/5)``.
ROUNDING_SQUARE_SPREAD = math.sqrt(0.8)


def evidence_floors(
    ctx: ReplayContext, blocks: np.ndarray, n_blocks: int, rounding: bool = True
) -> dict:
    """Least held-out error each signal's replay can be judged to reach, per block [-].

    A replay cannot be told to be better than the data resolve: per sample, the larger
    of the signal's white measurement noise (:func:`noise_variance`) and its rounding
    variance ``q^2/12`` (``q`` the step of a quantised signal,
    :func:`stictiondiag.gap.effects.quantization.detect_quantization`, else the
    spacing of double-precision numbers at the signal's size), normalised like the
    held-out errors and summed over each block's judged samples.  With ``rounding``
    False, the white noise and the spacing of double-precision numbers only: the
    floor of what is left once the rounding is accounted for (see :func:`evidence`).
    """
    judged = np.bincount(blocks, ctx.w_eval, minlength=n_blocks)
    floors = {}
    for s, norm in ctx.norm.items():
        x = np.asarray(getattr(ctx.sig, s), dtype=float)
        q = detect_quantization(x) if rounding else None
        step = q[0] if q is not None else np.finfo(float).eps * float(np.max(np.abs(x)))
        per_sample = max(noise_variance(x), step * step / 12.0)
        floors[s] = judged * per_sample / norm
    return floors


def evidence(
    ef: EffectFit,
    name: str,
    held: dict,
    n_eff: dict,
    d: np.ndarray,
    floors: dict,
    white: dict | None = None,
) -> float:
    """Held-out evidence for a candidate in the units of the Bayesian information
    criterion.

    On the blocks of :func:`score_candidate`, per signal the effect changes: ``n_eff``
    times the log ratio of the base's squared error to the effect's, less ``log n_eff``
    per extra parameter.  Signals differ in how much of their error a replay can ever
    explain (pv carries load no replay foresees): the accepted candidates are ranked
    by this ratio, not by the raw sum.  Both errors are taken at least at the signal's
    floor (:func:`evidence_floors`): an effect that brings a signal's held-out error
    to its noise floor (a quantised signal's rounding explained) gains the whole
    ratio of the base's error to the floor, instead of dropping out of the sum.

    A candidate that accounts for a signal's rounding (``ef.explained``: the
    quantization) leaves an error with the rounding taken out, so that error is not
    held at a floor that holds the rounding a second time: its floor is the white
    noise (``white``, :func:`evidence_floors` without rounding) or what the rounding
    variance is known to, its sampling error over the ``n_eff`` effectively
    independent errors (:data:`ROUNDING_SQUARE_SPREAD`), whichever is larger.  With
    the rounding in the floor, an mv whose base replay misses it by its rounding
    alone, 97 % of the error, counted as no evidence at all.
    """
    kept = _kept_blocks(ef, d)
    sigs = [s for s in ef.predictions if s in held["none"]]
    ev = 0.0
    for s in sigs:
        floor = float(floors[s][kept].sum())
        e0 = max(float(held["none"][s][kept].sum()), floor)
        floor1 = floor
        if white is not None and ef.explained.get(s, 0.0) > 0.0:
            spread = floor * ROUNDING_SQUARE_SPREAD / math.sqrt(max(n_eff[s], 1.0))
            floor1 = min(floor, max(float(white[s][kept].sum()), spread))
        e1 = max(float(held[name][s][kept].sum()), floor1)
        if e0 > 0.0 and e1 > 0.0:
            ev += n_eff[s] * math.log(e0 / e1)
    if sigs:
        ev -= ef.n_params * max(math.log(n_eff[s]) for s in sigs)
    return ev


def rank_key(scores: dict, evidences: dict):
    """Sort key of the candidates: accepted effects first, most evidence first; then
    ``none``; then the rest by penalised score."""

    def rank(e: str) -> tuple:
        if e == "none":
            return (1, 0.0)
        if scores[e].accepted:
            return (0, -evidences[e])
        return (2, scores[e].score)

    return rank


def margin(winner: str, runner: str | None, scores: dict, evidences: dict) -> float:
    """How clearly the winner won [%].

    The share of the winner's penalised gain over the base model that the runner-up
    does not reach (100: the runner-up gains nothing); between two accepted effects,
    the share of the winner's evidence the runner-up lacks (of the larger evidence in
    size when one is negative; at most 100); for ``none``, how far the
    best candidate's penalised score lies above the base error, in % of it.
    """
    if runner is None:
        return 0.0
    base_total = scores["none"].score
    gain = base_total - scores[winner].score
    if winner == "none":
        return 100.0 * (scores[runner].score - base_total) / max(base_total, 1e-300)
    if runner != "none" and scores[runner].accepted:
        # Evidence can be negative for both (a gain smaller than its penalty on some
        # signal): measured against the larger of the two in size, capped at 100.
        ev_w, ev_r = evidences[winner], evidences[runner]
        scale = max(abs(ev_w), abs(ev_r), 1e-300)
        return min(100.0, 100.0 * (ev_w - ev_r) / scale)
    return 100.0 * (scores[runner].score - scores[winner].score) / max(gain, 1e-300)


# --------------------------------------------------------------------------------------
# The winner
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Selection:
    """The winning candidate and the measure it was judged with.

    Attributes
    ----------
    winner : str
        The named effect, or ``none``.
    order : list of str
        The candidates still in the running, best first (``winner`` first).
    excluded : set of str
        Accepted candidates passed over because they do not lower the gap on the
        record.
    measure : Measure
        Normalisers and noise floors (those of the winner) of the gap.
    before : float
        Gap of the base replay on the record [%].
    afters : dict
        Gap of each candidate on the record [%].
    """

    winner: str
    order: list
    excluded: set
    measure: Measure
    before: float
    afters: dict


def noise_floors(
    ctx: ReplayContext, win_fit: EffectFit | None, base_pv_floor: float, heldout_pv: list
) -> dict:
    """Noise floor of each signal's replay error [units^2].

    mv: its white measurement noise; pv: measurement noise and the load the
    prediction cannot foresee, from the winner's process replay when the effect is on
    the process side (an unmodelled disturbance would otherwise pass for load), never
    below what the best pv replay achieves on held-out data (the load the replay
    tracks is not white, so part of it stays unpredictable whatever the valve or the
    process does); op: none, the controller replays it exactly.
    """
    pv_floor = base_pv_floor
    if win_fit is not None and win_fit.pv_floor is not None:
        # A floor is what a correct replay still misses, and the winner's replay
        # misses no less than its own floor on the record it was fitted to.  Where it
        # does, its filter's split of the error into load and noise is off (a load
        # tracking retuned to follow a second, unmodelled tone claims that tone as
        # load it could never foresee), and its error on the record bounds the claim.
        # That error is fitted, so it bounds the claim only down to the base
        # replay's own floor: below both estimates a floor would come from nothing but
        # the winner's fit to the record.
        own = float(np.dot(ctx.w_eval, (win_fit.predictions["pv"] - ctx.sig.pv) ** 2))
        own /= max(float(ctx.w_eval.sum()), 1.0)
        pv_floor = min(win_fit.pv_floor, max(own, base_pv_floor))
    floors = {"op": 0.0, "pv": max(pv_floor, min(heldout_pv))}
    if ctx.sig.mv is not None:
        floors["mv"] = noise_variance(ctx.sig.mv)
    return floors


def record_gaps(meas: Measure, ctx: ReplayContext, base: BaseFit, fits: dict) -> tuple:
    """Gap of the base replay and of every candidate on the whole record [%]."""
    sig = ctx.sig
    per_base = {s: meas.nmse(s, p, getattr(sig, s)) for s, p in base.predictions.items()}
    before = meas.gap(per_base)
    afters = {}
    for name, ef in fits.items():
        per = dict(per_base)
        for s_, p in ef.predictions.items():
            per[s_] = meas.nmse(s_, p, getattr(sig, s_)) - meas.rounding_left(
                s_, ef.explained.get(s_, 0.0)
            )
        afters[name] = meas.gap(per)
    return before, afters


def select_winner(
    ctx: ReplayContext, base: BaseFit, fits: dict, held: dict, scores: dict, evidences: dict
) -> Selection:
    """The best-ranked candidate that lowers the gap on the record (else ``none``).

    An effect is named only if adding it reduces the gap: a gap within the noise (0)
    is explained by the two-parameter model, and an effect that wins on held-out data
    without reducing the gap on the record is not the explanation; it is excluded and
    the next candidate taken.
    """
    rank = rank_key(scores, evidences)
    n_judged = max(float(ctx.w_eval.sum()), 1.0)
    heldout_pv = [
        float(held[name]["pv"].sum()) / n_judged * ctx.norm["pv"]
        for name in ["none", *fits]
        if "pv" in held[name] and (name == "none" or "pv" in fits[name].predictions)
    ]
    if base.pv_floor is None:
        raise ValueError("the gap is measured with the base fit on the whole record")
    base_pv_floor = base.pv_floor
    excluded: set = set()
    while True:
        order = sorted([e for e in ["none", *fits] if e not in excluded], key=rank)
        winner = order[0]
        win_fit = None if winner == "none" else fits[winner]
        floors = noise_floors(ctx, win_fit, base_pv_floor, heldout_pv)
        meas = Measure(norm=ctx.norm, floor=floors, w=ctx.w_eval)
        before, afters = record_gaps(meas, ctx, base, fits)
        if winner == "none" or afters[winner] < before:
            return Selection(winner, order, excluded, meas, before, afters)
        excluded.add(winner)


def heldout_gap(
    ctx: ReplayContext,
    meas: Measure,
    per_signal: dict,
    extra: float = 0.0,
    explained: dict | None = None,
) -> float:
    """Gap [%] of per-block held-out errors ``per_signal`` (summed over the blocks),
    with ``extra`` (a penalty) added, measured as on the record by ``meas``.

    Held-out errors have a candidate's rounding variance (``explained`` [units^2])
    taken out in full; as on the record, only the part the noise floor does not hold
    counts (:meth:`Measure.rounding_left`).
    """
    n_judged = max(float(ctx.w_eval.sum()), 1.0)
    expl = explained or {}
    tot = sum(
        meas.excess(
            s,
            float(v.sum()) / n_judged
            + expl.get(s, 0.0) / ctx.norm[s]
            - meas.rounding_left(s, expl.get(s, 0.0)),
        )
        for s, v in per_signal.items()
    )
    return 100.0 * math.sqrt(max(tot + extra / n_judged, 0.0))


def ranked_candidates(
    ctx: ReplayContext,
    sel: Selection,
    fits: dict,
    errors: dict,
    scores: dict,
    evidences: dict,
) -> list[Candidate]:
    """Every fitted effect as a :class:`~stictiondiag.gap.result.Candidate`: its gap
    on the record and on held-out blocks, its penalised score and whether it is
    accepted, in the order of :func:`rank_key`."""
    cands = []
    for name, ef in fits.items():
        after_c = sel.afters[name]
        cands.append(
            Candidate(
                effect=name,
                variant=ef.variant,
                after=after_c,
                shrink_pct=100.0 * (sel.before - after_c) / sel.before if sel.before > 0 else 0.0,
                params=ef.params,
                n_params=ef.n_params,
                heldout=heldout_gap(ctx, sel.measure, errors[name], explained=ef.explained),
                penalised_score=heldout_gap(
                    ctx,
                    sel.measure,
                    errors[name],
                    scores[name].penalty_excess,
                    explained=ef.explained,
                ),
                accepted=scores[name].accepted and name not in sel.excluded,
            )
        )
    cands.sort(key=lambda c: rank_key(scores, evidences)(c.effect))
    return cands
