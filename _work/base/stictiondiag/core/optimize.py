"""Bounded scalar minimisation without importing :mod:`scipy.optimize`.

:mod:`scipy.optimize` costs about half a second to import (it loads scipy.sparse and
the linear-programming machinery); the process identification needs only
``minimize_scalar(method="bounded")``.  :func:`minimize_scalar_bounded` is scipy's
``_minimize_scalar_bounded`` (scipy 1.17, ``scipy/optimize/_optimize.py``, BSD
licence; Brent's method with golden-section fallback, Forsythe, Malcolm & Moler
1977) line for line without its printing, so it evaluates the function at the same
points and returns the same numbers; ``tests/test_filters.py`` checks that.
"""

from __future__ import annotations

from collections.abc import Callable
from math import sqrt

import numpy as np


def minimize_scalar_bounded(
    func: Callable[[float], float],
    bounds: tuple[float, float],
    xatol: float = 1e-5,
    maxiter: int = 500,
) -> tuple[float, float]:
    """``scipy.optimize.minimize_scalar(func, bounds=bounds, method="bounded",
    options={"xatol": xatol, "maxiter": maxiter})``; returns ``(res.x, res.fun)``."""
    x1, x2 = bounds
    if not (np.isfinite(x1) and np.isfinite(x2)):
        raise ValueError("Optimization bounds must be finite scalars.")
    if x1 > x2:
        raise ValueError("The lower bound exceeds the upper bound.")
    maxfun = maxiter
    sqrt_eps = sqrt(2.2e-16)
    golden_mean = 0.5 * (3.0 - sqrt(5.0))
    a, b = x1, x2
    fulc = a + golden_mean * (b - a)
    nfc, xf = fulc, fulc
    rat = e = 0.0
    x = xf
    fx = func(x)
    num = 1
    fu = np.inf

    ffulc = fnfc = fx
    xm = 0.5 * (a + b)
    tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
    tol2 = 2.0 * tol1

    while np.abs(xf - xm) > (tol2 - 0.5 * (b - a)):
        golden = 1
        # Check for parabolic fit
        if np.abs(e) > tol1:
            golden = 0
            r = (xf - nfc) * (fx - ffulc)
            q = (xf - fulc) * (fx - fnfc)
            p = (xf - fulc) * q - (xf - nfc) * r
            q = 2.0 * (q - r)
            if q > 0.0:
                p = -p
            q = np.abs(q)
            r = e
            e = rat

            # Check for acceptability of parabola
            if (np.abs(p) < np.abs(0.5 * q * r)) and (p > q * (a - xf)) and (p < q * (b - xf)):
                rat = (p + 0.0) / q
                x = xf + rat

                if ((x - a) < tol2) or ((b - x) < tol2):
                    si = np.sign(xm - xf) + ((xm - xf) == 0)
                    rat = tol1 * si
            else:  # do a golden-section step
                golden = 1

        if golden:  # do a golden-section step
            if xf >= xm:
                e = a - xf
            else:
                e = b - xf
            rat = golden_mean * e

        si = np.sign(rat) + (rat == 0)
        x = xf + si * np.maximum(np.abs(rat), tol1)
        fu = func(x)
        num += 1

        if fu <= fx:
            if x >= xf:
                a = xf
            else:
                b = xf
            fulc, ffulc = nfc, fnfc
            nfc, fnfc = xf, fx
            xf, fx = x, fu
        else:
            if x < xf:
                a = x
            else:
                b = x
            if (fu <= fnfc) or (nfc == xf):
                fulc, ffulc = nfc, fnfc
                nfc, fnfc = x, fu
            elif (fu <= ffulc) or (fulc == xf) or (fulc == nfc):
                fulc, ffulc = x, fu

        xm = 0.5 * (a + b)
        tol1 = sqrt_eps * np.abs(xf) + xatol / 3.0
        tol2 = 2.0 * tol1

        if num >= maxfun:
            break

    return xf, fx
