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
(:func:`stictiondiag.gap.effects.process_noise_floor`), and never below the best pv
replay's error on held-out data.  A quantised signal's rounding error (``q^2/12``)
counts as explained once quantization is added.

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
effectively independent residuals, the judged samples over the residuals' integrated
autocorrelation time); when the log ratio of the blocks' errors, base against effect,
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
:func:`stictiondiag.gap.effects.gain_change_test`).  A signature with a direction is
tested one-sided, in the direction of the fitted effect.  ``none`` wins when no
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

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.errors import DataError
from stictiondiag.gap import effects as fx

#: Blocks of the record for validation (even blocks against odd ones).
N_BLOCKS = 8
#: Standard errors of the block-by-block improvement a candidate must exceed [-].
SIGNIFICANCE = 2.0
#: Fewest effectively independent residuals assumed for the per-parameter penalty [-].
MIN_EFFECTIVE_SAMPLES = 10
#: Shortest record analysed [samples].
MIN_SAMPLES = 400

METRIC_NAME = "excess_nrmse"
METRIC_DEFINITION = (
    "100 * sqrt(sum over op, mv, pv of max(MSE_s - N_s, 0) / V_s) [%]: driven replay "
    "(mv from recorded op, pv from recorded mv predicted dead time + time constant "
    "ahead with the load tracked, op from recorded sp and pv); V_s the variance of the "
    "signal's cycle-scale part, N_s its white-noise variance; 0 means within noise"
)

SIGNALS = ("op", "mv", "pv")


# --------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Candidate:
    """One effect added to the replay.

    Attributes
    ----------
    effect : str
        Effect name (see :data:`stictiondiag.gap.effects.EFFECTS`).
    variant : str
        Form that fitted best (e.g. ``step`` for a time-varying stiction).
    after : float
        Gap with the effect added, fitted on the whole record [%].
    shrink_pct : float
        Reduction of the gap [% of the gap before].
    params : dict
        Fitted parameters (units in the key names).
    n_params : int
        Parameters beyond the base model's.
    heldout : float
        Gap on held-out data (fitted on the other half) [%].
    penalised_score : float
        Held-out gap with the penalty for extra parameters added [%].
    accepted : bool
        The held-out improvement over the base model exceeds the penalty.
    """

    effect: str
    variant: str
    after: float
    shrink_pct: float
    params: dict
    n_params: int
    heldout: float
    penalised_score: float
    accepted: bool

    def to_dict(self) -> dict:
        return _plain(
            {
                "effect": self.effect,
                "variant": self.variant,
                "after": self.after,
                "shrink_pct": self.shrink_pct,
                "params": self.params,
                "n_params": self.n_params,
                "heldout": self.heldout,
                "penalised_score": self.penalised_score,
                "accepted": self.accepted,
            }
        )


@dataclass(frozen=True)
class GapDiagnosis:
    """Sim-to-real gap of a loop and the effect that explains it.

    Attributes
    ----------
    metric : str
        Name of the gap measure (:data:`METRIC_NAME`).
    definition : str
        Its definition (:data:`METRIC_DEFINITION`).
    before : float
        Gap of the two-parameter replay [%].
    after : float
        Gap with the winning effect added [%] (= before for ``none``).
    shrink_pct : float
        Reduction of the gap by the winning effect [% of before].
    effect : str
        The winning effect, ``none`` when the two-parameter model explains the data
        to within its noise or no effect beats it on held-out data.
    runner_up : str or None
        Second-best candidate (accepted effects by evidence, then ``none``, then the
        rest by penalised score).
    margin : float
        How clearly the winner won [%]: the share of the winner's penalised gain over
        the base model that the runner-up does not reach (100 when the runner-up gains
        nothing; between two accepted effects, the share of the winner's evidence the
        runner-up lacks); for ``none``, how far the best candidate's penalised score lies
        above the base model's error, in % of it.
    candidates : tuple of Candidate
        Every assessed effect, in the order of ``runner_up``.
    breakdown : dict
        Where the gap lies, before and after: by signal, valve phase, frequency,
        time and feature (JSON-able).
    not_assessed : tuple of str
        Effects that cannot be assessed with the data (e.g. valve-side effects
        without a recorded mv).
    heldout_before : float
        Gap of the two-parameter replay on held-out data [%] (the score of ``none``).
    base : dict
        The base replay's parameters: S and J [% of span], valve logic, process,
        controller.
    series : dict
        Time series for plots: ``time`` [s], recorded ``op``, ``mv``, ``pv`` and the
        replays ``<signal>_before`` and ``<signal>_after`` (None where absent).
    """

    metric: str
    definition: str
    before: float
    after: float
    shrink_pct: float
    effect: str
    runner_up: str | None
    margin: float
    candidates: tuple
    breakdown: dict
    not_assessed: tuple = ()
    heldout_before: float = 0.0
    base: dict = field(default_factory=dict)
    series: dict = field(default_factory=dict, repr=False, compare=False)

    def to_dict(self) -> dict:
        """JSON-able summary (no time series): the keys of ``gap`` in the analysis JSON."""
        return _plain(
            {
                "metric": self.metric,
                "definition": self.definition,
                "units": "%",
                "before": self.before,
                "after": self.after,
                "shrink_pct": self.shrink_pct,
                "effect": self.effect,
                "runner_up": self.runner_up,
                "margin": self.margin,
                "candidates": [c.to_dict() for c in self.candidates],
                "breakdown": self.breakdown,
                "not_assessed": list(self.not_assessed),
                "heldout_before": self.heldout_before,
                "base": self.base,
            }
        )

    def to_pandas(self):
        """The recorded signals and the replays before and after, one row per sample."""
        import pandas as pd

        return pd.DataFrame({k: v for k, v in self.series.items() if v is not None})

    def plot(self):
        """Where the gap lies (:func:`stictiondiag.plotting.gap.plot_gap_breakdown`)."""
        from stictiondiag.plotting.gap import plot_gap_breakdown

        return plot_gap_breakdown(self)

    def figures(self) -> dict:
        """Figures by name: ``gap_breakdown`` and ``gap_replay``."""
        from stictiondiag.plotting.gap import (
            plot_gap_breakdown,
            plot_gap_replay,
        )

        return {"gap_breakdown": plot_gap_breakdown(self), "gap_replay": plot_gap_replay(self)}


def _plain(obj):
    """Strictly JSON-able: numpy scalars to Python, NaN and inf to None."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_plain(v) for v in obj.tolist()]
    if isinstance(obj, bool | np.bool_):
        return bool(obj)
    if isinstance(obj, int | np.integer):
        return int(obj)
    if isinstance(obj, float | np.floating):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


# --------------------------------------------------------------------------------------
# Measure
# --------------------------------------------------------------------------------------


def noise_variance(x: np.ndarray) -> float:
    """White measurement-noise variance of a signal from its sample-to-sample changes.

    ``(1.4826 MAD(diff x))^2 / 2``: the median ignores the few large changes (slips,
    steps), and a still or slowly moving signal changes by its noise alone.
    """
    d = np.diff(np.asarray(x, dtype=float))
    if d.size == 0:
        return 0.0
    mad = float(np.median(np.abs(d - np.median(d))))
    return (1.4826 * mad) ** 2 / 2.0


@dataclass(frozen=True)
class _Measure:
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

    def gap(self, per_signal: dict) -> float:
        """Gap [%] from each signal's normalised mean squared error."""
        return 100.0 * math.sqrt(sum(self.excess(s, v) for s, v in per_signal.items()))


def _signals_of(tags) -> fx.LoopSignals:
    try:
        op = np.asarray(tags.op, dtype=float)
        pv = np.asarray(tags.pv, dtype=float)
        ts = float(tags.ts)
    except (AttributeError, TypeError, ValueError):
        raise DataError("gap diagnosis needs tags with op, pv and a sample time ts") from None
    mv = getattr(tags, "mv", None)
    sp = getattr(tags, "sp", None)
    mv = None if mv is None else np.asarray(mv, dtype=float)
    sp = None if sp is None else np.asarray(sp, dtype=float)
    n = op.size
    for name, x in (("op", op), ("pv", pv), ("mv", mv), ("sp", sp)):
        if x is None:
            continue
        if x.size != n:
            raise DataError(f"{name} has {x.size} samples, op has {n}: pass equally long signals")
        if not np.all(np.isfinite(x)):
            raise DataError(f"{name} has gaps (NaN): fill or drop them before the gap diagnosis")
    if n < MIN_SAMPLES:
        raise DataError(
            f"{n} samples are too few for the gap diagnosis: need at least {MIN_SAMPLES}"
        )
    if not (math.isfinite(ts) and ts > 0):
        raise DataError(f"sample time must be a positive number of seconds, got {ts}")
    if np.ptp(op) == 0.0 or np.ptp(pv) == 0.0:
        raise DataError("op or pv is constant: there is no movement to replay")
    if mv is not None and np.ptp(mv) == 0.0:
        mv = None
    return fx.LoopSignals(op=op, pv=pv, dt=ts, mv=mv, sp=sp)


# --------------------------------------------------------------------------------------
# Diagnosis
# --------------------------------------------------------------------------------------


def _blocks(n: int, n_blocks: int) -> np.ndarray:
    """Block index of every sample (contiguous blocks of equal length)."""
    return np.minimum((np.arange(n) * n_blocks) // n, n_blocks - 1)


def _predictions(base: fx.BaseFit, ef: fx.EffectFit | None) -> dict:
    preds = dict(base.predictions())
    if ef is not None:
        preds.update(ef.predictions)
    return preds


def _block_errors(
    preds: dict,
    sig: fx.LoopSignals,
    meas: _Measure,
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


def _add(acc: dict | None, new: dict) -> dict:
    if acc is None:
        return {k: v.copy() for k, v in new.items()}
    for k, v in new.items():
        acc[k] += v
    return acc


def _bic_share(residual: np.ndarray, w: np.ndarray) -> float:
    """``log(n_eff) / n_eff`` for a replay residual: the BIC penalty per parameter as a
    share of the squared error, with ``n_eff`` from :func:`_effective_samples`."""
    n_eff = _effective_samples(residual, w)
    return math.log(n_eff) / n_eff


def _bic_gain(base_error, n_params: float, share: float):
    """Least reduction of a squared error ``base_error`` that pays for ``n_params``
    extra parameters under the Bayesian information criterion.

    BIC asks ``n_eff log(E0 / E1) >= k log(n_eff)``, that is ``E1 <= E0 exp(-k s)`` with
    ``s = log(n_eff) / n_eff``: the reduction ``E0 - E1`` must reach
    ``E0 (1 - exp(-k s))``.  For a small ``k s`` this is ``k s E0``; for a large one
    (few effectively independent residuals) it stays below ``E0``, so an effect that
    removes most of the error is never asked for more than all of it.
    """
    return base_error * -math.expm1(-n_params * share)


def _effective_samples(residual: np.ndarray, w: np.ndarray) -> float:
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


def _blocks_agree(gain: np.ndarray, threshold: np.ndarray) -> bool:
    """Whether the blocks bear out an effect: it is better by more than ``threshold``
    in at least two blocks and in at least as many blocks as it is worse by as much.

    A block the effect changes by less than the threshold counts neither way: a
    change of stiction during the record, or an effect that shows only where the
    operating point goes, leaves the rest of the record as the base model has it.
    """
    better = int(np.sum(gain > threshold))
    worse = int(np.sum(gain < -threshold))
    return better >= max(worse, 2)


def diagnose_gap(
    tags,
    fit=None,
    replay=None,
    *,
    n_blocks: int = N_BLOCKS,
    effects: tuple[str, ...] | None = None,
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

    Returns
    -------
    GapDiagnosis

    Raises
    ------
    DataError
        Too short, gaps, constant op or pv.
    """
    sig = _signals_of(tags)
    n = sig.n
    n_blocks = max(int(n_blocks), 4)
    start = None
    mv_model = None
    if fit is not None:
        S, J = getattr(fit, "S", None), getattr(fit, "J", None)
        if S is not None and J is not None and math.isfinite(S) and math.isfinite(J):
            start = (float(S), float(J))
        if sig.mv is None and getattr(fit, "mv_model", None) is not None:
            mv_model = np.asarray(fit.mv_model, dtype=float)
            if mv_model.size != n:
                mv_model = None
    ctx = fx.build_context(sig, start=start, mv_model=mv_model)
    assessable, not_assessed = fx.assessable_effects(sig.mv is not None)
    if effects is not None:
        unknown = [e for e in effects if e not in fx.EFFECTS]
        if unknown:
            raise DataError(
                f"unknown effect(s) {', '.join(unknown)}: use {', '.join(fx.EFFECTS[1:])}"
            )
        assessable = [e for e in assessable if e in effects]

    # Whole-record fits.
    base = fx.fit_base(ctx, ctx.w_eval)
    fits = {}
    for name in assessable:
        ef = fx.EFFECT_MODELS[name](ctx, ctx.w_eval, base)
        if ef is not None:
            fits[name] = ef
    norm_only = _Measure(norm=ctx.norm, floor=dict.fromkeys(ctx.norm, 0.0), w=ctx.w_eval)

    # Held-out errors: fit on even blocks, judge on odd ones, and the other way round.
    blocks = _blocks(n, n_blocks)
    held: dict = dict.fromkeys(["none", *fits])
    # Quantization: every subset of the quantised signals (each step one parameter).
    q_subsets = []
    if "quantization" in fits:
        q_sig = fx.quantized_signals(fits["quantization"])
        q_subsets = [c for r in range(1, len(q_sig)) for c in itertools.combinations(q_sig, r)]
    q_held: dict = dict.fromkeys(q_subsets)
    for parity in (0, 1):
        train = (blocks % 2 == parity).astype(float)
        test = 1.0 - train
        w_train = ctx.w_eval * train
        base_f = fx.fit_base(ctx, w_train, like=base)
        errs = _block_errors(base_f.predictions(), sig, norm_only, blocks, test, n_blocks)
        held["none"] = _add(held["none"], errs)
        for name, ef_full in fits.items():
            ef = fx.EFFECT_MODELS[name](ctx, w_train, base_f, init=ef_full)
            if ef is None:
                ef = ef_full
            errs = _block_errors(
                _predictions(base_f, ef), sig, norm_only, blocks, test, n_blocks, ef.explained
            )
            held[name] = _add(held[name], errs)
            if name == "quantization":
                for sub in q_subsets:
                    ef_s = fx.restrict_quantization(ef, sub)
                    errs = _block_errors(
                        _predictions(base_f, ef_s),
                        sig,
                        norm_only,
                        blocks,
                        test,
                        n_blocks,
                        ef_s.explained,
                    )
                    q_held[sub] = _add(q_held[sub], errs)

    # Per-parameter penalty of each signal, as for the Bayesian information criterion
    # (an extra parameter must lower n log(SSE) by log(n)): a share log(n_eff)/n_eff of
    # the base error, with n_eff the number of effectively independent residuals
    # (the record over the residuals' integrated autocorrelation time), so that
    # slowly varying replay errors do not count as many independent samples.
    n_eff = {
        s: _effective_samples(p - getattr(sig, s), ctx.w_eval)
        for s, p in base.predictions().items()
    }
    share = {s: math.log(v) / v for s, v in n_eff.items()}

    if q_subsets:
        # All quantised signals when their steps together pay for themselves on
        # held-out data, else the subset that pays best: a step is one parameter on
        # its own signal, and a pv rounded too finely to matter must not charge an
        # mv rounding the BIC share of pv's error (pv carries load no replay
        # foresees).
        def q_net(h: dict, ef: fx.EffectFit) -> float:
            sigs = [s for s in ef.predictions if s in held["none"]]
            gain = sum(float((held["none"][s] - h[s]).sum()) for s in sigs)
            return gain - sum(
                _bic_gain(float(held["none"][s].sum()), ef.n_params, share[s]) for s in sigs
            )

        full_net = q_net(held["quantization"], fits["quantization"])
        best_q = (full_net, None)
        for sub in q_subsets if full_net <= 0.0 else ():
            ef_s = fx.restrict_quantization(fits["quantization"], sub)
            net = q_net(q_held[sub], ef_s)
            if net > best_q[0]:
                best_q = (net, sub)
        if best_q[1] is not None:
            fits["quantization"] = fx.restrict_quantization(fits["quantization"], best_q[1])
            held["quantization"] = q_held[best_q[1]]

    # Penalised scores (normalised held-out squared error summed over signals).
    base_preds = base.predictions()
    totals = {name: sum(v for v in h.values()) for name, h in held.items()}
    base_total = float(totals["none"].sum())
    scores = {"none": (base_total, True, 0.0)}
    evidence = {"none": 0.0}
    for name, ef in fits.items():
        d = totals["none"] - totals[name]
        # For effects on the valve, the improvement without its best and its worst
        # block (scaled back to the whole record): one block where the valve replay
        # happens to fall in or out of step with the data must not decide.
        if "mv" in ef.predictions:
            trimmed = (float(d.sum()) - float(d.max()) - float(d.min())) * n_blocks / (n_blocks - 2)
        else:
            # Process-side replays are not thrown out of step by a lucky or unlucky
            # block; an installed characteristic may show in the one block where the
            # valve travels far from its operating point.
            trimmed = float(d.sum())
        # Scatter of the block improvements, robust to a few blocks where a real
        # effect matters most (a characteristic away from the operating point).
        se = 1.4826 * float(np.median(np.abs(d - np.median(d)))) * math.sqrt(n_blocks)
        # The per-parameter share is of the base error on the signals the effect
        # changes: a valve effect is not asked to beat the process replay's error.
        sigs = [s for s in ef.predictions if s in held["none"]]
        per_param = sum(
            _bic_gain(float(held["none"][s].sum()), ef.n_params, share[s]) for s in sigs
        )
        penalty = max(SIGNIFICANCE * se, per_param)
        # The scatter in absolute terms overstates the uncertainty when the blocks'
        # errors differ in size (a valve replay far out of step in some blocks): the
        # same test on the log ratio of each block's errors is free of that scale.
        # When it passes, the penalty is the per-parameter share alone.
        e0_b = sum(held["none"][s] for s in sigs)
        e1_b = sum(held[name][s] for s in sigs)
        if sigs:
            # A block without judged samples (the start of the record) counts as even.
            both = (e0_b > 0.0) & (e1_b > 0.0)
            lr = np.where(both, np.log(np.where(both, e0_b, 1.0) / np.where(both, e1_b, 1.0)), 0.0)
            if "mv" in ef.predictions:
                keep_b = np.ones(n_blocks, dtype=bool)
                keep_b[int(np.argmax(d))] = False
                keep_b[int(np.argmin(d))] = False
                lr_sum = float(lr[keep_b].sum()) * n_blocks / (n_blocks - 2)
            else:
                lr_sum = float(lr.sum())
            se_lr = 1.4826 * float(np.median(np.abs(lr - np.median(lr)))) * math.sqrt(n_blocks)
            if lr_sum > SIGNIFICANCE * se_lr:
                penalty = per_param
        # Better in at least as many blocks as worse, and in two at least
        # (:func:`_blocks_agree`), each time by more than the per-parameter share of
        # the base error on the signals the effect changes.
        per_param_b = sum(
            _bic_gain(np.abs(held["none"][s]), max(ef.n_params, 1), share[s]) for s in sigs
        )
        # A real effect also explains the whole record it was fitted on: a held-out
        # gain that the in-sample fit does not show comes from a poor fit of the base
        # on a half, not from the effect.
        in_gain_norm = sum(
            (
                float(np.dot(ctx.w_eval, (base_preds[s] - getattr(sig, s)) ** 2))
                - float(np.dot(ctx.w_eval, (ef.predictions[s] - getattr(sig, s)) ** 2))
                + float(ctx.w_eval.sum()) * ef.explained.get(s, 0.0)
            )
            / ctx.norm[s]
            for s in sigs
        )
        consistent = _blocks_agree(d, per_param_b) and ef.supported and in_gain_norm > penalty
        accepted = trimmed > penalty and consistent
        score = base_total - trimmed + penalty if consistent else base_total + penalty
        scores[name] = (score, accepted, score - float(totals[name].sum()))
        # Evidence for the effect on the held-out blocks (those of ``trimmed``), in the
        # units of the Bayesian information criterion: per signal it changes, n_eff
        # times the log ratio of the base's squared error to the effect's, less log
        # n_eff per extra parameter.  Signals differ in how much of their error a
        # replay can ever explain (pv carries load no replay foresees): the accepted
        # candidates are ranked by this ratio-based evidence, not by the raw sum.
        kept = np.ones(n_blocks, dtype=bool)
        if "mv" in ef.predictions:
            kept[int(np.argmax(d))] = False
            kept[int(np.argmin(d))] = False
        ev = 0.0
        for s in sigs:
            e0 = float(held["none"][s][kept].sum())
            e1 = float(held[name][s][kept].sum())
            if e0 > 0.0 and e1 > 0.0:
                ev += n_eff[s] * math.log(e0 / e1)
        if sigs:
            ev -= ef.n_params * max(math.log(n_eff[s]) for s in sigs)
        evidence[name] = ev
    n_judged = max(float(ctx.w_eval.sum()), 1.0)
    heldout_pv = [
        float(held[name]["pv"].sum()) / n_judged * ctx.norm["pv"]
        for name in ["none", *fits]
        if "pv" in held[name] and (name == "none" or "pv" in fits[name].predictions)
    ]
    base_pv_floor = fx.process_noise_floor(fx._process_input(ctx, base), ctx, base.process)

    def rank(e: str) -> tuple:
        # Accepted effects first, most evidence first; then ``none``; then the rest by
        # penalised score.
        if e == "none":
            return (1, 0.0)
        if scores[e][1]:
            return (0, -evidence[e])
        return (2, scores[e][0])

    excluded: set = set()
    while True:
        order = sorted([e for e in ["none", *fits] if e not in excluded], key=rank)
        winner = order[0]
        win_fit = None if winner == "none" else fits[winner]
        # Noise floors: white noise of mv; measurement noise and unforeseeable load of
        # the pv prediction (from the winner's process replay when the effect is on
        # the process side: an unmodelled disturbance would otherwise pass for load),
        # never below what the best pv replay achieves on held-out data (the load the
        # replay tracks is not white, so part of it stays unpredictable whatever the
        # valve or the process does); none for op, which the controller replays
        # exactly.
        pv_floor = base_pv_floor
        if win_fit is not None and win_fit.pv_floor is not None:
            pv_floor = win_fit.pv_floor
        floors = {"op": 0.0, "pv": max(pv_floor, min(heldout_pv))}
        if sig.mv is not None:
            floors["mv"] = noise_variance(sig.mv)
        meas = _Measure(norm=ctx.norm, floor=floors, w=ctx.w_eval)

        # In-sample gaps before and after.
        per_base = {s: meas.nmse(s, p, getattr(sig, s)) for s, p in base.predictions().items()}
        before = meas.gap(per_base)
        afters = {}
        for name, ef in fits.items():
            per = dict(per_base)
            for s_, p in ef.predictions.items():
                per[s_] = (
                    meas.nmse(s_, p, getattr(sig, s_)) - ef.explained.get(s_, 0.0) / ctx.norm[s_]
                )
            afters[name] = meas.gap(per)
        # An effect is named only if adding it reduces the gap: a gap within the noise
        # (0) is explained by the two-parameter model, and an effect that wins on
        # held-out data without reducing the gap on the record is not the explanation.
        if winner == "none" or afters[winner] < before:
            break
        excluded.add(winner)
    runner = order[1] if len(order) > 1 else None
    # Margin: the share of the winner's penalised gain over the base model that the
    # runner-up does not reach (100: the runner-up gains nothing); for ``none``, how
    # far the best candidate's penalised score lies above the base error.
    margin = 0.0
    if runner is not None:
        gain = base_total - scores[winner][0]
        if winner == "none":
            margin = 100.0 * (scores[runner][0] - base_total) / max(base_total, 1e-300)
        elif runner != "none" and scores[runner][1]:
            # Both accepted: the share of the winner's evidence the runner-up lacks.
            margin = 100.0 * (evidence[winner] - evidence[runner]) / max(evidence[winner], 1e-300)
        else:
            margin = 100.0 * (scores[runner][0] - scores[winner][0]) / max(gain, 1e-300)

    def as_gap(per_signal: dict, extra: float = 0.0) -> float:
        tot = sum(meas.excess(s, float(v.sum()) / n_judged) for s, v in per_signal.items())
        return 100.0 * math.sqrt(max(tot + extra / n_judged, 0.0))

    cands = []
    for name, ef in fits.items():
        after_c = afters[name]
        shrink_c = 100.0 * (before - after_c) / before if before > 0 else 0.0
        _, accepted, penalty = scores[name]
        cands.append(
            Candidate(
                effect=name,
                variant=ef.variant,
                after=after_c,
                shrink_pct=shrink_c,
                params=_plain(dict(ef.params)),
                n_params=ef.n_params,
                heldout=as_gap(held[name]),
                penalised_score=as_gap(held[name], penalty),
                accepted=accepted and name not in excluded,
            )
        )
    cands.sort(key=lambda c: rank(c.effect))
    if winner == "none":
        after, shrink = before, 0.0
    else:
        win = next(c for c in cands if c.effect == winner)
        after, shrink = win.after, win.shrink_pct

    preds_before = base.predictions()
    preds_after = _predictions(base, win_fit)
    breakdown = _breakdown(sig, ctx, meas, base, preds_before, preds_after, replay)
    series = {"time": np.arange(n) * sig.dt}
    for s in SIGNALS:
        x = getattr(sig, s)
        series[s] = x
        series[f"{s}_before"] = preds_before.get(s)
        series[f"{s}_after"] = preds_after.get(s)
    base_info = {
        "valve": None
        if base.valve is None
        else {
            **base.valve.params,
            "logic": "kano" if base.valve.kano else "choudhury",
            "initial_direction": base.valve.initial_direction,
        },
        "process": {**base.process.params, "horizon_samples": base.process.model.horizon},
        "controller": base.controller,
        "noise_floor": {s: floors[s] / ctx.norm[s] for s in floors},
        "judged_from_sample": int(np.argmax(ctx.w_eval > 0)),
    }
    return GapDiagnosis(
        metric=METRIC_NAME,
        definition=METRIC_DEFINITION,
        before=before,
        after=after,
        shrink_pct=shrink,
        effect=winner,
        runner_up=runner,
        margin=margin,
        candidates=tuple(cands),
        breakdown=_plain(breakdown),
        not_assessed=tuple(not_assessed),
        heldout_before=as_gap(held["none"]),
        base=_plain(base_info),
        series=series,
    )


# --------------------------------------------------------------------------------------
# Breakdown
# --------------------------------------------------------------------------------------


def _breakdown(sig, ctx, meas, base, before: dict, after: dict, replay) -> dict:
    """Where the gap lies: by signal, phase, frequency, time and feature, before and after."""
    out = {
        "signal": {
            s: {
                "before": 100.0
                * math.sqrt(meas.excess(s, meas.nmse(s, before[s], getattr(sig, s)))),
                "after": 100.0 * math.sqrt(meas.excess(s, meas.nmse(s, after[s], getattr(sig, s)))),
                "noise_floor": 100.0 * math.sqrt(meas.floor[s] / meas.norm[s]),
            }
            for s in before
        }
    }
    phase = base.valve.phase if base.valve is not None else None
    if phase is not None:
        out["phase"] = _by_phase(sig, meas, phase, before, after)
    out["frequency"] = _by_frequency(sig, meas, before, after)
    out["time"] = _by_time(sig, meas, before, after)
    out["feature"] = _by_feature(sig, base, before, after, phase, replay)
    return out


def _phase_labels(phase: np.ndarray) -> np.ndarray:
    """Phase per sample with the breakaway sample and the two after it called slip."""
    lab = phase.astype(np.int64).copy()
    slips = np.where(phase == fx.PHASE_SLIP)[0]
    for k in (1, 2):
        idx = slips + k
        idx = idx[idx < lab.size]
        lab[idx] = fx.PHASE_SLIP
    return lab


def _by_phase(sig, meas, phase, before, after) -> dict:
    """Share of the mv (and pv) squared error in each valve phase (Fig. 2: A-B reversal,
    B-C stuck, C-D slip, D-E moving)."""
    lab = _phase_labels(phase)
    res = {}
    for s in ("mv", "pv"):
        if s not in before:
            continue
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            e = meas.w * (preds[s] - x) ** 2
            tot = float(e.sum()) or 1.0
            for code, name in fx.PHASE_NAMES.items():
                m = lab == code
                entry = res.setdefault(name, {})
                entry.setdefault("samples_pct", 100.0 * float(np.mean(m)))
                entry[f"{s}_share_pct_{when}"] = 100.0 * float(e[m].sum()) / tot
                n_m = float((meas.w * m).sum())
                entry[f"{s}_rms_{when}"] = math.sqrt(float(e[m].sum()) / n_m) if n_m > 0 else None
    return res


def _fundamental(sig) -> float | None:
    """Period of the loop's oscillation [samples], from op (or pv)."""
    for x in (sig.op, sig.pv):
        p = fx.dominant_period_samples(x)
        if p is not None:
            return p
    return None


def _by_frequency(sig, meas, before, after) -> dict:
    """Share of each signal's replay-error energy at the loop's fundamental, at its
    harmonics (2nd to 10th) and elsewhere."""
    period = _fundamental(sig)
    res = {"fundamental_period_s": None if period is None else period * sig.dt}
    if period is None:
        return res
    f0 = 1.0 / period
    for s in before:
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            r = (preds[s] - x) * meas.w
            n = r.size
            nfft = 1 << int(math.ceil(math.log2(n)))
            spec = np.abs(np.fft.rfft(r - r.mean(), nfft)) ** 2
            f = np.arange(spec.size) / nfft
            tot = float(spec.sum()) or 1.0
            fund = np.abs(f - f0) <= 0.15 * f0
            harm = np.zeros_like(fund)
            for h in range(2, 11):
                harm |= np.abs(f - h * f0) <= 0.15 * f0
            harm &= ~fund
            entry = res.setdefault(s, {})
            entry[f"fundamental_pct_{when}"] = 100.0 * float(spec[fund].sum()) / tot
            entry[f"harmonics_pct_{when}"] = 100.0 * float(spec[harm].sum()) / tot
            entry[f"other_pct_{when}"] = 100.0 * float(spec[~(fund | harm)].sum()) / tot
    return res


def _by_time(sig, meas, before, after) -> dict:
    """Gap of each signal in the first and the second half of the record [%]."""
    n = sig.n
    halves = {"early": np.arange(n) < n // 2, "late": np.arange(n) >= n // 2}
    res = {}
    for s in before:
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            for half, m in halves.items():
                v = meas.nmse(s, preds[s], x, meas.w * m)
                res.setdefault(s, {})[f"{half}_{when}"] = 100.0 * math.sqrt(meas.excess(s, v))
    return res


def _half_range(x: np.ndarray) -> float:
    return 0.5 * float(np.percentile(x, 98) - np.percentile(x, 2))


def _slip_features(op, mv, phase, window: int = 3) -> dict:
    """Median jump up and down at the replay's breakaways, moving-phase slope of mv on
    op, and the rise time of the average slip (the corner of the mv-op loop)."""
    slips = np.where(phase == fx.PHASE_SLIP)[0]
    slips = slips[(slips > 2) & (slips < mv.size - 2 * window - 2)]
    jumps_up, jumps_dn = [], []
    for k in slips:
        d = mv[k + window] - mv[k - 1]
        (jumps_up if d > 0 else jumps_dn).append(abs(d))
    resp = []
    for k in slips:
        seg = mv[k - 1 : k + 2 * window + 2] - mv[k - 1]
        amp = seg[-1]
        if abs(amp) > 0:
            resp.append(seg / amp)
    if resp:
        avg = np.mean(resp, axis=0)
        above = np.where(avg >= 0.9)[0]
        rise = float(above[0]) if above.size else float(avg.size)
    else:
        rise = None
    moving = phase == fx.PHASE_MOVING
    num = den = 0.0
    k = 0
    n = mv.size
    while k < n:
        if moving[k]:
            j = k
            while j < n and moving[j]:
                j += 1
            if j - k >= 3:
                o, m = op[k:j] - op[k:j].mean(), mv[k:j] - mv[k:j].mean()
                num += float(np.dot(o, m))
                den += float(np.dot(o, o))
            k = j
        else:
            k += 1
    return {
        "jump_up": float(np.median(jumps_up)) if jumps_up else None,
        "jump_down": float(np.median(jumps_dn)) if jumps_dn else None,
        "moving_slope": num / den if den > 0 else None,
        "corner_rise_samples": rise,
    }


def _by_feature(sig, base, before, after, phase, replay) -> dict:
    """Period, amplitude, jump up and down, moving-phase slope and corner shape of the
    data against the replay before and after."""
    res = {}
    for s in before:
        x = getattr(sig, s)
        entry = {"amplitude_data": _half_range(x)}
        for when, preds in (("before", before), ("after", after)):
            entry[f"amplitude_{when}"] = _half_range(preds[s])
        p = fx.dominant_period_samples(x)
        entry["period_s_data"] = None if p is None else p * sig.dt
        for when, preds in (("before", before), ("after", after)):
            p = fx.dominant_period_samples(preds[s])
            entry[f"period_s_{when}"] = None if p is None else p * sig.dt
        res[s] = entry
    if phase is not None and sig.mv is not None:
        res["valve"] = {
            "data": _slip_features(sig.op, sig.mv, phase),
            "before": _slip_features(sig.op, before["mv"], phase),
            "after": _slip_features(sig.op, after["mv"], phase),
        }
    if replay is not None:
        closed = {}
        for key in ("period_s", "amplitude"):
            v = getattr(replay, key, None)
            if v is not None:
                closed[key] = v
        if closed:
            res["closed_loop_replay"] = closed
    return res


def diagnose_file(path, **read_options) -> GapDiagnosis:
    """Read a loop's file, estimate S and J and diagnose the gap (``stiction gap FILE``).

    Parameters
    ----------
    path : str or Path
        CSV or Parquet file (:func:`stictiondiag.io.tags.read_tags`).
    **read_options
        Column names and sampling options passed to :func:`read_tags`.
    """
    from stictiondiag.io.tags import read_tags

    tags = read_tags(path, **read_options)
    return diagnose_tags(tags)


def diagnose_tags(tags) -> GapDiagnosis:
    """Estimate S and J from the tags and diagnose the gap (no closed-loop replay)."""
    fit = None
    try:
        if tags.mv is not None:
            from stictiondiag.stiction.segments import estimate_from_mv

            fit = estimate_from_mv(tags.op, tags.mv, tags.ts)
        else:
            from stictiondiag.stiction.hammerstein import fit_hammerstein

            fit = fit_hammerstein(
                tags.op,
                tags.pv,
                tags.ts,
                integrating=bool(tags.integrating),
                flow_loop=tags.loop_type == "flow",
            )
    except (ImportError, ValueError):
        fit = None
    return diagnose_gap(tags, fit)
