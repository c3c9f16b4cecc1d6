"""Describing function of the data-driven stiction model and limit-cycle prediction.

Choudhury, Thornhill & Shah (2005), Section 6 and Appendix A.  The stiction
nonlinearity (Section 5.1, Eq. 4) driven by ``X_m sin(w t)`` has the describing
function (ratio of the output's fundamental Fourier component to the input's)

    N = -(A - i B) / (pi X_m)                                            (Eq. 7)
    A = X_m/2 sin 2phi - 2 X_m cos phi - X_m (pi/2 + phi) + 2 (S - J) cos phi   (Eq. 8)
    B = -3 X_m/2 + X_m/2 cos 2phi + 2 X_m sin phi - 2 (S - J) sin phi          (Eq. 9)
    phi = asin((X_m - S) / X_m)                                         (Eq. 10)

A limit cycle of a loop with open-loop response ``G0(i w)`` (process times PI
controller) satisfies ``G0(i w) = -1 / N(X_m)`` (Eq. 5); :func:`predict_limit_cycle`
solves it for the frequency ``w`` and the controller-output amplitude ``X_m``.

Notes on the paper's text (see also REFERENCE.md):

* The main-text Eqs. 7-10 are right; they agree with the first harmonic of the
  simulated model (:func:`describing_function_numeric`).  The appendix term T5
  carries typos (``d/2`` and ``a``) that do not reach Eqs. 8-9.
* Eq. 11 as printed, ``N = 4/pi x J/2 e^{-i pi/2}``, is not dimensionally consistent.
  The limit at ``X_m = S/2`` (``phi = -pi/2``, ``A = 0``, ``B = -2 J``) is
  ``N = 2 J / (pi X_m) e^{-i pi/2}``, which is ``4/pi e^{-i pi/2}`` when ``S = J``
  and 0 for a pure deadband (``J = 0``).
* ``phi`` is the phase (input angle) at which the valve slips after it stuck at the
  input's peak: the input has fallen by ``S`` when ``X_m sin t = X_m - S`` at
  ``t = pi - phi``.  The principal branch of ``asin`` (``phi`` in [-pi/2, pi/2]) is
  the right one: it puts the slip between the peak (``t = pi/2``) and the trough
  (``t = 3 pi/2``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.serialize import plain_float
from stictiondiag.models.processes import (
    FOPTD,
    PI,
    Integrating,
    SampledLag,
    open_loop_response,
)
from stictiondiag.models.valve import choudhury_model


def _check_sj(S: float, J: float) -> tuple[float, float]:
    try:
        S_, J_ = float(S), float(J)
    except (TypeError, ValueError):
        raise UsageError(f"S and J must be numbers, got S={S!r}, J={J!r}") from None
    if not (math.isfinite(S_) and math.isfinite(J_)) or S_ < 0 or J_ < 0:
        raise UsageError(f"S and J must be finite and >= 0 (% of span), got S={S_}, J={J_}")
    return S_, J_


def describing_function(Xm: float | np.ndarray, S: float, J: float) -> np.ndarray:
    """Describing function ``N(X_m)`` of the stiction model, closed form (Eqs. 7-10).

    Parameters
    ----------
    Xm : float or ndarray
        Amplitude of the sinusoidal valve input (controller output) [% of span].
    S : float
        Deadband plus stickband [% of input span], >= 0.
    J : float
        Slip jump [% of output span], >= 0.

    Returns
    -------
    complex ndarray
        ``N`` [-], same shape as ``Xm`` (0-d for a scalar).  NaN (complex) where
        ``X_m < S/2`` or ``X_m <= 0``: the valve never slips, there is no oscillating
        output (Section 6.3).

    Notes
    -----
    Asymptotes (Section 6.3, Appendix A.3): ``N -> 1`` for ``X_m >> S``; at
    ``X_m = S/2``, ``N = 2 J / (pi X_m) e^{-i pi/2}`` (the printed Eq. 11 is
    inconsistent, see the module docstring), i.e. ``4/pi e^{-i pi/2}`` for ``S = J``
    and 0 for a pure deadband.
    """
    S, J = _check_sj(S, J)
    x = np.asarray(Xm, dtype=float)
    valid = (x >= S / 2.0) & (x > 0)
    xs = np.where(valid, x, 1.0)
    # Clipping guards the X_m = S/2 limit against rounding just below -1.
    phi = np.arcsin(np.clip((xs - S) / xs, -1.0, 1.0))
    d = S - J
    A = (
        xs / 2.0 * np.sin(2 * phi)
        - 2 * xs * np.cos(phi)
        - xs * (np.pi / 2 + phi)
        + 2 * d * np.cos(phi)
    )
    B = -1.5 * xs + xs / 2.0 * np.cos(2 * phi) + 2 * xs * np.sin(phi) - 2 * d * np.sin(phi)
    N = -(A - 1j * B) / (np.pi * xs)
    return np.where(valid, N, complex(np.nan, np.nan))


def describing_function_numeric(
    Xm: float | np.ndarray,
    S: float,
    J: float,
    *,
    n_periods: int = 3,
    samples_per_period: int = 20000,
) -> np.ndarray:
    """Describing function from a simulation of :func:`~stictiondiag.choudhury_model`.

    The model is driven by ``50 + X_m sin(2 pi k / P)`` [% of span]; the first period
    is discarded (start-up from rest) and ``N`` is the first Fourier coefficient of
    the output over the remaining whole periods divided by that of the input
    (Eq. 6), both computed by the same discrete sum.

    Parameters
    ----------
    Xm : float or ndarray
        Input amplitude [% of span].
    S, J : float
        Deadband plus stickband, slip jump [% of span].
    n_periods : int
        Periods simulated (>= 2); all but the first are analysed.
    samples_per_period : int
        Samples per period ``P``.  The slip is detected at sample resolution, so the
        error in ``N`` is of order ``2 J / (P X_m)``: about 1e-4 at the default.

    Returns
    -------
    complex ndarray
        ``N`` [-], same shape as ``Xm``.  Where ``X_m < S/2`` the valve does not
        move after start-up and the result is 0 (the closed form gives NaN there).

    Notes
    -----
    The model is positively homogeneous: scaling ``op - 50``, ``S`` and ``J`` by the
    same factor scales ``mv - 50`` by it.  Amplitudes above 40 % are therefore
    simulated scaled down to 40 % (with ``S`` and ``J``), so the valve never reaches
    its 0/100 % saturation.
    """
    S, J = _check_sj(S, J)
    if int(n_periods) < 2:
        raise UsageError(f"n_periods must be >= 2 (the first is discarded), got {n_periods}")
    if int(samples_per_period) < 16:
        raise UsageError(f"samples_per_period must be >= 16, got {samples_per_period}")
    P = int(samples_per_period)
    k = np.arange(int(n_periods) * P + 1)
    theta = 2 * np.pi * k / P
    sin_t = np.sin(theta)
    kernel = np.exp(-1j * theta[P:-1])
    x = np.asarray(Xm, dtype=float)
    out = np.empty(x.shape, dtype=complex)
    for idx, amp in np.ndenumerate(x):
        if not (math.isfinite(amp) and amp > 0):
            out[idx] = complex(np.nan, np.nan)
            continue
        scale = min(1.0, 40.0 / amp)
        op = 50.0 + scale * amp * sin_t
        mv = choudhury_model(op, scale * S, scale * J)
        y1 = np.sum((mv[P:-1] - 50.0) * kernel)
        x1 = np.sum((op[P:-1] - 50.0) * kernel)
        out[idx] = y1 / x1
    return out


@dataclass(frozen=True)
class LimitCycleSolution:
    """One intersection of ``G0(i w)`` with ``-1/N(X_m)``.

    Attributes
    ----------
    frequency_rad_s : float
        Angular frequency ``w`` [rad/s].
    amplitude_op : float
        Controller-output amplitude ``X_m`` [% of span].
    stable : bool
        Loeb criterion: a small growth of the amplitude makes the loop decay back
        (a limit cycle that is observed); False for an unstable cycle.
    """

    frequency_rad_s: float
    amplitude_op: float
    stable: bool

    @property
    def period_s(self) -> float:
        """Period ``2 pi / w`` [s]."""
        return 2.0 * math.pi / self.frequency_rad_s

    def to_dict(self) -> dict:
        return {
            "frequency_rad_s": float(self.frequency_rad_s),
            "period_s": float(self.period_s),
            "amplitude_op": float(self.amplitude_op),
            "stable": bool(self.stable),
        }


@dataclass(frozen=True)
class LimitCyclePrediction:
    """Limit cycle predicted by the describing function (Section 6.4, Eq. 5).

    Attributes
    ----------
    limit_cycle : bool
        An intersection of ``G0(i w)`` and ``-1/N(X_m)`` exists.
    period_s : float or None
        Period of the predicted cycle ``2 pi / w`` [s].
    frequency_rad_s : float or None
        Angular frequency ``w`` [rad/s].
    amplitude_op : float or None
        Amplitude ``X_m`` of the controller output (valve input) [% of span].
    stable : bool or None
        Loeb criterion for the reported solution.
    S, J : float
        Stiction parameters analysed [% of span].
    solutions : tuple of LimitCycleSolution
        Every intersection found, in order of increasing amplitude.
    """

    limit_cycle: bool
    period_s: float | None
    frequency_rad_s: float | None
    amplitude_op: float | None
    stable: bool | None
    S: float
    J: float
    solutions: tuple[LimitCycleSolution, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict:
        """JSON-able dict (plain floats, None when there is no limit cycle)."""
        plain = plain_float
        return {
            "limit_cycle": bool(self.limit_cycle),
            "period_s": plain(self.period_s),
            "frequency_rad_s": plain(self.frequency_rad_s),
            "amplitude_op": plain(self.amplitude_op),
            "stable": self.stable,
            "S": float(self.S),
            "J": float(self.J),
            "solutions": [s.to_dict() for s in self.solutions],
        }


def _frequency_grid(process, controller: PI, n: int) -> np.ndarray:
    """Log-spaced angular frequencies [rad/s] spanning the loop's time scales.

    From 1e-6 / (slowest time) to 1e2 / (fastest time): phase steps stay small even
    where a dead time wraps the phase, and ``|G0|`` at the top end is far below any
    ``1/|N|`` (which is at least about 0.75, Fig. 17).
    """
    times = [controller.integral_time]
    top = math.inf
    if isinstance(process, FOPTD):
        times += [process.time_constant, process.dead_time]
    elif isinstance(process, Integrating):
        times += [process.dead_time, 1.0 / abs(process.gain) if process.gain else 1.0]
    elif isinstance(process, SampledLag):
        # A sampled loop has no frequencies above Nyquist's.
        times += [process.time_constant, process.dead_time, process.sample_time]
        top = math.pi / process.sample_time
    times = [t for t in times if t > 0 and math.isfinite(t)]
    t_slow, t_fast = max(times), min(times)
    return np.logspace(math.log10(1e-6 / t_slow), math.log10(min(1e2 / t_fast, top)), n)


def _phase_crossings(
    phase: np.ndarray, target: float, lo: float, hi: float
) -> list[tuple[int, int, float]]:
    """Crossings of the unwrapped phase with ``target + 2 pi m`` for every m.

    Only ``m`` with ``target + 2 pi m`` in [lo, hi] are tried.  Returns (m, index,
    fraction) with the crossing between grid points ``index`` and
    ``index + 1``; ``m`` and the order of crossings with the same ``m`` identify a
    branch that can be followed as ``X_m`` changes.
    """
    m_lo = math.ceil((lo - target) / (2 * math.pi))
    m_hi = math.floor((hi - target) / (2 * math.pi))
    out = []
    for m in range(m_lo, m_hi + 1):
        d = phase - (target + 2 * math.pi * m)
        s = np.signbit(d)
        for j in np.flatnonzero(s[1:] != s[:-1]):
            out.append((m, int(j), float(d[j] / (d[j] - d[j + 1]))))
    return out


def _bracket_intersections(phase, log_mag, log_w, log_excess, target_phase, target_logmag, ok):
    """Starting points (log w, log(X_m - S/2)) near each intersection of the curves.

    Along ``X_m``, the phase condition ``arg G0(i w) = arg(-1/N) + 2 pi m`` defines
    branches ``w_m(X_m)``; where ``log |G0| - log |1/N|`` changes sign along a branch
    the curves cross.  Branches with the same ``m`` are matched in order of ``w``
    while their number stays the same.  Where a non-monotonic phase makes two
    crossings appear or vanish together (a fold of the branch), the two are joined
    through the fold, so a sign change between them is an intersection too.
    """
    brackets = []
    # Where |G0| is below half the smallest |1/N| there can be no intersection; the
    # phase wraps of a dead time there would only cost time.
    reach = log_mag >= np.min(target_logmag[ok]) - math.log(2.0) if ok.any() else log_mag > -np.inf
    lo, hi = (phase[reach].min(), phase[reach].max()) if reach.any() else (0.0, -1.0)
    previous: dict[int, list[tuple[float, float]]] = {}
    for i in range(log_excess.size):
        if not ok[i]:
            previous = {}
            continue
        current: dict[int, list[tuple[float, float]]] = {}
        for m, j, frac in _phase_crossings(phase, float(target_phase[i]), lo, hi):
            lw = log_w[j] + frac * (log_w[j + 1] - log_w[j])
            mismatch = log_mag[j] + frac * (log_mag[j + 1] - log_mag[j]) - target_logmag[i]
            current.setdefault(m, []).append((lw, mismatch))
        for m, now in current.items():
            before = previous.get(m, [])
            if len(before) == len(now):
                for (lw0, mis0), (lw1, mis1) in zip(before, now, strict=True):
                    if (mis0 < 0) != (mis1 < 0):
                        t = mis0 / (mis0 - mis1)
                        lx = log_excess[i - 1] + t * (log_excess[i] - log_excess[i - 1])
                        brackets.append((lw0 + t * (lw1 - lw0), lx))
                continue
            # A fold between the two amplitudes: look across adjacent pairs on the
            # side with more crossings.
            side, lx = (
                (now, log_excess[i]) if len(now) > len(before) else (before, log_excess[i - 1])
            )
            for (lw0, mis0), (lw1, mis1) in zip(side[:-1], side[1:], strict=True):
                if (mis0 < 0) != (mis1 < 0):
                    t = mis0 / (mis0 - mis1)
                    brackets.append((lw0 + t * (lw1 - lw0), lx))
        for m, before in previous.items():
            if m not in current and len(before) > 1:
                for (lw0, mis0), (lw1, mis1) in zip(before[:-1], before[1:], strict=True):
                    if (mis0 < 0) != (mis1 < 0):
                        t = mis0 / (mis0 - mis1)
                        brackets.append((lw0 + t * (lw1 - lw0), log_excess[i - 1]))
        previous = current
    return brackets


def predict_limit_cycle(
    process: FOPTD | Integrating | SampledLag,
    controller: PI,
    S: float,
    J: float,
    *,
    n_amplitudes: int = 400,
    n_frequencies: int = 20000,
) -> LimitCyclePrediction:
    """Predict the stiction limit cycle of a loop from ``G0(i w) = -1/N(X_m)`` (Eq. 5).

    Parameters
    ----------
    process : FOPTD, Integrating or SampledLag
        Process model (Eq. 3, Table 3; or the linear part of a Hammerstein fit).
    controller : PI
        PI controller in the paper's form.
    S, J : float
        Deadband plus stickband, slip jump [% of span].
    n_amplitudes, n_frequencies : int
        Sizes of the scanning grids (log-spaced in ``X_m - S/2`` and in ``w``).

    Returns
    -------
    LimitCyclePrediction
        ``limit_cycle=False`` and None values when the curves do not intersect (for
        example a pure deadband in the concentration loop, Section 6.4).

    Notes
    -----
    Method: ``X_m - S/2`` is scanned on a log grid from ``1e-12`` to ``10^4``
    times ``S``.  For each ``X_m`` the frequencies where the unwrapped phase of
    ``G0(i w)`` equals that of ``-1/N(X_m)`` (modulo ``2 pi``) are found on a
    frequency grid, each branch followed across ``X_m``; a sign change of
    ``log |G0| - log |1/N|`` along a branch brackets an intersection, which is then
    refined by solving the complex equation ``1 + N G0 = 0`` with
    :func:`scipy.optimize.root` (relative tolerance about 1e-10).

    Of several intersections the reported one is the stable one (Loeb criterion:
    with ``1 + N(X) G0(i w) = U + i V``, the cycle is stable when
    ``dU/dX dV/dw - dU/dw dV/dX > 0``, i.e. a slightly larger amplitude puts the
    loop on the decaying side); if several are stable, the one of largest
    amplitude; if none is, the largest-amplitude solution with ``stable=False``.
    """
    S, J = _check_sj(S, J)
    if not isinstance(controller, PI):
        raise UsageError("controller must be a PI (stictiondiag.models.processes.PI)")
    if S == 0.0 and J == 0.0:
        # A linear valve, N = 1: no amplitude-dependent intersection.
        return LimitCyclePrediction(False, None, None, None, None, S, J, ())

    w = _frequency_grid(process, controller, int(n_frequencies))
    g0 = open_loop_response(process, controller, w)
    phase = np.unwrap(np.angle(g0))
    log_mag = np.log(np.abs(g0))

    half = S / 2.0
    scale = max(S, J)
    excess = np.logspace(-12, 4, int(n_amplitudes)) * scale
    amplitudes = half + excess
    N = describing_function(amplitudes, S, J)
    ok = np.abs(N) > 0
    # Target phase and magnitude of -1/N.
    target_phase = np.angle(-1.0 / np.where(ok, N, 1.0))
    target_logmag = -np.log(np.where(ok, np.abs(N), 1.0))

    brackets = _bracket_intersections(
        phase, log_mag, np.log(w), np.log(excess), target_phase, target_logmag, ok
    )

    def residual(z):
        # The solver may step far out; exp of a clipped exponent keeps it finite.
        wz = math.exp(min(max(z[0], -700.0), 700.0))
        xz = half + math.exp(min(max(z[1], -700.0), 700.0))
        f = 1.0 + describing_function(xz, S, J) * open_loop_response(process, controller, wz)
        return [float(np.real(f)), float(np.imag(f))]

    # scipy.optimize only here: the analysis imports this module for the consistency
    # of Section 6, and a loop without a cycle never needs the solver.
    from scipy.optimize import root

    solutions: list[LimitCycleSolution] = []
    for lw, lx in brackets:
        sol = root(residual, [lw, lx], method="hybr", tol=1e-12)
        # Judge by the residual: hybr may report slow progress at an exact root.
        if not np.all(np.isfinite(sol.x)) or np.hypot(*residual(sol.x)) > 1e-8:
            continue
        w_s, x_s = math.exp(sol.x[0]), half + math.exp(sol.x[1])
        if any(
            abs(s.frequency_rad_s - w_s) <= 1e-6 * w_s and abs(s.amplitude_op - x_s) <= 1e-6 * x_s
            for s in solutions
        ):
            continue
        solutions.append(
            LimitCycleSolution(w_s, x_s, _loeb_stable(process, controller, S, J, w_s, x_s))
        )

    solutions.sort(key=lambda s: s.amplitude_op)
    if not solutions:
        return LimitCyclePrediction(False, None, None, None, None, S, J, ())
    stable = [s for s in solutions if s.stable]
    best = stable[-1] if stable else solutions[-1]
    return LimitCyclePrediction(
        limit_cycle=True,
        period_s=best.period_s,
        frequency_rad_s=best.frequency_rad_s,
        amplitude_op=best.amplitude_op,
        stable=best.stable,
        S=S,
        J=J,
        solutions=tuple(solutions),
    )


def _loeb_stable(process, controller, S, J, w, x) -> bool:
    """Loeb criterion for the limit cycle at (w [rad/s], x [% of span])."""
    hw, hx = 1e-6 * w, 1e-6 * max(x - S / 2.0, 1e-9 * x)

    def f(wv, xv):
        return 1.0 + describing_function(xv, S, J) * open_loop_response(process, controller, wv)

    df_dw = (f(w + hw, x) - f(w - hw, x)) / (2 * hw)
    df_dx = (f(w, x + hx) - f(w, x - min(hx, 0.5 * (x - S / 2.0)))) / (
        hx + min(hx, 0.5 * (x - S / 2.0))
    )
    loeb = df_dx.real * df_dw.imag - df_dw.real * df_dx.imag
    return bool(loeb > 0)


@dataclass(frozen=True)
class StabilityMargins:
    """Gain and phase margins of the loop with a linear valve (``N = 1``).

    Attributes
    ----------
    gain_margin : float
        ``1 / |G0|`` at the lowest frequency where the phase of ``G0`` reaches
        -180 degrees [-]; inf when it never does.  Below 1 the linear loop is
        unstable (it cycles on its own, up to op's limits).
    phase_margin_deg : float
        180 degrees plus the phase of ``G0`` where ``|G0|`` last falls through 1
        [deg]; 180 when it never reaches 1.
    """

    gain_margin: float
    phase_margin_deg: float

    def to_dict(self) -> dict:
        return {
            "gain_margin": plain_float(self.gain_margin),
            "phase_margin_deg": plain_float(self.phase_margin_deg),
        }


def stability_margins(
    process: FOPTD | Integrating | SampledLag, controller: PI, *, n_frequencies: int = 3000
) -> StabilityMargins:
    """Gain and phase margins of ``G0 = G C`` on the grid of :func:`predict_limit_cycle`
    (linear interpolation between grid points).  For a stable linear loop the
    Nyquist criterion leaves no self-sustained cycle: one needs the valve's
    nonlinearity, an external source, or a margin near 1."""
    w = _frequency_grid(process, controller, int(n_frequencies))
    g0 = open_loop_response(process, controller, w)
    phase = np.unwrap(np.angle(g0))
    mag = np.abs(g0)
    gm = math.inf
    k = np.flatnonzero(phase <= -math.pi)
    if k.size and k[0] > 0:
        j = int(k[0])
        t = (phase[j - 1] + math.pi) / (phase[j - 1] - phase[j])
        gm = 1.0 / float(np.exp(np.log(mag[j - 1]) + t * (np.log(mag[j]) - np.log(mag[j - 1]))))
    elif k.size:
        gm = 1.0 / float(mag[0])
    pm = 180.0
    k = np.flatnonzero(mag >= 1.0)
    if k.size and k[-1] < mag.size - 1:
        j = int(k[-1])
        t = math.log(mag[j]) / (math.log(mag[j]) - math.log(mag[j + 1]))
        pm = math.degrees(math.pi + float(phase[j] + t * (phase[j + 1] - phase[j])))
    elif k.size:
        pm = math.degrees(math.pi + float(phase[-1]))
    return StabilityMargins(gain_margin=gm, phase_margin_deg=pm)
