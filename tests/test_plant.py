"""Whole-plant inputs: loop types from tags and data, wide and long exports, the manifest,
the op units guard, and ``stiction scan`` on a plant folder made from the sample loops."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from stiction_cli.main import app
from stictiondiag.analysis import AnalysisConfig, analyze_file
from stictiondiag.core.errors import EXIT_DATA, EXIT_PARTIAL, EXIT_USAGE, DataError, UsageError
from stictiondiag.identification.looptype import (
    identify_structure,
    infer_integrating,
    pv_cycles,
    settle_loop_type,
)
from stictiondiag.io.looptype import isa_loop_type
from stictiondiag.io.plant import plant_loops, read_manifest, read_plant_loop
from stictiondiag.io.tags import Tags, read_tags
from stictiondiag.models.loops import simulate_loop
from stictiondiag.models.processes import FOPTD, PI, Integrating

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_data"
runner = CliRunner()

#: S and J of one loop read from the plant files and from its own sample file [% of
#: span]: the same numbers (written with 10 significant digits, the samples have at
#: most 7), so only float rounding may differ.
SAME_NUMBERS_TOL = 1e-6


def make_plant_folder(out: Path) -> dict:
    """scripts/make_plant_folder.py, loaded on use."""
    path = ROOT / "scripts" / "make_plant_folder.py"
    spec = importlib.util.spec_from_file_location("make_plant_folder", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make_plant_folder(out)


def _run(*args) -> object:
    result = runner.invoke(app, [str(a) for a in args])
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


def _error_line(result) -> str:
    lines = [line for line in result.stderr.splitlines() if line.startswith("stiction: error:")]
    assert len(lines) == 1, result.stderr
    return lines[0]


# --------------------------------------------------------------------------- tag prefix


@pytest.mark.parametrize(
    ("names", "expected"),
    [
        (["FIC101.PV", "FIC101.OP"], "flow"),
        (["FC-7.PV"], "flow"),
        (["LIC200.PV", "LIC200.OP", "LIC200.SP"], "level"),
        (["PIC_33.OUT"], "pressure"),
        (["TRC12.PV"], "temperature"),
        (["AIC3.PV"], "composition"),
        (["QIC9.OP"], "composition"),
        (["pv", "op"], None),
        (["ZT101.PV"], None),  # a position transmitter names no loop
        (["Tank level PV"], None),
        (["FIC1.PV", "LIC1.OP"], None),  # two types: none chosen
    ],
)
def test_isa_prefix_names_the_loop_type(names, expected):
    found = isa_loop_type(names)
    assert (found[0] if found else None) == expected


def test_tag_decides_and_option_overrides():
    tags = read_tags(SAMPLES / "level_undershoot.csv")  # tags LIC101.PV, ...
    assert (tags.loop_type, tags.integrating, tags.loop_type_source) == ("level", True, "tag")
    given = read_tags(SAMPLES / "level_undershoot.csv", loop_type="flow")
    assert (given.loop_type, given.integrating, given.loop_type_source) == ("flow", False, "user")


# --------------------------------------------------------------------------- data


def _simulated(process, controller, dt, S, J, with_mv):
    sim = simulate_loop(
        process,
        controller,
        duration=4000 * dt,
        dt=dt,
        S=S,
        J=J,
        noise_std=0.02,
        seed=3,
        sp=50.0,
        pv_bias=50.0,
    )
    mv = sim.mv if with_mv else None
    return Tags.from_arrays(sim.pv, sim.op, mv=mv, sp=sim.sp, ts=dt, loop_type=None)


@pytest.mark.parametrize("with_mv", [True, False])
def test_data_tell_a_sticky_level_loop_integrates(with_mv):
    # The level loop of sample_data/level_no_mv.csv (0.01/s, PI 3/100 s, S 3, J 1.5).
    tags = _simulated(Integrating(0.01, 2.0), PI(3.0, 100.0), 1.0, 3.0, 1.5, with_mv)
    assert tags.loop_type_source == "pending"
    integrating, why = infer_integrating(tags)
    assert integrating is True, why
    settled = settle_loop_type(tags, identify_structure(tags, cycling=pv_cycles(tags)))
    assert settled.integrating and settled.loop_type_source == "data"


def test_without_mv_a_fast_loop_is_not_taken_for_an_integrator():
    # The concentration loop of Table 3 (3 e^-10s / (10s + 1), PI 0.2 / 10 s) with
    # S 5, J 2: from op, the self-regulating fit's lag comes out far beyond the
    # record; only mv could tell, so the data must not decide "integrating".
    from stictiondiag.models.processes import LOOP_PARAMETERS

    loop = LOOP_PARAMETERS["concentration"]
    tags = _simulated(loop["process"], loop["controller"], 1.0, 5.0, 2.0, False)
    integrating, why = infer_integrating(tags)
    assert integrating is not True, why


def test_data_tell_a_sticky_flow_loop_self_regulates():
    tags = _simulated(FOPTD(1.2, 10.0, 20.0), PI(0.3, 30.0), 10.0, 3.0, 3.0, True)
    integrating, why = infer_integrating(tags)
    assert integrating is False, why


def test_a_loop_at_rest_is_left_self_regulating_with_a_warning():
    rng = np.random.default_rng(0)
    tags = Tags.from_arrays(
        50 + rng.normal(0, 0.1, 2000), 40 + rng.normal(0, 0.1, 2000), ts=1.0, loop_type=None
    )
    settled = settle_loop_type(tags, identify_structure(tags, cycling=pv_cycles(tags)))
    assert settled.loop_type_source == "default" and not settled.integrating
    assert "--loop-type" in settled.warnings[-1]


# --------------------------------------------------------------------------- op units


def _loop(tmp_path, op_scale, op_shift=0.0, name="loop.csv") -> Path:
    frame = pd.read_csv(SAMPLES / "healthy_flow.csv")
    frame["op"] = frame["op"] * op_scale + op_shift
    frame = frame.drop(columns=["mv"])
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path


@pytest.mark.parametrize(
    ("scale", "shift", "hint"),
    [
        (0.16, 4.0, "--op-units mA"),  # 4-20 mA read as percent
        (0.01, 0.0, "--op-range 0 1"),  # a fraction of span
        (4095 / 100, 0.0, "--op-range 0 4095"),  # 12-bit counts
    ],
)
def test_op_in_other_units_is_flagged(tmp_path, scale, shift, hint):
    tags = read_tags(_loop(tmp_path, scale, shift), loop_type="flow")
    assert any(hint in w for w in tags.warnings), tags.warnings


def test_op_in_percent_is_not_flagged(tmp_path):
    tags = read_tags(_loop(tmp_path, 1.0), loop_type="flow")
    assert not any("op_units" in w or "op_range" in w for w in tags.warnings)


def test_percent_declared_as_milliamps_is_a_one_line_data_error(tmp_path):
    with pytest.raises(DataError, match="not a 4-20 mA signal"):
        read_tags(_loop(tmp_path, 1.0), op_units="mA")
    result = _run("analyze", _loop(tmp_path, 1.0), "--op-units", "mA", "--no-gap")
    assert result.exit_code == EXIT_DATA
    assert "not a 4-20 mA signal" in _error_line(result)


# --------------------------------------------------------------------------- long, wide


def test_long_export_is_put_on_the_fastest_tags_grid(tmp_path):
    frame = pd.read_csv(SAMPLES / "healthy_flow.csv").iloc[:1200]
    start = pd.Timestamp("2024-01-01")
    parts = [
        pd.DataFrame(
            {
                "timestamp": start + pd.to_timedelta(frame["time"], unit="s"),
                "tag": "FIC7.PV",
                "value": frame["pv"],
            }
        ),
        # op every 2 s: the grid steps by 2 s, no detail is invented for op.
        pd.DataFrame(
            {
                "timestamp": start + pd.to_timedelta(frame["time"][::2], unit="s"),
                "tag": "FIC7.OP",
                "value": frame["op"][::2],
            }
        ),
    ]
    path = tmp_path / "long.csv"
    pd.concat(parts).sample(frac=1.0, random_state=1).to_csv(path, index=False)  # any row order
    (loop,) = plant_loops(path)
    assert loop.layout == "long" and loop.loop == "FIC7"
    tags = read_plant_loop(loop)
    # op's last sample is at 1198 s: the tags overlap on 1199 points every second.
    assert tags.ts == 1.0 and tags.n == 1199
    assert "common grid of 1199 points every 1 s" in tags.warnings[0]
    # pv is recorded at every grid point (exact); op between its samples is their mean.
    np.testing.assert_allclose(tags.pv, frame["pv"].to_numpy()[:1199], atol=1e-12)
    op = frame["op"].to_numpy()
    np.testing.assert_allclose(tags.op[1::2], 0.5 * (op[0:1198:2] + op[2:1199:2]), atol=1e-9)
    # The export's clock is kept: the record starts at 2024-01-01 00:00 UTC.
    assert tags.start_time == pd.Timestamp("2024-01-01", tz="UTC").timestamp()
    assert tags.loop_type == "flow" and tags.loop_type_source == "tag"


def _long_frame(frame: pd.DataFrame, start: pd.Timestamp) -> pd.DataFrame:
    stamps = start + pd.to_timedelta(frame["time"], unit="s")
    return pd.concat(
        pd.DataFrame({"timestamp": stamps, "tag": f"FIC7.{role.upper()}", "value": frame[role]})
        for role in ("pv", "op")
    ).reset_index(drop=True)


def test_long_export_gap_rule_and_grid_ceiling_are_the_wide_files(tmp_path):
    # The long export goes through the clock rules of every other file
    # (io.timebase.onto_grid): a tag's hole longer than the interpolation limit is
    # missing data (here op loses 200 s in the middle, far beyond MAX_GAP_SAMPLES = 10
    # steps, and the loop keeps the longest stretch without it; timestamps are epoch
    # seconds, where a relative "on a sample" tolerance used to hide every clock gap),
    # and a mistyped year is a one-line data error, not a grid of billions of points.
    from stictiondiag.io.timebase import MAX_GAP_SAMPLES

    frame = pd.read_csv(SAMPLES / "healthy_flow.csv").iloc[:1200]
    long = _long_frame(frame, pd.Timestamp("2024-01-01"))
    hole = (long["tag"] == "FIC7.OP") & long["timestamp"].between(
        pd.Timestamp("2024-01-01 00:08:00"), pd.Timestamp("2024-01-01 00:11:20")
    )
    assert hole.sum() > 2 * MAX_GAP_SAMPLES
    path = tmp_path / "holed.csv"
    long[~hole].to_csv(path, index=False)
    tags = read_plant_loop(plant_loops(path)[0])
    assert tags.n < 1200 - hole.sum()  # the hole is not bridged by a straight line

    # Both tags' last rows stamped a century ahead (a year mistyped in the export):
    # the tags then overlap over a century at 1 s.
    far = long.copy()
    last = far.groupby("tag").tail(1).index
    far.loc[last, "timestamp"] = pd.Timestamp("2124-01-01")
    path = tmp_path / "typo.csv"
    far.to_csv(path, index=False)
    with pytest.raises(DataError, match="needs a grid of"):
        read_plant_loop(plant_loops(path)[0])


def test_wide_export_lists_incomplete_and_ambiguous_loops(tmp_path):
    frame = pd.read_csv(SAMPLES / "healthy_flow.csv")
    wide = pd.DataFrame(
        {
            "time": frame["time"],
            "FIC1.PV": frame["pv"],
            "FIC1.OP": frame["op"],
            "FIC2.PV": frame["pv"],  # no op
            "LIC3.PV": frame["pv"],
            "LIC3.OUT": frame["op"],
            "LIC3.OP": frame["op"],  # two ops
        }
    )
    path = tmp_path / "wide.csv"
    wide.to_csv(path, index=False)
    loops = {p.loop: p for p in plant_loops(path)}
    assert set(loops) == {"FIC1", "FIC2", "LIC3"}
    assert loops["FIC1"].problem is None
    assert loops["FIC2"].problem.startswith("incomplete: no op")
    assert loops["LIC3"].problem.startswith("ambiguous")
    with pytest.raises(DataError, match="incomplete"):
        read_plant_loop(loops["FIC2"])
    tags = read_plant_loop(loops["FIC1"])
    np.testing.assert_array_equal(tags.op, frame["op"].to_numpy())


# --------------------------------------------------------------------------- manifest


def test_manifest_reads_per_loop_settings(tmp_path):
    path = tmp_path / "loops.csv"
    path.write_text(
        "loop,loop_type,ts,op_units,op_range,pv\n"
        "FIC1,flow,2,percent,0 4095,\n"
        "LIC3,level,,mA,,LIC3.PV\n"
    )
    m = read_manifest(path)
    assert m["FIC1"] == {
        "loop_type": "flow",
        "ts": 2.0,
        "op_units": "percent",
        "op_range": (0.0, 4095.0),
    }
    assert m["LIC3"] == {"loop_type": "level", "op_units": "mA", "pv": "LIC3.PV"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("name,ts\nx,1\n", "needs a 'file' or 'loop' column"),
        ("loop,loop_type\nx,boiler\n", "line 2: loop_type 'boiler'"),
        ("loop,ts\nx,-1\n", "line 2: ts '-1'"),
        ("loop,op_range\nx,5 1\n", "line 2: op_range"),
        ("loop,colour\nx,red\n", "unknown column 'colour'"),
    ],
)
def test_bad_manifest_is_a_one_line_usage_error(tmp_path, text, message):
    manifest = tmp_path / "loops.csv"
    manifest.write_text(text)
    with pytest.raises(UsageError, match=message):
        read_manifest(manifest)
    result = _run("scan", SAMPLES, "--loops", manifest, "--out", tmp_path / "out", "--no-gap")
    assert result.exit_code == EXIT_USAGE
    assert message.split("'")[0].strip() in _error_line(result)


def test_missing_manifest_is_a_one_line_usage_error(tmp_path):
    result = _run(
        "report",
        SAMPLES / "healthy_flow.csv",
        "--loops",
        tmp_path / "none.csv",
        "--out",
        tmp_path / "out",
    )
    assert result.exit_code == EXIT_USAGE
    assert "file not found" in _error_line(result)


# --------------------------------------------------------------------------- the plant folder


@pytest.fixture(scope="module")
def plant(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plant")
    expected = make_plant_folder(folder)
    out = folder.parent / f"{folder.name}_scan"
    result = _run(
        "scan", folder, "--loops", folder / "loops.csv", "--out", out, "--no-gap", "--workers", "1"
    )
    return folder, expected, out, result


def test_scan_of_the_plant_folder_lists_the_broken_loop_and_exits_4(plant):
    _, _, out, result = plant
    assert result.exit_code == EXIT_PARTIAL
    assert "not analysed: FIC900" in result.stderr and "incomplete: no op" in result.stderr
    table = pd.read_csv(out / "scan.csv")
    assert set(table.loc[table["verdict"] == "error", "loop"]) == {"FIC900"}
    assert len(table) == 13  # six loops in each file, and the broken one


def test_scan_infers_every_loop_type_of_the_plant(plant):
    _, expected, out, _ = plant
    table = pd.read_csv(out / "scan.csv").set_index("loop")
    for layout in ("plant_wide", "plant_long"):
        for loop, want in expected.items():
            row = table.loc[f"{layout}:{loop}"]
            assert row["loop_type"] == want["loop_type"], (layout, loop)
            assert bool(row["integrating"]) is want["integrating"], (layout, loop)
            assert row["loop_type_source"] == ("data" if loop == "Loop6" else "tag")


def test_scan_gives_the_verdicts_and_sj_of_each_loop_analysed_by_hand(plant):
    _, expected, out, _ = plant
    table = pd.read_csv(out / "scan.csv").set_index("loop")
    for loop, want in expected.items():
        by_hand = analyze_file(
            SAMPLES / want["file"], config=AnalysisConfig(gap=False), **want["options"]
        ).to_dict()["stiction"]
        for layout in ("plant_wide", "plant_long"):
            row = table.loc[f"{layout}:{loop}"]
            assert row["verdict"] == by_hand["status"], (layout, loop)
            for key in ("S", "J"):
                assert abs(row[key] - by_hand[key]) <= SAME_NUMBERS_TOL, (layout, loop, key)
    summary = json.loads((out / "loops" / "plant_long_LIC-200.json").read_text())
    assert any("common grid" in w for w in summary["analysis"]["warnings"])


@pytest.mark.parametrize(
    ("name", "integrating"),
    [
        ("level_undershoot.csv", True),  # with mv
        ("level_no_mv.csv", True),
        ("slave_flow_stickslip.csv", False),
        ("temperature_quantised.csv", False),
        ("flow_mixed.csv", False),
    ],
)
def test_data_alone_tell_the_structure_of_the_cycling_sample_loops(name, integrating):
    # Tag names dropped (Tags.from_arrays): only the data decide.
    t = read_tags(SAMPLES / name, loop_type="other")
    tags = Tags.from_arrays(t.pv, t.op, mv=t.mv, sp=t.sp, ts=t.ts, loop_type=None)
    decided, why = infer_integrating(tags)
    assert decided is integrating, why


def test_report_without_options_replays_the_level_loops_as_integrating(tmp_path):
    # README: `stiction report sample_data/*.csv`; the two level loops, one named by
    # its ISA tags (LIC101), one by nothing but its data.
    files = [SAMPLES / "level_undershoot.csv", SAMPLES / "level_no_mv.csv"]
    result = _run("report", *files, "--out", tmp_path / "rep", "--no-gap", "--workers", "1")
    assert result.exit_code == 0, result.stderr
    for name, source in (("level_undershoot", "tag"), ("level_no_mv", "data")):
        d = json.loads((tmp_path / "rep" / "loops" / f"{name}.json").read_text())
        assert d["tags"]["integrating"] is True and d["tags"]["loop_type_source"] == source
        assert d["replay"]["process"]["type"] == "integrating"
