"""Vendor tag conventions, European CSVs, .xlsx, op scale and controller action."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from stictiondiag.core.errors import DataError
from stictiondiag.io.plant import plant_loops, read_manifest, read_plant_loop
from stictiondiag.io.tags import read_tags

SAMPLES = Path(__file__).resolve().parents[1] / "sample_data"


def _flow(n: int = 1500) -> pd.DataFrame:
    frame = pd.read_csv(SAMPLES / "healthy_flow.csv").iloc[:n].reset_index(drop=True)
    frame["timestamp"] = pd.Timestamp("2024-05-01") + pd.to_timedelta(frame["time"], unit="s")
    return frame


def _wide(frame: pd.DataFrame, names: dict[str, str], loops=("FIC101", "FIC102")) -> pd.DataFrame:
    out = {"Timestamp": frame["timestamp"]}
    for k, loop in enumerate(loops):
        for role, suffix in names.items():
            out[f"{loop}{suffix}"] = frame[role] + k  # two loops, told apart by prefix
    return pd.DataFrame(out)


@pytest.mark.parametrize(
    ("vendor", "names"),
    [
        ("honeywell", {"pv": ".PV", "op": ".OP", "sp": ".SP"}),
        ("deltav", {"pv": "/PV.CV", "op": "/OUT.CV", "sp": "/SP.CV"}),
        ("yokogawa", {"pv": ".PV", "op": ".MV", "sp": ".SV"}),
        ("pi", {"pv": "_PV", "op": "_OP", "sp": "_SP"}),
    ],
)
def test_wide_plant_export_in_each_vendors_naming_is_read(tmp_path, vendor, names):
    frame = _flow()
    path = tmp_path / f"{vendor}.csv"
    _wide(frame, names).to_csv(path, index=False)
    loops = plant_loops(path)
    assert [loop.loop for loop in loops] == ["FIC101", "FIC102"]
    assert all(loop.problem is None for loop in loops)
    tags = read_plant_loop(loops[1])
    np.testing.assert_allclose(tags.op, frame["op"] + 1, atol=1e-9)
    np.testing.assert_allclose(tags.pv, frame["pv"] + 1, atol=1e-9)
    assert tags.loop_type == "flow"
    said = [w for w in tags.warnings if "read as the controller output" in w]
    # Only the ambiguous Yokogawa MV is said to be read as op.
    assert bool(said) == (vendor == "yokogawa")
    if vendor == "yokogawa":
        # vendor generic reads MV as the valve position: no op, a one-line error.
        with pytest.raises(DataError, match="no op tag"):
            read_plant_loop(loops[0], vendor="generic")
        # A manifest that names op rescues it whatever the vendor.
        named = read_plant_loop(loops[0], vendor="generic", op="FIC101.MV")
        assert named.names["op"] == "FIC101.MV"


def test_manifest_names_vendor_action_and_compression(tmp_path):
    path = tmp_path / "loops.csv"
    path.write_text("loop,vendor,action,compression\nFIC101,Yokogawa,direct,hold\n")
    assert read_manifest(path) == {
        "FIC101": {"vendor": "yokogawa", "action": "direct", "compression": "hold"}
    }
    path.write_text("loop,action\nFIC101,sideways\n")
    with pytest.raises(Exception, match="action 'sideways' is not one of direct, reverse"):
        read_manifest(path)


def test_european_csv_with_decimal_comma_and_day_first_dates(tmp_path):
    frame = _flow(300)
    text = frame[["timestamp", "pv", "op", "sp"]].copy()
    text["timestamp"] = text["timestamp"].dt.strftime("%d.%m.%Y %H:%M:%S")
    path = tmp_path / "eu.csv"
    text.to_csv(path, sep=";", decimal=",", index=False)
    tags = read_tags(path)
    np.testing.assert_allclose(tags.pv, frame["pv"], atol=1e-9)
    assert tags.ts == 1.0
    # 01.05.2024 is the first of May (day first), not the fifth of January.
    assert tags.start_time == pd.Timestamp("2024-05-01", tz="UTC").timestamp()


def test_xlsx_workbook_is_read(tmp_path):
    frame = _flow(300)
    path = tmp_path / "loop.xlsx"
    frame[["timestamp", "pv", "op", "sp"]].to_excel(path, index=False)
    tags = read_tags(path)
    np.testing.assert_allclose(tags.op, frame["op"], atol=1e-9)
    assert tags.n == 300 and tags.ts == pytest.approx(1.0)


def test_xlsx_rows_are_counted_against_the_ceiling(tmp_path, monkeypatch):
    # The workbook is streamed and its rows counted: one row past the ceiling is one
    # line and exit 3 (DataError), as for CSV and Parquet; at the ceiling it reads.
    frame = _flow(300)
    path = tmp_path / "loop.xlsx"
    frame[["timestamp", "pv", "op", "sp"]].to_excel(path, index=False)
    monkeypatch.setenv("STICTION_MAX_ROWS", "299")
    with pytest.raises(DataError, match="more than 299 rows"):
        read_tags(path)
    monkeypatch.setenv("STICTION_MAX_ROWS", "300")
    assert read_tags(path).n == 300


@pytest.mark.slow
def test_normalised_op_is_not_sized_in_percent_nor_sent_to_inspection():
    # The bundled level loop's op and mv normalised to -2.5..2.5 (a scaled export):
    # the stiction pattern is found, but S and J are in op's own units and the advice
    # is to size them, never "schedule a valve inspection".
    from stictiondiag import AnalysisConfig, analyze
    from stictiondiag.apps.findings import findings_from_dict
    from stictiondiag.io.tags import Tags

    raw = read_tags(SAMPLES / "level_undershoot.csv")
    tags = Tags.from_arrays(
        raw.pv,
        (raw.op - 50) / 20,
        mv=(raw.mv - 50) / 20,
        sp=raw.sp,
        ts=raw.ts,
        loop_type="level",
    )
    assert tags.op_scale == "unknown"
    result = analyze(tags, config=AnalysisConfig(gap=False, replay=False, compensation=False))
    findings = findings_from_dict(result.to_dict())
    assert result.verdict.status == "stiction"
    # S scales with op: 5 % of span / 20 = 0.25 op units (within 5 %, the plain fit's
    # interval being far tighter).
    assert result.fit.S == pytest.approx(0.25, rel=0.05)
    assert "op's own units" in findings.S_text
    assert "inspection" not in findings.action and "--op-range" in findings.action


@pytest.mark.slow
def test_declared_action_fixes_the_controller_sign_in_the_replay():
    # The bundled level loop is reverse acting (Kc = 2 on e = sp - pv).  Declared
    # direct, the replay takes the controller with the other sign and says so.
    from stictiondiag.analysis import AnalysisConfig, analyze

    tags = read_tags(SAMPLES / "level_undershoot.csv")
    plain = analyze(tags, config=AnalysisConfig(gap=False, compensation=False))
    assert plain.replay.controller["gain"] > 0
    direct = read_tags(SAMPLES / "level_undershoot.csv", action="direct")
    assert direct.action == "direct"
    result = analyze(direct, config=AnalysisConfig(gap=False, compensation=False))
    assert result.replay.controller["gain"] < 0
    assert any("declared direct action" in w for w in result.replay.warnings)
