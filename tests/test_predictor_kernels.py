"""The compiled kernels of the prediction-error fit give the numbers of the plain
computations they replace (stictiondiag.identification.predictor_kernels)."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.core.filters import delayed
from stictiondiag.identification.numerics import fractional_delay_wls
from stictiondiag.identification.predictor_kernels import (
    _prediction_errors,
    _prediction_errors_rows,
    kalman_gains,
    shifted_grams,
    shifted_pair_wls,
)


@pytest.mark.parametrize("m", [1, 3, 4, 6])
@pytest.mark.parametrize("horizon", [1, 7])
def test_rows_are_each_filter_alone_to_the_last_bit(m, horizon):
    """Each row with its own filter (pole, load ratio), driven or not, against
    ``_prediction_errors`` of that row alone: tolerance 0, since a row goes through
    the same operations in the same order whichever rows run beside it (a group
    short of four repeats its last row)."""
    rng = np.random.default_rng(11)
    n = 2500  # beyond two restarts of the horizon's running sum (every 1024 samples)
    Zs = np.stack([np.cumsum(rng.normal(size=n)), np.zeros(n)])
    Es = rng.normal(size=(1, n))
    sources = np.concatenate([Zs, Es])
    Ds = np.stack([np.zeros(n), np.cumsum(rng.normal(size=n)) * 0.1])
    zi = np.arange(m) % 3
    di = (np.arange(m) // 2) % 2
    pole = np.linspace(0.7, 1.0, m)
    ratio = np.geomspace(1e-6, 1e-1, m)
    gains = [kalman_gains(p, r) for p, r in zip(pole, ratio, strict=True)]
    k1 = np.array([g[0] for g in gains])
    k2 = np.array([g[1] for g in gains])
    y0 = rng.normal(size=m)
    got = _prediction_errors_rows(Zs, Es, zi, Ds, di, y0, pole, k1, k2, horizon)
    for c in range(m):
        ref = _prediction_errors(sources[zi[c]], Ds[di[c]], pole[c], k1[c], k2[c], y0[c], horizon)
        assert got[c].tolist() == ref.tolist()


def _plain_pair(e0, base, delay, E, w):
    X = np.column_stack([delayed(base, delay), delayed(base, delay + 1), -E.T])
    coef = fractional_delay_wls(X, -e0, w)
    r = e0 + X @ coef
    return float(np.dot(w, r * r)), coef, r


@pytest.mark.parametrize("n_extra", [0, 2, 4])
@pytest.mark.parametrize("differentiator", [False, True])
def test_shifted_pair_wls_is_fractional_delay_wls(n_extra, differentiator):
    """Against numpy's normal equations on the built regressors: the same products,
    summed in another order (some 1e-15 relative on n = 3000 terms), through the
    same scaled solve of a well-conditioned system: 1e-9 relative on the
    coefficients and the sum of squares, 1e-9 of pv's scale on the residuals.  With
    a differentiator in the data the pair's free gains have opposite signs and the
    better single column replaces them."""
    rng = np.random.default_rng(12 + n_extra)
    n, delay = 3000, 4
    base = np.cumsum(rng.normal(size=n))
    E = rng.normal(size=(n_extra, n))
    x0, x1 = delayed(base, delay), delayed(base, delay + 1)
    target = 3.0 * (x0 - x1) if differentiator else 0.6 * x0 + 0.3 * x1
    e0 = -(target - E.T @ np.linspace(0.5, 1.0, n_extra)) + 0.05 * rng.normal(size=n)
    w = (rng.random(n) > 0.1).astype(float)
    w[:50] = 0.0
    sse, coef, r = shifted_pair_wls(e0, base, delay, E, w)
    want_sse, want_coef, want_r = _plain_pair(e0, base, delay, E, w)
    if differentiator:
        assert coef[0] * coef[1] == 0.0
    np.testing.assert_allclose(coef, want_coef, rtol=1e-9, atol=1e-12)
    assert sse == pytest.approx(want_sse, rel=1e-9)
    np.testing.assert_allclose(r, want_r, rtol=0, atol=1e-9 * np.max(np.abs(e0)))


def test_shifted_grams_are_the_gram_entries_used():
    """The diagonal, the pairs' off-diagonal entries, the products with the
    innovations and their sum of squares, against BLAS on the shifted rows: the same
    products summed in another order, 1e-12 relative."""
    rng = np.random.default_rng(13)
    n = 2000
    base = np.cumsum(rng.normal(size=n)) + 5.0
    e0 = rng.normal(size=n)
    w = (rng.random(n) > 0.2).astype(float)
    shifts = np.array([0, 1, 2, 8, 9, 30, 31])
    ii, jj = np.array([0, 1, 3, 5]), np.array([1, 2, 4, 6])
    G, g, ee = shifted_grams(base, e0, w, shifts, ii, jj)
    Xs = np.stack([delayed(base, int(s)) for s in shifts])
    Xw = Xs * w
    want_G = Xw @ Xs.T
    np.testing.assert_allclose(np.diag(G), np.diag(want_G), rtol=1e-12)
    np.testing.assert_allclose(G[ii, jj], want_G[ii, jj], rtol=1e-12)
    np.testing.assert_allclose(G[jj, ii], want_G[ii, jj], rtol=1e-12)
    np.testing.assert_allclose(g, Xw @ e0, rtol=1e-12)
    assert ee == pytest.approx(float(np.dot(w * e0, e0)), rel=1e-12)
