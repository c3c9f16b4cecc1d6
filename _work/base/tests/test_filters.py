"""The scipy-free replacements on the analysis path agree with the scipy functions.

``stictiondiag.core.filters``, ``_stats`` and ``_optimize`` stand in for
:mod:`scipy.signal`, :mod:`scipy.ndimage`, :mod:`scipy.stats` and
:mod:`scipy.optimize`, whose imports cost more than the rest of a ``stiction
analyze`` run (ndimage: a tenth of a second).  Each replacement performs
scipy's own operations (or calls the same LAPACK/ndimage routines), so on this
platform the results are identical to the last bit; the tests allow 1e-12 relative
(to the scale of the output) so that only a real change of the computation fails,
not a compiler or BLAS build that rounds one operation differently.
:func:`correlate_lags` is the exception: it and scipy both correlate by FFT, whose
rounding errors scale with ``|v| |w|``, not with each lag's own value.

Also checked: the command-line entry point and the analysis modules do not import
the heavy packages at import time.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy import ndimage, optimize, signal, special, stats

import stictiondiag
from stictiondiag.core.filters import (
    convolve1d_constant,
    correlate_lags,
    detrend_linear,
    lfilter1,
    median_filter_nearest,
    savgol_smooth,
)
from stictiondiag.core.optimize import minimize_scalar_bounded
from stictiondiag.core.stats import mannwhitneyu

RTOL = 1e-12


def _close(actual, expected, rtol=RTOL):
    """Equal to ``rtol`` relative to the largest magnitude of ``expected``."""
    expected = np.asarray(expected, dtype=float)
    scale = max(float(np.max(np.abs(expected))), 1e-300) if expected.size else 1.0
    np.testing.assert_allclose(actual, expected, rtol=0.0, atol=rtol * scale)


@pytest.mark.parametrize("n", [1, 2, 17, 1000, 10_001])
def test_lfilter1_matches_scipy_lfilter(n):
    rng = np.random.default_rng(n)
    x = rng.standard_normal(n).cumsum()
    for a in (0.0, 0.3, 0.95, 0.9999):
        # first-order lag started in steady state (identify, effects)
        _close(
            lfilter1((1.0 - a,), -a, x, zi=a * x[0]),
            signal.lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])[0],
        )
        # gain and lag from rest (replay)
        _close(lfilter1((2.5 * (1.0 - a),), -a, x), signal.lfilter([2.5 * (1.0 - a)], [1.0, -a], x))
        # first-order high-pass (identify._highpass)
        _close(lfilter1((a, -a), -a, x), signal.lfilter([a, -a], [1.0, -a], x))


@pytest.mark.parametrize("n", [2, 3, 50, 8_640])
def test_detrend_linear_matches_scipy_detrend(n):
    rng = np.random.default_rng(n)
    x = 3.0 + 0.01 * np.arange(n) + rng.standard_normal(n)
    _close(detrend_linear(x), signal.detrend(x))


@pytest.mark.parametrize("n", [1, 5, 64, 1000, 10_000])
def test_correlate_lags_matches_scipy_correlate(n):
    rng = np.random.default_rng(n)
    v, w = rng.standard_normal(n).cumsum(), rng.standard_normal(n)
    d_max = n // 4
    expected = signal.correlate(v, w, mode="full", method="auto")[(n - 1) + np.arange(d_max + 1)]
    got = correlate_lags(v, w, d_max)
    np.testing.assert_allclose(
        got, expected, rtol=0.0, atol=RTOL * np.linalg.norm(v) * np.linalg.norm(w)
    )


@pytest.mark.parametrize(
    "n_v,n_w,max_lag", [(30_000, 30_000, 50), (30_000, 20_000, 7), (15_000, 20_000, 1200)]
)
def test_correlate_lags_in_blocks_matches_scipy_correlate(n_v, n_w, max_lag):
    # Few lags against a long w: correlated block by block (overlap-add), here 3-5
    # blocks with a partial last one, and v longer or shorter than w.  The block
    # sums round like one FFT or better: the same tolerance.
    rng = np.random.default_rng(n_v + max_lag)
    v, w = rng.standard_normal(n_v).cumsum(), rng.standard_normal(n_w)
    expected = signal.correlate(v, w, mode="full", method="fft")[(n_w - 1) + np.arange(max_lag + 1)]
    got = correlate_lags(v, w, max_lag)
    assert got.shape == (max_lag + 1,)
    np.testing.assert_allclose(
        got, expected, rtol=0.0, atol=RTOL * np.linalg.norm(v) * np.linalg.norm(w)
    )


@pytest.mark.parametrize("window,order", [(5, 3), (11, 3), (101, 3), (8, 2), (31, 0), (9, 5)])
def test_savgol_smooth_matches_scipy_savgol_filter(window, order):
    rng = np.random.default_rng(window)
    x = np.sin(np.arange(3000) / 40.0) + 0.1 * rng.standard_normal(3000)
    _close(savgol_smooth(x, window, order), signal.savgol_filter(x, window, order))
    short = x[:window]  # window as long as the record: only the edge fits
    _close(savgol_smooth(short, window, order), signal.savgol_filter(short, window, order))


def test_convolve1d_constant_matches_ndimage():
    # ndimage's loop and symmetry test, repeated: the same numbers to the last bit on
    # this platform (checked to 1e-12 here, like the others).
    rng = np.random.default_rng(7)
    for trial in range(400):
        size = int(rng.integers(1, 40))
        half = rng.standard_normal(size // 2)
        weights = [
            rng.standard_normal(size),
            np.concatenate([half, rng.standard_normal(size % 2), half[::-1]]),  # symmetric
            np.concatenate([half, np.zeros(size % 2), -half[::-1]]),  # antisymmetric
        ][trial % 3]
        x = rng.standard_normal(int(rng.integers(1, 500))).cumsum()
        _close(convolve1d_constant(x, weights), ndimage.convolve1d(x, weights, mode="constant"))


def _median_sorted_window(x, size):
    """The running median as the sorted-window kernel that
    ``median_filter_nearest`` used before (O(n size)): the record extended by its end
    values (``size // 2`` before, ``size - size // 2 - 1`` after, ndimage's centring
    of an even window), each window sorted, element ``size // 2`` taken."""
    x = np.asarray(x, dtype=float)
    before, after = size // 2, size - size // 2 - 1
    ext = np.concatenate([np.full(before, x[0]), x, np.full(after, x[-1])])
    windows = np.lib.stride_tricks.sliding_window_view(ext, size)
    return np.sort(windows, axis=1)[:, size // 2]


def test_median_filter_nearest_matches_the_sorted_window_and_ndimage():
    # A median picks a sample: the same numbers, exactly (no tolerance), for odd and
    # even windows, windows longer than the record, ties and the ends.
    rng = np.random.default_rng(8)
    for trial in range(300):
        n = int(rng.integers(1, 600))
        x = rng.standard_normal(n).cumsum()
        if trial % 3 == 0:
            x = np.round(x)  # ties
        size = int(rng.integers(1, 800))
        if trial % 2:
            size |= 1
        got = median_filter_nearest(x, size)
        np.testing.assert_array_equal(got, _median_sorted_window(x, size))
        np.testing.assert_array_equal(got, ndimage.median_filter(x, size=size, mode="nearest"))
    x = np.array([1.0, np.nan, 3.0, 2.0, 5.0])  # not finite: scipy's own
    for size in (3, 4):
        np.testing.assert_array_equal(
            median_filter_nearest(x, size), ndimage.median_filter(x, size=size, mode="nearest")
        )


def test_median_filter_nearest_long_record_quarter_window():
    # The window cycle_samples starts with (a quarter of the record) on a record long
    # enough that the old O(n size) kernel's cost showed; the reference in blocks of
    # output samples (its sorted windows would need n * size floats at once).
    rng = np.random.default_rng(3)
    n = 6000
    x = np.round(rng.standard_normal(n).cumsum(), 1)
    for size in (n // 4 | 1, n // 4 & ~1):  # odd and even
        got = median_filter_nearest(x, size)
        before, after = size // 2, size - size // 2 - 1
        ext = np.concatenate([np.full(before, x[0]), x, np.full(after, x[-1])])
        for k0 in range(0, n, 500):
            windows = np.lib.stride_tricks.sliding_window_view(ext[k0 : k0 + 500 + size - 1], size)
            np.testing.assert_array_equal(
                got[k0 : k0 + 500], np.sort(windows, axis=1)[:, size // 2]
            )


def test_mannwhitneyu_matches_scipy():
    rng = np.random.default_rng(0)
    for _ in range(300):
        n1, n2 = rng.integers(1, 30, 2)
        x = rng.standard_normal(n1)
        y = rng.standard_normal(n2) + rng.uniform(-1.0, 1.0)
        for kind in ("continuous", "rounded", "integers"):  # exact test; ties; many ties
            if kind == "rounded":
                x, y = np.round(x, 1), np.round(y, 1)
            elif kind == "integers":
                x = rng.integers(0, 4, n1).astype(float)
                y = rng.integers(0, 4, n2).astype(float)
            expected = stats.mannwhitneyu(x, y, alternative="two-sided")
            got = mannwhitneyu(x, y, alternative="two-sided")
            _close(got.statistic, expected.statistic)
            _close(got.pvalue, expected.pvalue)


def test_minimize_scalar_bounded_matches_scipy():
    rng = np.random.default_rng(1)
    for _ in range(200):
        c, s = rng.uniform(-3.0, 3.0), rng.uniform(0.1, 3.0)

        def f(g, c=c, s=s):
            return float(np.cos(g * s) + 0.1 * (g - c) ** 2 + 0.01 * np.sin(13.0 * g))

        lo = rng.uniform(-5.0, 0.0)
        hi = lo + rng.uniform(0.01, 6.0)
        res = optimize.minimize_scalar(
            f, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4}
        )
        x, fx = minimize_scalar_bounded(f, (lo, hi), xatol=1e-4)
        _close(x, res.x)
        _close(fx, res.fun)


@pytest.mark.parametrize("nu", [1.0, 3.5, 40.0, 1e4])
def test_fdtri_is_the_f_quantile(nu):
    # estimate.cost_threshold: scipy.stats.f.ppf(q, 1, nu) is scipy.special.fdtri(1, nu, q)
    _close(special.fdtri(1, nu, 0.95), stats.f.ppf(0.95, 1, nu))


@pytest.mark.parametrize("alpha", [0.05, 1e-3, 0.05 / 2016, 1e-9])
def test_chdtri_is_the_chi2_upper_quantile(alpha):
    # baselines.bicoherence_indices: scipy.stats.chi2.isf(alpha, 2) is scipy.special.chdtri(2, alpha)
    _close(special.chdtri(2, alpha), stats.chi2.isf(alpha, 2))


def test_lazy_package_namespace():
    assert set(stictiondiag.__all__) <= set(dir(stictiondiag))
    for name in stictiondiag.__all__:
        assert getattr(stictiondiag, name) is not None
    with pytest.raises(AttributeError):
        stictiondiag.no_such_name  # noqa: B018


def _imported(code: str) -> set[str]:
    """Top-level packages (and scipy sub-packages) a fresh interpreter has imported."""
    probe = (
        code + "\nimport sys\n"
        "print(' '.join(m for m in sys.modules if m.count('.') == 0 or m.startswith('scipy.')"
        " and m.count('.') == 1))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_cli_and_package_import_nothing_heavy():
    heavy = {"numpy", "scipy", "pandas", "numba", "matplotlib", "pyarrow"}
    assert not _imported("import cli.main") & heavy
    assert not _imported("import stictiondiag") & heavy


def test_analysis_path_imports_neither_scipy_signal_nor_stats():
    mods = (
        "analysis io.tags signals.oscillation stiction.segments stiction.valvefit stiction.verdict "
        "identification.controller identification.process replay models.loops stiction.hammerstein "
        "gap.effects gap.diagnose"
    )
    loaded = _imported("\n".join(f"import stictiondiag.{m}" for m in mods.split()))
    assert not loaded & {"scipy.signal", "scipy.stats", "scipy.optimize", "scipy.ndimage"}
