"""The fit kernels of :mod:`stictiondiag.stiction.valvefit` against the per-sample step
functions of :mod:`stictiondiag.models.valve` (Fig. 10 of Choudhury et al. 2005 and
Kano et al. 2004), run here in plain Python on the state vector.

The kernels keep the valve's state in local variables; the reference below keeps it
in the state array of :func:`valve_state`.  Both run the same scalar flowchart
(``_choudhury_next`` / ``_kano_next``), so the outputs must agree bit for bit:
the tolerance is zero.
"""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.models.valve import choudhury_step, kano_step, valve_state
from stictiondiag.stiction.valvefit import valve_run, valve_sse_batch


def _reference_run(op, S, J, kano, k_start, d_start, offset):
    """valve_run with the state in the array of :func:`valve_state` (the former kernel)."""
    n = op.size
    st = valve_state(op[k_start], False)
    st[2] = d_start
    st[3] = d_start
    if offset < 0.0:
        st[0] = op[k_start] - d_start * (S - J) / 2.0
    else:
        x_ss = op[k_start] - d_start * offset
        st[1] = x_ss
        st[4] = 1.0
        st[0] = x_ss - d_start * (S - J) / 2.0
    y = np.empty(n)
    y[: k_start + 1] = st[0]
    slips = 0
    step = kano_step if kano else choudhury_step
    for k in range(k_start + 1, n):
        was_stuck = st[4] == 1.0
        y[k] = step(op[k], st, S, J)
        if was_stuck and st[4] == 0.0:
            slips += 1
    return y, slips


def _signals(seed):
    rng = np.random.default_rng(seed)
    n = 1500
    t = np.arange(n)
    op = 50 + 6 * np.sin(2 * np.pi * t / 230) + rng.normal(0, 0.3, n)
    op[400:430] = op[400]  # a flat stretch: the valve sticks on a zero slope
    op = np.round(op, 2)  # repeated samples, as a quantised recording has
    mv = op + rng.normal(0, 0.2, n)
    return np.ascontiguousarray(op), np.ascontiguousarray(mv)


CASES = [
    (5.0, 2.0, 0, 1.0, -1.0),
    (3.0, 3.0, 17, -1.0, -1.0),
    (6.0, 0.5, 40, 1.0, 2.5),
    (2.0, 4.0, 5, -1.0, 0.0),
    (0.0, 0.0, 0, 0.0, -1.0),
]


@pytest.mark.parametrize("kano", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_valve_run_is_the_step_functions_bit_for_bit(kano, seed):
    noisy, _ = _signals(seed)
    # Without noise the Choudhury model slips too (with noise it re-sticks at every
    # reversal of op), so the slip counts are compared on non-zero numbers.
    clean = np.round(50 + 6 * np.sin(2 * np.pi * np.arange(1500) / 230), 2)
    total = 0
    for op in (noisy, clean):
        for S, J, k_start, d_start, offset in CASES:
            y, slips = valve_run(op, S, J, kano, k_start, d_start, offset)
            y_ref, slips_ref = _reference_run(op, S, J, kano, k_start, d_start, offset)
            assert np.array_equal(y, y_ref)
            assert slips == slips_ref
            total += slips
    assert total > 0


@pytest.mark.parametrize("kano", [False, True])
def test_valve_sse_batch_is_the_step_functions_bit_for_bit(kano):
    op, mv = _signals(3)
    k0 = 41
    S_arr = np.array([c[0] for c in CASES])
    J_arr = np.array([c[1] for c in CASES])
    for k_start, d_start, offset in ((40, 1.0, -1.0), (40, -1.0, 1.5), (0, 1.0, -1.0)):
        k0 = k_start + 1
        got = valve_sse_batch(op, mv, S_arr, J_arr, kano, k0, k_start, d_start, offset)
        for i in range(S_arr.size):
            y, _ = _reference_run(op, S_arr[i], J_arr[i], kano, k_start, d_start, offset)
            # The kernel's own summation order (one pass, sample by sample).
            s1 = 0.0
            s2 = 0.0
            for k in range(k_start + 1, op.size):
                if k >= k0:
                    r = mv[k] - y[k]
                    s1 += r
                    s2 += r * r
            cnt = op.size - k0
            assert got[i] == s2 - s1 * s1 / cnt


def test_variant_sse_is_one_pair_of_the_batch_run_by_its_band():
    """``ValveVariant.sse`` is the batch's number for one (S, J) pair, run by the
    variant that represents the band (:meth:`ValveVariant.for_band`): behind the play
    operator for a wide band, on the raw op for one narrower than the play.  The same
    kernel on the same inputs, so the tolerance is zero."""
    from stictiondiag.stiction.valvefit import ValveVariant

    rng = np.random.default_rng(3)
    op = 50.0 + np.cumsum(rng.normal(0.0, 0.3, 600))
    mv = op + rng.normal(0.0, 0.05, op.size)
    played = ValveVariant("kano+play", True, play_width=1.0)
    sync = (11, 10, 1.0)
    for S, J in ((3.0, 1.0), (0.5, 0.2)):
        v = played.for_band(S)
        batch = valve_sse_batch(
            v.prepare(op), mv, v.model_S(np.array([S])), np.array([J]), v.kano, *sync, -1.0
        )
        assert played.sse(op, mv, S, J, sync) == float(batch[0])
    # The narrow band runs on the raw op (no play), the wide one behind it.
    assert played.for_band(0.5).play_width == 0.0 and played.for_band(3.0) is played
