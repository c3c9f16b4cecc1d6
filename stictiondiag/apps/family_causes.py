"""Simulated loops that oscillate for different reasons, labelled by counterfactual
twins, for the cause model of :mod:`stictiondiag.stiction.cause`.

Plant experts ask *why* a loop oscillates (the ISDB comments name stiction, tight
tuning, an external disturbance, quantisation, or no oscillation at all).  The
friction family of :mod:`stictiondiag.apps.family` asks whether the valve has any
friction, which most simulated sticky valves never show.  This family draws each loop
from one of several **generators**, each a plausible source of a plant oscillation:

``valve``
    A sticky valve (S log-uniform over 1-8 % of span, ``J/S`` uniform over 0.2-1,
    pure dead band ``J = 0`` in a tenth of them) under normal or aggressive SIMC
    tuning or the integral-dominant tuning plants often run (every generator draws
    its tuning the same way, :func:`_tuning`), with random non-periodic loads.  The stick model itself is drawn:
    Choudhury's data-driven model, Kano et al.'s, Karnopp's physical valve (Section 4
    of Choudhury, Thornhill & Shah 2005), He et al.'s two-parameter model or a valve
    that holds until its demand moves more than a band
    (:mod:`stictiondiag.models.stick_models`).  With ``varying_friction`` (only on
    request: the shipped cause model was fitted on constant friction) its friction
    varies as real friction does (:data:`FRICTION_VARIATION`), over time and with
    the direction of travel, and an external triangle leans as such a valve's
    cycle would; ``scripts/train_cause.py --varying-friction`` measures the model
    on such loops.
``tuning``
    A linear valve and a PI controller tuned tight, at a gain margin of 1.1 to 1.8
    (:func:`ultimate_gain`): a lightly damped loop rung by its noise and loads.
``external``
    A linear valve (or, in a quarter of them, a mildly sticky one) and a periodic
    load that is not a sinusoid in most loops: a triangle (an upstream sticky valve's
    cycle through a lag), a square wave, two tones, intermittent bursts, or a sine;
    for cascade slaves the master's set point carries the oscillation.
``deadzone`` (only on request, ``generator="deadzone"``: not in the draw of
:data:`GENERATORS`, so the training family stays the one the shipped cause model was
fitted on; ``scripts/train_cause.py --deadzone`` measures the model on it)
    An integrating loop (a level) with a linear valve whose controller ignores errors
    inside a dead zone of half-width 1-4 times the spread of its noise-free pv without
    it (``e - clip(e, -dz, dz)``, a gap action), little measurement noise: the level
    drifts across the zone and the controller pushes it back, a cycle no valve causes.
``quantiser``
    A linear valve and a controller that sees pv through a quantiser (a coarse
    transmitter or A/D converter; a step of 1-4 times the spread of the loop's
    noise-free pv without it, little measurement noise; :func:`_quantised_loop`): the integral action hunts between two
    levels, a limit cycle no valve causes.

Every generator uses the friction family's process kinds (flow, self-regulating,
integrating, cascade slave), noise levels and historian recording
(:func:`stictiondiag.apps.family._record`).

The label is a **counterfactual**: the loop is simulated again with one change at a
time, with every other draw (noise sequence included) the same,

1. a linear valve (``valve``),
2. without the external oscillation (``external``),
3. without the quantiser or the dead zone (``other``),
4. with conservative tuning, a quarter of the ultimate gain and twice the
   integral time (``tuning``; tried last, because slowing the controller down
   slows, and so can hide within the record, a cycle it does not cause),

and the cause is the first change whose twin no longer oscillates (the stage-1 test,
:func:`stictiondiag.stiction.cause.cycle_of_record`, on the twin's record).  A loop
that does not oscillate is labelled ``none``; one whose cycle survives every change
is ``unexplained`` and left out of training.  So the label never comes from the
generator: a sticky valve whose loop cycles only with the external load is an
``external`` loop, a tight loop whose cycle a linear valve stops is a ``valve`` loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.apps.family import (
    NOISE_DOMINANT,
    NOISE_DOMINANT_SHARE,
    NOISE_RANGE,
    WARMUP,
    FamilyLoop,
    LoopSetup,
    _filtered_walk,
    _loguniform,
    _pick,
    _process,
    _record,
    loop_type_of,
    physical_valve,
)
from stictiondiag.core.errors import StictionError
from stictiondiag.models.processes import FOPTD, PI
from stictiondiag.stiction.cause import find_cycle

#: The generators and their shares of the family.
GENERATORS: dict[str, float] = {"valve": 0.5, "tuning": 0.15, "external": 0.2, "quantiser": 0.15}

#: The stick models of the ``valve`` generator and their shares.  He's model and the
#: band-hold valve (:mod:`stictiondiag.models.stick_models`) take half of the physical
#: valve's former fifth; being last in the draw, they leave the loops of the other
#: models exactly as they were.
STICK_MODELS: dict[str, float] = {
    "choudhury": 0.4,
    "kano": 0.4,
    "physical": 0.1,
    "he": 0.05,
    "band": 0.05,
}

#: External oscillation shapes and their shares.
EXTERNAL_SHAPES: dict[str, float] = {
    "sine": 0.15,
    "triangle": 0.25,
    "square": 0.2,
    "two_tones": 0.2,
    "bursts": 0.2,
}

#: The counterfactual changes, in the order they are tried, and the cause each names.
CHANGES: tuple[tuple[str, str], ...] = (
    ("linear_valve", "valve"),
    ("no_external", "external"),
    ("no_quantiser", "other"),
    ("no_deadzone", "other"),
    ("conservative", "tuning"),
)

#: Share of loops (of every generator) with the integral-dominant tuning plants run
#: (:func:`_tuning`) [-].  The pv-op plot of a PI loop opens with the controller's
#: phase at the cycle, ``atan(1 / (w Ti))``: the simulated valve cycles under SIMC
#: settings alone gave a median minor/major axis ratio of 0.22 against 0.42 on the
#: real records with a cycle (labels not read), and an integral-dominant setting moves
#: a valve's cycle there (``python scripts/tuning_shapes.py``, docs/history.md,
#: "Plants tune integral-dominant").
INTEGRAL_DOMINANT_SHARE = 0.4

#: The tuning styles of :func:`_tuning`.
TUNING_STYLES: tuple[str, ...] = ("simc", "integral_dominant")


@dataclass(frozen=True)
class FrictionVariation:
    """How real friction varies, for a sticky valve of the family other than the
    physical one (:func:`_friction_variation`, with ``varying_friction``).

    S and J are scaled by ``exp(sigma w(t))``, ``w`` a unit-spread slow random signal
    whose correlation time is ``time`` [loop time scales] and ``sigma`` uniform on
    [0, ``spread``] [-] (packing wear, temperature and process pressure move the
    friction from one stick to the next), and by ``1 +- a`` with the direction of
    travel, ``a`` uniform on [-``asymmetry``, ``asymmetry``] [-] (a spring-return
    actuator pushes harder one way; the process pressure on the plug helps one
    direction).  An external triangle, an upstream sticky valve's cycle, falls over
    ``0.5 +- triangle`` [-] of its period, as such a valve's would.
    """

    spread: float = 0.3
    time: tuple[float, float] = (1.0, 5.0)
    asymmetry: float = 0.35
    triangle: float = 0.2


#: The variation of :func:`_friction_variation`.
FRICTION_VARIATION = FrictionVariation()

#: Record length in units of the loop's time scale [-] and in samples [-].
DURATION_SCALES = (60.0, 400.0)
N_RANGE = (600, 5000)


def ultimate_gain(process, integral_time: float) -> float:
    """Gain [% per pv unit] at which a PI controller with ``integral_time`` [s] puts
    the loop at its stability limit (gain margin 1): ``1 / |C1(jw) G(jw)|`` at the
    lowest frequency where the phase of ``C1 G`` reaches -180 degrees, ``C1`` the PI
    with unit gain."""
    w = np.logspace(-4, 1.5, 4000)
    c1 = PI(gain=1.0, integral_time=float(integral_time)).frequency_response(w)
    L = c1 * process.frequency_response(w)
    phase = np.unwrap(np.angle(L))
    k = np.nonzero(phase <= -math.pi)[0]
    if k.size == 0:
        return math.inf
    return float(1.0 / abs(L[k[0]]))


def _wave(rng, shape: str, n: int, period: float, fall: float = 0.5) -> np.ndarray:
    """Unit-amplitude periodic wave of ``shape`` with ``period`` [samples]; a
    triangle falls over the fraction ``fall`` of each period and rises over the
    rest."""
    t = np.arange(n) / period + rng.uniform(0.0, 1.0)
    frac = t % 1.0
    if shape == "triangle":
        return np.where(
            frac < fall, 1.0 - 2.0 * frac / fall, 2.0 * (frac - fall) / (1.0 - fall) - 1.0
        )
    if shape == "square":
        duty = rng.uniform(0.35, 0.65)
        w = np.where(frac < duty, 1.0, -1.0)
        # An upstream actuator does not switch in zero time: a short first-order lag.
        from scipy.signal import lfilter

        a = math.exp(-1.0 / max(1.0, period * rng.uniform(0.01, 0.08)))
        return lfilter([1.0 - a], [1.0, -a], w)
    if shape == "two_tones":
        ratio = rng.uniform(1.6, 4.0)
        return 0.7 * np.sin(2 * math.pi * t) + 0.5 * np.sin(2 * math.pi * t * ratio + 1.0)
    if shape == "bursts":
        on = _filtered_walk(rng, n, 3.0 * period) > rng.uniform(-0.5, 0.3)
        env = np.convolve(
            on.astype(float), np.ones(max(1, int(period))) / max(1, int(period)), "same"
        )
        return env * np.sin(2 * math.pi * t)
    return np.sin(2 * math.pi * t)


def _quantised_loop(process, controller, n, sp, load, noise, q, op_bias, seed, dz=0.0):
    """PI loop whose controller sees pv through a quantiser of step ``q`` [pv units]
    (``q = 0``: no quantiser) and its error through a dead zone of half-width ``dz``
    [pv units] (``e - clip(e, -dz, dz)``: the controller ignores errors inside it);
    a linear valve, one step per sample.  Returns pv (unquantised, with noise), op,
    sp."""
    rng = np.random.default_rng(seed)
    e_noise = rng.normal(0.0, 1.0, n) * noise
    d = int(round(process.dead_time))
    K = float(process.gain)
    a = math.exp(-1.0 / process.time_constant) if isinstance(process, FOPTD) else 1.0
    b = K * (1.0 - a) if isinstance(process, FOPTD) else K
    Kc, Ti = float(controller.gain), float(controller.integral_time)
    x = 0.0
    u_hist = np.full(n + d + 1, 0.0)
    pv = np.empty(n)
    op = np.empty(n)
    integ = 0.0
    for k in range(n):
        pv[k] = x + load[k] + e_noise[k]
        meas = np.round(pv[k] / q) * q if q > 0 else pv[k]
        e = sp[k] - meas
        e = e - min(max(e, -dz), dz)
        u = Kc * (e + integ + e / Ti)
        if 0.0 < u + op_bias < 100.0:  # conditional integration against windup
            integ += e / Ti
        u = min(max(u + op_bias, 0.0), 100.0) - op_bias
        op[k] = u + op_bias
        u_hist[k + d] = u
        x = a * x + b * u_hist[k]
    return pv, op, np.asarray(sp, dtype=float)


def _measurement_nonlinearity(gen: str, change: str | None, size: float) -> tuple[float, float]:
    """The quantiser's step and the dead zone's half-width [pv units] of a loop: ``size``
    (1-4 times the spread of the loop's noise-free pv) for its generator's own, 0 for
    the other and when the twin's change removes it."""
    q_step = size if gen == "quantiser" and change != "no_quantiser" else 0.0
    dz = size if gen == "deadzone" and change != "no_deadzone" else 0.0
    return q_step, dz


def _tuning(
    process, Kc: float, Ti: float, gen: str, change: str | None, u_gen: np.ndarray, style: str
) -> tuple[PI, PI, float, float]:
    """The loop's PI controller and, for the ``conservative`` twin, its replacement.

    ``style`` (:data:`TUNING_STYLES`) ``simc``: SIMC normal or aggressive; or
    ``integral_dominant``, the setting plants often run (drawn in
    :data:`INTEGRAL_DOMINANT_SHARE` of the loops, whatever the generator): a fifth to
    a half of SIMC's gain with a sixth to three fifths of its integral time.  Tight (a gain
    margin of 1.1-1.8) for the ``tuning`` generator; no other generator closer than
    a gain margin of 2.  Returns the loop's own controller, the one simulated (the
    twin's where ``change`` asks for it), the loop's gain and the ultimate gain.
    """
    if style == "integral_dominant":
        Ti = float(Ti * (0.15 + 0.45 * u_gen[1]))
        Kc = float(Kc * (0.2 + 0.3 * u_gen[0]))
    else:
        Ti = float(Ti * (0.6 + 0.6 * u_gen[1]))
        Kc = float(Kc * (0.7 + 1.1 * u_gen[0]))
    ku = ultimate_gain(process, Ti)
    gm = 1.1 + 0.7 * u_gen[2]
    if gen == "tuning" and math.isfinite(ku):
        Kc = ku / gm
    elif math.isfinite(ku):
        Kc = min(Kc, ku / 2.0)  # the other generators are not tight-tuned
    controller = PI(gain=float(Kc), integral_time=float(Ti))
    if change != "conservative":
        return controller, controller, Kc, ku
    ku2 = ultimate_gain(process, 2.0 * Ti)
    twin = PI(gain=float(ku2 / 4.0 if math.isfinite(ku2) else Kc / 4.0), integral_time=2.0 * Ti)
    return controller, twin, Kc, ku


def _valve_friction(rng, gen: str, u_gen: np.ndarray) -> tuple[bool, float, float]:
    """Whether the valve sticks, and its S and J [% of span]: large for the ``valve``
    generator, small for a quarter of the ``external`` ones, none otherwise."""
    sticky = gen == "valve" or (gen == "external" and u_gen[3] < 0.25)
    S = (
        (_loguniform(rng, 1.0, 8.0) if gen == "valve" else _loguniform(rng, 0.2, 1.0))
        if sticky
        else 0.0
    )
    J = S * (0.0 if u_gen[4] < 0.1 else float(rng.uniform(0.2, 1.0))) if sticky else 0.0
    return sticky, S, J


def _friction_variation(seed: int, n: int, t_loop: float) -> tuple[np.ndarray, float, float]:
    """How a loop's friction varies (:data:`FRICTION_VARIATION`): the factor on S and J
    per sample [-], the asymmetry between the directions of travel [-] and the fall
    fraction of an external triangle [-].  Drawn from a generator of its own (seeded
    by the loop's seed), so every other draw of the loop stays as it was."""
    v = FRICTION_VARIATION
    rng = np.random.default_rng([seed, 7])
    sigma = float(rng.uniform(0.0, v.spread))
    corr = t_loop * float(rng.uniform(*v.time))
    scale = np.exp(sigma * _filtered_walk(rng, n, corr))
    asym = float(rng.uniform(-v.asymmetry, v.asymmetry))
    fall = 0.5 + float(rng.uniform(-1.0, 1.0)) * v.triangle
    return scale, asym, fall


def _loads(
    rng,
    kind: str,
    shape: str,
    n: int,
    t_loop: float,
    scale: float,
    u_gen: np.ndarray,
    fall: float = 0.5,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The non-periodic load every loop gets, the periodic external disturbance (used
    by the ``external`` generator only; a triangle falls over ``fall`` of its
    period) and the set point [pv units]; all drawn for every loop, so that a twin
    draws the same numbers as its loop."""
    base = 0.05 * scale * _filtered_walk(rng, n, max(2.0, t_loop / 4))
    slow = scale * _loguniform(rng, 0.3, 3.0) * _filtered_walk(rng, n, rng.uniform(20, 60) * t_loop)
    base = base + (slow if u_gen[5] < 0.4 else 0.0)
    period = t_loop * _loguniform(rng, 2.0, 25.0)
    ext = scale * _loguniform(rng, 0.5, 4.0) * _wave(rng, shape, n, period, fall)
    sp = np.zeros(n)
    if kind == "slave":
        sp += scale * _loguniform(rng, 0.5, 3.0) * _filtered_walk(rng, n, 30.0 * t_loop)
    return base, ext, sp


def cause_loop(
    seed: int,
    *,
    change: str | None = None,
    generator: str | None = None,
    tuning: str | None = None,
    varying_friction: bool = False,
) -> FamilyLoop:
    """One loop of the cause family, a deterministic function of ``seed``.

    ``change`` is one of the counterfactual changes of :data:`CHANGES` (None: the
    loop itself); every draw, the noise sequence included, is the same for the loop
    and its twins.  ``generator`` forces the generator (default drawn by
    :data:`GENERATORS`), ``tuning`` the tuning style (:data:`TUNING_STYLES`; default
    drawn, :func:`_tuning`); every other draw stays the seed's.  ``varying_friction``
    gives a sticky valve a friction that varies and leans an external triangle
    (:func:`_friction_variation`; drawn apart, so every other draw stays the
    seed's).  ``truth`` holds the draws; the label is :func:`cause_label`'s.
    """
    rng = np.random.default_rng(seed)
    gen = _pick(rng, GENERATORS)
    gen = generator or gen
    kind = _pick(rng, {"flow": 0.25, "self": 0.3, "integrating": 0.25, "slave": 0.2})
    if gen == "deadzone":
        kind = "integrating"
    record = _pick(rng, {"plain": 0.6, "quantised": 0.1, "deadband": 0.15, "swinging_door": 0.15})
    stick = _pick(rng, STICK_MODELS)
    shape = _pick(rng, EXTERNAL_SHAPES)
    characteristic = "equal_percentage" if rng.random() < 1 / 3 else "linear"
    decim = int(rng.choice([1, 1, 2, 3]))
    span = _loguniform(rng, *DURATION_SCALES)
    process, Kc, Ti, t_loop, scale = _process(rng, kind)
    u_gen = rng.random(8)  # uniform draws each generator maps to its own ranges

    style = tuning or ("integral_dominant" if u_gen[6] < INTEGRAL_DOMINANT_SHARE else "simc")
    if style not in TUNING_STYLES:
        raise StictionError(f"tuning style {style!r}: expected one of {', '.join(TUNING_STYLES)}")
    base_controller, controller, Kc, ku = _tuning(process, Kc, Ti, gen, change, u_gen, style)
    sticky, S, J = _valve_friction(rng, gen, u_gen)
    valve = stick if sticky else "linear"
    n_rec = int(np.clip(span * t_loop / decim, *N_RANGE))
    if valve == "physical":
        n_rec = min(n_rec, 2000)
    n = WARMUP + n_rec * decim

    f_scale, f_asym, fall = (
        _friction_variation(seed, n, t_loop) if varying_friction else (None, 0.0, 0.5)
    )
    base, ext, sp = _loads(rng, kind, shape, n, t_loop, scale, u_gen, fall)
    external_on = gen == "external" and change != "no_external"
    load = base + (ext if external_on and kind != "slave" else 0.0)
    if external_on and kind == "slave":
        sp = sp + ext
    dominant = bool(rng.random() < NOISE_DOMINANT_SHARE)
    noise_ratio = _loguniform(rng, *(NOISE_DOMINANT if dominant else NOISE_RANGE))
    if gen in ("quantiser", "deadzone"):
        noise_ratio = _loguniform(rng, 0.001, 0.03)
    op_bias = float(rng.uniform(30.0, 70.0))
    sim_seed = int(rng.integers(2**31))
    q_ratio = float(rng.uniform(1.0, 4.0))
    linear = change == "linear_valve"
    physical = physical_valve(S, J) if valve == "physical" else None
    setup = LoopSetup(
        process, n, valve, S, J, physical, op_bias, characteristic, sim_seed, f_scale, f_asym
    )

    def run(ctrl, lin: bool, load_, sp_, noise_std: float, q: float = 0.0, dz: float = 0.0):
        if gen in ("quantiser", "deadzone"):
            return _quantised_loop(
                process, ctrl, n, sp_, load_, noise_std, q, op_bias, sim_seed, dz
            )
        sim = setup.simulate(ctrl, sp=sp_, load=load_, noise_std=noise_std, linear=lin)
        return sim.pv, sim.op, sim.sp

    # The noise level is the loop's own (noise-free pv of the loop itself, not of a
    # twin), so a twin differs from its loop by its one change only.
    load_0 = base + (ext if gen == "external" and kind != "slave" else 0.0)
    sp_0 = sp + (ext if gen == "external" and kind == "slave" else 0.0)
    clean = run(base_controller, False, load_0, sp_0, 0.0)[0]
    spread = float(np.std(clean[WARMUP:])) or scale * 0.01
    q_step, dz = _measurement_nonlinearity(gen, change, q_ratio * max(spread, 0.05 * scale))
    pv, op, spv = run(controller, linear, load, sp, noise_ratio * spread, q_step, dz)
    mv = op
    sl = slice(WARMUP, n, decim)
    pv, op, mv, spv = pv[sl].copy(), op[sl].copy(), mv[sl].copy(), spv[sl].copy()
    pv, op = _record(rng, pv, op, record)
    truth = {  # the draws
        "seed": int(seed),
        "generator": gen,
        "change": change,
        "valve": valve,
        "S": S,
        "J": J,
        "friction_spread": float(np.std(np.log(f_scale)))
        if sticky and f_scale is not None
        else 0.0,
        "friction_asymmetry": f_asym if sticky else 0.0,
        "kind": kind,
        "shape": shape if gen == "external" else None,
        "triangle_fall": fall if gen == "external" and shape == "triangle" else None,
        "record": record,
        "deadzone": dz,
        "gain_margin": float(ku / Kc) if math.isfinite(ku) else None,
        "tuning": style,
        "noise_ratio": noise_ratio,
        "decimation": decim,
        "n": int(pv.size),
    }
    return FamilyLoop(
        pv=pv,
        op=op,
        sp=spv,
        mv=None,
        ts=float(decim),
        integrating=kind == "integrating",
        loop_type=loop_type_of(kind, t_loop),
        sticky=bool(sticky and not linear),
        truth=truth,
    )


def _applies(change: str, loop: FamilyLoop) -> bool:
    t = loop.truth
    return {
        "linear_valve": t["valve"] != "linear",
        "no_external": t["generator"] == "external",
        "conservative": True,
        "no_quantiser": t["generator"] == "quantiser",
        "no_deadzone": t["generator"] == "deadzone",
    }[change]


def has_cycle(loop: FamilyLoop) -> bool | None:
    """Stage 1 of the analysis on the loop's record
    (:func:`stictiondiag.analysis.find_oscillations`,
    :func:`stictiondiag.analysis.check_record_length`); None when the analysis
    refuses the record (too short for the cycle it shows)."""
    # Imported here: the analysis brings numba (about 0.3 s); only analysing needs it.
    from stictiondiag.analysis import check_record_length, find_oscillations

    try:
        tags = loop.tags()
        osc_pv, osc_op = find_oscillations(tags, [])
        short = check_record_length(tags, osc_pv, osc_op)
    except StictionError:
        return None
    return find_cycle(osc_pv, osc_op, short_record=bool(short)).present


def cause_label(
    seed: int,
    generator: str | None = None,
    tuning: str | None = None,
    varying_friction: bool = False,
) -> tuple[FamilyLoop, str | None]:
    """The loop of ``seed`` and its cause (module doc): ``none`` (no cycle), one of
    ``valve``, ``external``, ``tuning``, ``other``, or ``unexplained``; None when
    the analysis refuses the record.  ``generator``, ``tuning`` and
    ``varying_friction`` as in :func:`cause_loop`, for the loop and its twins."""
    loop = cause_loop(seed, generator=generator, tuning=tuning, varying_friction=varying_friction)
    cycle = has_cycle(loop)
    if cycle is None:
        return loop, None
    if not cycle:
        return loop, "none"
    for change, cause in CHANGES:
        if not _applies(change, loop):
            continue
        twin = cause_loop(
            seed,
            change=change,
            generator=generator,
            tuning=tuning,
            varying_friction=varying_friction,
        )
        if has_cycle(twin) is False:
            return loop, cause
    return loop, "unexplained"
