"""Where the gap lies: by signal, valve phase, frequency, time and feature, before and after.

The phases are those of Fig. 2 of Choudhury, Thornhill & Shah (2005) (A-B reversal,
B-C stuck, C-D slip, D-E moving), read from the base valve replay.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np

from stictiondiag.core.serialize import plain_float, to_plain
from stictiondiag.models.valve import PHASE_MOVING, PHASE_NAMES, PHASE_SLIP
from stictiondiag.replay.result import ReplayMeasures

T = TypeVar("T")

#: The replayed signals, in the order the breakdown reports them.
SIGNAL_ORDER = ("op", "pv", "mv")


@dataclass(frozen=True)
class PerSignal(Generic[T]):
    """One value per replayed signal (None for a signal that is not replayed: mv
    without a recorded mv).

    Attributes
    ----------
    op, pv, mv : T or None
    """

    op: T | None = None
    pv: T | None = None
    mv: T | None = None

    @classmethod
    def of(cls, values: dict[str, T]) -> PerSignal[T]:
        """From a dict by signal name (``op``, ``pv``, ``mv``)."""
        return cls(**{s: values[s] for s in SIGNAL_ORDER if s in values})

    def items(self) -> list[tuple[str, T]]:
        """(signal, value) of the signals present, in the order op, pv, mv."""
        return [(s, v) for s in SIGNAL_ORDER if (v := getattr(self, s)) is not None]

    def names(self) -> list[str]:
        """The signals present, in the order op, pv, mv."""
        return [s for s, _ in self.items()]

    def to_dict(self) -> dict[str, Any]:
        return {s: v.to_dict() if hasattr(v, "to_dict") else to_plain(v) for s, v in self.items()}


@dataclass(frozen=True)
class SignalGap:
    """One signal's share of the gap.

    Attributes
    ----------
    before, after : float
        Its gap (excess over its noise floor) with the base replay and with the
        winning effect added [%].
    noise_floor : float
        Its noise floor, ``100 sqrt(N_s / V_s)`` [%].
    """

    before: float
    after: float
    noise_floor: float

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class PhaseError:
    """One signal's replay error in one valve phase.

    Attributes
    ----------
    share_pct_before, share_pct_after : float
        Share of the signal's squared replay error in the phase, before and after [%].
    rms_before, rms_after : float or None
        RMS replay error in the phase [units of the signal]; None when the phase has
        no judged sample.
    """

    share_pct_before: float
    rms_before: float | None
    share_pct_after: float
    rms_after: float | None


@dataclass(frozen=True)
class PhaseShare:
    """The replay error in one valve phase (Fig. 2), of mv and pv.

    Attributes
    ----------
    samples_pct : float
        Share of the record's samples in the phase [%].
    mv, pv : PhaseError or None
        None for a signal not replayed.
    """

    samples_pct: float
    mv: PhaseError | None = None
    pv: PhaseError | None = None

    def to_dict(self) -> dict[str, Any]:
        """``samples_pct`` and ``<signal>_share_pct_<when>``, ``<signal>_rms_<when>``."""
        out: dict[str, Any] = {"samples_pct": self.samples_pct}
        for s in ("mv", "pv"):
            e = getattr(self, s)
            if e is not None:
                for when in ("before", "after"):
                    out[f"{s}_share_pct_{when}"] = getattr(e, f"share_pct_{when}")
                    out[f"{s}_rms_{when}"] = getattr(e, f"rms_{when}")
        return to_plain(out)

    def share_before(self, signal: str) -> float | None:
        """The share of ``signal``'s error before [%]; None for a signal not replayed."""
        e = getattr(self, signal)
        return None if e is None else e.share_pct_before


@dataclass(frozen=True)
class ByPhase:
    """The replay error by valve phase (Fig. 2: A-B reversal, B-C stuck, C-D slip,
    D-E moving), read from the base valve replay."""

    stuck: PhaseShare
    slip: PhaseShare
    moving: PhaseShare
    reversal: PhaseShare

    def items(self) -> list[tuple[str, PhaseShare]]:
        """(phase, its share), in the order of :data:`PHASE_NAMES`."""
        return [(name, getattr(self, name)) for name in PHASE_NAMES.values()]

    def to_dict(self) -> dict[str, Any]:
        return {name: p.to_dict() for name, p in self.items()}


@dataclass(frozen=True)
class FrequencyShares:
    """Where one signal's replay-error energy lies in frequency, before and after
    [%]: at the loop's fundamental, at its harmonics (2nd to 10th) and elsewhere.
    Each is None when the replay has no error to split (exact to rounding)."""

    fundamental_pct_before: float | None
    harmonics_pct_before: float | None
    other_pct_before: float | None
    fundamental_pct_after: float | None
    harmonics_pct_after: float | None
    other_pct_after: float | None

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class ByFrequency:
    """The replay error by frequency.

    Attributes
    ----------
    fundamental_period_s : float or None
        Period of the loop's oscillation [s] (from op, else pv); None without one,
        and then no signal is split.
    signals : PerSignal of FrequencyShares
    """

    fundamental_period_s: float | None
    signals: PerSignal[FrequencyShares] = PerSignal()

    def to_dict(self) -> dict[str, Any]:
        return {
            "fundamental_period_s": to_plain(self.fundamental_period_s),
            **self.signals.to_dict(),
        }


@dataclass(frozen=True)
class TimeGap:
    """One signal's gap in the first and second half of the record, before and after [%]."""

    early_before: float
    late_before: float
    early_after: float
    late_after: float

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class SignalFeatures:
    """Amplitude and period of one signal in the data and the replays before and after.

    Attributes
    ----------
    amplitude_data, amplitude_before, amplitude_after : float
        Half the range between the 2nd and 98th percentiles [units of the signal].
    period_s_data, period_s_before, period_s_after : float or None
        Period of the largest spectral peak [s]; None without one.
    """

    amplitude_data: float
    amplitude_before: float
    amplitude_after: float
    period_s_data: float | None
    period_s_before: float | None
    period_s_after: float | None

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class SlipFeatures:
    """The shape of the valve's slips (Fig. 2, C-D) in one mv series.

    Attributes
    ----------
    jump_up, jump_down : float or None
        Median jump at the breakaways, opening and closing [% of span].
    moving_slope : float or None
        Least-squares slope of mv on op in the moving phase [-].
    corner_rise_samples : float or None
        Rise time of the average slip to 90 % [samples] (the corner of the mv-op loop).
    """

    jump_up: float | None
    jump_down: float | None
    moving_slope: float | None
    corner_rise_samples: float | None

    def to_dict(self) -> dict[str, Any]:
        return to_plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class ValveFeatures:
    """The slip features of the recorded mv and of the valve replays before and after."""

    data: SlipFeatures
    before: SlipFeatures
    after: SlipFeatures

    def to_dict(self) -> dict[str, Any]:
        return {w: getattr(self, w).to_dict() for w in ("data", "before", "after")}


@dataclass(frozen=True)
class ClosedLoopFeatures:
    """Period and amplitudes of the closed-loop replay
    (:class:`stictiondiag.replay.result.Replay`) against the data.

    Attributes
    ----------
    period_s_data, period_s_replay : float or None
        Oscillation period of the record and the replay [s].
    measures : ReplayMeasures
        The replay's measures per signal (amplitudes [units of the signal]).
    """

    period_s_data: float | None
    period_s_replay: float | None
    measures: ReplayMeasures

    def to_dict(self) -> dict[str, Any]:
        return to_plain(
            {
                "period_s": {"data": self.period_s_data, "replay": self.period_s_replay},
                "amplitude": self.measures.to_dict()["amplitude"],
            }
        )


@dataclass(frozen=True)
class ByFeature:
    """Features of the data against the replays: per signal, the valve's slips (with
    a recorded mv and valve phases) and the closed-loop replay (where there is one)."""

    signals: PerSignal[SignalFeatures]
    valve: ValveFeatures | None = None
    closed_loop_replay: ClosedLoopFeatures | None = None

    def to_dict(self) -> dict[str, Any]:
        out = self.signals.to_dict()
        if self.valve is not None:
            out["valve"] = self.valve.to_dict()
        if self.closed_loop_replay is not None:
            out["closed_loop_replay"] = self.closed_loop_replay.to_dict()
        return out


@dataclass(frozen=True)
class Breakdown:
    """Where the gap lies, before and after the winning effect.

    Attributes
    ----------
    signal : PerSignal of SignalGap
        Gap per signal and its noise floor [%].
    phase : ByPhase or None
        Error by valve phase; None without a valve replay (no recorded mv).
    frequency : ByFrequency
        Error energy at the fundamental, its harmonics and elsewhere [%].
    time : PerSignal of TimeGap
        Gap in the first and second half of the record [%].
    feature : ByFeature
        Period, amplitude and slip shape of data and replays.
    """

    signal: PerSignal[SignalGap]
    phase: ByPhase | None = None
    frequency: ByFrequency = ByFrequency(fundamental_period_s=None)
    time: PerSignal[TimeGap] = PerSignal()
    feature: ByFeature = ByFeature(signals=PerSignal())

    def to_dict(self) -> dict[str, Any]:
        """The ``breakdown`` entry of the gap's JSON."""
        out: dict[str, Any] = {"signal": self.signal.to_dict()}
        if self.phase is not None:
            out["phase"] = self.phase.to_dict()
        out["frequency"] = self.frequency.to_dict()
        out["time"] = self.time.to_dict()
        out["feature"] = self.feature.to_dict()
        return out

    def largest_signal(self) -> str | None:
        """The signal that holds most of the gap before; None without any."""
        vals = {s: v for s, g in self.signal.items() if (v := plain_float(g.before)) is not None}
        return max(vals, key=lambda s: vals[s]) if vals else None


def dominant_period_samples(x: np.ndarray) -> float | None:
    """Period of the largest spectral peak of ``x`` [samples], or None.

    Slow drift (fewer than four cycles in the record) is excluded, so a load change
    does not pass for the oscillation; the periodogram is smoothed over three bins.
    """
    x = np.asarray(x, dtype=float)
    n = x.size
    if n < 16 or not np.std(x) > 0:
        return None
    xd = x - np.mean(x)
    nfft = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.abs(np.fft.rfft(xd * np.hanning(n), nfft)) ** 2
    spec = np.convolve(spec, np.ones(3) / 3.0, mode="same")
    f = np.arange(spec.size) / nfft  # [cycles/sample]
    ok = (f >= 4.0 / n) & (f <= 0.25)
    if not np.any(ok):
        return None
    i = int(np.argmax(np.where(ok, spec, -1.0)))
    return float(1.0 / f[i])


def breakdown(sig, meas, base, before: dict, after: dict, replay) -> Breakdown:
    """Where the gap lies: by signal, phase, frequency, time and feature, before and after.

    ``meas`` is the diagnosis's :class:`stictiondiag.gap.selection.Measure`, ``base``
    its base fit (the valve phases), ``before`` and ``after`` the replayed signals by
    name without and with the winning effect, ``replay`` the closed-loop replay or None.
    """

    def gap_of(s: str, preds: dict) -> float:
        return 100.0 * math.sqrt(meas.excess(s, meas.nmse(s, preds[s], getattr(sig, s))))

    signal = PerSignal.of(
        {
            s: SignalGap(
                before=gap_of(s, before),
                after=gap_of(s, after),
                noise_floor=100.0 * math.sqrt(meas.floor[s] / meas.norm[s]),
            )
            for s in before
        }
    )
    phase = base.valve.phase if base.valve is not None else None
    return Breakdown(
        signal=signal,
        phase=None if phase is None else _by_phase(sig, meas, phase, before, after),
        frequency=_by_frequency(sig, meas, before, after),
        time=_by_time(sig, meas, before, after),
        feature=_by_feature(sig, before, after, phase, replay),
    )


def _phase_labels(phase: np.ndarray) -> np.ndarray:
    """Phase per sample with the breakaway sample and the two after it called slip."""
    lab = phase.astype(np.int64).copy()
    slips = np.where(phase == PHASE_SLIP)[0]
    for k in (1, 2):
        idx = slips + k
        idx = idx[idx < lab.size]
        lab[idx] = PHASE_SLIP
    return lab


def _by_phase(sig, meas, phase, before, after) -> ByPhase:
    """Share of the mv (and pv) squared error in each valve phase (Fig. 2: A-B reversal,
    B-C stuck, C-D slip, D-E moving)."""
    lab = _phase_labels(phase)
    cells: dict[str, dict[str, dict[str, float | None]]] = {n: {} for n in PHASE_NAMES.values()}
    for s in ("mv", "pv"):
        if s not in before:
            continue
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            e = meas.w * (preds[s] - x) ** 2
            tot = float(e.sum()) or 1.0
            for code, name in PHASE_NAMES.items():
                m = lab == code
                n_m = float((meas.w * m).sum())
                entry = cells[name].setdefault(s, {})
                entry[f"share_pct_{when}"] = 100.0 * float(e[m].sum()) / tot
                entry[f"rms_{when}"] = math.sqrt(float(e[m].sum()) / n_m) if n_m > 0 else None
    shares = {
        name: PhaseShare(
            samples_pct=100.0 * float(np.mean(lab == code)),
            **{s: PhaseError(**v) for s, v in cells[name].items()},  # type: ignore[arg-type]
        )
        for code, name in PHASE_NAMES.items()
    }
    return ByPhase(**shares)


def _fundamental(sig) -> float | None:
    """Period of the loop's oscillation [samples], from op (or pv)."""
    for x in (sig.op, sig.pv):
        p = dominant_period_samples(x)
        if p is not None:
            return p
    return None


def _by_frequency(sig, meas, before, after) -> ByFrequency:
    """Share of each signal's replay-error energy at the loop's fundamental, at its
    harmonics (2nd to 10th) and elsewhere [%]; None for a signal whose replay has no
    error (exact to rounding)."""
    period = _fundamental(sig)
    if period is None:
        return ByFrequency(fundamental_period_s=None)
    f0 = 1.0 / period
    shares: dict[str, FrequencyShares] = {}
    for s in before:
        x = getattr(sig, s)
        entry: dict[str, float | None] = {}
        for when, preds in (("before", before), ("after", after)):
            r = (preds[s] - x) * meas.w
            n = r.size
            nfft = 1 << int(math.ceil(math.log2(n)))
            spec = np.abs(np.fft.rfft(r - r.mean(), nfft)) ** 2
            f = np.arange(spec.size) / nfft
            tot = float(spec.sum())
            # A replay exact to rounding has no error to split: its shares are None
            # (not three zeros), so that a plot says so instead of drawing nothing.
            scale = float(np.dot(meas.w * x, x))
            if tot <= 1e-20 * max(scale, 1e-300) * nfft:
                for part in ("fundamental", "harmonics", "other"):
                    entry[f"{part}_pct_{when}"] = None
                continue
            fund = np.abs(f - f0) <= 0.15 * f0
            harm = np.zeros_like(fund)
            for h in range(2, 11):
                harm |= np.abs(f - h * f0) <= 0.15 * f0
            harm &= ~fund
            entry[f"fundamental_pct_{when}"] = 100.0 * float(spec[fund].sum()) / tot
            entry[f"harmonics_pct_{when}"] = 100.0 * float(spec[harm].sum()) / tot
            entry[f"other_pct_{when}"] = 100.0 * float(spec[~(fund | harm)].sum()) / tot
        shares[s] = FrequencyShares(**entry)  # type: ignore[arg-type]
    return ByFrequency(fundamental_period_s=period * sig.dt, signals=PerSignal.of(shares))


def _by_time(sig, meas, before, after) -> PerSignal[TimeGap]:
    """Gap of each signal in the first and the second half of the record [%]."""
    n = sig.n
    halves = {"early": np.arange(n) < n // 2, "late": np.arange(n) >= n // 2}
    res: dict[str, TimeGap] = {}
    for s in before:
        x = getattr(sig, s)
        entry: dict[str, float] = {}
        for when, preds in (("before", before), ("after", after)):
            for half, m in halves.items():
                v = meas.nmse(s, preds[s], x, meas.w * m)
                entry[f"{half}_{when}"] = 100.0 * math.sqrt(meas.excess(s, v))
        res[s] = TimeGap(**entry)
    return PerSignal.of(res)


def _half_range(x: np.ndarray) -> float:
    return 0.5 * float(np.percentile(x, 98) - np.percentile(x, 2))


def _slip_features(op, mv, phase, window: int = 3) -> SlipFeatures:
    """Median jump up and down at the replay's breakaways, moving-phase slope of mv on
    op, and the rise time of the average slip (the corner of the mv-op loop).

    Array operations over all slips and moving stretches at once (O(n)); the same
    numbers as one slip and one stretch at a time, except the moving-phase slope,
    whose per-stretch means are summed in another order (within 1e-12 relative).
    """
    slips = np.where(phase == PHASE_SLIP)[0]
    slips = slips[(slips > 2) & (slips < mv.size - 2 * window - 2)]
    d = mv[slips + window] - mv[slips - 1]
    jumps_up, jumps_dn = np.abs(d[d > 0]), np.abs(d[~(d > 0)])
    rise = None
    if slips.size:
        seg = mv[slips[:, None] - 1 + np.arange(2 * window + 3)[None, :]] - mv[slips - 1][:, None]
        amp = seg[:, -1]
        ok = np.abs(amp) > 0
        if ok.any():
            avg = np.mean(seg[ok] / amp[ok, None], axis=0)
            above = np.where(avg >= 0.9)[0]
            rise = float(above[0]) if above.size else float(avg.size)
    return SlipFeatures(
        jump_up=float(np.median(jumps_up)) if jumps_up.size else None,
        jump_down=float(np.median(jumps_dn)) if jumps_dn.size else None,
        moving_slope=_moving_slope(op, mv, phase == PHASE_MOVING),
        corner_rise_samples=rise,
    )


def _moving_slope(op, mv, moving) -> float | None:
    """Least-squares slope of mv on op within the stretches of ``moving`` of three or
    more samples (each about its own means), None without any."""
    edges = np.diff(np.concatenate([[0], moving.astype(np.int8), [0]]))
    starts, ends = np.where(edges == 1)[0], np.where(edges == -1)[0]
    long = ends - starts >= 3
    starts, ends = starts[long], ends[long]
    if not starts.size:
        return None
    # The samples of the kept stretches and the stretch each belongs to (stretches
    # are separated by at least one sample outside, so starts and ends never meet).
    step = np.zeros(op.size + 1, dtype=np.int64)
    step[starts] = 1
    step[ends] -= 1
    inside = np.cumsum(step[:-1]) > 0
    first = np.zeros(op.size, dtype=np.int64)
    first[starts] = 1
    idx = (np.cumsum(first) - 1)[inside]
    o, m = op[inside], mv[inside]
    nrun = starts.size
    cnt = (ends - starts).astype(float)
    o = o - (np.bincount(idx, o, nrun) / cnt)[idx]
    m = m - (np.bincount(idx, m, nrun) / cnt)[idx]
    num = float(np.sum(np.bincount(idx, o * m, nrun)))
    den = float(np.sum(np.bincount(idx, o * o, nrun)))
    return num / den if den > 0 else None


def _by_feature(sig, before, after, phase, replay) -> ByFeature:
    """Period, amplitude, jump up and down, moving-phase slope and corner shape of the
    data against the replay before and after."""

    def period_s(x) -> float | None:
        p = dominant_period_samples(x)
        return None if p is None else p * sig.dt

    signals = {
        s: SignalFeatures(
            amplitude_data=_half_range(getattr(sig, s)),
            amplitude_before=_half_range(before[s]),
            amplitude_after=_half_range(after[s]),
            period_s_data=period_s(getattr(sig, s)),
            period_s_before=period_s(before[s]),
            period_s_after=period_s(after[s]),
        )
        for s in before
    }
    valve = None
    if phase is not None and sig.mv is not None:
        valve = ValveFeatures(
            data=_slip_features(sig.op, sig.mv, phase),
            before=_slip_features(sig.op, before["mv"], phase),
            after=_slip_features(sig.op, after["mv"], phase),
        )
    closed = None
    if replay is not None:
        closed = ClosedLoopFeatures(
            period_s_data=replay.period_data_s,
            period_s_replay=replay.period_replay_s,
            measures=replay.measures,
        )
    return ByFeature(signals=PerSignal.of(signals), valve=valve, closed_loop_replay=closed)
