"""The one-step structure grid gives the numbers of its plain form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stictiondiag.core.filters import delayed
from stictiondiag.identification.predictor import (
    ProcessModel,
    _pair_sse,
    _structure_grid,
)
from stictiondiag.identification.predictor_kernels import _prediction_errors, kalman_gains


def _plain_grid(u, pv, w):
    """The grid with every shifted regressor row built by ``delayed`` and stacked
    (the form :func:`_structure_grid` replaces with one gather)."""
    n = u.size
    zeros = np.zeros(n)
    taus = np.geomspace(0.5, max(n / 8.0, 2.0), 14)
    pole_grid = np.concatenate([np.exp(-1.0 / taus), [1.0]])
    d_max = int(min(max(n // 10, 5), 200))
    d_grid = np.unique(
        np.concatenate(
            [np.arange(0, min(d_max, 8)), np.geomspace(8, max(d_max, 9), 10).astype(int)]
        )
    )
    shifts = np.unique(np.concatenate([d_grid, d_grid + 1]))
    where = {int(d): i for i, d in enumerate(shifts)}
    ii = np.array([where[int(d)] for d in d_grid])
    jj = np.array([where[int(d) + 1] for d in d_grid])
    best, per_pole = None, {}
    for pole in pole_grid:
        for lr in (1e-6, 1e-4, 1e-3, 1e-2, 1e-1):
            k1, k2 = kalman_gains(pole, lr)
            e0 = _prediction_errors(pv, zeros, pole, k1, k2, float(pv[0]), 1)
            base = _prediction_errors(zeros, np.ascontiguousarray(u - u[0]), pole, k1, k2, 0.0, 1)
            Xs = np.stack([delayed(base, int(d)) for d in shifts])
            Xw = Xs * w
            sse = _pair_sse(Xw @ Xs.T, Xw @ e0, float(np.dot(w * e0, e0)), ii, jj)
            k = int(np.argmin(sse))
            if not math.isfinite(sse[k]):
                continue
            cand = (float(sse[k]), ProcessModel(float(pole), int(d_grid[k]), float(lr)))
            if best is None or cand[0] < best[0]:
                best = cand
            if pole not in per_pole or cand[0] < per_pole[pole][0]:
                per_pole[pole] = cand
    return best, per_pole, d_grid


def test_structure_grid_is_its_plain_form():
    """Same best structure and best per pole, the same sums of squares to 1e-12
    relative: the filtered rows are the very numbers of ``_prediction_errors`` (the
    rows of several filters run side by side with each row's own operations), and
    the Gram entries the pairs use are the same products ``(x_i w) x_j`` summed in
    another order than BLAS sums them (rounding of n = 1500 terms, some 1e-14
    relative; the sums of squares are differences of such sums, a few hundred times
    smaller than them at most here).  A record with a dead time of 6 samples whose
    regressors start away from zero, with some samples weighted out."""
    rng = np.random.default_rng(7)
    n = 1500
    u = np.cumsum(rng.standard_normal(n)) * 0.1 + 3.0
    pv = np.convolve(delayed(u, 6), np.full(12, 1.0 / 12))[:n] + 0.05 * rng.standard_normal(n)
    w = (rng.random(n) > 0.1).astype(float)
    best, per_pole, d_grid = _structure_grid(u, pv, w)
    want_best, want_per_pole, want_d = _plain_grid(u, pv, w)
    assert best[1] == want_best[1]
    assert best[0] == pytest.approx(want_best[0], rel=1e-12)
    assert per_pole.keys() == want_per_pole.keys()
    for pole, (sse, model) in per_pole.items():
        assert model == want_per_pole[pole][1]
        assert sse == pytest.approx(want_per_pole[pole][0], rel=1e-12)
    np.testing.assert_array_equal(d_grid, want_d)
    assert best[1].delay > 0  # the dead times beyond 0 (shifted rows) took part
