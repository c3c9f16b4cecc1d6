"""The cheaper kernels give the numbers of the direct computations they replace.

Each faster form is compared with the plain computation it stands for, written out
here: the horizon predictions stepped sample by sample, least squares by numpy's
lstsq, the one-sign fit column by column, the threaded batch cost against the
serial one.
"""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.identification.numerics import fractional_delay_wls, wls
from stictiondiag.identification.predictor import _pair_sse
from stictiondiag.identification.predictor_kernels import (
    _prediction_errors,
    _prediction_errors_rows,
    kalman_gains,
)
from stictiondiag.stiction.hammerstein import columns as hc
from stictiondiag.stiction.hammerstein import kernels as hk


def _stepped_errors(z, drive, pole, k1, k2, y0, horizon):
    """The horizon predictions by stepping each one ``horizon`` times (O(n h))."""
    n = z.size
    yf, lf, err = np.empty(n), np.empty(n), np.empty(n)
    yh, lh = y0, 0.0
    for k in range(n):
        e = z[k] - yh
        err[k] = e
        yf[k] = yh + k1 * e
        lf[k] = lh + k2 * e
        yh = pole * yf[k] + lf[k] + drive[k]
        lh = lf[k]
    for j in range(n - horizon):
        y = yf[j]
        for i in range(horizon):
            y = pole * y + lf[j] + drive[j + i]
        err[j + horizon] = z[j + horizon] - y
    return err


@pytest.mark.parametrize("pole", [0.8, 0.99, 1.0])
@pytest.mark.parametrize("horizon", [1, 2, 7, 60])
def test_horizon_errors_match_stepped_predictions(pole, horizon):
    rng = np.random.default_rng(3)
    n = 3000  # three restarts of the running sum (every 1024 samples)
    z = np.cumsum(rng.normal(size=n))
    drive = np.cumsum(rng.normal(size=n)) * 0.1
    k1, k2 = kalman_gains(pole, 1e-3)
    ref = _stepped_errors(z, drive, pole, k1, k2, z[0], horizon)
    got = _prediction_errors(z, drive, pole, k1, k2, z[0], horizon)
    many = _prediction_errors_rows(
        np.stack([z]),
        np.zeros((0, n)),
        np.array([0, 0]),
        np.stack([drive, np.zeros(n)]),
        np.array([0, 1]),
        np.array([z[0], z[0]]),
        np.full(2, pole),
        np.full(2, k1),
        np.full(2, k2),
        horizon,
    )
    # Rounding only: the running sum adds and removes terms instead of summing
    # afresh, a few ulps of the largest value per restart interval.
    tol = 1e-11 * np.max(np.abs(ref))
    np.testing.assert_allclose(got, ref, rtol=0, atol=tol)
    np.testing.assert_allclose(many[0], ref, rtol=0, atol=tol)
    undriven = _stepped_errors(z, np.zeros(n), pole, k1, k2, z[0], horizon)
    np.testing.assert_allclose(many[1], undriven, rtol=0, atol=tol)


def test_wls_matches_lstsq():
    rng = np.random.default_rng(4)
    X = rng.normal(size=(500, 4))
    y = X @ np.array([1.0, -2.0, 0.5, 3.0]) + 0.1 * rng.normal(size=500)
    w = (rng.random(500) > 0.2).astype(float)
    sw = np.sqrt(w)
    ref, *_ = np.linalg.lstsq(X * sw[:, None], y * sw, rcond=None)
    # Normal equations of a well-conditioned problem with a 1e-10 ridge: 1e-8 relative.
    np.testing.assert_allclose(wls(X, y, w), ref, rtol=1e-8)


def test_fractional_delay_wls_keeps_one_sign():
    rng = np.random.default_rng(5)
    u = np.cumsum(rng.normal(size=800))
    X = np.column_stack([u, np.r_[u[0], u[:-1]], rng.normal(size=800)])
    # A differentiator: opposite weights on the two delayed columns.
    y = 3.0 * (X[:, 0] - X[:, 1]) + 0.5 * X[:, 2] + 0.01 * rng.normal(size=800)
    w = np.ones(800)
    coef = fractional_delay_wls(X, y, w)
    assert coef[0] * coef[1] >= 0.0
    # The better single column, solved directly.
    best = None
    for keep in ([0, 2], [1, 2]):
        c = np.zeros(3)
        c[keep], *_ = np.linalg.lstsq(X[:, keep], y, rcond=None)
        sse = float(np.sum((y - X @ c) ** 2))
        if best is None or sse < best[0]:
            best = (sse, c)
    np.testing.assert_allclose(coef, best[1], rtol=1e-7, atol=1e-9)


def test_pair_sse_matches_solve():
    rng = np.random.default_rng(6)
    M = rng.normal(size=(6, 200))
    e0 = rng.normal(size=200)
    G, g, ee = M @ M.T, M @ e0, float(e0 @ e0)
    ii, jj = np.array([0, 1, 2, 3, 4]), np.array([1, 2, 3, 4, 5])
    got = _pair_sse(G, g, ee, ii, jj)
    for k, (i, j) in enumerate(zip(ii, jj, strict=True)):
        A = np.array([[G[i, i], G[i, j]], [G[j, i], G[j, j]]])
        rhs = -np.array([g[i], g[j]])
        coef = np.linalg.solve(A, rhs)
        if coef[0] * coef[1] < 0.0:
            coef = max(
                (np.array([rhs[0] / A[0, 0], 0.0]), np.array([0.0, rhs[1] / A[1, 1]])),
                key=lambda c: float(rhs @ c),
            )
        # Cramer's rule against LU of a 2 x 2 system: rounding only.
        assert got[k] == pytest.approx(ee - float(rhs @ coef), rel=1e-9)


def test_same_sign_fit_many_equals_column_by_column():
    rng = np.random.default_rng(7)
    P = rng.normal(size=(300, 5))
    A = P.T @ P
    Y = rng.normal(size=(300, 6)) + P[:, :1] * np.linspace(-1, 1, 6)
    B = P.T @ Y
    yy = np.sum(Y**2, axis=0)
    out = np.empty(6)
    hk.same_sign_fit_many(A, B, yy, 2, 0, out)
    ref = [hk.same_sign_fit(A, np.ascontiguousarray(B[:, k]), yy[k], 2, 0) for k in range(6)]
    # The same operations per active set: equal to the last bit (no set ties with
    # the full one here, where the shortcut could differ by rounding).
    assert out.tolist() == ref
    # Both cases are covered: columns whose unconstrained fit has gains of one sign
    # (done after the full set) and columns that need the smaller sets.
    free = yy - np.einsum("ij,ij->j", B, np.linalg.solve(A, B))
    feasible = np.isclose(out, free, rtol=1e-12)
    assert feasible.any() and not feasible.all()


#: The time constant whose pole is the high-pass pole 0.97 of the test below.
_TAU_AT_HIGHPASS = -1.0 / np.log(0.97)


@pytest.mark.parametrize(
    "taus",
    [
        np.geomspace(2.0, 90.0, 1),
        np.geomspace(2.0, 90.0, 3),
        np.geomspace(2.0, 90.0, 4),
        np.geomspace(2.0, 90.0, 5),
        np.geomspace(2.0, 90.0, 9),
        # At and next to the high-pass pole: the chained recursions take over there,
        # and just outside their range the partial fractions still hold.
        np.array([5.0, _TAU_AT_HIGHPASS, 60.0]),
        np.array([_TAU_AT_HIGHPASS * (1 + 1e-3), _TAU_AT_HIGHPASS * (1 - 1e-3)]),
        np.array([0.0, 3.0]),
    ],
    ids=["1", "3", "4", "5", "9", "at-highpass", "near-highpass", "tau-0"],
)
def test_normal_equations_match_the_columns_one_at_a_time(taus):
    """The four-at-a-time recursions (partial fractions, or the chained lag and
    high-pass for a pole at the high-pass's) give the columns of :func:`regressors`
    (one time constant at a time, the lag and the high-pass chained) at the kept
    rows.  The partial fractions round differently, by at most ``(1 - b) / |b - a|``
    times the last bit (at most 2e3 here, 1e-4 relative pole separation at the
    worst), and numba and numpy may call the matrix product differently: compared
    within 1e-11 of the products' size."""
    rng = np.random.default_rng(5)
    n, k0, j0, j1, stride = 3000, 20, 40, 2900, 3
    u = np.cumsum(rng.normal(size=n))
    rows_all = np.arange(j0, j1, stride)
    keep = rng.random(rows_all.size) > 0.2
    rows = rows_all[keep]
    Y = np.ascontiguousarray(rng.normal(size=(rows.size, 4)))
    D = np.zeros((rows.size, 0))
    A, B = hc.normal_equations(u, taus, 0.97, k0, j0, j1, stride, keep, Y, D)
    for t, tau in enumerate(taus):
        P = hc.regressors(u, tau, 0.97, k0)[rows]
        At = P.T @ P
        At[np.diag_indices(hc.NCOL)] += 1e-10 * np.trace(At) / hc.NCOL + 1e-300
        scale = np.abs(At).max()
        np.testing.assert_allclose(A[t], At, rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(B[t], P.T @ Y, rtol=0, atol=1e-11 * np.abs(P.T @ Y).max())


def test_threaded_batch_cost_equals_serial():
    rng = np.random.default_rng(8)
    n = 1500
    x = 50.0 + np.cumsum(rng.normal(size=n)) * 0.3
    yf = np.cumsum(rng.normal(size=n + 20)) * 0.1
    prob = hk.Problem(x, yf, [5.0, 20.0], 0.9, 10, 0.0, 20, n - 20, 2, np.array([1, 3, 5]))
    S = np.linspace(0.0, 3.0, 7)
    J = np.linspace(0.0, 1.0, 7)
    args = (
        x,
        S,
        J,
        np.array([0.0, 0.5]),
        prob.taus,
        True,
        prob.k_start,
        prob.d_start,
        prob.a_hp,
        prob.j0,
        prob.j1,
        prob.stride,
        prob.keep,
        prob.Y,
        prob.yy,
        0.0,
        prob.D,
        0,
    )
    serial = hk.batch_cost(*args)
    threaded = hk.batch_cost_threaded(*args)
    for a, b in zip(serial, threaded, strict=True):
        assert a.tolist() == b.tolist()  # each pair computed alone: the same numbers


def test_kernel_threads_setting(monkeypatch):
    monkeypatch.delenv(hk.THREADS_VARIABLE, raising=False)
    assert hk.kernel_threads() == 1
    monkeypatch.setenv(hk.THREADS_VARIABLE, "not a number")
    assert hk.kernel_threads() == 1
    monkeypatch.setenv(hk.THREADS_VARIABLE, "64")
    import numba

    assert hk.kernel_threads() == min(64, numba.config.NUMBA_NUM_THREADS)


def _small_problem(seed: int = 8):
    rng = np.random.default_rng(seed)
    n = 1500
    x = 50.0 + np.cumsum(rng.normal(size=n)) * 0.3
    yf = np.cumsum(rng.normal(size=n + 20)) * 0.1
    return hk.Problem(x, yf, [5.0, 20.0], 0.9, 10, 0.0, 20, n - 20, 2, np.array([1, 3, 5]))


def test_pairs_seen_before_are_not_computed_again(monkeypatch):
    """A pair evaluated before in the same state returns the numbers a fresh problem
    computes (to the bit), without running the kernel for it again; a change of
    state (time constants, rows kept) computes afresh."""
    from stictiondiag.stiction.valvefit import ValveVariant

    v = ValveVariant("kano", True)
    off = np.array([0.0, 0.5])
    S, J = np.array([0.5, 1.0, 1.5]), np.array([0.2, 0.4, 0.2])
    prob = _small_problem()
    computed: list[int] = []
    kernel = hk.Problem._kernel_cost

    def counting(self, S_, J_, variant, o):
        if self is prob:
            computed.append(S_.size)
        return kernel(self, S_, J_, variant, o)

    monkeypatch.setattr(hk.Problem, "_kernel_cost", counting)
    first = prob.cost(S, J, v, off)
    again = prob.cost(np.array([1.0, 2.0, 1.0]), np.array([0.4, 0.1, 0.4]), v, off)
    assert computed == [3, 1]  # only (2.0, 0.1) is new; a repeat within a call counts once
    fresh = _small_problem().cost(np.array([1.0, 2.0]), np.array([0.4, 0.1]), v, off)
    # cost, dead time, start offset, time constant of each pair
    for a, b, f in zip(first, again, fresh, strict=True):
        assert b[0] == b[2] == a[1] == f[0]  # (1.0, 0.4), remembered
        assert b[1] == f[1]  # (2.0, 0.1), computed
    prob.taus = np.array([7.0])
    prob.cost(S[:1], J[:1], v, off)
    keep = np.ones(prob.all_rows.size, dtype=bool)
    keep[:50] = False
    prob.set_keep(keep)
    after = prob.cost(S[:1], J[:1], v, off)
    assert computed == [3, 1, 1, 1]
    ref = _small_problem()
    ref.taus = np.array([7.0])
    ref.set_keep(keep)
    assert [a.tolist() for a in after] == [r.tolist() for r in ref.cost(S[:1], J[:1], v, off)]


def test_process_fit_shares_its_filter_sums_to_the_last_bit():
    """The FOPTD fit computes the filter's free response and its prefix sums once
    for all its scans and fits: the same numbers as computed afresh in each."""
    from stictiondiag.identification import process as ip

    rng = np.random.default_rng(12)
    n = 4000
    u = np.cumsum(rng.normal(size=n))
    y_f = ip.highpass(np.cumsum(rng.normal(size=n)), 0.995)
    b = 0.995
    sums = ip.FilterSums.of(y_f, b)
    for a in (0.5, 0.9, 0.999):
        alone = ip.oe_delay_scan(u, y_f, a, b, 300)
        shared = ip.oe_delay_scan(u, y_f, a, b, 300, sums)
        assert alone.tolist() == shared.tolist()
        for d in (0, 7, 300):
            m0, c0 = ip.foptd_oe(u, y_f, d, a, b)
            m1, c1 = ip.foptd_oe(u, y_f, d, a, b, sums.q)
            assert m0 == m1 and c0.tolist() == c1.tolist()
