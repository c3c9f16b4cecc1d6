"""The pv-op ellipse of Choudhury et al. (2004, 2006): apparent stiction.

Choudhury, M. A. A. S., Shah, S. L. & Thornhill, N. F. (2004), "Diagnosis of poor
control-loop performance using higher-order statistics", Automatica 40, 1719-1728,
Section 5; Choudhury, M. A. A. S., Shah, S. L., Thornhill, N. F. & Shook, D. S.
(2006), "Automatic detection and quantification of stiction in control valves",
Control Engineering Practice 14, 1395-1412, Section 4.

Once the bicoherence test has found a nonlinear loop, pv and op are band-pass
filtered around the oscillation frequency (the 2006 paper uses a frequency-domain
Wiener filter; here a zero-phase Butterworth band of :data:`ELLIPSE_BAND` times the
oscillation frequency) and an ellipse is fitted to the pv-op plot by direct least
squares.  An open ellipse means op and pv are a sizeable phase apart (a valve that
moves late); its width along op through the centre is the *apparent stiction*
[% of op], ``2 m n / sqrt(m^2 sin^2(a) + n^2 cos^2(a))`` with ``m``, ``n`` the
semi-axes and ``a`` the major axis' angle (Choudhury et al. 2006, Eq. 13).

What was verified and what was not
----------------------------------
* Verified: the chord formula (re-derived; ``tests/test_classic_horch_choudhury.py`` checks
  the fitted width against the closed form for two sinusoids, and against the
  apparent stiction of a simulated limit cycle).
* Not from the paper: the axis-ratio threshold :data:`ELLIPSE_MIN_AXIS_RATIO` that
  says "open ellipse" (the paper judges the plot by eye and by the fitted width).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.filters import detrend_linear
from stictiondiag.core.serialize import plain_float

# --------------------------------------------------------------------------------------
# pv-op ellipse (Choudhury et al. 2004, 2006)
# --------------------------------------------------------------------------------------

#: Minor-to-major axis ratio above which the filtered pv-op plot is an open ellipse.
#: Two unit-variance sinusoids with phase difference phi give the ratio
#: sqrt((1 - |cos phi|) / (1 + |cos phi|)); 0.2 means phi at least 22.6 degrees away
#: from in-phase or anti-phase.
ELLIPSE_MIN_AXIS_RATIO = 0.2
#: Band of the pv-op band-pass filter around the oscillation frequency [multiples of
#: the oscillation frequency] (the oscillation band Choudhury et al. 2006 keep).
ELLIPSE_BAND = (0.5, 2.0)


@dataclass(frozen=True)
class EllipseResult:
    """Result of :func:`pv_op_ellipse`.

    Attributes
    ----------
    fitted : bool
        An ellipse was fitted to the filtered pv-op plot.
    axis_ratio : float or None
        Minor over major axis in the plane of unit-variance filtered signals [-].
    elliptic : bool
        ``axis_ratio >= ELLIPSE_MIN_AXIS_RATIO``: an open ellipse.
    apparent_stiction : float or None
        Width of the ellipse along op through its centre [% of op span]
        (Choudhury et al. 2006's apparent stiction).
    """

    fitted: bool
    axis_ratio: float | None
    elliptic: bool
    apparent_stiction: float | None

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "fitted": bool(self.fitted),
            "axis_ratio": plain_float(self.axis_ratio),
            "elliptic": bool(self.elliptic),
            "apparent_stiction": plain_float(self.apparent_stiction),
        }


def fit_ellipse(x: np.ndarray, y: np.ndarray) -> np.ndarray | None:
    """Direct least-squares ellipse fit (Fitzgibbon, Pilu & Fisher 1999).

    Numerically stable form of Halir & Flusser (1998).  Returns the conic
    coefficients ``(a, b, c, d, e, f)`` of ``a x^2 + b x y + c y^2 + d x + e y + f = 0``
    (an ellipse: ``4 a c - b^2 > 0``), or None when no ellipse fits.
    """
    d1 = np.column_stack([x * x, x * y, y * y])
    d2 = np.column_stack([x, y, np.ones_like(x)])
    s1 = d1.T @ d1
    s2 = d1.T @ d2
    s3 = d2.T @ d2
    try:
        t = -np.linalg.solve(s3, s2.T)
    except np.linalg.LinAlgError:
        return None
    m = s1 + s2 @ t
    # Premultiply by the inverse of the constraint matrix [[0,0,2],[0,-1,0],[2,0,0]].
    m = np.array([m[2] / 2.0, -m[1], m[0] / 2.0])
    try:
        _, vecs = np.linalg.eig(m)
    except np.linalg.LinAlgError:
        return None
    vecs = np.real(vecs)
    cond = 4.0 * vecs[0] * vecs[2] - vecs[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        return None
    a1 = vecs[:, ok[0]]
    return np.concatenate([a1, t @ a1])


def _ellipse_geometry(coef: np.ndarray) -> tuple[float, float] | None:
    """(minor/major axis ratio, half chord along x through the centre) of a conic."""
    a, b, c, d, e, f = coef
    q = np.array([[a, b / 2.0], [b / 2.0, c]])
    try:
        centre = np.linalg.solve(2.0 * q, -np.array([d, e]))
    except np.linalg.LinAlgError:
        return None
    f0 = float(centre @ q @ centre + d * centre[0] + e * centre[1] + f)
    if f0 == 0.0:
        return None
    m = q / -f0
    lam = np.linalg.eigvalsh(m)
    if lam[0] <= 0:
        return None
    ratio = math.sqrt(lam[0] / lam[1])
    half_chord_x = 1.0 / math.sqrt(m[0, 0])
    return ratio, half_chord_x


def pv_op_ellipse(op: np.ndarray, pv: np.ndarray, dt: float, period_s: float) -> EllipseResult:
    """Ellipse fitted to the band-pass filtered pv-op plot (Choudhury et al. 2004, 2006).

    Both signals are detrended and band-pass filtered (zero-phase Butterworth, order
    2) over :data:`ELLIPSE_BAND` times the oscillation frequency, scaled to unit
    variance, and an ellipse is fitted by direct least squares.

    Returns
    -------
    EllipseResult
    """
    nyquist = 0.5 / dt
    f0 = 1.0 / period_s
    lo = ELLIPSE_BAND[0] * f0 / nyquist
    hi = ELLIPSE_BAND[1] * f0 / nyquist
    out = EllipseResult(fitted=False, axis_ratio=None, elliptic=False, apparent_stiction=None)
    if not 0.0 < lo < hi < 1.0:
        return out
    from scipy import signal as sps  # imported here: scipy.signal is slow to import

    b, a = sps.butter(2, [lo, hi], btype="band")
    padlen = min(3 * max(len(a), len(b)), op.size - 1)
    opf = sps.filtfilt(b, a, detrend_linear(op), padlen=padlen)
    pvf = sps.filtfilt(b, a, detrend_linear(pv), padlen=padlen)
    s_op, s_pv = float(opf.std()), float(pvf.std())
    if s_op <= 0 or s_pv <= 0:
        return out
    coef = fit_ellipse(opf / s_op, pvf / s_pv)
    geom = None if coef is None else _ellipse_geometry(coef)
    if geom is None:
        return out
    ratio, half_chord = geom
    return EllipseResult(
        fitted=True,
        axis_ratio=float(ratio),
        elliptic=bool(ratio >= ELLIPSE_MIN_AXIS_RATIO),
        apparent_stiction=float(2.0 * half_chord * s_op),
    )
