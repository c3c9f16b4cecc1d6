"""The cheap figure helpers of :mod:`stictiondiag.plotting.canvas`: same pictures."""

from __future__ import annotations

import io

import numpy as np
import pytest
from matplotlib.font_manager import FontProperties
from PIL import Image

from stictiondiag.plotting.canvas import (
    decimate,
    new_figure,
    pin_decorations,
    place_axes,
    text_width,
)


def test_decimate_keeps_short_series_and_gaps():
    t = np.arange(100.0)
    y = np.sin(t)
    td, yd = decimate(t, y)
    assert td is t or np.array_equal(td, t)
    assert np.array_equal(yd, y)
    y_long = np.sin(np.arange(10_000.0))
    y_long[50] = np.nan
    assert decimate(np.arange(10_000.0), y_long)[1].size == 10_000


def test_decimate_keeps_the_envelope():
    rng = np.random.default_rng(0)
    n = 10_001
    t = np.arange(n) * 0.5
    y = np.cumsum(rng.normal(size=n))
    y[1234] += 50.0  # a spike
    y[7000:] += 20.0  # a jump
    td, yd = decimate(t, y, n_out=2000)
    assert yd.size <= 2002
    assert td[0] == t[0] and td[-1] == t[-1] and yd[-1] == y[-1]
    assert np.all(np.diff(td) > 0)
    assert yd.max() == y.max() and yd.min() == y.min()
    assert 1234 * 0.5 in td
    # Every run of samples keeps its extremes: the envelope is the same.
    k = -(-n // 1000)
    for start in range(0, n, k):
        sel = (td >= t[start]) & (td <= t[min(start + k, n) - 1])
        assert yd[sel].max() == y[start : start + k].max()
        assert yd[sel].min() == y[start : start + k].min()


@pytest.mark.parametrize(
    "text", ["-0.125", "\N{MINUS SIGN}2.5", "valve_characteristic", "a\nlonger line"]
)
def test_text_width_is_the_drawn_width(text):
    fig, _ = new_figure(1, 1, (4, 3))
    renderer = fig.canvas.get_renderer()
    for size in (8, 10):
        drawn = max(
            renderer.get_text_width_height_descent(line, FontProperties(size=size), False)[0]
            for line in text.split("\n")
        )
        assert text_width(text, size) * fig.dpi == pytest.approx(drawn, rel=0.05, abs=1.0)


def test_png_canvas_writes_the_same_pixels():
    fig, axes = new_figure(1, 2, (6, 3))
    axes[0, 0].plot([0, 1, 2], [3, -1, 2])
    axes[0, 1].set_title("t")
    fast, best = io.BytesIO(), io.BytesIO()
    fig.savefig(fast, format="png", dpi=80)
    fig.savefig(best, format="png", dpi=80, pil_kwargs={"compress_level": 9})
    a = np.asarray(Image.open(io.BytesIO(fast.getvalue())))
    b = np.asarray(Image.open(io.BytesIO(best.getvalue())))
    assert a.shape == (240, 480, 4)
    assert np.array_equal(a, b)
    assert len(fast.getvalue()) >= len(best.getvalue())


def _demo(pin: bool):
    fig, axes = new_figure(2, 2, (9, 6), width_ratios=(2, 1))
    rng = np.random.default_rng(1)
    ax = axes[0, 0]
    ax.plot(np.arange(500.0), 1234.5 + np.cumsum(rng.normal(size=500)))
    ax.set_ylabel("pv [units]")
    ax.set_title("trend", loc="left", fontsize=9)
    ax = axes[0, 1]
    ax.bar([0, 1, 2], [3e-7, 1e-7, 2e-7])  # y offset text: the title stays automatic
    ax.set_xticks([0, 1, 2], ["op\nearly", "op\nlate", "pv\nearly"])
    ax.set_title("over time (first and second half)", fontsize=10)
    ax.set_ylabel("gap [%]")
    ax = axes[1, 0]
    ax.barh([0, 1], [0.1, 0.2])
    ax.set_yticks([0, 1], ["valve_characteristic", "lag"], fontsize=8)
    ax.set_xlabel("gap [%]")
    ax = axes[1, 1]
    ax.plot([-5, 5], [-0.02, 0.03])
    ax.set_xlabel("op [% of span]")
    ax.set_ylabel("mv\n[% of span]")
    ax.set_title("mv-op")
    place_axes(fig, left=1.6, right=0.2, top=0.5, bottom=0.7, wspace=1.0, hspace=0.9)
    if pin:
        pin_decorations(fig)
    fig.set_dpi(110)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    boxes = {}
    for i, ax in enumerate(fig.axes):
        for name, text in (
            ("x", ax.xaxis.label),
            ("y", ax.yaxis.label),
            ("title", ax.title),
            ("left title", ax._left_title),
        ):
            if text.get_text():
                boxes[i, name] = text.get_window_extent(renderer).extents
    return boxes


def test_pinned_labels_and_titles_sit_where_matplotlib_puts_them():
    auto, pinned = _demo(False), _demo(True)
    assert auto.keys() == pinned.keys()
    for key, box in auto.items():
        assert np.abs(np.asarray(pinned[key]) - box).max() < 1.5, key


def test_analysis_figures_are_pngs(tmp_path):
    from stictiondiag.analysis import (
        AnalysisConfig,
        analyze,
    )
    from stictiondiag.io.tags import Tags
    from stictiondiag.models.loops import simulate_loop
    from stictiondiag.models.processes import LOOP_PARAMETERS

    loop = LOOP_PARAMETERS["concentration"]
    sim = simulate_loop(
        loop["process"], loop["controller"], duration=6000.0, dt=1.0, S=5.0, J=2.0, seed=2
    )
    tags = Tags.from_arrays(sim.pv, sim.op, mv=sim.mv, ts=1.0)
    figs = analyze(tags, config=AnalysisConfig(gap=False)).figures()
    assert set(figs) == {"phase", "valve_zoom", "reconstruction"}
    for name, fig in figs.items():
        _assert_units_and_no_empty_panels(name, fig)
        path = tmp_path / f"{name}.png"
        fig.savefig(path, dpi=110, format="png")
        with Image.open(path) as im:
            assert im.format == "PNG"
            w, h = fig.get_size_inches() * 110
            assert im.size == (round(w), round(h))


def _assert_units_and_no_empty_panels(name, fig):
    """Every visible panel shows something, and every axis label carries its unit
    in brackets (a time axis shared down a column is labelled at the bottom only)."""
    for ax in fig.axes:
        if not ax.axison:
            assert ax.texts, f"{name}: an empty panel"
            continue
        assert ax.has_data(), f"{name}: panel {ax.get_title()!r} is empty"
        assert "[" in ax.get_ylabel(), f"{name}: y axis {ax.get_ylabel()!r} has no unit"
        assert ax.get_xlabel() == "" or "[" in ax.get_xlabel(), (name, ax.get_xlabel())


def test_valve_zoom_draws_S_and_J_at_a_slip():
    """Fig. 10: S along op ending at the slip, J along mv from the stuck position.
    Open loop through Choudhury's valve (Eq. 4), so the slips are known: each one
    jumps J plus what op moved in that sample (0.1 s of a 50 s sine, < 0.13 %)."""
    from stictiondiag.models.valve import choudhury_model
    from stictiondiag.plotting.valve import find_slip, plot_valve_zoom

    t = np.arange(0, 300, 0.1)
    op = 50 + 10 * np.sin(2 * np.pi * t / 50)
    mv = choudhury_model(op, 5.0, 2.0)
    fig = plot_valve_zoom(op, mv, ts=0.1, S=5.0, J=2.0, period_s=50.0)
    _assert_units_and_no_empty_panels("valve_zoom", fig)
    ax = fig.axes[0]
    arrows = [a for a in ax.texts if getattr(a, "arrow_patch", None) is not None]
    assert len(arrows) == 2
    (x0, y0), (x1, y1) = arrows[0].xyann, arrows[0].xy  # S: horizontal
    assert y0 == y1 and abs(x1 - x0) == pytest.approx(5.0, abs=1e-9)
    (x2, y2), (x3, y3) = arrows[1].xyann, arrows[1].xy  # J: vertical, from the stuck mv
    assert x2 == x3 == x1 and y2 == y1 and abs(y3 - y2) == pytest.approx(2.0, abs=1e-9)
    k = find_slip(mv[-1500:], 2.0)
    assert k is not None and abs(mv[-1500:][k] - mv[-1500:][k - 1]) == pytest.approx(2.0, abs=0.13)
    # No slip as large as half of J: the figure says so instead of drawing arrows.
    fig = plot_valve_zoom(op, op, ts=0.1, S=5.0, J=2.0, period_s=50.0)
    assert not [a for a in fig.axes[0].texts if getattr(a, "arrow_patch", None) is not None]


def test_poorly_determined_parameters_are_marked_on_the_figures():
    from stictiondiag.plotting.valve import plot_valve_zoom
    from stictiondiag.stiction.fit_result import Determinacy, StictionFit

    def fit_of(S, S_iv, det_S, J=5.78, J_iv=(2.89, 5.78), det_J=Determinacy.OPEN):
        return StictionFit(
            S=S, J=J, S_scaled=S, J_scaled=J, S_interval=S_iv, J_interval=J_iv,
            method="hammerstein", mv_model=np.zeros(3), n_slips=0, cost=1.0,
            linear_cost=1.0, S_determinacy=det_S, J_determinacy=det_J,
        )  # fmt: skip

    fit = fit_of(0.5, (0.0, 1.7), Determinacy.WELL)
    assert [s for s in ("S", "J") if fit.poorly_determined(s)] == ["J"]
    zero = fit_of(0.0, (0.0, 0.0), Determinacy.POOR)
    assert not zero.poorly_determined("S")  # pinned at zero by the data
    t = np.arange(0, 300, 0.1)
    op = 50 + 10 * np.sin(2 * np.pi * t / 50)
    fig = plot_valve_zoom(op, op, ts=0.1, S=0.5, J=5.78, period_s=50.0, poorly=["J"])
    texts = " ".join(t.get_text() for t in fig.axes[0].texts)
    assert "J = 5.78 % (poorly determined)" in texts and "S = 0.5 %," in texts
    # On the arrows too, when the window holds a slip.
    from stictiondiag.models.valve import choudhury_model

    mv = choudhury_model(op, 5.0, 2.0)
    fig = plot_valve_zoom(op, mv, ts=0.1, S=5.0, J=2.0, period_s=50.0, poorly=["J"])
    labels = [a.get_text() for a in fig.axes[0].texts if a.get_text()]
    assert labels == ["S = 5 %", "J = 2 % (poorly determined)"]


def test_gap_breakdown_layout_survives_a_summary_wider_than_the_figure():
    # A summary line wider than the figure (a runner-up margin printed with 300
    # digits did it) used to give matplotlib "left cannot be >= right"; the figure
    # now widens so that each panel keeps at least 1.2 in.
    from stictiondiag.plotting.canvas import new_figure
    from stictiondiag.plotting.gap import _breakdown_layout

    fig, axes = new_figure(2, 3, (14, 7.5))
    _breakdown_layout(fig, axes, summary_width=30.0)
    assert fig.get_figwidth() > 30.0
    params = fig.subplotpars
    assert params.left < params.right
    width_in = (params.right - params.left) * fig.get_figwidth()
    assert width_in >= 3 * 1.2  # three columns of at least min_cell
    fig.clf()


def _gap_stub(mv_share, pv_share):
    from types import SimpleNamespace

    from stictiondiag.gap.breakdown import (
        Breakdown,
        ByPhase,
        PerSignal,
        PhaseError,
        PhaseShare,
        SignalGap,
    )

    share = PhaseShare(
        samples_pct=25.0,
        mv=PhaseError(mv_share, None, mv_share, None),
        pv=PhaseError(pv_share, None, pv_share, None),
    )
    phase = ByPhase(stuck=share, slip=share, moving=share, reversal=share)
    signal = PerSignal.of({s: SignalGap(1.0, 1.0, 0.0) for s in ("op", "pv", "mv")})
    return SimpleNamespace(
        breakdown=Breakdown(signal=signal, phase=phase),
        candidates=(),
        before=3.5,
        after=3.5,
        effect="none",
        shrink_pct=0.0,
        runner_up=None,
        margin=0.0,
        not_assessed=(),
    )


def test_gap_valve_phase_panel_is_never_empty():
    """Issue 27: on level_undershoot the mv replay is exact (every mv share 0): the
    panel shows pv's shares, and with no error in either it is left out and the
    summary says so in words."""
    from stictiondiag.plotting.gap import plot_gap_breakdown

    fig = plot_gap_breakdown(_gap_stub(0.0, 25.0))
    titles = [ax.get_title() for ax in fig.axes]
    assert "By valve phase (share of pv error)" in titles
    fig = plot_gap_breakdown(_gap_stub(0.0, 0.0))
    assert not any("valve phase" in ax.get_title() for ax in fig.axes)
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert any("by valve phase: no replay error in mv or pv" in t for t in texts)


def test_gap_frequency_panel_names_an_exact_replay_instead_of_empty_bars():
    """Issue 27: with mv replayed exactly (level_undershoot) mv's frequency shares are
    None, not zeros; the panel draws pv only and names mv in words, and with every
    replay exact the panel is left out and the summary says why."""
    from dataclasses import replace

    from stictiondiag.gap.breakdown import ByFrequency, FrequencyShares, PerSignal
    from stictiondiag.plotting.gap import plot_gap_breakdown

    shares = FrequencyShares(60.0, 30.0, 10.0, 60.0, 30.0, 10.0)
    exact = FrequencyShares(None, None, None, None, None, None)
    stub = _gap_stub(0.0, 25.0)
    stub.breakdown = replace(
        stub.breakdown, frequency=ByFrequency(100.0, PerSignal(pv=shares, mv=exact))
    )
    fig = plot_gap_breakdown(stub)
    ax = next(a for a in fig.axes if a.get_title().startswith("By frequency"))
    assert [t.get_text() for t in ax.get_xticklabels()] == ["pv"]
    assert "mv: replay exact" in ax.get_xlabel()
    # The stacked bar of pv reaches 100 % (60 + 30 + 10): nothing is dropped from it.
    tops = [p.get_y() + p.get_height() for p in ax.patches]
    assert max(tops) == pytest.approx(100.0, abs=1e-9)
    stub.breakdown = replace(
        stub.breakdown, frequency=ByFrequency(100.0, PerSignal(pv=exact, mv=exact))
    )
    fig = plot_gap_breakdown(stub)
    assert not any(a.get_title().startswith("By frequency") for a in fig.axes)
    texts = [t.get_text() for a in fig.axes for t in a.texts]
    assert any("by frequency: every replay exact" in t for t in texts)


def test_gap_breakdown_marks_an_exact_replay_by_frequency():
    """The breakdown gives None shares for a replay with no error, real shares that
    sum to 100 % (to rounding) for one with an error."""
    from types import SimpleNamespace

    from stictiondiag.gap.breakdown import _by_frequency

    n = 2000
    t = np.arange(n)
    pv = np.sin(2 * np.pi * t / 100.0)
    sig = SimpleNamespace(op=pv.copy(), pv=pv, mv=pv.copy(), dt=1.0)
    meas = SimpleNamespace(w=np.ones(n))
    preds = {"mv": pv.copy(), "pv": pv + 0.1 * np.sin(2 * np.pi * t / 50.0)}
    fr = _by_frequency(sig, meas, preds, preds)
    assert fr.signals.mv.fundamental_pct_before is None
    total = sum(
        getattr(fr.signals.pv, f"{p}_pct_before") for p in ("fundamental", "harmonics", "other")
    )
    assert total == pytest.approx(100.0, abs=1e-9)
    # The error is the second harmonic: nearly all of it lands there (leakage < 5 %).
    assert fr.signals.pv.harmonics_pct_before > 95.0
