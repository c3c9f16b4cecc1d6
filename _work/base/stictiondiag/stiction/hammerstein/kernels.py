"""Compiled least-squares kernels of the Hammerstein fit, and the problem they solve.

For a fixed valve output ``u`` (the valve model of Fig. 10 of Choudhury, Thornhill &
Shah (2005) run on op) the linear part of :mod:`stictiondiag.stiction.hammerstein` is
linear in its parameters: the columns of
:func:`stictiondiag.stiction.hammerstein.columns.regressors` (a first-order process
with dead time and a direct part, Eq. 3 / Table 3, seen through a high-pass), two of
them gains of one sign.  :func:`batch_cost` evaluates many (S, J) pairs in one
compiled call; :class:`Problem` holds what those costs need for one fit.
"""

from __future__ import annotations

import math
import multiprocessing
import os

import numba
import numpy as np

from stictiondiag.core.jit import jit
from stictiondiag.stiction.hammerstein.columns import lag, normal_equations, regressors
from stictiondiag.stiction.valvefit import ValveVariant, valve_run


@jit
def _solve_subset(A, b, idx, k, theta):
    """Solve ``A[idx, idx] theta = b[idx]`` (symmetric positive definite, k <= 8) by
    Cholesky; returns ``theta . b[idx]`` (the explained sum of squares) or -1.0 when
    the subsystem is singular."""
    L = np.zeros((8, 8))
    for i in range(k):
        for j in range(i + 1):
            s = A[idx[i], idx[j]]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            if i == j:
                if s <= 0.0:
                    return -1.0
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    z = np.empty(8)
    for i in range(k):
        s = b[idx[i]]
        for p in range(i):
            s -= L[i, p] * z[p]
        z[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, k):
            s -= L[p, i] * theta[p]
        theta[i] = s / L[i, i]
    e = 0.0
    for i in range(k):
        e += theta[i] * b[idx[i]]
    return e


@jit
def same_sign_fit(A, b, yy, nb):
    """Least squares with the first ``nb`` (basis) gains of one common sign.

    The remaining columns are free.  A combination of first-order lags with gains of
    one sign has a monotone step response: a process, and not the inverse of the
    controller, which an unconstrained fit to closed-loop data finds instead (through
    the PI law of Eq. 3, pv is a high-pass of op).  Solved exactly by enumerating the
    active sets (at most 2^4 small systems).  Returns the sum of squared residuals.
    """
    m = A.shape[0]
    idx = np.empty(8, dtype=np.int64)
    theta = np.empty(8)
    best = yy
    for mask in range(0, 1 << nb):
        k = 0
        for i in range(nb):
            if mask & (1 << i):
                idx[k] = i
                k += 1
        kb = k
        for i in range(nb, m):
            idx[k] = i
            k += 1
        e = _solve_subset(A, b, idx, k, theta)
        if e < 0.0:
            continue
        pos = True
        neg = True
        for i in range(kb):
            if theta[i] < 0.0:
                pos = False
            if theta[i] > 0.0:
                neg = False
        if (pos or neg) and yy - e < best:
            best = yy - e
    return max(best, 0.0)


@jit
def _cholesky_subset(A, idx, k, L):
    """Cholesky factor of ``A[idx, idx]`` (k <= 8) into ``L``; False when singular.

    The operations of :func:`_solve_subset`, so a system factored here and solved by
    :func:`_solve_factored` gives the very same numbers."""
    for i in range(k):
        for j in range(i + 1):
            s = A[idx[i], idx[j]]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            if i == j:
                if s <= 0.0:
                    return False
                L[i, i] = math.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@jit
def _solve_factored(L, b, idx, k, theta, z):
    """Solve with the factor of :func:`_cholesky_subset`; returns ``theta . b[idx]``."""
    for i in range(k):
        s = b[idx[i]]
        for p in range(i):
            s -= L[i, p] * z[p]
        z[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = z[i]
        for p in range(i + 1, k):
            s -= L[p, i] * theta[p]
        theta[i] = s / L[i, i]
    e = 0.0
    for i in range(k):
        e += theta[i] * b[idx[i]]
    return e


@jit
def same_sign_fit_many(A, B, yy, nb, out):
    """:func:`same_sign_fit` for every column of ``B`` (one right-hand side per dead
    time) with the same ``A``: each active set is factored once, not once per column.
    Writes the sums of squared residuals to ``out``.

    The active sets are tried from the full one down; a column whose unconstrained
    fit already has its basis gains of one sign is done, as no smaller set can fit
    it better (the others are tried for the remaining columns only).  The same
    numbers as column by column, but for a smaller set that ties with the full one
    to the last bit (a basis gain of exactly zero), where the two differ by rounding.
    """
    m = A.shape[0]
    nd = B.shape[1]
    idx = np.empty(8, dtype=np.int64)
    theta = np.empty(8)
    z = np.empty(8)
    L = np.zeros((8, 8))
    done = np.zeros(nd, dtype=np.bool_)
    full = (1 << nb) - 1
    for c in range(nd):
        out[c] = yy[c]
    for mask in range(full, -1, -1):
        k = 0
        for i in range(nb):
            if mask & (1 << i):
                idx[k] = i
                k += 1
        kb = k
        for i in range(nb, m):
            idx[k] = i
            k += 1
        if not _cholesky_subset(A, idx, k, L):
            continue
        for c in range(nd):
            if done[c]:
                continue
            e = _solve_factored(L, B[:, c], idx, k, theta, z)
            pos = True
            neg = True
            for i in range(kb):
                if theta[i] < 0.0:
                    pos = False
                if theta[i] > 0.0:
                    neg = False
            if pos or neg:
                if yy[c] - e < out[c]:
                    out[c] = yy[c] - e
                if mask == full:
                    done[c] = True
    for c in range(nd):
        out[c] = max(out[c], 0.0)


@jit
def _pair_cost(
    i,
    x,
    S_arr,
    J_arr,
    offsets,
    taus,
    kano,
    k_start,
    d_start,
    a_hp,
    j0,
    j1,
    stride,
    keep,
    Y,
    yy,
    pre_lag,
    D,
    cost,
    best_d,
    best_o,
    best_t,
):  # pragma: no cover - compiled
    """Row ``i`` of :func:`batch_cost`, written to ``cost``, ``best_d``, ``best_o`` and
    ``best_t`` (rows are independent, so they may run on several threads)."""
    nt = taus.shape[0]
    nd = Y.shape[1]
    sse_d = np.empty(nd)
    cost[i] = np.inf
    for io in range(offsets.shape[0]):
        u = valve_run(x, S_arr[i], J_arr[i], kano, k_start, d_start, offsets[io])[0]
        if pre_lag > 0.0:
            u = lag(u, pre_lag, k_start)
        A, B = normal_equations(u, taus, a_hp, k_start, j0, j1, stride, keep, Y, D)
        for t in range(nt):
            same_sign_fit_many(A[t], B[t], yy, 2, sse_d)
            for k in range(nd):
                sse = sse_d[k]
                if sse < cost[i]:
                    cost[i] = sse
                    best_d[i] = k
                    best_o[i] = io
                    best_t[i] = t
        if S_arr[i] == 0.0:
            break  # a linear valve has no stuck state to start from


@jit
def batch_cost(
    x,
    S_arr,
    J_arr,
    offsets,
    taus,
    kano,
    k_start,
    d_start,
    a_hp,
    j0,
    j1,
    stride,
    keep,
    Y,
    yy,
    pre_lag,
    D,
):  # pragma: no cover - compiled
    """Best cost over start offsets, process time constants and delays for every (S, J).

    ``Y[r, i]`` is the high-passed pv at regression row ``r`` shifted by delay ``i``
    and ``yy[i]`` its sum of squares; ``pre_lag`` [samples] a lag applied to the valve
    output first (the same lag the target went through; 0: none).  Returns the cost
    and, for each pair, the indices of the best delay, start offset and time
    constant.  O(pairs x offsets x n x time constants).
    """
    m = S_arr.shape[0]
    cost = np.empty(m)
    best_d = np.zeros(m, dtype=np.int64)
    best_o = np.zeros(m, dtype=np.int64)
    best_t = np.zeros(m, dtype=np.int64)
    for i in range(m):
        _pair_cost(
            i,
            x,
            S_arr,
            J_arr,
            offsets,
            taus,
            kano,
            k_start,
            d_start,
            a_hp,
            j0,
            j1,
            stride,
            keep,
            Y,
            yy,
            pre_lag,
            D,
            cost,
            best_d,
            best_o,
            best_t,
        )
    return cost, best_d, best_o, best_t


@numba.njit(cache=True, nogil=True, parallel=True)
def batch_cost_threaded(
    x,
    S_arr,
    J_arr,
    offsets,
    taus,
    kano,
    k_start,
    d_start,
    a_hp,
    j0,
    j1,
    stride,
    keep,
    Y,
    yy,
    pre_lag,
    D,
):  # pragma: no cover - compiled
    """:func:`batch_cost` with the pairs shared among numba's threads: the same
    numbers (each pair is computed alone), less wall time when the process has
    cores to spare (see :func:`kernel_threads`)."""
    m = S_arr.shape[0]
    cost = np.empty(m)
    best_d = np.zeros(m, dtype=np.int64)
    best_o = np.zeros(m, dtype=np.int64)
    best_t = np.zeros(m, dtype=np.int64)
    for i in numba.prange(m):
        _pair_cost(
            i,
            x,
            S_arr,
            J_arr,
            offsets,
            taus,
            kano,
            k_start,
            d_start,
            a_hp,
            j0,
            j1,
            stride,
            keep,
            Y,
            yy,
            pre_lag,
            D,
            cost,
            best_d,
            best_o,
            best_t,
        )
    return cost, best_d, best_o, best_t


#: Environment variable: threads for the batch kernels of a process that analyses
#: one loop at a time by itself (``stiction analyze``); unset or 1: one thread.
THREADS_VARIABLE = "STICTION_KERNEL_THREADS"


def kernel_threads() -> int:
    """Threads the batch kernels may use in this process.

    ``STICTION_KERNEL_THREADS`` (default 1), at most numba's thread count; always 1
    in a worker process (a child of a scan or report, local pool or Dask), where
    one loop per core already keeps every core busy and threads would only contend.
    """
    try:
        n = int(os.environ.get(THREADS_VARIABLE, "1"))
    except ValueError:
        return 1
    if n <= 1 or multiprocessing.parent_process() is not None:
        return 1
    return min(n, numba.get_num_threads())


def same_sign_lstsq(X: np.ndarray, y: np.ndarray, nb: int) -> np.ndarray:
    """Parameters of :func:`same_sign_fit` (first ``nb`` gains of one sign)."""
    m = X.shape[1]
    best, best_theta = np.inf, np.zeros(m)
    for mask in range(0, 1 << nb):
        cols = [i for i in range(nb) if mask & (1 << i)] + list(range(nb, m))
        th, *_ = np.linalg.lstsq(X[:, cols], y, rcond=None)
        g = th[: len(cols) - (m - nb)]
        if g.size and not (np.all(g >= 0) or np.all(g <= 0)):
            continue
        sse = float(np.sum((y - X[:, cols] @ th) ** 2))
        if sse < best:
            best = sse
            best_theta = np.zeros(m)
            best_theta[cols] = th
    return best_theta


class Problem:
    """Everything the cost of one (S, J) needs, fixed for one fit.

    Regression rows are ``j0, j0 + stride, ... < j1``; ``j1`` leaves room for the
    longest dead time, so every delay uses the same rows.
    """

    def __init__(self, x, yf, taus, a_hp, k_start, d_start, j0, j1, stride, delays, pre_lag=0.0):
        self.x, self.yf = x, yf
        self.taus = np.asarray(taus, dtype=float)
        self.a_hp = float(a_hp)
        self.k_start, self.d_start = int(k_start), float(d_start)
        self.j0, self.j1, self.stride = int(j0), int(j1), int(stride)
        self.all_rows = np.arange(self.j0, self.j1, self.stride, dtype=np.int64)
        self.keep = np.ones(self.all_rows.size, dtype=np.bool_)
        self.rows = self.all_rows
        self.inputs: dict[str, np.ndarray] = {}
        self.pre_lag = float(pre_lag)
        self.n_drift = 0
        self.D = np.zeros((self.rows.size, 0))
        # Costs already computed, per state of the problem (see _cost); the rows
        # and drift states are counted by ``_rows_version``.
        self._rows_version = 0
        self._costs: dict[tuple, dict[tuple[float, float], tuple]] = {}
        self.set_delays(delays)

    def coarser(self, taus, stride) -> Problem:
        """The same problem with other time constants and row stride, every row kept."""
        return Problem(
            self.x,
            self.yf,
            taus,
            self.a_hp,
            self.k_start,
            self.d_start,
            self.j0,
            self.j1,
            stride,
            self.delays,
            self.pre_lag,
        ).with_drift(self.n_drift)

    def with_drift(self, n_drift: int) -> Problem:
        """Estimate ``n_drift`` drift states alongside (see :meth:`drift_basis`); returns self."""
        self.n_drift = int(n_drift)
        self.D = self.drift_basis()
        self._rows_version += 1
        self.set_delays(self.delays)
        return self

    def drift_basis(self) -> np.ndarray:
        """Orthonormal basis of the drift on the regression rows kept.

        The cosines ``cos(pi m (j - j0 + 1/2) / (j1 - j0))``, ``m = 1 .. n_drift``, of
        a discrete cosine transform over the fitted span: every slow signal whose
        frequency is below ``n_drift / (2 (j1 - j0))`` cycles per sample (a load
        drift, a set-point or operating-point move) is a combination of them.  At
        most an eighth of the rows, so that the valve keeps most of the degrees of
        freedom.
        """
        m = min(self.n_drift, self.rows.size // 8)
        if m <= 0:
            return np.zeros((self.rows.size, 0))
        t = (self.rows - self.j0 + 0.5) / max(1, self.j1 - self.j0)
        C = np.cos(np.pi * t[:, None] * np.arange(1, m + 1)[None, :])
        # Orthonormalised through the Cholesky factor of the Gram matrix: cosines of
        # distinct frequencies below the row rate are nearly orthogonal already, so
        # it is well conditioned, and much cheaper than a QR of the tall matrix.
        L = np.linalg.cholesky(C.T @ C)
        return np.ascontiguousarray(np.linalg.solve(L, C.T).T)

    def set_delays(self, delays):
        self.delays = np.asarray(delays, dtype=np.int64)
        Y = self.yf[self.rows[:, None] + self.delays[None, :]]
        if self.D.shape[1]:
            Y = Y - self.D @ (self.D.T @ Y)
        self.Y = np.ascontiguousarray(Y)
        self.yy = np.sum(self.Y**2, axis=0)

    def set_keep(self, keep):
        """Leave out the regression rows whose flag is False."""
        self.keep = np.asarray(keep, dtype=np.bool_)
        self.rows = self.all_rows[self.keep]
        self.D = self.drift_basis()
        self._rows_version += 1
        self.set_delays(self.delays)

    def cost(self, S, J, variant: ValveVariant, offsets):
        """Cost, best delay, start offset and time constant for every (S, J) pair.

        Pairs with a band narrower than the play operator are run without it
        (:meth:`stictiondiag.stiction.valvefit.ValveVariant.for_band`).
        """
        S = np.atleast_1d(np.asarray(S, dtype=float))
        J = np.atleast_1d(np.asarray(J, dtype=float))
        off = np.atleast_1d(np.asarray(offsets, dtype=float))
        parts = variant.band_parts(S)
        if len(parts) == 1:
            return self._cost(S, J, parts[0][1], off)
        out = [np.empty(S.size), np.empty(S.size, np.int64), np.empty(S.size), np.empty(S.size)]
        for mask, v in parts:
            part = self._cost(S[mask], J[mask], v, off)
            for o, p in zip(out, part, strict=True):
                o[mask] = p
        return out[0], out[1], out[2], out[3]

    def _input(self, variant: ValveVariant) -> np.ndarray:
        """The op that ``variant`` runs on (prepared once per variant)."""
        x = self.inputs.get(variant.name)
        if x is None:
            x = self.inputs[variant.name] = variant.prepare(self.x)
        return x

    def _cost(self, S, J, variant: ValveVariant, off):
        """:meth:`cost` for one variant.  A pair evaluated before in the same state
        (variant, time constants, dead times, start offsets, rows) is not computed
        again: the searches' zooms come back to their centres and overlap (about a
        sixth of a fit's pairs), and the kernel is deterministic, so the
        remembered numbers are the ones it would return."""
        state = (
            variant,
            self.taus.tobytes(),
            self.delays.tobytes(),
            off.tobytes(),
            self._rows_version,
        )
        known = self._costs.setdefault(state, {})
        pairs = list(zip(S.tolist(), J.tolist(), strict=True))
        new = list(dict.fromkeys(p for p in pairs if p not in known))
        if new:
            S_new = np.array([p[0] for p in new])
            J_new = np.array([p[1] for p in new])
            c, bd, bo, bt = self._kernel_cost(S_new, J_new, variant, off)
            for i, p in enumerate(new):
                known[p] = (c[i], self.delays[bd[i]], off[bo[i]], self.taus[bt[i]])
        rows = [known[p] for p in pairs]
        return tuple(np.array([r[i] for r in rows]) for i in range(4))

    def _kernel_cost(self, S, J, variant: ValveVariant, off):
        """The compiled batch cost of every pair: costs and the indices of the best
        dead time, start offset and time constant."""
        x = self._input(variant)
        threads = kernel_threads() if S.size > 1 else 1
        kernel = batch_cost
        if threads > 1:
            numba.set_num_threads(threads)
            kernel = batch_cost_threaded
        return kernel(
            x,
            variant.model_S(S),
            J,
            off,
            self.taus,
            variant.kano,
            self.k_start,
            self.d_start,
            self.a_hp,
            self.j0,
            self.j1,
            self.stride,
            self.keep,
            self.Y,
            self.yy,
            self.pre_lag,
            self.D,
        )

    def residual(self, S, J, variant: ValveVariant, delay, offset, tau):
        """Residual on the regression rows, fitted parameters and valve output."""
        variant = variant.for_band(float(S))
        x = self._input(variant)
        u, n_slips = valve_run(
            x,
            float(variant.model_S(S)),
            float(J),
            variant.kano,
            self.k_start,
            self.d_start,
            float(offset),
        )
        uf = lag(u, self.pre_lag, self.k_start) if self.pre_lag > 0 else u
        phi = regressors(uf, float(tau), self.a_hp, self.k_start)
        X = phi[self.rows]
        y = self.yf[self.rows + int(delay)]
        if self.D.shape[1]:
            X = X - self.D @ (self.D.T @ X)
            y = y - self.D @ (self.D.T @ y)
        theta = same_sign_lstsq(X, y, 2)
        return y - X @ theta, theta, u, n_slips
