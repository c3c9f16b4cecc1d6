"""Physical (force-balance) model of a pneumatic sliding-stem valve with friction.

Choudhury, Thornhill & Shah (2005), "Modelling valve stiction", Section 4.  The stem
obeys Newton's second law (Eq. 1)

    M d2x/dt2 = Fa + Fr + Ff,    Fa = A u,   Fr = -k x,

with the actuator force ``Fa`` from the air pressure ``u`` on the diaphragm, the spring
force ``Fr`` and the friction ``Ff`` of Karnopp (1985) (Eq. 2)::

    Ff = -Fc sgn(v) - Fv v              if v != 0            (moving)
    Ff = -(Fa + Fr)                     if v = 0, |Fa + Fr| <= Fs   (stuck)
    Ff = -Fs sgn(Fa + Fr)               if v = 0, |Fa + Fr| >  Fs   (breakaway)

The input is the required stem position ``x_r``; the air pressure is ``u = c (k/A)
x_r`` with the calibration factor ``c k/A`` of Table 1 (``c = 1`` is a correctly
calibrated valve, ``c = 1.25`` the miscalibration of the bottom row of Fig. 8).  Valve
demand and position are exchanged in % of span with 1 % of span = 1 cm of stem travel
(Fig. 8 uses an amplitude of 10 cm), so the span is 1 m of travel and 0 % is the
relaxed spring.  The travel is limited to the span by end stops.

An optional Stribeck term makes the moving friction fall continuously from ``Fs`` at
rest to ``Fc``: ``Fc + (Fs - Fc) exp(-(v / vs)^2)`` (Olsson 1996).

Integration choice
------------------
The valve is fast and stiff compared with any process it drives: with Table 1 values
the undamped natural frequency is ``sqrt(k/M)`` ~ 196 rad/s and the poles of the
moving valve are at -115 and -335 rad/s (overdamped, ``Fv = 612 N s/m``).  Between
stick/slip events the moving valve is a *linear* system (spring, viscous friction,
mass) driven by a force that is constant over a short interval (actuator force and
Coulomb level).  Each sub-step of length ``h`` (default 1e-4 s, ``h`` times the fast
pole ~ 0.03) therefore uses the exact zero-order-hold discretisation of that linear
system (matrix exponential, computed once per call), which is unconditionally stable
and exact for Karnopp friction without a Stribeck term; the only approximation is
where a sub-step contains an event:

* **velocity crossing zero** within a sub-step: the crossing is located by linear
  interpolation of the velocity, the valve is put at rest there and Eq. 2 decides:
  it stays stuck when ``|Fa + Fr| <= Fs``, otherwise it breaks away on the next
  sub-step in the direction of ``Fa + Fr`` (the remainder of the sub-step is dropped,
  an O(h) timing error at reversals only);
* **Karnopp's zero-velocity band**: a valve whose speed has decayed below
  ``zero_velocity_band`` (default 1e-6 m/s, far below any stem speed a controller
  ramp demands) while ``|Fa + Fr| <= Fs`` is at rest.  In continuous time an overdamped
  valve only approaches rest asymptotically; without the band it would never stick
  again and would move on with Coulomb friction instead of static friction;
* while the valve is at rest and ``|Fa + Fr| <= Fs`` nothing changes, so no work is
  done for a stuck valve.

An explicit Euler scheme would need the same small step for accuracy and would also
be only conditionally stable; an adaptive ODE solver with event location would be
exact but cannot be compiled into the closed-loop kernel.  The Stribeck friction, if
used, is held at its value at the start of each sub-step (first-order accurate).

The per-sub-step function :func:`karnopp_step` is compiled (numba) and is called by
:func:`karnopp` here and by the closed-loop kernel of :mod:`stictiondiag.models.loops`.

Quasi-static correspondence
---------------------------
For a slow input and an overdamped valve, the valve sticks until ``|Fa + Fr|``
exceeds ``Fs``, slips to where ``|Fa + Fr| = Fc`` and then follows the input with the
offset ``Fc / k``: the data-driven model of Section 5 with ``S = (Fs + Fc)/k`` and
``J = (Fs - Fc)/k`` in stem-position units (:meth:`PhysicalValve.data_driven_equivalent`).
The paper stresses that there is no one-to-one relation in general; this one holds
only where inertia and viscous friction do not matter.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.linalg import expm

from stictiondiag.core.errors import UsageError
from stictiondiag.core.jit import jit

#: Stem travel of 1 % of span [m] (1 % = 1 cm, Section 4.2.1 and Fig. 8).
STEM_TRAVEL_PER_PERCENT = 0.01

#: Default integration sub-step [s]: about 0.03 / (fastest valve pole, 335 rad/s).
DEFAULT_TIME_STEP = 1.0e-4

#: Karnopp's zero-velocity band [m/s] (a valve slower than this with |Fa + Fr| <= Fs
#: is at rest).
DEFAULT_ZERO_VELOCITY_BAND = 1.0e-6

_TABLE1 = {
    "mass": 1.36,
    "spring_constant": 52_500.0,
    "diaphragm_area": 0.0645,
    "Fv": 612.0,
    "calibration": 1.0,
}

#: Parameter sets of Tables 1 and 2 (Section 4), as keyword arguments of
#: :class:`PhysicalValve` (masses in kg, forces in N, Fv in N s/m, k in N/m, A in m^2).
#: ``nominal`` is Table 1; the others are the friction cases of Table 2 (Figs. 8-9);
#: ``miscalibrated`` is the bottom row of Fig. 8: calibration factor 25 % too large,
#: "a slip jump was also used", with the no-offset friction values.
VALVE_PARAMETERS: dict[str, dict[str, float]] = {
    "nominal": {**_TABLE1, "Fs": 1750.0, "Fc": 1250.0},
    "linear": {**_TABLE1, "Fs": 45.0, "Fc": 45.0},
    "deadband": {**_TABLE1, "Fs": 1250.0, "Fc": 1250.0},
    "undershoot_open_loop": {**_TABLE1, "Fs": 2250.0, "Fc": 1250.0},
    "undershoot_closed_loop": {**_TABLE1, "Fs": 1000.0, "Fc": 400.0},
    "no_offset": {**_TABLE1, "Fs": 1750.0, "Fc": 0.0},
    "miscalibrated": {**_TABLE1, "Fs": 1750.0, "Fc": 0.0, "calibration": 1.25},
}

# Layout of the compiled parameter vector (see PhysicalValve.kernel_parameters).
_P_K, _P_CAL, _P_FS, _P_FC, _P_VS, _P_BAND, _P_LO, _P_HI = range(8)
_P_PHI = 8  # 4 entries of the 2x2 transition matrix, row-major
_P_GAM = 12  # 2 entries of the input vector
PARAMETER_SIZE = 14


@dataclass(frozen=True)
class PhysicalValve:
    """Parameters of the physical valve model (Section 4, Eqs. 1-2, Tables 1-2).

    Attributes
    ----------
    mass : float
        Mass of the moving parts M [kg], > 0.
    spring_constant : float
        Spring constant k [N/m], > 0.
    diaphragm_area : float
        Diaphragm area A [m^2], > 0.
    Fs : float
        Maximum static friction [N], >= Fc.
    Fc : float
        Coulomb (moving) friction [N], >= 0.
    Fv : float
        Viscous friction coefficient [N s/m], >= 0.
    calibration : float
        Multiplier on the nominal calibration factor k/A [-]; 1 is a calibrated valve,
        1.25 the miscalibrated valve of Fig. 8.
    stribeck_velocity : float or None
        Stribeck velocity vs [m/s]; when set the moving friction falls from Fs at rest
        to Fc as ``exp(-(v/vs)^2)``.  None: Karnopp's model as in Eq. 2.
    stem_travel_per_percent : float
        Stem travel of 1 % of span [m] (default 0.01: 1 % = 1 cm).
    time_step : float
        Integration sub-step [s] (default 1e-4 s; see the module docstring).
    zero_velocity_band : float
        Karnopp's zero-velocity band [m/s].
    """

    mass: float = _TABLE1["mass"]
    spring_constant: float = _TABLE1["spring_constant"]
    diaphragm_area: float = _TABLE1["diaphragm_area"]
    Fs: float = 1750.0
    Fc: float = 1250.0
    Fv: float = _TABLE1["Fv"]
    calibration: float = 1.0
    stribeck_velocity: float | None = None
    stem_travel_per_percent: float = STEM_TRAVEL_PER_PERCENT
    time_step: float = DEFAULT_TIME_STEP
    zero_velocity_band: float = DEFAULT_ZERO_VELOCITY_BAND

    def __post_init__(self) -> None:
        for name in (
            "mass",
            "spring_constant",
            "diaphragm_area",
            "Fs",
            "Fc",
            "Fv",
            "calibration",
            "stem_travel_per_percent",
            "time_step",
            "zero_velocity_band",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise UsageError(f"physical valve {name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise UsageError(f"physical valve {name} must be finite, got {value}")
        for name in ("mass", "spring_constant", "diaphragm_area", "calibration"):
            if getattr(self, name) <= 0:
                raise UsageError(f"physical valve {name} must be > 0, got {getattr(self, name)}")
        for name in ("stem_travel_per_percent", "time_step"):
            if getattr(self, name) <= 0:
                raise UsageError(f"physical valve {name} must be > 0, got {getattr(self, name)}")
        for name in ("Fc", "Fv", "zero_velocity_band"):
            if getattr(self, name) < 0:
                raise UsageError(f"physical valve {name} must be >= 0, got {getattr(self, name)}")
        if self.Fs < self.Fc:
            raise UsageError(
                f"static friction Fs={self.Fs} N is below Coulomb friction Fc={self.Fc} N: "
                "use Fs >= Fc"
            )
        vs = self.stribeck_velocity
        if vs is not None and not (isinstance(vs, int | float) and math.isfinite(vs) and vs > 0):
            raise UsageError(
                f"stribeck_velocity must be a positive number [m/s] or None, got {vs!r}"
            )

    @classmethod
    def from_case(cls, name: str, **overrides: float) -> PhysicalValve:
        """Valve of a named case of :data:`VALVE_PARAMETERS`, with optional overrides."""
        if name not in VALVE_PARAMETERS:
            raise UsageError(
                f"unknown physical valve case {name!r}: use one of {', '.join(VALVE_PARAMETERS)}"
            )
        return cls(**{**VALVE_PARAMETERS[name], **overrides})

    @property
    def calibration_factor(self) -> float:
        """Calibration factor relating required stem position to air pressure [Pa/m]."""
        return self.calibration * self.spring_constant / self.diaphragm_area

    @property
    def natural_frequency(self) -> float:
        """Undamped natural frequency sqrt(k/M) [rad/s]."""
        return math.sqrt(self.spring_constant / self.mass)

    @property
    def damping_ratio(self) -> float:
        """Damping ratio Fv / (2 sqrt(k M)) of the moving valve [-]."""
        return self.Fv / (2.0 * math.sqrt(self.spring_constant * self.mass))

    def data_driven_equivalent(self) -> dict[str, float]:
        """Quasi-static data-driven parameters (slow input, overdamped valve).

        Returns
        -------
        dict
            ``S = (Fs + Fc) / (c k)`` [% of op span], ``J = (Fs - Fc) / k`` [% of mv
            span] and ``gain = c`` [-] (slope of mv against op while moving).  With
            ``c = 1`` these are the paper's ``(Fs + Fc)/k`` and ``(Fs - Fc)/k``; the
            band is measured on the op axis, where a calibration error scales it.
        """
        k = self.spring_constant
        scale = self.stem_travel_per_percent
        return {
            "S": (self.Fs + self.Fc) / (self.calibration * k) / scale,
            "J": (self.Fs - self.Fc) / k / scale,
            "gain": float(self.calibration),
        }

    def to_dict(self) -> dict:
        """JSON-able parameters (SI units, as the attribute names document)."""
        d = {k: (None if v is None else float(v)) for k, v in asdict(self).items()}
        d["calibration_factor_Pa_per_m"] = self.calibration_factor
        return d

    def kernel_parameters(self, step: float) -> tuple[float, ...]:
        """Parameter tuple for :func:`karnopp_step` with sub-step ``step`` [s].

        Holds the exact zero-order-hold discretisation of the moving valve's linear
        part ``M x'' = f - k x - Fv v`` over one sub-step (``f`` constant).
        """
        M, k, Fv = self.mass, self.spring_constant, self.Fv
        a = np.zeros((3, 3))
        a[0, 1] = 1.0
        a[1, 0] = -k / M
        a[1, 1] = -Fv / M
        a[1, 2] = 1.0 / M
        e = expm(a * step)
        p = np.zeros(PARAMETER_SIZE)
        p[_P_K] = k
        p[_P_CAL] = self.calibration
        p[_P_FS] = self.Fs
        p[_P_FC] = self.Fc
        p[_P_VS] = 0.0 if self.stribeck_velocity is None else self.stribeck_velocity
        p[_P_BAND] = self.zero_velocity_band
        p[_P_LO] = 0.0
        p[_P_HI] = 100.0 * self.stem_travel_per_percent
        p[_P_PHI : _P_PHI + 4] = e[:2, :2].ravel()
        p[_P_GAM : _P_GAM + 2] = e[:2, 2]
        # A tuple of floats is passed by value to compiled code (an array would be
        # reference-counted on every call of the step function).
        return tuple(float(value) for value in p)

    def substeps(self, dt: float) -> tuple[int, float]:
        """Number of integration sub-steps per sample ``dt`` [s] and their length [s]."""
        n = max(1, math.ceil(dt / self.time_step - 1e-9))
        return n, dt / n


@jit
def karnopp_step(x_required, x, v, p):
    """Advance the physical valve by one integration sub-step (Eqs. 1-2).

    Scalars in, scalars out (no arrays), so that the function costs a few
    nanoseconds when called from another compiled kernel.

    Parameters
    ----------
    x_required : float
        Required stem position x_r over the sub-step [m].
    x, v : float
        Stem position [m] and velocity [m/s] at the start of the sub-step; ``v == 0``
        means at rest.
    p : tuple of float
        Parameters from :meth:`PhysicalValve.kernel_parameters`.

    Returns
    -------
    (float, float)
        Stem position [m] and velocity [m/s] at the end of the sub-step.
    """
    k = p[0]
    Fs = p[2]
    Fc = p[3]
    vs = p[4]
    lo = p[6]
    hi = p[7]
    f_actuator = k * p[1] * x_required  # Fa = A u with u = c (k/A) x_r
    f_net = f_actuator - k * x  # Fa + Fr
    if v == 0.0:
        # At rest: Eq. 2, second line (stuck) or third line (breakaway).
        if abs(f_net) <= Fs:
            return x, 0.0
        d = 1.0 if f_net > 0.0 else -1.0
        if (x <= lo and d < 0.0) or (x >= hi and d > 0.0):
            return x, 0.0  # held by an end stop
    else:
        d = 1.0 if v > 0.0 else -1.0
    f_coulomb = Fc
    if vs > 0.0:
        f_coulomb = Fc + (Fs - Fc) * math.exp(-((v / vs) ** 2))
    f_const = f_actuator - f_coulomb * d
    x1 = p[8] * x + p[9] * v + p[12] * f_const
    v1 = p[10] * x + p[11] * v + p[13] * f_const
    if v1 * d <= 0.0:
        # The velocity reached zero inside the sub-step: stop there; the next
        # sub-step applies Eq. 2 at rest (stick, or break away the other way).
        theta = v / (v - v1) if v != v1 else 0.0
        x1 = x + theta * (x1 - x)
        v1 = 0.0
    elif abs(v1) < p[5] and abs(f_actuator - k * x1) <= Fs:
        v1 = 0.0  # Karnopp's zero-velocity band
    if x1 < lo:
        x1 = lo
        v1 = 0.0
    elif x1 > hi:
        x1 = hi
        v1 = 0.0
    return x1, v1


@jit
def _karnopp_open_loop(x_req, n_sub, p, x0, linear_hold):
    n = x_req.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    x = x0
    v = 0.0
    out[0] = x0
    for i in range(1, n):
        a = x_req[i - 1]
        b = x_req[i]
        for j in range(n_sub):
            if linear_hold:
                xr = a + (b - a) * (j + 1.0) / n_sub
            else:
                xr = b
            x, v = karnopp_step(xr, x, v, p)
        out[i] = x
    return out


def karnopp(
    op: np.ndarray,
    valve: PhysicalValve,
    dt: float,
    *,
    hold: str = "linear",
    initial_position: float | None = None,
) -> np.ndarray:
    """Valve position from valve demand with the physical valve model (Section 4).

    Parameters
    ----------
    op : ndarray
        Valve demand, the required stem position [% of span], sampled every ``dt``.
    valve : PhysicalValve
        Valve parameters (see :data:`VALVE_PARAMETERS`).
    dt : float
        Sample time of ``op`` [s]; the model is integrated in sub-steps of about
        ``valve.time_step`` inside each sample.
    hold : {"linear", "zoh"}
        How ``op`` moves between samples: ``"linear"`` interpolation (a sampled
        continuous signal, as the sinusoids of Fig. 8) or zero-order hold (a digital
        controller output: a staircase, on which a valve with Fs > Fc sticks between
        the steps).
    initial_position : float, optional
        Initial valve position [% of span]; default: the force-balance rest position
        ``c op[0]``.  The valve starts at rest (stuck until |Fa + Fr| exceeds Fs).

    Returns
    -------
    ndarray
        Valve position mv [% of span], one per sample of ``op``.
    """
    if not isinstance(valve, PhysicalValve):
        raise UsageError("valve must be a PhysicalValve (see stictiondiag.models.physical)")
    try:
        dt_ = float(dt)
    except (TypeError, ValueError):
        raise UsageError(f"sample time dt must be a number of seconds, got {dt!r}") from None
    if not (math.isfinite(dt_) and dt_ > 0):
        raise UsageError(f"sample time dt must be a positive number of seconds, got {dt_}")
    if hold not in ("linear", "zoh"):
        raise UsageError(f"unknown hold {hold!r}: use linear or zoh")
    x = np.ascontiguousarray(op, dtype=float)
    if x.ndim != 1:
        raise UsageError("op must be a one-dimensional signal")
    if x.size and not np.isfinite(x).all():
        raise UsageError("op contains NaN or infinite values: fill or drop them first")
    scale = valve.stem_travel_per_percent
    x_req = np.clip(x, 0.0, 100.0) * scale
    n_sub, h = valve.substeps(dt_)
    if x.size:
        x0 = (
            valve.calibration * x_req[0]
            if initial_position is None
            else float(initial_position) * scale
        )
    else:
        x0 = 0.0
    x0 = min(max(x0, 0.0), 100.0 * scale)
    pos = _karnopp_open_loop(x_req, n_sub, valve.kernel_parameters(h), x0, hold == "linear")
    return pos / scale
