"""Compressed historian archives ("recorded values") read back onto one grid.

The archives are written by the project itself (stictiondiag.io.compression) from the
bundled level_undershoot loop (true S = 5 %, J = 2.5 %), with a deadband (exception
reporting, held) and with a swinging door (linear), as a long export.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stictiondiag.io.compression import (
    archive_deadbands,
    archive_kind,
    exception_compress,
    reconstruct,
    swinging_door,
)
from stictiondiag.io.plant import plant_loops, read_plant_loop
from stictiondiag.io.tags import read_tags

SAMPLES = Path(__file__).resolve().parents[1] / "sample_data"


def _level() -> pd.DataFrame:
    return pd.read_csv(SAMPLES / "level_undershoot.csv", parse_dates=["Timestamp"])


def _long_archive(frame: pd.DataFrame, keep) -> pd.DataFrame:
    seconds = (frame["Timestamp"] - frame["Timestamp"][0]).dt.total_seconds().to_numpy()
    parts = []
    for tag in frame.columns[1:]:
        index = keep(seconds, frame[tag].to_numpy())
        parts.append(
            pd.DataFrame(
                {
                    "timestamp": frame["Timestamp"].iloc[index].dt.strftime("%Y-%m-%d %H:%M:%S"),
                    "tag": tag,
                    "value": frame[tag].to_numpy()[index],
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


def test_deadband_archive_held_is_within_the_deadband_and_swinging_door_linear():
    # Reconstruction by the historian's convention is within the compression's own
    # error bound of every scan: the deadband for a held exception archive; for a
    # swinging door read linearly (Bristol 1990) twice the deviation, since the door
    # keeps some line from the last archived point within the deviation and the next
    # archived value may itself lie a deviation off that line.
    rng = np.random.default_rng(3)
    t = np.arange(5000) * 2.0
    v = np.cumsum(rng.normal(0.0, 0.05, t.size)) + 3 * np.sin(t / 400.0)
    for keep, deviation, kind in (
        (lambda: exception_compress(v, 0.2), 0.2, "hold"),
        (lambda: swinging_door(t, v, 0.2), 0.4, "linear"),
    ):
        index = keep()
        assert 10 < index.size < t.size / 2  # it compresses
        assert archive_kind(v[index]) == kind
        arrays, grid, step, note = reconstruct({"pv": (t[index], v[index])}, "x")
        assert step == 2.0 and grid.size == t.size and note is not None
        # 1e-9: rounding of the line through two archived points.
        assert np.max(np.abs(arrays["pv"] - v)) <= deviation + 1e-9
        assert np.max(np.abs(arrays["pv"] - v)) > 0.4 * deviation  # not the raw data


def test_op_of_an_exception_archive_is_read_banded_and_follows_its_drift():
    # op under integral action drifts; its exception archive (deadband 0.1) keeps a
    # value each time it has moved 0.1.  Held, it is a sawtooth about the drift (RMS
    # error d / sqrt(3) = 0.058); banded it follows the ramp (the error is the 0.002
    # noise and the scan the archive fired on), and never leaves the band the archive
    # guarantees (2 d: the signal and the reading both within d of the archived value).
    # The valve's position, a staircase of 1 % steps, stays held and exact.
    rng = np.random.default_rng(5)
    t = np.arange(3000) * 1.0
    op = 40 + 0.01 * t + rng.normal(0, 0.002, t.size)
    mv = np.floor(op)
    i, j = exception_compress(op, 0.1), exception_compress(mv, 0.1)
    series = {"pv": (t, np.zeros(t.size)), "op": (t[i], op[i]), "mv": (t[j], mv[j])}
    arrays, _, _, note = reconstruct(series, "x")
    held, *_ = reconstruct(series, "x", "hold")

    def rms(e):
        return float(np.sqrt(np.mean(e**2)))

    assert np.max(np.abs(arrays["op"] - op)) <= 0.2
    assert rms(arrays["op"] - op) < 0.1 * rms(held["op"] - op)
    assert rms(held["op"] - op) == pytest.approx(0.1 / np.sqrt(3), rel=0.1)
    np.testing.assert_array_equal(arrays["mv"], mv)
    assert "op 285 values linear within its deadband 0.1" in note and "mv 32 values held" in note
    # Asked for, every tag is held, and the deadbands are carried either way.
    assert archive_deadbands(series, "x") == archive_deadbands(series, "x", "hold")


def test_constant_set_point_of_two_rows_is_held_not_two_samples(tmp_path):
    # The flat sp of a compressed export is two rows; the grid is the fastest tag's,
    # never "only 2 samples ... export a longer record".
    frame = _level()
    long = _long_archive(frame, lambda s, v: exception_compress(v, 0.1))
    assert (long["tag"] == "LIC101.SV").sum() == 2
    path = tmp_path / "recorded.csv"
    long.to_csv(path, index=False)
    tags = read_plant_loop(plant_loops(path)[0])
    assert tags.n == len(frame) and tags.ts == 5.0
    np.testing.assert_array_equal(tags.sp, np.full(tags.n, 50.0))
    assert "compressed archive" in tags.warnings[0] and "sp 2 values held" in tags.warnings[0]
    assert tags.start_time == pd.Timestamp("2004-03-01", tz="UTC").timestamp()


def test_wide_recorded_values_export_with_empty_cells_is_rebuilt(tmp_path):
    # A wide "recorded values" export: each tag's cell is filled only where it was
    # archived.  Held, the stuck valve's position is exact between its slips.
    frame = _level()
    seconds = np.arange(len(frame)) * 5.0
    wide = frame.copy()
    for tag in frame.columns[1:]:
        kept = np.zeros(len(frame), dtype=bool)
        kept[exception_compress(frame[tag].to_numpy(), 0.1)] = True
        wide.loc[~kept, tag] = np.nan
    path = tmp_path / "wide.csv"
    wide.to_csv(path, index=False)
    tags = read_tags(path)
    assert tags.n == len(frame)
    assert any("compressed archive" in w for w in tags.warnings)
    mv = frame["LIC101.MV"].to_numpy()
    assert np.max(np.abs(tags.mv - mv)) <= 0.1 + 1e-9  # the deadband
    assert seconds[-1] == tags.time[-1]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "keep"),
    [
        # PI: exception reporting that sends the previous value, read linearly.
        ("pi_exception_0.1", lambda s, v: exception_compress(v, 0.1, previous=True)),
        ("swinging_door_0.1", lambda s, v: swinging_door(s, v, 0.1)),
        ("deadband_0.05_held", lambda s, v: exception_compress(v, 0.05)),
    ],
)
def test_compressed_level_loop_gives_the_plain_s_and_j(tmp_path, name, keep):
    # True S = 5 %, J = 2.5 % (plain export: 5.00 [4.98, 5.01], 2.50 [2.49, 2.51]).  The
    # old reader took the coarsest median step and gave S 1.35 %, J 0.02 % on 109
    # samples.  A compressed archive loses detail up to its deadband or deviation
    # (0.05-0.1 % of span in op, mv) at every sample and at every slip, so S and J are
    # asked to within 0.3 % of span (6 % of S): the price of the compression, not of
    # the reading.
    from stictiondiag import AnalysisConfig, analyze

    path = tmp_path / f"{name}.csv"
    _long_archive(_level(), keep).to_csv(path, index=False)
    tags = read_plant_loop(plant_loops(path)[0])
    assert tags.n == 8640
    result = analyze(tags, config=AnalysisConfig(gap=False))
    assert result.verdict.status == "stiction"
    assert result.fit.S == pytest.approx(5.0, abs=0.3)
    assert result.fit.J == pytest.approx(2.5, abs=0.3)
