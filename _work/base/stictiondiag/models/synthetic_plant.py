"""Simulated plants with plant-wide oscillations: sticky sources and their propagation.

A plant of 5 to 15 PI loops on self-regulating FOPTD processes, sampled together
(one time grid, a wide export ``time, FIC101.PV, FIC101.OP, FIC101.SP, ...``):

* one or two **sources**: a loop whose valve sticks (the stick-slip element of
  Section 5.1 of Choudhury, Thornhill & Shah 2005, from the benchmark's own kernel
  :func:`stictiondiag.models.synthetic_loop.closed_loop`), which limit-cycles;
* **propagated** loops downstream of a source: healthy loops (linear valve) whose
  process output receives the pv of an upstream loop of the same group (the source
  or a loop already reached by its cycle) through a first-order-plus-dead-time
  coupling ``g e^{-theta s} / (tau s + 1)``, as a feed or a heat duty passes from
  one unit to the next (Thornhill & Horch 2007, Section 2);
* **independent** loops with their own cause: ``tuning`` (a PI at a gain margin of 1.3-1.8,
  an oscillatory response to noise at the loop's own period), ``external`` (a sinusoidal load of its own period) or
  ``none`` (noise and a wandering load only).  Their periods are kept at least
  a factor :data:`MIN_PERIOD_SEPARATION` away from every source's and from each
  other's (two loops cycling at one period share an oscillation for any
  spectral method, whatever the cause).

The truth of every loop (:attr:`SyntheticPlant.truth`) says its role, group and
cause; the diagnosis sees only the export.  Like :mod:`stictiondiag.models.synthetic`
this module imports nothing from the valve, loop or identification modules the
diagnosis uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from stictiondiag.models.synthetic_loop import closed_loop

__all__ = ["SyntheticPlant", "generate_plant", "PLANT_CAUSES"]

#: Causes of an independent loop.
PLANT_CAUSES = ("tuning", "external", "none")
#: Smallest ratio between an independent loop's period and any source's period [-].
MIN_PERIOD_SEPARATION = 1.3
#: Fewest cycles of a source's limit cycle in the record.
MIN_SOURCE_CYCLES = 12
#: Loops per plant (inclusive bounds).
N_LOOPS = (5, 15)


@dataclass(frozen=True)
class SyntheticPlant:
    """One simulated plant.

    Attributes
    ----------
    seed : int
        Seed it was generated from.
    ts : float
        Sample time [s].
    frame : DataFrame
        Wide export: ``time`` [s], then ``<loop>.PV`` [pv units], ``<loop>.OP``
        [% of span] and ``<loop>.SP`` [pv units] per loop.
    truth : dict
        Loop -> ``{"role": "source" | "propagated" | "independent", "group": int
        or None, "source": loop or None, "upstream": loop or None, "cause":
        "stiction" | "propagated" | "tuning" | "external" | "none", "period_s":
        the loop's own cycle period [s] or None}``.
    groups : dict
        Group id -> ``{"source": loop, "members": [loops], "period_s": float}``.
    """

    seed: int
    ts: float
    frame: pd.DataFrame = field(repr=False)
    truth: dict
    groups: dict

    @property
    def loops(self) -> list[str]:
        """Loop names in export order."""
        return list(self.truth)


def _spectral_period(x: np.ndarray, ts: float) -> float:
    """Period [s] of the largest periodogram peak of the detrended signal (the truth's record)."""
    x = np.asarray(x, float)
    x = x - np.polyval(np.polyfit(np.arange(x.size), x, 1), np.arange(x.size))
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    f = np.fft.rfftfreq(x.size, ts)
    lo = 6  # the lowest bins hold the drift, not a cycle of the record
    k = lo + int(np.argmax(p[lo:]))
    return float(1.0 / f[k])


def _foptd_filter(u: np.ndarray, ts: float, gain: float, tau: float, delay: int) -> np.ndarray:
    """``gain e^{-delay ts s} / (tau s + 1)`` applied to ``u`` (exact for a held input)."""
    a = math.exp(-ts / tau)
    y = np.empty_like(u)
    state = 0.0
    shifted = np.concatenate([np.full(delay, u[0]), u[: u.size - delay]]) if delay else u
    for k in range(u.size):
        state = a * state + (1.0 - a) * shifted[k]
        y[k] = gain * state
    return y


def _ultimate_kc(gain: float, tau: float, theta: float, ti: float) -> float:
    """Controller gain at which the PI loop on ``K e^{-theta s}/(tau s + 1)`` is marginal."""
    w = np.geomspace(1e-4, 10.0, 20000) / max(theta, 1e-3)
    phase = -w * theta - np.arctan(w * tau) - np.pi / 2 + np.arctan(w * ti)
    k = int(np.argmax(phase <= -np.pi))
    mag = gain / np.sqrt(1 + (w[k] * tau) ** 2) * np.sqrt(1 + (w[k] * ti) ** 2) / (w[k] * ti)
    return float(1.0 / mag)


def _loop(
    rng: np.random.Generator,
    n: int,
    ts: float,
    *,
    gain: float,
    tau: float,
    delay: int,
    kc: float,
    ti: float,
    S: float = 0.0,
    J: float = 0.0,
    load: np.ndarray,
    noise_std: float,
    pv0: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One closed loop of the benchmark kernel: pv, op, sp (no mv recorded)."""
    sp = np.full(n, pv0)
    zeros = np.zeros(n)
    s_arr, j_arr = np.full(n, S), np.full(n, J)
    pv, op, *_ = closed_loop(
        ts, False, gain, tau, delay, kc, ti, 1.0, 50.0, pv0, 0.0, sp, zeros, load,
        rng.normal(0.0, noise_std, n), False, s_arr, j_arr, s_arr, j_arr,
        1.0, 50.0, 1.0, 0, 50.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, ts, 1e-6,
    )  # fmt: skip
    return pv, op, sp


def _wander(rng: np.random.Generator, n: int, std: float) -> np.ndarray:
    """Slow AR(1) load (pole 0.995) of standard deviation ``std``."""
    e = rng.normal(0.0, std * math.sqrt(1 - 0.995**2), n)
    out = np.empty(n)
    acc = 0.0
    for k in range(n):
        acc = 0.995 * acc + e[k]
        out[k] = acc
    return out


def _process(rng: np.random.Generator, ts: float) -> tuple[float, float, int]:
    return (
        float(rng.uniform(0.8, 2.0)),
        float(rng.uniform(4.0, 20.0)) * ts,
        int(rng.integers(1, 4)),
    )


def generate_plant(
    seed: int, *, n_loops: int | None = None, n_samples: int = 3000, ts: float = 1.0
) -> SyntheticPlant:
    """Draw and simulate one plant (see the module docstring).

    Parameters
    ----------
    seed : int
        Seed of every random draw (same seed, same plant).
    n_loops : int, optional
        Loops in the plant, 5-15 (default drawn).
    n_samples : int
        Samples per loop.
    ts : float
        Sample time [s].
    """
    rng = np.random.default_rng(seed)
    n = int(n_samples)
    if n_loops is None:
        n_loops = int(rng.integers(N_LOOPS[0], N_LOOPS[1] + 1))
    n_loops = int(min(max(n_loops, N_LOOPS[0]), N_LOOPS[1]))
    n_sources = 2 if n_loops >= 8 and rng.random() < 0.5 else 1
    # Each source reaches 1-4 loops (at least one); the rest are independent.
    budget = n_loops - n_sources
    reach: list[int] = []
    for _ in range(n_sources):
        k = int(rng.integers(1, min(4, budget - (n_sources - len(reach) - 1)) + 1))
        reach.append(k)
        budget -= k
    prefixes = ("FIC", "TIC", "PIC")
    names = [f"{prefixes[i % 3]}{101 + i}" for i in range(n_loops)]
    order = list(rng.permutation(n_loops))
    signals: dict[str, tuple] = {}
    truth: dict[str, dict] = {}
    groups: dict[int, dict] = {}
    source_periods: list[float] = []
    for g in range(n_sources):
        src = names[order.pop()]
        pv, op, sp, S, J = _sticky_loop(rng, n, ts)
        period = _spectral_period(pv, ts)
        # A second source must cycle at a clearly other period, or the groups merge.
        if any(max(period, p) / min(period, p) < MIN_PERIOD_SEPARATION for p in source_periods):
            order.append(names.index(src))
            reach[g] = 0
            continue
        source_periods.append(period)
        signals[src] = (pv, op, sp)
        gid = len(groups) + 1
        truth[src] = {
            "role": "source", "group": gid, "source": src, "upstream": None,
            "cause": "stiction", "period_s": period, "S": S, "J": J,
        }  # fmt: skip
        members = [src]
        for _ in range(reach[g]):
            name = names[order.pop()]
            upstream = members[int(rng.integers(0, len(members)))]
            up = signals[upstream][0]
            coupled = _foptd_filter(
                (up - up.mean()) / (up.std() or 1.0), ts, 1.0,
                float(rng.uniform(2.0, 15.0)) * ts, int(rng.integers(0, 10)),
            )  # fmt: skip
            amp = float(rng.uniform(0.5, 2.0))
            load = amp * coupled / (coupled.std() or 1.0) + _wander(rng, n, 0.2)
            gain, tau, delay = _process(rng, ts)
            kc = float(rng.uniform(0.2, 0.6)) / gain
            pv, op, sp = _loop(
                rng, n, ts, gain=gain, tau=tau, delay=delay, kc=kc, ti=tau,
                load=load, noise_std=float(rng.uniform(0.05, 0.2)), pv0=50.0,
            )  # fmt: skip
            signals[name] = (pv, op, sp)
            truth[name] = {
                "role": "propagated", "group": gid, "source": src, "upstream": upstream,
                "cause": "propagated", "period_s": period,
            }  # fmt: skip
            members.append(name)
        groups[gid] = {"source": src, "members": members, "period_s": period}
    taken = list(source_periods)
    for i, idx in enumerate(order):
        name = names[idx]
        cause = PLANT_CAUSES[(i + int(rng.integers(0, 3))) % 3]
        signals[name], own = _independent(rng, n, ts, cause, taken)
        if own is not None:
            taken.append(own)
        truth[name] = {
            "role": "independent", "group": None, "source": None, "upstream": None,
            "cause": cause, "period_s": own,
        }  # fmt: skip
    frame = pd.DataFrame({"time": np.arange(n) * ts})
    for name in names:
        pv, op, sp = signals[name]
        frame[f"{name}.PV"] = np.round(pv, 5)
        frame[f"{name}.OP"] = np.round(op, 4)
        frame[f"{name}.SP"] = sp
    truth = {name: truth[name] for name in names}
    return SyntheticPlant(int(seed), float(ts), frame, truth, groups)


def _sticky_loop(rng: np.random.Generator, n: int, ts: float) -> tuple:
    """A loop with a sticky valve, redrawn until it limit-cycles.

    The cycle must repeat at least :data:`MIN_SOURCE_CYCLES` times in the record
    and hold a third of the pv's power in its band (a slow, wandering cycle is no
    clear source for anyone to find); the last draw is kept after 20 tries.
    """
    for _ in range(20):
        gain, tau, delay = _process(rng, ts)
        S = float(rng.uniform(2.0, 6.0))
        J = float(rng.uniform(0.3, 0.8)) * S
        kc = float(rng.uniform(0.3, 0.8)) / gain
        ti = float(rng.uniform(0.5, 1.5)) * tau
        noise = float(rng.uniform(0.02, 0.1))
        pv, op, sp = _loop(
            rng, n, ts, gain=gain, tau=tau, delay=delay, kc=kc, ti=ti, S=S, J=J,
            load=_wander(rng, n, 0.3), noise_std=noise, pv0=50.0,
        )  # fmt: skip
        period = _spectral_period(pv, ts)
        if period * MIN_SOURCE_CYCLES <= n * ts and _cycle_share(pv, ts, period) >= 1 / 3:
            break
    return pv, op, sp, S, J


def _cycle_share(x: np.ndarray, ts: float, period: float) -> float:
    """Share of the detrended signal's power within 10 % of ``1 / period``."""
    x = np.asarray(x, float)
    x = x - np.polyval(np.polyfit(np.arange(x.size), x, 1), np.arange(x.size))
    p = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
    f = np.fft.rfftfreq(x.size, ts)
    band = (f >= 1 / (1.1 * period)) & (f <= 1.1 / period)
    return float(p[band].sum() / p[6:].sum())


def _independent(
    rng: np.random.Generator, n: int, ts: float, cause: str, taken: list[float]
) -> tuple[tuple, float | None]:
    """A loop with its own cause, redrawn until its period is apart from the others'."""
    for _ in range(20):
        gain, tau, delay = _process(rng, ts)
        ti = float(rng.uniform(0.7, 1.2)) * tau
        load = _wander(rng, n, 0.3)
        kc = float(rng.uniform(0.2, 0.6)) / gain
        own: float | None = None
        if cause == "tuning":
            # The held input of a sampled loop adds half a sample of delay.
            kc = _ultimate_kc(gain, tau, (delay + 0.5) * ts, ti) / float(rng.uniform(1.3, 1.8))
            load = _wander(rng, n, 0.1) + rng.normal(0.0, 0.3, n)
        elif cause == "external":
            own = float(rng.uniform(15.0, 400.0)) * ts
            phase = float(rng.uniform(0, 2 * np.pi))
            load = load + float(rng.uniform(0.5, 2.0)) * np.sin(
                2 * np.pi * np.arange(n) * ts / own + phase
            )
        pv, op, sp = _loop(
            rng, n, ts, gain=gain, tau=tau, delay=delay, kc=kc, ti=ti,
            load=load, noise_std=float(rng.uniform(0.05, 0.2)), pv0=50.0,
        )  # fmt: skip
        if cause == "tuning":
            own = _spectral_period(pv, ts)
        if own is None or all(max(own, p) / min(own, p) >= MIN_PERIOD_SEPARATION for p in taken):
            return (pv, op, sp), own
    return (pv, op, sp), own
