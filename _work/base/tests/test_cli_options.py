"""The read options of the commands that read loop files have one home.

``analyze``, ``gap`` and ``report`` turn their column, unit, loop-type, vendor,
action and compression options into the reader's keyword arguments through
:func:`stiction_cli.options.command_read_options`; given the same options, each must
hand the reader the same arguments.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

import stiction_cli.analyze as cli_analyze
import stiction_cli.gap as cli_gap
import stiction_cli.report as cli_report
from stiction_cli.main import app
from stiction_cli.options import READ_OPTION_NAMES, command_read_options
from stictiondiag.core.errors import DataError

runner = CliRunner()

ARGV = [
    "--pv", "A.PV", "--op", "A.OP", "--sp", "A.SP", "--ts", "2", "--op-units", "mA",
    "--op-range", "4", "20", "--loop-type", "level", "--self-regulating",
    "--vendor", "honeywell", "--action", "reverse", "--compression", "linear",
    "--mode", "A.MODE",
]  # fmt: skip

EXPECTED = {
    "pv": "A.PV",
    "op": "A.OP",
    "mv": None,
    "sp": "A.SP",
    "time": None,
    "ts": 2.0,
    "op_units": "mA",
    "op_range": (4.0, 20.0),
    "loop_type": "level",
    "integrating": False,
    "vendor": "honeywell",
    "action": "reverse",
    "compression": "linear",
    "mode": "A.MODE",
}


@pytest.fixture
def captured(monkeypatch):
    seen: dict[str, dict] = {}

    def reader(name):
        def fake(*args, **kwargs):
            options = kwargs.get("read_options", kwargs)
            seen[name] = {k: v for k, v in options.items() if k in READ_OPTION_NAMES}
            raise DataError("stop here")  # the reading is not under test

        return fake

    import stictiondiag.analysis as analysis
    import stictiondiag.apps.report as report

    monkeypatch.setattr(analysis, "analyze_file", reader("analyze"))
    monkeypatch.setattr(analysis, "diagnose_gap_file", reader("gap"))
    monkeypatch.setattr(report, "build_report", reader("report"))
    for module in (cli_analyze, cli_gap, cli_report):
        monkeypatch.setattr(module, "compile_if_cold", lambda: None)
    return seen


def test_analyze_gap_and_report_pass_the_same_read_options(captured, tmp_path: Path):
    data = tmp_path / "loop.csv"
    data.write_text("A.PV,A.OP\n1,2\n")
    for argv in (
        ["analyze", str(data), *ARGV],
        ["gap", str(data), *ARGV],
        ["report", str(data), "--out", str(tmp_path / "rep"), *ARGV],
    ):
        result = runner.invoke(app, argv)
        assert result.exit_code == 3, (argv[0], result.output)  # the fake reader's DataError
    assert set(captured) == {"analyze", "gap", "report"}
    for name, options in captured.items():
        assert options == EXPECTED, name


def test_command_read_options_names_every_option_and_no_more():
    params = {name: None for name in READ_OPTION_NAMES}
    params.update({"op_units": cli_analyze.OpUnits.percent, "file": "x", "gap": True})
    options = command_read_options(params)
    assert set(options) == set(READ_OPTION_NAMES) - {"vendor", "action", "compression"}
    del params["ts"]
    with pytest.raises(KeyError):
        command_read_options(params)
