"""He, Wang, Pottmann & Qin (2007): the curve-fitting stiction test.

He, Q. P., Wang, J., Pottmann, M. & Qin, S. J. (2007), "A curve fitting method for
detecting valve stiction in oscillating control loops", Ind. Eng. Chem. Res. 46,
4549-4560.

The idea (their Section 3): the first integrating element after a sticky valve turns
the valve's stick-slip (a square-ish wave) into a *triangle*.  In a self-regulating
loop that element is the PI controller, so ``op`` is triangular; in an integrating
(level) loop it is the process, so ``pv`` is triangular.  A linear oscillation
(tuning, an external sinusoidal load) makes the same signal sinusoidal.  Each half
cycle of the chosen signal (between consecutive zero crossings) is fitted by least
squares with a half sine and with a triangle whose apex position is free; the
stiction index is

    SI = MSE_sin / (MSE_sin + MSE_tri)                                 [-]

``SI <= 0.4``: no stiction; ``SI >= 0.6``: stiction; between: undetermined (their
Section 4).

What was verified and what was not
----------------------------------
* Verified from the method as published (and re-derived): the signal choice by loop
  type, the index's definition and its limits (a pure triangle gives SI = 1, a pure
  sine SI = 0), the thresholds 0.4 and 0.6.  ``tests/test_classic_shape.py``
  reproduces the paper's synthetic argument (triangle -> SI near 1, sine -> SI near
  0) and its closed-loop claim on the paper loops of Choudhury et al. (2005): a
  stiction cycle gives a triangular op (self-regulating) / pv (integrating) with
  SI >= 0.6, a sinusoidal load gives SI <= 0.4.
* Not verified (the paper's text was not available here): He et al. fit a sinusoid
  with free frequency and phase and a triangle by a constrained optimisation per half
  period; here the half period is fixed by the zero crossings, the sine is the half
  sine over it (amplitude and offset free) and the triangle has a free apex (found
  exactly by a scan with cumulative sums), amplitude and offset free.  Both models
  thus have the offset and amplitude; the triangle has one more parameter (the apex).
  The per-half-cycle errors are pooled over the record (sum of squared errors / total
  samples), rather than averaged per half cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.checks import check_dt
from stictiondiag.core.filters import detrend_linear
from stictiondiag.core.serialize import plain_float
from stictiondiag.stiction.classic._common import (
    VerdictLabel,
    half_cycles,
    lowpass,
    signal,
)

#: SI at or below which the oscillation is sinusoidal: no stiction (He et al. 2007).
HE_NO_STICTION_MAX = 0.4
#: SI at or above which the oscillation is triangular: stiction (He et al. 2007).
HE_STICTION_MIN = 0.6
#: Fewest complete half cycles for a verdict.
HE_MIN_HALF_CYCLES = 4
#: Low-pass cut-off before the fit, in multiples of the oscillation frequency: ten
#: harmonics keep the corners of a triangle (its harmonics fall as 1/k^2) while
#: white measurement noise, which both fits see alike, is cut.
HE_FILTER_HARMONICS = 10.0
#: Longest half cycle fitted at full resolution [samples]; longer ones are
#: subsampled (the shapes are smooth at this resolution, and the fit stays O(n)).
HE_MAX_HALF_SAMPLES = 400


@dataclass(frozen=True)
class HeResult:
    """Result of :func:`he_curve_fit`.

    Attributes
    ----------
    verdict : {"stiction", "no_stiction", "inconclusive"}
    signal : {"op", "pv"}
        The signal fitted: op for self-regulating loops, pv for integrating ones.
    stiction_index : float or None
        He's SI [-], 0 (sine) to 1 (triangle); None when too few half cycles.
    mse_sin, mse_tri : float or None
        Pooled mean squared errors of the two fits [units of the signal squared].
    n_half_cycles : int
        Complete half cycles fitted.
    reasons : tuple of str
    """

    verdict: VerdictLabel
    signal: str
    stiction_index: float | None
    mse_sin: float | None
    mse_tri: float | None
    n_half_cycles: int
    reasons: tuple[str, ...]

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "verdict": self.verdict,
            "signal": self.signal,
            "stiction_index": plain_float(self.stiction_index),
            "mse_sin": plain_float(self.mse_sin),
            "mse_tri": plain_float(self.mse_tri),
            "n_half_cycles": int(self.n_half_cycles),
            "reasons": list(self.reasons),
        }


def _ls_sse(y: np.ndarray, basis: np.ndarray) -> float:
    """Residual sum of squares of y on [1, basis] (offset and amplitude)."""
    a = np.column_stack([np.ones_like(basis), basis])
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    r = y - a @ coef
    return float(r @ r)


def _triangle_sse(y: np.ndarray) -> float:
    """Least residual sum of squares of y on [1, triangle with apex c] over all c.

    For apex ``c`` (0 < c < m - 1) the basis is ``t / c`` up to the apex and
    ``(m - 1 - t) / (m - 1 - c)`` after it.  The normal equations need
    ``sum(phi)``, ``sum(phi^2)`` and ``sum(y phi)``, all from cumulative sums, so every
    apex is tried in O(m).
    """
    m = y.size
    t = np.arange(m, dtype=float)
    c = np.arange(1, m - 1, dtype=float)
    ci = c.astype(int)
    cs = lambda v: np.concatenate([[0.0], np.cumsum(v)])  # noqa: E731
    ct, ct2, cy, cty = cs(t), cs(t * t), cs(y), cs(t * y)
    e = m - 1.0
    # Rising part t <= c: phi = t / c;  falling part t > c: phi = (e - t) / (e - c).
    s1 = ct[ci + 1] / c + ((m - ci - 1) * e - (ct[m] - ct[ci + 1])) / (e - c)
    s2 = (
        ct2[ci + 1] / c**2
        + ((m - ci - 1) * e * e - 2 * e * (ct[m] - ct[ci + 1]) + (ct2[m] - ct2[ci + 1]))
        / (e - c) ** 2
    )
    sy = cty[ci + 1] / c + (e * (cy[m] - cy[ci + 1]) - (cty[m] - cty[ci + 1])) / (e - c)
    n, ysum, yy = float(m), float(cy[m]), float(y @ y)
    # Two-parameter least squares (offset b, amplitude a): SSE = yy - beta' G^-1 beta.
    det = n * s2 - s1 * s1
    ok = det > 1e-12 * n * s2
    a_amp = np.where(ok, (n * sy - s1 * ysum) / np.where(ok, det, 1.0), 0.0)
    b_off = np.where(ok, (ysum - a_amp * s1) / n, ysum / n)
    sse = yy - (b_off * ysum + a_amp * sy)
    return float(max(np.min(sse), 0.0)) if sse.size else math.inf


def _fit_half(y: np.ndarray) -> tuple[float, float]:
    if y.size > HE_MAX_HALF_SAMPLES:
        idx = np.linspace(0, y.size - 1, HE_MAX_HALF_SAMPLES).round().astype(int)
        y = y[idx]
    m = y.size
    s = np.sin(math.pi * (np.arange(m) + 0.5) / m)
    return _ls_sse(y, s) / m, _triangle_sse(y) / m


def he_curve_fit(
    op,
    pv,
    dt: float,
    *,
    integrating: bool = False,
    period_s: float | None = None,
) -> HeResult:
    """He et al. (2007) curve-fitting test: triangle versus sine on op or pv.

    Parameters
    ----------
    op : ndarray
        Controller output [% of span].
    pv : ndarray
        Process output [pv units].
    dt : float
        Sample time [s].
    integrating : bool
        Integrating (level) process: fit pv; otherwise fit op.
    period_s : float, optional
        Oscillation period [s]; when given, the signal is low-pass filtered at
        :data:`HE_FILTER_HARMONICS` times its frequency first.

    Returns
    -------
    HeResult
    """
    dt = check_dt(dt)
    name = "pv" if integrating else "op"
    x = signal(pv if integrating else op, name)
    y = detrend_linear(x)
    if period_s is not None and period_s > 0:
        y = lowpass(y, dt, HE_FILTER_HARMONICS / period_s)
    halves = half_cycles(y)
    if len(halves) < HE_MIN_HALF_CYCLES:
        return HeResult(
            "inconclusive", name, None, None, None, len(halves),
            (f"{len(halves)} complete half cycles of {name}; the fit needs "
             f"{HE_MIN_HALF_CYCLES}",),
        )  # fmt: skip
    sse_sin = sse_tri = 0.0
    count = 0
    for a, b in halves:
        e_sin, e_tri = _fit_half(y[a:b])
        w = b - a
        sse_sin += e_sin * w
        sse_tri += e_tri * w
        count += w
    mse_sin, mse_tri = sse_sin / count, sse_tri / count
    total = mse_sin + mse_tri
    si = 0.5 if total <= 0.0 else mse_sin / total
    if si >= HE_STICTION_MIN:
        verdict: VerdictLabel = "stiction"
        why = f"{name} is triangular (SI {si:.2f} >= {HE_STICTION_MIN}): stiction"
    elif si <= HE_NO_STICTION_MAX:
        verdict = "no_stiction"
        why = f"{name} is sinusoidal (SI {si:.2f} <= {HE_NO_STICTION_MAX}): no stiction"
    else:
        verdict = "inconclusive"
        why = f"{name} is neither triangular nor sinusoidal (SI {si:.2f})"
    return HeResult(verdict, name, si, mse_sin, mse_tri, len(halves), (why,))
