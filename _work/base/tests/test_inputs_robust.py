"""Inputs that are too big, options that make no sense, and API calls of the wrong type.

The row ceiling is measured in a subprocess (its peak resident memory), the rest in
process on small generated data.  The column-reading cost is a benchmark
(benchmarks/bench_columns.py prints it), not a timed test.
"""

from __future__ import annotations

import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import stictiondiag.apps.report as report_module
from stictiondiag.analysis import AnalysisConfig, analyze
from stictiondiag.apps.report import build_report
from stictiondiag.apps.scan import discover, scan
from stictiondiag.core.errors import DataError, UsageError
from stictiondiag.io.plant import plant_loops, read_plant_loop, unmatched_manifest_rows
from stictiondiag.io.tags import Tags, read_frame, read_tags

ROOT = Path(__file__).resolve().parents[1]
HEALTHY = ROOT / "sample_data" / "healthy_flow.csv"
STICTION = Path(sys.executable).with_name("stiction")


# -- a row ceiling, counted while reading, in bounded memory -----------------------------

_PEAK = r"""
import sys
from stictiondiag.core.errors import DataError
from stictiondiag.io.tags import read_tags

def rss(field):
    for line in open("/proc/self/status"):
        if line.startswith(field):
            return int(line.split()[1]) // 1024

read_tags(sys.argv[2])  # the reading modules imported and warmed up on a small file
before = rss("VmRSS:")
with open("/proc/self/clear_refs", "w") as handle:
    handle.write("5")  # the peak resident memory (VmHWM) counts from here
try:
    read_tags(sys.argv[1])
    print("read")
except DataError as exc:
    print("refused:", exc)
print(before, rss("VmHWM:"))
"""


@pytest.fixture(scope="module")
def bomb(tmp_path_factory) -> Path:
    """A 0.2 MB gzip CSV that expands to 12 million rows (108 MB of text)."""
    path = tmp_path_factory.mktemp("bomb") / "loop.csv.gz"
    with gzip.open(path, "wb", compresslevel=6) as handle:
        handle.write(b"time,pv,op\n")
        block = b"1,1.5,40\n" * 100_000
        for _ in range(120):
            handle.write(block)
    return path


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="Linux /proc only")
def test_a_compressed_file_past_the_row_ceiling_stops_in_bounded_memory(bomb):
    # Issue 31: a few hundred kB of gzip drove analyze past 10 GB before any check.
    # With a ceiling of 10^6 rows the read stops after two chunks.  Linux only: the
    # peak is read from /proc/self/status after resetting it (clear_refs).
    env = {**os.environ, "STICTION_MAX_ROWS": "1000000"}
    child = subprocess.run(
        [sys.executable, "-c", _PEAK, str(bomb), str(HEALTHY)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    refused, sizes = child.stdout.strip().splitlines()
    assert refused.startswith("refused:") and "more than 1,000,000 rows" in refused
    before, peak = (int(v) for v in sizes.split())
    # What the read adds to the process's resident memory: two 10^6-row chunks of
    # three columns and the parser's buffers, measured 71 MB.  Reading the whole file
    # (the code before the ceiling) added 837 MB.  250 MB leaves room for allocator
    # slack and stays far below that.
    assert peak - before < 250, f"{before} MB before the read, peak {peak} MB"


@pytest.mark.skipif(not STICTION.exists(), reason="needs the console script")
def test_the_ceiling_is_a_data_error_of_one_line(bomb):
    env = {**os.environ, "STICTION_MAX_ROWS": "1000000"}
    result = subprocess.run(
        [str(STICTION), "analyze", str(bomb), "--no-gap"],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert result.returncode == 3
    assert result.stderr.strip().splitlines()[-1].startswith("stiction: error: ")
    assert "more than 1,000,000 rows" in result.stderr and "Traceback" not in result.stderr


def test_a_parquet_file_past_the_ceiling_is_refused_from_its_metadata(tmp_path, monkeypatch):
    path = tmp_path / "loop.parquet"
    pd.DataFrame({"pv": np.zeros(5000), "op": np.zeros(5000)}).to_parquet(path)
    monkeypatch.setenv("STICTION_MAX_ROWS", "4999")
    with pytest.raises(DataError, match="more than 4,999 rows"):
        read_tags(path)
    monkeypatch.setenv("STICTION_MAX_ROWS", "5000")
    with pytest.raises(DataError, match="constant"):  # read: past the ceiling no more
        read_tags(path)


# -- option values that make no sense ----------------------------------------------------


def _loop(op_low: float = 40.0, op_high: float = 59.0, n: int = 600):
    k = np.arange(n)
    op = np.where(np.sin(2 * np.pi * k / 60) > 0, op_high, op_low)
    pv = np.cumsum(op - op.mean()) * 0.01 + np.random.default_rng(1).normal(0, 0.01, n)
    return pv, op


@pytest.mark.parametrize("op_range", [(0.0, 1e308), (0.0, 1e6), (-1e308, 1e308)])
def test_an_op_range_that_makes_op_constant_is_refused(op_range):
    # Issue 31: 0 1e308 ended in a ZeroDivisionError (exit 3); 0 1e6 on an op
    # between 40 and 59 analysed silently to "S = 0.0003 %".
    pv, op = _loop()
    with pytest.raises(UsageError, match="op_range|op range"):
        Tags.from_arrays(pv, op, op_range=op_range)


def test_an_op_range_in_which_op_barely_moves_is_warned_about():
    pv, op = _loop()
    tags = Tags.from_arrays(pv, op, op_range=(0.0, 2000.0))  # op travels 0.95 % of it
    assert any("moves by only 0.95 % of the op range" in w for w in tags.warnings)
    plain = Tags.from_arrays(pv, op, op_range=(0.0, 100.0))
    assert not any("moves by only" in w for w in plain.warnings)


# -- manifest rows that match no loop ------------------------------------------------------


def test_manifest_rows_matching_no_loop_are_listed_with_a_hint():
    manifest = {"fic101": {"ts": 2.0}, "LIC200": {"ts": 1.0}, "ghost.csv": {}}
    loops = [("FIC101", "plant/FIC101.csv"), ("LIC200", "plant/LIC200.csv")]
    (note,) = unmatched_manifest_rows(manifest, loops)
    assert "2 row(s) match no loop" in note
    assert "'fic101' (did you mean 'FIC101'?)" in note and "'ghost.csv'" in note
    assert unmatched_manifest_rows({"LIC200": {}}, loops) == []


def test_report_warns_of_an_unmatched_manifest_row(tmp_path, monkeypatch):
    def fake(source, read_options, gap):  # the folder and notes are under test
        name = source[1]
        row = {"loop": name, "source": source[0], "verdict": "no_stiction"}
        return {
            "file": source[0],
            "loop": name,
            "name": name,
            "page": "<p>",
            "json": "{}",
            "row": row,
        }

    monkeypatch.setattr(report_module, "analyse_for_report", fake)
    (tmp_path / "in").mkdir()
    files = [tmp_path / "in" / "FIC101.csv"]
    files[0].write_text("pv,op\n1,2\n")
    said: list[str] = []
    result = build_report(
        files, tmp_path / "r", workers=1, manifest={"fic101": {"ts": 2.0}}, on_note=said.append
    )
    assert result.notes and "'fic101'" in result.notes[0]
    assert said == [f"warning: {result.notes[0]}"]


# -- repeated time stamps in a long export -------------------------------------------------


def test_repeated_time_stamps_of_a_long_export_are_warned_about(tmp_path):
    # The daylight-saving fall-back hour in local time: the clock runs an hour twice.
    n = 400
    stamps = pd.date_range("2026-10-25 01:00", periods=n, freq="10s")
    stamps = stamps.append(stamps[300:360])  # one minute written twice
    k = np.arange(len(stamps))
    op = 50 + 5 * np.sign(np.sin(2 * np.pi * k / 40))
    rows = [
        (t.isoformat(), tag, v)
        for t, kk, o in zip(stamps, k, op, strict=True)
        for tag, v in (("FIC7.PV", np.sin(kk / 6.0)), ("FIC7.OP", o))
    ]
    path = tmp_path / "long.csv"
    pd.DataFrame(rows, columns=["timestamp", "tag", "value"]).to_csv(path, index=False)
    (loop,) = plant_loops(path)
    tags = read_plant_loop(loop)
    notes = [w for w in tags.warnings if "repeated time stamps" in w]
    assert notes and "FIC7.PV 60" in notes[0] and "FIC7.OP 60" in notes[0]


# -- symlinked folders --------------------------------------------------------------------


def test_symlinked_folders_are_followed_once(tmp_path):
    plant = tmp_path / "plant"
    elsewhere = tmp_path / "unit2"
    plant.mkdir()
    elsewhere.mkdir()
    (plant / "L1.csv").write_bytes(HEALTHY.read_bytes())
    (elsewhere / "L2.csv").write_bytes(HEALTHY.read_bytes())
    (plant / "unit2").symlink_to(elsewhere, target_is_directory=True)
    (plant / "again").symlink_to(elsewhere, target_is_directory=True)  # same folder twice
    (elsewhere / "up").symlink_to(plant, target_is_directory=True)  # a cycle
    loops = sorted(s.loop for s in discover(plant))
    # Issue 31: the linked folder was skipped without a word; now its loop is found,
    # once, and the cycle ends.
    assert loops == ["L1", "L2"]


# -- the Python API: wrong types are TypeErrors that say what to pass ---------------------


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: analyze(None), "takes the loop's Tags, not NoneType"),
        (lambda: analyze(pd.DataFrame({"pv": [1.0]})), "read_frame"),
        (lambda: analyze("loop.csv"), "analyze_file"),
        (lambda: AnalysisConfig(gap="no"), "gap must be True or False"),
        (lambda: read_tags(HEALTHY, integrating="no"), "integrating must be True, False or None"),
        (lambda: read_frame(None), "read_frame takes a pandas DataFrame"),
        (lambda: read_tags(None), "path must be a file path"),
        (lambda: build_report("loop.csv", "out"), "a list of paths"),
        (lambda: build_report([], "out", gap="yes"), "gap must be True or False"),
        (lambda: scan(".", out="out", force="no"), "force must be True or False"),
    ],
)
def test_wrong_types_raise_clear_type_errors(call, match):
    with pytest.raises(TypeError, match=match):
        call()


def test_boolean_options_take_numpy_booleans_too():
    assert AnalysisConfig(gap=np.bool_(False)).gap is False
    pv, op = _loop()
    assert Tags.from_arrays(pv, op, integrating=np.bool_(True)).integrating is True
    assert json.dumps(AnalysisConfig(gap=np.bool_(True)).gap) == "true"
