"""``stiction simulate`` through Typer's CliRunner: normal paths and every error path."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from stiction_cli.main import app

runner = CliRunner()


def _run(*args: str):
    result = runner.invoke(app, ["simulate", *args])
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result


def test_default_run_json_to_stdout():
    result = _run("--S", "5", "--J", "2", "--json", "-")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert data["loop"] == "concentration"  # processes.DEFAULT_LOOP
    assert data["limit_cycle"] is True
    # Table 3 / REFERENCE.md: 142 s at dt = 0.1 s (1 %, see tests/test_loops.py).
    assert data["period_s"] == pytest.approx(142.0, rel=0.01)
    assert set(data["amplitude"]) >= {"op", "mv", "pv"}
    df = data["describing_function"]
    assert df["limit_cycle"] is True
    # REFERENCE.md describing-function column: 198 s, op amplitude 2.57 (0.5 %:
    # rounding of the printed values).
    assert df["period_s"] == pytest.approx(198.0, rel=0.005)
    assert df["amplitude"] == pytest.approx(2.57, rel=0.005)
    assert "limit cycle  YES" in result.stderr
    assert "describing" in result.stderr


def test_level_loop_deadband_and_files(tmp_path):
    out = tmp_path / "out"
    result = _run(
        "--loop",
        "level",
        "--S",
        "3",
        "--J",
        "0",
        "--duration",
        "300",
        "--json",
        str(out / "sim.json"),
        "--csv",
        str(out / "sim.csv"),
        "--plot",
        str(out / "sim.png"),
    )
    assert result.exit_code == 0, result.output
    assert result.stdout == ""  # data only to files; messages on stderr
    data = json.loads((out / "sim.json").read_text())
    assert data["limit_cycle"] is True
    assert data["period_s"] == pytest.approx(18.3, rel=0.03)  # Table 3 row, see test_loops
    frame = pd.read_csv(out / "sim.csv")
    assert list(frame.columns) == ["time", "sp", "pv", "op", "mv"] and len(frame) == 3000
    assert (out / "sim.png").stat().st_size > 1000
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temp files left


def test_no_limit_cycle_gives_null_period():
    result = _run("--S", "5", "--J", "0", "--json", "-")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert data["limit_cycle"] is False and data["period_s"] is None
    assert data["describing_function"]["limit_cycle"] is False
    assert "limit cycle  no" in result.stderr


def test_physical_valve():
    result = _run(
        "--valve", "physical", "--Fs", "1750", "--Fc", "0", "--calibration", "1.25", "--json", "-"
    )
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["settings"]["physical"]["calibration"] == 1.25
    # REFERENCE.md: 60.7 s; 3000 s holds ~33 cycles (2 %, see test_loops.py).
    assert data["period_s"] == pytest.approx(60.7, rel=0.02)
    assert data["amplitude"]["mv"] > data["amplitude"]["op"]  # miscalibration overshoot
    assert "quasi-static" in data["describing_function"]["basis"]
    assert "integrated at 0.0001 s" in result.stderr


def test_linear_valve_and_variable_integral():
    result = _run("--valve", "linear", "--json", "-")
    assert result.exit_code == 0
    assert json.loads(result.stdout)["limit_cycle"] is False
    result = _run("--kick", "5", "--integral-band", "4", "--json", "-")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert data["limit_cycle"] is False and data["settings"]["integral_band"] == 4.0


@pytest.mark.parametrize(
    "args,message",
    [
        (["--S", "abc"], "--S must be a number"),
        (["--S", "-1"], "--S must be >= 0"),
        (["--J", "nan"], "--J must be a finite number"),
        (["--J", "-0.5"], "--J must be >= 0"),
        (["--duration", "1e9"], "exceeds the limit"),
        (["--duration", "0"], "--duration must be > 0"),
        (["--dt", "x"], "--dt must be a number"),
        (["--loop", "flow"], "unknown loop 'flow'"),
        (["--valve", "sticky"], "unknown valve 'sticky'"),
        (["--valve", "physical", "--case", "rusty"], "unknown physical valve case"),
        (["--valve", "physical", "--Fs", "100", "--Fc", "200"], "use Fs >= Fc"),
        (["--Fs", "100"], "apply to --valve physical only"),
        # S and J mean nothing to the physical or the linear valve: refused, not ignored.
        (["--valve", "physical", "--S", "5", "--J", "2"], "--S/--J apply to the data-driven"),
        (["--valve", "physical", "--S", "5"], "--S applies to the data-driven valves"),
        (["--valve", "linear", "--J", "2"], "not to --valve linear"),
        (["--noise", "-1"], "--noise must be >= 0"),
        (["--integral-band", "-2"], "--integral-band must be >= 0"),
    ],
)
def test_usage_errors(args, message):
    result = _run(*args)
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("stiction: error: ")
    assert message in lines[0]


def test_unwritable_output(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for option in ("--json", "--csv", "--plot"):
        result = _run("--duration", "100", option, str(blocker / "out.x"))
        assert result.exit_code == 2, option
        assert "cannot write" in result.stderr.strip().splitlines()[-1]
    directory = tmp_path / "adir"
    directory.mkdir()
    result = _run("--duration", "100", "--json", str(directory))
    assert result.exit_code == 2


def test_noisy_data_driven_valve_that_never_slips_is_announced():
    """Choudhury's valve re-arms its stuck band at every reversal of a noisy op
    (Section 5.1): it sticks for good and op winds to its limit.  The run is kept and
    the summary and the JSON say why there is no cycle, and what to use instead."""
    result = _run("--S", "5", "--J", "2", "--noise", "0.01", "--seed", "1", "--json", "-")
    assert result.exit_code == 0, result.output
    data = json.loads(result.stdout)
    assert data["limit_cycle"] is False
    (warning,) = data["warnings"]
    assert "never slipped" in warning and "--valve kano" in warning
    assert "warning      the data-driven (Choudhury) valve never slipped" in result.stderr
    # Kano's valve keeps its stuck band through the noise: it cycles, no warning.
    result = _run(
        "--valve", "kano", "--S", "5", "--J", "2", "--noise", "0.01", "--seed", "1", "--json", "-"
    )
    data = json.loads(result.stdout)
    assert data["limit_cycle"] is True and data["warnings"] == []


def test_noiseless_run_has_no_warning():
    result = _run("--duration", "600", "--json", "-")
    assert json.loads(result.stdout)["warnings"] == []
