"""Effect ``external_disturbance``: an oscillation entering the loop that the valve did not cause.

Acts on pv: a sinusoid and its second harmonic added to the process replay (Eq. 3 of
Choudhury, Thornhill & Shah 2005).  Parameters: frequency, amplitudes and phases.
Signature: the oscillation keeps its phase along the record (Rayleigh test,
:func:`phase_coherence`), which a loop's own stick-slip cycle does not.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stictiondiag.gap.context import ReplayContext
from stictiondiag.gap.effects.base import (
    BaseFit,
    Effect,
    EffectFit,
    EffectParams,
    fit_process,
    process_input,
    pv_noise_floor,
)
from stictiondiag.identification.numerics import golden_section
from stictiondiag.identification.process_result import ProcessFit


def _sinusoids(n: int, omega: float, harmonics: int) -> np.ndarray:
    """The columns ``cos(h omega k)``, ``sin(h omega k)`` for ``h = 1..harmonics`` (n x
    2 harmonics), stored column by column: the process fit reads them as rows."""
    k = np.arange(n, dtype=float)
    rows = np.empty((2 * harmonics, n))
    for h in range(1, harmonics + 1):
        arg = h * omega * k
        np.cos(arg, out=rows[2 * h - 2])
        np.sin(arg, out=rows[2 * h - 1])
    return rows.T


#: Spectral peaks refined by golden-section search (the rest are screened out).
REFINED_PEAKS = 2


def _screen_peaks(peaks: list, cost_at: Callable[[int], float], keep: int) -> list:
    """The ``keep`` peaks whose sinusoid, fitted at the peak's own frequency, leaves the
    smallest process-replay error, in their original order.

    The golden-section search around a peak moves the frequency by at most four bins
    of the four times zero-padded spectrum (one bin of the record's own resolution)
    either way, so the error at the peak is close to its refined value and the
    ranking at the peaks is taken for the ranking after refinement.  Each refinement
    costs some 18 process refits (16 for the golden section, two retuned); a
    screen costs one per peak.
    """
    if len(peaks) <= keep:
        return peaks
    c = np.array([cost_at(i) for i in peaks])
    chosen = set(np.argsort(c, kind="stable")[:keep].tolist())
    return [p for k, p in enumerate(peaks) if k in chosen]


#: Significance of the phase coherence an external oscillation must show (Rayleigh test).
COHERENCE_P = 0.01


def phase_coherence(r: np.ndarray, omega: float, w: np.ndarray) -> tuple[float, float]:
    """Phase coherence of a sinusoid of ``omega`` [rad/sample] in ``r`` along the record.

    An oscillation from outside the loop keeps its own clock: its phase, measured
    in consecutive blocks of one period, stays put.  A loop's own stick-slip cycle
    drifts in phase from cycle to cycle (noise and load change each cycle's
    length), and a sinusoid fitted to broadband residual has random phases.  Returns
    the mean resultant length R of the block phases (1: one phase) and the Rayleigh
    test's p-value ``exp(-B R^2)`` for B blocks.
    """
    n = r.size
    period = 2.0 * math.pi / max(omega, 1e-9)
    L = int(max(period, 16))
    B = n // L
    if B < 3:
        return 0.0, 1.0
    k = np.arange(n)
    z = (r * w) * np.exp(-1j * omega * k)
    ph = []
    for b in range(B):
        c = z[b * L : (b + 1) * L].sum()
        if abs(c) > 0:
            ph.append(c / abs(c))
    if len(ph) < 3:
        return 0.0, 1.0
    R = float(abs(np.mean(ph)))
    return R, float(math.exp(-len(ph) * R * R))


@dataclass(frozen=True)
class ExternalDisturbanceParams(EffectParams):
    """An oscillation entering the loop that the valve did not cause.

    Attributes
    ----------
    period_s : float
        Its period [s].
    amplitude, amplitude_second_harmonic : float
        Amplitudes at pv of the fundamental and the second harmonic [pv units]
        (0 for a fundamental alone).
    phase_coherence : float or None
        How steadily its phase holds along the record [-] (None on part of the record).
    phase_coherence_p : float
        p-value of the Rayleigh test of that phase [-].
    """

    SIGNATURE = "phase_coherence_p"

    period_s: float
    amplitude: float
    amplitude_second_harmonic: float
    phase_coherence: float | None
    phase_coherence_p: float


def _candidate_peaks(
    pv: np.ndarray, pv_replay: np.ndarray, w: np.ndarray, load_spacing: float
) -> tuple[list[int], np.ndarray, int]:
    """Candidate frequencies of a disturbance: the three largest spectral peaks of the
    process replay's residual and the three of pv itself (the load tracking follows
    part of a slow disturbance, so its peak can be small in the residual while it
    dominates pv), between two cycles in the record (and the slow load's knot
    spacing) and three samples per cycle.

    Returns the peaks' bins, the bins' frequencies [rad/sample] and the FFT length.
    """
    n = pv.size
    r = (pv - pv_replay) * w
    nfft = 1 << int(math.ceil(math.log2(4 * n)))
    spec = np.abs(np.fft.rfft(r, nfft)) ** 2
    omega = 2.0 * math.pi * np.arange(spec.size) / nfft  # [rad/sample]
    lo = max(2.0 * math.pi * 2.0 / n, 2.0 * math.pi / load_spacing)
    ok = (omega >= lo) & (omega <= 2.0 * math.pi / 3.0)
    cand = np.where(ok)[0]
    if cand.size < 3:
        cand = np.arange(1, spec.size)

    def top_peaks(spec_x, k):
        # Local maxima of the spectrum over the candidates, largest first (ties in
        # frequency order).
        sx = spec_x[cand]
        inner = (sx[1:-1] >= sx[:-2]) & (sx[1:-1] >= sx[2:])
        pk = cand[np.flatnonzero(inner) + 1]
        pk = pk[np.argsort(-spec_x[pk], kind="stable")[:k]]
        return [int(i) for i in pk] or [int(cand[int(np.argmax(sx))])]

    pvc = (pv - np.sum(pv * w) / max(np.sum(w), 1.0)) * w
    spec_pv = np.abs(np.fft.rfft(pvc, nfft)) ** 2
    peaks = list(dict.fromkeys(top_peaks(spec, 3) + top_peaks(spec_pv, 3)))
    return peaks, omega, nfft


def fit_external_disturbance(
    ctx: ReplayContext,
    w: np.ndarray,
    base: BaseFit,
    init: EffectFit[ExternalDisturbanceParams] | None = None,
) -> EffectFit[ExternalDisturbanceParams]:
    """An oscillation entering the loop that the valve did not cause.

    ``pv = G(mv) + A1 sin(w t + p1) [+ A2 sin(2 w t + p2)]``: the frequency starts at
    one of the largest peaks of the spectrum of the process-replay residual, is
    refined by golden-section search, and the process is refitted together with the
    sinusoids (a disturbance biases the process fit, so they are fitted together).
    Periods longer than the slow load's knot spacing belong to the load.
    """
    sig = ctx.sig
    u = process_input(ctx, base)
    pv, n = sig.pv, sig.n
    var_pv = ctx.norm["pv"]
    model = base.process.prediction.model

    def cost(om, harmonics, model=model, retune=False):
        f = fit_process(
            u,
            ctx,
            w,
            extra=_sinusoids(n, om, harmonics),
            model=model,
            retune=retune,
            horizon=base.process.prediction.model.horizon,
        )
        return float(np.dot(w, (f.prediction.pv - pv) ** 2)) / var_pv, f

    if init is not None:
        om = 2.0 * math.pi * sig.dt / init.params.period_s
        harmonics = 1 if init.variant == "fundamental" else 2
        c, f = cost(om, harmonics, model=init.process.prediction.model if init.process else model)
    else:
        peaks, omega, nfft = _candidate_peaks(pv, base.process.prediction.pv, w, ctx.load.spacing)
        # Each peak is screened with the process dynamics refitted together with the
        # sinusoid: in closed loop the controller answers the disturbance, so a
        # process fitted without it has taken part of the disturbance for the
        # valve's effect (pv correlates with mv through the controller), and the
        # residual of that fit hides the disturbance's own peak.
        screened = {i: cost(omega[i], 1, model=None) for i in peaks}
        peaks = _screen_peaks(peaks, lambda i: screened[i][0], REFINED_PEAKS)
        best: tuple[float, float, int, ProcessFit] | None = None
        width = 2.0 * math.pi / nfft * 4.0
        for i in peaks:
            om0 = omega[i]
            m_i = screened[i][1].prediction.model

            def cost_at(o: float, m_i=m_i) -> float:
                return cost(o, 1, model=m_i)[0]

            om = golden_section(
                cost_at,
                max(om0 - width, 1e-6),
                om0 + width,
                n_iter=14,
            )
            for harmonics in (1, 2):
                # Judged with the load tracking retuned: with the oscillation in the
                # model there is less load to follow.
                c, f = cost(om, harmonics, model=m_i, retune=True)
                if best is None or c < best[0]:
                    best = (c, om, harmonics, f)
        # top_peaks returns at least one peak, and the screen keeps some of them.
        assert best is not None
        c, om, harmonics, f = best
        # The process dynamics refitted with the disturbance in the model, and the
        # load tracking retuned: the disturbance is no longer load to follow.
        c2, f2 = cost(om, harmonics, model=None)
        if c2 < c:
            c, f = c2, f2
        c3, f3 = cost(om, harmonics, model=f.prediction.model, retune=True)
        if c3 < c:
            f = f3
    amp = f.prediction.coef[-2 * harmonics :]
    amplitudes = [float(math.hypot(amp[2 * h], amp[2 * h + 1])) for h in range(harmonics)]
    coherence, p_value = (
        phase_coherence(pv - base.process.prediction.pv, om, ctx.w_eval)
        if init is None
        else (None, 0.0)
    )
    return EffectFit(
        effect="external_disturbance",
        variant="fundamental" if harmonics == 1 else "fundamental_and_second_harmonic",
        n_params=1 + 2 * harmonics,
        params=ExternalDisturbanceParams(
            period_s=float(2.0 * math.pi / om * sig.dt),
            amplitude=amplitudes[0],
            amplitude_second_harmonic=amplitudes[1] if harmonics > 1 else 0.0,
            phase_coherence=coherence,
            phase_coherence_p=p_value,
        ),
        predictions={"pv": f.prediction.pv},
        supported=p_value < COHERENCE_P,
        x=(float(om),),
        process=f,
        pv_floor=None
        if init is not None
        else pv_noise_floor(u, ctx, f, _sinusoids(n, om, harmonics)),
    )


EFFECT = Effect(
    name="external_disturbance",
    acts_on=("pv",),
    parameters=("period_s", "amplitude", "amplitude_second_harmonic"),
    fit=fit_external_disturbance,
    signature="the oscillation keeps its phase along the record",
    signature_test=phase_coherence,
)
