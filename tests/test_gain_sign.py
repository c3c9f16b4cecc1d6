"""The no-mv fit's process gain held to the sign that closes a negative feedback loop
with the identified controller (``Kc Kp > 0``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from stictiondiag.analysis import FLOW_LIKE, estimate_loop
from stictiondiag.apps.family import family_loop
from stictiondiag.identification.controller import SIGN_MIN_R2, loop_gain_sign
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import LOOP_PARAMETERS
from stictiondiag.stiction.hammerstein import fit_hammerstein
from stictiondiag.stiction.hammerstein import kernels as hk


def _normal_equations(seed: int):
    rng = np.random.default_rng(seed)
    P = rng.normal(size=(400, 5))
    Y = rng.normal(size=(400, 8)) + P[:, :2] @ rng.normal(size=(2, 8))
    return P, Y, P.T @ P, P.T @ Y, np.sum(Y**2, axis=0)


def test_signed_least_squares_is_the_best_fit_of_that_sign():
    """With the sign held, the cost is that of the best fit whose two basis gains
    have it (checked against the plain least squares of every active set), the
    free cost is the smaller of the two signed ones, and the batched kernel gives
    the per-column numbers."""
    P, Y, A, B, yy = _normal_equations(3)
    for sign in (1, -1, 0):
        out = np.empty(Y.shape[1])
        hk.same_sign_fit_many(A, B, yy, 2, sign, out)
        for k in range(Y.shape[1]):
            one = hk.same_sign_fit(A, np.ascontiguousarray(B[:, k]), yy[k], 2, sign)
            # Same operations per active set; the shortcut of the batch may differ
            # by rounding only where a smaller set ties with the full one.
            assert out[k] == pytest.approx(one, rel=1e-12)
            theta = hk.same_sign_lstsq(P, Y[:, k], 2, sign)
            if sign:
                assert np.all(theta[:2] * sign >= 0.0)
            # Rounding of a Cholesky solve against numpy's lstsq on 400 rows.
            assert one == pytest.approx(float(np.sum((Y[:, k] - P @ theta) ** 2)), rel=1e-9)
    plus, minus, free = (np.empty(Y.shape[1]) for _ in range(3))
    hk.same_sign_fit_many(A, B, yy, 2, 1, plus)
    hk.same_sign_fit_many(A, B, yy, 2, -1, minus)
    hk.same_sign_fit_many(A, B, yy, 2, 0, free)
    np.testing.assert_allclose(free, np.minimum(plus, minus), rtol=1e-12)
    # Both signs bind somewhere in this draw, so the test can tell them apart.
    assert np.any(plus > free * (1 + 1e-9)) and np.any(minus > free * (1 + 1e-9))


def _pi_loop():
    p = LOOP_PARAMETERS["concentration"]
    sim = simulate_loop(
        p["process"], p["controller"], duration=1500.0, dt=0.5, valve="choudhury",
        S=5.0, J=2.0, noise_std=0.02, seed=11, kick=2.0,
    )  # fmt: skip
    w = sim.op.size // 5
    return sim.op[w:], sim.pv[w:], 0.5


def test_controller_sign_well_determined_or_not_at_all():
    op, pv, dt = _pi_loop()
    # op computed by the PI law from pv: the law explains nearly all of op's moves.
    sign, r2 = loop_gain_sign(None, pv, op, dt)
    assert sign == 1 and r2 > 0.9
    # A reverse-acting controller (op's sign flipped) needs a negative process gain.
    assert loop_gain_sign(None, pv, -op, dt)[0] == -1
    # An op that is not computed from this pv (a random walk): no law, no sign.
    walk = 50.0 + np.cumsum(np.random.default_rng(1).normal(size=op.size)) * 0.1
    sign, r2 = loop_gain_sign(None, pv, walk, dt)
    assert sign == 0 and r2 < SIGN_MIN_R2


def _family_fits(seed: int):
    loop = dataclasses.replace(family_loop(seed), mv=None)
    est = estimate_loop(loop.tags())
    t = est.tags
    free = fit_hammerstein(
        t.op, t.pv, float(t.ts), integrating=bool(t.integrating),
        flow_loop=t.loop_type in FLOW_LIKE,
    )  # fmt: skip
    return loop, est.fit, free


def _gain(fit) -> float:
    lp = fit.linear_part
    return float(lp.direct_gain + lp.lag_gain)


def test_the_sign_recovers_a_sticky_valve_the_free_fit_misses():
    """Family loop 20210 (self-regulating, S 0.71, J 0.70 % of span, no load): with
    the sign free the fit finds a negative process gain and no band (S 0, error
    0.71 %); held to the controller's positive sign it finds the valve.  Tolerance
    0.2 % of span: a fifth of the J of the loop, and below the free fit's error."""
    loop, signed, free = _family_fits(20210)
    S, J = loop.truth["S"], loop.truth["J"]
    assert _gain(free) < 0.0 and abs(free.S - S) > 0.5
    gs = signed.gain_sign
    assert gs is not None and gs.required == 1 and gs.consistent_fit
    assert gs.controller_fit_r2 is not None and gs.controller_fit_r2 > 0.99
    assert _gain(signed) > 0.0
    assert signed.S == pytest.approx(S, abs=0.2)
    assert signed.J == pytest.approx(J, abs=0.2)


def test_no_sign_when_the_controller_law_explains_little():
    """Family loop 20054 (healthy, a swinging-door record: op's archive hides the
    law, R^2 0.08): the controller's sign is not well determined, so the fit is the
    free one, to the last bit, and says that no sign was held."""
    _, signed, free = _family_fits(20054)
    gs = signed.gain_sign
    assert gs is not None and gs.required == 0 and not gs.binding_at_estimate
    assert gs.controller_fit_r2 is not None and gs.controller_fit_r2 < SIGN_MIN_R2
    assert (signed.S, signed.J, signed.cost) == (free.S, free.J, free.cost)


def test_no_fit_of_the_right_sign_is_reported_as_undetermined():
    """Family loop 20260 (sticky, a deadband archive): no valve output drives pv with
    the controller's sign, so the fitted gain is zero; the fit says so and S and J
    are not claimed (intervals over the whole search range)."""
    _, signed, _ = _family_fits(20260)
    assert signed.gain_sign is not None and signed.gain_sign.required == 1
    assert not signed.gain_sign.consistent_fit
    assert _gain(signed) == 0.0
    assert signed.poorly_determined("S") and signed.poorly_determined("J")
