"""The compiled kernels of the Hammerstein fit give the numbers of their plain forms."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.stiction.hammerstein_kernels import valve_output
from stictiondiag.stiction.valvefit import valve_run


@pytest.mark.parametrize("kano", [True, False])
@pytest.mark.parametrize("offset", [-1.0, 0.0, 0.7])
@pytest.mark.parametrize("d_start", [-1.0, 0.0, 1.0])
def test_valve_output_is_valve_run_to_the_last_bit(kano, offset, d_start):
    """The local-state valve run used by the batch cost repeats the operations of
    ``valve_run`` (Fig. 10 of Choudhury et al. 2005; Kano et al. 2004) in the same
    order, so the outputs are equal exactly (tolerance 0: any change of order or of
    a branch would show).  op: a noisy sine with flat stretches, so that the valve
    sticks, slips, and sees zero slopes."""
    rng = np.random.default_rng(3)
    k = np.arange(3000)
    op = 2.0 * np.sin(2 * np.pi * k / 400) + 0.05 * rng.standard_normal(k.size)
    op[1000:1100] = op[1000]  # a stretch where op does not move
    op = np.round(op, 2)  # quantised: repeated samples, zero slopes
    for S, J in [(0.0, 0.0), (0.5, 0.1), (1.5, 1.5), (3.0, 0.0)]:
        for k_start in (0, 17):
            want, _ = valve_run(op, S, J, kano, k_start, d_start, offset)
            got = valve_output(op, S, J, kano, k_start, d_start, offset)
            np.testing.assert_array_equal(got, want)
            assert np.ptp(want[k_start:]) > 0.0 or S >= 3.0  # the valve did move
