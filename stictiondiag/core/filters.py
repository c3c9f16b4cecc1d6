"""Filters of one signal: the first-order responses the process fit simulates, and
drop-in replacements for the few :mod:`scipy.signal` and :mod:`scipy.ndimage` calls
on the analysis path.

The first-order responses (:func:`lfilter1`, :func:`delayed`, :func:`powers`,
:func:`lag_response`, :func:`integrating_regressors`, :func:`highpass`) are the
discrete responses of the FOPTD and the integrating process (Choudhury, Thornhill &
Shah 2005, Eq. 3, Table 3, exact zero-order hold) and the drift high-pass its output-error fit compares model and data after
(:mod:`stictiondiag.identification.process`).

Importing :mod:`scipy.signal` costs more than a second (it pulls in
:mod:`scipy.stats`), longer than a whole ``stiction analyze`` of a short loop
otherwise needs; :mod:`scipy.ndimage` about 0.1 s (its array-API layer parses
every function's docstring at import).  The functions here compute the same numbers
with numpy, numba kernels and :mod:`scipy.linalg`, which the analysis loads anyway
(numba itself imports it); ``tests/test_filters.py`` checks each against the scipy
function it replaces.  The running median is the exception: it calls
:func:`scipy.ndimage.median_filter` (imported at its first call), whose
O(n log w) rank filter no simple kernel here matches.
"""

from __future__ import annotations

import math

import numpy as np

from stictiondiag.core.jit import jit


@jit
def _lfilter1(b0, b1, a1, x, z0):
    # Direct form II transposed, the operations of scipy's lfilter in their order:
    # y = z + b0 x, then z = b1 x - a1 y.
    y = np.empty(x.shape[0])
    z = z0
    for k in range(x.shape[0]):
        yk = z + b0 * x[k]
        y[k] = yk
        z = x[k] * b1 - yk * a1
    return y


def lfilter1(b: tuple[float, ...], a1: float, x: np.ndarray, zi: float = 0.0) -> np.ndarray:
    """``scipy.signal.lfilter(b, [1, a1], x, zi=[zi])[0]`` for a first-order filter.

    ``b`` holds one or two numerator coefficients; the denominator is monic.  The
    kernel performs scipy's operations in scipy's order, so the output is the same
    to the last bit (the final filter state is not returned).
    """
    b0 = float(b[0])
    b1 = float(b[1]) if len(b) > 1 else 0.0
    x = np.ascontiguousarray(x, dtype=float)
    return _lfilter1(b0, b1, float(a1), x, float(zi))


def delayed(u: np.ndarray, shift: int) -> np.ndarray:
    """``u[k - shift]``, held at ``u[0]`` before the record starts."""
    if shift <= 0:
        return u
    out = np.empty_like(u)
    out[:shift] = u[0]
    out[shift:] = u[: u.size - shift]
    return out


#: ``a^k`` with ``k ln a < UNDERFLOW_LOG`` is below 2^-1080, a 64th of the smallest
#: subnormal double: it rounds to 0 [-].
UNDERFLOW_LOG = -1080.0 * math.log(2.0)


def powers(a: float, start: int, stop: int) -> np.ndarray:
    """``a ** np.arange(start, stop)``, the same numbers, for a pole ``0 <= a <= 1``.

    Powers far below the smallest subnormal are zero whatever the rounding and are
    not computed: pow's underflow path costs ten times its normal one, and the
    free responses of a fast pole (``a^k`` for a time constant of a few samples)
    underflow after a few thousand samples, so on a long record almost every
    power took that path.  O(n), about 5 ns per computed power.
    """
    k = np.arange(start, stop)
    if not 0.0 < a < 1.0:
        return a**k
    last = math.ceil(UNDERFLOW_LOG / math.log(a))  # a^k == 0 from k = last on
    m = min(max(last - start, 0), k.size)
    out = np.zeros(k.size)
    out[:m] = a ** k[:m]
    return out


def lag_response(u: np.ndarray, d: int, a: float) -> np.ndarray:
    """``z[k+1] = a z[k] + (1 - a) u[k - d]``, ``z[0] = u[0]``: first-order lag with
    dead time ``d`` samples (exact zero-order-hold discretisation of the FOPTD)."""
    x = delayed(u, d + 1)
    return lfilter1((1.0 - a,), -a, x, zi=a * u[0])


def integrating_regressors(u: np.ndarray, d: int, dt: float) -> np.ndarray:
    """Columns [1, dt sum_{j<k} u[j-d], dt k] of the simulated integrator response."""
    x = delayed(u, d + 1)
    x[0] = 0.0
    k = np.arange(u.size)
    return np.column_stack([np.ones(u.size), dt * np.cumsum(x), dt * k])


def highpass(x: np.ndarray, b: float) -> np.ndarray:
    """First-order high-pass ``y[k] = b (y[k-1] + x[k] - x[k-1])`` with pole ``b``,
    started at rest at ``x[0]`` (``y[0] = 0``); ``b = 1`` only removes ``x[0]``."""
    x = np.asarray(x, dtype=float) - x[0]
    if b >= 1.0:
        return x
    return lfilter1((b, -b), -b, x)


def detrend_linear(x: np.ndarray) -> np.ndarray:
    """``scipy.signal.detrend(x)`` (type ``'linear'``, no breakpoints) of a 1-D signal.

    The same least-squares problem as scipy's (regressors ``k / n`` and 1, solved by
    LAPACK ``gelsd``), so the result agrees to rounding.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    a = np.ones((n, 2))
    a[:, 0] = np.arange(1, n + 1, dtype=float) / n
    coef = np.linalg.lstsq(a, x, rcond=None)[0]
    return x - a @ coef


def _fast_length(m: int) -> int:
    """Smallest ``2^i 3^j 5^k >= m`` (a size the FFT handles quickly)."""
    best = 1 << max(0, (m - 1).bit_length())
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            p = p35
            while p < m:
                p *= 2
            best = min(best, p)
            p35 *= 3
        p5 *= 5
    return best


#: :func:`correlate_lags` splits ``w`` into blocks of at least this many samples ...
CORRELATE_MIN_BLOCK = 4096
#: ... and of at least this many times the number of lags asked for [-].
CORRELATE_BLOCK_LAGS = 4


def correlate_lags(v: np.ndarray, w: np.ndarray, max_lag: int) -> np.ndarray:
    """``c[d] = sum_k v[k] w[k - d]`` for ``d = 0 .. max_lag`` (real 1-D inputs).

    Equals ``scipy.signal.correlate(v, w, mode="full")[w.size - 1 + d]``; computed,
    like scipy's choice for long signals, by FFT, so both carry rounding errors of
    order ``eps * |v| |w|`` (not relative to each lag's own value).

    Cost: one FFT of ``v.size + w.size`` samples, O(n log n), when the lags asked for
    span a good part of the signal.  When they are few against the signal (``w``
    longer than two blocks of ``max(CORRELATE_MIN_BLOCK, CORRELATE_BLOCK_LAGS *
    (max_lag + 1))`` samples), ``w`` is cut into such blocks and each block
    correlated, by one batched FFT of about ``block + max_lag`` samples, with the
    stretch of ``v`` it meets at those lags (overlap-add; the circular correlation
    does not wrap onto lags ``0 .. max_lag`` because the FFT is at least
    ``block + max_lag`` long): O(n log max_lag) time, linear in the signal for a
    fixed number of lags, and O(n) memory.  The block sums differ from the single
    FFT's only by rounding (smaller: each block's error scales with its own norms).
    """
    v = np.asarray(v, dtype=float)
    w = np.asarray(w, dtype=float)
    max_lag = int(max_lag)
    block = max(CORRELATE_MIN_BLOCK, CORRELATE_BLOCK_LAGS * (max_lag + 1))
    if w.size <= 2 * block or max_lag < 0:
        length = _fast_length(v.size + w.size - 1)
        c = np.fft.irfft(np.fft.rfft(v, length) * np.conj(np.fft.rfft(w, length)), length)
        return c[: max_lag + 1]
    n_blocks = -(-w.size // block)
    w_flat = np.zeros(n_blocks * block)
    w_flat[: w.size] = w
    w_blocks = w_flat.reshape(n_blocks, block)
    # Block j (w[j B .. j B + B - 1]) meets v[j B .. j B + B - 1 + max_lag].
    span = block + max_lag
    v_pad = np.zeros(n_blocks * block + max_lag)
    m = min(v.size, v_pad.size)
    v_pad[:m] = v[:m]
    v_blocks = np.lib.stride_tricks.sliding_window_view(v_pad, span)[::block]
    length = _fast_length(span)
    spectra = np.fft.rfft(v_blocks, length, axis=1) * np.conj(np.fft.rfft(w_blocks, length, axis=1))
    return np.fft.irfft(spectra, length, axis=1)[:, : max_lag + 1].sum(axis=0)


def _polyfit_edge(t: np.ndarray, x: np.ndarray, order: int) -> np.ndarray:
    """Polynomial coefficients (highest power first) as scipy 1.17's
    ``scipy.signal._polyutils.polyfit``: column-scaled Vandermonde, ``scipy.linalg.lstsq``."""
    from scipy.linalg import lstsq

    powers = np.arange(order + 1, dtype=float)[::-1]
    lhs = t[:, None] ** powers[None, :]
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    c = lstsq(lhs, x, cond=t.shape[0] * np.finfo(float).eps)[0]
    return (c.T / scale).T


#: DBL_EPSILON, the tolerance of ndimage's symmetry test of a filter.
_DBL_EPSILON = float(np.finfo(float).eps)


@jit
def _correlate_constant(x, w, origin):
    # scipy.ndimage's NI_Correlate1D on one line padded with zeros (mode "constant",
    # cval 0): the same symmetry test and the same operations in the same order.
    n = x.shape[0]
    fs = w.shape[0]
    size1 = fs // 2
    size2 = fs - size1 - 1
    symmetric = 0
    if fs & 1:
        symmetric = 1
        for i in range(1, fs // 2 + 1):
            if abs(w[i + size1] - w[size1 - i]) > _DBL_EPSILON:
                symmetric = 0
                break
        if symmetric == 0:
            symmetric = -1
            for i in range(1, fs // 2 + 1):
                if abs(w[size1 + i] + w[size1 - i]) > _DBL_EPSILON:
                    symmetric = 0
                    break
    before = size1 + origin
    buf = np.zeros(n + before + size2 - origin)
    buf[before : before + n] = x
    out = np.empty(n)
    for k in range(n):
        c = size1 + k  # the centre sample in the padded line
        if symmetric > 0:
            acc = buf[c] * w[size1]
            for j in range(-size1, 0):
                acc += (buf[c + j] + buf[c - j]) * w[size1 + j]
        elif symmetric < 0:
            acc = buf[c] * w[size1]
            for j in range(-size1, 0):
                acc += (buf[c + j] - buf[c - j]) * w[size1 + j]
        else:
            acc = buf[c + size2] * w[size1 + size2]
            for j in range(-size1, size2):
                acc += buf[c + j] * w[size1 + j]
        out[k] = acc
    return out


def convolve1d_constant(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``scipy.ndimage.convolve1d(x, weights, mode="constant")`` of a 1-D signal.

    ndimage's own loop (:func:`_correlate_constant`) on the reversed weights, with
    the origin ndimage gives a convolution; the same numbers to the last bit.
    """
    x = np.ascontiguousarray(x, dtype=float)
    w = np.ascontiguousarray(np.asarray(weights, dtype=float)[::-1])
    origin = 0 if w.size & 1 else -1
    return _correlate_constant(x, w, origin)


def median_filter_nearest(x: np.ndarray, size: int) -> np.ndarray:
    """``scipy.ndimage.median_filter(x, size=size, mode="nearest")`` of a 1-D signal.

    The running median over ``size`` samples, the record extended by its end values.
    Cost O(n log size) time and O(n + size) memory for ``size <= 2 n + 1``:
    ndimage's one-dimensional rank filter keeps the window in a double heap, one
    sample out and one in per step (a longer window falls back to its generic
    O(n size) filter; the analysis asks for at most a few periods).  (The
    sorted-window kernel it replaces shifted up to ``size`` samples per step,
    O(n size): quadratic in the record for the quarter-record windows of
    :func:`stictiondiag.stiction.valvefit.cycle_samples`.)  A median picks one of
    the samples, so the numbers are those of any exact method;
    ``tests/test_filters.py`` checks them against a sorted-window reference.
    ndimage is imported here, at the first call, not with this module (it costs a
    tenth of a second).
    """
    from scipy.ndimage import median_filter

    x = np.ascontiguousarray(x, dtype=float)
    return median_filter(x, size=int(size), mode="nearest")


def savgol_smooth(x: np.ndarray, window_length: int, polyorder: int) -> np.ndarray:
    """``scipy.signal.savgol_filter(x, window_length, polyorder)`` of a 1-D signal
    (smoothing, ``mode="interp"``).

    The steps of scipy 1.17's implementation with the same building blocks: the
    least-squares convolution coefficients (``scipy.linalg.lstsq``), the convolution
    (``scipy.ndimage.convolve1d``, as :func:`convolve1d_constant`) and a polynomial
    fitted to the first and the last window for the ``window_length // 2`` samples
    at either end.
    """
    from scipy.linalg import lstsq

    x = np.asarray(x, dtype=float)
    n = x.size
    if polyorder >= window_length:
        raise ValueError("polyorder must be less than window_length.")
    if window_length > n:
        raise ValueError("window_length must be less than or equal to the size of x.")
    halflen, rem = divmod(window_length, 2)
    pos = halflen if rem else halflen - 0.5
    # savgol_coeffs: the rows of the (reversed) Vandermonde matrix, y = e_0.
    t = np.arange(-pos, window_length - pos, dtype=float)[::-1]
    a = t ** np.arange(polyorder + 1, dtype=float).reshape(-1, 1)
    e0 = np.zeros(polyorder + 1)
    e0[0] = 1.0
    coeffs = lstsq(a, e0, cond=np.finfo(float).eps * max(a.shape))[0]
    y = convolve1d_constant(x, coeffs)
    # _fit_edges_polyfit
    t_edge = np.arange(0, window_length, dtype=float)
    for w0, i0, i1 in ((0, 0, halflen), (n - window_length, n - halflen, n)):
        c = _polyfit_edge(t_edge, x[w0 : w0 + window_length].reshape(window_length, -1), polyorder)
        i = np.arange(i0 - w0, i1 - w0, dtype=float).reshape(-1, 1)
        values = np.zeros_like(i)
        for j in range(c.shape[0]):
            values = values * i + c[j, ...]
        y[i0:i1] = (values / 1.0).reshape(i1 - i0)
    return y
