"""Searches over the stiction thresholds of a valve replay.

With a noisy demand each breakaway happens at the first noisy sample beyond the
threshold, so a replay is in step with the data only in a narrow region of S and J
(about 1 % of J) and off by whole slips elsewhere; the error is a rugged function
that defeats descent methods.  The searches therefore lay dense product grids over
the coupled thresholds (:func:`grid_search_nd`, :func:`needle_search`), evaluated
thousands of parameter sets per compiled call.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def needle_search(
    batch_cost: Callable[[np.ndarray, float], np.ndarray],
    x0: np.ndarray,
    pair: tuple[int, int],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    rel: float = 0.15,
    n_grid: int = 31,
    beam: int = 3,
    zooms: int = 2,
    floor: float | None = None,
) -> tuple[np.ndarray, float]:
    """Dense grid over two parameters, then zooming grids around the best few points.

    The replay error of a stiction model with a noisy demand is a rugged function of
    S and J: each breakaway happens at the first noisy sample beyond the threshold,
    so the replay matches the data only in a narrow region (about 1 % of J) and is
    off by whole slips elsewhere.  A descent method stalls on the steps; this search
    lays an ``n_grid x n_grid`` grid over ``+-rel`` of the starting values (at least
    ``+-rel floor``), keeps the ``beam`` best points and zooms around each to two of
    the previous steps either side, ``zooms`` times.  ``batch_cost(X, bound)``
    evaluates all rows of X in one compiled call and may abandon rows above
    ``bound``.  A pair ``(i, i)`` is a one-dimensional scan.

    Returns the best point and its cost.
    """
    i, j = pair
    x0 = np.clip(np.asarray(x0, dtype=float), lower, upper)
    best_c = float(batch_cost(x0[None, :], np.inf)[0])
    best_x = x0
    fl = max(abs(x0[i]), abs(x0[j])) if floor is None else floor

    def grid(x, hw_i, hw_j, m):
        gi = np.clip(np.linspace(x[i] - hw_i, x[i] + hw_i, m), lower[i], upper[i])
        if i == j:
            X = np.repeat(x[None, :], gi.size, axis=0)
            X[:, i] = gi
            return X
        gj = np.clip(np.linspace(x[j] - hw_j, x[j] + hw_j, m), lower[j], upper[j])
        GI, GJ = np.meshgrid(gi, gj, indexing="ij")
        X = np.repeat(x[None, :], GI.size, axis=0)
        X[:, i] = GI.ravel()
        X[:, j] = GJ.ravel()
        return X

    m0 = 4 * n_grid if i == j else n_grid
    hw_i = rel * max(abs(x0[i]), 0.5 * fl, 1e-6)
    hw_j = rel * max(abs(x0[j]), 0.5 * fl, 1e-6)
    X = grid(x0, hw_i, hw_j, m0 if i == j else n_grid)
    c = batch_cost(X, best_c)
    order = np.argsort(c)[:beam]
    if c[order[0]] < best_c:
        best_c, best_x = float(c[order[0]]), X[order[0]].copy()
    starts = [X[k].copy() for k in order]
    step_i = 2 * hw_i / max((m0 if i == j else n_grid) - 1, 1)
    step_j = 2 * hw_j / max(n_grid - 1, 1)
    for x in starts:
        si, sj = step_i, step_j
        for _ in range(zooms):
            m = 21 if i == j else 11
            Z = grid(x, 2 * si, 2 * sj, m)
            cz = batch_cost(Z, best_c)
            k = int(np.argmin(cz))
            x = Z[k].copy()
            if cz[k] < best_c:
                best_c, best_x = float(cz[k]), x
            si, sj = 4 * si / (m - 1), 4 * sj / (m - 1)
    return best_x, best_c


#: Stages of :func:`grid_search_nd` when starting from the measured slips, whose
#: S and J can be 30 % off for an asymmetric or time-varying valve (relative span,
#: values per parameter).
WIDE_STAGES = ((0.35, 15), (0.06, 7), (0.015, 5), (0.004, 5))


#: The same from the windowed fits of a time-varying valve, which start closer.
TVS_STAGES = ((0.25, 9), (0.06, 7), (0.015, 5), (0.004, 5))


def needle_from_seeds(
    batch_cost: Callable[[np.ndarray, float], np.ndarray],
    seeds,
    pair: tuple[int, int],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    rel: float = 0.15,
    zooms: int = 2,
) -> tuple[np.ndarray, float] | None:
    """The best of :func:`needle_search` started from each of ``seeds``: (x, cost), or
    None without seeds."""
    best = None
    for s in seeds:
        x, c = needle_search(
            batch_cost, np.asarray(s, dtype=float), pair, lower, upper, rel=rel, zooms=zooms
        )
        if best is None or c < best[1]:
            best = (x, c)
    return best


def grid_search_nd(
    batch_cost: Callable[[np.ndarray, float], np.ndarray],
    x0: np.ndarray,
    dims: tuple[int, ...],
    *,
    stages: tuple[tuple[float, int], ...] = ((0.12, 9), (0.03, 7), (0.008, 5)),
) -> tuple[np.ndarray, float]:
    """Coarse-to-fine product grid over several parameters at once, relative to x0.

    Stiction parameters of an augmented valve are coupled: with the closing S a
    little off, the replay misses the closing slips and the opening S and J cannot
    be found either.  Each stage lays a grid of ``steps`` values per parameter over
    ``+-span`` (relative) around the current point, all combinations at once (the
    compiled cost abandons the bad ones early), and recentres on the best.
    """
    x = np.asarray(x0, dtype=float).copy()
    best = float(batch_cost(x[None, :], np.inf)[0])
    dims = tuple(dims)
    for span, steps in stages:
        g = np.linspace(1.0 - span, 1.0 + span, steps)
        mesh = np.meshgrid(*([g] * len(dims)), indexing="ij")
        F = np.column_stack([m.ravel() for m in mesh])
        X = np.repeat(x[None, :], F.shape[0], axis=0)
        # Offsets relative to each value, but at least to a third of the largest one
        # (a J near zero still moves).
        xd = np.abs(x[list(dims)])
        scale = np.maximum(xd, max(0.3 * float(xd.max()), 1e-3))
        X[:, list(dims)] = x[list(dims)] + (F - 1.0) * scale
        X = np.maximum(X, 0.0)
        # Nearest points first: a good early bound makes the rest cheap.
        X = X[np.argsort(np.abs(F - 1.0).sum(axis=1))]
        c = batch_cost(X, best)
        k = int(np.argmin(c))
        if c[k] < best:
            best, x = float(c[k]), X[k].copy()
    return x, best
