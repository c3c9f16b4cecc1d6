"""The orchestrator: one loop's data in, the stiction diagnosis out.

The paper's procedure for plant data (Choudhury, Thornhill & Shah 2005) is one
chain, run by everything that needs it (``analyze``, ``gap``, ``validate``, the
training of P(stiction), the scripts):

1. the tags, in % of span for op and mv (Section 5.1), with the process structure
   settled when neither the user nor the tag named it
   (:func:`~stictiondiag.identification.looptype.identify_structure`); a record whose
   mode tag leaves automatic was cut on reading to its longest automatic stretch
   (:mod:`stictiondiag.io.mode`: in manual no controller closes the loop);
2. is there an oscillation at all (the limit cycles of Sections 4.2.2 and 5.3);
3. S and J of the data-driven model (Section 5.1): from the stick and slip segments
   of the mv-op plot when mv is recorded, otherwise by fitting the valve model and a
   linear process together to op and pv;
4. the verdict: is there a limit cycle, does the stiction model explain it better than
   a linear valve, and what causes it.  For a loop with a cycle and without mv, its
   evidence includes the closed-loop reproduction of Section 6
   (:mod:`stictiondiag.replay.reproduction`): the identified loop replayed with the
   fitted S and J (the open-loop fit, without the refit of step 5) and again with a
   linear valve, each compared with the recorded cycle.  So this step runs a replay
   of its own before step 5, whatever the configuration says of step 5 (a median
   0.12 of the CPU of steps 1-4 without it, on the cause family's loops with a
   cycle; loops without a cycle skip it);
5. the closed-loop replay of the fitted valve with the identified controller and
   process, compared with the data;
6. the sim-to-real gap: where the replay departs from the data and which unmodelled
   effect explains the departure.

Steps 1-3 are the chain's head, :func:`estimate_loop`, whose result
:class:`LoopEstimate` carries everything later steps need (the identified
structure included: the replay reuses its controller and process fits instead of
identifying them again).  The entry points, in the manner of pvlib's
``ModelChain.run_model_from_*``, share that head:

* :func:`analyze` (tags) and :func:`analyze_file` (a file): the whole chain;
* :func:`run_from_estimate`: steps 4-6 from a head already computed;
* :func:`diagnose_gap_tags` and :func:`diagnose_gap_file`: the head, then the gap
  diagnosis alone (``stiction gap``);
* :meth:`LoopEstimate.features`: the head's evidence as the probability model's
  features (its training, ``scripts/train_probability.py``);
* :attr:`LoopEstimate.reproduction`: the closed-loop reproduction that step 4 reads
  (computed once per estimate, on first use).

Every step is a pure function of its own module; this module only calls them in
order and gathers their results in :class:`~stictiondiag.result.Analysis`.
Nothing here starts a process or a thread: the parallelism of many loops is
``stiction scan``'s.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from functools import cached_property
from typing import Any, TypeVar

import numpy as np

from stictiondiag.core.errors import DataError, StictionError, require_bool
from stictiondiag.gap.diagnose import GapDiagnosis, diagnose_gap
from stictiondiag.identification.controller import loop_gain_sign
from stictiondiag.identification.looptype import (
    StructureEvidence,
    identify_structure,
    settle_loop_type,
)
from stictiondiag.io.tags import Tags, read_tags
from stictiondiag.replay import replay
from stictiondiag.replay.compensation import compensation_from_replay
from stictiondiag.replay.reproduction import reproduction_features
from stictiondiag.result import FIGURE_DPI, Analysis
from stictiondiag.signals.kpis import loop_kpis
from stictiondiag.signals.oscillation import (
    MIN_CYCLES,
    REGULARITY_THRESHOLD,
    Oscillation,
    acf_period_samples,
    detect_oscillation,
)
from stictiondiag.stiction.cause import Cycle, find_cycle, setpoint_share
from stictiondiag.stiction.fit_result import StictionFit
from stictiondiag.stiction.hammerstein import fit_hammerstein
from stictiondiag.stiction.segments import Segments, estimate_from_mv, segment_valve
from stictiondiag.stiction.verdict import stiction_verdict, verdict_features
from stictiondiag.stiction.verdict_result import Verdict, VerdictStatus

__all__ = [
    "FIGURE_DPI",
    "FLOW_LIKE",
    "Analysis",
    "AnalysisConfig",
    "LoopEstimate",
    "analyze",
    "analyze_file",
    "diagnose_gap_file",
    "diagnose_gap_tags",
    "estimate_loop",
    "run_from_estimate",
]

#: Loop types where pv is (nearly) proportional to the valve opening (Section 5.3.1:
#: "in liquid flow loops ... pv can be taken to be proportional to valve opening").
#: Without mv the fit records it and uses the self-regulating structure
#: (:mod:`stictiondiag.stiction.hammerstein`, "The linear part").
FLOW_LIKE = frozenset({"flow"})

_T = TypeVar("_T")


@dataclass(frozen=True)
class AnalysisConfig:
    """Options of :func:`analyze`.

    Attributes
    ----------
    gap : bool
        Run the sim-to-real gap diagnosis (the slowest step).
    replay : bool
        Run the closed-loop replay (needed by the gap diagnosis).
    compensation : bool
        Try the variable-integral compensation on the replayed loop (Section 6.4,
        :mod:`stictiondiag.replay.compensation`; needs the replay).
    """

    gap: bool = True
    replay: bool = True
    compensation: bool = True

    def __post_init__(self) -> None:
        # AnalysisConfig(gap="no") must not run the gap diagnosis: booleans only.
        for name in ("gap", "replay", "compensation"):
            flag = require_bool(f"AnalysisConfig.{name}", getattr(self, name))
            object.__setattr__(self, name, flag)


#: Fewest periods of a regular cycle a record must hold to be analysed at all [-].
#: Seen twice, a pattern repeats (and a sticky valve slips at least four times);
#: seen once it is an event.  Between this and
#: :data:`~stictiondiag.signals.oscillation.MIN_CYCLES` the analysis runs but cannot
#: conclude "no oscillation" (see :func:`check_record_length`).
MIN_ANALYSIS_CYCLES = 2.0


def check_record_length(tags: Tags, osc_pv: Oscillation, osc_op: Oscillation) -> str | None:
    """Check that the record holds enough periods of a regular cycle.

    Stiction shows as a sustained limit cycle (Sections 4.2.2 and 5.3), and the
    oscillation test needs :data:`~stictiondiag.signals.oscillation.MIN_CYCLES` periods.
    When pv or op has a regular autocorrelation (regularity above
    :data:`~stictiondiag.signals.oscillation.REGULARITY_THRESHOLD`) whose period
    (:func:`~stictiondiag.signals.oscillation.acf_period_samples` times the sample
    time) the record holds fewer than ``MIN_CYCLES`` times, "no oscillation" would only mean "not enough data":

    * fewer than :data:`MIN_ANALYSIS_CYCLES` periods: the analysis stops and says
      how long a record it needs;
    * from ``MIN_ANALYSIS_CYCLES`` to ``MIN_CYCLES`` periods: the analysis runs, the
      returned message goes into the warnings, and the verdict is told the record is
      short (:func:`~stictiondiag.stiction.valvefit.stiction_verdict`, ``short_record``): the
      valve model's own evidence can still show stiction, but the missing cycle is
      not taken as evidence against it.

    A slow irregular wander is not a cycle and passes. A recorded mv is exempt: its
    stick and slip phases show the stiction directly, cycle or not (Figs. 3 and 6).

    Returns
    -------
    str or None
        The short-record warning, or None when the record is long enough.

    Raises
    ------
    DataError
        The record holds fewer than ``MIN_ANALYSIS_CYCLES`` periods of a regular
        cycle.
    """
    if osc_pv.present or osc_op.present or tags.mv is not None:
        return None
    for role, osc in (("pv", osc_pv), ("op", osc_op)):
        if osc.regularity is None or not osc.regularity > REGULARITY_THRESHOLD:
            continue
        samples = acf_period_samples(getattr(tags, role))
        period = None if samples is None else samples * float(tags.ts)
        if not period or tags.duration >= MIN_CYCLES * period:
            continue
        need = math.ceil(MIN_CYCLES * period / float(tags.ts))
        held = (
            f"{tags.n} samples hold only {tags.duration / period:.1f} cycles of the "
            f"{period:.0f} s oscillation in {role}"
        )
        if tags.duration < MIN_ANALYSIS_CYCLES * period:
            raise DataError(
                f"record too short: {held}, and telling a limit cycle needs "
                f"{MIN_CYCLES:g}; export at least {need} samples ({MIN_CYCLES * period:.0f} s)"
            )
        return (
            f"short record: {held}, and confirming a limit cycle needs {MIN_CYCLES:g}; "
            "the verdict rests on the valve model alone and does not take the missing "
            f"cycle as evidence against stiction (export at least {need} samples)"
        )
    return None


@dataclass(frozen=True)
class LoopEstimate:
    """The head of the chain (steps 1-3): the loop as analysed and S and J.

    Attributes
    ----------
    tags : Tags
        The data as analysed (uniformly sampled, op and mv in % of span), with the
        process structure settled.
    structure : StructureEvidence or None
        The data's evidence on the process structure and the fits behind it, when
        the structure was left to the data; None when the user or the tag named it.
    oscillation : Oscillation
        Oscillation of pv, or of the control error when only it shows one (period
        [s], amplitude [pv units], regularity [-]).
    oscillation_op : Oscillation
        Oscillation of op (period [s], amplitude [% of span]).
    short_record : str or None
        The short-record warning of :func:`check_record_length`, None when the
        record is long enough.
    segments : Segments or None
        Stick and slip segments of the mv-op plot (mv recorded only).
    fit : StictionFit
        S and J [% of op span] with intervals and method.
    warnings : tuple of str
        The tags' warnings and those of steps 1-3, in the order they arose.
    """

    tags: Tags
    structure: StructureEvidence | None
    oscillation: Oscillation
    oscillation_op: Oscillation
    short_record: str | None
    segments: Segments | None
    fit: StictionFit
    warnings: tuple[str, ...] = ()

    @cached_property
    def cycle(self) -> Cycle:
        """Stage 1 of the verdict: the limit cycle to explain, if any
        (:func:`~stictiondiag.stiction.cause.find_cycle`)."""
        osc = self.oscillation if self.oscillation.present else self.oscillation_op
        tags = self.tags
        return find_cycle(
            self.oscillation,
            self.oscillation_op,
            short_record=bool(self.short_record),
            setpoint_share=setpoint_share(tags.sp, tags.pv, tags.ts, osc.period_s),
        )

    @cached_property
    def reproduction(self) -> dict[str, float] | None:
        """The closed-loop reproduction's features
        (:func:`~stictiondiag.replay.reproduction.reproduction_features`) when the
        loop has a cycle (stage 1, :func:`~stictiondiag.stiction.cause.find_cycle`)
        and a Hammerstein fit; None otherwise (the verdict then takes their "no
        replay" values).  Two O(n) closed-loop simulations; computed once."""
        if not self.cycle.present or self.fit.method != "hammerstein":
            return None
        return reproduction_features(self.tags, self.fit, known=self.structure)[0]

    def verdict(self, *, with_reproduction: bool = True) -> Verdict:
        """Step 4: the verdict on this estimate, with :attr:`reproduction` (or,
        ``with_reproduction=False``, its "no replay" values: what a measurement of
        the reproduction's own cost compares with)."""
        return stiction_verdict(
            self.fit,
            self.oscillation,
            cycle=self.cycle,
            oscillation_op=self.oscillation_op,
            has_mv=self.tags.mv is not None,
            short_record=bool(self.short_record),
            data=self.tags,
            reproduction=self.reproduction if with_reproduction else None,
        )

    def features(self) -> tuple[dict, tuple[float, float, tuple[float, float]], dict]:
        """The evidence the verdict decides on
        (:func:`~stictiondiag.stiction.verdict.verdict_features`): the probability
        model's features, the improvement's support and the classic tests' statistics.
        The same call the verdict makes, so a model trained on these features scores
        exactly what it was trained on."""
        return verdict_features(
            self.fit,
            self.oscillation,
            self.oscillation_op,
            short_record=bool(self.short_record),
            data=self.tags,
            cycle=self.cycle,
            reproduction=self.reproduction,
        )


def estimate_loop(tags: Tags) -> LoopEstimate:
    """Steps 1-3 of the chain: settle the loop type, find the oscillations (found
    first: the loop-type step reads them), check the record's length, and estimate
    S and J.

    Raises
    ------
    DataError
        The record holds fewer than two periods of a regular cycle
        (:func:`check_record_length`), or the estimator cannot use the data.
    """
    # 2. Is there an oscillation at all?  Found first: the loop-type step reads it.
    found: list[str] = []
    osc_pv, osc_op = find_oscillations(tags, found)
    # 1. The loop type, where neither the user nor the tag name gave it.
    structure = None
    if tags.loop_type_source == "pending":
        structure = identify_structure(tags, cycling=osc_pv.present)
        tags = settle_loop_type(tags, structure)  # the data decide the structure
    warnings = [*tags.warnings, *found]
    short = check_record_length(tags, osc_pv, osc_op)
    if short:
        warnings.append(short)

    # 3. S and J: from the valve's own signal when recorded, else the Hammerstein fit.
    # The stick and slip segments of the mv-op plot serve the gap diagnosis too.
    segments = None
    if tags.mv is not None:
        deadband = tags.archive_deadband.get("mv", 0.0)
        segments = segment_valve(tags.op, tags.mv, float(tags.ts), deadband)
    fit = estimate_stiction(tags, segments=segments)
    return LoopEstimate(tags, structure, osc_pv, osc_op, short, segments, fit, tuple(warnings))


def analyze(tags: Tags, *, config: AnalysisConfig | None = None) -> Analysis:
    """Diagnose stiction in one loop, in the paper's order (see the module docstring).

    Parameters
    ----------
    tags : Tags
        Loop data from :func:`stictiondiag.io.tags.read_tags` or ``Tags.from_arrays``
        (op and mv already in % of span: step 1).
    config : AnalysisConfig, optional
        Which optional steps to run.

    Returns
    -------
    Analysis

    Raises
    ------
    DataError
        The record holds fewer than two periods of a regular cycle
        (:func:`check_record_length`), or a step cannot use the data (its message
        says why).  The replay and the gap diagnosis do not raise: when they cannot
        use the data the reason goes into the warnings and their field is None.
    TypeError
        ``tags`` is not a :class:`Tags` (a DataFrame, a path, None) or ``config``
        not an :class:`AnalysisConfig`.
    """
    _check_arguments(tags, config)
    return run_from_estimate(estimate_loop(tags), config=config)


def _check_arguments(tags: object, config: object) -> None:
    """TypeErrors that say what :func:`analyze` takes and how to get it."""
    if not isinstance(tags, Tags):
        what = type(tags).__name__
        if what == "DataFrame":
            hint = "read it with stictiondiag.io.tags.read_frame(frame) first"
        elif isinstance(tags, str | os.PathLike):
            hint = "use analyze_file(path) for a file"
        else:
            hint = "get them from read_tags(path), read_frame(frame) or Tags.from_arrays(pv, op)"
        raise TypeError(f"analyze() takes the loop's Tags, not {what}: {hint}")
    if config is not None and not isinstance(config, AnalysisConfig):
        raise TypeError(
            f"config must be an AnalysisConfig (e.g. AnalysisConfig(gap=False)), "
            f"not {type(config).__name__}"
        )


def analyze_file(
    path: str | os.PathLike[str],
    *,
    config: AnalysisConfig | None = None,
    **read_options: Any,
) -> Analysis:
    """Read one loop's file with :func:`~stictiondiag.io.tags.read_tags` and
    :func:`analyze` it."""
    return analyze(read_tags(path, **read_options), config=config)


def run_from_estimate(est: LoopEstimate, *, config: AnalysisConfig | None = None) -> Analysis:
    """Steps 4-6 of the chain from its head: the verdict, the closed-loop replay
    (with the variable-integral compensation of Section 6.4) and the gap."""
    config = config or AnalysisConfig()
    tags, fit, segments = est.tags, est.fit, est.segments
    warnings = list(est.warnings)

    # 4. Verdict.
    verdict = est.verdict()

    # 5. Closed-loop replay; its own notes (a poor identification, a replay without
    # a cycle) say how far the reconstruction can be trusted.
    rep = None
    if config.replay:
        rep = _or_warn(
            "replay not possible",
            warnings,
            lambda: replay(
                tags,
                fit,
                valve=fit.valve_family,
                integrating=tags.integrating,
                action=tags.action,
                known=est.structure,
            ),
        )
        if rep is not None:
            warnings.extend(f"replay: {w}" for w in rep.warnings)

    # 5b. Variable-integral compensation of the replayed loop (Section 6.4).
    comp = None
    if config.compensation and rep is not None and verdict.status != VerdictStatus.NO_STICTION:
        replayed_loop = rep
        comp = _or_warn(
            "compensation not tried",
            warnings,
            lambda: compensation_from_replay(replayed_loop),
        )

    # 6. Sim-to-real gap (it needs the replay); when there is none, the reason why.
    gap, gap_skipped = None, None
    if not config.gap:
        gap_skipped = "not asked for"
    elif rep is None:
        made = "could not be made from these data" if config.replay else "was not asked for"
        gap_skipped = f"it needs the closed-loop replay, which {made}"
    else:
        try:
            gap = diagnose_gap(tags, fit, rep, segments=segments)
        except StictionError as exc:
            gap_skipped = str(exc)
            warnings.append(f"gap diagnosis not possible: {exc}")

    # 7. The loop's performance indicators; the Harris index takes the replay's
    # identified process dead time plus the controller's one-sample delay.
    osc = est.oscillation
    kpis = loop_kpis(
        tags.pv,
        tags.op,
        tags.sp,
        float(tags.ts),
        op_in_percent=getattr(tags, "op_scale", "percent") == "percent",
        service_factor_pct=tags.service_factor,
        dead_time_s=None
        if rep is None
        else (int(rep.process_fit.dead_time_samples) + 1) * float(tags.ts),
        oscillation_period_s=osc.period_s if osc.present else None,
        oscillation_amplitude=osc.amplitude if osc.present else None,
    )
    return Analysis(
        tags=tags,
        oscillation=est.oscillation,
        oscillation_op=est.oscillation_op,
        fit=fit,
        verdict=verdict,
        replay=rep,
        gap=gap,
        warnings=tuple(warnings),
        compensation=comp,
        analysed_at=datetime.now(UTC).isoformat(timespec="seconds"),
        kpis=kpis,
        gap_skipped=gap_skipped,
    )


def diagnose_gap_tags(tags: Tags) -> GapDiagnosis:
    """The chain's head, then the sim-to-real gap alone (``stiction gap``): S and J
    estimated as :func:`analyze` does, and the gap diagnosed without the
    closed-loop replay of step 5.

    Raises
    ------
    DataError
        As :func:`estimate_loop`.
    """
    est = estimate_loop(tags)
    return diagnose_gap(est.tags, est.fit, segments=est.segments)


def diagnose_gap_file(path: str | os.PathLike[str], **read_options: Any) -> GapDiagnosis:
    """Read a loop's file with :func:`~stictiondiag.io.tags.read_tags` and
    :func:`diagnose_gap_tags` it."""
    return diagnose_gap_tags(read_tags(path, **read_options))


def find_oscillations(tags: Tags, warnings: list[str]) -> tuple[Oscillation, Oscillation]:
    """Step 2: the oscillation of pv (or of the control error) and of op.

    A set-point change puts a step into pv that can hide the cycle from the
    autocorrelation; the control error ``sp - pv``, on which Thornhill et al. (2003)
    detect oscillations, has the cycle without the step.  When only the error shows
    it, its oscillation stands for pv's and a note goes into ``warnings``.
    """
    dt = float(tags.ts)
    osc_pv = detect_oscillation(tags.pv, dt)
    if not osc_pv.present and tags.sp is not None and float(np.ptp(tags.sp)) > 0:
        osc_error = detect_oscillation(tags.sp - tags.pv, dt)
        if osc_error.present:
            osc_pv = osc_error
            warnings.append(
                "the set point moves: the oscillation was found in the control error sp - pv"
            )
    return osc_pv, detect_oscillation(tags.op, dt)


def estimate_stiction(tags: Tags, segments: Segments | None = None) -> StictionFit:
    """Step 3: S and J [% of op span] of the data-driven model (Section 5.1).

    From the stick and slip segments of the mv-op plot when mv is recorded (Figs. 3
    and 6), otherwise from the valve model and a linear process fitted together to
    op and pv (Section 5.3.1), its process gain of the sign the identified
    controller needs (``StictionFit.gain_sign``, with the R^2 of the controller's
    law).  ``segments``: :func:`segment_valve` of op, mv and ts when the caller has
    it already.
    """
    if tags.mv is not None:
        return estimate_from_mv(
            tags.op, tags.mv, float(tags.ts), segments=segments, deadband=tags.archive_deadband
        )
    # The process gain takes the sign that closes a negative feedback loop with the
    # identified controller, when that sign is well determined (loop_gain_sign).
    sign, r2 = loop_gain_sign(tags.sp, tags.pv, tags.op, float(tags.ts))
    fit = fit_hammerstein(
        tags.op,
        tags.pv,
        float(tags.ts),
        integrating=bool(tags.integrating),
        flow_loop=tags.loop_type in FLOW_LIKE,
        gain_sign=sign,
    )
    if fit.gain_sign is None:
        return fit
    return replace(fit, gain_sign=replace(fit.gain_sign, controller_fit_r2=r2))


def _or_warn(what: str, warnings: list[str], step: Callable[[], _T]) -> _T | None:
    """``step()``, or None with ``"<what>: <reason>"`` among the warnings when the
    step cannot use the data (a :class:`StictionError`; other errors propagate)."""
    try:
        return step()
    except StictionError as exc:
        warnings.append(f"{what}: {exc}")
        return None
