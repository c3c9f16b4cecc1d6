"""Closed-loop simulation of a PI loop with a sticky valve (Sections 4.2.2, 5.3, 6.4).

The loop of Eq. 3 and Table 3 of Choudhury, Thornhill & Shah (2005): a PI controller
in the paper's form ``C(s) = Kc (1 + 1/(Ti s))`` drives a valve model whose position
``mv`` is the input of a first-order-plus-dead-time or integrating process::

    e  = sp - pv
    op = op_bias + Kc (e + (1/Ti) integral(e dt))      saturated to [0, 100] % of span
    mv = valve(op)                                      linear | choudhury | kano | physical
    pv = pv_bias + G(s) (f(mv) - f(op_bias)) + load + noise

``f`` is the valve characteristic (linear by default).  The controller may read pv
through a first-order filter (``pv_filter_time`` T: ``f = a f + (1 - a) pv`` each
controller step, ``a = exp(-step / T)``, started at the first pv; none by default, as
in the paper); the recorded pv is the unfiltered one.  The whole loop -- controller,
valve and process -- runs in one compiled kernel:

* the process is discretised exactly for a zero-order-hold input (exact ZOH of the
  first-order lag or the integrator, with the dead time split into whole steps and a
  fractional part by the modified z-transform), so the only discretisation error is
  that of the controller (rectangular integration) and the sampling of the valve;
* the data-driven valves call the same compiled per-sample functions as the
  open-loop models (:func:`stictiondiag.models.valve.choudhury_step`, ``kano_step``);
* with the physical valve (Section 4) the whole loop runs at the valve's integration
  sub-step (about 1e-4 s, see :mod:`stictiondiag.models.physical`): the controller and
  process of Eq. 3 are continuous-time, and a controller output held for 0.1 s would
  make a valve with ``Fs > Fc`` stick after every step of the staircase.  Signals are
  recorded every ``dt``.

Gerry & Ruel's variable-integral PI (Section 6.4) switches the integral action off
while ``|sp - pv| < integral_band``.  The integral is also frozen while the output is
saturated and the error would drive it further (conditional-integration anti-windup);
this never acts in the paper's cases, which stay inside the span.

Start-up
--------
The cycle is started by a *kick*: at t = 0 the valve is found stuck ``kick`` % of span
away from the operating point while the controller output is at ``op_bias``, and the
process is at rest.  The loop must move the stuck valve, which a pure setpoint pulse
of small size would never do in a loop with a deadband.  ``initial_op`` and
``initial_mv`` replace the output and the valve position of that start (the kick is
then ignored); ``initial_integral`` the error integral [pv units * s], by default the
one that gives ``initial_op`` at the initial error.  ``initial_stop`` is the state of
a data-driven valve that starts stuck: the controller output at which it stuck [% of
span] and the direction of its last movement (+1 or -1).  Moving on in that direction
it breaks away once op is ``J`` past the stop, reversing once op is ``S`` back
(Fig. 10); by default it is stuck at ``initial_op`` with no movement yet, so any
breakaway needs ``S``.  A replay of recorded data passes the state the record shows
(:mod:`stictiondiag.replay.closed_loop`, "Start-up").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import jit
from stictiondiag.models.loop_inputs import (
    _band_setting,
    _checked_friction,
    _friction_setting,
    _integral_band,
    _number,
    _series,
)
from stictiondiag.models.physical import (
    PhysicalValve,
    karnopp_step,
)
from stictiondiag.models.processes import (
    FOPTD,
    LOOP_PARAMETERS,
    PI,
    Integrating,
)
from stictiondiag.models.simulation import Simulation
from stictiondiag.models.stick_models import band_step, he_step
from stictiondiag.models.valve import (
    EQUAL_PERCENTAGE_RANGEABILITY,
    _check_sj,
    choudhury_step,
    kano_step,
    valve_state,
)

#: Valve models :func:`simulate_loop` accepts.
VALVES = ("linear", "choudhury", "kano", "physical", "he", "band")
_VALVE_CODE = {"linear": 0, "choudhury": 1, "kano": 2, "physical": 3, "he": 4, "band": 5}
#: The valves whose S and J are parameters (the physical valve has forces instead).
_SJ_VALVES = ("choudhury", "kano", "he", "band")
_CHARACTERISTIC_CODE = {"linear": 0, "equal_percentage": 1, "quick_opening": 2}

#: Largest number of recorded samples ``duration / dt`` (5 arrays of float64: 2 GB).
MAX_SAMPLES = 50_000_000
#: Largest number of integration steps of the physical valve (some tens of seconds).
MAX_VALVE_STEPS = 2_000_000_000
#: Default kick [% of span]: initial displacement of the stuck valve.
DEFAULT_KICK = 1.0
#: Default duration of :func:`simulate_paper_loop` [s] (about 10 cycles of the slowest
#: cycle of Section 4.2.2).
PAPER_LOOP_DURATION = 3000.0


@jit
def _characteristic(position, kind, rangeability):
    x = min(max(position, 0.0), 100.0)
    if kind == 1:
        return 100.0 * rangeability ** (x / 100.0 - 1.0)
    if kind == 2:
        return 100.0 * math.sqrt(x / 100.0)
    return x


@jit
def _loop_kernel(
    n,
    n_sub,
    h,
    sp,
    load,
    noise,
    a,
    b_now,
    b_prev,
    delay,
    Kc,
    Ti,
    band,
    op_bias,
    pv_bias,
    valve_kind,
    S,
    J,
    s_scale,
    asym,
    p,
    stem,
    char_kind,
    rangeability,
    op0,
    mv0,
    xss0,
    dirn0,
    integral0,
    f_pole,
    out_pv,
    out_op,
    out_mv,
):
    # Dead-time line of process inputs: u[m - delay] and u[m - delay - 1].
    size = delay + 2
    buf = np.zeros(size)
    y = 0.0  # process output, deviation from pv_bias [pv units]
    integral = integral0  # integral of e [pv units * s]
    f_bias = _characteristic(op_bias, char_kind, rangeability)
    st = valve_state(op0, True)
    st[0] = mv0
    st[1] = xss0  # the input at which the valve last stuck
    st[2] = dirn0  # the direction of its last movement (0: none yet)
    st[3] = dirn0  # the input's slope sign (Fig. 10), that of the last movement
    # The first sample repeats op0; seen as still travelling in the direction of the
    # last movement, not as a stop of the input (which would re-arm the stick test).
    st[5] = op0 - dirn0 * 1e-9 * max(1.0, abs(op0))
    if valve_kind == 4:
        st[1] = 0.0  # He's residual force: none at rest
    x_stem = mv0 * stem
    v_stem = 0.0
    # Ring-buffer indices of the newest input and of u[m - delay], u[m - delay - 1].
    i_new = 0
    i_now = (size - delay) % size
    i_prev = (size - delay - 1) % size
    linear_flow = char_kind == 0
    inv_Ti = 1.0 / Ti
    pv_f = pv_bias + load[0] + noise[0]  # the controller's filtered pv, started at rest
    for k in range(n):
        spk = sp[k]
        band_k = band[k]
        disturbance = pv_bias + load[k] + noise[k]
        s_k = s_scale[k]
        for j in range(n_sub):
            pv = y + disturbance
            pv_f = f_pole * pv_f + (1.0 - f_pole) * pv
            e = spk - pv_f
            trial = integral
            if band_k < 0.0 or abs(e) >= band_k:
                trial = integral + e * h  # Gerry & Ruel: integrate only outside the band
            op = op_bias + Kc * (e + trial * inv_Ti)
            if (op > 100.0 and Kc * (trial - integral) > 0.0) or (
                op < 0.0 and Kc * (trial - integral) < 0.0
            ):
                trial = integral  # anti-windup: do not integrate into saturation
                op = op_bias + Kc * (e + trial * inv_Ti)
            integral = trial
            op = min(max(op, 0.0), 100.0)
            if valve_kind == 3:
                x_stem, v_stem = karnopp_step(op * stem, x_stem, v_stem, p)
                mv = x_stem / stem
            elif valve_kind == 0:
                mv = op
            else:
                # Friction that varies over time and with the direction of travel
                # (``friction_scale``, ``friction_asymmetry``; 1 and 0 by default).
                m = s_k
                if asym != 0.0:
                    m *= (1.0 + asym) if op > st[0] else (1.0 - asym)
                Sk = S * m
                Jk = J * m
                if valve_kind == 1:
                    mv = choudhury_step(op, st, Sk, Jk)
                elif valve_kind == 2:
                    mv = kano_step(op, st, Sk, Jk)
                elif valve_kind == 4:
                    mv = he_step(op, st, Sk, Jk)
                else:
                    mv = band_step(op, st, Sk)
            if j == 0:
                out_pv[k] = pv
                out_op[k] = op
                out_mv[k] = mv
            if linear_flow:
                buf[i_new] = mv - f_bias
            else:
                buf[i_new] = _characteristic(mv, char_kind, rangeability) - f_bias
            y = a * y + b_now * buf[i_now] + b_prev * buf[i_prev]
            i_new += 1
            if i_new == size:
                i_new = 0
            i_now += 1
            if i_now == size:
                i_now = 0
            i_prev += 1
            if i_prev == size:
                i_prev = 0


def _process_coefficients(process, h: float) -> tuple[float, float, float, int]:
    """Exact ZOH discretisation ``y+ = a y + b_now u[m-d] + b_prev u[m-d-1]``.

    The dead time ``theta = (d + f) h`` with whole steps ``d`` and fraction ``f`` in
    [0, 1): during the step the delayed input is ``u[m-d-1]`` for ``f h`` and
    ``u[m-d]`` for ``(1 - f) h`` (modified z-transform).
    """
    theta = float(process.dead_time)
    ratio = theta / h
    d = int(math.floor(ratio + 1e-9))
    f = max(0.0, ratio - d)
    if f < 1e-9:
        f = 0.0
    K = float(process.gain)
    if isinstance(process, FOPTD):
        tau = float(process.time_constant)
        a = math.exp(-h / tau)
        late = math.exp(-(1.0 - f) * h / tau)
        return a, K * (1.0 - late), K * (late - a), d
    return 1.0, K * (1.0 - f) * h, K * f * h, d


def _check_loop(process, controller) -> None:
    if not isinstance(process, FOPTD | Integrating):
        raise UsageError(
            "process must be a FOPTD or Integrating model (stictiondiag.models.processes)"
        )
    if not isinstance(controller, PI):
        raise UsageError("controller must be a PI model (stictiondiag.models.processes)")
    _number("process gain", process.gain)
    _number("process dead time", process.dead_time, minimum=0.0)
    if isinstance(process, FOPTD):
        _number("process time constant", process.time_constant, positive=True)
    _number("controller gain", controller.gain)
    _number("controller integral time", controller.integral_time, positive=True)


def _valve_integration(
    valve: str, physical: PhysicalValve | None, dt: float, n: int
) -> tuple[PhysicalValve | None, int, float, tuple[float, ...], float]:
    """Integration set-up of the valve: ``(physical, n_sub, h, kernel parameters, stem)``.

    The physical valve of Section 4 is integrated in ``n_sub`` sub-steps ``h`` per
    sample; the data-driven valves of Section 5 take one step ``dt`` (their kernel
    parameters are unused).
    """
    if valve != "physical":
        return physical, 1, dt, PhysicalValve().kernel_parameters(dt), 1.0
    if physical is None:
        physical = PhysicalValve.from_case("nominal")
    if not isinstance(physical, PhysicalValve):
        raise UsageError("physical must be a PhysicalValve (see stictiondiag.models.physical)")
    n_sub, h = physical.substeps(dt)
    if n * n_sub > MAX_VALVE_STEPS:
        raise UsageError(
            f"{n * n_sub:.3g} integration steps of the physical valve exceed the limit "
            f"of {MAX_VALVE_STEPS:,}: shorten the duration"
        )
    return physical, n_sub, h, physical.kernel_parameters(h), physical.stem_travel_per_percent


def _initial_state(
    controller: PI,
    *,
    op_bias: float,
    pv_bias: float,
    kick: float,
    e0: float,
    initial_op: float | None,
    initial_mv: float | None,
    initial_integral: float | None,
) -> tuple[float, float, float]:
    """Initial controller output, valve position [% of span] and error integral.

    Defaults: op at ``op_bias``, the valve stuck ``kick`` away from it, and the
    integral that gives that op at the initial error ``e0`` (module docstring).
    """
    op0 = op_bias if initial_op is None else _number("initial_op", initial_op)
    op0 = min(max(op0, 0.0), 100.0)
    mv0 = op_bias + kick if initial_mv is None else _number("initial_mv", initial_mv)
    mv0 = min(max(mv0, 0.0), 100.0)
    Kc = float(controller.gain)
    Ti = float(controller.integral_time)
    if initial_integral is None:
        integral0 = Ti * ((op0 - op_bias) / Kc - e0) if Kc != 0 else 0.0
    else:
        integral0 = _number("initial_integral", initial_integral)
    return op0, mv0, integral0


def _initial_stop(value, op0: float) -> tuple[float, float]:
    """``(stop input, direction)`` of a valve that starts stuck (``simulate_loop``'s
    ``initial_stop``): default stuck at ``op0`` with no movement yet."""
    if value is None:
        return op0, 0.0
    try:
        xss, d = value
    except (TypeError, ValueError):
        raise UsageError(f"initial_stop must be (stop input, direction), got {value!r}") from None
    xss = _number("initial_stop input", xss)
    d = _number("initial_stop direction", d)
    if d not in (-1.0, 0.0, 1.0):
        raise UsageError(f"initial_stop direction must be -1, 0 or +1, got {d:g}")
    return xss, d


@dataclass(frozen=True)
class _LoopRun:
    """A run of :func:`simulate_loop`, checked and discretised: what the kernel and the
    recorded settings read."""

    valve: str
    characteristic: str
    n: int  # recorded samples
    dt: float  # sample time [s]
    h: float  # integration step [s]
    n_sub: int  # integration steps per sample
    S: float  # [% of op span]
    J: float  # [% of mv span]
    friction_scale: np.ndarray  # S and J's factor per sample [-]
    friction_asymmetry: float  # [-]
    physical: PhysicalValve | None  # the physical valve's parameters; None for the others
    valve_parameters: tuple[float, ...]  # the physical valve's kernel parameters
    stem: float  # stem travel per % of span [m]
    sp: np.ndarray  # [pv units]
    load: np.ndarray  # [pv units]
    noise: np.ndarray  # [pv units]
    noise_std: float  # [pv units]
    seed: int | np.integer | None
    band: np.ndarray  # integral band per sample [pv units], NaN: none
    op_bias: float  # [% of span]
    pv_bias: float  # [pv units]
    kick: float  # [% of span]
    op0: float  # initial controller output [% of span]
    mv0: float  # initial valve position [% of span]
    integral0: float  # initial error integral [pv units * s]
    stop_given: bool  # initial_stop was given
    stop: float  # controller output at which the valve stuck [% of span]
    direction: float  # its last direction of movement (+1, -1, 0: none)
    pv_filter_time: float  # [s]


def _set_up(
    process,
    controller,
    *,
    duration,
    dt,
    valve,
    S,
    J,
    friction_scale,
    friction_asymmetry,
    physical,
    sp,
    load,
    noise_std,
    seed,
    op_bias,
    pv_bias,
    kick,
    integral_band,
    characteristic,
    initial_op,
    initial_mv,
    initial_integral,
    initial_stop,
    pv_filter_time,
) -> _LoopRun:
    """:func:`simulate_loop`'s arguments checked, each with a one-line UsageError, the
    valve's integration set up, the inputs sampled and the start-up state found."""
    _check_loop(process, controller)
    dt = _number("sample time dt", dt, positive=True)
    duration = _number("duration", duration, positive=True)
    if valve not in VALVES:
        raise UsageError(f"unknown valve {valve!r}: use one of {', '.join(VALVES)}")
    if characteristic not in _CHARACTERISTIC_CODE:
        raise UsageError(
            f"unknown valve characteristic {characteristic!r}: "
            f"use one of {', '.join(_CHARACTERISTIC_CODE)}"
        )
    S, J = _check_sj(S, J)
    ratio = duration / dt
    if ratio > MAX_SAMPLES:
        raise UsageError(
            f"duration/dt = {ratio:.3g} samples exceeds the limit of {MAX_SAMPLES:,}: "
            "shorten the duration or increase dt"
        )
    n = max(2, int(round(ratio)))
    op_bias = _number("op_bias", op_bias)
    if not 0.0 <= op_bias <= 100.0:
        raise UsageError(f"op_bias must be within [0, 100] % of span, got {op_bias}")
    pv_bias = _number("pv_bias", pv_bias)
    kick = _number("kick", kick)
    noise_std = _number("noise_std", noise_std, minimum=0.0)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer)):
        raise UsageError(f"seed must be an integer or None, got {seed!r}")
    band = _integral_band(integral_band, n)
    f_scale, f_asym = _checked_friction(friction_scale, friction_asymmetry, n)
    physical, n_sub, h, p, stem = _valve_integration(valve, physical, dt, n)
    sp_arr = _series("sp", sp, n, 0.0)
    load_arr = _series("load", load, n, 0.0)
    if noise_std > 0:
        noise = np.random.default_rng(seed).normal(0.0, noise_std, n)
    else:
        noise = np.zeros(n)
    op0, mv0, integral0 = _initial_state(
        controller,
        op_bias=op_bias,
        pv_bias=pv_bias,
        kick=kick,
        e0=sp_arr[0] - (pv_bias + load_arr[0]),
        initial_op=initial_op,
        initial_mv=initial_mv,
        initial_integral=initial_integral,
    )
    xss0, dirn0 = _initial_stop(initial_stop, op0)
    return _LoopRun(
        valve=valve,
        characteristic=characteristic,
        n=n,
        dt=dt,
        h=h,
        n_sub=n_sub,
        S=S,
        J=J,
        friction_scale=f_scale,
        friction_asymmetry=f_asym,
        physical=physical if valve == "physical" else None,
        valve_parameters=p,
        stem=stem,
        sp=sp_arr,
        load=load_arr,
        noise=noise,
        noise_std=noise_std,
        seed=seed,
        band=band,
        op_bias=op_bias,
        pv_bias=pv_bias,
        kick=kick,
        op0=op0,
        mv0=mv0,
        integral0=integral0,
        stop_given=initial_stop is not None,
        stop=xss0,
        direction=dirn0,
        pv_filter_time=_number("pv_filter_time", pv_filter_time, minimum=0.0),
    )


def _simulated(process: FOPTD | Integrating, controller: PI, run: _LoopRun) -> Simulation:
    """The loop of ``run`` through the compiled kernel: the recorded signals and settings."""
    n, h = run.n, run.h
    f_pole = math.exp(-h / run.pv_filter_time) if run.pv_filter_time > 0.0 else 0.0
    a, b_now, b_prev, delay = _process_coefficients(process, h)
    out_pv = np.empty(n)
    out_op = np.empty(n)
    out_mv = np.empty(n)
    _loop_kernel(
        n,
        run.n_sub,
        h,
        run.sp,
        run.load,
        run.noise,
        a,
        b_now,
        b_prev,
        delay,
        float(controller.gain),
        float(controller.integral_time),
        run.band,
        run.op_bias,
        run.pv_bias,
        _VALVE_CODE[run.valve],
        run.S,
        run.J,
        run.friction_scale,
        run.friction_asymmetry,
        run.valve_parameters,
        run.stem,
        _CHARACTERISTIC_CODE[run.characteristic],
        EQUAL_PERCENTAGE_RANGEABILITY,
        run.op0,
        run.mv0,
        run.stop,
        run.direction,
        run.integral0,
        f_pole,
        out_pv,
        out_op,
        out_mv,
    )
    return Simulation(
        time=np.arange(n) * run.dt,
        sp=run.sp,
        pv=out_pv,
        op=out_op,
        mv=out_mv,
        dt=run.dt,
        settings=_settings(process, controller, run),
        process=process,
        controller=controller,
        physical=run.physical,
    )


def _settings(process: FOPTD | Integrating, controller: PI, run: _LoopRun) -> dict:
    """:attr:`Simulation.settings` of ``run``: the parameters as used, in JSON types."""
    sj = run.valve in _SJ_VALVES
    physical = run.physical
    return {
        "process": process.to_dict(),
        "controller": controller.to_dict(),
        "valve": run.valve,
        "S": run.S if sj else None,
        "J": run.J if sj else None,
        "friction_variation": _friction_setting(run) if sj else None,
        "physical": None if physical is None else physical.to_dict(),
        "data_driven_equivalent": (None if physical is None else physical.data_driven_equivalent()),
        "duration_s": run.n * run.dt,
        "dt_s": run.dt,
        "integration_step_s": run.h,
        "op_bias": run.op_bias,
        "pv_bias": run.pv_bias,
        "kick": run.kick,
        "initial_op": run.op0,
        "initial_mv": run.mv0,
        "initial_stop": [run.stop, run.direction] if run.stop_given else None,
        "integral_band": _band_setting(run.band),
        "noise_std": run.noise_std,
        "seed": None if run.seed is None else int(run.seed),
        "characteristic": run.characteristic,
        "pv_filter_time": run.pv_filter_time,
    }


def simulate_loop(
    process: FOPTD | Integrating,
    controller: PI,
    *,
    duration: float,
    dt: float = 0.1,
    valve: str = "choudhury",
    S: float = 0.0,
    J: float = 0.0,
    friction_scale: float | np.ndarray | None = None,
    friction_asymmetry: float = 0.0,
    physical: PhysicalValve | None = None,
    sp: float | np.ndarray = 0.0,
    load: float | np.ndarray | None = None,
    noise_std: float = 0.0,
    seed: int | None = None,
    op_bias: float = 50.0,
    pv_bias: float = 0.0,
    kick: float = DEFAULT_KICK,
    integral_band: float | np.ndarray | None = None,
    characteristic: str = "linear",
    initial_op: float | None = None,
    initial_mv: float | None = None,
    initial_integral: float | None = None,
    initial_stop: tuple[float, float] | None = None,
    pv_filter_time: float = 0.0,
) -> Simulation:
    """Simulate a PI control loop with a linear or sticky valve.

    Eq. 3 and Table 3 of Choudhury, Thornhill & Shah (2005); see the module docstring
    for the loop equations, the discretisation and the start-up.

    Parameters
    ----------
    process : FOPTD or Integrating
        Process model; gain in pv units per % of span.
    controller : PI
        PI controller in the paper's form ``Kc (1 + 1/(Ti s))``.
    duration : float
        Simulated time [s]; ``round(duration/dt)`` samples are recorded (at most
        :data:`MAX_SAMPLES`).
    dt : float
        Sample time of the records and, except for the physical valve, the
        simulation step [s].
    valve : {"linear", "choudhury", "kano", "physical", "he", "band"}
        Valve model: ``mv = op``; the data-driven models of Section 5 (Choudhury) or
        Kano et al. (2004) with ``S`` and ``J``; the physical model of Section 4; He
        et al.'s two-parameter model or the band-hold valve
        (:mod:`stictiondiag.models.stick_models`).
    S, J : float
        Deadband plus stickband [% of op span] and slip jump [% of mv span], >= 0,
        for the data-driven valves.
    friction_scale : float or ndarray, optional
        Factor on ``S`` and ``J`` [-], a number or one value per sample, > 0: a
        friction that varies over time (packing wear, temperature, process
        pressure).  Default 1.
    friction_asymmetry : float
        ``a`` in (-1, 1): ``S`` and ``J`` are scaled by ``1 + a`` while op is above
        the valve's position (opening) and ``1 - a`` while below (closing), a
        friction that differs with the direction of travel (a spring-return
        actuator, the process force on the plug).  Default 0.  Neither applies to
        the physical valve.
    physical : PhysicalValve, optional
        Parameters of the physical valve; default the nominal valve of Table 1.
    sp : float or ndarray
        Setpoint [pv units], a number or one value per sample.
    load : float or ndarray, optional
        Load disturbance added to the process output [pv units].
    noise_std : float
        Standard deviation of white measurement noise on pv [pv units], one value per
        sample ``dt`` (held between samples for the physical valve).
    seed : int, optional
        Seed of the noise generator.
    op_bias : float
        Operating point [% of span]: the controller output at zero integral and error,
        and the valve position at which the process output is ``pv_bias``.
    pv_bias : float
        Process output at the operating point [pv units].
    kick : float
        The valve starts stuck ``kick`` % of span away from ``op_bias``.
    integral_band : float or ndarray, optional
        Gerry & Ruel (2001) variable-integral PI (Section 6.4): no integral action
        while ``|sp - pv| < integral_band`` [pv units].  An array gives one band per
        sample, NaN meaning a normal PI at that sample (to switch the scheme on
        during a run).
    characteristic : {"linear", "equal_percentage", "quick_opening"}
        Valve characteristic between position and flow (the process sees the flow).
    initial_op, initial_mv, initial_integral : float, optional
        Initial controller output and valve position [% of span] and error integral
        [pv units * s] (module docstring, "Start-up").
    initial_stop : (float, float), optional
        Stop input [% of span] and last direction (+1 or -1) of a data-driven valve
        that starts stuck (module docstring, "Start-up").
    pv_filter_time : float
        Time constant of a first-order filter on the pv the controller reads [s]; 0,
        the default, for none (module docstring).

    Returns
    -------
    Simulation
        Time series and settings; ``.limit_cycle()`` measures the cycle.

    Raises
    ------
    UsageError
        A parameter is out of range, or the run would be too long.
    """
    run = _set_up(
        process,
        controller,
        duration=duration,
        dt=dt,
        valve=valve,
        S=S,
        J=J,
        friction_scale=friction_scale,
        friction_asymmetry=friction_asymmetry,
        physical=physical,
        sp=sp,
        load=load,
        noise_std=noise_std,
        seed=seed,
        op_bias=op_bias,
        pv_bias=pv_bias,
        kick=kick,
        integral_band=integral_band,
        characteristic=characteristic,
        initial_op=initial_op,
        initial_mv=initial_mv,
        initial_integral=initial_integral,
        initial_stop=initial_stop,
        pv_filter_time=pv_filter_time,
    )
    return _simulated(process, controller, run)


def simulate_paper_loop(
    name: str,
    S: float = 0.0,
    J: float = 0.0,
    *,
    duration: float = PAPER_LOOP_DURATION,
    dt: float | None = None,
    **kwargs,
) -> Simulation:
    """Simulate one of the paper's loops (Eq. 3, Table 3) with setpoint 0.

    Parameters
    ----------
    name : {"concentration", "level"}
        Loop of :data:`stictiondiag.models.processes.LOOP_PARAMETERS`.
    S, J : float
        Data-driven stiction parameters [% of span].
    duration : float
        Simulated time [s].
    dt : float, optional
        Sample time [s]; default the loop's (0.1 s).
    **kwargs
        Further arguments of :func:`simulate_loop` (``valve``, ``physical``,
        ``integral_band``, ``noise_std``, ...).
    """
    if name not in LOOP_PARAMETERS:
        raise UsageError(f"unknown loop {name!r}: use one of {', '.join(LOOP_PARAMETERS)}")
    loop = LOOP_PARAMETERS[name]
    return simulate_loop(
        loop["process"],
        loop["controller"],
        duration=duration,
        dt=loop["dt"] if dt is None else dt,
        S=S,
        J=J,
        **kwargs,
    )
