"""The columns of the Hammerstein fit's linear part and their normal equations.

For a fixed valve output ``u`` (the valve model of Fig. 10 of Choudhury, Thornhill &
Shah (2005) run on op) the linear part of :mod:`stictiondiag.stiction.hammerstein` is
linear in its parameters: the columns of :func:`regressors` (a first-order process
with dead time and a direct part, Eq. 3 / Table 3, seen through a high-pass), two of
them gains of one sign.  :func:`regressors` defines them plainly, one time constant
at a time; :func:`normal_equations` computes their normal equations at the kept
regression rows for many time constants in one pass over the record, which is
what the batch costs of :mod:`stictiondiag.stiction.hammerstein.kernels` evaluate.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.jit import jit


@jit
def lag(x, T, k0):
    """First-order lag, unit gain, time constant ``T`` [samples] (T <= 0: a copy),
    started in steady state at sample ``k0``; zero before ``k0``."""
    n = x.shape[0]
    y = np.zeros(n)
    if T <= 0.0:
        for k in range(k0, n):
            y[k] = x[k]
        return y
    a = math.exp(-1.0 / T)
    y[k0] = x[k0]
    for k in range(k0 + 1, n):
        y[k] = a * y[k - 1] + (1.0 - a) * x[k]
    return y


@jit
def highpass(x, a, k0):
    """``(1 - q^-1) / (1 - a q^-1)`` started at rest at sample ``k0``; zero before."""
    n = x.shape[0]
    y = np.zeros(n)
    for k in range(k0 + 1, n):
        y[k] = a * y[k - 1] + x[k] - x[k - 1]
    return y


#: Columns of the linear part (see :func:`regressors`).
NCOL = 5


@jit
def regressors(u, tau, a_hp, k0):
    """Columns of the linear part for one process time constant ``tau`` [samples].

    ``[F u, F lag(u, tau), 1, a^(k - k0), b^(k - k0)]`` with ``F`` the high-pass,
    ``a`` the high-pass pole and ``b = exp(-1/tau)`` the process pole.  The first two
    are the process (a direct part and a first-order lag, gains of one sign); the
    last three are free: a constant, the high-pass response to a step at the start,
    and the process's own response to its unknown state at the start (together they
    also carry an integrating process's unknown inflow imbalance).  Everything starts
    at sample ``k0``, so no history from before the start (where the valve state is
    unknown) enters.
    """
    n = u.shape[0]
    phi = np.zeros((n, NCOL))
    g0 = highpass(u, a_hp, k0)
    g1 = highpass(lag(u, tau, k0), a_hp, k0)
    b = math.exp(-1.0 / tau) if tau > 0.0 else 0.0
    e = 1.0
    f = 1.0
    for k in range(k0, n):
        phi[k, 0] = g0[k]
        phi[k, 1] = g1[k]
        phi[k, 2] = 1.0
        phi[k, 3] = e
        phi[k, 4] = f
        e *= a_hp
        f *= b
    return phi


@jit
def _row_samples(n, k0, j0, j1, stride, keep, nr):  # pragma: no cover - compiled
    """Samples of the kept regression rows ``j = j0, j0 + stride, ... < j1`` (at most
    ``nr``, from ``k0`` on) and how many there are."""
    rows = np.empty(max(nr, 1), dtype=np.int64)
    r = 0
    if j0 < k0:
        return rows, 0
    row = 0
    k = j0
    while k < n:
        if r >= nr or k >= j1:
            break
        row += 1
        if keep[row - 1]:
            rows[r] = k
            r += 1
        k += stride
    return rows, r


#: A time constant whose pole ``b`` lies this close to the high-pass pole ``a``
#: (``|b - a| < POLE_SEPARATION (1 - b)``) gets its column from the chained lag
#: and high-pass (:func:`_four_lags`): the partial fractions of
#: :func:`_four_partial_fractions` lose ``log10((1 - b) / |b - a|)`` digits, here at
#: most four of sixteen.
POLE_SEPARATION = 1e-4


@jit
def _four_lags(u, rows, nrow, k0, a_hp, bl, t0, m, phi, first):  # pragma: no cover
    """Columns 1 and 4 of :func:`regressors` at the kept rows for the time constants
    ``t0 .. t0 + m - 1`` (m <= 4), written to ``phi``,
    by the lag and the high-pass chained as :func:`regressors` defines them (for
    poles too close to the high-pass's for :func:`_four_partial_fractions`).  The
    chains of a missing fourth repeat the last one and are not written; with
    ``first`` also columns 0, 2 and 3 (the same for every time constant), as
    :func:`_four_partial_fractions`."""
    b0 = bl[t0]
    b1 = bl[t0 + min(1, m - 1)]
    b2 = bl[t0 + min(2, m - 1)]
    b3 = bl[t0 + min(3, m - 1)]
    g = 0.0
    e = 1.0
    u0 = u[k0]
    l0 = l1 = l2 = l3 = u0
    h0 = h1 = h2 = h3 = 0.0
    f0 = f1 = f2 = f3 = 1.0
    k = k0
    for r in range(nrow):
        target = rows[r]
        while k < target:
            k += 1
            uk = u[k]
            if first:
                g = a_hp * g + uk - u[k - 1]
                e *= a_hp
            p0, p1, p2, p3 = l0, l1, l2, l3
            l0 = b0 * p0 + (1.0 - b0) * uk
            l1 = b1 * p1 + (1.0 - b1) * uk
            l2 = b2 * p2 + (1.0 - b2) * uk
            l3 = b3 * p3 + (1.0 - b3) * uk
            h0 = a_hp * h0 + l0 - p0
            h1 = a_hp * h1 + l1 - p1
            h2 = a_hp * h2 + l2 - p2
            h3 = a_hp * h3 + l3 - p3
            f0 *= b0
            f1 *= b1
            f2 *= b2
            f3 *= b3
        _write_four(phi, t0, m, r, h0, h1, h2, h3, f0, f1, f2, f3)
        if first:
            _write_shared(phi, r, g, e)


@jit
def _write_four(phi, t0, m, r, h0, h1, h2, h3, f0, f1, f2, f3):  # pragma: no cover
    """Row ``r`` of columns 1 and 4 for the time constants ``t0 .. t0 + m - 1``."""
    phi[t0, r, 1] = h0
    phi[t0, r, 4] = f0
    if m > 1:
        phi[t0 + 1, r, 1] = h1
        phi[t0 + 1, r, 4] = f1
    if m > 2:
        phi[t0 + 2, r, 1] = h2
        phi[t0 + 2, r, 4] = f2
    if m > 3:
        phi[t0 + 3, r, 1] = h3
        phi[t0 + 3, r, 4] = f3


@jit
def _write_shared(phi, r, g, e):  # pragma: no cover
    """Row ``r`` of columns 0, 2 and 3 (the same for every time constant)."""
    for t in range(phi.shape[0]):
        phi[t, r, 0] = g
        phi[t, r, 2] = 1.0
        phi[t, r, 3] = e


@jit
def _four_partial_fractions(u, rows, nrow, k0, a_hp, bl, t0, m, phi, first):  # pragma: no cover
    """:func:`_four_lags` by partial fractions: one recursion per time constant
    instead of two.

    With ``z = q^-1``, the lag started in steady state and the high-pass started at
    rest, column 1 is ``(1 - b) / ((1 - a z) (1 - b z))`` applied to the increments
    of ``u``, which splits into ``(1 - b) / (b - a) (b p_b - a p_a)`` with
    ``p_x = 1 / (1 - x z)`` of the increments, both started at rest: ``p_a`` is
    column 0 (written with ``first``, as columns 2 and 3), so each time constant
    needs only ``p_b`` and its power chain.  The same numbers as the chained form up to
    rounding, amplified by ``(1 - b) / |b - a|`` (see :data:`POLE_SEPARATION`).
    """
    b0 = bl[t0]
    b1 = bl[t0 + min(1, m - 1)]
    b2 = bl[t0 + min(2, m - 1)]
    b3 = bl[t0 + min(3, m - 1)]
    c0 = (1.0 - b0) / (b0 - a_hp)
    c1 = (1.0 - b1) / (b1 - a_hp)
    c2 = (1.0 - b2) / (b2 - a_hp)
    c3 = (1.0 - b3) / (b3 - a_hp)
    p0 = p1 = p2 = p3 = 0.0
    f0 = f1 = f2 = f3 = 1.0
    g = 0.0
    e = 1.0
    k = k0
    for r in range(nrow):
        target = rows[r]
        while k < target:
            k += 1
            du = u[k] - u[k - 1]
            g = a_hp * g + du
            e *= a_hp
            p0 = b0 * p0 + du
            p1 = b1 * p1 + du
            p2 = b2 * p2 + du
            p3 = b3 * p3 + du
            f0 *= b0
            f1 *= b1
            f2 *= b2
            f3 *= b3
        ag = a_hp * g
        _write_four(
            phi,
            t0,
            m,
            r,
            c0 * (b0 * p0 - ag),
            c1 * (b1 * p1 - ag),
            c2 * (b2 * p2 - ag),
            c3 * (b3 * p3 - ag),
            f0,
            f1,
            f2,
            f3,
        )
        if first:
            _write_shared(phi, r, g, e)


@jit
def normal_equations(u, taus, a_hp, k0, j0, j1, stride, keep, Y, D):
    """Normal equations of the linear part for every time constant and delay.

    The columns are those of :func:`regressors`, computed on the fly and kept only at
    the regression rows ``j = j0, j0 + stride, ... < j1`` whose ``keep`` flag is set;
    ``Y[r, i]`` is the target ``yf[j_r + delays[i]]`` of the r-th kept row.  Returns
    ``A[t]`` (5 x 5) and ``B[t]`` (5 x delays).

    The columns that do not depend on the time constant (0, 2, 3) are computed once,
    in the first pass; the other two run over the record four time constants at a
    time, in scalars (:func:`_four_partial_fractions`): each
    is a chain of dependent operations whose latency, not the arithmetic, sets the
    time, and four independent chains overlap.  Equal to the columns of
    :func:`regressors` up to rounding (``tests/test_work_per_loop.py``).
    O(n x time constants + rows x time constants x delays).
    """
    nt = taus.shape[0]
    n = u.shape[0]
    nr = Y.shape[0]
    phi = np.empty((nt, nr, NCOL))
    rows, nrow = _row_samples(n, k0, j0, j1, stride, keep, nr)
    bl = np.empty(nt)
    for t in range(nt):
        bl[t] = math.exp(-1.0 / taus[t]) if taus[t] > 0.0 else 0.0
    # Four time constants per pass; a pass with fewer repeats its last one.
    for t0 in range(0, max(nt, 1), 4):
        m = min(nt - t0, 4)
        if m <= 0:
            break
        close = False
        for t in range(t0, t0 + m):
            close |= abs(bl[t] - a_hp) < POLE_SEPARATION * (1.0 - bl[t])
        if close:
            _four_lags(u, rows, nrow, k0, a_hp, bl, t0, m, phi, t0 == 0)
        else:
            _four_partial_fractions(u, rows, nrow, k0, a_hp, bl, t0, m, phi, t0 == 0)
    A = np.empty((nt, NCOL, NCOL))
    B = np.empty((nt, NCOL, Y.shape[1]))
    for t in range(nt):
        P = phi[t]
        At = P.T @ P
        if D.shape[1] > 0:
            # Drift states projected out (Frisch-Waugh): Y is already orthogonal to D.
            DP = D.T @ P
            At -= DP.T @ DP
        tr = 0.0
        for p in range(NCOL):
            tr += At[p, p]
        ridge = 1e-10 * tr / NCOL + 1e-300
        for p in range(NCOL):
            At[p, p] += ridge
        A[t] = At
        B[t] = P.T @ Y
    return A, B
