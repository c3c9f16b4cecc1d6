"""Where the gap lies: by signal, valve phase, frequency, time and feature, before and after.

The phases are those of Fig. 2 of Choudhury, Thornhill & Shah (2005) (A-B reversal,
B-C stuck, C-D slip, D-E moving), read from the base valve replay.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from stictiondiag.models.valve import PHASE_MOVING, PHASE_NAMES, PHASE_SLIP


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


def breakdown(sig, ctx, meas, base, before: dict, after: dict, replay) -> dict:
    """Where the gap lies: by signal, phase, frequency, time and feature, before and after."""
    out = {
        "signal": {
            s: {
                "before": 100.0
                * math.sqrt(meas.excess(s, meas.nmse(s, before[s], getattr(sig, s)))),
                "after": 100.0 * math.sqrt(meas.excess(s, meas.nmse(s, after[s], getattr(sig, s)))),
                "noise_floor": 100.0 * math.sqrt(meas.floor[s] / meas.norm[s]),
            }
            for s in before
        }
    }
    phase = base.valve.phase if base.valve is not None else None
    if phase is not None:
        out["phase"] = _by_phase(sig, meas, phase, before, after)
    out["frequency"] = _by_frequency(sig, meas, before, after)
    out["time"] = _by_time(sig, meas, before, after)
    out["feature"] = _by_feature(sig, base, before, after, phase, replay)
    return out


def _phase_labels(phase: np.ndarray) -> np.ndarray:
    """Phase per sample with the breakaway sample and the two after it called slip."""
    lab = phase.astype(np.int64).copy()
    slips = np.where(phase == PHASE_SLIP)[0]
    for k in (1, 2):
        idx = slips + k
        idx = idx[idx < lab.size]
        lab[idx] = PHASE_SLIP
    return lab


def _by_phase(sig, meas, phase, before, after) -> dict:
    """Share of the mv (and pv) squared error in each valve phase (Fig. 2: A-B reversal,
    B-C stuck, C-D slip, D-E moving)."""
    lab = _phase_labels(phase)
    res: dict[str, dict[str, float | None]] = {}
    for s in ("mv", "pv"):
        if s not in before:
            continue
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            e = meas.w * (preds[s] - x) ** 2
            tot = float(e.sum()) or 1.0
            for code, name in PHASE_NAMES.items():
                m = lab == code
                entry = res.setdefault(name, {})
                entry.setdefault("samples_pct", 100.0 * float(np.mean(m)))
                entry[f"{s}_share_pct_{when}"] = 100.0 * float(e[m].sum()) / tot
                n_m = float((meas.w * m).sum())
                entry[f"{s}_rms_{when}"] = math.sqrt(float(e[m].sum()) / n_m) if n_m > 0 else None
    return res


def _fundamental(sig) -> float | None:
    """Period of the loop's oscillation [samples], from op (or pv)."""
    for x in (sig.op, sig.pv):
        p = dominant_period_samples(x)
        if p is not None:
            return p
    return None


def _by_frequency(sig, meas, before, after) -> dict:
    """Share of each signal's replay-error energy at the loop's fundamental, at its
    harmonics (2nd to 10th) and elsewhere [%]; None for a signal whose replay has no
    error (exact to rounding)."""
    period = _fundamental(sig)
    res: dict[str, Any] = {"fundamental_period_s": None if period is None else period * sig.dt}
    if period is None:
        return res
    f0 = 1.0 / period
    for s in before:
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            r = (preds[s] - x) * meas.w
            n = r.size
            nfft = 1 << int(math.ceil(math.log2(n)))
            spec = np.abs(np.fft.rfft(r - r.mean(), nfft)) ** 2
            f = np.arange(spec.size) / nfft
            entry = res.setdefault(s, {})
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
    return res


def _by_time(sig, meas, before, after) -> dict:
    """Gap of each signal in the first and the second half of the record [%]."""
    n = sig.n
    halves = {"early": np.arange(n) < n // 2, "late": np.arange(n) >= n // 2}
    res: dict[str, dict[str, float]] = {}
    for s in before:
        x = getattr(sig, s)
        for when, preds in (("before", before), ("after", after)):
            for half, m in halves.items():
                v = meas.nmse(s, preds[s], x, meas.w * m)
                res.setdefault(s, {})[f"{half}_{when}"] = 100.0 * math.sqrt(meas.excess(s, v))
    return res


def _half_range(x: np.ndarray) -> float:
    return 0.5 * float(np.percentile(x, 98) - np.percentile(x, 2))


def _slip_features(op, mv, phase, window: int = 3) -> dict:
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
    return {
        "jump_up": float(np.median(jumps_up)) if jumps_up.size else None,
        "jump_down": float(np.median(jumps_dn)) if jumps_dn.size else None,
        "moving_slope": _moving_slope(op, mv, phase == PHASE_MOVING),
        "corner_rise_samples": rise,
    }


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


def _by_feature(sig, base, before, after, phase, replay) -> dict:
    """Period, amplitude, jump up and down, moving-phase slope and corner shape of the
    data against the replay before and after."""
    res: dict[str, dict[str, Any]] = {}
    for s in before:
        x = getattr(sig, s)
        entry: dict[str, float | None] = {"amplitude_data": _half_range(x)}
        for when, preds in (("before", before), ("after", after)):
            entry[f"amplitude_{when}"] = _half_range(preds[s])
        p = dominant_period_samples(x)
        entry["period_s_data"] = None if p is None else p * sig.dt
        for when, preds in (("before", before), ("after", after)):
            p = dominant_period_samples(preds[s])
            entry[f"period_s_{when}"] = None if p is None else p * sig.dt
        res[s] = entry
    if phase is not None and sig.mv is not None:
        res["valve"] = {
            "data": _slip_features(sig.op, sig.mv, phase),
            "before": _slip_features(sig.op, before["mv"], phase),
            "after": _slip_features(sig.op, after["mv"], phase),
        }
    if replay is not None:
        closed = {}
        for key in ("period_s", "amplitude"):
            v = getattr(replay, key, None)
            if v is not None:
                closed[key] = v
        if closed:
            res["closed_loop_replay"] = closed
    return res
