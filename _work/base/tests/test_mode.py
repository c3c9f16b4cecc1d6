"""The controller's mode: read from plant exports, the service factor, and the record
analysed when the loop spends part of it in manual (stictiondiag.io.mode)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from stictiondiag.core.errors import DataError
from stictiondiag.io.compression import exception_compress
from stictiondiag.io.mode import automatic_stretch, mode_codes
from stictiondiag.io.plant import plant_loops, read_manifest, read_plant_loop
from stictiondiag.io.tags import Tags, read_frame, read_tags
from stictiondiag.models.valve import choudhury_step, valve_state

S_TRUE, J_TRUE = 4.0, 2.0
TS = 2.0


def _loop_with_manual_stretch(n=9000, manual=(5600, 6800), seed=7):
    """A self-regulating loop (gain 1.5, time constant 40 s, dead time 4 s) under PI
    control (Kc 0.4, Ti 60 s) through a sticky valve (Choudhury model, S 4 %, J 2 %),
    with the operator taking it to manual over ``manual`` (samples): op held where it
    was, then stepped by +6 % halfway, and the controller back in automatic after,
    restarting bumplessly from the held op.  The controller sees pv without the
    measurement noise of the record (a noisy op would re-arm the flowchart valve's
    stuck band at every reversal, Section 5.1)."""
    rng = np.random.default_rng(seed)
    a = np.exp(-TS / 40.0)
    delay = 2
    pv = np.zeros(n)
    op = np.zeros(n)
    mv = np.zeros(n)
    sp = np.full(n, 50.0)
    auto = np.ones(n, dtype=bool)
    auto[manual[0] : manual[1]] = False
    st = valve_state(45.0, True)
    y, integral, m_prev = 47.0, 45.0, 45.0  # starts off the set point: the cycle starts
    for k in range(n):
        u = m_prev if k < delay else mv[k - delay]
        y = a * y + (1 - a) * (1.5 * (u - 45.0) + 48.0)
        pv[k] = y + rng.normal(0.0, 0.02)  # recorded with measurement noise
        e = sp[k] - y
        if auto[k]:
            integral += 0.4 * TS / 60.0 * e
            op[k] = 0.4 * e + integral
        else:
            op[k] = op[k - 1] + (6.0 if k == (manual[0] + manual[1]) // 2 else 0.0)
            integral = op[k] - 0.4 * e  # bumpless transfer back to automatic
        mv[k] = choudhury_step(float(op[k]), st, S_TRUE, J_TRUE)
    return pv, op, mv, sp, auto


def test_mode_words_of_the_vendors_and_the_missing_ones():
    words = ["AUTO", "aut", "Cascade", "BCAS", "RCAS", "MAN", "IMAN (CAS)", "O/S", "ROUT",
             "TRK", "", "Bad Input", "I/O Timeout", "Out of Service"]  # fmt: skip
    codes = mode_codes(pd.Series(words, dtype=object), "X.MODE", "f", [])
    expected = [1, 1, 1, 1, 1, 0, 0, 0, 0, 0, np.nan, np.nan, np.nan, 0]
    np.testing.assert_array_equal(codes, np.array(expected, dtype=float))


def test_unknown_words_and_plain_numbers_leave_the_mode_unused_with_one_line():
    notes: list[str] = []
    assert mode_codes(pd.Series(["AUTO", "SOMETHING"] * 3), "X.MODE", "f", notes) is None
    assert len(notes) == 1 and "'SOMETHING' (3 rows)" in notes[0] and "\n" not in notes[0]
    notes.clear()
    # A "Status" column of data quality beside a value is said to be that.
    assert mode_codes(pd.Series(["Good", "Bad", "Good"]), "Status", "f", notes) is None
    assert notes[0].startswith("column 'Status' in f holds data quality flags ('Good' (2 rows))")
    notes.clear()
    assert mode_codes(pd.Series([0, 1, 1]), "X.MODE", "f", notes) is None
    assert "numbers" in notes[0] and "--vendor deltav" in notes[0]
    # DeltaV's actual mode holds the Foundation Fieldbus bit: 8 AUTO, 16 MAN, 4 CAS.
    codes = mode_codes(pd.Series([8, 16, 4]), "FIC1/MODE.ACTUAL", "f", [])
    np.testing.assert_array_equal(codes, [1.0, 0.0, 1.0])


def test_service_factor_and_longest_automatic_stretch_by_hand():
    # 1000 samples: unknown for 50, auto 50-399, manual 400-449, auto 450-999.  By hand:
    # service factor over the 950 known samples = (350 + 550) / 950; longest automatic
    # stretch 450-999.  A missing value inside holds the last known mode.
    codes = np.ones(1000)
    codes[:50] = np.nan
    codes[400:450] = 0.0
    codes[700] = np.nan
    notes: list[str] = []
    start, stop, factor = automatic_stretch(codes, "X.MODE", "", notes)
    assert (start, stop) == (450, 1000)
    assert factor == pytest.approx(100.0 * 900 / 950, rel=1e-12)
    assert "samples 450 to 999 (550 of 1000)" in notes[0]
    assert "first 50 samples" in notes[0]
    codes[450:] = 0.0
    codes[300:] = 0.0  # longest automatic stretch 50-299: 250 samples, still enough
    assert automatic_stretch(codes, "X.MODE", "", [])[:2] == (50, 300)
    codes[120:] = 0.0  # 70 samples in automatic: too few
    with pytest.raises(DataError, match=r"at most 70 samples in a row; need 100"):
        automatic_stretch(codes, "X.MODE", "", [])


@pytest.mark.slow
def test_a_loop_with_a_manual_stretch_is_analysed_on_its_longest_automatic_stretch():
    # The manual stretch (samples 5600-6799) splits the record into automatic stretches
    # of 5600 and 2200 samples: the first is analysed, and said so.  The service factor
    # is by hand (9000 - 1200) / 9000.  S and J are those of the simulated valve to
    # 0.5 % of span (the mv-op estimate on 5600 samples; a tenth of S, the spread of the
    # segment estimate over the slips of a few dozen cycles).
    from stictiondiag import AnalysisConfig, analyze

    pv, op, mv, sp, auto = _loop_with_manual_stretch()
    tags = Tags.from_arrays(pv, op, mv=mv, sp=sp, ts=TS, loop_type="flow", mode=auto)
    assert tags.n == 5600
    np.testing.assert_array_equal(tags.pv, pv[:5600])
    assert tags.service_factor == pytest.approx(100.0 * 7800 / 9000, rel=1e-12)
    result = analyze(tags, config=AnalysisConfig(gap=False, compensation=False))
    assert any("analysed the longest automatic stretch, samples 0 to 5599" in w
               for w in result.warnings)  # fmt: skip
    kpis = result.to_dict()["kpis"]
    assert kpis["service_factor"]["value"] == pytest.approx(100.0 * 7800 / 9000, rel=1e-12)
    assert result.verdict.status == "stiction"
    assert result.fit.S == pytest.approx(S_TRUE, abs=0.5)
    assert result.fit.J == pytest.approx(J_TRUE, abs=0.5)


def _export(tmp_path, modes, name="loop.csv"):
    pv, op, mv, sp, auto = _loop_with_manual_stretch(n=3000, manual=(1000, 1600))
    stamps = pd.date_range("2024-03-01", periods=pv.size, freq="2s")
    frame = pd.DataFrame({"Timestamp": stamps, "FIC7.PV": pv, "FIC7.OP": op, "FIC7.SP": sp})
    frame["FIC7.MODE"] = np.where(auto, modes[0], modes[1])
    path = tmp_path / name
    frame.to_csv(path, index=False)
    return path, frame


def test_wide_file_mode_column_is_found_and_the_record_cut(tmp_path):
    path, frame = _export(tmp_path, ("CAS", "MAN"))
    tags = read_tags(path)
    assert tags.names["mode"] == "FIC7.MODE"
    assert tags.n == 1400 and tags.service_factor == pytest.approx(100.0 * 2400 / 3000)
    assert tags.start_time == pd.Timestamp("2024-03-01 00:53:20", tz="UTC").timestamp()
    assert tags.to_dict()["service_factor_pct"] == tags.service_factor
    # Unknown words: one warning, the mode unused, the whole record read.
    path, _ = _export(tmp_path, ("CAS", "HAND"), "other.csv")
    tags = read_tags(path)
    assert tags.n == 3000 and tags.service_factor is None
    assert any("'HAND' (600 rows)" in w for w in tags.warnings)


def test_compressed_long_export_holds_the_mode_between_its_changes(tmp_path):
    # A "recorded values" export: pv and op through a 0.1 deadband, the mode tag
    # (DeltaV's MODE.ACTUAL) archived only where it changes: three rows.
    _, frame = _export(tmp_path, ("AUTO", "MAN"))
    parts = []
    for tag in ("FIC7.PV", "FIC7.OP", "FIC7.SP"):
        index = exception_compress(frame[tag].to_numpy(), 0.1)
        parts.append(pd.DataFrame({"timestamp": frame["Timestamp"].iloc[index], "tag": tag,
                                   "value": frame[tag].to_numpy()[index]}))  # fmt: skip
    modes = frame["FIC7.MODE"].to_numpy()
    change = np.flatnonzero(np.concatenate(([True], modes[1:] != modes[:-1])))
    assert change.size == 3
    parts.append(pd.DataFrame({"timestamp": frame["Timestamp"].iloc[change],
                               "tag": "FIC7/MODE.ACTUAL", "value": modes[change]}))  # fmt: skip
    path = tmp_path / "long.csv"
    pd.concat(parts).to_csv(path, index=False)
    (loop,) = plant_loops(path)
    assert loop.columns["mode"] == "FIC7/MODE.ACTUAL"
    tags = read_plant_loop(loop)
    assert tags.n == 1400 and tags.service_factor == pytest.approx(100.0 * 2400 / 3000)
    # The manifest names the mode tag too; a wrong one is a one-line data error.
    manifest = tmp_path / "loops.csv"
    manifest.write_text("loop,mode\nFIC7,FIC7/MODE.ACTUAL\n")
    assert read_manifest(manifest)["FIC7"] == {"mode": "FIC7/MODE.ACTUAL"}


def test_a_record_in_manual_throughout_is_a_one_line_data_error():
    t = np.arange(500.0)
    frame = pd.DataFrame({"time": t, "pv": np.sin(t / 9), "op": np.cos(t / 9), "mode": "MAN"})
    with pytest.raises(DataError) as info:
        read_frame(frame)
    assert "automatic or cascade for 0 % of the record" in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("names", "vendor"),
    [
        (("FIC7.PV", "FIC7.OP", "FIC7.MODE"), None),  # Honeywell, ISA
        (("FIC7.PV", "FIC7.MV", "FIC7.MODE"), "yokogawa"),  # CENTUM: MV is op
        (("FIC7/PV.CV", "FIC7/OUT.CV", "FIC7/MODE.ACTUAL"), None),  # DeltaV
        ((r"\\SRV1\FIC7.PV", r"\\SRV1\FIC7.OP", r"\\SRV1\FIC7.MD"), None),  # PI tags
    ],
)
def test_vendor_mode_tags_join_their_loop_in_a_plant_export(tmp_path, names, vendor):
    # Two loops in one wide export, each with its mode tag in the vendor's naming; the
    # second loop (FIC8) is in cascade throughout, FIC7 in manual for 400 samples.
    t = np.arange(2000)
    frame = pd.DataFrame({"Timestamp": pd.date_range("2024-03-01", periods=t.size, freq="5s")})
    for loop in ("FIC7", "FIC8"):
        pv_name, op_name, mode_name = (n.replace("FIC7", loop) for n in names)
        frame[pv_name] = np.sin(t / 20.0)
        frame[op_name] = 50 + np.cos(t / 20.0)
        manual = (t >= 1600) if loop == "FIC7" else np.zeros(t.size, dtype=bool)
        frame[mode_name] = np.where(manual, "MAN", "CAS")
    path = tmp_path / "plant.csv"
    frame.to_csv(path, index=False)
    loops = {loop.loop.rsplit("\\", 1)[-1]: loop for loop in plant_loops(path)}
    assert set(loops) == {"FIC7", "FIC8"}
    fic7 = read_plant_loop(loops["FIC7"], vendor=vendor)
    fic8 = read_plant_loop(loops["FIC8"], vendor=vendor)
    assert fic7.names["mode"].endswith(names[2].split("FIC7")[1])
    assert (fic7.n, fic7.service_factor) == (1600, pytest.approx(80.0, rel=1e-12))
    assert (fic8.n, fic8.service_factor) == (2000, 100.0)


def test_long_export_with_unknown_mode_words_warns_and_reads_the_whole_record(tmp_path):
    t = pd.date_range("2024-03-01", periods=600, freq="5s")
    rows = [pd.DataFrame({"timestamp": t, "tag": "PIC3.PV", "value": np.sin(np.arange(600) / 9)}),
            pd.DataFrame({"timestamp": t, "tag": "PIC3.OP", "value": np.cos(np.arange(600) / 9)}),
            pd.DataFrame({"timestamp": t[[0, 300]], "tag": "PIC3.MODE", "value": ["AUTO", "HAND"]})]  # fmt: skip
    path = tmp_path / "long.csv"
    pd.concat(rows).to_csv(path, index=False)
    tags = read_plant_loop(plant_loops(path)[0])
    assert tags.n == 600 and tags.service_factor is None
    assert any("'HAND' (1 row)" in w and "mode not used" in w for w in tags.warnings)
