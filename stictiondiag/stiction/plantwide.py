"""Where a plant-wide oscillation comes from, and what that makes of each loop.

Every loop a sticky valve's cycle reaches oscillates at its period, and a per-loop
diagnosis sees a candidate in each (Thornhill & Horch 2007, Section 1).  Given the
groups of :func:`stictiondiag.signals.plantwide.plant_oscillations`, this module
ranks the members of each group as the source, by the field's root-cause
evidence, and gives every loop its role:

* **time order** (first key): the member whose cycle leads the others
  (:func:`~stictiondiag.signals.plantwide.cycle_lag`, relative to one reference
  member, then again relative to the earliest, so a chain longer than half a
  period is timed from its head);
* **P(valve)**, the probability of each loop's own verdict (that the valve causes
  its cycle, or P(stiction) where mv is recorded; second key, between members whose
  leads are within :data:`LEAD_MARGIN` samples of each other), when given;
* **nonlinearity** (third key): the harmonic content of the cycle
  (:func:`~stictiondiag.signals.plantwide.harmonic_ratio`), largest nearest the
  source where each process on the way is a low-pass filter (Thornhill & Horch
  2007, Section 4.2).

The order of the keys is measured, on the 20 simulated plants of
:mod:`stictiondiag.models.synthetic_plant` the method was developed on (seeds
0-19, 24 groups whose true source is a member; ``python
benchmarks/bench_plantwide_methods.py --probability``): each piece of evidence
alone puts the true source first in 23 groups (time order), 20 (P(stiction)) and
15 (harmonic content).  The harmonic content is weakest because the receiving
loop's own controller takes more out of the fundamental than of the harmonics
(its sensitivity rises with frequency), so a propagated loop's pv can be more
distorted than the source's.  The bicoherence NLI (Choudhury et al. 2004), counted
when significant, puts it first in 5 only: in records of a few thousand samples
most members show no significant bicoherence, so it is not used.

Roles (:data:`ROLES`): ``source_candidate`` (ranked first, or tied with the first
when the evidence does not single one out), ``propagated`` (in a group whose source
is another loop: its cause is "propagated: the cycle comes from <loop>" and not its
own stiction call), ``independent`` (in no group).  A loop that is a source
candidate in one group and propagated in another stays a source candidate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.serialize import plain_float
from stictiondiag.signals.plantwide import (
    OscillationGroup,
    PlantOscillations,
    cycle_lag,
    harmonic_ratio,
    plant_oscillations,
)

__all__ = [
    "ROLES",
    "GroupSources",
    "LoopRole",
    "PlantDiagnosis",
    "SourceEvidence",
    "diagnose_plant",
    "rank_sources",
]

#: Roles of a loop in a plant.
ROLES = ("source_candidate", "propagated", "independent")
#: Leads closer than this are a tie [samples]: a lag is the peak of a sampled
#: cross-correlation, known to a sample either way.
LEAD_MARGIN = 2


@dataclass(frozen=True)
class SourceEvidence:
    """One member's evidence of being its group's source.

    Attributes
    ----------
    loop : str
        The member.
    lead_s : float
        How far its cycle leads the group's earliest member's [s] (0 for the
        earliest, negative for the others).
    harmonic_ratio : float
        Harmonic over fundamental power of its cycle [-] (NaN when not measured).
    probability : float or None
        The probability its own verdict decided on [-] (P(the valve causes the
        cycle), or P(stiction) with mv), None when not given.
    share : float
        Its share of the group's power [-].
    """

    loop: str
    lead_s: float
    harmonic_ratio: float
    probability: float | None
    share: float

    def to_dict(self) -> dict:
        return {
            "loop": self.loop,
            "lead_s": float(self.lead_s),
            "harmonic_ratio": plain_float(self.harmonic_ratio),
            "probability": plain_float(self.probability),
            "share": float(self.share),
        }


@dataclass(frozen=True)
class GroupSources:
    """A group with its members ranked as the source.

    Attributes
    ----------
    group : OscillationGroup
        The group.
    ranking : tuple of SourceEvidence
        Members, most likely source first.
    candidates : tuple of str
        The source candidates: the first, and those tied with it.
    clear : bool
        One candidate only: the evidence singles out the source.
    note : str
        The ranking in words (why the first, or why no single one).
    """

    group: OscillationGroup
    ranking: tuple[SourceEvidence, ...]
    candidates: tuple[str, ...]
    clear: bool
    note: str

    def to_dict(self) -> dict:
        return {
            **self.group.to_dict(),
            "ranking": [e.to_dict() for e in self.ranking],
            "source_candidates": list(self.candidates),
            "source_clear": bool(self.clear),
            "note": self.note,
        }


@dataclass(frozen=True)
class LoopRole:
    """A loop's place in the plant's oscillations.

    Attributes
    ----------
    loop : str
    role : str
        One of :data:`ROLES`.
    groups : tuple of int
        Groups it belongs to.
    cause : str or None
        ``"propagated: the cycle comes from <loop>"`` for a propagated loop
        (``<loop> or <loop>`` when the source is not singled out), else None.
    source : str or None
        Its group's first-ranked source when propagated.
    """

    loop: str
    role: str
    groups: tuple[int, ...]
    cause: str | None
    source: str | None

    def to_dict(self) -> dict:
        return {
            "loop": self.loop,
            "role": self.role,
            "groups": list(self.groups),
            "cause": self.cause,
            "source": self.source,
        }


@dataclass(frozen=True)
class PlantDiagnosis:
    """Result of :func:`diagnose_plant`.

    Attributes
    ----------
    oscillations : PlantOscillations
        The groups found.
    groups : tuple of GroupSources
        Each group with its ranked source candidates.
    roles : dict
        Loop -> :class:`LoopRole`, for every loop analysed.
    """

    oscillations: PlantOscillations
    groups: tuple[GroupSources, ...]
    roles: dict

    def to_dict(self) -> dict:
        return {
            "method": self.oscillations.method,
            "dt_s": float(self.oscillations.dt),
            "n_samples": int(self.oscillations.n_samples),
            "groups": [g.to_dict() for g in self.groups],
            "loops": {k: r.to_dict() for k, r in self.roles.items()},
        }


def _finite(v, default: float) -> float:
    return float(v) if v is not None and math.isfinite(float(v)) else default


def rank_sources(
    group: OscillationGroup,
    signals: Mapping[str, np.ndarray],
    dt: float,
    probabilities: Mapping[str, float | None] | None = None,
) -> GroupSources:
    """Rank a group's members as its source (see the module docstring).

    Parameters
    ----------
    group : OscillationGroup
        From :func:`~stictiondiag.signals.plantwide.plant_oscillations`.
    signals : mapping of str to ndarray
        The signals the group was found in (pv), by loop, on one grid.
    dt : float
        Sample time [s].
    probabilities : mapping, optional
        The probability of each loop's own verdict [-] (P(valve) or, with mv,
        P(stiction); None where not known).

    Cost: two cross-correlations and one periodogram per member, O(members x n log n).
    """
    probabilities = probabilities or {}
    period = group.period_s
    first = group.members[0]
    lags = {m: cycle_lag(signals[m], signals[first], dt, period) for m in group.members}
    head = min(lags, key=lambda m: (lags[m], m))
    if head != first:
        lags = {m: cycle_lag(signals[m], signals[head], dt, period) for m in group.members}
    evidence = [
        SourceEvidence(
            loop=m,
            lead_s=0.0 - float(lags[m]),  # never -0.0
            harmonic_ratio=harmonic_ratio(signals[m], dt, period),
            probability=plain_float(probabilities.get(m)),
            share=float(s),
        )
        for m, s in zip(group.members, group.shares, strict=True)
    ]
    top_lead = max(e.lead_s for e in evidence)
    margin = LEAD_MARGIN * dt
    tied = [e for e in evidence if top_lead - e.lead_s < margin]
    rest = [e for e in evidence if top_lead - e.lead_s >= margin]

    def tie_key(e: SourceEvidence) -> tuple:
        return (-_finite(e.probability, -1.0), -_finite(e.harmonic_ratio, -1.0), e.loop)

    tied.sort(key=tie_key)
    rest.sort(key=lambda e: (-e.lead_s, *tie_key(e)))
    ranking = tuple(tied + rest)
    candidates = tuple(e.loop for e in tied)
    clear = len(candidates) == 1
    lead = ranking[0]
    if clear:
        runner = ranking[1] if len(ranking) > 1 else None
        gap = f", {lead.lead_s - runner.lead_s:.0f} s before {runner.loop}" if runner else ""
        note = f"{lead.loop}: its cycle leads every other member's{gap}"
    else:
        note = (
            f"no single source: the cycles of {', '.join(candidates)} arrive less than "
            f"{margin:.0f} s apart; ranked by P(stiction), then harmonic content"
        )
    return GroupSources(group, ranking, candidates, clear, note)


def _roles(loops: tuple[str, ...], groups: list[GroupSources]) -> dict:
    member_of: dict[str, list[GroupSources]] = {m: [] for m in loops}
    for g in groups:
        for m in g.group.members:
            member_of[m].append(g)
    roles = {}
    for loop in loops:
        mine = member_of[loop]
        numbers = tuple(g.group.group for g in mine)
        if not mine:
            roles[loop] = LoopRole(loop, "independent", (), None, None)
        elif any(loop in g.candidates for g in mine):
            roles[loop] = LoopRole(loop, "source_candidate", numbers, None, None)
        else:
            g = mine[0]
            names = " or ".join(g.candidates)
            roles[loop] = LoopRole(
                loop, "propagated", numbers, f"propagated: the cycle comes from {names}",
                g.ranking[0].loop,
            )  # fmt: skip
    return roles


def diagnose_plant(
    signals: Mapping[str, np.ndarray],
    dt: float,
    probabilities: Mapping[str, float | None] | None = None,
    *,
    method: str = "spectral",
) -> PlantDiagnosis:
    """Groups of loops sharing a cycle, their ranked sources, and every loop's role.

    Parameters
    ----------
    signals : mapping of str to ndarray
        Loop -> pv [pv units], all on one time grid (time-aligned), equally long.
    dt : float
        Sample time [s].
    probabilities : mapping, optional
        P(stiction) [-] of each loop's own analysis.
    method : {"spectral", "acf"}
        Grouping method of :func:`~stictiondiag.signals.plantwide.plant_oscillations`.

    Cost beyond the per-loop analyses: O(loops x n log n) for the spectra and
    O(members x n log n) per group for the ranking, linear in the group's size.
    """
    osc = plant_oscillations(signals, dt, method=method)
    ranked = [rank_sources(g, signals, osc.dt, probabilities) for g in osc.groups]
    return PlantDiagnosis(osc, tuple(ranked), _roles(osc.loops, ranked))
