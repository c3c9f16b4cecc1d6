"""Classic data-driven stiction tests, each faithful to its paper and checked against it.

One module per published test; each returns a frozen result with a verdict
(``"stiction"``, ``"no_stiction"``, ``"inconclusive"``, or ``"not_applicable"`` where
the paper says the test does not apply) and the paper's own statistic:

===================  ==========================================================
module               test
===================  ==========================================================
``bicoherence``      Choudhury, Shah & Thornhill (2004): NGI/NLI, then the pv-op
                     ellipse (``ellipse``) with the apparent stiction of
                     Choudhury et al. (2006)
``he``               He, Wang, Pottmann & Qin (2007): triangle versus sine fit,
                     on op (self-regulating) or pv (integrating)
``horch``            Horch (1999) op-pv cross-correlation; Horch (2000)
                     second-derivative test for integrating loops
``kano``             Kano et al. (2004): stick sections of mv (pv as mv proxy
                     for flow loops only)
``rossi_scali``      Rossi & Scali (2005): relay-response versus sine fit on pv
===================  ==========================================================

:func:`run_classic` runs them all on one loop; :func:`classic_features` runs them and
returns stable, named numbers for a calibrated combination (:func:`features_of` does
the same from results already computed).

Features (:data:`FEATURE_NAMES`; NaN when the test could not run or does not apply)
-----------------------------------------------------------------------------------
``choudhury_ngi``
    Non-Gaussianity index of the control error [-]; > 0.001: non-Gaussian.
``choudhury_nli``
    Nonlinearity index [-]; > 0.01 (with NGI > 0.001): nonlinear.
``choudhury_tnli``
    Total nonlinearity index, sum of significant squared bicoherence [-].
``choudhury_bic_threshold``
    Critical squared bicoherence of the record [-] (large: short record, weak test).
``ellipse_axis_ratio``
    Minor/major axis of the band-pass filtered pv-op ellipse [-] (0 a line, 1 a
    circle); computed whenever an oscillation was found, not only for nonlinear loops.
``ellipse_apparent_stiction``
    Width of that ellipse along op [% of op span] (Choudhury et al. 2006).
``he_si``
    He et al.'s stiction index MSE_sin / (MSE_sin + MSE_tri) [-]; >= 0.6 stiction.
``horch_phase_index``
    Horch's CCF phase index delta_phi / pi [-], 0 even (no stiction) to 1 odd
    (stiction); NaN for integrating loops, where the CCF rule misfires.
``horch_d2_kurtosis``
    Kurtosis of the filtered second derivative of pv [-] (integrating loops only;
    > 3.5 spike train: stiction, < 2.5 sinusoid).
``kano_rho``
    Share of the record in which the valve position (or a flow pv) is stuck while op
    moves [-]; NaN when no position signal applies.
``rossi_scali_delta_e``
    Rossi & Scali's (E_sin - E_relay) / (E_sin + E_relay) [-]; >= 0.4 stiction.
``<test>_call``
    The test's verdict as a number: +1 stiction, 0 inconclusive, -1 no stiction, NaN
    not applicable or not run; for ``choudhury``, ``he``, ``horch``, ``kano``,
    ``rossi_scali``.
``oscillation_period_s``, ``oscillation_regularity``
    Period [s] and Thornhill regularity [-] of the oscillation the shape tests used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.checks import check_dt
from stictiondiag.core.errors import DataError
from stictiondiag.signals.oscillation import Oscillation, detect_oscillation
from stictiondiag.stiction.classic._common import VERDICT_CODE, nan_if_none, signal
from stictiondiag.stiction.classic.bicoherence import (
    BicoherenceResult,
    ChoudhuryResult,
    bicoherence_indices,
    choudhury_hos,
)
from stictiondiag.stiction.classic.ellipse import EllipseResult, pv_op_ellipse
from stictiondiag.stiction.classic.he import HeResult, he_curve_fit
from stictiondiag.stiction.classic.horch import HorchResult, horch_cross_correlation
from stictiondiag.stiction.classic.kano import KanoResult, kano_stick_sections
from stictiondiag.stiction.classic.rossi_scali import RossiScaliResult, rossi_scali_relay

#: Names of :func:`classic_features`, in order (stable: a model is trained on them).
FEATURE_NAMES = (
    "choudhury_ngi",
    "choudhury_nli",
    "choudhury_tnli",
    "choudhury_bic_threshold",
    "choudhury_call",
    "ellipse_axis_ratio",
    "ellipse_apparent_stiction",
    "he_si",
    "he_call",
    "horch_phase_index",
    "horch_d2_kurtosis",
    "horch_call",
    "kano_rho",
    "kano_call",
    "rossi_scali_delta_e",
    "rossi_scali_call",
    "oscillation_period_s",
    "oscillation_regularity",
)

#: Names of the tests in :class:`ClassicResults`.
TESTS = ("choudhury", "he", "horch", "kano", "rossi_scali")


@dataclass(frozen=True)
class ClassicResults:
    """All classic tests on one loop (:func:`run_classic`).

    Attributes
    ----------
    loop_type : str or None
        Loop type given by the caller.
    integrating : bool
        The process was treated as integrating.
    oscillation : Oscillation
        Oscillation of pv (op when pv has none) used by the shape tests.
    choudhury, he, horch, kano, rossi_scali : result or None
        Each test's frozen result; None when it could not run (see ``errors``).
    ellipse : EllipseResult or None
        The pv-op ellipse, whenever an oscillation was found.
    errors : tuple of (str, str)
        (test, one-line reason) for every test that could not run.
    """

    loop_type: str | None
    integrating: bool
    oscillation: Oscillation
    choudhury: ChoudhuryResult | None
    he: HeResult | None
    horch: HorchResult | None
    kano: KanoResult | None
    rossi_scali: RossiScaliResult | None
    ellipse: EllipseResult | None
    errors: tuple[tuple[str, str], ...]

    def verdicts(self) -> dict[str, str]:
        """Test name -> verdict (``"error"`` for a test that could not run)."""
        return {t: getattr(self, t).verdict if getattr(self, t) else "error" for t in TESTS}

    def to_dict(self) -> dict:
        """JSON-able dict of every result."""
        out: dict = {
            "loop_type": self.loop_type,
            "integrating": bool(self.integrating),
            "oscillation": self.oscillation.to_dict(),
        }
        for t in TESTS:
            r = getattr(self, t)
            out[t] = None if r is None else r.to_dict()
        out["ellipse"] = None if self.ellipse is None else self.ellipse.to_dict()
        out["errors"] = [list(e) for e in self.errors]
        return out


def _loop_oscillation(pv: np.ndarray, op: np.ndarray, dt: float) -> Oscillation:
    osc = detect_oscillation(pv, dt)
    if osc.present:
        return osc
    osc_op = detect_oscillation(op, dt)
    return osc_op if osc_op.present else osc


def run_classic(
    pv,
    op,
    sp=None,
    dt: float = 1.0,
    loop_type: str | None = None,
    *,
    integrating: bool | None = None,
    mv=None,
) -> ClassicResults:
    """Run every classic test on one loop.

    Parameters
    ----------
    pv : ndarray
        Process output [pv units].
    op : ndarray
        Controller output [% of span].
    sp : ndarray, optional
        Setpoint [pv units].
    dt : float
        Sample time [s].
    loop_type : str, optional
        ``"flow"``, ``"pressure"``, ``"level"``, ``"temperature"``, ``"composition"``
        or other; decides Kano's pv proxy and, unless ``integrating`` is given,
        whether the process integrates (``"level"``).
    integrating : bool, optional
        The process integrates (overrides the loop type).
    mv : ndarray, optional
        Measured valve position [% of span] (Kano's test).

    Returns
    -------
    ClassicResults
        A test that cannot run on these data (too short, no oscillation to fit)
        leaves its field None and a one-line reason in ``errors``; bad input (NaN,
        mismatched lengths, a bad dt) raises DataError or UsageError.
    """
    dt = check_dt(dt)
    pv = signal(pv, "pv")
    op = signal(op, "op")
    if pv.size != op.size:
        raise DataError(f"pv and op must have the same length, got {pv.size} and {op.size}")
    integ = (loop_type == "level") if integrating is None else bool(integrating)
    osc = _loop_oscillation(pv, op, dt)
    period = osc.period_s if osc.present else None
    errors: list[tuple[str, str]] = []

    def attempt(name, fn):
        try:
            return fn()
        except DataError as exc:
            errors.append((name, str(exc)))
            return None

    res = {
        "choudhury": attempt("choudhury", lambda: choudhury_hos(op, pv, sp, dt)),
        "horch": attempt(
            "horch", lambda: horch_cross_correlation(op, pv, dt, integrating=integ, period_s=period)
        ),
        "kano": attempt(
            "kano", lambda: kano_stick_sections(op, pv, dt, mv=mv, loop_type=loop_type)
        ),
    }
    if period is None:
        errors.extend((t, "no oscillation: the shape fit needs one") for t in ("he", "rossi_scali"))
        res["he"] = res["rossi_scali"] = None
        ellipse = None
    else:
        res["he"] = attempt(
            "he", lambda: he_curve_fit(op, pv, dt, integrating=integ, period_s=period)
        )
        res["rossi_scali"] = attempt("rossi_scali", lambda: rossi_scali_relay(pv, dt, period))
        ellipse = pv_op_ellipse(op, pv, dt, period)
    return ClassicResults(
        loop_type=loop_type,
        integrating=integ,
        oscillation=osc,
        ellipse=ellipse,
        errors=tuple(errors),
        **res,
    )


def _call(r) -> float:
    return math.nan if r is None else VERDICT_CODE.get(r.verdict, math.nan)


def classic_features(
    pv,
    op,
    sp=None,
    dt: float = 1.0,
    loop_type: str | None = None,
    *,
    integrating: bool | None = None,
    mv=None,
) -> dict[str, float]:
    """Run :func:`run_classic` and return :func:`features_of` its results.

    Parameters are those of :func:`run_classic`.
    """
    res = run_classic(pv, op, sp, dt, loop_type, integrating=integrating, mv=mv)
    return features_of(res)


def features_of(results: ClassicResults) -> dict[str, float]:
    """Stable, named numeric statistics of :func:`run_classic`'s results (module doc).

    Returns a dict with exactly :data:`FEATURE_NAMES` as keys, in that order; NaN where
    a test could not run or does not apply.
    """
    c, h, ho, k, rs, el = (
        results.choudhury,
        results.he,
        results.horch,
        results.kano,
        results.rossi_scali,
        results.ellipse,
    )
    bic = None if c is None else c.bicoherence
    osc = results.oscillation
    feats = {
        "choudhury_ngi": math.nan if bic is None else bic.ngi,
        "choudhury_nli": math.nan if bic is None else bic.nli,
        "choudhury_tnli": math.nan if bic is None else bic.tnli,
        "choudhury_bic_threshold": math.nan if bic is None else bic.threshold,
        "choudhury_call": _call(c),
        "ellipse_axis_ratio": math.nan if el is None else nan_if_none(el.axis_ratio),
        "ellipse_apparent_stiction": math.nan if el is None else nan_if_none(el.apparent_stiction),
        "he_si": math.nan if h is None else nan_if_none(h.stiction_index),
        "he_call": _call(h),
        "horch_phase_index": (
            math.nan if ho is None or ho.delta_phi is None else ho.delta_phi / math.pi
        ),
        "horch_d2_kurtosis": math.nan if ho is None else nan_if_none(ho.kurtosis),
        "horch_call": _call(ho),
        "kano_rho": math.nan if k is None else nan_if_none(k.rho),
        "kano_call": _call(k),
        "rossi_scali_delta_e": math.nan if rs is None else nan_if_none(rs.delta_e),
        "rossi_scali_call": _call(rs),
        "oscillation_period_s": nan_if_none(osc.period_s if osc.present else None),
        "oscillation_regularity": nan_if_none(osc.regularity),
    }
    return {name: float(feats[name]) for name in FEATURE_NAMES}


__all__ = [
    "FEATURE_NAMES",
    "TESTS",
    "BicoherenceResult",
    "ChoudhuryResult",
    "ClassicResults",
    "EllipseResult",
    "HeResult",
    "HorchResult",
    "KanoResult",
    "RossiScaliResult",
    "bicoherence_indices",
    "choudhury_hos",
    "classic_features",
    "features_of",
    "he_curve_fit",
    "horch_cross_correlation",
    "kano_stick_sections",
    "pv_op_ellipse",
    "rossi_scali_relay",
    "run_classic",
]
