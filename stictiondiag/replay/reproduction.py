"""Closed-loop reproduction as evidence of the cause of a cycle (Section 6, by simulation).

Section 6 of Choudhury, Thornhill & Shah (2005) predicts a sticky loop's limit cycle
from the loop and the valve; :mod:`stictiondiag.stiction.consistency` asks that by the
describing function.  This module asks it by simulation, with the replay of
:mod:`stictiondiag.replay.closed_loop`: replay the identified loop with the fitted S
and J, replay *the same identified loop* (the replay's controller and process) with a
linear valve (S = J = 0), and compare both with the recorded cycle of pv
(:func:`stictiondiag.replay.metrics.cycle_reproduction`).  If the fitted loop
reproduces the cycle and its linear twin settles, the valve makes the cycle; if the
linear twin cycles too, the loop as identified cycles without the valve's help; if
neither reproduces it, the cycle comes from outside the loop.

The replay is the **open-loop fit's** (``refit=False``): the closed-loop refit of
:mod:`stictiondiag.replay.refit` adjusts S, J and the process until the replay
reproduces the recorded cycle, whatever made it, so a refitted reproduction is not
evidence of the cause.  Measured on the cause family (``scripts/replay_cause_probe.py``,
``docs/calibration.md``, "Closed-loop reproduction"), the refitted variant separated
the valve's cycles from the others' less on the training seeds (area under the ROC
curve of ``replay_contrast`` 0.63 against 0.72).

The features (:data:`~stictiondiag.stiction.consistency.REPLAY_FEATURES`; without a
replay :data:`~stictiondiag.stiction.consistency.REPLAY_FILL`):

``replay_available``
    1 when the replay ran (a controller and a process could be identified).
``replay_reproduces``
    1 when the fitted loop's pv reproduces the recorded cycle over the samples the
    replay covers: period within 20 %, amplitude within 35 % (the criterion of
    ``docs/real_loops.md``).
``linear_cycles``
    1 when the linear twin's pv still cycles over the second half of the replayed
    samples (the start-up transient has had half the record to die out).
``replay_amplitude_ratio``, ``linear_amplitude_ratio``
    ``log(A_replay / A_data)`` of pv over the second half, ``A`` half the 5-95 %
    spread (:func:`~stictiondiag.replay.metrics.spread_amplitude`), clipped to
    ``+-log 10`` (``-log 10`` for a replay that is flat).
``replay_contrast``
    ``replay_amplitude_ratio - linear_amplitude_ratio``: how much larger the fitted
    valve's cycle is than that of the same loop with a linear valve.

A limit of the test, shown by ``tests/test_replay_cause_probe.py``: when an external
oscillation is the loop's only excitation, op answers pv through the controller, so
the process identified from op to pv is ``-1/C`` at the cycle's frequency and the
identified loop sits on its stability limit; its linear twin then cycles like a
tightly tuned loop.  From closed-loop data alone the replay cannot always tell an
external cycle from a tight loop.

Cost: two closed-loop simulations of the record (the replay without its refit and the
linear twin, which reuses the identified controller and process), O(n) each, and the
replay's identification and cycle measures, O(n log n) (autocorrelations by FFT).
Measured on the cause family's loops with a cycle (records of 600-5000 samples):
median 0.036 s of CPU per 1000 samples, 0.12 of the analysis steps 1-4.  Loops
without a cycle, or with a recorded valve position (no Hammerstein fit), skip it.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace as dc_replace

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.replay.closed_loop import replay
from stictiondiag.replay.metrics import cycle_reproduction, spread_amplitude
from stictiondiag.stiction.consistency import LOG_CAP, REPLAY_FILL

__all__ = ["reproduction_features", "reproduction_call"]

#: What a replay that cannot use the data raises: the replay's own errors, and a
#: singular or non-finite identification (seen on one simulated loop in several
#: hundred: ``numpy.linalg.LinAlgError`` from the process fit's normal equations).
#: Such a loop gets the "no replay" values, as one whose loop cannot be identified.
_NO_REPLAY = (StictionError, np.linalg.LinAlgError, ValueError, FloatingPointError)


def _log_ratio(a: float | None, b: float | None) -> float:
    """``log(a / b)`` clipped to ``+-LOG_CAP``; ``-LOG_CAP`` when ``a`` is 0 or missing."""
    if a is None or b is None or not b > 0 or not a > 0:
        return -LOG_CAP
    return float(min(max(math.log(a / b), -LOG_CAP), LOG_CAP))


def reproduction_features(
    tags, fit, *, known=None, refit: bool = False
) -> tuple[dict[str, float], dict[str, float]]:
    """The features of the module docstring for one loop with a cycle, and the CPU
    seconds of each replay (``replay_s``, ``linear_s``; for the cost figures).

    ``tags`` as analysed and ``fit`` its :class:`~stictiondiag.stiction.valvefit.StictionFit`
    (a Hammerstein fit; any other gets the fill values); ``known`` the loop-type
    step's fits (:class:`~stictiondiag.identification.looptype.StructureEvidence`),
    reused as the replay reuses them; ``refit`` True replays the refitted loop
    instead (the variant measured and not taken, module docstring).
    """
    cost = {"replay_s": 0.0, "linear_s": 0.0}
    if fit.method != "hammerstein":
        return dict(REPLAY_FILL), cost
    t0 = time.process_time()
    try:
        rep = replay(
            tags,
            fit,
            valve=fit.valve_family,
            integrating=tags.integrating,
            action=tags.action,
            known=known,
            refit=refit,
        )
    except _NO_REPLAY:
        cost["replay_s"] = time.process_time() - t0
        return dict(REPLAY_FILL), cost
    t1 = time.process_time()
    cost["replay_s"] = t1 - t0
    try:
        lin = replay(
            tags,
            dc_replace(fit, S=0.0, J=0.0),
            controller=rep.controller_fit,
            process=rep.process_fit,
            valve=fit.valve_family,
            refit=False,
        )
    except _NO_REPLAY:
        lin = None
    cost["linear_s"] = time.process_time() - t1
    dt = float(rep.dt)
    pv = rep.data.pv
    h = pv.size // 2
    a_data = spread_amplitude(pv[h:])
    out = dict(REPLAY_FILL)
    out["replay_available"] = 1.0
    out["replay_reproduces"] = float(cycle_reproduction(pv, rep.pv, dt).reproduced)
    out["replay_amplitude_ratio"] = _log_ratio(spread_amplitude(rep.pv[h:]), a_data)
    if lin is not None and lin.pv.size == pv.size:
        twin = cycle_reproduction(pv[h:], lin.pv[h:], dt)
        out["linear_cycles"] = float(twin.period_replay_s is not None)
        out["linear_amplitude_ratio"] = _log_ratio(spread_amplitude(lin.pv[h:]), a_data)
    out["replay_contrast"] = out["replay_amplitude_ratio"] - out["linear_amplitude_ratio"]
    return out, cost


def reproduction_call(features: dict[str, float]) -> str:
    """The hypothesis's call from the features: ``tuning`` when the linear twin cycles,
    ``valve`` when the fitted loop reproduces the cycle, else ``external``."""
    if features["linear_cycles"] > 0.5:
        return "tuning"
    if features["replay_reproduces"] > 0.5:
        return "valve"
    return "external"
