"""Kano, Maruta, Kugemoto & Shimizu (2004): stick sections of the valve position.

Kano, M., Maruta, H., Kugemoto, H. & Shimizu, K. (2004), "Practical model and
detection algorithm for valve stiction", IFAC DYCOPS 7, Boston, Section 4 (also
Chapter 10 of Jelali & Huang, eds., 2010, Detection and Diagnosis of Stiction in
Control Loops, Springer).

A sticky valve spends much of the time *stuck*: the valve position ``mv`` does not
move while the controller output ``op`` keeps moving.  Kano et al. find the sections
in which ``mv`` stays constant (within its noise) and ``op`` changes, and measure the
share of the record they cover,

    rho = (samples in stick sections) / (samples in the record)        [-].

The test needs ``mv``.  Without it, pv stands in for mv only where pv follows the
valve nearly statically: flow loops (a flow is the valve's output, through fast
dynamics).  For every other loop type the test does not apply
(``verdict="not_applicable"``), since the process dynamics move pv while the valve is
stuck.

What was verified and what was not
----------------------------------
* Verified by simulation (``tests/test_classic_shape.py``): the data-driven valve of
  Choudhury et al. (2005) in its limit cycle sticks for most of each cycle (rho well
  above the threshold), a linear valve in a loop with a load gives rho near 0.
* Not verified (the paper was not available here): Kano et al.'s exact definition of
  "constant" (here ``|d mv| <= 3 sqrt(2) sigma``, sigma the white-noise level of mv
  from its second differences, at least :data:`KANO_MIN_SECTION` samples, with op
  moving by more than its own noise band over the section), and the threshold on rho:
  :data:`KANO_RHO_STICTION` is this implementation's reading of the method (a valve
  stuck for at least a quarter of the time), with :data:`KANO_RHO_NO_STICTION` below
  which the valve is called free; the band between is left undecided.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.checks import check_dt
from stictiondiag.core.robust import robust_std
from stictiondiag.core.serialize import plain_float
from stictiondiag.stiction.classic._common import (
    VerdictLabel,
    same_length,
    signal,
)

#: rho at or above which the valve sticks [-].
KANO_RHO_STICTION = 0.25
#: rho at or below which the valve moves freely [-].
KANO_RHO_NO_STICTION = 0.10
#: Shortest stick section [samples].
KANO_MIN_SECTION = 3
#: Width of the "no movement" band, in white-noise standard deviations of a
#: difference of two samples.
KANO_NOISE_BANDS = 3.0
#: Loop types for which pv may stand in for mv.
KANO_PROXY_LOOP_TYPES = ("flow",)


@dataclass(frozen=True)
class KanoResult:
    """Result of :func:`kano_stick_sections`.

    Attributes
    ----------
    verdict : {"stiction", "no_stiction", "inconclusive", "not_applicable"}
    signal : {"mv", "pv", "none"}
        The valve-position signal used (pv as a proxy for flow loops).
    rho : float or None
        Share of the record in stick sections [-].
    n_sections : int
        Number of stick sections.
    mv_band : float or None
        Largest sample-to-sample change still counted as "not moving"
        [units of the position signal].
    reasons : tuple of str
    """

    verdict: VerdictLabel
    signal: str
    rho: float | None
    n_sections: int
    mv_band: float | None
    reasons: tuple[str, ...]

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "verdict": self.verdict,
            "signal": self.signal,
            "rho": plain_float(self.rho),
            "n_sections": int(self.n_sections),
            "mv_band": plain_float(self.mv_band),
            "reasons": list(self.reasons),
        }


def _noise_band(x: np.ndarray) -> float:
    """KANO_NOISE_BANDS white-noise std of a first difference of x (from 2nd diffs)."""
    sigma = robust_std(np.diff(x, 2)) / math.sqrt(6.0)
    return KANO_NOISE_BANDS * math.sqrt(2.0) * sigma


def stick_sections(mv: np.ndarray, op: np.ndarray) -> tuple[list[tuple[int, int]], float]:
    """Stick sections ``[a, b)`` of ``mv`` in which ``op`` moves, and the mv band used.

    A section is a maximal run of samples whose changes ``|mv[k] - mv[k-1]|`` stay
    within the noise band, at least :data:`KANO_MIN_SECTION` samples long, over
    which op's range exceeds op's own noise band.
    """
    band = _noise_band(mv)
    band_op = _noise_band(op)
    still = np.abs(np.diff(mv)) <= band
    # runs of True in `still`: change k is between samples k and k + 1
    padded = np.concatenate([[False], still, [False]])
    starts = np.flatnonzero(padded[1:] & ~padded[:-1])
    ends = np.flatnonzero(~padded[1:] & padded[:-1])
    out = []
    for s, e in zip(starts, ends, strict=True):
        a, b = int(s), int(e) + 1  # samples s .. e
        if b - a >= KANO_MIN_SECTION and np.ptp(op[a:b]) > band_op:
            out.append((a, b))
    return out, band


def kano_stick_sections(
    op,
    pv,
    dt: float,
    *,
    mv=None,
    loop_type: str | None = None,
) -> KanoResult:
    """Kano et al. (2004) stick-section test.

    Parameters
    ----------
    op : ndarray
        Controller output [% of span].
    pv : ndarray
        Process output [pv units]; the mv proxy for flow loops.
    dt : float
        Sample time [s] (checked only: the test counts samples).
    mv : ndarray, optional
        Measured valve position [% of span].
    loop_type : str, optional
        ``"flow"`` lets pv stand in for a missing mv.

    Returns
    -------
    KanoResult
    """
    check_dt(dt)
    op = signal(op, "op")
    if mv is not None:
        x = signal(mv, "mv")
        name = "mv"
    elif loop_type in KANO_PROXY_LOOP_TYPES:
        x = signal(pv, "pv")
        name = "pv"
    else:
        return KanoResult(
            "not_applicable", "none", None, 0, None,
            (f"no valve position, and pv of a {loop_type or 'unknown'} loop does not "
             f"follow the valve statically",),
        )  # fmt: skip
    same_length(("op", op), (name, x))
    sections, band = stick_sections(x, op)
    stuck = sum(b - a for a, b in sections)
    rho = stuck / x.size
    if rho >= KANO_RHO_STICTION:
        verdict: VerdictLabel = "stiction"
        why = f"{name} stuck while op moved for {100 * rho:.0f} % of the record: stiction"
    elif rho <= KANO_RHO_NO_STICTION:
        verdict = "no_stiction"
        why = f"{name} stuck while op moved for only {100 * rho:.0f} % of the record"
    else:
        verdict = "inconclusive"
        why = f"{name} stuck while op moved for {100 * rho:.0f} % of the record"
    return KanoResult(verdict, name, rho, len(sections), band, (why,))
