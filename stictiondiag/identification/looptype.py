"""Is the process integrating? The data decide when neither the user nor the tags did.

An integrating process (a level, Choudhury, Thornhill & Shah 2005, Table 3) turns its
input into pv's *rate*: ``d(pv)/dt = K (mv - balance)``; a self-regulating one into
pv's *level*: ``tau d(pv)/dt + pv = K mv``.  Both structures are identified from the
valve position (mv when recorded, else op: the valve's input, which mv follows up to
the stiction band) to pv by :func:`stictiondiag.identification.process.identify_process`,
and the loop's PI controller from sp, pv and op by
:func:`stictiondiag.identification.controller.identify_controller`.

Only a cycling pv (or control error) is used: a loop at rest shows no structure.  Then three first
principles choose:

1. **The loop is a negative feedback loop.**  A loop that holds its set point has
   controller and process gains of one sign (``Kc K > 0``); a structure whose
   identified gain contradicts the identified controller is not the plant.  When
   only one structure is consistent, it is chosen.
2. **A lag slower than the record is an integrator.**  ``K/(tau s + 1)`` with
   ``tau`` beyond the record acts as ``(K/tau)/s`` over it (both fit alike): with mv
   recorded, the process is taken as integrating.  On a record of thousands of
   cycles the fit searches time constants up to 1600 periods of the cycle only
   (:func:`stictiondiag.identification.process.search_span`); a lag at the top of
   that range (within :data:`TOP_OF_RANGE`) counts as slower than the record.
3. **pv's rate follows mv, or pv's level does.**  With mv recorded, the structure
   that explains clearly more of pv (R^2 higher by :data:`R2_MARGIN`) is chosen.

Without mv, only the first principle is used: the valve's stick-slip lies between
op and pv, and the fits from op are not the process's (a sticky valve's square mv
turns op's ramps into steps, so a self-regulating loop's op -> pv fit can come out
as a lag far slower than the record: the paper's concentration loop, Table 3, does).

Otherwise the data cannot tell: the loop is taken as self-regulating, as before,
and a warning says so and how to set it.

Choice of the rule and of :data:`R2_MARGIN` on simulated loops only (PI loops of
:func:`stictiondiag.models.loops.simulate_loop` with the data-driven sticky valve,
FOPTD time constants 3-300 s and integrators, S 0-6 %, J 0-4 %, noise, some with a
slow random load), each record with and without mv: of 112 records the rule decided
17, all right, and left 95 undecided (most of them records in which pv does not
cycle: slow loops over 4000-5000 samples).  On the sample loops without their tag
names it decides every cycling loop right; without mv, ``level_undershoot`` stays
undecided.  The rule is conservative: an undecided loop keeps the default it had
before the data were asked.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

from stictiondiag.core.errors import StictionError
from stictiondiag.identification.controller import ControllerFit, identify_controller
from stictiondiag.identification.process import (
    FOPTD,
    identify_process,
    longest_time_constant,
)
from stictiondiag.identification.process_result import ProcessFit
from stictiondiag.io.tags import Tags
from stictiondiag.signals.oscillation import detect_oscillation

__all__ = [
    "R2_MARGIN",
    "StructureEvidence",
    "identify_structure",
    "infer_integrating",
    "settle_loop_type",
]

#: Least R^2 advantage [-] of one structure over the other for the data to decide
#: when both are consistent with negative feedback: one tenth of pv's variance,
#: well above the differences between the two fits of a process slow against the
#: record (below 0.01 in the simulations).
R2_MARGIN = 0.10


#: A fitted time constant within this fraction of the longest one searched counts as
#: at the top of the range [-] (the bounded search stops within 1e-4 of it in log tau).
TOP_OF_RANGE = 0.01


@dataclass(frozen=True)
class StructureEvidence:
    """What the data say of the process structure, and the fits that said it.

    Attributes
    ----------
    integrating : bool or None
        The process integrates (True), regulates itself (False), or the data cannot
        tell (None).
    why : str
        One-line reason.
    controller : ControllerFit or None
        The PI controller identified from sp, pv and op over the whole record; None
        when pv does not cycle or the controller could not be identified.
    processes : Mapping[bool, ProcessFit]
        The process fits from the valve position (mv, else op) to pv over the whole
        record, by structure (``True``: integrating), with the default drift
        high-pass; the structures that could be fitted.
    u_signal : str
        ``"mv"`` or ``"op"``: the input of the process fits.

    The closed-loop replay (:func:`stictiondiag.replay.replay`, ``known=``) reuses
    the controller, and with mv the process, when it identifies from the same
    samples with the same settings: the fits are passed on, not computed again.
    """

    integrating: bool | None
    why: str
    controller: ControllerFit | None = None
    processes: Mapping[bool, ProcessFit] = field(default_factory=lambda: MappingProxyType({}))
    u_signal: str = "op"


def pv_cycles(tags: Tags) -> bool:
    """Whether pv or the control error oscillates (a set-point step can hide the
    cycle from pv's autocorrelation, Thornhill et al. 2003): what
    :func:`identify_structure` asks first.  The chain has it from its oscillation step
    (:func:`stictiondiag.analysis.find_oscillations`)."""
    dt = float(tags.ts)
    error = tags.pv if tags.sp is None else tags.sp - tags.pv
    return detect_oscillation(tags.pv, dt).present or detect_oscillation(error, dt).present


def infer_integrating(tags: Tags) -> tuple[bool | None, str]:
    """Whether the data say the process integrates (None: they cannot tell), and why
    (:func:`identify_structure` without its fits)."""
    evidence = identify_structure(tags, cycling=pv_cycles(tags))
    return evidence.integrating, evidence.why


def identify_structure(tags: Tags, *, cycling: bool) -> StructureEvidence:
    """Whether the data say the process integrates, why, and the fits behind it.

    Parameters
    ----------
    tags : Tags
        The loop's signals (op, mv in % of span).
    cycling : bool
        Whether pv (or the control error) oscillates (:func:`pv_cycles`; the chain
        has it from its step 2, :func:`stictiondiag.analysis.find_oscillations`).

    Returns
    -------
    StructureEvidence
        The decision (None: the data cannot tell), a one-line reason, and the
        controller and process fits it rests on.
    """
    has_mv = tags.mv is not None
    u = tags.op if tags.mv is None else tags.mv
    what = "mv" if has_mv else "op"
    dt = float(tags.ts)
    if not cycling:
        return StructureEvidence(
            None,
            "pv does not cycle, so the response to the valve is not seen clearly",
            None,
            u_signal=what,
        )
    try:
        cf = identify_controller(tags.sp, tags.pv, tags.op, dt)
    except (StictionError, ValueError, FloatingPointError):
        return StructureEvidence(None, "the controller could not be identified", u_signal=what)
    kc = float(cf.controller.gain)
    processes: dict[bool, ProcessFit] = {}
    fits: dict[bool, tuple[bool, float]] = {}
    lag = math.nan  # time constant of the self-regulating fit [s]
    for integrating in (False, True):
        try:
            pf = identify_process(u, tags.pv, dt, integrating=integrating)
        except (StictionError, ValueError, FloatingPointError):
            continue
        processes[integrating] = pf
        r2 = float(pf.output_error.fit_r2)
        if math.isfinite(r2) and math.isfinite(kc):
            fits[integrating] = (kc * float(pf.process.gain) > 0.0, r2)
        if isinstance(pf.process, FOPTD):
            lag = float(pf.process.time_constant)
    decided, why = _decide(tags, fits, lag, what)
    return StructureEvidence(decided, why, cf, MappingProxyType(processes), what)


def _decide(
    tags: Tags, fits: dict[bool, tuple[bool, float]], lag: float, what: str
) -> tuple[bool | None, str]:
    """The three principles of the module docstring applied to the fits (sign
    consistency and R^2 by structure, the self-regulating fit's time constant)."""
    has_mv = tags.mv is not None
    dt = float(tags.ts)
    consistent = [k for k, (ok, _) in fits.items() if ok]
    r2s = ", ".join(
        f"{'integrating' if k else 'self-regulating'} R^2 {r2:.2f}" for k, (_, r2) in fits.items()
    )
    if len(consistent) == 1:
        other = "self-regulating" if consistent[0] else "integrating"
        return consistent[0], (
            f"only it closes a negative feedback loop with the identified controller "
            f"({other} gain has the wrong sign; {what} -> pv)"
        )
    if len(consistent) < 2:
        return None, "no structure closes a negative feedback loop with the identified controller"
    slow = tags.duration
    if has_mv and math.isfinite(lag):
        slow = min(slow, (1.0 - TOP_OF_RANGE) * longest_time_constant(tags.pv, dt))
    if has_mv and lag >= slow:
        beyond = (
            f"exceeds the record ({tags.duration:.3g} s)"
            if lag >= tags.duration
            else f"is at the top of the range searched ({slow:.3g} s, a record of thousands of cycles)"
        )
        return True, (
            f"the self-regulating fit's time constant ({lag:.3g} s) {beyond}: "
            f"over it the process is an integrator ({what} -> pv)"
        )
    gap = fits[True][1] - fits[False][1]
    if has_mv and abs(gap) >= R2_MARGIN:
        return gap > 0, f"it explains more of pv ({r2s}; {what} -> pv)"
    why = "both structures fit alike" if has_mv else "without mv the valve hides the process"
    return None, f"{why} ({r2s})"


def settle_loop_type(tags: Tags, evidence: StructureEvidence) -> Tags:
    """``tags`` with the process structure decided, when reading left it to the data.

    Only tags whose :attr:`~stictiondiag.io.tags.Tags.loop_type_source` is
    ``"pending"`` change: to ``"data"`` with the structure the data show (the loop
    type stays ``other``: the data tell integrating from self-regulating, not a
    level from a flow), or to ``"default"``
    (self-regulating) with a warning when they cannot tell.  A note gives the
    reason either way.  ``evidence``: :func:`identify_structure` of ``tags``.
    """
    if tags.loop_type_source != "pending":
        return tags
    integrating, why = evidence.integrating, evidence.why
    if integrating is None:
        note = (
            f"loop type not known (no ISA tag such as LIC101 names it and the data cannot "
            f"tell: {why}): taken as self-regulating; pass --loop-type (level integrates)"
        )
        return replace(
            tags, integrating=False, loop_type_source="default", warnings=(*tags.warnings, note)
        )
    structure = "integrating" if integrating else "self-regulating"
    note = f"process {structure} from the data: {why} (override: --loop-type)"
    return replace(
        tags,
        integrating=integrating,
        loop_type_source="data",
        warnings=(*tags.warnings, note),
    )
