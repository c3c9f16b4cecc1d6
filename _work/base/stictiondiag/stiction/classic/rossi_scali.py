"""Rossi & Scali (2005): the relay-fit shape test.

Rossi, M. & Scali, C. (2005), "A comparison of techniques for automatic detection of
stiction: simulation and application to industrial data", Journal of Process Control
15, 505-514; the same shape argument is Hägglund (2011), "A shape-analysis approach
for diagnosis of stiction in control valves", Control Engineering Practice 19,
782-789.

A sticky valve acts on the loop like a relay: it holds still, then jumps.  Between
jumps the valve position is constant, so the process output follows a *step
response*: in a first-order-like self-regulating process an exponential approach
``a + b exp(-t / tau)``, in an integrating process a ramp.  A linear oscillation makes
pv sinusoidal.  Each monotone stretch of pv (from one extremum to the next, where the
valve jumps) is fitted by least squares with the relay response (offset, amplitude
and time constant free; a ramp is its limit for large ``tau``) and with a half
cosine (offset and amplitude free); with the pooled mean squared errors

    Delta_E = (E_sin - E_relay) / (E_sin + E_relay)                     [-]

``Delta_E >= 0.4`` points to stiction, ``Delta_E <= -0.4`` to a linear oscillation,
between is undecided.

What was verified and what was not
----------------------------------
* Verified (``tests/test_classic_shape.py``): an exact first-order relay
  response gives Delta_E near 1 and a sine near -1; on the paper loops of Choudhury
  et al. (2005) a stiction limit cycle gives Delta_E >= 0.4 in the self-regulating
  and in the integrating loop, a sinusoidal load Delta_E <= -0.4.
* Not verified (the paper was not available here): Rossi & Scali fit their three
  models (sine, triangle, relay response) on half periods of the oscillation and
  keep the better of the two stiction shapes; here the fit is on the stretches
  between extrema (where a relay switches), and the triangle is the large-tau limit
  of the relay response.  The +/-0.4 band is this implementation's reading of their
  decision rule.
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
    extrema_segments,
    lowpass,
    signal,
)

#: Delta_E at or above which pv looks like a relay response: stiction.
RS_STICTION_MIN = 0.4
#: Delta_E at or below which pv looks sinusoidal: no stiction.
RS_NO_STICTION_MAX = -0.4
#: Fewest monotone stretches for a verdict.
RS_MIN_STRETCHES = 4
#: Time constants tried for the relay response [fractions of the stretch length].
RS_TAU_GRID = np.geomspace(0.02, 5.0, 40)
#: Low-pass cut-off in multiples of the oscillation frequency (as He et al.).
RS_FILTER_HARMONICS = 10.0
#: Longest stretch fitted at full resolution [samples].
RS_MAX_SAMPLES = 200


@dataclass(frozen=True)
class RossiScaliResult:
    """Result of :func:`rossi_scali_relay`.

    Attributes
    ----------
    verdict : {"stiction", "no_stiction", "inconclusive"}
    delta_e : float or None
        Rossi & Scali's index [-], -1 (sine) to 1 (relay response).
    mse_sin, mse_relay : float or None
        Pooled mean squared errors of the fits [pv units squared].
    n_stretches : int
        Monotone stretches of pv fitted.
    reasons : tuple of str
    """

    verdict: VerdictLabel
    delta_e: float | None
    mse_sin: float | None
    mse_relay: float | None
    n_stretches: int
    reasons: tuple[str, ...]

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "verdict": self.verdict,
            "delta_e": plain_float(self.delta_e),
            "mse_sin": plain_float(self.mse_sin),
            "mse_relay": plain_float(self.mse_relay),
            "n_stretches": int(self.n_stretches),
            "reasons": list(self.reasons),
        }


def _sse_on(y: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """Residual sums of squares of y on [1, basis_j], for every row basis_j."""
    m = y.size
    yc = y - y.mean()
    bc = bases - bases.mean(axis=1, keepdims=True)
    den = np.einsum("ij,ij->i", bc, bc)
    num = bc @ yc
    fit = np.where(den > 0, num**2 / np.where(den > 0, den, 1.0), 0.0)
    return np.maximum(float(yc @ yc) - fit, 0.0) / m


def _fit_stretch(y: np.ndarray) -> tuple[float, float]:
    if y.size > RS_MAX_SAMPLES:
        y = y[np.linspace(0, y.size - 1, RS_MAX_SAMPLES).round().astype(int)]
    s = np.linspace(0.0, 1.0, y.size)
    e_sin = float(_sse_on(y, np.cos(math.pi * s)[None, :])[0])
    relay = np.exp(-s[None, :] / RS_TAU_GRID[:, None])
    ramp = s[None, :]
    e_relay = float(np.min(_sse_on(y, np.vstack([relay, ramp]))))
    return e_sin, e_relay


def rossi_scali_relay(pv, dt: float, period_s: float) -> RossiScaliResult:
    """Rossi & Scali (2005) relay-fit test on pv.

    Parameters
    ----------
    pv : ndarray
        Process output [pv units].
    dt : float
        Sample time [s].
    period_s : float
        Oscillation period [s] (sets the low-pass filter and the shortest stretch).

    Returns
    -------
    RossiScaliResult
    """
    dt = check_dt(dt)
    y = detrend_linear(signal(pv, "pv"))
    y = lowpass(y, dt, RS_FILTER_HARMONICS / period_s)
    stretches = extrema_segments(y, period_s / dt)
    if len(stretches) < RS_MIN_STRETCHES:
        return RossiScaliResult(
            "inconclusive", None, None, None, len(stretches),
            (f"{len(stretches)} monotone stretches of pv; the fit needs {RS_MIN_STRETCHES}",),
        )  # fmt: skip
    sse_sin = sse_relay = 0.0
    count = 0
    for a, b in stretches:
        e_sin, e_relay = _fit_stretch(y[a : b + 1])
        w = b + 1 - a
        sse_sin += e_sin * w
        sse_relay += e_relay * w
        count += w
    mse_sin, mse_relay = sse_sin / count, sse_relay / count
    total = mse_sin + mse_relay
    de = 0.0 if total <= 0 else (mse_sin - mse_relay) / total
    if de >= RS_STICTION_MIN:
        verdict: VerdictLabel = "stiction"
        why = f"pv follows relay responses (Delta_E {de:.2f} >= {RS_STICTION_MIN}): stiction"
    elif de <= RS_NO_STICTION_MAX:
        verdict = "no_stiction"
        why = f"pv is sinusoidal (Delta_E {de:.2f} <= {RS_NO_STICTION_MAX}): no stiction"
    else:
        verdict = "inconclusive"
        why = f"pv neither relay-like nor sinusoidal (Delta_E {de:.2f})"
    return RossiScaliResult(verdict, de, mse_sin, mse_relay, len(stretches), (why,))
