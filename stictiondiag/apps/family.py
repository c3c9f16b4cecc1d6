"""A broad family of simulated control loops, sticky and healthy, for calibrating the
stiction probability (:mod:`stictiondiag.stiction.probability`).

Every loop is a PI loop simulated by :func:`stictiondiag.models.loops.simulate_loop`
(Eq. 3 of Choudhury, Thornhill & Shah 2005) and then recorded as a plant historian
would record it.  Each draw is independent of the label where the plant would be:
loads, tuning, set-point moves, noise, quantisation and compression are drawn from
the same distributions for sticky and healthy loops, so that none of them tells the
label by itself.

What varies (each loop draws one option of each line):

* **valve**: healthy (linear valve, ``mv = op``) or sticky, in equal shares; a sticky
  valve is the data-driven model of Section 5 (Choudhury or Kano et al. 2004 reading)
  or, in a quarter of the sticky loops, the Karnopp physical valve of Section 4
  (Table 1 mass, spring and diaphragm, friction forces from the quasi-static
  correspondence ``S = (Fs + Fc)/k``, ``J = (Fs - Fc)/k``).  S is log-uniform over
  0.3-6 % of span, ``J / S`` uniform over 0-1.  A third of all loops (either label)
  have an equal-percentage installed characteristic.
* **loop**: self-regulating (first order plus dead time; flow, pressure, temperature),
  integrating (level) or a cascade slave (a fast flow loop whose set point is the
  slowly moving output of a master controller).
* **tuning**: SIMC (Skogestad 2003) settings, times a factor: aggressive (gain 1.4-2x,
  integral time 0.5-1x), normal (0.7-1.3x) or sluggish (gain 0.15-0.5x, integral
  time 1.5-3x).
* **external load** at the process output: small coloured noise only, a slow
  drift, random steps, or a periodic load (period 0.3-5 times the loop's own
  time scale).
* **set point**: fixed, or one to four steps (cascade slaves always move).
* **measurement noise**: white, with a standard deviation 1 % to 50 % of the
  noise-free pv's in most loops and 50 % to 150 % (dominant) in a tenth of them
  (:data:`NOISE_RANGE`; the range follows the noise real records carry, see
  ``docs/history.md``, "Why real loops came out inconclusive").
* **recording**: 40 to 400 times the loop's time scale long (600 to 5000 samples),
  sampled every 1-3 simulation steps; in some loops pv (and op)
  quantised to a resolution of 5-40 % of their spread, or compressed by a
  deadband or swinging-door historian (the archive holds a point only when the
  signal leaves the band; the export holds, or interpolates linearly between,
  the archived points).
* **mv** recorded in a quarter of the loops (most plant records, like the ISDB,
  have pv, op and sp only).

The label is the simulated valve: ``sticky`` is True for every valve with friction,
whatever the record shows.  How much the friction shows is kept beside it:
``truth["stiction_share"]``, the variance of the difference between the loop's
noise-free pv and that of its twin with a linear valve (same process, tuning, loads
and set point), over the variance of the recorded pv (:func:`stiction_share`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from stictiondiag.core.errors import StictionError
from stictiondiag.io.tags import read_frame
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.physical import PhysicalValve
from stictiondiag.models.processes import FOPTD, PI, Integrating

if TYPE_CHECKING:
    import pandas as pd

#: Share of sticky loops [-] (healthy loops in the same proportion).
STICKY_SHARE = 0.5
#: Share of sticky loops whose valve is the Karnopp physical model [-].
PHYSICAL_SHARE = 0.25
#: Share of loops with the valve position recorded [-].
MV_SHARE = 0.25
#: Samples simulated before the record starts (transient of the start) [-].
WARMUP = 400
#: Range of the record's length in units of the loop's time scale (process lag plus
#: dead time; closed-loop time constant plus dead time for an integrating loop) [-]:
#: a record an engineer exports spans tens to hundreds of them.
DURATION_SCALES = (40.0, 400.0)
#: Range of recorded samples [-].
N_RANGE = (600, 5000)
#: Measurement noise: standard deviation over the noise-free pv's, log-uniform over
#: this range in most loops [-].  Set from the inputs of real records, no label:
#: the robust white-noise share of pv's spread (first differences' MAD over pv's
#: standard deviation, ``scripts/shift_diagnosis.py``) is 0.13 in the median ISDB loop
#: and 0.41 at its 95th percentile; a noise ratio of 0.5 gives about 0.45.
NOISE_RANGE = (0.01, 0.5)
#: Range of dominant noise, and the share of loops that draw from it [-] (noise
#: beyond the signal stays covered, as rare as it is in plant records).
NOISE_DOMINANT = (0.5, 1.5)
NOISE_DOMINANT_SHARE = 0.1


@dataclass(frozen=True)
class FamilyLoop:
    """One simulated loop as a historian records it.

    Attributes
    ----------
    pv, sp : ndarray
        Process variable and set point [pv units].
    op : ndarray
        Controller output [% of span].
    mv : ndarray or None
        Valve position [% of span], None when not recorded.
    ts : float
        Sample time of the record [s].
    integrating : bool
        The process is integrating.
    loop_type : str
        ``flow``, ``pressure``, ``temperature`` or ``level``.
    sticky : bool
        The simulated valve has friction (the label).
    truth : dict
        The draws behind the loop (JSON-able).
    """

    pv: np.ndarray = field(repr=False)
    op: np.ndarray = field(repr=False)
    sp: np.ndarray = field(repr=False)
    mv: np.ndarray | None = field(repr=False)
    ts: float
    integrating: bool
    loop_type: str
    sticky: bool
    truth: dict = field(default_factory=dict)

    def frame(self) -> pd.DataFrame:
        """The record as a historian exports it: a ``time`` column [s] and the
        loop's tags named by the ISA convention of its loop type (``FIC1.PV``,
        ``FIC1.OP``, ``FIC1.SP``, and ``FIC1.MV`` when the valve position is
        recorded), so that reading it decides the loop type as it does for a
        plant file (:mod:`stictiondiag.io.looptype`)."""
        import pandas as pd

        tag = f"{ISA_PREFIX[self.loop_type]}{self.truth.get('seed', 0)}"
        columns = {
            "time": np.arange(self.pv.size) * self.ts,
            f"{tag}.PV": self.pv,
            f"{tag}.OP": self.op,
            f"{tag}.SP": self.sp,
        }
        if self.mv is not None:
            columns[f"{tag}.MV"] = self.mv
        return pd.DataFrame(columns)

    def tags(self):
        """The record as :class:`stictiondiag.io.tags.Tags`, read from :meth:`frame`
        by the reader of plant files (:func:`stictiondiag.io.tags.read_frame`)."""
        return read_frame(self.frame(), source=f"family-{self.truth.get('seed')}")


#: ISA instrument prefix of a family loop's tags, by loop type.
ISA_PREFIX = {"flow": "FIC", "pressure": "PIC", "temperature": "TIC", "level": "LIC"}


def _loguniform(rng, lo, hi) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _process(rng, kind: str):
    """Process, SIMC tuning and time scale [s] of one loop kind."""
    if kind == "integrating":
        K = _loguniform(rng, 0.005, 0.05)  # pv units per (% s)
        theta = float(rng.uniform(1.0, 8.0))
        tau_c = max(theta, 2.0) * rng.uniform(1.0, 3.0)
        Kc = 1.0 / (K * (tau_c + theta))
        Ti = 4.0 * (tau_c + theta)
        return Integrating(gain=K, dead_time=theta), Kc, Ti, tau_c + theta, K * 20.0
    if kind in ("flow", "slave"):
        T = float(rng.uniform(2.0, 10.0))
        theta = float(rng.uniform(0.5, 2.0))
    else:
        T = _loguniform(rng, 10.0, 120.0)
        theta = float(rng.uniform(1.0, 0.4 * T))
    K = _loguniform(rng, 0.3, 3.0)
    tau_c = max(theta, 1.0)
    Kc = T / (K * (tau_c + theta))
    Ti = min(T, 4.0 * (tau_c + theta))
    return FOPTD(gain=K, time_constant=T, dead_time=theta), Kc, Ti, T + theta, K


def _filtered_walk(rng, n: int, corr: float) -> np.ndarray:
    """Unit-spread slow random signal: white noise through two first-order lags."""
    from scipy.signal import lfilter

    a = math.exp(-1.0 / corr)
    x = rng.normal(size=n)
    for _ in range(2):
        x = lfilter([1.0 - a], [1.0, -a], x)
    s = float(np.std(x))
    return x / s if s > 0 else x


def _load(rng, kind: str, n: int, scale: float, t_loop: float) -> np.ndarray:
    """External load at the process output [pv units]."""
    base = 0.05 * scale * _filtered_walk(rng, n, max(2.0, t_loop / 4))
    amp = scale * _loguniform(rng, 0.3, 4.0)
    if kind == "drift":
        return base + amp * _filtered_walk(rng, n, float(rng.uniform(20, 60)) * t_loop)
    if kind == "steps":
        out = np.zeros(n)
        for k0 in rng.integers(0, n, size=int(rng.integers(1, 6))):
            out[k0:] += amp * rng.normal()
        return base + out
    if kind == "periodic":
        period = t_loop * _loguniform(rng, 2.0, 30.0)
        t = np.arange(n)
        phase = rng.uniform(0, 2 * math.pi)
        wave = np.sin(2 * math.pi * t / period + phase)
        wave += rng.uniform(0, 0.3) * np.sin(4 * math.pi * t / period)
        return base + amp * wave
    return base


def _setpoint(rng, kind: str, moves: bool, n: int, scale: float, t_loop: float) -> np.ndarray:
    sp = np.zeros(n)
    if kind == "slave":
        # The master's output: slow movement, sometimes its own slow cycle.
        sp += scale * _loguniform(rng, 0.5, 4.0) * _filtered_walk(rng, n, 30.0 * t_loop)
        if rng.random() < 0.3:
            period = t_loop * _loguniform(rng, 20.0, 80.0)
            sp += scale * rng.uniform(0.5, 2.0) * np.sin(2 * math.pi * np.arange(n) / period)
    elif moves:
        for k0 in rng.integers(WARMUP, n, size=int(rng.integers(1, 5))):
            sp[k0:] += scale * rng.uniform(1.0, 5.0) * rng.choice([-1.0, 1.0])
    return sp


def _quantise(x: np.ndarray, q: float) -> np.ndarray:
    return np.round(x / q) * q if q > 0 else x


def _deadband_archive(x: np.ndarray, d: float) -> np.ndarray:
    """Deadband compression: hold the last archived value until x leaves +-d of it."""
    y = np.empty_like(x)
    last = x[0]
    for k in range(x.size):
        if abs(x[k] - last) > d:
            last = x[k]
        y[k] = last
    return y


def _swinging_door(x: np.ndarray, d: float) -> np.ndarray:
    """Swinging-door compression (Bristol 1990), exported by linear interpolation
    between the archived points.

    From the last archived point the door keeps the slopes that pass within ``d`` of
    every sample since; when no slope is left, the point before is archived on the
    middle of the slopes that were still open, so every exported sample lies within
    ``d`` of the recorded one.
    """
    idx, val = [0], [float(x[0])]
    lo, hi = -np.inf, np.inf
    for k in range(1, x.size):
        a, xa = idx[-1], val[-1]
        dt = k - a
        new_hi = min(hi, (x[k] + d - xa) / dt)
        new_lo = max(lo, (x[k] - d - xa) / dt)
        if new_lo > new_hi:
            slope = 0.5 * (lo + hi)
            idx.append(k - 1)
            val.append(xa + slope * (k - 1 - a))
            hi = x[k] + d - val[-1]
            lo = x[k] - d - val[-1]
        else:
            lo, hi = new_lo, new_hi
    if idx[-1] != x.size - 1:
        a, xa = idx[-1], val[-1]
        idx.append(x.size - 1)
        val.append(xa + 0.5 * (lo + hi) * (x.size - 1 - a))
    return np.interp(np.arange(x.size), np.array(idx), np.array(val))


def _record(rng, pv, op, how: str):
    """Quantise or compress pv and op as a historian would."""
    if how == "quantised":
        pv = _quantise(pv, float(np.std(pv)) * rng.uniform(0.05, 0.4))
        if rng.random() < 0.5:
            op = _quantise(op, rng.uniform(0.1, 0.5))
    elif how in ("deadband", "swinging_door"):
        f = _deadband_archive if how == "deadband" else _swinging_door
        pv = f(pv, float(np.std(pv)) * rng.uniform(0.05, 0.3))
        op = f(op, float(np.std(op)) * rng.uniform(0.02, 0.2))
    return pv, op


def stiction_share(effect: np.ndarray, pv: np.ndarray) -> float:
    """How much of the recorded pv the valve's friction accounts for [-]: the variance
    of ``effect`` (the noise-free pv of the loop minus that of its twin with a linear
    valve) over the variance of the recorded pv.  It can exceed 1 where the twin's pv
    moves in ways the sticky loop's does not.
    """
    v = float(np.var(pv))
    return float(np.var(effect) / v) if v > 0 else 0.0


def _pick(rng, options: dict) -> str:
    keys = list(options)
    p = np.array([options[k] for k in keys], dtype=float)
    return str(keys[int(rng.choice(len(keys), p=p / p.sum()))])


@dataclass(frozen=True)
class LoopSetup:
    """What every simulation of one family loop (the loop and its twins) shares.

    ``n`` is the record's length [samples of 1 s, warm-up included]; ``valve`` the
    stiction model and ``S``, ``J`` [% of span] (``physical`` the Karnopp valve
    where ``valve`` is ``"physical"``); ``op_bias`` [% of span]; ``seed`` the noise
    sequence's, the same for a loop and its twins; ``friction_scale`` and
    ``friction_asymmetry`` a friction that varies over time and with the direction
    of travel (:func:`stictiondiag.models.loops.simulate_loop`; None and 0: constant).
    """

    process: FOPTD | Integrating
    n: int
    valve: str
    S: float
    J: float
    physical: PhysicalValve | None
    op_bias: float
    characteristic: str
    seed: int
    friction_scale: np.ndarray | None = None
    friction_asymmetry: float = 0.0

    def simulate(self, controller: PI, *, sp, load, noise_std: float, linear: bool = False):
        """The closed loop under ``controller`` (:func:`simulate_loop`); with
        ``linear`` the twin whose valve is linear."""
        return simulate_loop(
            self.process,
            controller,
            duration=float(self.n),
            dt=1.0,
            valve="linear" if linear else self.valve,
            S=0.0 if linear else self.S,
            J=0.0 if linear else self.J,
            friction_scale=None if linear else self.friction_scale,
            friction_asymmetry=0.0 if linear else self.friction_asymmetry,
            physical=None if linear else self.physical,
            sp=sp,
            load=load,
            noise_std=noise_std,
            seed=self.seed,
            op_bias=self.op_bias,
            characteristic=self.characteristic,
        )


def _controller(rng, tuning: str, Kc: float, Ti: float) -> PI:
    """The PI controller of a tuning class: the process's SIMC gain and integral
    time scaled by drawn factors (all six drawn whatever the class, so the draws
    that follow do not depend on it)."""
    fk, fi = {
        "aggressive": (rng.uniform(1.4, 2.0), rng.uniform(0.5, 1.0)),
        "normal": (rng.uniform(0.7, 1.3), rng.uniform(0.8, 1.2)),
        "sluggish": (rng.uniform(0.15, 0.5), rng.uniform(1.5, 3.0)),
    }[tuning]
    return PI(gain=float(Kc * fk), integral_time=float(Ti * fi))


def _valve_draw(rng, sticky: bool) -> tuple[float, float, str]:
    """S and J [% of span] and the stiction model of a sticky valve (a linear valve
    draws nothing)."""
    if not sticky:
        return 0.0, 0.0, "linear"
    S = _loguniform(rng, 0.3, 6.0)
    J = S * float(rng.uniform(0.0, 1.0))
    shares = {
        "choudhury": (1 - PHYSICAL_SHARE) / 2,
        "kano": (1 - PHYSICAL_SHARE) / 2,
        "physical": PHYSICAL_SHARE,
    }
    return S, J, _pick(rng, shares)


def physical_valve(S: float, J: float) -> PhysicalValve:
    """The physical valve whose friction gives the band S and jump J [% of span] of a
    family loop: ``Fs = k (S + J) / 2`` and ``Fc = k (S - J) / 2`` with Table 1's
    spring constant ``k`` [N/m] and 1 % of span = 0.01 m of stem travel."""
    k = 52_500.0
    return PhysicalValve(Fs=k * 0.01 * (S + J) / 2, Fc=k * 0.01 * (S - J) / 2, time_step=5e-4)


def loop_type_of(kind: str, t_loop: float) -> str:
    """The loop type a family loop of ``kind`` and time scale ``t_loop`` [s] stands
    for (flow, level, pressure or temperature)."""
    return {"flow": "flow", "slave": "flow", "integrating": "level"}.get(
        kind, "pressure" if t_loop < 40 else "temperature"
    )


def family_loop(seed: int, *, twin: bool = False) -> FamilyLoop:
    """One loop of the family, a deterministic function of ``seed``.

    With ``twin`` the loop's twin with a linear valve: every draw the same (process,
    tuning, loads, set point, noise and its level, recording), only the valve
    linear; ``sticky`` is then False and ``truth["twin"]`` True.
    """
    rng = np.random.default_rng(seed)
    sticky = bool(rng.random() < STICKY_SHARE)
    kind = _pick(rng, {"flow": 0.25, "self": 0.3, "integrating": 0.25, "slave": 0.2})
    tuning = _pick(rng, {"aggressive": 0.25, "normal": 0.45, "sluggish": 0.3})
    load_kind = _pick(rng, {"none": 0.25, "drift": 0.25, "steps": 0.2, "periodic": 0.3})
    record = _pick(rng, {"plain": 0.55, "quantised": 0.15, "deadband": 0.15, "swinging_door": 0.15})
    has_mv = bool(rng.random() < MV_SHARE)
    sp_moves = bool(rng.random() < 0.3)
    characteristic = "equal_percentage" if rng.random() < 1 / 3 else "linear"
    decim = int(rng.choice([1, 1, 2, 3]))
    span = _loguniform(rng, *DURATION_SCALES)

    process, Kc, Ti, t_loop, scale = _process(rng, kind)
    n_rec = int(np.clip(span * t_loop / decim, *N_RANGE))
    controller = _controller(rng, tuning, Kc, Ti)
    S, J, valve = _valve_draw(rng, sticky)
    physical = physical_valve(S, J) if valve == "physical" else None
    if physical is not None:
        n_rec = min(n_rec, 2000)  # the physical valve's fine time step is slow
    n = WARMUP + n_rec * decim
    load = _load(rng, load_kind, n, scale, t_loop)
    sp = _setpoint(rng, kind, sp_moves, n, scale, t_loop)
    dominant = bool(rng.random() < NOISE_DOMINANT_SHARE)
    noise_ratio = _loguniform(rng, *(NOISE_DOMINANT if dominant else NOISE_RANGE))
    op_bias = float(rng.uniform(30.0, 70.0))
    sim_seed = int(rng.integers(2**31))

    setup = LoopSetup(process, n, valve, S, J, physical, op_bias, characteristic, sim_seed)

    def run(noise_std: float, linear: bool = False):
        return setup.simulate(controller, sp=sp, load=load, noise_std=noise_std, linear=linear)

    clean = run(0.0)
    spread = float(np.std(clean.pv[WARMUP:])) or scale * 0.01
    sim = run(noise_ratio * spread, linear=twin)
    sl = slice(WARMUP, n, decim)
    pv, op, mv, spv = sim.pv[sl].copy(), sim.op[sl].copy(), sim.mv[sl].copy(), sim.sp[sl].copy()
    pv, op = _record(rng, pv, op, record)
    label = sticky and not twin  # a twin's valve is linear
    share = 0.0
    if label:
        # Its twin with a linear valve: same process, tuning, loads and set point.
        share = stiction_share((clean.pv - run(0.0, linear=True).pv)[sl], pv)
    if has_mv:
        mv = mv + rng.normal(0.0, rng.uniform(0.02, 0.2), mv.size)
    truth = {
        "seed": int(seed),
        "sticky": label,
        "twin": twin,
        "valve": valve,
        "S": S,
        "J": J,
        "kind": kind,
        "tuning": tuning,
        "load": load_kind,
        "record": record,
        "has_mv": has_mv,
        "sp_moves": sp_moves or kind == "slave",
        "characteristic": characteristic,
        "noise_ratio": noise_ratio,
        "decimation": decim,
        "n": int(pv.size),
        "saturated": float(np.mean((op <= 0.0) | (op >= 100.0))),
        "stiction_share": share,
    }
    return FamilyLoop(
        pv=pv,
        op=op,
        sp=spv,
        mv=mv if has_mv else None,
        ts=float(decim),
        integrating=kind == "integrating",
        loop_type=loop_type_of(kind, t_loop),
        sticky=label,
        truth=truth,
    )


def loop_features(loop: FamilyLoop, *, with_classic: bool = False):
    """The probability model's features of one family loop: the loop read as a
    plant file (:meth:`FamilyLoop.tags`) and taken through the head of the analysis
    chain (:func:`stictiondiag.analysis.estimate_loop`), whose
    :meth:`~stictiondiag.analysis.LoopEstimate.features` are what the verdict
    decides on.

    Returns the features (a dict of :data:`~stictiondiag.stiction.probability.CANDIDATES`),
    or with ``with_classic`` the pair (features, the classic tests' statistics and the
    shape statistics); None for a loop the analysis refuses (a record too short for
    its cycle, or data it cannot use), as it would refuse a plant record.
    """
    # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
    from stictiondiag.analysis import estimate_loop

    try:
        features, _, classic = estimate_loop(loop.tags()).features()
    except StictionError:
        return None
    return (features, classic) if with_classic else features
