"""Linear process and controller models of the closed loops (Section 4.2.2, Table 3).

Transfer functions are kept as small frozen dataclasses with their frequency
response, so the time-domain simulator (:mod:`stictiondiag.models.loops`) and the
describing-function analysis (:mod:`stictiondiag.models.describing`) share one definition.
Times are in seconds; gains in (units of pv) per (% of valve span).
"""

from __future__ import annotations

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


Process = FOPTD | Integrating


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
