"""A change of stiction's slips tested in the direction of the fitted change."""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.analysis import diagnose_gap_tags
from stictiondiag.gap.effects.signatures import slips_differ
from stictiondiag.models.synthetic import generate_case


def _slips(n=40, seed=3):
    """Reversal travels of 2.0 in the first half and 1.8 in the second, noise 0.1."""
    rng = np.random.default_rng(seed)
    travel = np.r_[2.0 + 0.1 * rng.standard_normal(n), 1.8 + 0.1 * rng.standard_normal(n)]
    return {
        "travel": travel,
        "J": np.full(2 * n, 0.5),
        "reversal": np.ones(2 * n, dtype=bool),
    }


def test_slips_differ_one_sided_follows_the_fitted_change():
    slips = _slips()
    early = np.arange(80) < 40
    late = ~early
    two = slips_differ(slips, early, late)
    # 40 against 40 slips two standard deviations apart: the rank test is far
    # below 1 % two-sided.
    assert two < 1e-8
    # Fitted S falling (the later slips smaller, as they are): half the two-sided p.
    assert slips_differ(slips, early, late, expect={"travel": -0.2}) == pytest.approx(0.5 * two)
    # Fitted S rising: the slips differ the other way, no evidence (1 - p/2).
    assert slips_differ(slips, early, late, expect={"travel": 0.2}) == pytest.approx(1 - 0.5 * two)
    # No direction (0) keeps the two-sided test.
    assert slips_differ(slips, early, late, expect={"travel": 0.0}) == pytest.approx(two)


def test_installed_characteristic_is_not_taken_for_a_change_of_stiction():
    """Generated loop (development seed 17, case 6): an equal-percentage
    characteristic on an integrating loop with a Karnopp valve.  A time-varying
    stiction with S 4.914 -> 4.938 and J 4.186 -> 4.205 % (a change of 0.5 %) was
    accepted, its slips differing before and after at p 0.008 two-sided, and it
    outranked the characteristic (gap 28.5 to 23.8 % against 16.2 %).  The later
    slips are smaller, not larger as the fitted rise says: one-sided p 0.53, and the
    characteristic is named."""
    case = generate_case("valve_characteristic", 2210455490)
    g = diagnose_gap_tags(case.tags())
    tvs = next(c for c in g.candidates if c.effect == "time_varying_stiction")
    assert tvs.params.S_end > tvs.params.S_start
    assert tvs.params.slips_differ_p == pytest.approx(0.53, abs=0.02)
    assert not tvs.accepted
    assert g.effect == "valve_characteristic"
    # Tolerance: the gaps to the hundredth of a point, as measured.
    assert g.after == pytest.approx(16.16, abs=0.01)
