"""The orchestrator :func:`stictiondiag.analysis.analyze`: golden cases and invariants.

Golden cases are the bundled sample loops (``sample_data/``, written by
``scripts/make_sample_data.py`` with the data-driven valve of Section 5.1, so the
true S and J are known). Invariants (``/work``'s style guide): replaying the fitted
parameters reproduces the data; S and J are in % of span, so giving op and mv in
other units with the matching ``op_range`` changes nothing, nor does rescaling pv;
reading twice gives the same result; the result is strictly JSON.

The sim-to-real gap diagnosis is left out (``AnalysisConfig(gap=False)``) except in
the one test about it: it is the slowest step and has its own tests.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import sawtooth

from stictiondiag.analysis import (
    Analysis,
    AnalysisConfig,
    analyze,
    analyze_file,
    find_oscillations,
)
from stictiondiag.core.errors import DataError
from stictiondiag.io.tags import Tags
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import LOOP_PARAMETERS
from stictiondiag.signals.oscillation import detect_oscillation
from stictiondiag.stiction.verdict import stiction_verdict

SAMPLE_DATA = Path(__file__).resolve().parents[1] / "sample_data"
NO_GAP = AnalysisConfig(gap=False)

#: Sample file -> (read options, true S, true J, stiction present); sample_data/README.md.
SAMPLES = {
    "level_undershoot.csv": ({"loop_type": "level"}, 5.0, 2.5, True),
    "slave_flow_stickslip.csv": ({"loop_type": "flow"}, 3.0, 3.0, True),
    "temperature_quantised.csv": ({"loop_type": "temperature"}, 2.0, 2.5, True),
    "level_no_mv.csv": ({"loop_type": "level"}, 3.0, 1.5, True),
    "flow_mixed.csv": ({"loop_type": "flow"}, None, None, True),
    "healthy_flow.csv": ({"loop_type": "flow"}, 0.0, 0.0, False),
}

_cache: dict[str, Analysis] = {}


def sample_analysis(name: str) -> Analysis:
    """Analysis of one sample file, computed once per test session."""
    if name not in _cache:
        options = SAMPLES[name][0]
        _cache[name] = analyze_file(SAMPLE_DATA / name, config=NO_GAP, **options)
    return _cache[name]


def _concentration(S=5.0, J=2.0, noise=0.05, seed=3, n=3000):
    """The concentration loop of Eq. 3 / Table 3 at 1 s, start-up transient dropped."""
    loop = LOOP_PARAMETERS["concentration"]
    sim = simulate_loop(
        loop["process"],
        loop["controller"],
        duration=500.0 + n,
        dt=1.0,
        S=S,
        J=J,
        noise_std=noise,
        seed=seed,
    )
    keep = slice(500, 500 + n)
    return {k: getattr(sim, k)[keep] for k in ("pv", "op", "mv", "sp")}


@pytest.fixture(scope="module")
def conc():
    return _concentration()


@pytest.fixture(scope="module")
def conc_mv(conc) -> Analysis:
    tags = Tags.from_arrays(conc["pv"], conc["op"], mv=conc["mv"], sp=conc["sp"], ts=1.0)
    return analyze(tags, config=NO_GAP)


@pytest.fixture(scope="module")
def conc_no_mv(conc) -> Analysis:
    tags = Tags.from_arrays(conc["pv"], conc["op"], sp=conc["sp"], ts=1.0)
    return analyze(tags, config=NO_GAP)


# ----------------------------------------------------------------------------- golden cases


#: Known shortfalls of the estimation steps on the sample loops, kept visible: strict
#: xfail, so the test fails (XPASS) as soon as the step is fixed and the mark can go.
KNOWN = {
    ("S_J", "level_no_mv.csv"): "Hammerstein fit on the integrating loop without mv: "
    "S 2.3 / J 5.8 against 3 / 1.5 (stictiondiag.stiction.hammerstein)",
}


def _cases(kind: str, names):
    return [
        pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=KNOWN[(kind, n)]))
        if (kind, n) in KNOWN
        else n
        for n in names
    ]


@pytest.mark.parametrize(
    "name",
    _cases("S_J", [n for n, (_, S, _J, sticky) in SAMPLES.items() if sticky and S is not None]),
)
def test_sample_loops_recover_S_and_J(name):
    _, S_true, J_true, _ = SAMPLES[name]
    a = sample_analysis(name)
    if a.tags.mv is not None and "quantised" not in name:
        # mv recorded: stick phases are exact and the slip is one sample, so the
        # segment estimate is limited by the noise on op at the reversals (a few
        # tenths of a percent at the sample loops' noise levels).
        tol = 0.3
    elif a.tags.mv is not None:
        # mv read to 1 % of span: the stuck position and the jump are known to
        # half a quantum each.
        tol = 0.5
    else:
        # No mv: S and J come through the identified process and the noise on pv
        # (the accuracy target without mv is 1 % of span).
        tol = 1.0
    assert a.fit.S == pytest.approx(S_true, abs=tol), (a.fit.S, a.fit.J)
    assert a.fit.J == pytest.approx(J_true, abs=tol), (a.fit.S, a.fit.J)
    if a.tags.mv is None:
        assert a.fit.method == "hammerstein"
    else:
        assert a.fit.method == "mv_segments"


def test_mixed_valve_lies_between_its_two_regions():
    # flow_mixed.csv: S 3 / J 4.5 below 50 % travel, S 4 / J 2 above. One pair of
    # parameters for the whole record must fall within the two regions' values
    # (widened by the 0.3 % noise tolerance of the single-valve cases).
    a = sample_analysis("flow_mixed.csv")
    assert 3.0 - 0.3 <= a.fit.S <= 4.0 + 0.3
    assert 2.0 - 0.3 <= a.fit.J <= 4.5 + 0.3


@pytest.mark.parametrize("name", _cases("verdict", list(SAMPLES)))
def test_sample_verdicts(name):
    sticky = SAMPLES[name][3]
    a = sample_analysis(name)
    if sticky:
        assert a.verdict.status == "stiction", a.verdict.reasons
        assert a.verdict.detected is True
    else:
        assert a.verdict.status != "stiction", a.verdict.reasons
        assert a.verdict.detected is not True
    assert 0.0 <= a.verdict.confidence <= 1.0


def test_healthy_loop_has_no_stiction_parameters():
    # A linear valve: mv = op, so S and J estimate zero up to the noise on op at
    # reversals (0.3 %, as for the sticky loops).
    a = sample_analysis("healthy_flow.csv")
    assert a.fit.S == pytest.approx(0.0, abs=0.3)
    assert a.fit.J == pytest.approx(0.0, abs=0.3)


# ----------------------------------------------------------------------------- invariants


def test_simulated_loop_with_and_without_mv(conc_mv, conc_no_mv):
    # Same loop, S = 5, J = 2: from mv within the 0.3 % target, from pv within 1 %.
    assert conc_mv.fit.S == pytest.approx(5.0, abs=0.3)
    assert conc_mv.fit.J == pytest.approx(2.0, abs=0.3)
    assert conc_no_mv.fit.S == pytest.approx(5.0, abs=1.0)
    assert conc_no_mv.fit.J == pytest.approx(2.0, abs=1.0)
    for a in (conc_mv, conc_no_mv):
        assert a.verdict.status == "stiction"
        assert a.oscillation.present
        # Table 3 / REFERENCE.md: 142 s at 0.1 s, 140 s at 1 s; the detector's
        # ACF period on 3000 noisy samples within 5 %.
        assert a.oscillation.period_s == pytest.approx(140.0, rel=0.05)


@pytest.mark.parametrize("which", ["conc_mv", "conc_no_mv"])
def test_replay_reproduces_the_data(which, request):
    a = request.getfixturevalue(which)
    rep = a.replay
    assert rep is not None, a.warnings
    # The generating valve is the data-driven model: the replayed limit cycle has
    # the data's period within 5 % (the target; the cycle period moves a
    # few percent with how S and J are rounded, Table 3 vs REFERENCE.md).
    assert rep.period_replay_s == pytest.approx(rep.period_data_s, rel=0.05)
    # Amplitudes within 15 %: the op cycle is set by S and J (Section 6, Xm), which
    # are recovered to a few percent of their size.
    for signal in ("pv", "op"):
        amp = rep.measures.by_signal()[signal]
        assert amp.amplitude_replay == pytest.approx(amp.amplitude_data, rel=0.15), signal
    # Same cycle shape (phase-free measure): triangle op, sharp-turning pv.
    assert rep.measures.pv.waveform > 0.9
    assert rep.measures.op.waveform > 0.9


def _same_result(a: Analysis, b: Analysis, abs_tol: float) -> None:
    assert a.fit.S == pytest.approx(b.fit.S, abs=abs_tol)
    assert a.fit.J == pytest.approx(b.fit.J, abs=abs_tol)
    # Scaled S and J are in units of op's standard deviation: unit-free.
    assert a.fit.S_scaled == pytest.approx(b.fit.S_scaled, abs=abs_tol)
    assert a.fit.J_scaled == pytest.approx(b.fit.J_scaled, abs=abs_tol)
    assert a.verdict.status == b.verdict.status
    # The probability reads features of the fit, which moves by the optimiser's
    # rounding (S and J within abs_tol): 1e-4, far below the two decimals shown and the
    # distance to a decision level.
    assert a.verdict.confidence == pytest.approx(b.verdict.confidence, abs=1e-4)
    assert a.oscillation.period_s == pytest.approx(b.oscillation.period_s, rel=1e-9)


@pytest.mark.parametrize(
    "units,op_range,to_raw",
    [
        ("percent", (0.0, 1.0), lambda x: x / 100.0),  # fraction of span
        ("percent", (-2000.0, 6000.0), lambda x: -2000.0 + 80.0 * x),  # raw counts
        ("mA", None, lambda x: 4.0 + 0.16 * x),  # 4-20 mA (Section 5.1)
    ],
)
def test_op_units_change_nothing(units, op_range, to_raw, conc, conc_mv):
    # op and mv in other units with the matching op_range map back to % of span;
    # S and J are in % of span (Section 5.1), so the whole result is the same.
    # Tolerance 1e-6 % of span: only float rounding of the unit conversion differs.
    tags = Tags.from_arrays(
        conc["pv"],
        to_raw(conc["op"]),
        mv=to_raw(conc["mv"]),
        sp=conc["sp"],
        ts=1.0,
        op_units=units,
        op_range=op_range,
    )
    a = analyze(tags, config=NO_GAP)
    _same_result(a, conc_mv, abs_tol=1e-6)


def test_pv_units_change_nothing(conc, conc_no_mv):
    # pv in other units (x 250 + 40, e.g. % to kPa with an offset): the process
    # gain absorbs the scale, S and J (op side) do not move. Without mv the fit
    # goes through pv, so this is where pv's units could leak in.
    # Tolerance 1e-3 % of span: the fit's optimiser stops at a relative tolerance,
    # the scale changes only rounding.
    tags = Tags.from_arrays(
        250.0 * conc["pv"] + 40.0, conc["op"], sp=250.0 * conc["sp"] + 40.0, ts=1.0
    )
    a = analyze(tags, config=NO_GAP)
    _same_result(a, conc_no_mv, abs_tol=1e-3)


def test_reading_twice_gives_the_same_result():
    name = "slave_flow_stickslip.csv"
    again = analyze_file(SAMPLE_DATA / name, config=NO_GAP, loop_type="flow")
    # The same result apart from when it ran.
    first, second = again.to_dict(), sample_analysis(name).to_dict()
    assert first.pop("analysed_at") and second.pop("analysed_at")
    assert first == second


def test_input_file_not_modified(tmp_path):
    path = SAMPLE_DATA / "level_undershoot.csv"
    before = path.read_bytes()
    sample_analysis("level_undershoot.csv")
    assert path.read_bytes() == before


def _walk(obj, path="$"):
    """Yield (path, leaf) for every leaf of a nested dict/list."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            assert isinstance(k, str), path
            yield from _walk(v, f"{path}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _walk(v, f"{path}[{i}]")
    else:
        yield path, obj


def test_to_dict_is_strict_json(conc_mv, conc_no_mv):
    for a in (conc_mv, conc_no_mv):
        d = a.to_dict()
        json.dumps(d, allow_nan=False)  # no NaN or inf anywhere
        for path, leaf in _walk(d):
            assert leaf is None or type(leaf) in (str, int, float, bool), (path, type(leaf))
            if isinstance(leaf, float):
                assert math.isfinite(leaf), path
        st = d["stiction"]
        assert st["units"] == "% of op span"
        assert st["S"] == a.fit.S and st["J"] == a.fit.J
        assert st["detected"] is True and st["status"] == "stiction"
        for key in ("process", "controller", "fit"):
            assert isinstance(d["replay"][key], dict) and d["replay"][key]
        assert d["gap"] is None  # not run


def test_summary_row_is_flat(conc_mv):
    row = conc_mv.summary_row()
    assert row["verdict"] == "stiction" and row["has_mv"] is True
    assert row["S"] == conc_mv.fit.S
    for key, value in row.items():
        assert value is None or type(value) in (str, int, float, bool), key


def test_figures(conc_no_mv):
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    figs = conc_no_mv.figures()
    try:
        assert {"phase", "reconstruction"} <= set(figs)
        assert all(isinstance(f, Figure) for f in figs.values())
        # Phase plot: trends and pv-op always, mv-op of the fitted model (no mv
        # recorded), pv-sp only when sp moves (here it is constant).
        assert len(figs["phase"].axes) >= 4
    finally:
        for f in figs.values():
            plt.close(f)


def test_no_sp_and_no_replay(conc, conc_mv):
    # Without sp the fit is the same (it does not use sp); without the replay step
    # there is no replay, no gap and only the phase figure.
    tags = Tags.from_arrays(conc["pv"], conc["op"], mv=conc["mv"], ts=1.0)
    a = analyze(tags, config=AnalysisConfig(gap=False, replay=False))
    assert a.fit.S == conc_mv.fit.S and a.fit.J == conc_mv.fit.J
    assert a.verdict.status == conc_mv.verdict.status
    assert a.replay is None and a.gap is None
    d = a.to_dict()
    assert d["replay"] is None and d["tags"]["has_sp"] is False
    figs = a.figures()
    assert set(figs) == {"phase", "valve_zoom"}
    import matplotlib.pyplot as plt

    plt.close(figs["phase"])


def test_gap_diagnosis_is_reported(conc, tmp_path):
    # The one test with the gap on: its result lands in the JSON with its keys, and
    # its figures, saved as files, are the figures of the result.
    tags = Tags.from_arrays(conc["pv"], conc["op"], mv=conc["mv"], sp=conc["sp"], ts=1.0)
    a = analyze(tags)
    gap = a.to_dict()["gap"]
    assert gap is not None, a.warnings
    for key in ("metric", "before", "after", "shrink_pct", "effect", "candidates"):
        assert key in gap
    assert a.summary_row()["gap_effect"] == gap["effect"]
    written = a.save_figures(tmp_path / "figures")
    figs = a.figures()
    assert list(figs) == ["phase", "valve_zoom", "reconstruction", "gap_breakdown", "gap_replay"]
    assert written == [tmp_path / "figures" / a.figure_file(name) for name in figs]
    for name, fig in figs.items():
        fig.savefig(tmp_path / "direct.png", dpi=110, format="png")
        assert (tmp_path / "figures" / a.figure_file(name)).read_bytes() == (
            tmp_path / "direct.png"
        ).read_bytes(), name


def test_to_pandas_holds_the_data_the_model_and_the_replay(conc_mv):
    # One row per sample; the recorded columns are the tags' own, the fitted valve's
    # output is mv_model, and the replay's columns sit on the samples it covers
    # (exact: the frame only copies the arrays).
    a = conc_mv
    frame = a.to_pandas()
    assert len(frame) == a.tags.n
    for role in ("time", "pv", "op", "mv", "sp"):
        assert np.array_equal(frame[role].to_numpy(), getattr(a.tags, role)), role
    assert np.array_equal(frame["mv_model"].to_numpy(), a.fit.mv_model)
    start = int(round(a.replay.time[0] / a.replay.dt))
    covered = slice(start, start + a.replay.n)
    for name in ("pv", "op", "mv"):
        column = frame[f"{name}_replay"].to_numpy()
        assert np.array_equal(column[covered], getattr(a.replay, name)), name
        assert np.isnan(column[:start]).all()


def test_to_pandas_without_a_replay(conc):
    tags = Tags.from_arrays(conc["pv"], conc["op"], ts=1.0)
    a = analyze(tags, config=AnalysisConfig(gap=False, replay=False))
    assert list(a.to_pandas().columns) == ["time", "pv", "op", "mv_model"]


def test_plot_is_the_phase_figure(conc_mv):
    from matplotlib.figure import Figure

    fig = conc_mv.plot()
    # Trends and phase plots of pv-op and mv-op (sp is constant: no pv-sp row).
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 4
    assert fig.get_suptitle() == conc_mv.loop
    assert conc_mv.plot(title="other").get_suptitle() == "other"


def test_noise_free_constant_loop_is_not_stiction():
    # A loop at rest with a little noise (no cycle, linear valve): nothing to call.
    rng = np.random.default_rng(5)
    n = 2000
    op = 50.0 + np.cumsum(rng.normal(0, 0.02, n))
    pv = 0.5 * op + rng.normal(0, 0.05, n)
    a = analyze(Tags.from_arrays(pv, op, mv=op.copy(), ts=1.0), config=NO_GAP)
    assert a.verdict.status != "stiction"
    assert not a.oscillation.present


def test_record_short_of_three_cycles_is_analysed_with_a_warning(conc):
    # 400 samples of a regular 140 s cycle (2.9 cycles) without mv: the oscillation
    # test needs 3 cycles, so the analysis runs, says the record is short, and does
    # not take the missing cycle as evidence against stiction.
    short = {k: v[:400] for k, v in conc.items()}
    tags = Tags.from_arrays(short["pv"], short["op"], sp=short["sp"], ts=1.0)
    a = analyze(tags, config=NO_GAP)
    assert not a.oscillation.present
    assert any(w.startswith("short record") and "export at least" in w for w in a.warnings)
    assert a.verdict.evidence.short_record is True
    # The sticky valve (S = 5 %) is not called healthy.  The fit covers less than two
    # one-cycle blocks, too few for the bootstrap to measure consistency, and the
    # verdict says so; whether it calls stiction is up to the calibrated probability.
    assert a.verdict.status != "no_stiction"
    assert any("too few to measure consistency" in r for r in a.verdict.reasons)
    # With mv the stick and slip phases are seen directly: no length requirement.
    tags = Tags.from_arrays(short["pv"], short["op"], mv=short["mv"], ts=1.0)
    a = analyze(tags, config=AnalysisConfig(gap=False, replay=False))
    assert a.fit.S == pytest.approx(5.0, abs=0.3)  # as in the long record
    assert not any(w.startswith("short record") for w in a.warnings)


def test_record_under_two_cycles_of_a_regular_cycle_is_refused(conc):
    # Fewer than MIN_ANALYSIS_CYCLES periods of a regular cycle: a pattern seen once
    # is an event, not a cycle.  (detect_oscillation measures regularity only from
    # 2.5 cycles on, so the regular cycle is stated here.)
    from stictiondiag.analysis import (
        MIN_ANALYSIS_CYCLES,
        check_record_length,
    )
    from stictiondiag.signals.oscillation import Oscillation

    assert MIN_ANALYSIS_CYCLES == 2.0
    n = 250  # 1.8 periods of the 136 s cycle
    tags = Tags.from_arrays(conc["pv"][:n], conc["op"][:n], ts=1.0)
    regular = Oscillation(False, None, None, 10.0, None, "too few cycles")
    with pytest.raises(DataError, match="record too short.*export at least"):
        check_record_length(tags, regular, regular)
    tags = Tags.from_arrays(conc["pv"][:400], conc["op"][:400], ts=1.0)
    assert check_record_length(tags, regular, regular).startswith("short record")


def test_set_point_step_does_not_hide_the_cycle():
    # flow_mixed.csv: the set point drops half-way and the step dominates pv's
    # autocorrelation; the oscillation test, seeded by that autocorrelation's peaks,
    # finds the cycle in pv itself (period of the longer second half, 231 s in
    # sample_data/README.md; 5 % for the ACF estimate over two regimes), so the
    # control error is not needed and no note is written.
    a = sample_analysis("flow_mixed.csv")
    assert a.oscillation.present
    assert a.oscillation.period_s == pytest.approx(231.0, rel=0.05)
    assert not any("control error" in w for w in a.warnings)


def test_a_step_too_large_for_pv_leaves_the_cycle_to_the_control_error():
    # A triangular cycle (57 samples) under a set-point step of 8 peak-to-peaks:
    # even seeded, pv's own test finds no cycle (the running mean smears the step),
    # while sp - pv has the cycle without the step; its oscillation stands for pv's,
    # with a note.  Period within 1 %: the error is the cycle plus noise.
    k = np.arange(1000)
    sp = 8.0 * (k >= 500)
    pv = (
        sp
        + sawtooth(2 * np.pi * k / 57.0, 0.5)
        + 0.2 * np.random.default_rng(0).standard_normal(k.size)
    )
    tags = Tags.from_arrays(pv, 50.0 + 0.01 * np.cumsum(sp - pv), sp=sp, ts=1.0)
    warnings: list[str] = []
    assert not detect_oscillation(pv, 1.0).present
    osc_pv, _ = find_oscillations(tags, warnings)
    assert osc_pv.present and osc_pv.period_s == pytest.approx(57.0, rel=0.01)
    assert warnings == [
        "the set point moves: the oscillation was found in the control error sp - pv"
    ]


@pytest.mark.parametrize("name", ["level_undershoot.csv", "slave_flow_stickslip.csv"])
def test_replay_warnings_reach_the_user(name):
    # The replay's own notes (poor identification, no cycle in the replay) decide
    # how far the reconstruction can be trusted: they are part of the result.
    a = sample_analysis(name)
    assert a.replay is not None
    for note in a.replay.warnings:
        assert f"replay: {note}" in a.warnings
    assert a.to_dict()["warnings"] == list(a.warnings)


def test_evidence_states_s_and_j_in_ops_own_units_when_its_scale_is_unknown(conc_mv):
    # op in other units than % of span (Tags.op_scale "unknown", as read_tags sets for a
    # normalised export): the verdict's evidence line must not call S and J "% of
    # span".  The same loop as conc_mv, only the scale flag differs.
    tags = dataclasses.replace(conc_mv.tags, op_scale="unknown")
    v = stiction_verdict(
        conc_mv.fit,
        conc_mv.oscillation,
        oscillation_op=conc_mv.oscillation_op,
        cycle=conc_mv.verdict.cycle,
        data=tags,
    )
    line = next(r for r in v.reasons if r.startswith("S = "))
    assert "in op's own units (scale unknown)" in line and "%" not in line
    known = next(r for r in conc_mv.verdict.reasons if r.startswith("S = "))
    assert " % [" in known and "of span (valve position)" in known


def test_a_missing_gap_diagnosis_says_why(conc_mv, conc, monkeypatch):
    """Without a gap diagnosis the result says why, and the findings repeat it: not
    'it needs the replay' when the replay is there and the diagnosis refused the data
    (a 201-sample plant record once read so)."""
    import stictiondiag.analysis as chain
    from stictiondiag.apps.findings import findings_of
    from stictiondiag.core.errors import DataError as Refused

    assert conc_mv.gap is None and conc_mv.gap_skipped == "not asked for"
    assert findings_of(conc_mv).gap == "no gap diagnosis: not asked for"

    def refuse(*args, **kwargs):
        raise Refused("201 samples are too few for the gap diagnosis: need at least 400")

    monkeypatch.setattr(chain, "diagnose_gap", refuse)
    tags = Tags.from_arrays(conc["pv"], conc["op"], mv=conc["mv"], sp=conc["sp"], ts=1.0)
    a = analyze(tags, config=AnalysisConfig(compensation=False))
    assert a.replay is not None and a.gap is None
    assert a.gap_skipped == "201 samples are too few for the gap diagnosis: need at least 400"
    assert findings_of(a).gap.startswith("no gap diagnosis: 201 samples are too few")
    assert "gap diagnosis not possible: 201 samples" in a.warnings[-1]

    b = analyze(tags, config=AnalysisConfig(replay=False, compensation=False))
    assert b.gap_skipped == "it needs the closed-loop replay, which was not asked for"
    assert Analysis.from_json(a.to_json()).gap_skipped == a.gap_skipped
