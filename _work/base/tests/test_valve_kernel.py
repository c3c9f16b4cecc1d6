"""The open-loop valve kernels (state in locals, saturation inside) give the same
output as the per-sample step functions the closed-loop simulators use."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stictiondiag.models.valve import (
    choudhury_model,
    choudhury_step,
    kano_model,
    kano_step,
    valve_state,
)


def _by_steps(step, op, S, J, start_stuck=True, initial_position=None):
    """The model as Section 5.1 describes it: saturate the input, run the Fig. 10
    state machine one sample at a time, saturate the output."""
    x = np.clip(op, 0.0, 100.0)
    st = valve_state(x[0], start_stuck)
    if initial_position is not None:
        st[0] = initial_position
    y = [st[0]] + [step(float(xk), st, S, J) for xk in x[1:]]
    return np.clip(np.array(y), 0.0, 100.0)


def _signal(seed: int, n: int = 3000) -> np.ndarray:
    """Noisy random walk that saturates at both ends, with stops and a NaN."""
    rng = np.random.default_rng(seed)
    op = 50.0 + np.cumsum(rng.normal(0.0, 2.0, n))
    op[rng.random(n) < 0.1] = np.nan
    op = np.where(np.isnan(op), np.roll(op, 1), op)  # repeated samples: stops
    op[n // 2] = math.nan
    return op


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("S, J", [(0.0, 0.0), (5.0, 0.0), (5.0, 2.0), (5.0, 5.0), (3.0, 8.0)])
@pytest.mark.parametrize(
    "model, step", [(choudhury_model, choudhury_step), (kano_model, kano_step)]
)
def test_kernel_equals_the_step_function(model, step, seed, S, J):
    op = _signal(seed)
    # Same operations in the same order: equal to the last bit (NaN where NaN).
    np.testing.assert_array_equal(model(op, S, J), _by_steps(step, op, S, J))
    np.testing.assert_array_equal(
        model(op, S, J, start_stuck=False, initial_position=104.0),
        _by_steps(step, op, S, J, start_stuck=False, initial_position=104.0),
    )
