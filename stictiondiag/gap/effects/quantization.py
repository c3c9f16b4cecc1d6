"""Effect ``quantization``: historian or instrument resolution (Loop 4, Section 3).

Acts on any signal whose values lie on a grid (Fig. 6 of Choudhury, Thornhill & Shah
2005): the rounding error ``q^2/12`` of each quantised signal counts as a known
measurement error.  Parameters: one step per quantised signal.  Signature: the
grid itself, read from the data (:func:`detect_quantization`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.base import (
    BaseFit,
    Effect,
    EffectFit,
    EffectParams,
)
from stictiondiag.identification.controller import filtered_pv

#: The signals whose rounding is read, in the order they are reported.
QUANTISED_SIGNALS = ("op", "mv", "pv")


@dataclass(frozen=True)
class Rounding:
    """The grid a recorded signal's values lie on.

    Attributes
    ----------
    step : float
        Resolution [units of the signal].
    offset : float
        The grid's level nearest zero [units of the signal].
    """

    step: float
    offset: float


@dataclass(frozen=True)
class QuantizationParams(EffectParams):
    """The resolution of each quantised signal (one parameter each, the step).

    Attributes
    ----------
    op, mv, pv : Rounding or None
        The signal's grid; None when it is not quantised (or not counted).
    op_from_pv_rounding : float or None
        Variance per sample of the controller replay's error that a historian-rounded
        pv causes [(% of span)^2]; None without one.
    """

    op: Rounding | None = None
    mv: Rounding | None = None
    pv: Rounding | None = None
    op_from_pv_rounding: float | None = None

    def signals(self) -> tuple[str, ...]:
        """The quantised signals, in the order op, mv, pv."""
        return tuple(s for s in QUANTISED_SIGNALS if getattr(self, s) is not None)

    def to_dict(self) -> dict:
        """``<signal>_step`` and ``<signal>_offset`` per quantised signal, then
        ``op_from_pv_rounding`` where there is one."""
        out: dict = {}
        for s in self.signals():
            grid = getattr(self, s)
            out[f"{s}_step"] = grid.step
            out[f"{s}_offset"] = grid.offset
        if self.op_from_pv_rounding is not None:
            out["op_from_pv_rounding"] = self.op_from_pv_rounding
        return to_plain(out)


def quantize(x: np.ndarray, step: float, offset: float = 0.0) -> np.ndarray:
    """Round ``x`` to the grid ``offset + step * integer`` (instrument or historian resolution)."""
    return offset + step * np.round((np.asarray(x, dtype=float) - offset) / step)


def detect_quantization(x: np.ndarray | None) -> tuple[float, float] | None:
    """Resolution of a recorded signal: the step and offset of the grid its values lie on.

    A signal counts as quantised when all its distinct values are whole multiples of
    the smallest difference between them (to 1 % of that step), that step is at least
    1/1000 of the signal's standard deviation (a coarser grid than the decimals of a
    CSV file), and there are at least two levels.

    Returns
    -------
    (step, offset) or None
        Step [units of x] and the level nearest zero, or None when not quantised.
    """
    if x is None:
        return None
    values = np.unique(np.asarray(x, dtype=float)[np.isfinite(x)])
    if values.size < 2:
        return None
    sd = float(np.std(x))
    if not sd > 0.0:
        return None
    diffs = np.diff(values)
    step = float(np.min(diffs))
    if step < 1e-3 * sd:
        return None
    rel = (values - values[0]) / step
    if float(np.max(np.abs(rel - np.round(rel)))) > 0.01:
        return None
    offset = float(values[0] - step * np.round(values[0] / step))
    return step, offset


def fit_quantization(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[QuantizationParams] | None = None,
) -> EffectFit[QuantizationParams] | None:
    """Historian or instrument resolution (Loop 4 of Section 3, Fig. 6).

    The resolution (step ``q``) of each recorded signal is read from the data
    (:func:`detect_quantization`).  A continuous replay cannot reproduce the rounding:
    the recorded value departs from the true one by a rounding error of variance
    ``q^2/12``, which the augmented replay accounts for as a known measurement error
    (one parameter per quantised signal, the step).  The replay itself is unchanged.
    None when no signal is quantised.
    """
    preds, grids, explained = {}, {}, {}
    base_preds = base.predictions
    for name in QUANTISED_SIGNALS:
        x = getattr(ctx.sig, name)
        q = detect_quantization(x)
        if q is None or name not in base_preds:
            continue
        step, offset = q
        preds[name] = base_preds[name]
        explained[name] = step * step / 12.0
        grids[name] = Rounding(step, offset)
    if not preds:
        return None
    extra = None
    if "pv" in grids:
        # A pv rounded by the historian (not by the instrument the controller reads)
        # also throws the controller replay off: it is driven by the rounded pv.
        pv_grid = grids["pv"]
        extra = _rounding_in_op(ctx, w, base, pv_grid.step, pv_grid.offset)
        if extra > 0.0:
            preds["op"] = base_preds["op"]
            explained["op"] = explained.get("op", 0.0) + extra
        else:
            extra = None
    params = QuantizationParams(**grids, op_from_pv_rounding=extra)
    return EffectFit(
        effect="quantization",
        variant="+".join(preds),
        n_params=len(grids),
        params=params,
        predictions=preds,
        explained=explained,
    )


def quantized_signals(ef: EffectFit[QuantizationParams]) -> tuple[str, ...]:
    """The signals whose resolution a quantization fit reads from the data (``op``,
    ``mv``, ``pv``, in that order)."""
    return ef.params.signals()


def restrict_quantization(
    ef: EffectFit[QuantizationParams], signals: tuple[str, ...]
) -> EffectFit[QuantizationParams]:
    """The quantization fit ``ef`` with the resolution of ``signals`` only.

    Each step is one parameter and acts on its own signal (a historian-rounded pv also
    on the controller replay, ``op_from_pv_rounding``), so a loop whose mv is rounded
    and whose pv is rounded too finely to matter is explained by mv's step alone; the
    gap diagnosis keeps the subset that pays for its parameters
    (:func:`stictiondiag.gap.diagnose.diagnose_gap`).
    """
    grids, explained, preds = {}, {}, {}
    for name in ef.params.signals():
        if name not in signals:
            continue
        grid = getattr(ef.params, name)
        grids[name] = grid
        explained[name] = grid.step * grid.step / 12.0
        preds[name] = ef.predictions[name]
    extra = ef.params.op_from_pv_rounding
    if "pv" not in grids:
        extra = None
    if extra is not None:
        explained["op"] = explained.get("op", 0.0) + float(extra)
        preds["op"] = ef.predictions["op"]
    preds = {k: v for k, v in ef.predictions.items() if k in preds}
    return replace(
        ef,
        variant="+".join(preds),
        n_params=len(grids),
        params=QuantizationParams(**grids, op_from_pv_rounding=extra),
        predictions=preds,
        explained=explained,
    )


def quantization_subsets(
    ef: EffectFit[QuantizationParams],
) -> dict[tuple[str, ...], EffectFit[QuantizationParams]]:
    """The quantization fit ``ef`` restricted to every proper subset of its quantised
    signals (:func:`restrict_quantization`), by subset, fewest signals first: each
    step is one parameter, so the gap diagnosis judges each subset on held-out data
    and keeps the one that pays (:func:`stictiondiag.gap.selection.choose_quantization`)."""
    names = quantized_signals(ef)
    subsets = [c for r in range(1, len(names)) for c in itertools.combinations(names, r)]
    return {sub: restrict_quantization(ef, sub) for sub in subsets}


def _rounding_in_op(
    ctx: ReplayContext, w: np.ndarray, base: BaseFit, step: float, offset: float
) -> float:
    """Variance per sample of the controller replay's error that a rounded pv causes
    [(% of span)^2].

    The replayed controller
    (:func:`stictiondiag.identification.controller.fit_controller_replay`) is driven by the recorded pv; if
    the historian rounded pv after the controller read it, the replay answers the
    rounding error ``e`` that the controller never saw, by ``Kc (e_f + (1/Ti) int e_f)``
    (``e_f`` the filtered ``e``).  ``e`` is unobserved; its stand-in is the rounding of
    the continuous process replay (same step and grid), which moves like pv and so has
    the rounding error's own correlation.  The value is capped by the controller
    replay's error on ``w``: when the instrument rounds (the controller reads the
    rounded pv), the replay has no such error and nothing is explained.
    """
    ctrl = base.controller
    kc = float(ctrl.gain or 0.0)
    if kc == 0.0 or step <= 0.0:
        return 0.0
    dt = ctx.sig.dt
    smooth = np.asarray(base.process.prediction.pv, dtype=float)
    e = quantize(smooth, step, offset) - smooth
    tf = float(ctrl.filter_time_s or 0.0)
    ef = filtered_pv(e, tf, dt) if tf > 0.0 else e
    ti = ctrl.integral_time_s
    d_op = kc * ef
    if ti:
        d_op = d_op + kc / float(ti) * np.cumsum(ef) * dt
    wsum = max(float(w.sum()), 1.0)
    d_op = d_op - float(np.dot(w, d_op)) / wsum
    predicted = float(np.dot(w, d_op * d_op)) / wsum
    r = base.op - ctx.sig.op
    observed = float(np.dot(w, r * r)) / wsum
    return min(predicted, observed)


EFFECT = Effect(
    name="quantization",
    acts_on=("op", "mv", "pv"),
    parameters=("op_step", "mv_step", "pv_step"),
    fit=fit_quantization,
    signature="the signal's values lie on a grid",
    signature_test=detect_quantization,
)
