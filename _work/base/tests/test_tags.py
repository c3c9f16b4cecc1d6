"""Reading tags: formats, column matching, units, sampling, gaps, validation."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from stictiondiag.core.errors import (
    DataError,
    UsageError,
)
from stictiondiag.io.tags import (
    MAX_GAP_SAMPLES,
    MIN_SAMPLES,
    Tags,
    read_frame,
    read_tags,
    scale,
)

ISDB = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "isdb"
ISDB_LOOPS = sorted((ISDB / "loops").glob("*.csv")) if ISDB.is_dir() else []

# Float round trips through CSV text: pandas writes 17 significant digits, so values
# come back bit-identical; arithmetic on them (unit conversion, interpolation) is
# exact to a few ulps of numbers of order 100.
ARITHMETIC_TOL = 1e-9


def loop_frame(n: int = 400, *, ts: float = 1.0, seed_value: int = 0) -> pd.DataFrame:
    """A plausible cycling loop: op [% of span], pv, sp, mv, time [s]."""
    rng = np.random.default_rng(seed_value)
    time = ts * np.arange(n)
    op = 50.0 + 8.0 * np.sin(2 * np.pi * time / (40 * ts)) + rng.normal(0, 0.3, n)
    mv = op - 1.5
    pv = 20.0 + 0.4 * (mv - 50.0) + rng.normal(0, 0.05, n)
    return pd.DataFrame({"time": time, "pv": pv, "op": op, "mv": mv, "sp": np.full(n, 20.0)})


def write_csv(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False)
    return path


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_error(error_type, call, *fragments: str) -> str:
    """Run ``call``, check it raises ``error_type`` with one line naming the problem."""
    with pytest.raises(error_type) as info:
        call()
    message = str(info.value)
    assert message and "\n" not in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message


# --------------------------------------------------------------------------- errors


def test_missing_file(tmp_path):
    one_line_error(DataError, lambda: read_tags(tmp_path / "nope.csv"), "not found", "nope.csv")


def test_directory_instead_of_file(tmp_path):
    one_line_error(DataError, lambda: read_tags(tmp_path), "directory")


@pytest.mark.parametrize("content", [b"", b"   \n\n", b"time,pv,op\n"])
def test_empty_files(tmp_path, content):
    path = tmp_path / "empty.csv"
    path.write_bytes(content)
    message = one_line_error(DataError, lambda: read_tags(path))
    assert "empty" in message or "no data rows" in message


def test_binary_file_with_csv_extension(tmp_path):
    path = tmp_path / "garbage.csv"
    path.write_bytes(bytes(range(256)) * 20)
    one_line_error(DataError, lambda: read_tags(path), "not a text CSV")


def test_corrupt_gzip(tmp_path):
    path = tmp_path / "loop.csv.gz"
    path.write_bytes(b"pv,op\n1,2\n" * 20)  # plain text behind a .gz name
    one_line_error(DataError, lambda: read_tags(path), "cannot read gzip file")


def test_corrupt_parquet(tmp_path):
    path = tmp_path / "broken.parquet"
    loop_frame().to_parquet(path)
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    one_line_error(DataError, lambda: read_tags(path), "not a readable Parquet")


@pytest.mark.parametrize(
    ("name", "fragment"),
    [
        ("data.dat", "unknown file type"),
        ("data.ods", "spreadsheet"),
        ("data.xlsx", "not a readable .xlsx workbook"),
    ],
)
def test_unknown_extension(tmp_path, name, fragment):
    path = tmp_path / name
    path.write_text("pv,op\n1,2\n")
    one_line_error(DataError, lambda: read_tags(path), fragment)


@pytest.mark.parametrize("role", ["pv", "op"])
def test_missing_required_tag(tmp_path, role):
    path = write_csv(loop_frame().drop(columns=[role]), tmp_path / "loop.csv")
    one_line_error(DataError, lambda: read_tags(path), f"no {role} column", f"{role}=<column>")


def test_yokogawa_mv_without_op_is_read_as_op_and_said(tmp_path):
    # Yokogawa CENTUM names the controller output MV: with no op beside it, MV is op
    # and the output says so; vendor=generic reads MV as the valve position (no op).
    frame = loop_frame()
    yoko = frame.drop(columns=["mv"]).rename(
        columns={"pv": "FIC1.PV", "sp": "FIC1.SV", "op": "FIC1.MV"}
    )
    path = write_csv(yoko, tmp_path / "yoko.csv")
    tags = read_tags(path)
    np.testing.assert_array_equal(tags.op, frame["op"].to_numpy())
    assert tags.mv is None and tags.names["op"] == "FIC1.MV"
    assert any("'FIC1.MV' read as the controller output" in w for w in tags.warnings)
    assert read_tags(path, vendor="yokogawa").names["op"] == "FIC1.MV"
    one_line_error(DataError, lambda: read_tags(path, vendor="generic"), "op='FIC1.MV'")


def test_non_numeric_column(tmp_path):
    frame = loop_frame()
    frame["pv"] = ["high" if i % 3 else "low" for i in range(len(frame))]
    path = write_csv(frame, tmp_path / "text.csv")
    one_line_error(DataError, lambda: read_tags(path), "not numeric", "'pv'")


@pytest.mark.parametrize("role", ["pv", "op"])
def test_all_nan_signal(tmp_path, role):
    frame = loop_frame()
    frame[role] = np.nan
    path = write_csv(frame, tmp_path / "nan.csv")
    one_line_error(DataError, lambda: read_tags(path), "no numeric values", role)


@pytest.mark.parametrize("role", ["pv", "op"])
def test_constant_signal(tmp_path, role):
    frame = loop_frame()
    frame[role] = 42.0
    path = write_csv(frame, tmp_path / "flat.csv")
    one_line_error(DataError, lambda: read_tags(path), "constant", role)


def test_too_few_samples(tmp_path):
    path = write_csv(loop_frame(MIN_SAMPLES - 1), tmp_path / "short.csv")
    one_line_error(DataError, lambda: read_tags(path), f"only {MIN_SAMPLES - 1} samples")
    assert read_tags(write_csv(loop_frame(MIN_SAMPLES), tmp_path / "ok.csv")).n == MIN_SAMPLES


def test_ambiguous_columns_ask_for_a_name(tmp_path):
    frame = loop_frame().rename(columns={"pv": "FIC101.PV", "op": "FIC101.OP"})
    frame["FIC102.PV"] = frame["FIC101.PV"] * 2
    path = write_csv(frame, tmp_path / "two.csv")
    one_line_error(DataError, lambda: read_tags(path), "look like pv", "pv=<column>")
    assert read_tags(path, pv="FIC102.PV").names["pv"] == "FIC102.PV"


def test_override_naming_a_missing_column(tmp_path):
    path = write_csv(loop_frame(), tmp_path / "loop.csv")
    one_line_error(DataError, lambda: read_tags(path, op="FIC9.OUT"), "'FIC9.OUT' not found")


@pytest.mark.parametrize(
    ("options", "fragment"),
    [
        ({"op_units": "volts"}, "op_units"),
        ({"loop_type": "analyser"}, "loop_type"),
        ({"op_range": (100, 0)}, "op_range"),
        ({"op_range": (1, "x")}, "op_range"),
        ({"ts": 0}, "ts"),
        ({"ts": float("nan")}, "ts"),
        ({"pv": "pv", "op": "pv"}, "both"),
    ],
)
def test_bad_options_are_usage_errors(tmp_path, options, fragment):
    path = write_csv(loop_frame(), tmp_path / "loop.csv")
    one_line_error(UsageError, lambda: read_tags(path, **options), fragment)


def test_file_is_never_modified(tmp_path):
    frame = loop_frame()
    frame.loc[5:7, "pv"] = np.nan  # exercises gap filling on the in-memory copy
    csv = write_csv(frame, tmp_path / "loop.csv")
    parquet = tmp_path / "loop.parquet"
    frame.to_parquet(parquet)
    for path in (csv, parquet):
        before, mtime = sha256(path), path.stat().st_mtime_ns
        read_tags(path, op_units="percent", op_range=(0, 100))
        assert sha256(path) == before
        assert path.stat().st_mtime_ns == mtime


# --------------------------------------------------------------------------- columns


@pytest.mark.parametrize(
    ("names", "expected"),
    [
        ({"pv": "PV", "op": "Op", "mv": "MV", "sp": "Sp"}, None),
        ({"pv": "FIC101.PV", "op": "FIC101.OP", "mv": "FIC101.MV", "sp": "FIC101.SP"}, None),
        (
            {"pv": "LIC63001_PV", "op": "LIC63001_OP", "mv": "LV63001_POS", "sp": "LIC63001_SP"},
            None,
        ),
        ({"pv": "TIC-7.pv", "op": "TIC-7.OUT", "mv": "ZT-7.PV", "sp": "TIC-7.SV"}, None),
        ({"pv": "PV [degC]", "op": "OP (%)", "mv": "ZT101", "sp": "Setpoint"}, None),
        (
            {"pv": "Process Value", "op": "Controller Output", "mv": "valve position", "sp": "SP"},
            None,
        ),
        ({"pv": "FC12:MEAS", "op": "FC12:CO", "mv": "FV12:ZT", "sp": "FC12:SPT"}, None),
    ],
)
def test_column_matching_rules(tmp_path, names, expected):
    frame = loop_frame().rename(columns=names)
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    assert {role: tags.names[role] for role in names} == names
    reference = loop_frame()
    for role in names:
        # CSV text round trip of float64 is exact (17 significant digits).
        np.testing.assert_array_equal(getattr(tags, role), reference[role].to_numpy())


def test_exact_role_name_wins_over_suffix_candidates(tmp_path):
    frame = loop_frame()
    frame["FIC101.PV"] = frame["pv"] + 1.0
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    assert tags.names["pv"] == "pv"


def test_overrides_are_case_insensitive_and_excluded_from_matching(tmp_path):
    frame = loop_frame().rename(columns={"op": "FIC1.MV", "mv": "valve_travel"})
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"), op="fic1.mv", mv="VALVE_TRAVEL")
    assert tags.names["op"] == "FIC1.MV"
    assert tags.names["mv"] == "valve_travel"


def test_mv_and_sp_are_optional(tmp_path):
    tags = read_tags(write_csv(loop_frame()[["time", "pv", "op"]], tmp_path / "loop.csv"))
    assert tags.mv is None and tags.sp is None
    assert list(tags.to_pandas().columns) == ["time", "pv", "op"]


@pytest.mark.parametrize("separator", [";", "\t", "|"])
def test_other_delimiters(tmp_path, separator):
    path = tmp_path / "loop.csv"
    loop_frame().to_csv(path, index=False, sep=separator)
    tags = read_tags(path)
    np.testing.assert_array_equal(tags.op, loop_frame()["op"].to_numpy())


def test_gzip_csv(tmp_path):
    path = tmp_path / "loop.csv.gz"
    loop_frame().to_csv(path, index=False, compression="gzip")
    plain = read_tags(write_csv(loop_frame(), tmp_path / "plain.csv"))
    assert read_tags(path) == dataclasses.replace(plain, source=str(path))


# --------------------------------------------------------------------------- units


def test_milliamp_op_and_mv_converted_to_percent_of_span(tmp_path):
    frame = loop_frame()
    reference = frame.copy()
    frame["op"] = 4.0 + 16.0 * frame["op"] / 100.0
    frame["mv"] = 4.0 + 16.0 * frame["mv"] / 100.0
    tags = read_tags(write_csv(frame, tmp_path / "ma.csv"), op_units="mA")
    np.testing.assert_allclose(tags.op, reference["op"], atol=ARITHMETIC_TOL)
    np.testing.assert_allclose(tags.mv, reference["mv"], atol=ARITHMETIC_TOL)
    np.testing.assert_array_equal(tags.pv, reference["pv"])  # pv is never converted
    np.testing.assert_array_equal(tags.sp, reference["sp"])


def test_op_range_maps_raw_units_to_percent(tmp_path):
    frame = loop_frame()
    reference = frame.copy()
    for role in ("op", "mv"):
        frame[role] = 1000.0 + 30.0 * frame[role]  # 1000 -> 0 %, 4000 -> 100 %
    tags = read_tags(write_csv(frame, tmp_path / "raw.csv"), op_range=(1000, 4000))
    np.testing.assert_allclose(tags.op, reference["op"], atol=ARITHMETIC_TOL)
    np.testing.assert_allclose(tags.mv, reference["mv"], atol=ARITHMETIC_TOL)


def test_milliamp_with_own_range(tmp_path):
    frame = loop_frame()
    reference = frame["op"].to_numpy()
    frame["op"] = 20.0 * frame["op"] / 100.0  # a 0-20 mA output
    tags = read_tags(write_csv(frame, tmp_path / "ma.csv"), op_units="mA", op_range=(0, 20))
    np.testing.assert_allclose(tags.op, reference, atol=ARITHMETIC_TOL)


def test_op_far_outside_span_is_flagged(tmp_path):
    frame = loop_frame()
    frame["op"] = 4.0 + 16.0 * frame["op"] / 100.0  # mA read as percent by mistake
    tags = read_tags(write_csv(frame, tmp_path / "ma.csv"))
    # 4-20 lies inside 0-100, but a whole record inside 4-20 suggests mA (issue 18).
    assert any("--op-units mA" in note for note in tags.warnings)
    frame["op"] = frame["op"] * 100.0
    tags = read_tags(write_csv(frame, tmp_path / "big.csv"))
    assert any("op_units" in note for note in tags.warnings)


@pytest.mark.parametrize(
    ("loop_type", "integrating", "expected"),
    [("level", None, True), ("flow", None, False), ("level", False, False), ("other", True, True)],
)
def test_level_implies_integrating(tmp_path, loop_type, integrating, expected):
    path = write_csv(loop_frame(), tmp_path / "loop.csv")
    tags = read_tags(path, loop_type=loop_type, integrating=integrating)
    assert tags.integrating is expected and tags.loop_type == loop_type


# --------------------------------------------------------------------------- sampling


def test_uniform_time_column_sets_ts(tmp_path):
    tags = read_tags(write_csv(loop_frame(ts=0.5), tmp_path / "loop.csv"))
    assert tags.ts == 0.5
    np.testing.assert_array_equal(tags.time, 0.5 * np.arange(tags.n))
    assert tags.warnings == ()


def test_no_time_column_defaults_to_one_second_with_warning(tmp_path):
    tags = read_tags(write_csv(loop_frame().drop(columns=["time"]), tmp_path / "loop.csv"))
    assert tags.ts == 1.0
    assert any("assumed ts = 1 s" in note for note in tags.warnings)


def test_explicit_ts_overrides_time_column_and_notes_mismatch(tmp_path):
    path = write_csv(loop_frame(ts=30.0), tmp_path / "loop.csv")
    tags = read_tags(path, ts=1.0)
    assert tags.ts == 1.0 and tags.n == 400
    assert any("steps by 30 s" in note for note in tags.warnings)
    assert read_tags(path, ts=30.0).warnings == ()


def test_irregular_timestamps_resampled_on_median_step(tmp_path):
    rng = np.random.default_rng(3)
    steps = rng.choice([0.9, 1.0, 1.0, 1.0, 1.2], size=499)
    time = np.concatenate(([0.0], np.cumsum(steps)))
    frame = pd.DataFrame({"t": time, "pv": 2.0 * time + 1.0, "op": 50.0 - 0.1 * time})
    tags = read_tags(write_csv(frame, tmp_path / "jitter.csv"))
    assert tags.ts == 1.0  # median step
    assert tags.n == int(np.floor(time[-1])) + 1
    # Linear interpolation of a linear signal is exact up to rounding.
    np.testing.assert_allclose(tags.pv, 2.0 * tags.time + 1.0, atol=ARITHMETIC_TOL)
    np.testing.assert_allclose(tags.op, 50.0 - 0.1 * tags.time, atol=ARITHMETIC_TOL)
    assert any("resampled" in note for note in tags.warnings)


def test_hole_in_the_clock_is_a_long_gap(tmp_path):
    time = np.concatenate((np.arange(300.0), 400.0 + np.arange(150.0)))
    frame = pd.DataFrame({"time": time, "pv": np.sin(time / 7), "op": np.cos(time / 9)})
    tags = read_tags(write_csv(frame, tmp_path / "hole.csv"))
    assert tags.n == 300  # the longer side of the 100 s hole
    np.testing.assert_allclose(tags.pv, np.sin(np.arange(300.0) / 7), atol=ARITHMETIC_TOL)
    assert any("longest complete stretch" in note for note in tags.warnings)


def test_hole_in_a_timestamped_clock_is_a_long_gap(tmp_path):
    # The same hole with ISO time stamps (epoch seconds near 1.7e9 inside): a relative
    # tolerance on "grid point on a sample" spanned hours there, so the hole used to
    # be bridged by a straight line over 100 s.
    time = np.concatenate((np.arange(300.0), 400.0 + np.arange(150.0)))
    stamps = pd.Timestamp("2024-03-01 06:00:00") + pd.to_timedelta(time, unit="s")
    frame = pd.DataFrame({"time": stamps, "pv": np.sin(time / 7), "op": np.cos(time / 9)})
    tags = read_tags(write_csv(frame, tmp_path / "hole.csv"))
    assert tags.n == 300
    np.testing.assert_allclose(tags.pv, np.sin(np.arange(300.0) / 7), atol=ARITHMETIC_TOL)


def test_rows_without_time_stamp_are_dropped(tmp_path):
    frame = loop_frame()
    frame["time"] = frame["time"].astype(object)
    frame.loc[200, "time"] = ""
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    # The missing stamp leaves a one-step hole in the clock, interpolated on the grid.
    assert tags.n == 400 and tags.ts == 1.0
    np.testing.assert_allclose(
        tags.op[199:202],
        np.interp([199, 200, 201], [199, 201], frame["op"].to_numpy()[[199, 201]]),
        atol=ARITHMETIC_TOL,
    )
    assert any("without a readable time stamp" in note for note in tags.warnings)


def test_iso_timestamp_strings(tmp_path):
    frame = loop_frame()
    stamps = pd.Timestamp("2024-03-01T08:00:00Z") + pd.to_timedelta(frame["time"] * 5, unit="s")
    frame["time"] = stamps.dt.strftime("%Y-%m-%dT%H:%M:%S%z")
    tags = read_tags(write_csv(frame, tmp_path / "iso.csv"))
    assert tags.ts == 5.0 and tags.n == len(frame)
    assert tags.warnings == ()


def test_parquet_datetime_index_is_the_time_axis(tmp_path):
    frame = loop_frame().drop(columns=["time"])
    frame.index = pd.date_range("2024-01-01", periods=len(frame), freq="2s", tz="Europe/Berlin")
    path = tmp_path / "indexed.parquet"
    frame.to_parquet(path)
    tags = read_tags(path)
    assert tags.ts == 2.0
    np.testing.assert_array_equal(tags.pv, frame["pv"].to_numpy())


def test_parquet_round_trip(tmp_path):
    original = Tags.from_arrays(**{k: v for k, v in loop_frame().items() if k != "time"}, ts=0.2)
    path = tmp_path / "loop.parquet"
    original.to_pandas().to_parquet(path)
    again = read_tags(path)
    assert again.ts == pytest.approx(0.2, rel=1e-12)  # median of float time steps
    for role in ("pv", "op", "mv", "sp"):
        np.testing.assert_array_equal(getattr(again, role), getattr(original, role))


# --------------------------------------------------------------------------- gaps


def ramp_frame(n: int = 300) -> pd.DataFrame:
    index = np.arange(n, dtype=float)
    return pd.DataFrame({"pv": 0.5 * index, "op": 30.0 + 0.1 * index})


@pytest.mark.parametrize("length", [1, 5, MAX_GAP_SAMPLES])
def test_short_gaps_are_interpolated(length):
    frame = ramp_frame()
    frame.loc[100 : 100 + length - 1, "pv"] = np.nan
    tags = read_frame(frame, ts=1.0)
    assert tags.n == 300
    # Linear interpolation across a gap in a straight line restores it exactly.
    np.testing.assert_allclose(tags.pv, 0.5 * np.arange(300.0), atol=ARITHMETIC_TOL)
    assert any("interpolated short gaps" in note for note in tags.warnings)


def test_long_gap_keeps_longest_stretch():
    frame = ramp_frame()
    frame.loc[180 : 180 + MAX_GAP_SAMPLES, "op"] = np.nan  # one sample too long
    tags = read_frame(frame, ts=1.0)
    assert tags.n == 180
    np.testing.assert_array_equal(tags.op, 30.0 + 0.1 * np.arange(180.0))
    assert any("samples 0 to 179 (180 of 300)" in note for note in tags.warnings)


def test_long_gap_leaving_too_little_is_a_data_error():
    frame = ramp_frame(250)
    frame.loc[90:160, "pv"] = np.nan
    one_line_error(DataError, lambda: read_frame(frame, ts=1.0), "contiguous samples")


def test_edge_gaps_are_trimmed_not_extrapolated():
    frame = ramp_frame()
    frame.loc[:2, "op"] = np.nan
    frame.loc[297:, "pv"] = np.nan
    tags = read_frame(frame, ts=1.0)
    assert tags.n == 294
    assert tags.pv[0] == 1.5 and tags.op[-1] == pytest.approx(30.0 + 0.1 * 296)


def test_bad_quality_strings_become_gaps(tmp_path):
    frame = ramp_frame().astype(object)
    frame.loc[50, "pv"] = "Bad"
    frame.loc[51, "pv"] = "I/O Timeout"
    tags = read_tags(write_csv(frame, tmp_path / "quality.csv"), ts=1.0)
    np.testing.assert_allclose(tags.pv, 0.5 * np.arange(300.0), atol=ARITHMETIC_TOL)
    assert any("non-numeric entries" in note for note in tags.warnings)


def test_empty_optional_column_is_dropped():
    frame = ramp_frame()
    frame["sp"] = np.nan
    tags = read_frame(frame, ts=1.0)
    assert tags.sp is None and any("sp column" in note for note in tags.warnings)


# --------------------------------------------------------------------------- Tags


def test_tags_are_frozen_and_arrays_read_only():
    pv = np.linspace(0.0, 1.0, 200) ** 2
    op = np.linspace(10.0, 20.0, 200)
    tags = Tags.from_arrays(pv, op, ts=0.1)
    with pytest.raises(dataclasses.FrozenInstanceError):
        tags.ts = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        tags.pv[0] = 5.0
    pv[0] = 99.0  # the caller's array stays theirs
    assert tags.pv[0] == 0.0
    assert pv.flags.writeable


def test_from_arrays_validates_like_read_tags():
    one_line_error(DataError, lambda: Tags.from_arrays(np.zeros(200), np.arange(200.0)), "constant")
    one_line_error(DataError, lambda: Tags.from_arrays(np.arange(50.0), np.arange(50.0)), "only 50")
    one_line_error(
        DataError, lambda: Tags.from_arrays(np.arange(200.0), np.arange(150.0)), "differ in length"
    )
    one_line_error(UsageError, lambda: Tags.from_arrays(np.arange(200.0), np.arange(200.0), ts=-1))


def test_scaled_is_mean_centred_unit_variance_and_keeps_errors_meaningful():
    frame = loop_frame()
    tags = read_frame(frame, ts=1.0)
    scaled = tags.scaled()
    for role in ("pv", "op"):
        assert abs(scaled[role].mean()) < 1e-12  # rounding of a mean of ~400 O(1) values
        assert scaled[role].std() == pytest.approx(1.0, rel=1e-12)
    # sp shares pv's scale and mv shares op's: differences keep their meaning.
    pv_std = tags.pv.std()
    np.testing.assert_allclose(
        scaled["sp"] - scaled["pv"], (tags.sp - tags.pv) / pv_std, atol=1e-12
    )
    np.testing.assert_allclose(scaled["op"] - scaled["mv"], 1.5 / tags.op.std(), rtol=1e-9)
    np.testing.assert_allclose(scale(tags.pv), scaled["pv"], atol=1e-15)


def test_scale_of_constant_signal_is_zero_not_nan():
    np.testing.assert_array_equal(scale(np.full(10, 3.0)), np.zeros(10))


def test_to_pandas_and_to_dict():
    tags = read_frame(loop_frame(), ts=1.0, loop_type="flow")
    frame = tags.to_pandas()
    assert list(frame.columns) == ["time", "sp", "pv", "op", "mv"]
    assert len(frame) == tags.n == 400
    summary = json.loads(json.dumps(tags.to_dict()))
    assert summary["n_samples"] == 400 and summary["loop_type"] == "flow"
    assert summary["names"]["pv"] == "pv"


def test_reading_twice_gives_identical_results(tmp_path):
    frame = loop_frame()
    frame.loc[30:33, "op"] = np.nan
    path = write_csv(frame, tmp_path / "loop.csv")
    first, second = read_tags(path), read_tags(path)
    assert first == second
    assert first is not second
    assert first != dataclasses.replace(second, warnings=())


# --------------------------------------------------------------------------- ISDB


@pytest.mark.isdb
@pytest.mark.skipif(not ISDB_LOOPS, reason="ISDB data not present next to the repository")
def test_every_isdb_loop_reads():
    manifest = pd.read_csv(ISDB / "manifest.csv").set_index("loop")
    for path in ISDB_LOOPS:
        before = sha256(path)
        tags = read_tags(path)
        assert sha256(path) == before
        raw = pd.read_csv(path)
        steps = np.diff(raw["time_s"].to_numpy())
        assert tags.ts == pytest.approx(np.median(steps), rel=1e-12), path.name
        assert tags.n >= MIN_SAMPLES
        assert tags.names == {"pv": "pv", "op": "op", "sp": "sp", "time": "time_s"}
        for values in tags.signals().values():
            assert np.isfinite(values).all()
        resampled = any("resampled" in note for note in tags.warnings)
        if not resampled:
            assert tags.n == manifest.loc[path.stem, "n_samples"], path.name
            np.testing.assert_array_equal(tags.op, raw["op"].to_numpy())
        # With the published sample time the file is taken sample by sample.
        published = read_tags(path, ts=float(manifest.loc[path.stem, "ts_s"]))
        assert published.n == manifest.loc[path.stem, "n_samples"]
        np.testing.assert_array_equal(published.pv, raw["pv"].to_numpy())


# --------------------------------------------------------------------------- properties

ROLE_STYLES = {
    "pv": ["pv", "FIC101.PV", "LIC63001_PV", "PV [m3/h]"],
    "op": ["op", "FIC101.OP", "LIC63001_OUT", "OP (%)"],
    "mv": ["mv", "FV101.POS", "ZT63001", "valve position"],
    "sp": ["sp", "FIC101.SV", "LIC63001_SP", "setpoint"],
}


@st.composite
def case_permuted_names(draw):
    names = {}
    for role, styles in ROLE_STYLES.items():
        base = draw(st.sampled_from(styles))
        flips = draw(st.lists(st.booleans(), min_size=len(base), max_size=len(base)))
        names[role] = "".join(
            c.upper() if f else c.lower() for c, f in zip(base, flips, strict=True)
        )
    return names


@seed(20050101)
@settings(max_examples=60, deadline=None, database=None)
@given(names=case_permuted_names())
def test_property_column_names_in_any_case_and_style(names):
    frame = loop_frame(n=150).drop(columns=["time"])
    tags = read_frame(frame.rename(columns=names), ts=1.0)
    assert {role: tags.names[role] for role in names} == names
    for role in names:
        np.testing.assert_array_equal(getattr(tags, role), frame[role].to_numpy())


@st.composite
def valid_frames(draw):
    n = draw(st.integers(MIN_SAMPLES, 400))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    pv_offset = draw(st.floats(-1e4, 1e4))
    pv_scale = draw(st.floats(1e-3, 1e3))
    op_mean = draw(st.floats(5.0, 95.0))
    op_scale = draw(st.floats(0.1, 20.0))
    frame = pd.DataFrame(
        {
            "pv": pv_offset + pv_scale * rng.standard_normal(n),
            "op": op_mean + op_scale * rng.standard_normal(n),
            "mv": op_mean + op_scale * rng.standard_normal(n),
            "sp": pv_offset + pv_scale * np.repeat(rng.standard_normal(4), -(-n // 4))[:n],
        }
    )
    n_gaps = draw(st.integers(0, 3))
    # One gap per signal at most: two short gaps of one signal that touch would make
    # a long one, which is cut (not what these frames are for).
    roles = draw(st.permutations(["pv", "op", "mv", "sp"]))
    for role in roles[:n_gaps]:
        start = draw(st.integers(1, n - MAX_GAP_SAMPLES - 2))
        frame.loc[start : start + draw(st.integers(0, MAX_GAP_SAMPLES - 1)), role] = np.nan
    return frame


@seed(20050102)
@settings(
    max_examples=60, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)
@given(frame=valid_frames())
def test_property_valid_frames_load_and_scale(frame):
    tags = read_frame(frame, ts=1.0)
    assert tags.n == len(frame)  # short interior gaps only: nothing is cut
    scaled = tags.scaled()
    for role in ("pv", "op"):
        # Mean and std of <= 400 samples after centring: rounding ~1e-15 relative.
        assert abs(scaled[role].mean()) < 1e-9
        assert scaled[role].std() == pytest.approx(1.0, rel=1e-9)
        assert np.isfinite(scaled[role]).all()


@seed(20050103)
@settings(max_examples=60, deadline=None, database=None)
@given(
    frame=valid_frames(),
    low=st.floats(-1e3, 1e3),
    span=st.floats(1e-2, 1e4),
)
def test_property_op_range_rescales_op_and_mv_only(frame, low, span):
    reference = read_frame(frame, ts=1.0)
    raw = frame.copy()
    for role in ("op", "mv"):
        raw[role] = low + raw[role] / 100.0 * span
    rescaled = read_frame(raw, ts=1.0, op_range=(low, low + span))
    # op and mv return to % of span up to the rounding of the affine map and back.
    tol = 1e-9 * (1.0 + abs(low) / span) * 100.0
    np.testing.assert_allclose(rescaled.op, reference.op, atol=tol)
    np.testing.assert_allclose(rescaled.mv, reference.mv, atol=tol)
    # Everything else is untouched, bit for bit.
    np.testing.assert_array_equal(rescaled.pv, reference.pv)
    np.testing.assert_array_equal(rescaled.sp, reference.sp)
    np.testing.assert_array_equal(rescaled.time, reference.time)
    assert rescaled.ts == reference.ts
    np.testing.assert_allclose(rescaled.scaled()["op"], reference.scaled()["op"], atol=1e-6)


# --------------------------------------------------------------------------- robustness
# (issue 20: memory bounded by the data, time units, ambiguous columns, overflow)


def test_one_far_future_stamp_splits_the_record_instead_of_sizing_the_grid(tmp_path):
    # One stamp 1e12 s away used to make a grid of 1e12 samples (tens of GB).
    frame = loop_frame(n=600)
    frame.loc[300, "time"] = 1e12
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    assert tags.ts == 1.0
    # The stamp is dropped with its row: 599 rows -> the longest stretch holds at most
    # 599 samples and at least the 300 before or after the hole (interpolated over).
    assert 300 <= tags.n <= 600
    assert any("split there" in note for note in tags.warnings), tags.warnings


def test_mistyped_iso_year_is_split_off(tmp_path):
    frame = loop_frame(n=600)
    stamps = (pd.Timestamp("2024-03-01") + pd.to_timedelta(frame.time, unit="s")).astype(str)
    stamps.iloc[450] = "2204-03-01 00:07:30"
    tags = read_tags(write_csv(frame.assign(time=stamps), tmp_path / "loop.csv"))
    assert tags.ts == 1.0 and 400 <= tags.n <= 600


def test_grid_beyond_the_ceiling_is_a_one_line_error(tmp_path, monkeypatch):
    from stictiondiag.io import timebase

    monkeypatch.setattr(timebase, "MAX_GRID_SAMPLES", 500)
    frame = loop_frame(n=600)
    frame["time"] = frame["time"] + np.r_[0.0, np.full(599, 0.3)]  # irregular: one step 1.3
    one_line_error(
        DataError, lambda: read_tags(write_csv(frame, tmp_path / "l.csv")), "grid", "cut the record"
    )


@pytest.mark.parametrize(
    ("start", "per_second", "label"),
    [
        (1.7e12, 1e3, "epoch milliseconds"),
        (1.7e15, 1e6, "epoch microseconds"),
        (1.7e18, 1e9, "epoch nanoseconds"),
        (45000.0, 1 / 86400, "Excel serial dates"),
    ],
)
def test_time_units_are_detected_from_the_size_of_the_stamps(tmp_path, start, per_second, label):
    frame = loop_frame(n=400, ts=2.0)
    frame["time"] = start + frame["time"] * per_second
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    # 2 s steps in the unit, back in seconds; CSV text keeps 17 digits, so the step
    # of a 1.7e18 ns stamp is exact to about 1e-6 s relative.
    assert tags.ts == pytest.approx(2.0, rel=1e-4)
    assert any(label in note for note in tags.warnings), tags.warnings


def test_time_unit_named_in_the_header_wins(tmp_path):
    frame = loop_frame(n=400).rename(columns={"time": "time [ms]"})
    frame["time [ms]"] = frame["time [ms]"] * 1000.0
    assert read_tags(write_csv(frame, tmp_path / "loop.csv")).ts == 1.0


def test_ambiguous_serial_dates_are_warned_about(tmp_path):
    frame = loop_frame(n=400)
    frame["time"] = 45000.0 + 0.05 * frame["time"]  # 0.05 days (72 min) or 0.05 s?
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    assert tags.ts == pytest.approx(0.05)
    assert any("could be Excel serial days or seconds" in note for note in tags.warnings)


def test_two_columns_with_one_name_is_an_error_naming_both(tmp_path):
    path = tmp_path / "dup.csv"
    text = loop_frame().to_csv(index=False).replace("time,pv,op,mv,sp", "time,pv,op,pv,sp", 1)
    path.write_text(text)
    one_line_error(DataError, lambda: read_tags(path), "columns 2 and 4", "'pv'")


def test_exact_name_beside_another_candidate_is_noted(tmp_path):
    frame = loop_frame()
    frame["FIC1.PV"] = frame["pv"] * 2
    tags = read_tags(write_csv(frame, tmp_path / "loop.csv"))
    assert tags.names["pv"] == "pv"
    assert any("'FIC1.PV' also read as pv" in note for note in tags.warnings), tags.warnings


@pytest.mark.parametrize("factor", [1e300, -1e300])
def test_values_near_the_float_limit_are_a_data_error(tmp_path, factor):
    frame = loop_frame()
    frame["pv"] = frame["pv"] * factor
    one_line_error(
        DataError, lambda: read_tags(write_csv(frame, tmp_path / "l.csv")), "pv", "1e+75"
    )


def test_wide_export_reads_only_the_loop_columns(tmp_path):
    frame = loop_frame(n=200)
    extra = pd.DataFrame(np.zeros((200, 1000)), columns=[f"c{i}" for i in range(1000)])
    path = write_csv(pd.concat([frame, extra], axis=1), tmp_path / "wide.csv")
    from stictiondiag.io.readers import read_table

    seen = {}

    def select(header):
        seen["n"] = header.shape[1]
        return ["time", "pv", "op"]

    table = read_table(path, select)
    assert seen["n"] == 1005 and list(table.columns) == ["time", "pv", "op"]
    assert read_tags(path).n == 200
