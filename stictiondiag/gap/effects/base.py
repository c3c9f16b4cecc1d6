"""The base replay of a loop and the result of one effect's fit.

The *driven replay* feeds every element of the loop with its recorded input, so a
departure is located in the element that causes it (Choudhury, Thornhill & Shah 2005):

* valve: ``mv_hat = valve(op)`` (the stiction model, Section 5.1), replayed freely
  from the recorded op;
* process: ``pv_hat = G(mv)`` (first order with dead time, or an integrator; Section
  4.2.2, Eq. 3), driven by the recorded mv (or the modelled mv when mv is not
  recorded) and predicted a dead time plus a time constant ahead, with the unmeasured
  load tracked by a steady-state Kalman filter
  (:func:`stictiondiag.identification.predictor.fit_predictor`);
* controller: ``op_hat = C(sp - pv)`` (a PI controller on a filtered pv, Eq. 3,
  :func:`stictiondiag.identification.controller.fit_controller_replay`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np

from stictiondiag.core.serialize import to_plain
from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.kernels import valve_replay
from stictiondiag.gap.effects.valve import ValveFit, fit_valve
from stictiondiag.identification.controller import ControllerReplay, fit_controller_replay
from stictiondiag.identification.predictor import fit_predictor
from stictiondiag.identification.predictor_kernels import process_noise_floor
from stictiondiag.identification.process_result import ProcessFit, ProcessModel


@dataclass(frozen=True)
class Effect:
    """Declaration of one effect of the catalogue.

    Attributes
    ----------
    name : str
        Effect name, as reported.
    acts_on : tuple of str
        Replayed signals the effect changes (``op``, ``mv``, ``pv``).
    parameters : tuple of str
        Its parameters beyond the base model's, units in the names (``_s`` seconds,
        ``_pct`` % of span; S and J in % of span).
    fit : callable
        ``fit(context, weights, base, init=None)`` returning an :class:`EffectFit`, or
        None when the effect does not apply; ``init`` is the fit on the whole record.
    signature : str
        What the data must show besides a smaller replay error.
    signature_test : callable or None
        The test of that signature (None when it is a bound on a parameter).
    valve_side : bool
        The effect acts on the valve and needs a recorded mv to be assessed.
    """

    name: str
    acts_on: tuple[str, ...]
    parameters: tuple[str, ...]
    fit: Callable[..., EffectFit | None]
    signature: str
    signature_test: Callable | None = None
    valve_side: bool = False


@dataclass(frozen=True)
class EffectParams:
    """An effect's fitted parameters: each effect's own frozen subclass, units in the
    field docs (``_s`` seconds, ``_pct`` % of span; S and J always in % of span).

    :meth:`to_dict` writes the fields by name, in their order (the ``params`` of a
    candidate in the gap's JSON); :attr:`SIGNATURE` names the field that holds the
    p-value of the effect's signature test, if it has one.
    """

    #: The field holding the p-value of the signature test (None: no such test).
    SIGNATURE: ClassVar[str | None] = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able dict of the fields, in their order."""
        return to_plain({f.name: getattr(self, f.name) for f in fields(self)})

    def signature_p(self) -> float | None:
        """The p-value of the signature test; None without one (or before it is run)."""
        return None if self.SIGNATURE is None else getattr(self, self.SIGNATURE)


P = TypeVar("P", bound=EffectParams)


@dataclass(frozen=True)
class EffectFit(Generic[P]):
    """One fitted candidate: the base replay with one effect added.

    Attributes
    ----------
    effect : str
        Effect name (one of :data:`EFFECTS`).
    variant : str
        Which form of the effect fitted best (e.g. ``step`` or ``ramp`` for
        ``time_varying_stiction``).
    n_params : int
        Parameters beyond the base model's.
    params : EffectParams
        Fitted parameters (the effect's own :class:`EffectParams`, units per field).
    predictions : dict
        Replayed signals this effect changes (``mv``, ``pv`` or ``op``) [their units].
    x : tuple
        The searched parameter vector (starts the search on a part of the record).
    process : ProcessFit or None
        For effects on the process side, the process replay with the effect in it.
    pv_floor : float or None
        For effects on the process side, the pv noise floor of that replay
        (:func:`pv_noise_floor`) [pv units^2].
    supported : bool
        False when a check of the effect's own signature fails (an external
        oscillation without a steady phase): it then cannot be named.
    explained : dict
        Variance per sample the effect accounts for as a known measurement error
        (the rounding of a quantised signal), by signal [units^2].
    """

    effect: str
    variant: str
    n_params: int
    params: P
    predictions: dict
    x: tuple = ()
    process: ProcessFit | None = None
    pv_floor: float | None = None
    supported: bool = True
    explained: dict = field(default_factory=dict)


@dataclass(frozen=True)
class BaseFit:
    """The base replay on one set of weights: two-parameter valve, process, controller.

    Attributes
    ----------
    valve : ValveFit or None
        None when mv is not recorded.
    process : ProcessFit
        Process replay driven by the recorded mv (or ``mv_model``).
    op : ndarray
        Controller replay [% of span].
    controller : ControllerReplay
        The PI law that replays op
        (:func:`stictiondiag.identification.controller.fit_controller_replay`).
    mv_model : ndarray
        Valve output of the two-parameter model [% of span].
    pv_floor : float or None
        The pv noise floor of the process replay on the judged samples
        (:func:`pv_noise_floor`) [pv units^2]; None for a fit on part of the record
        (as :attr:`EffectFit.pv_floor`).
    predictions : dict
        The replayed signals by name, ``op``, ``pv`` and (with a valve replay) ``mv``
        [their units], as an :class:`EffectFit` carries those it changes (derived
        from the fields above).
    """

    valve: ValveFit | None
    process: ProcessFit
    op: np.ndarray
    controller: ControllerReplay
    mv_model: np.ndarray
    pv_floor: float | None = None
    predictions: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        preds = {"op": self.op, "pv": self.process.prediction.pv}
        if self.valve is not None:
            preds["mv"] = self.valve.mv
        object.__setattr__(self, "predictions", preds)

    def recorded_valve(self) -> ValveFit:
        """The valve replay, for the valve-side effects: they are fitted only on loops
        with a recorded mv, where :func:`fit_base` always fits one."""
        if self.valve is None:
            raise ValueError("the base fit has no valve replay: mv is not recorded")
        return self.valve


def fit_process(
    u: np.ndarray,
    ctx: ReplayContext,
    w: np.ndarray,
    *,
    extra: np.ndarray | None = None,
    model: ProcessModel | None = None,
    retune: bool = False,
    horizon: int | None = None,
) -> ProcessFit:
    """The process replay of ``ctx``'s pv from the input ``u`` on the weights ``w``
    (:func:`stictiondiag.identification.predictor.fit_predictor`, sharing the
    context's cache of structure terms).

    ``horizon`` (with ``model`` None): the structure is searched afresh but pv is
    predicted this many samples ahead (the load tracking retuned for it).  A
    candidate that refits the process must be judged at the base replay's horizon:
    a structure with a shorter dead time plus time constant predicts fewer samples
    ahead, and a nearer prediction has a smaller error whatever the effect.
    """
    fit = fit_predictor(
        u, ctx.sig.pv, ctx.sig.dt, w, extra=extra, model=model, retune=retune, cache=ctx.cache
    )
    if model is None and horizon is not None and fit.prediction.model.horizon != horizon:
        fit = fit_predictor(
            u,
            ctx.sig.pv,
            ctx.sig.dt,
            w,
            extra=extra,
            model=replace(fit.prediction.model, horizon=int(horizon)),
            retune=True,
            cache=ctx.cache,
        )
    return fit


def pv_noise_floor(
    u: np.ndarray, ctx: ReplayContext, fit: ProcessFit, extra: np.ndarray | None = None
) -> float:
    """The pv noise floor of a process replay on the judged samples of ``ctx`` [pv^2]
    (:func:`stictiondiag.identification.predictor_kernels.process_noise_floor`)."""
    return process_noise_floor(u, ctx.sig.pv, ctx.w_eval, fit, extra)


def process_input(ctx: ReplayContext, base: BaseFit | None = None) -> np.ndarray:
    """The input of the process replay: the recorded mv, else the base fit's modelled
    mv, else the context's ``mv_model`` [% of span]."""
    if ctx.sig.mv is not None:
        return ctx.sig.mv
    if base is not None:
        return base.mv_model
    if ctx.mv_model is None:
        raise ValueError("no process input: mv is not recorded and there is no modelled mv")
    return ctx.mv_model


def fit_base(ctx: ReplayContext, w: np.ndarray, *, like: BaseFit | None = None) -> BaseFit:
    """Fit the base replay: the two-parameter valve, the process and the controller.

    Parameters
    ----------
    ctx : ReplayContext
        Signals, slow-load basis, starting S and J.
    w : ndarray
        Sample weights (0 or 1).
    like : BaseFit, optional
        The fit on the whole record, to start from (fits on parts of the record,
        which carry no pv noise floor).
    """
    sig = ctx.sig
    valve = None
    if sig.mv is not None:
        valve = fit_valve(ctx, w, like=None if like is None else like.valve)
        mvm = valve.mv
    elif ctx.mv_model is not None:
        mvm = ctx.mv_model
    else:
        S, J = ctx.start if ctx.start is not None else (0.0, 0.0)
        mvm, _ = valve_replay(sig.op, S, J)
    u = sig.mv if sig.mv is not None else mvm
    process = fit_process(u, ctx, w, model=None if like is None else like.process.prediction.model)
    # The noise floor of the whole record's process replay (the gap is measured
    # against it); fits on parts of the record are only judged, not measured.
    pv_floor = None if like is not None else process_noise_floor(u, sig.pv, ctx.w_eval, process)
    op_hat, ctrl = fit_controller_replay(sig.sp, sig.pv, sig.op, sig.dt, w)
    return BaseFit(
        valve=valve, process=process, op=op_hat, controller=ctrl, mv_model=mvm, pv_floor=pv_floor
    )
