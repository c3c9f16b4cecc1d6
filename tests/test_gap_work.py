"""The cheaper gap diagnosis names what the full one names.

Three savings are checked against the work they replace: effects acting on mv alone
are not fitted when the base replay of mv is within its noise (they cannot lower the
gap); only the two most promising spectral peaks of ``external_disturbance`` are
refined; the slip features of the breakdown are computed by array operations.
"""

from __future__ import annotations

import numpy as np
import pytest

from stictiondiag.gap.breakdown import _slip_features
from stictiondiag.gap.context import build_context, signals_of, starting_point
from stictiondiag.gap.diagnose import diagnose_gap
from stictiondiag.gap.effects import external_disturbance as ed
from stictiondiag.gap.effects.base import fit_base
from stictiondiag.gap.effects.kernels import valve_replay
from stictiondiag.gap.selection import mv_within_noise
from stictiondiag.io.tags import Tags
from stictiondiag.models.synthetic import generate_case
from stictiondiag.models.valve import PHASE_MOVING, PHASE_SLIP

N = 2000  # short records keep the file fast; the hidden effects are strong enough

MV_ONLY = ("actuator_lag", "miscalibration", "asymmetry", "time_varying_stiction")


@pytest.fixture(scope="module")
def disturbed():
    """A loop with an external oscillation: its valve replay is within the mv noise."""
    return generate_case("external_disturbance", 4, n_samples=N)


def test_skipped_effects_leave_the_diagnosis_as_the_full_one(disturbed):
    g = diagnose_gap(disturbed.tags())
    full = diagnose_gap(disturbed.tags(), fit_all=True)
    assert set(g.within_noise) == set(MV_ONLY)
    assert not ({c.effect for c in g.candidates} & set(MV_ONLY))
    # The same effect and the same gap before and after, to the last bit: the effects
    # that remain are fitted by the same computations, and a skipped one can never win.
    assert g.effect == full.effect == "external_disturbance"
    assert (g.before, g.after, g.shrink_pct) == (full.before, full.after, full.shrink_pct)
    # The bound the skip rests on, seen in the full diagnosis: each effect on mv alone
    # leaves the gap on the record where the base has it (never below).
    for c in full.candidates:
        if c.effect in MV_ONLY:
            assert c.after >= full.before


def test_a_hidden_valve_effect_is_not_skipped():
    # A miscalibrated positioner puts mv off the two-parameter replay by far more than
    # its noise: every valve effect is fitted and the right one named.
    case = generate_case("miscalibration", 3, n_samples=N)
    g = diagnose_gap(case.tags())
    assert g.within_noise == ()
    assert g.effect == "miscalibration"


def test_within_noise_is_the_excess_of_the_gap(disturbed):
    sig = signals_of(disturbed.tags())
    ctx = build_context(sig, **starting_point(None, sig))
    base = fit_base(ctx, ctx.w_eval)
    assert mv_within_noise(ctx, base)
    # The same replay against an mv moved by 3 noise deviations is not within noise.
    shifted = signals_of(
        Tags.from_arrays(
            sig.pv, sig.op, mv=sig.mv + 3.0 * np.std(np.diff(sig.mv)), sp=sig.sp, ts=sig.dt
        )
    )
    ctx2 = build_context(shifted, **starting_point(None, shifted))
    assert not mv_within_noise(ctx2, base)


def test_screened_peaks_give_the_full_search_frequency(disturbed, monkeypatch):
    sig = signals_of(disturbed.tags())
    ctx = build_context(sig, **starting_point(None, sig))
    base = fit_base(ctx, ctx.w_eval)
    screened = ed.fit_external_disturbance(ctx, ctx.w_eval, base)
    monkeypatch.setattr(ed, "REFINED_PEAKS", 99)
    full = ed.fit_external_disturbance(ctx, ctx.w_eval, base)
    # The winning peak is among the two best at their centres, and its refinement is
    # the same computation: the same period and amplitudes (1e-12 relative allows
    # only rounding).
    assert screened.variant == full.variant
    assert screened.params.period_s == pytest.approx(full.params.period_s, rel=1e-12)
    assert screened.params.amplitude == pytest.approx(full.params.amplitude, rel=1e-12)
    # The hidden period, to 2 % (the fit's resolution on 2000 samples is finer).
    assert screened.params.period_s == pytest.approx(
        disturbed.truth["effect_parameters"]["period_s"], rel=0.02
    )


def test_screen_keeps_the_lowest_in_order():
    costs = {10: 5.0, 20: 1.0, 30: 3.0, 40: 0.5}
    assert ed._screen_peaks([10, 20, 30, 40], costs.__getitem__, 2) == [20, 40]
    assert ed._screen_peaks([10, 20], costs.__getitem__, 2) == [10, 20]


def _slip_features_loop(op, mv, phase, window=3):
    """The slip features one slip and one moving stretch at a time."""
    slips = np.where(phase == PHASE_SLIP)[0]
    slips = slips[(slips > 2) & (slips < mv.size - 2 * window - 2)]
    up, dn, resp = [], [], []
    for k in slips:
        d = mv[k + window] - mv[k - 1]
        (up if d > 0 else dn).append(abs(d))
        seg = mv[k - 1 : k + 2 * window + 2] - mv[k - 1]
        if abs(seg[-1]) > 0:
            resp.append(seg / seg[-1])
    rise = None
    if resp:
        avg = np.mean(resp, axis=0)
        above = np.where(avg >= 0.9)[0]
        rise = float(above[0]) if above.size else float(avg.size)
    moving = phase == PHASE_MOVING
    num = den = 0.0
    k = 0
    while k < mv.size:
        j = k
        while j < mv.size and moving[j]:
            j += 1
        if j - k >= 3:
            o, m = op[k:j] - op[k:j].mean(), mv[k:j] - mv[k:j].mean()
            num += float(np.dot(o, m))
            den += float(np.dot(o, o))
        k = max(j, k + 1)
    return {
        "jump_up": float(np.median(up)) if up else None,
        "jump_down": float(np.median(dn)) if dn else None,
        "moving_slope": num / den if den > 0 else None,
        "corner_rise_samples": rise,
    }


@pytest.mark.parametrize("seed", range(6))
def test_slip_features_match_one_slip_at_a_time(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    op = 50 + np.cumsum(rng.normal(0, 0.3, n)) + 5 * np.sin(np.arange(n) / 40)
    mv, phase = valve_replay(op, rng.uniform(0.5, 4), rng.uniform(0, 2))
    mv = mv + rng.normal(0, 0.05, n) * (seed % 2)
    fast, slow = _slip_features(op, mv, phase).to_dict(), _slip_features_loop(op, mv, phase)
    assert fast["jump_up"] == slow["jump_up"] and fast["jump_down"] == slow["jump_down"]
    assert fast["corner_rise_samples"] == slow["corner_rise_samples"]
    # The slope's sums run in another order: rounding only (1e-12 relative).
    assert fast["moving_slope"] == pytest.approx(slow["moving_slope"], rel=1e-12)


def test_slip_features_without_slips_or_moves():
    op = np.linspace(40, 60, 500)
    phase = np.full(500, 1, dtype=np.int8)
    f = _slip_features(op, op.copy(), phase).to_dict()
    assert f == {
        "jump_up": None,
        "jump_down": None,
        "moving_slope": None,
        "corner_rise_samples": None,
    }


def test_shared_segments_give_the_same_diagnosis():
    # analyze segments the mv-op plot once and hands the result to the gap diagnosis;
    # the diagnosis must be the one it computes from its own segmentation, to the bit
    # (the same function on the same arrays), on a loop where valve effects are fitted.
    from stictiondiag.stiction.segments import segment_valve

    case = generate_case("miscalibration", 3, n_samples=N)
    tags = case.tags()
    segs = segment_valve(tags.op, tags.mv, tags.ts)
    own = diagnose_gap(tags)
    shared = diagnose_gap(tags, segments=segs)
    assert shared.effect == own.effect
    assert (shared.before, shared.after, shared.shrink_pct) == (
        own.before,
        own.after,
        own.shrink_pct,
    )
    assert [(c.effect, c.after) for c in shared.candidates] == [
        (c.effect, c.after) for c in own.candidates
    ]


def test_a_refitted_process_is_judged_at_the_base_horizon(disturbed):
    """A candidate that searches the process structure afresh is judged at the base
    replay's prediction horizon: a nearer prediction has a smaller error whatever
    the effect (a healthy loop was named external_disturbance for it)."""
    from stictiondiag.gap.effects.base import fit_process

    sig = signals_of(disturbed.tags())
    ctx = build_context(sig, **starting_point(None, sig))
    base = fit_base(ctx, ctx.w_eval)
    h = base.process.prediction.model.horizon
    for target in (max(h - 3, 1), h + 3):
        f = fit_process(sig.mv, ctx, ctx.w_eval, horizon=target)
        assert f.prediction.model.horizon == target
    # Without a horizon the structure search sets its own (the base's here).
    assert fit_process(sig.mv, ctx, ctx.w_eval).prediction.model.horizon == h
