"""Linear process and controller models of the closed loops (Section 4.2.2, Table 3).

Transfer functions are kept as small frozen dataclasses with their frequency
response, so the time-domain simulator (:mod:`stictiondiag.models.loops`) and the
describing-function analysis (:mod:`stictiondiag.models.describing`) share one definition.
Times are in seconds; gains in (units of pv) per (% of valve span).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FOPTD:
    """First-order plus dead time process ``K e^{-theta s} / (tau s + 1)``.

    Attributes
    ----------
    gain : float
        Steady-state gain K [pv units / % of span].
    time_constant : float
        tau [s], > 0.
    dead_time : float
        theta [s], >= 0.
    """

    gain: float
    time_constant: float
    dead_time: float = 0.0

    kind = "foptd"

    def frequency_response(self, w: np.ndarray) -> np.ndarray:
        """``G(i w)`` at angular frequencies ``w`` [rad/s]."""
        s = 1j * np.asarray(w, dtype=float)
        return self.gain * np.exp(-self.dead_time * s) / (self.time_constant * s + 1.0)

    def to_dict(self) -> dict:
        return {
            "type": "foptd",
            "gain": self.gain,
            "time_constant_s": self.time_constant,
            "dead_time_s": self.dead_time,
        }


@dataclass(frozen=True)
class Integrating:
    """Integrating process ``K e^{-theta s} / s`` (a level loop, Table 3).

    Attributes
    ----------
    gain : float
        K [pv units / (% of span * s)].
    dead_time : float
        theta [s], >= 0.
    """

    gain: float
    dead_time: float = 0.0

    kind = "integrating"

    def frequency_response(self, w: np.ndarray) -> np.ndarray:
        """``G(i w)`` at angular frequencies ``w`` [rad/s]."""
        s = 1j * np.asarray(w, dtype=float)
        return self.gain * np.exp(-self.dead_time * s) / s

    def to_dict(self) -> dict:
        return {"type": "integrating", "gain": self.gain, "dead_time_s": self.dead_time}


@dataclass(frozen=True)
class PI:
    """PI controller in the paper's form ``C(s) = Kc (Ti s + 1) / (Ti s)`` (Eq. 3).

    Attributes
    ----------
    gain : float
        Kc [% of span / pv units].
    integral_time : float
        Ti [s], > 0.
    """

    gain: float
    integral_time: float

    def frequency_response(self, w: np.ndarray) -> np.ndarray:
        """``C(i w)`` at angular frequencies ``w`` [rad/s]."""
        s = 1j * np.asarray(w, dtype=float)
        return self.gain * (self.integral_time * s + 1.0) / (self.integral_time * s)

    def to_dict(self) -> dict:
        return {"type": "pi", "gain": self.gain, "integral_time_s": self.integral_time}


@dataclass(frozen=True)
class SampledLag:
    """Sampled process of a Hammerstein fit's linear part
    (:mod:`stictiondiag.stiction.hammerstein`, "The linear part"):

        G(z) = z^-d (b0 + b1 (1 - a) / (1 - a z^-1))        (self-regulating)
        G(z) = z^-d (b0 + b1 (1 - a) / (1 - a z^-1)) / (1 - z^-1)  (integrating)

    with ``a = exp(-dt / tau)``: a direct part and a first-order lag of unit gain
    behind a dead time of ``d`` samples, and for an integrating loop a sampled
    integrator (the fit explains pv's increments).  Evaluated at ``z = exp(i w dt)``,
    so it holds up to the Nyquist frequency ``pi / dt``.

    Attributes
    ----------
    direct_gain, lag_gain : float
        b0, b1 [pv units / % of span; per sample when integrating].
    time_constant : float
        tau [s], >= 0 (0: no lag, its gain adds to the direct part).
    dead_time : float
        d dt [s], >= 0.
    sample_time : float
        dt [s], > 0.
    integrating : bool
        The sampled integrator is part of the process.
    """

    direct_gain: float
    lag_gain: float
    time_constant: float
    dead_time: float
    sample_time: float
    integrating: bool = False

    kind = "sampled_lag"

    @property
    def gain(self) -> float:
        """Steady-state gain b0 + b1 [pv units / % of span; per sample when integrating]."""
        return float(self.direct_gain + self.lag_gain)

    def frequency_response(self, w: np.ndarray) -> np.ndarray:
        """``G(exp(i w dt))`` at angular frequencies ``w`` [rad/s]."""
        zi = np.exp(-1j * np.asarray(w, dtype=float) * self.sample_time)  # z^-1
        a = math.exp(-self.sample_time / self.time_constant) if self.time_constant > 0 else 0.0
        g = self.direct_gain + self.lag_gain * (1.0 - a) / (1.0 - a * zi)
        g = g * zi ** round(self.dead_time / self.sample_time)
        return g / (1.0 - zi) if self.integrating else g

    def to_dict(self) -> dict:
        return {
            "type": "sampled_lag",
            "direct_gain": self.direct_gain,
            "lag_gain": self.lag_gain,
            "time_constant_s": self.time_constant,
            "dead_time_s": self.dead_time,
            "sample_time_s": self.sample_time,
            "integrating": self.integrating,
        }


Process = FOPTD | Integrating | SampledLag


def open_loop_response(process: Process, controller: PI, w: np.ndarray) -> np.ndarray:
    """Open-loop frequency response ``G0(i w) = G(i w) C(i w)`` (Section 6.1, Eq. 5)."""
    return process.frequency_response(w) * controller.frequency_response(w)


#: The paper's closed loops (Eq. 3 and Table 3). ``dt`` is the simulation step [s].
LOOP_PARAMETERS: dict[str, dict] = {
    "concentration": {
        "process": FOPTD(gain=3.0, time_constant=10.0, dead_time=10.0),
        "controller": PI(gain=0.2, integral_time=10.0),
        "dt": 0.1,
        "description": "Concentration loop, G = 3 e^{-10s}/(10s+1), C = 0.2(10s+1)/(10s)",
    },
    "level": {
        "process": Integrating(gain=1.0),
        "controller": PI(gain=0.4, integral_time=2.0),
        "dt": 0.1,
        "description": "Level loop, G = 1/s, C = 0.4(2s+1)/(2s)",
    },
}

#: Loop used by ``stiction simulate`` when no ``--loop`` is given.
DEFAULT_LOOP = "concentration"
