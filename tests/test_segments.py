"""Stick, slip and moving phases from op and mv, and S and J from them (Sections 2.3, 3)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stictiondiag.core.errors import DataError
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import LOOP_PARAMETERS
from stictiondiag.models.valve import choudhury_model
from stictiondiag.stiction.fit_details import MvFitDetails
from stictiondiag.stiction.resolution import quantum
from stictiondiag.stiction.segments import (
    estimate_from_mv,
    segment_valve,
)

DT = 0.1


def sine_op(n=6000, amp=10.0, period=50.0):
    t = np.arange(n) * DT
    return 50.0 + amp * np.sin(2 * np.pi * t / period)


def concentration_loop(S, J, *, valve="choudhury", noise=0.0, duration=2500.0, dt=0.5):
    """The paper's concentration loop (Eq. 3, Table 3), the start-up fifth dropped."""
    p = LOOP_PARAMETERS["concentration"]
    sim = simulate_loop(
        p["process"],
        p["controller"],
        duration=duration,
        dt=dt,
        valve=valve,
        S=S,
        J=J,
        noise_std=noise,
        seed=7,
        kick=2.0,
    )
    w = sim.op.size // 5
    return sim.op[w:], sim.mv[w:], sim.pv[w:], dt


def test_open_loop_sine_every_slip_measured():
    # Fig. 11, third row: S = 5, J = 2 on a 10 % sine.  After the first swing every
    # stop is at a reversal of op, and every slip is a jump of J (REFERENCE.md).
    op = sine_op()
    mv = choudhury_model(op, 5.0, 2.0)
    seg = segment_valve(op, mv, DT)
    assert seg.n_slips >= 20  # two slips per 50 s cycle, 12 cycles
    # The breakaway overshoots the threshold by less than one op step (at most
    # 2 pi 10 / 500 = 0.126 % per sample); half a step is taken off, so each slip's
    # S and J are within half a step of the truth.  The first slip is left out: the
    # valve starts at rest without having moved, so Eq. 4 does not place it.
    step = 2 * np.pi * 10 / 500
    assert np.all(np.abs(seg.jump[1:] - 2.0) <= step / 2 + 1e-9)
    assert np.all(np.abs(seg.band[1:] - 5.0) <= step + 1e-9)
    # After the first slip the valve only stops at reversals of op.
    assert seg.reversal[1:].all()
    # Stuck while op travels, the slip right after the stuck interval.
    assert np.all(seg.slip[:, 0] == seg.stuck[:, 1])
    # The moving phase follows op at the Eq. 4 offset (S - J)/2 = 1.5.
    for a, b in seg.moving:
        if b - a > 5:
            off = op[a:b] - mv[a:b]
            assert np.allclose(np.abs(off), 1.5, atol=1e-9)


def test_travel_at_reversals_is_S():
    # The op travel from the stop to the breakaway is S at a reversal (Fig. 2, A-C).
    op = sine_op()
    mv = choudhury_model(op, 4.0, 1.0)
    seg = segment_valve(op, mv, DT)
    step = 2 * np.pi * 10 / 500
    assert np.all(np.abs(seg.travel[seg.reversal] - 4.0) <= step)


def test_closed_loop_recovers_S_and_J():
    op, mv, _, dt = concentration_loop(5.0, 2.0)
    fit = estimate_from_mv(op, mv, dt)
    # The least-squares fit of the exact model to noise-free mv: only the grid
    # resolution (op range / 30, refined three times by 2.5, about 1e-3 % here) is
    # left; 0.01 % of span is ten times that.
    assert fit.S == pytest.approx(5.0, abs=0.01)
    assert fit.J == pytest.approx(2.0, abs=0.01)
    assert fit.method == "mv_segments"
    assert isinstance(fit.details, MvFitDetails)
    seg = fit.details.segments
    # The slip-by-slip estimate has the op step (about 0.02 %/sample here) as its
    # resolution.
    assert seg.S == pytest.approx(5.0, abs=0.05)
    assert seg.J == pytest.approx(2.0, abs=0.05)
    lo, hi = fit.S_interval
    assert lo <= 5.0 <= hi
    lo, hi = fit.J_interval
    assert lo <= 2.0 <= hi
    assert fit.improvement > 0.9


@pytest.mark.parametrize("S, J", [(5.0, 5.0), (5.0, 7.0), (3.0, 0.5)])
def test_closed_loop_cases_of_fig_11(S, J):
    # No offset (J = S) and overshoot (J > S) as well as undershoot.
    op, mv, _, dt = concentration_loop(S, J)
    fit = estimate_from_mv(op, mv, dt)
    # As above: noise-free mv, resolution well below 0.02 % of span.
    assert fit.S == pytest.approx(S, abs=0.02)
    assert fit.J == pytest.approx(J, abs=0.02)


def test_noisy_and_quantised_mv():
    # Kano valve with measurement noise in the loop (noisy op), then position
    # transmitter noise of 0.1 % and a 0.5 % resolution on the recorded mv.
    op, mv, _, dt = concentration_loop(5.0, 2.0, valve="kano", noise=0.05)
    rng = np.random.default_rng(3)
    noisy = mv + 0.1 * rng.standard_normal(mv.size)
    quantised = np.round(mv / 0.5) * 0.5
    fit_n = estimate_from_mv(op, noisy, dt)
    fit_q = estimate_from_mv(op, quantised, dt)
    # A 0.1 % white noise averages out over each stuck level (hundreds of
    # samples); the quantised mv leaves levels off by up to 0.25 % each, which the
    # fit over many slips averages to within a tenth of that.
    assert fit_n.S == pytest.approx(5.0, abs=0.05)
    assert fit_n.J == pytest.approx(2.0, abs=0.05)
    assert fit_q.S == pytest.approx(5.0, abs=0.1)
    assert fit_q.J == pytest.approx(2.0, abs=0.1)
    assert quantum(quantised) == pytest.approx(0.5)
    assert quantum(noisy) == 0.0
    seg = segment_valve(op, quantised, dt)
    # The still band must cover the quantisation step, or every level change of
    # the quantised position would count as a slip.
    assert seg.still_band >= 0.5
    assert isinstance(fit_n.details, MvFitDetails)
    assert seg.n_slips == fit_n.details.segments.n_slips


def test_linear_valve_has_no_stiction():
    # mv = op plus transmitter noise: no stuck interval, S ~ 0.
    rng = np.random.default_rng(5)
    op = sine_op(n=4000) + 0.02 * rng.standard_normal(4000)
    mv = op + 0.05 * rng.standard_normal(op.size)
    seg = segment_valve(op, mv, DT)
    assert seg.n_slips == 0
    fit = estimate_from_mv(op, mv, DT)
    # A band wider than the noise (0.05 %) would leave the valve behind op at every
    # reversal and cost far more than it saves.
    assert fit.S < 0.05
    assert fit.J < 0.05
    assert abs(fit.improvement) < 0.05


def test_units_rescale_S_and_J_and_nothing_else():
    # STYLE.md invariant: op and mv in other units (here twice the % scale, an
    # exact binary factor) give S and J in those units and the same everything else.
    op, mv, _, dt = concentration_loop(4.0, 1.5, valve="kano", noise=0.03)
    a = estimate_from_mv(op, mv, dt)
    b = estimate_from_mv(2.0 * op, 2.0 * mv, dt)
    assert b.S == pytest.approx(2.0 * a.S, rel=1e-9)
    assert b.J == pytest.approx(2.0 * a.J, rel=1e-9)
    assert b.S_scaled == pytest.approx(a.S_scaled, rel=1e-9)
    assert b.J_scaled == pytest.approx(a.J_scaled, rel=1e-9)
    assert np.allclose(b.S_interval, 2.0 * np.asarray(a.S_interval), rtol=1e-9)
    assert b.n_slips == a.n_slips
    assert b.improvement == pytest.approx(a.improvement, rel=1e-9)
    assert b.valve_model == a.valve_model


def test_to_dict_is_json():
    op, mv, _, dt = concentration_loop(5.0, 2.0)
    fit = estimate_from_mv(op, mv, dt)
    d = fit.to_dict()
    json.dumps(d, allow_nan=False)
    assert d["method"] == "mv_segments"
    assert "mv_model" not in d
    assert fit.mv_model.shape == op.shape
    json.dumps(segment_valve(op, mv, dt).to_dict(), allow_nan=False)


@pytest.mark.parametrize(
    "op, mv, match",
    [
        (np.ones(100), np.ones(100), "constant"),
        (np.arange(100.0), np.arange(99.0), "equal length"),
        (np.r_[np.arange(99.0), np.nan], np.arange(100.0), "NaN"),
        (np.arange(10.0), np.arange(10.0), "at least"),
    ],
)
def test_bad_input_is_a_data_error(op, mv, match):
    with pytest.raises(DataError, match=match):
        estimate_from_mv(op, mv, 1.0)


def test_play_variant_band_below_play_width_is_the_raw_flowchart():
    # With mv too: behind the play operator every S below its width is a deadband
    # of that width, so S = J = 0 must run on the raw op and be the linear valve.
    from stictiondiag.stiction.segments import _grid_search
    from stictiondiag.stiction.valvefit import valve_variants

    rng = np.random.default_rng(5)
    t = np.arange(2000)
    op = 50 + 5 * np.sin(2 * np.pi * t / 200) + 0.1 * rng.standard_normal(t.size)
    mv = op.copy()  # a linear valve
    played = [v for v in valve_variants(op) if v.name == "kano+play"]
    assert played, "the noisy op should bring in the play variant"
    v = played[0]
    S_all, J_all, C_all, S_ls, J_ls, cost = _grid_search(
        op, mv, (1, 0, 0.0, -1.0), v, 10.0, 10.0, n_grid=11, n_zoom=1
    )
    at_zero = C_all[(S_all == 0) & (J_all == 0)]
    assert at_zero.size and float(at_zero.min()) == pytest.approx(0.0, abs=1e-9)
    assert S_ls < v.play_width


@pytest.mark.parametrize("m", [12, 700, 3001])
def test_median_ci_in_chunks_is_the_one_draw_bootstrap(m):
    from stictiondiag.core.stats import BOOTSTRAP_CHUNK_VALUES, bootstrap_median_ci

    # Issue 19: the bootstrap draws its resamples chunk by chunk (a few rows for
    # thousands of slips) from the one generator; the interval is that of drawing
    # all n_boot x m indices at once, to the bit (the same stream in the same order).
    # 12 slips take one chunk, 700 and 3001 several, the last one partial.
    assert 2000 * 12 <= BOOTSTRAP_CHUNK_VALUES < 2000 * 700
    x = np.random.default_rng(m).standard_normal(m)
    rng = np.random.default_rng(0)
    med = np.median(x[rng.integers(0, m, size=(2000, m))], axis=1)
    expected = tuple(float(v) for v in np.percentile(med, [2.5, 97.5]))
    assert bootstrap_median_ci(x) == expected


def test_short_median_is_numpys_bit_for_bit():
    # The per-run median of segment_valve replaces np.median for speed; the numbers
    # must be the very same (tolerance zero), odd and even counts, repeated values.
    from stictiondiag.stiction.segments import median_small as _median

    rng = np.random.default_rng(11)
    for _ in range(3000):
        k = int(rng.integers(1, 40))
        x = np.round(rng.normal(50.0, rng.uniform(1e-3, 10.0), k), int(rng.integers(0, 6)))
        assert _median(x) == float(np.median(x))
    assert _median(np.array([1.0, 2.0])) == 1.5
