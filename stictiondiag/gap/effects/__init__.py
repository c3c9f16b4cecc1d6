"""The catalogue of unmodelled effects: augmentations of the driven replay of a loop.

The two-parameter model of Choudhury, Thornhill & Shah (2005) (Section 5.1, Fig. 10,
Eq. 4) never matches a real valve exactly.  Each effect module declares one named
effect (:class:`stictiondiag.gap.effects.base.Effect`): the signals it acts on, its
parameters, its fit by least squares and the test of its own signature in the data,
so :mod:`stictiondiag.gap` can ask which effect explains the departure of the replay
from the data.

=====================  ======  =====================================================
effect                 signal  augmentation (extra parameters)
=====================  ======  =====================================================
actuator_lag           mv      first-order positioner/actuator lag after the friction
                               element (time constant)
miscalibration         mv      moving-phase slope of mv against op not 1 and an offset
                               (Section 4.2.1, Fig. 8 bottom row) (slope, offset)
asymmetry              mv      S and J differ opening and closing (Loop 1, Section 3)
                               (S and J of the second direction)
valve_characteristic   pv, mv  installed characteristic between valve position and
                               flow (Section 5.1, last step of Fig. 10) (curvature)
quantization           any     historian or instrument resolution (Loop 4, Section 3)
                               (one step per quantised signal)
external_disturbance   pv      an oscillation entering the loop that the valve did not
                               cause (frequency, amplitudes, phases)
time_varying_stiction  mv      S and J changing during the record: a step, a ramp or
                               a drift (end values and instants)
=====================  ======  =====================================================

Every fitter takes per-sample weights (0 or 1) so the same code fits on a training
part of the record and is validated on the held-back part (:mod:`stictiondiag.gap`).
"""

from __future__ import annotations

from collections.abc import Callable

from stictiondiag.core.errors import DataError
from stictiondiag.gap.effects import (
    actuator_lag,
    asymmetry,
    external_disturbance,
    miscalibration,
    quantization,
    time_varying_stiction,
    valve_characteristic,
)
from stictiondiag.gap.effects.base import Effect, EffectFit
from stictiondiag.gap.effects.kernels import valve_replay

#: The declared effects, in the order they are reported.
REGISTRY: dict[str, Effect] = {
    m.EFFECT.name: m.EFFECT
    for m in (
        actuator_lag,
        miscalibration,
        asymmetry,
        valve_characteristic,
        quantization,
        external_disturbance,
        time_varying_stiction,
    )
}

#: Effect names in the order they are reported; ``none`` is the base two-parameter model.
EFFECTS: tuple[str, ...] = ("none", *REGISTRY)

#: The catalogue: effect name -> fitter ``f(context, weights, base, init=None)``
#: returning an :class:`EffectFit` (None when the effect does not apply, e.g. no
#: signal is quantised).  ``init`` is the fit on the whole record, to start from.
EFFECT_MODELS: dict[str, Callable[..., EffectFit | None]] = {
    name: e.fit for name, e in REGISTRY.items()
}

#: Effects that act on the valve and need a recorded mv to be assessed.
VALVE_SIDE_EFFECTS: frozenset[str] = frozenset(e.name for e in REGISTRY.values() if e.valve_side)


def assessable_effects(
    has_mv: bool, effects: tuple[str, ...] | None = None
) -> tuple[list[str], list[str]]:
    """Effects that can and cannot be assessed with or without a recorded mv.

    Without mv the valve-side effects (lag, miscalibration, asymmetry, time-varying
    S and J) are confounded with the process dynamics and gain in pv; the
    process-side ones remain.  With ``effects`` given, only those of them are
    assessed.

    Raises
    ------
    DataError
        ``effects`` names an effect the catalogue does not have.
    """
    names = [e for e in EFFECTS if e != "none"]
    if has_mv:
        assessable, not_assessed = names, []
    else:
        assessable = [e for e in names if e not in VALVE_SIDE_EFFECTS]
        not_assessed = [e for e in names if e in VALVE_SIDE_EFFECTS]
    if effects is not None:
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            raise DataError(f"unknown effect(s) {', '.join(unknown)}: use {', '.join(EFFECTS[1:])}")
        assessable = [e for e in assessable if e in effects]
    return assessable, not_assessed


__all__ = [
    "EFFECTS",
    "EFFECT_MODELS",
    "REGISTRY",
    "VALVE_SIDE_EFFECTS",
    "Effect",
    "EffectFit",
    "assessable_effects",
    "valve_replay",
]
