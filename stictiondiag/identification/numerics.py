"""Small numerical tools shared by the process and controller fits and the gap searches.

Signal checks, delayed copies of a signal, weighted linear least squares (with the
one-signed pair of columns of a fractional dead time) and golden-section search, for
the identification of the loop's linear blocks (Eq. 3 of Choudhury, Thornhill & Shah
2005) and the parameter searches of the gap diagnosis.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import jit

#: Fewest usable samples for an identification.
MIN_SAMPLES = 20


def as_signal(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1:
        raise UsageError(f"{name} must be a one-dimensional signal")
    return a


def check_dt(dt) -> float:
    try:
        dt_ = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"sample time dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt_) and dt_ > 0):
        raise UsageError(f"sample time dt must be a positive number of seconds, got {dt_}")
    return dt_


def r_squared(y: np.ndarray, y_hat: np.ndarray) -> float:
    sst = float(np.sum((y - y.mean()) ** 2))
    if sst <= 0.0:
        return 0.0
    return 1.0 - float(np.sum((y - y_hat) ** 2)) / sst


def delayed(u: np.ndarray, shift: int) -> np.ndarray:
    """``u[k - shift]``, held at ``u[0]`` before the record starts."""
    if shift <= 0:
        return u
    out = np.empty_like(u)
    out[:shift] = u[0]
    out[shift:] = u[: u.size - shift]
    return out


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


@jit
def _gram(X, y, w):  # pragma: no cover - compiled
    """Weighted normal equations ``(X' W X, X' W y)`` in one pass over the samples.

    O(n p^2) for n samples and p columns, with no temporary of the record's length;
    samples of weight 0 are skipped.
    """
    n, p = X.shape
    A = np.zeros((p, p))
    b = np.zeros(p)
    for k in range(n):
        wk = w[k]
        if wk == 0.0:
            continue
        yk = wk * y[k]
        for i in range(p):
            xi = X[k, i]
            b[i] += xi * yk
            wxi = wk * xi
            for j in range(i + 1):
                A[i, j] += wxi * X[k, j]
    for i in range(p):
        for j in range(i):
            A[j, i] = A[i, j]
    return A, b


@jit
def _scaled_solve(A, b):  # pragma: no cover - compiled
    """Solve ``A x = b`` with the columns scaled to unit norm and a tiny ridge."""
    p = b.shape[0]
    d = np.empty(p)
    for i in range(p):
        d[i] = math.sqrt(max(A[i, i], 1e-300))
    As = np.empty((p, p))
    for i in range(p):
        for j in range(p):
            As[i, j] = A[i, j] / (d[i] * d[j])
        As[i, i] += 1e-10
    return np.linalg.solve(As, b / d) / d


def _weighted_problem(X, y, w):
    return (
        np.ascontiguousarray(X, dtype=float),
        np.ascontiguousarray(y, dtype=float),
        np.ascontiguousarray(w, dtype=float),
    )


def _solve_normal(A, b, X, y, w) -> np.ndarray:
    """Solution of the normal equations ``A``, ``b`` of ``X``, ``y``, ``w`` (see :func:`wls`)."""
    try:
        return _scaled_solve(A, b)
    except np.linalg.LinAlgError:
        sw = np.sqrt(w)
        coef, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
        return coef


def wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted linear least squares (weights 0/1) by the normal equations.

    Columns are scaled to unit norm and a tiny ridge keeps collinear columns
    solvable; far faster than an SVD for the few columns used here.  The normal
    equations are summed in one compiled pass (:func:`_gram`, O(n p^2)).
    """
    X, y, w = _weighted_problem(X, y, w)
    A, b = _gram(X, y, w)
    return _solve_normal(A, b, X, y, w)


@jit
def _one_sign_pair(X, y, w, A, b, coef):  # pragma: no cover - compiled
    """The better of the fits with the first or the second column left out (the
    first on a tie), from the normal equations ``A``, ``b``; its error is summed
    over the samples as the residual's (see :func:`fractional_delay_wls`)."""
    n, p = X.shape
    best = np.inf
    out = coef.copy()
    for drop in (1, 0):
        keep = np.empty(p - 1, dtype=np.int64)
        q = 0
        for j in range(p):
            if j != drop:
                keep[q] = j
                q += 1
        As = np.empty((p - 1, p - 1))
        bs = np.empty(p - 1)
        for i in range(p - 1):
            bs[i] = b[keep[i]]
            for j in range(p - 1):
                As[i, j] = A[keep[i], keep[j]]
        c = np.zeros(p)
        cs = _scaled_solve(As, bs)
        for i in range(p - 1):
            c[keep[i]] = cs[i]
        sse = 0.0
        for k in range(n):
            r = y[k]
            for j in range(p):
                r -= X[k, j] * c[j]
            sse += w[k] * (r * r)
        if sse < best:
            best = sse
            out = c
    return out


def fractional_delay_wls(X: np.ndarray, y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """:func:`wls` with the first two columns (the input at dead times d and d + 1)
    weighted with one sign.

    The two columns stand for one gain and a dead time between d and d + 1 samples:
    ``b ((1 - f) u(t - d) + f u(t - d - 1))`` with ``0 <= f <= 1``.  Unconstrained,
    the pair can take large weights of opposite sign, ``b (u(t - d) - u(t - d - 1))``:
    a differentiator that answers the valve's slips instead of its position, fits a
    part of the record and fails elsewhere.  When the free solution has opposite
    signs, the constrained optimum lies on the boundary ``f = 0`` or ``f = 1``: the
    better fit with one of the two columns alone.  The normal equations are summed
    once (O(n p^2)); the fits with a column left out take their rows and columns.
    """
    X, y, w = _weighted_problem(X, y, w)
    A, b = _gram(X, y, w)
    coef = _solve_normal(A, b, X, y, w)
    if X.shape[1] < 2 or coef[0] * coef[1] >= 0.0:
        return coef
    try:
        return _one_sign_pair(X, y, w, A, b, coef)
    except np.linalg.LinAlgError:
        pass
    best = None
    for drop in (1, 0):
        keep = np.array([j for j in range(X.shape[1]) if j != drop])
        c = np.zeros(X.shape[1])
        c[keep] = wls(X[:, keep], y, w)
        r = y - X @ c
        sse = float(np.dot(w, r * r))
        if best is None or sse < best[0]:
            best = (sse, c)
    return best[1]
