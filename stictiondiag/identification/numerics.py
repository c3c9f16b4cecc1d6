"""Small numerical tools shared by the process and controller fits and the gap searches.

Weighted linear least squares (with the one-signed pair of columns of a
fractional dead time), the R^2 of a fit and golden-section search, for
the identification of the loop's linear blocks (Eq. 3 of Choudhury, Thornhill & Shah
2005) and the parameter searches of the gap diagnosis.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from stictiondiag.core.jit import jit

#: Fewest usable samples for an identification.
MIN_SAMPLES = 20


def r_squared(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Coefficient of determination of ``y_hat`` against ``y`` [-]; NaN for an empty
    ``y`` (said without numpy's warning of an empty mean)."""
    if y.size == 0:
        return math.nan
    sst = float(np.sum((y - y.mean()) ** 2))
    if sst <= 0.0:
        return 0.0
    return 1.0 - float(np.sum((y - y_hat) ** 2)) / sst


def golden_section(cost: Callable[[float], float], lo: float, hi: float, n_iter: int = 30) -> float:
    """Minimise a unimodal scalar function on [lo, hi] by golden-section search."""
    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    for _ in range(n_iter):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
    return c if fc < fd else d


#: Largest system solved in the compiled :func:`_scaled_solve`: up to this size its
#: LAPACK call gives numpy's numbers to the last bit (larger ones may differ in
#: rounding, so they keep numpy's solve).
_COMPILED_SOLVE_MAX = 5


def _normal_equations(X: np.ndarray, y: np.ndarray, w: np.ndarray):
    """Weighted normal equations ``(X' W X, X' W y)`` (BLAS; O(n p^2))."""
    Xw = X * w[:, None]
    return Xw.T @ X, Xw.T @ y


@jit
def _scaled_solve(A, b):  # pragma: no cover - compiled
    """Solve ``A x = b`` with the columns scaled to unit norm and a tiny ridge (the
    operations of the numpy expression ``solve(A / outer(d, d) + 1e-10 I, b / d) / d``
    in one compiled call: a small system costs less than numpy's call overhead)."""
    p = b.shape[0]
    d = np.empty(p)
    for i in range(p):
        v = A[i, i]
        d[i] = math.sqrt(1e-300 if v < 1e-300 else v)  # NaN stays NaN
    As = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            As[i, j] = A[i, j] / (d[i] * d[j])
        As[i, i] += 1e-10
    return np.linalg.solve(As, b / d) / d


def _solve_normal(A, b, X, y, w) -> np.ndarray:
    """Solution of the normal equations ``A``, ``b`` of ``X``, ``y``, ``w`` (see :func:`wls`)."""
    try:
        if b.size <= _COMPILED_SOLVE_MAX:
            return _scaled_solve(A, b)
        d = np.sqrt(np.maximum(np.diag(A), 1e-300))
        As = A / np.outer(d, d)
        As[np.diag_indices_from(As)] += 1e-10
        return np.linalg.solve(As, b / d) / d
    except np.linalg.LinAlgError:
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
        return coef


def wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted linear least squares (weights 0/1) by the normal equations.

    Columns are scaled to unit norm and a tiny ridge keeps collinear columns
    solvable; far faster than an SVD for the few columns used here.  O(n p^2).
    """
    A, b = _normal_equations(X, y, w)
    return _solve_normal(A, b, X, y, w)


def fractional_delay_wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`wls` with the first two columns (the input at dead times d and d + 1)
    weighted with one sign.

    The two columns stand for one gain and a dead time between d and d + 1 samples:
    ``b ((1 - f) u(t - d) + f u(t - d - 1))`` with ``0 <= f <= 1``.  Unconstrained,
    the pair can take large weights of opposite sign, ``b (u(t - d) - u(t - d - 1))``:
    a differentiator that answers the valve's slips instead of its position, fits a
    part of the record and fails elsewhere.  When the free solution has opposite
    signs, the constrained optimum lies on the boundary ``f = 0`` or ``f = 1``: the
    better fit with one of the two columns alone.  O(n p^2).
    """
    coef = wls(X, y, w)
    if X.shape[1] < 2 or coef[0] * coef[1] >= 0.0:
        return coef
    fits = []
    for drop in (1, 0):
        keep = [j for j in range(X.shape[1]) if j != drop]
        c = np.zeros(X.shape[1])
        c[keep] = wls(X[:, keep], y, w)
        r = y - X @ c
        fits.append((float(np.dot(w, r * r)), c))
    # min keeps the first of equal (or unordered) sse, as the comparison sse < best did.
    return min(fits, key=lambda fit: fit[0])[1]
