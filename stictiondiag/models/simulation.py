"""Result objects of the closed-loop simulation (:mod:`stictiondiag.models.loops`).

:class:`Simulation` holds the time series of a run of Eq. 3 and Table 3 of
Choudhury, Thornhill & Shah (2005); :class:`LimitCycle` the sustained oscillation
measured on it (Sections 4.2.2 and 5.3).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from stictiondiag.core.errors import UsageError
from stictiondiag.core.serialize import plain_float
from stictiondiag.models.describing import predict_limit_cycle
from stictiondiag.models.physical import PhysicalValve
from stictiondiag.models.processes import FOPTD, PI, Integrating
from stictiondiag.signals.oscillation import detect_oscillation


@dataclass(frozen=True)
class LimitCycle:
    """Sustained oscillation of a simulated loop (after the start-up transient).

    Attributes
    ----------
    present : bool
        pv oscillates regularly and without decay (Thornhill et al. 2003 test).
    period_s : float or None
        Period of the pv cycle [s].
    amplitude : dict
        Half peak-to-peak amplitude of the cycle of ``pv`` [pv units], ``op`` and
        ``mv`` [% of span]; None for a signal without a cycle.
    oscillations : dict
        The :class:`~stictiondiag.signals.oscillation.Oscillation` of pv, op and mv.
    transient_s : float
        Length of the start of the run left out of the analysis [s].
    """

    present: bool
    period_s: float | None
    amplitude: dict
    oscillations: dict
    transient_s: float

    def to_dict(self) -> dict:
        """JSON-able dict."""
        return {
            "present": bool(self.present),
            "period_s": plain_float(self.period_s),
            "amplitude": {k: plain_float(v) for k, v in self.amplitude.items()},
            "oscillations": {k: v.to_dict() for k, v in self.oscillations.items()},
            "transient_s": float(self.transient_s),
        }


@dataclass(frozen=True, eq=False)
class Simulation:
    """Time series of a closed-loop simulation (:func:`simulate_loop`).

    Attributes
    ----------
    time : ndarray
        Time [s], every ``dt`` from 0.
    sp : ndarray
        Setpoint [pv units].
    pv : ndarray
        Measured process output, noise included [pv units].
    op : ndarray
        Controller output, the valve demand [% of span].
    mv : ndarray
        Valve position [% of span].
    dt : float
        Sample time of the records [s].
    settings : dict
        Everything the run depended on (JSON-able): process, controller, valve, S, J,
        physical valve, integration step [s], biases, kick, noise, seed, ...
    process : FOPTD or Integrating, optional
        The simulated process (for the describing-function prediction).
    controller : PI, optional
        The simulated controller.
    physical : PhysicalValve, optional
        The physical valve, when ``settings["valve"] == "physical"``.
    """

    time: np.ndarray
    sp: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray
    dt: float
    settings: dict = field(default_factory=dict)
    process: FOPTD | Integrating | None = None
    controller: PI | None = None
    physical: PhysicalValve | None = None

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time.size)

    def to_pandas(self):
        """DataFrame with columns time [s], sp, pv [pv units], op, mv [% of span]."""
        import pandas as pd

        return pd.DataFrame(
            {"time": self.time, "sp": self.sp, "pv": self.pv, "op": self.op, "mv": self.mv}
        )

    def to_dict(self, include_series: bool = True) -> dict:
        """JSON-able dict: settings and, optionally, the series as lists."""
        d = {"dt": float(self.dt), "n_samples": self.n, "settings": self.settings}
        if include_series:
            d["series"] = {
                name: [plain_float(v) for v in getattr(self, name).tolist()]
                for name in ("time", "sp", "pv", "op", "mv")
            }
        return d

    def plot(self, **kwargs):
        """Trends of sp/pv and op/mv with the mv-op and pv-op maps (Figs. 9, 12-15).

        Keyword arguments go to :func:`stictiondiag.plotting.simulation.plot_simulation`.
        """
        # Imported when a figure is asked for: callers that want numbers skip matplotlib.
        from stictiondiag.plotting.simulation import plot_simulation

        return plot_simulation(self, **kwargs)

    def describing_function(self):
        """Limit cycle predicted by the describing function for this loop (Section 6).

        :func:`stictiondiag.models.describing.predict_limit_cycle` with the run's process,
        controller and stiction parameters.  For the physical valve the quasi-static
        data-driven equivalent is used (:meth:`PhysicalValve.data_driven_equivalent`):
        with calibration ``c`` the valve output is ``c`` times that of a data-driven
        valve with ``S`` and ``J / c`` on the op axis, so the process gain is
        multiplied by ``c``.  For the linear valve there is no nonlinearity and no
        cycle.

        Returns
        -------
        tuple of (LimitCyclePrediction, dict)
            The prediction and the basis of it: ``{"S", "J", "process_gain_factor",
            "source"}``.
        """
        import dataclasses

        if self.process is None or self.controller is None:
            raise UsageError("this simulation does not carry its process and controller")
        valve = self.settings.get("valve")
        process = self.process
        if valve == "physical":
            eq = self.physical.data_driven_equivalent()
            gain = eq["gain"]
            S, J = eq["S"], eq["J"] / gain
            if gain != 1.0:
                process = dataclasses.replace(process, gain=process.gain * gain)
            source = (
                "quasi-static equivalent of the physical valve, S=(Fs+Fc)/(c k), J=(Fs-Fc)/(c k)"
            )
        elif valve in ("choudhury", "kano", "he"):
            S, J, gain = float(self.settings["S"]), float(self.settings["J"]), 1.0
            source = "data-driven S and J"
        elif valve == "band":
            S = float(self.settings["S"])
            J, gain = S, 1.0  # the band-hold valve slips all the way to its demand
            source = "band-hold valve: J = S"
        else:
            S, J, gain = 0.0, 0.0, 1.0
            source = "linear valve (no nonlinearity)"
        prediction = predict_limit_cycle(process, self.controller, S, J)
        basis = {"S": S, "J": J, "process_gain_factor": gain, "source": source}
        return prediction, basis

    def summary(
        self,
        transient: float | None = None,
        *,
        cycle: LimitCycle | None = None,
        describing: tuple | None = None,
    ) -> dict:
        """JSON-able summary: simulated cycle and describing-function prediction.

        Keys: ``limit_cycle`` (bool), ``period_s`` (pv period [s] or None),
        ``amplitude`` {op, mv [% of span], pv [pv units]} (half peak-to-peak),
        ``describing_function`` {limit_cycle, period_s, amplitude (X_m, % of span),
        S, J, basis}, ``oscillation`` (per-signal detail) and ``settings``.
        ``cycle`` and ``describing``: :meth:`limit_cycle` (then ``transient`` is not
        used) and :meth:`describing_function` of this run when already computed.
        """
        lc = self.limit_cycle(transient) if cycle is None else cycle
        prediction, basis = self.describing_function() if describing is None else describing
        return {
            "limit_cycle": bool(lc.present),
            "period_s": plain_float(lc.period_s),
            "amplitude": {k: plain_float(lc.amplitude[k]) for k in ("op", "mv", "pv")},
            "describing_function": {
                "limit_cycle": bool(prediction.limit_cycle),
                "period_s": plain_float(prediction.period_s),
                "amplitude": plain_float(prediction.amplitude_op),
                "S": float(basis["S"]),
                "J": float(basis["J"]),
                "basis": basis["source"],
            },
            "oscillation": lc.to_dict(),
            "settings": self.settings,
        }

    def limit_cycle(self, transient: float | None = None) -> LimitCycle:
        """Detect the sustained cycle of pv, op and mv after the start-up transient.

        Parameters
        ----------
        transient : float, optional
            Start of the run to leave out [s]; default the first third.

        Returns
        -------
        LimitCycle
            Uses :func:`stictiondiag.signals.oscillation.detect_oscillation` on each signal.
        """

        duration = self.n * self.dt
        if transient is None:
            transient = duration / 3.0
        transient = float(transient)
        if not (math.isfinite(transient) and 0.0 <= transient < duration):
            raise UsageError(
                f"transient must be in [0, {duration:g}) s (the run length), got {transient}"
            )
        start = int(round(transient / self.dt))
        osc = {
            name: detect_oscillation(getattr(self, name)[start:], self.dt)
            for name in ("pv", "op", "mv")
        }
        return LimitCycle(
            present=bool(osc["pv"].present),
            period_s=osc["pv"].period_s,
            amplitude={name: o.amplitude for name, o in osc.items()},
            oscillations=osc,
            transient_s=start * self.dt,
        )
