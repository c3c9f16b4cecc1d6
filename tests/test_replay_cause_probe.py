"""The closed-loop reproduction probe (scripts/replay_cause_probe.py): the fitted
loop's replay against the same identified loop with a linear valve."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from stictiondiag.analysis import estimate_loop
from stictiondiag.io.tags import Tags
from stictiondiag.models.describing import stability_margins
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI
from stictiondiag.replay import replay

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "replay_cause_probe.py"


def _probe():
    spec = importlib.util.spec_from_file_location("replay_cause_probe", SCRIPT)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _estimate(S, J, load=None):
    """The paper's concentration loop at 1 s (Table 3), 2000 samples after a
    1000-sample start, through the chain's head as a user's record."""
    sim = simulate_loop(
        FOPTD(3.0, 10.0, 10.0),
        PI(0.2, 10.0),
        duration=3000.0,
        dt=1.0,
        valve="choudhury" if S > 0 else "linear",
        S=S,
        J=J,
        load=load,
        seed=1,
    )
    tags = Tags.from_arrays(
        sim.pv[1000:], sim.op[1000:], sp=sim.sp[1000:], ts=1.0, integrating=False
    )
    return estimate_loop(tags)


def test_a_sticky_loop_is_reproduced_and_its_linear_twin_settles():
    # S = J = 5 on the concentration loop: a stiction limit cycle (REFERENCE.md). The
    # replay reproduces it (period within 20 %, amplitude within 35 %); the same loop
    # with a linear valve is stable (gain margin 2.6) and, with no load in the replay,
    # settles: its second-half pv spread is below a tenth of the data's.
    probe = _probe()
    f, cost = probe.replay_features(_estimate(5.0, 5.0))
    assert f["replay_available"] == 1.0
    assert f["replay_reproduces"] == 1.0
    assert f["linear_cycles"] == 0.0
    assert f["linear_amplitude_ratio"] <= math.log(0.1)
    # The replay's amplitude within 35 % (reproduced), the twin's below a tenth.
    assert f["replay_contrast"] > math.log(0.65 / 0.1)
    assert probe.replay_call(f) == "valve"
    assert cost["replay_s"] >= 0.0 and cost["linear_s"] >= 0.0


def test_an_external_cycle_makes_an_identified_loop_that_cycles_on_its_own():
    # A linear valve and a 100-s sinusoidal load, the load the only excitation: op
    # answers pv through the controller, op = -C pv, so the process identified from
    # op to pv is -1/C at the cycle's frequency and the identified loop sits on its
    # stability limit there.  Its linear-valve replay (no load) then cycles at the
    # data's period and size (amplitude within 35 %), and the call is "tuning": from
    # closed-loop data alone the replay cannot tell an external cycle from a tight loop.
    k = np.arange(3000)
    est = _estimate(0.0, 0.0, load=2.0 * np.sin(2 * np.pi * k / 100.0))
    probe = _probe()
    f, _ = probe.replay_features(est)
    assert f["linear_cycles"] == 1.0
    assert abs(f["linear_amplitude_ratio"]) < math.log(1.35)
    assert probe.replay_call(f) == "tuning"
    # The identified loop's gain margin is 1 within 10 % (the true loop's: 2.6).
    rep = replay(est.tags, est.fit, valve=est.fit.valve_family, integrating=False)
    margins = stability_margins(rep.process_fit.process, rep.controller_fit.controller)
    assert margins.gain_margin == pytest.approx(1.0, rel=0.1)
