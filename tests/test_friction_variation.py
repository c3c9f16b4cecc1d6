"""A friction that varies over time and with the direction of travel
(``friction_scale``, ``friction_asymmetry`` of stictiondiag.models.loops.simulate_loop),
as the cause family's sticky valves have it (stictiondiag.apps.family_causes)."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag import UsageError
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI

#: The concentration loop of Eq. 3 (Table 3) at 1 s samples.
PROCESS = FOPTD(3.0, 10.0, 10.0)
CONTROLLER = PI(0.2, 10.0)


def _run(**kw):
    return simulate_loop(PROCESS, CONTROLLER, duration=4000.0, dt=1.0, valve="choudhury", **kw)


def test_a_constant_factor_is_the_same_valve_with_S_and_J_scaled():
    # S * 2 and J * 2 are exact in floating point, so the runs must agree to the bit,
    # noise included.
    a = _run(S=2.0, J=1.0, friction_scale=2.0, noise_std=0.02, seed=3)
    b = _run(S=4.0, J=2.0, noise_std=0.02, seed=3)
    assert np.array_equal(a.mv, b.mv) and np.array_equal(a.pv, b.pv)
    assert a.settings["friction_variation"] == {
        "asymmetry": 0.0,
        "scale_min": 2.0,
        "scale_max": 2.0,
    }
    assert b.settings["friction_variation"] is None


def _breakaway_travel(op, mv):
    """op's travel from its last turn to each breakaway of a stuck valve, with the
    breakaway's direction (+1 opening, -1 closing)."""
    dmv = np.diff(mv)
    moving = np.abs(dmv) > 1e-9
    out = []
    for k in np.flatnonzero(moving[1:] & ~moving[:-1]) + 1:
        d = np.sign(dmv[k])
        # Go back from the breakaway while op moved in the breakaway's direction.
        j = k
        while j > 0 and np.sign(op[j] - op[j - 1]) == d:
            j -= 1
        turn = op[j]
        out.append((d, abs(op[k + 1] - turn)))
    return out


def test_asymmetry_scales_the_stick_band_by_direction():
    # S = 4 with a = 0.5: the valve breaks away after op has travelled S (1 + a) = 6
    # back from its turn when opening and S (1 - a) = 2 when closing (Fig. 10's
    # band, one factor per direction).  Noise-free, op is monotone between turns and
    # moves well under 0.2 % a sample while the valve is stuck, hence the tolerance.
    sim = _run(S=4.0, J=2.0, friction_asymmetry=0.5)
    travel = _breakaway_travel(sim.op[500:], sim.mv[500:])[1:]  # the first turn: before 500
    up = [t for d, t in travel if d > 0]
    down = [t for d, t in travel if d < 0]
    assert len(up) >= 3 and len(down) >= 3
    assert np.allclose(up, 6.0, atol=0.2)
    assert np.allclose(down, 2.0, atol=0.2)


@pytest.mark.parametrize(
    ("kw", "words"),
    [
        ({"friction_scale": 0.0}, "friction_scale must be > 0"),
        ({"friction_scale": np.ones(3)}, "friction_scale must be a number or an array"),
        ({"friction_asymmetry": 1.0}, "friction_asymmetry must lie in (-1, 1)"),
    ],
)
def test_bad_friction_variation_is_a_usage_error(kw, words):
    with pytest.raises(UsageError, match=words.replace("(", r"\(").replace(")", r"\)")):
        _run(S=4.0, J=2.0, **kw)
