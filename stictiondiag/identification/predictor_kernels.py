"""The process-with-load Kalman filter of the prediction-error process fit
(:mod:`stictiondiag.identification.predictor`; Section 4.2.2, Eq. 3 of Choudhury,
Thornhill & Shah 2005): its compiled kernels and its algebra.

Compiled: the steady-state Kalman gains of the process-with-load model; the
filter's ``horizon``-step prediction errors of one signal or of many with a filter
each (a grid's filters at once); the entries of the one-step structure grid's normal
equations; and the weighted least-squares fit of one structure
(:func:`shifted_pair_wls`).  Rows filtered together run side by side (one's latency
hides behind the others'); each row goes through the same operations as alone, so
it gets the same numbers.  The weighted sums are reassociated into vector registers:
the same products, summed in another order than BLAS sums them (the same numbers to
rounding).

In Python, over those kernels: the gains remembered per filter
(:func:`kalman_gains`), the variances of the one-step and ``horizon``-step prediction
errors (:func:`prediction_variance_ratio`), the innovation responses to the input
(:func:`process_regressors`) and the pv noise floor of a fitted replay
(:func:`process_noise_floor`).  They sit beside the kernels they call, so that a
caller of the filter's algebra finds all of it in one place.
"""

from __future__ import annotations

import functools

import numba
import numpy as np

from stictiondiag.core.filters import delayed
from stictiondiag.core.jit import jit
from stictiondiag.identification.numerics import _scaled_solve
from stictiondiag.identification.process_result import ProcessFit, ProcessModel

#: A sum over the samples that may be reassociated (numba's ``fastmath`` flag
#: ``reassoc`` alone: no other assumption about the numbers), so that it is computed
#: in vector registers, several partial sums at once, as BLAS computes its dots.
_reduction = numba.njit(cache=True, nogil=True, fastmath={"reassoc"})


@jit
def _riccati_gains(pole, load_ratio):  # pragma: no cover - compiled
    p11, p12, p22 = 1.0 + load_ratio, 0.0, 1.0 + load_ratio
    k1 = k2 = 0.0
    for _ in range(2000):
        s = p11 + 1.0
        n1, n2 = p11 / s, p12 / s
        f11 = p11 - n1 * p11
        f12 = p12 - n1 * p12
        f22 = p22 - n2 * p12
        # P = F Pf F' + Q with F = [[a, 1], [0, 1]].
        q11 = pole * pole * f11 + 2.0 * pole * f12 + f22
        q12 = pole * f12 + f22
        q22 = f22 + load_ratio
        done = abs(n1 - k1) < 1e-13 and abs(n2 - k2) < 1e-13
        k1, k2 = n1, n2
        p11, p12, p22 = q11, q12, q22
        if done:
            break
    return k1, k2, p11, p12, p22


#: Samples between exact restarts of the running sum of :func:`_horizon_errors`.
_RESTART = 1024


@jit
def _horizon_errors(z, yf, lf, drive, pole, horizon, err):  # pragma: no cover - compiled
    """Errors of the ``horizon``-step predictions, written to ``err[horizon:]``.

    The prediction of ``z[j + h]`` made at ``j`` runs the model ``h`` steps from the
    filtered state with the load held: ``pole^h yf[j] + lf[j] (1 + pole + ... +
    pole^(h-1)) + S[j]``, ``S[j] = sum_i pole^(h-1-i) drive[j+i]``.  ``S`` is a
    sliding weighted sum, updated in O(1) per sample
    (``S[j+1] = pole S[j] - pole^h drive[j] + drive[j+h]``) and summed afresh every
    ``_RESTART`` samples so that rounding cannot build up: O(n) for any horizon
    (stepping every prediction ``h`` times costs O(n h)).
    """
    n = z.shape[0]
    q = n - horizon
    ph = 1.0
    geo = 0.0
    for _ in range(horizon):
        geo = geo * pole + 1.0
        ph *= pole
    moving = False
    for j in range(n):
        if drive[j] != 0.0:
            moving = True
            break
    acc = 0.0
    for j in range(q):
        if moving:
            if j % _RESTART == 0:
                acc = 0.0
                for i in range(horizon):
                    acc = pole * acc + drive[j + i]
            else:
                acc = pole * acc - ph * drive[j - 1] + drive[j - 1 + horizon]
        err[j + horizon] = z[j + horizon] - (ph * yf[j] + geo * lf[j] + acc)


@jit
def _prediction_errors(z, drive, pole, k1, k2, y0, horizon):  # pragma: no cover - compiled
    """Errors of the ``horizon``-step-ahead predictions of the steady-state filter.

    ``z`` are the measurements, ``drive`` the known input term added to the next
    process output.  The filter runs on every sample; the prediction of ``z[k]`` is
    made at ``k - horizon`` from the filtered state then, with the known inputs in
    between and the load held (samples before the horizon get the one-step error).
    """
    n = z.shape[0]
    yf = np.empty(n)
    lf = np.empty(n)
    err = np.empty(n)
    yh = y0
    lh = 0.0
    for k in range(n):
        e = z[k] - yh
        err[k] = e
        yf[k] = yh + k1 * e
        lf[k] = lh + k2 * e
        yh = pole * yf[k] + lf[k] + drive[k]
        lh = lf[k]
    if horizon > 1 and n > horizon:
        _horizon_errors(z, yf, lf, drive, pole, horizon, err)
    return err


@jit
def _source_row(Zs, Es, i):  # pragma: no cover - compiled
    """Row ``i`` of ``Zs`` stacked on ``Es``."""
    nz = Zs.shape[0]
    return Zs[i] if i < nz else Es[i - nz]


@jit
def _slide(acc, pole, ph, x, k, horizon):  # pragma: no cover - compiled
    """The running sum of :func:`_horizon_errors` at step ``k``: summed afresh every
    ``_RESTART`` samples, else updated in O(1), with its operations."""
    if k % _RESTART == 0:
        acc = 0.0
        for i in range(horizon):
            acc = pole * acc + x[k + i]
        return acc
    return pole * acc - ph * x[k - 1] + x[k - 1 + horizon]


@jit
def _row_constants(Ds, di, pole, horizon):  # pragma: no cover - compiled
    """Per row: ``pole^h``, ``1 + pole + ... + pole^(h-1)`` and whether its drive
    moves, as :func:`_horizon_errors` computes them."""
    m = di.shape[0]
    ph = np.ones(m)
    geo = np.zeros(m)
    moving = np.zeros(m, dtype=np.bool_)
    for c in range(m):
        for _ in range(horizon):
            geo[c] = geo[c] * pole[c] + 1.0
            ph[c] *= pole[c]
        x = Ds[di[c]]
        for j in range(x.shape[0]):
            if x[j] != 0.0:
                moving[c] = True
                break
    return ph, geo, moving


@jit
def _prediction_errors_rows(
    Zs, Es, zi, Ds, di, y0, pole, k1, k2, horizon
):  # pragma: no cover - compiled
    """:func:`_prediction_errors` of the rows ``zi[c]`` of ``Zs`` then ``Es``
    (driven by ``Ds[di[c]]``, started at ``y0[c]``), each with its own filter
    (``pole[c]``, ``k1[c]``, ``k2[c]``): the rows of several filters (a grid of load
    ratios or poles) at once.

    Row ``c`` goes through the operations of :func:`_prediction_errors` and
    :func:`_horizon_errors` with its own filter, so it gets their numbers; the
    prediction of sample ``k + horizon`` is made at step ``k``, as the filter
    passes, so the filtered states are never stored.  The rows run four at a time
    with their states in registers: one filter's step waits on its previous step,
    so four independent ones cost little more than one (a group short of four
    repeats its last row, which writes the same numbers twice).  O(n m) for ``m``
    rows, for any horizon.
    """
    m = zi.shape[0]
    n = Zs.shape[1]
    h = horizon
    q = n - h if h > 1 and n > h else 0
    one = h if q > 0 else n  # samples that keep their one-step error
    ph, geo, mv = _row_constants(Ds, di, pole, h)
    err = np.empty((m, n))
    for g in range(0, m, 4):
        a, b, c, d = g, min(g + 1, m - 1), min(g + 2, m - 1), min(g + 3, m - 1)
        za, zb = _source_row(Zs, Es, zi[a]), _source_row(Zs, Es, zi[b])
        zc, zd = _source_row(Zs, Es, zi[c]), _source_row(Zs, Es, zi[d])
        xa, xb, xc, xd = Ds[di[a]], Ds[di[b]], Ds[di[c]], Ds[di[d]]
        pa, pb, pc, pd = pole[a], pole[b], pole[c], pole[d]
        ka, kb, kc, kd = k1[a], k1[b], k1[c], k1[d]
        qa, qb, qc, qd = k2[a], k2[b], k2[c], k2[d]
        ya, yb, yc, yd = y0[a], y0[b], y0[c], y0[d]
        la = lb = lc = ld = 0.0
        sa = sb = sc = sd = 0.0
        for k in range(n):
            ea = za[k] - ya
            eb = zb[k] - yb
            ec = zc[k] - yc
            ed = zd[k] - yd
            if k < one:
                err[a, k], err[b, k], err[c, k], err[d, k] = ea, eb, ec, ed
            fa = ya + ka * ea
            fb = yb + kb * eb
            fc = yc + kc * ec
            fd = yd + kd * ed
            la = la + qa * ea
            lb = lb + qb * eb
            lc = lc + qc * ec
            ld = ld + qd * ed
            if k < q:
                if mv[a]:
                    sa = _slide(sa, pa, ph[a], xa, k, h)
                if mv[b]:
                    sb = _slide(sb, pb, ph[b], xb, k, h)
                if mv[c]:
                    sc = _slide(sc, pc, ph[c], xc, k, h)
                if mv[d]:
                    sd = _slide(sd, pd, ph[d], xd, k, h)
                err[a, k + h] = za[k + h] - (ph[a] * fa + geo[a] * la + sa)
                err[b, k + h] = zb[k + h] - (ph[b] * fb + geo[b] * lb + sb)
                err[c, k + h] = zc[k + h] - (ph[c] * fc + geo[c] * lc + sc)
                err[d, k + h] = zd[k + h] - (ph[d] * fd + geo[d] * ld + sd)
            ya = pa * fa + la + xa[k]
            yb = pb * fb + lb + xb[k]
            yc = pc * fc + lc + xc[k]
            yd = pd * fd + ld + xd[k]
    return err


@_reduction
def _wdot(x, w, y):  # pragma: no cover - compiled
    """``sum_k (x[k] w[k]) y[k]``, the sum reassociated so that it runs in vector
    registers (the products are rounded as written; the rounding of the sum is that
    of an order of summation, as BLAS's blocks are).  O(n)."""
    s = 0.0
    for k in range(w.shape[0]):
        s += (x[k] * w[k]) * y[k]
    return s


@jit
def _shifted_wdot(x, si, y, sj, w):  # pragma: no cover - compiled
    """``sum_k (x[k - si] w[k]) y[k - sj]`` with ``x`` and ``y`` held at their first
    value before the record starts (:func:`~stictiondiag.core.filters.delayed`),
    summed as :func:`_wdot` sums.  O(n)."""
    n = w.shape[0]
    k0 = min(max(si, sj), n)
    head = 0.0
    for k in range(k0):
        xa = x[k - si] if k >= si else x[0]
        ya = y[k - sj] if k >= sj else y[0]
        head += (xa * w[k]) * ya
    return head + _wdot(x[k0 - si : n - si], w[k0:], y[k0 - sj : n - sj])


@jit
def shifted_grams(base, e0, w, shifts, ii, jj):  # pragma: no cover - compiled
    """The entries of the one-step grid's normal equations that its pairs use
    (:func:`stictiondiag.identification.predictor._pair_sse`): with ``x_s`` the
    input's response ``base`` delayed by ``shifts[s]``, ``G[s, s]`` and
    ``G[ii, jj] = G[jj, ii] = sum (x_ii w) x_jj`` of the Gram matrix, ``g[s] = sum
    (x_s w) e0`` and ``ee = sum (w e0) e0`` (the rest of ``G`` is 0).  O(n) per entry,
    about three per dead time, where the whole Gram matrix of the shifted rows costs
    O(n) per pair of shifts.
    """
    ns = shifts.shape[0]
    G = np.zeros((ns, ns))
    g = np.empty(ns)
    for s in range(ns):
        G[s, s] = _shifted_wdot(base, shifts[s], base, shifts[s], w)
        g[s] = _shifted_wdot(base, shifts[s], e0, 0, w)
    for t in range(ii.shape[0]):
        i, j = ii[t], jj[t]
        if i != j:
            G[i, j] = G[j, i] = _shifted_wdot(base, shifts[i], base, shifts[j], w)
    ee = _shifted_wdot(w, 0, e0, 0, e0)
    return G, g, ee


@jit
def _pair_residual(e0, base, delay, E, coef, w, r):  # pragma: no cover - compiled
    """``r = e0 + X coef`` for the regressors ``X`` of :func:`shifted_pair_wls` and its
    weighted sum of squares (:func:`_wdot`)."""
    n = e0.shape[0]
    c0, c1 = coef[0], coef[1]
    k0 = min(delay + 1, n)
    for k in range(k0):
        x0 = base[k - delay] if k >= delay else base[0]
        r[k] = e0[k] + x0 * c0 + base[0] * c1
    b0 = base[1 : n - delay]
    b1 = base[: n - delay - 1]
    for k in range(k0, n):
        i = k - k0
        r[k] = e0[k] + b0[i] * c0 + b1[i] * c1
    for i in range(E.shape[0]):
        c = coef[2 + i]
        Ei = E[i]
        for k in range(n):
            r[k] -= Ei[k] * c
    return _wdot(r, w, r)


@jit
def shifted_pair_wls(e0, base, delay, E, w):  # pragma: no cover - compiled
    """:func:`~stictiondiag.identification.numerics.fractional_delay_wls` of ``-e0`` on
    ``X = [delayed(base, delay), delayed(base, delay + 1), -E.T]``: ``(sse, coef,
    r)`` with ``r = e0 + X coef`` and ``sse`` its weighted sum of squares, in one
    compiled call and without building ``X``.

    The weighted normal equations hold the products ``(x_i w) x_j`` of
    :func:`~stictiondiag.identification.numerics.wls` (a negated column flips the
    sign of its sums exactly), summed in vector registers (:func:`_wdot`) instead of BLAS
    blocks (the same numbers to rounding); the system is solved as ``wls`` solves it
    (``_scaled_solve``), and when the two input gains have opposite signs the
    better single column (sub-systems of the same normal equations) replaces the
    pair.  O(n p^2) for ``p = 2 + len(E)`` columns, as ``fractional_delay_wls``; the
    Python-level cost of building ``X`` and the BLAS calls of a small system, which
    outweigh the arithmetic at these few columns, is gone.
    """
    n = e0.shape[0]
    m = E.shape[0]
    p = 2 + m
    A = np.empty((p, p))
    b = np.empty(p)
    shift = (delay, delay + 1)
    for i in range(2):
        b[i] = -_shifted_wdot(base, shift[i], e0, 0, w)
        for j in range(i, 2):
            A[i, j] = A[j, i] = _shifted_wdot(base, shift[i], base, shift[j], w)
        for j in range(m):
            A[i, 2 + j] = A[2 + j, i] = -_shifted_wdot(base, shift[i], E[j], 0, w)
    for i in range(m):
        b[2 + i] = _shifted_wdot(E[i], 0, e0, 0, w)
        for j in range(i, m):
            A[2 + i, 2 + j] = A[2 + j, 2 + i] = _shifted_wdot(E[i], 0, E[j], 0, w)
    coef = _scaled_solve(A, b)
    r = np.empty(n)
    if coef[0] * coef[1] < 0.0:
        best_sse = np.inf
        best = coef
        for drop in (1, 0):
            keep = np.array([j for j in range(p) if j != drop])
            c = np.zeros(p)
            c_keep = _scaled_solve(A[keep][:, keep], b[keep])
            for i in range(keep.shape[0]):
                c[keep[i]] = c_keep[i]
            sse = _pair_residual(e0, base, delay, E, c, w, r)
            # The first of equal (or unordered) sums, as fractional_delay_wls keeps.
            if drop == 1 or sse < best_sse:
                best_sse, best = sse, c
        coef = best
    sse = _pair_residual(e0, base, delay, E, coef, w, r)
    return sse, coef, r


# ------------------------------------------------------------------------------------
# The filter's algebra in Python: gains, prediction variances, innovation responses and
# the noise floor of a fitted replay (each over the compiled kernels above)
# ------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1024)
def kalman_gains(pole: float, load_ratio: float) -> tuple[float, float]:
    """Steady-state Kalman gains of the process-with-load model (remembered: the
    searches of a fit, and the fits of a loop, come back to the same filters).

    States: the process output ``y`` and an unmeasured load ``l`` (a random walk)
    entering with the valve: ``y[k+1] = a y[k] + b u[k-d] + l[k]``, ``l[k+1] = l[k] +
    v[k]``, measured ``pv = y + e``; ``load_ratio`` is var(v)/var(e).  Returns the
    gains of the filtered estimates of ``y`` and ``l`` on the innovation.
    """
    k1, k2, *_ = _riccati_gains(float(pole), float(load_ratio))
    return float(k1), float(k2)


def prediction_variance_ratio(pole: float, load_ratio: float, horizon: int) -> tuple[float, float]:
    """Variances of the one-step innovation and of the ``horizon``-step prediction error,
    in units of the measurement-noise variance, for the process-with-load model.

    A correct model's ``horizon``-step error variance is the second value times the
    measurement noise variance: measurement noise plus the load the filter could not
    foresee.
    """
    k1, k2, p11, p12, p22 = _riccati_gains(float(pole), float(load_ratio))
    s1 = p11 + 1.0
    # Filtered covariance.
    f11, f12, f22 = p11 - k1 * p11, p12 - k1 * p12, p22 - k2 * p12
    P = np.array([[f11, f12], [f12, f22]])
    F = np.array([[pole, 1.0], [0.0, 1.0]])
    Q = np.array([[0.0, 0.0], [0.0, load_ratio]])
    acc = np.zeros((2, 2))
    Fj = np.eye(2)
    for _ in range(max(int(horizon), 1)):
        acc += Fj @ Q @ Fj.T
        Fj = F @ Fj
    Pm = Fj @ P @ Fj.T + acc
    return float(s1), float(Pm[0, 0] + 1.0)


def extra_start(column: np.ndarray) -> float:
    """Initial state of the filter of an extra column (an output disturbance): its
    first value.

    The innovations are linear in the filtered signal and in the filter's initial
    state, so pv less a disturbance ``a c`` is filtered from ``pv[0] - a c[0]`` only
    if the column's own filter starts at ``c[0]`` (pv's starts at ``pv[0]``).  From
    0, the fitted disturbance's first value is an error the filter carries into the
    record as load, for as long as its tracking takes to forget it (on a slow filter,
    the first block of the record): a disturbance fitted on the other blocks then
    lost on the first one what it gained on all the others.
    """
    return float(column[0]) if column.size else 0.0


def _input_response(u: np.ndarray, model: ProcessModel, k1: float, k2: float) -> np.ndarray:
    """Innovation response to a unit gain on the input without dead time."""
    u0 = u - u[0]
    return _prediction_errors(
        np.zeros(u.size), np.ascontiguousarray(u0), model.pole, k1, k2, 0.0, model.horizon
    )


def _shifted_pair(base: np.ndarray, delay: int) -> np.ndarray:
    """``base`` delayed by ``delay`` and ``delay + 1`` samples, as two columns."""
    X = np.empty((base.size, 2))
    X[:, 0] = delayed(base, delay)
    X[:, 1] = delayed(base, delay + 1)
    return X


def process_regressors(u: np.ndarray, model: ProcessModel, k1: float, k2: float) -> np.ndarray:
    """Innovation responses to a unit gain on the input at two adjacent dead times."""
    response = _input_response(u, model, k1, k2)
    return _shifted_pair(response, model.delay)


def process_noise_floor(
    u: np.ndarray,
    pv: np.ndarray,
    w: np.ndarray,
    fit: ProcessFit,
    extra: np.ndarray | None = None,
) -> float:
    """Variance of the pv prediction error that a correct process replay still makes [pv^2].

    The measurement-noise variance is read from the one-step innovations of the fitted
    replay (their variance is a known multiple of it for the fitted load-to-noise
    ratio), and the horizon's error is that multiple of it again
    (:func:`prediction_variance_ratio`): measurement noise plus the load the filter
    could not foresee.
    """
    m = fit.prediction.model
    k1, k2 = kalman_gains(m.pole, m.load_ratio)
    r1, rm = prediction_variance_ratio(m.pole, m.load_ratio, m.horizon)
    pv = np.ascontiguousarray(pv, dtype=float)
    zeros = np.zeros(pv.size)
    one = ProcessModel(m.pole, m.delay, m.load_ratio, 1)
    # One-step innovations of the fitted replay: those of pv, plus the input's and
    # any extra column's responses times their fitted coefficients.
    e0 = _prediction_errors(pv, zeros, m.pole, k1, k2, float(pv[0]), 1)
    coef = fit.prediction.coef
    E = None
    if extra is not None and coef.size > 2:
        E = np.column_stack(
            [
                -_prediction_errors(
                    np.ascontiguousarray(c), zeros, m.pole, k1, k2, extra_start(c), 1
                )
                for c in np.atleast_2d(extra.T)
            ]
        )
    X = process_regressors(np.ascontiguousarray(u, dtype=float), one, k1, k2)
    if E is not None:
        X = np.column_stack([X, E])
    e1 = e0 + X @ coef[: X.shape[1]]
    s1 = float(np.dot(w, e1 * e1)) / max(float(w.sum()), 1.0)
    return s1 / r1 * rm
